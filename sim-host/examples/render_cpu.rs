//! CPU time of rendered hazcam stereo pairs on one core, on a scenario's terrain (default
//! `scenarios/marsyard-25m.toml`), through the simulator's camera device
//! ([`sim_host::devices::renderer::TexturedRenderer`]).
//!
//! `cargo run --release -p sim-host --example render_cpu -- [SCENARIO] [PAIRS]`
//!
//! The rover stands at points along the scenario's path, heading along it, 0.25 m above the
//! ground; the pairs are rendered in a one-thread rayon pool, and the time on the CPU of that
//! thread (Linux `/proc/thread-self/schedstat`, else wall clock) is reported per pair. Also
//! prints an FNV-1a hash of all images (a quick determinism check between builds).

use sim_host::devices::hazcam_calibration;
use sim_host::devices::renderer::StereoRenderer as _;
use sim_host::scenario::Scenario;
use sim_host::surface::TerrainSurface;
use sim_host::terrain::Terrain;

/// Nanoseconds this thread has spent on a CPU (wall clock where schedstat is unavailable).
fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| {
            static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
            START
                .get_or_init(std::time::Instant::now)
                .elapsed()
                .as_nanos() as u64
        })
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .unwrap_or_else(|| "scenarios/marsyard-25m.toml".into());
    let pairs: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(20);
    let scenario = Scenario::load(std::path::Path::new(&path))?;
    let terrain = Terrain::new(scenario.terrain.clone(), scenario.seed, &scenario.waypoints);
    let calib = hazcam_calibration();
    let sun = scenario.site.sun_w(0.0);
    // Poses along the path.
    let wp = &scenario.waypoints;
    let poses: Vec<([[f64; 3]; 3], [f64; 3])> = (0..pairs)
        .map(|k| {
            let s = k as f64 / pairs.max(1) as f64 * (wp.len() - 1) as f64;
            let i = (s as usize).min(wp.len() - 2);
            let t = s - i as f64;
            let (a, b) = (wp[i], wp[i + 1]);
            let (x, y) = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
            let yaw = (b[1] - a[1]).atan2(b[0] - a[0]);
            let (sy, cy) = yaw.sin_cos();
            let r_wr = [[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]];
            let p = [x, y, -terrain.height_m(x, y) - 0.25];
            let k = calib.rot_rover_from_camera;
            let mut r_wk = [[0.0; 3]; 3];
            for (i, row) in r_wk.iter_mut().enumerate() {
                for (j, out) in row.iter_mut().enumerate() {
                    *out = (0..3).map(|m| r_wr[i][m] * k[m][j]).sum();
                }
            }
            let t = calib.pos_camera_in_rover_m;
            let mut c = p;
            for (i, ci) in c.iter_mut().enumerate() {
                *ci += (0..3).map(|m| r_wr[i][m] * t[m]).sum::<f64>();
            }
            (r_wk, c)
        })
        .collect();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let (w, h) = (rover_hal::IMAGE_WIDTH_PX, rover_hal::IMAGE_HEIGHT_PX);
    let (ns, hash, errors) = pool.install(|| {
        let renderer = sim_host::devices::renderer::TexturedRenderer::new(
            calib,
            scenario.seed,
            [sun.x, sun.y, sun.z],
        );
        let mut left = vec![0u8; w * h];
        let mut right = vec![0u8; w * h];
        // One warm-up pair (first-touch of the buffers).
        renderer.render(
            &terrain, poses[0].0, poses[0].1, &calib, 0, &mut left, &mut right,
        );
        let mut hash = 0xcbf2_9ce4_8422_2325u64;
        let mut ns = Vec::new();
        for (k, (rot, pos)) in poses.iter().enumerate() {
            let t0 = thread_cpu_ns();
            renderer.render(
                &terrain,
                *rot,
                *pos,
                &calib,
                k as u64 + 1,
                &mut left,
                &mut right,
            );
            ns.push(thread_cpu_ns() - t0);
            if std::env::var_os("RENDER_CPU_EACH").is_some() {
                println!(
                    "pair {k}: {:.1} ms at {pos:?}",
                    (thread_cpu_ns() - t0) as f64 * 1e-6
                );
            }
            for &b in left.iter().chain(right.iter()) {
                hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
            }
        }
        (ns, hash, renderer.errors())
    });
    let mut ms: Vec<f64> = ns.iter().map(|&n| n as f64 * 1e-6).collect();
    let mean = ms.iter().sum::<f64>() / ms.len() as f64;
    ms.sort_by(f64::total_cmp);
    println!(
        "{} pairs on one core: mean {mean:.1} ms, median {:.1} ms, min {:.1} ms, max {:.1} ms \
         CPU per stereo pair; errors {}; image hash {hash:016x}",
        ms.len(),
        ms[ms.len() / 2],
        ms[0],
        ms[ms.len() - 1],
        errors
    );
    Ok(())
}
