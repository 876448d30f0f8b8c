//! Host benchmarks of the kinematics hot path: forward kinematics (eq. 15), inverse kinematics
//! (eq. 16-25), contact points (eq. 12) and one odometry step.
// A host tool, not flight code: the flight crate's lints for panics and docs do not apply.
#![allow(missing_docs, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use criterion::{criterion_group, criterion_main, Criterion};
use fsw::kinematics::{
    forward_kinematics, inverse_kinematics, wheel_contact_points, KinematicOdometry,
    OdometryConfig, SuspensionRates, SuspensionState, VehicleCommand, ROCKY8,
};
use rover_hal::JointState;
use std::hint::black_box;

fn state() -> SuspensionState {
    SuspensionState {
        rocker_rad: 0.1,
        bogie_rad: [-0.2, 0.15],
        steer_rad: [0.2, 0.25, 0.0, 0.05, -0.2, -0.15],
    }
}

fn bench(c: &mut Criterion) {
    let s = state();
    let rates = SuspensionRates {
        rocker_rad_s: 0.01,
        bogie_rad_s: [0.02, -0.01],
    };
    let drive = [1.0, 1.1, 0.9, 1.0, 0.95, 1.05];
    c.bench_function("kinematics/forward_eq15", |b| {
        b.iter(|| {
            forward_kinematics(
                &ROCKY8,
                black_box(&s),
                black_box(&rates),
                black_box(&drive),
                &[true; 6],
            )
        })
    });
    let cmd = VehicleCommand {
        x_dot_m_s: 0.08,
        y_dot_m_s: 0.02,
        yaw_rate_rad_s: 0.05,
    };
    c.bench_function("kinematics/inverse_eq16_25", |b| {
        b.iter(|| inverse_kinematics(&ROCKY8, black_box(&s), black_box(&cmd)))
    });
    c.bench_function("kinematics/contact_points_eq12", |b| {
        b.iter(|| wheel_contact_points(&ROCKY8, black_box(&s)))
    });
    let j0 = JointState {
        t_us: 0,
        steer_angle_rad: s.steer_rad,
        rocker_rad: s.rocker_rad,
        bogie_rad: s.bogie_rad,
        wheel_valid: [true; 6],
        suspension_valid: true,
        ..Default::default()
    };
    let j1 = JointState {
        t_us: 50_000,
        drive_angle_rad: [0.05; 6],
        ..j0
    };
    c.bench_function("kinematics/odometry_step_with_covariance", |b| {
        let mut odo = KinematicOdometry::new(ROCKY8, OdometryConfig::default());
        b.iter(|| {
            let _ = odo.start(&j0);
            odo.update(black_box(&j1))
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
