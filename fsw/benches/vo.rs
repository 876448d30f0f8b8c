//! Benchmark: one full visual odometry update (track 150 features, motion, new keyframe) on a
//! 640x480 stereo pair of a textured ground plane seen by the Rocky 8 hazcams.
// A host tool, not flight code: the flight crate's lints for panics and docs do not apply.
#![allow(missing_docs, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use criterion::{criterion_group, criterion_main, Criterion};
use fsw::types::{Mat6, Quat, RelativePose, Vec3};
use fsw::vo::{VisualOdometry, VoConfig};
use rover_hal::{StereoCalibration, StereoFrame, IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX};
use std::hint::black_box;

/// Albedo: a lattice of random grey levels (2 cm cells) smoothed by bilinear interpolation.
fn albedo(x: f64, y: f64) -> f64 {
    let cell = |i: i64, j: i64| {
        let h = (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
            ^ (j as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f);
        let h = (h ^ (h >> 31)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        40.0 + 180.0 * ((h >> 40) as f64 / (1u64 << 24) as f64)
    };
    let (u, v) = (x / 0.02, y / 0.02);
    let (i, j) = (u.floor(), v.floor());
    let (fu, fv) = (u - i, v - j);
    let (i, j) = (i as i64, j as i64);
    let top = cell(i, j) * (1.0 - fu) + cell(i + 1, j) * fu;
    let bottom = cell(i, j + 1) * (1.0 - fu) + cell(i + 1, j + 1) * fu;
    top * (1.0 - fv) + bottom * fv
}

/// Left and right images with the rover at `forward_m` along x, yawed by `yaw_rad`.
fn render(cal: &StereoCalibration, forward_m: f64, yaw_rad: f64) -> (Vec<u8>, Vec<u8>) {
    let m = cal.rot_rover_from_camera;
    let (sy, cy) = yaw_rad.sin_cos();
    let rot = |v: [f64; 3]| [cy * v[0] - sy * v[1], sy * v[0] + cy * v[1], v[2]];
    let k_to_w = |v: [f64; 3]| {
        rot([
            m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
            m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
            m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
        ])
    };
    let p = rot(cal.pos_camera_in_rover_m);
    let left_centre = [p[0] + forward_m, p[1], p[2]];
    let b = k_to_w([cal.baseline_m, 0.0, 0.0]);
    let right_centre = [
        left_centre[0] + b[0],
        left_centre[1] + b[1],
        left_centre[2] + b[2],
    ];
    let image = |c: [f64; 3]| {
        let mut img = vec![0u8; IMAGE_PIXELS];
        for y in 0..IMAGE_HEIGHT_PX {
            for x in 0..IMAGE_WIDTH_PX {
                let d = k_to_w([
                    (x as f64 - cal.cx_px) / cal.fx_px,
                    (y as f64 - cal.cy_px) / cal.fy_px,
                    1.0,
                ]);
                let t = -c[2] / d[2];
                img[y * IMAGE_WIDTH_PX + x] = albedo(c[0] + t * d[0], c[1] + t * d[1]) as u8;
            }
        }
        img
    };
    (image(left_centre), image(right_centre))
}

fn bench_vo(c: &mut Criterion) {
    let cal = fsw::vo::rocky8_hazcam();
    let (l0, r0) = render(&cal, 0.0, 0.0);
    let (l1, r1) = render(&cal, 0.25, 0.02);
    let f0 = StereoFrame {
        left: &l0,
        right: &r0,
        capture_t_us: 1_000_000,
        sequence: 0,
    };
    let f1 = StereoFrame {
        left: &l1,
        right: &r1,
        capture_t_us: 2_000_000,
        sequence: 1,
    };
    let mut keyed = Box::new(VisualOdometry::<150>::new(VoConfig::default(), &cal).unwrap());
    keyed.run_to_completion(&f0, None).unwrap();
    // Motion prior from wheel odometry: 5 % short and 0.5 deg off in yaw.
    let prior = RelativePose {
        t0_us: 1_000_000,
        t1_us: 2_000_000,
        rot_0_1: Quat::from_euler_angles(0.0, 0.0, 0.02 - 0.5f64.to_radians()),
        trans_0_1_m: Vec3::new(0.2375, 0.0, 0.0),
        covariance: Mat6::identity() * 1e-3,
        observed: [true; 6],
    };
    let out = keyed.clone().run_to_completion(&f1, Some(&prior)).unwrap();
    println!("vo bench update: {:?}", out.quality);
    assert!(out.pose.is_some());
    c.bench_function("vo_update_640x480_n150", |b| {
        b.iter_batched_ref(
            || keyed.clone(),
            |vo| black_box(vo.run_to_completion(black_box(&f1), Some(&prior))),
            criterion::BatchSize::LargeInput,
        )
    });
    c.bench_function("vo_first_frame_640x480_n150", |b| {
        b.iter_batched_ref(
            || Box::new(VisualOdometry::<150>::new(VoConfig::default(), &cal).unwrap()),
            |vo| black_box(vo.run_to_completion(black_box(&f0), None)),
            criterion::BatchSize::LargeInput,
        )
    });
}

criterion_group!(benches, bench_vo);
criterion_main!(benches);
