//! Time of one rendered hazcam stereo pair (640x480 x 2): a flat textured yard and a 10 deg
//! slope seen face on. Set `RAYON_NUM_THREADS=1` to measure a single core.

use criterion::{criterion_group, criterion_main, Criterion};
use sim_host::devices::hazcam_calibration;
use sim_host::render::{
    AlbedoTexture, CameraPose, HeightFn, RenderSettings, StereoRenderer, Sun, TextureParams,
    TexturedSurface,
};
use std::hint::black_box;
use std::sync::Arc;

fn bench_pairs(c: &mut Criterion) {
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
    let sloped = TexturedSurface::new(HeightFn(move |x: f64, _y: f64| slope * x), texture);
    let mut seed = 0u64;
    c.bench_function("stereo_pair_flat_yard", |b| {
        b.iter(|| {
            seed += 1;
            renderer
                .render(black_box(&flat), &pose, &sun, seed, &mut left, &mut right)
                .ok()
        })
    });
    c.bench_function("stereo_pair_slope_10deg", |b| {
        b.iter(|| {
            seed += 1;
            renderer
                .render(black_box(&sloped), &pose, &sun, seed, &mut left, &mut right)
                .ok()
        })
    });
}

criterion_group!(benches, bench_pairs);
criterion_main!(benches);
