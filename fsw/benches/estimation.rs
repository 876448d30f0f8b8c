//! Estimator timing on the host: one IMU propagation step (with 3 live clones, the flight
//! case) and one 5-dof kinematic relative-pose update.
// A host tool, not flight code: the flight crate's lints for panics and docs do not apply.
#![allow(missing_docs, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use criterion::{criterion_group, criterion_main, Criterion};
use fsw::estimation::{CoreCov, Ekf, EkfConfig, NominalState, MARS_GRAVITY_M_S2};
use fsw::types::{Mat6, Quat, RelativePose, Vec3};
use rover_hal::ImuSample;
use std::hint::black_box;

fn sample(t_us: u64) -> ImuSample {
    ImuSample {
        t_us,
        gyro_rad_s: [0.001, -0.002, 0.05],
        accel_m_s2: [0.02, -0.01, -MARS_GRAVITY_M_S2],
        valid: true,
    }
}

fn filter_with_clones() -> Ekf {
    let mut p0 = CoreCov::identity() * 1e-4;
    p0[(4, 4)] = 1e-8;
    let mut ekf = Ekf::new(EkfConfig::default(), NominalState::at_rest(0), &p0).expect("filter");
    for k in 1..=3u64 {
        ekf.propagate(&sample(k * 5_000)).expect("propagate");
        ekf.clone_at(k * 5_000).expect("clone");
    }
    ekf
}

fn bench(c: &mut Criterion) {
    let base = filter_with_clones();
    c.bench_function("ekf_propagate_3_clones", |b| {
        let mut ekf = base.clone();
        let mut t = ekf.time_us();
        b.iter(|| {
            t += 5_000;
            black_box(ekf.propagate(black_box(&sample(t)))).ok();
        })
    });
    let mut ekf = base.clone();
    ekf.propagate(&sample(20_000)).expect("propagate");
    let m = RelativePose {
        t0_us: 15_000,
        t1_us: 20_000,
        rot_0_1: Quat::identity(),
        trans_0_1_m: Vec3::new(0.001, 0.0, 0.0),
        covariance: Mat6::identity() * 1e-6,
        observed: [true, true, true, true, true, false],
    };
    c.bench_function("ekf_relative_pose_update", |b| {
        b.iter_batched_ref(
            || ekf.clone(),
            |e| black_box(e.update_relative_pose(black_box(&m), false)).ok(),
            criterion::BatchSize::SmallInput,
        )
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
