//! Cost of each visual-odometry work item on simulator-rendered pairs (host wall time per item,
//! the largest items listed by their index in the update), to see which items dominate a
//! background slot. Run: `cargo run --release -p sim-host --example vo_items`.

use fsw::types::{Mat6, Quat, RelativePose, Vec3};
use fsw::vo::{Progress, VisualOdometry};
use nalgebra::{Rotation3, Vector3};
use rover_hal::{StereoFrame, IMAGE_PIXELS};
use sim_host::devices::hazcam_calibration;
use sim_host::render::{
    AlbedoTexture, CameraPose, HeightFn, RenderSettings, StereoRenderer, Sun, TextureParams,
    TexturedSurface,
};
use std::sync::Arc;
use std::time::Instant;

fn pose(k: usize) -> (Rotation3<f64>, Vector3<f64>) {
    let p = Vector3::new(0.1 * k as f64, 0.0, -0.1);
    (Rotation3::identity(), p)
}

fn main() {
    let calib = hazcam_calibration();
    let texture = Arc::new(AlbedoTexture::new(TextureParams {
        seed: 11,
        ..TextureParams::default()
    }));
    let ground = TexturedSurface::new(HeightFn(|_x: f64, _y: f64| 0.0), texture);
    let sun = Sun::from_azimuth_elevation(0.6, 0.7);
    let mut renderer = StereoRenderer::new(calib, RenderSettings::default());
    let config = fsw::flight::nav::NavConfig::rocky8([0.0; 3], 0.0)
        .vo
        .pipeline;
    let Ok(mut vo) = VisualOdometry::<150>::new(config, &calib) else {
        eprintln!("VO refused the calibration");
        return;
    };
    let mut left = vec![0u8; IMAGE_PIXELS];
    let mut right = vec![0u8; IMAGE_PIXELS];
    for k in 0..3usize {
        let (rot, pos) = pose(k);
        let rows = [0, 1, 2].map(|i| [rot[(i, 0)], rot[(i, 1)], rot[(i, 2)]]);
        let cam = CameraPose::from_rover(rows, [pos.x, pos.y, pos.z], &calib);
        if renderer
            .render(&ground, &cam, &sun, 100 + k as u64, &mut left, &mut right)
            .is_err()
        {
            eprintln!("render failed");
            return;
        }
        let frame = StereoFrame {
            left: &left,
            right: &right,
            capture_t_us: 1_000_000 * (k as u64 + 1),
            sequence: k as u32,
        };
        let prior = (k > 0).then(|| RelativePose {
            t0_us: 1_000_000 * k as u64,
            t1_us: 1_000_000 * (k as u64 + 1),
            rot_0_1: Quat::identity(),
            trans_0_1_m: Vec3::new(0.1, 0.0, 0.0),
            covariance: Mat6::identity() * 1e-3,
            observed: [true; 6],
        });
        if vo.start(&frame, prior.as_ref()).is_err() {
            eprintln!("start failed");
            return;
        }
        let mut times = Vec::new();
        let t_all = Instant::now();
        loop {
            let t = Instant::now();
            let p = vo.step(&frame, 1);
            times.push(t.elapsed().as_secs_f64() * 1e6);
            if let Progress::Finished(r) = p {
                println!(
                    "update {k}: {} items, {:.1} ms, result ok {}",
                    times.len(),
                    t_all.elapsed().as_secs_f64() * 1e3,
                    r.is_ok()
                );
                break;
            }
        }
        let mut idx: Vec<usize> = (0..times.len()).collect();
        idx.sort_by(|a, b| times[*b].total_cmp(&times[*a]));
        let top: Vec<String> = idx
            .iter()
            .take(12)
            .map(|i| format!("#{i}:{:.0}us", times[*i]))
            .collect();
        println!("  largest items: {}", top.join(" "));
        let median = {
            let mut t = times.clone();
            t.sort_by(f64::total_cmp);
            t[t.len() / 2]
        };
        println!("  median item {median:.1} us");
    }
}
