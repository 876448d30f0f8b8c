//! Time of one rendered hazcam stereo pair (640x480 x 2) on ONE core: each pair is rendered
//! inside a one-thread rayon pool, so criterion's time per iteration is the single-core time per
//! stereo pair. Scenes: a flat textured yard, a 10 deg slope seen face on, and the
//! `marsyard-25m` terrain (rocks, roughness) at the start of its path. The `_threads` variant
//! renders the marsyard pair with the default pool, for comparison (same bytes).
//!
//! `cargo bench -p sim-host --bench render -- --quick`. On a shared machine criterion's
//! wall-clock figure includes time the process waits for a CPU; `cargo run --release -p sim-host
//! --example render_cpu` reports the CPU time of the rendering thread instead.

use criterion::{criterion_group, criterion_main, Criterion};
use sim_host::devices::hazcam_calibration;
use sim_host::render::{
    AlbedoTexture, CameraPose, HeightFn, RenderSettings, StereoRenderer, Sun, TextureParams,
    TexturedSurface,
};
use sim_host::scenario::Scenario;
use sim_host::surface::TerrainSurface;
use sim_host::terrain::Terrain;
use std::hint::black_box;
use std::sync::Arc;

fn bench_pairs(c: &mut Criterion) {
    let one_core = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    let texture = Arc::new(AlbedoTexture::new(TextureParams::default()));
    let calib = hazcam_calibration();
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let pose = CameraPose::from_rover(identity, [0.0, 0.0, -0.25], &calib);
    let sun = Sun::from_azimuth_elevation(135f64.to_radians(), 40f64.to_radians());
    let mut renderer = StereoRenderer::new(calib, RenderSettings::default());
    let mut left = vec![0u8; rover_hal::IMAGE_PIXELS];
    let mut right = vec![0u8; rover_hal::IMAGE_PIXELS];
    let slope = 10f64.to_radians().tan();
    let flat = TexturedSurface::new(HeightFn(|_x: f64, _y: f64| 0.0), texture.clone());
    let sloped = TexturedSurface::new(HeightFn(move |x: f64, _y: f64| slope * x), texture.clone());
    let scenario_path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../scenarios/marsyard-25m.toml"
    );
    let scenario = Scenario::load(std::path::Path::new(scenario_path)).expect("marsyard-25m");
    let yard = TexturedSurface::new(
        Terrain::new(scenario.terrain.clone(), scenario.seed, &scenario.waypoints),
        texture,
    );
    // Rover at the first waypoint heading north, 0.25 m above the ground.
    let [x0, y0] = scenario.waypoints[0];
    let yard_pose =
        CameraPose::from_rover(identity, [x0, y0, -yard.height_m(x0, y0) - 0.25], &calib);
    let mut seed = 0u64;
    for (name, surface, pose) in [
        ("stereo_pair_flat_yard_1core", &flat as &dyn Scene, &pose),
        ("stereo_pair_slope_10deg_1core", &sloped, &pose),
        ("stereo_pair_marsyard_1core", &yard, &yard_pose),
    ] {
        c.bench_function(name, |b| {
            b.iter(|| {
                seed += 1;
                one_core.install(|| {
                    surface
                        .render(&mut renderer, pose, &sun, seed, &mut left, &mut right)
                        .ok()
                })
            })
        });
    }
    c.bench_function("stereo_pair_marsyard_threads", |b| {
        b.iter(|| {
            seed += 1;
            renderer
                .render(
                    black_box(&yard),
                    &yard_pose,
                    &sun,
                    seed,
                    &mut left,
                    &mut right,
                )
                .ok()
        })
    });
}

/// A textured surface of any height model, rendered through the generic
/// [`StereoRenderer::render`].
trait Scene: Sync {
    fn render(
        &self,
        renderer: &mut StereoRenderer,
        pose: &CameraPose,
        sun: &Sun,
        seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<sim_host::render::RenderStats, sim_host::render::RenderError>;
}

impl<H: TerrainSurface> Scene for TexturedSurface<H> {
    fn render(
        &self,
        renderer: &mut StereoRenderer,
        pose: &CameraPose,
        sun: &Sun,
        seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<sim_host::render::RenderStats, sim_host::render::RenderError> {
        renderer.render(black_box(self), pose, sun, seed, left, right)
    }
}

criterion_group!(benches, bench_pairs);
criterion_main!(benches);
