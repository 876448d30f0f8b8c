//! Tests of inverse kinematics, odometry, the planar model and robustness (KIN-4 .. KIN-9).

#![allow(clippy::needless_range_loop)]

use super::tests::{level, random_state};
use super::*;
use crate::types::Vec3;
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rover_hal::JointState;

const PI: f64 = core::f64::consts::PI;

fn cmd(x: f64, y: f64, yaw: f64) -> VehicleCommand {
    VehicleCommand {
        x_dot_m_s: x,
        y_dot_m_s: y,
        yaw_rate_rad_s: yaw,
    }
}

/// KIN-4: IK then FK round trip over random commands and random rocker/bogie/steering states:
/// the commanded [x_dot, y_dot, yaw] come back with a residual below 1e-9 (FK fed with IK's
/// steering angles, wheel rates and the suspension rates of the solution).
#[test]
fn kin_4_round_trip_ik_fk() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut worst: f64 = 0.0;
    for _ in 0..2000 {
        let s = random_state(&mut rng);
        let c = cmd(
            rng.random_range(-0.15..0.15),
            rng.random_range(-0.15..0.15),
            rng.random_range(-0.4..0.4),
        );
        // Keep within the wheel-rate limit (exercises the scaling helper).
        let k = max_speed_scale(&ROCKY8, &s, &c, 1.9).unwrap().min(1.0);
        let c = cmd(c.x_dot_m_s * k, c.y_dot_m_s * k, c.yaw_rate_rad_s * k);
        let ik = inverse_kinematics(&ROCKY8, &s, &c).unwrap();
        let mut s_cmd = s;
        s_cmd.steer_rad = ik.command.steer_angle_rad;
        let fk = forward_kinematics(
            &ROCKY8,
            &s_cmd,
            &ik.suspension_rates,
            &ik.command.wheel_rate_rad_s,
            &[true; 6],
        )
        .unwrap();
        let back = [fk.body_rates[0], fk.body_rates[1], fk.body_rates[5]];
        let sent = [c.x_dot_m_s, c.y_dot_m_s, c.yaw_rate_rad_s];
        for (b, e) in back.iter().zip(sent.iter()) {
            worst = worst.max((b - e).abs());
        }
        worst = worst.max((fk.body_rates - ik.body_rates).norm());
        assert!(fk.residual_rms_m_s < 1e-9);
    }
    assert!(worst < 1e-9, "worst round-trip residual {worst}");
}

/// KIN-5: hand calculations on level ground (contacts from Table 2: front x_1 = 0.39343 m,
/// middle x_3 = 0.00048 m, rear x_5 = -0.3541 m, y = +-0.3111 m, r = 0.1 m).
#[test]
fn kin_5_hand_calculated_cases() {
    let s = level();
    let p = wheel_contact_points(&ROCKY8, &s).unwrap();
    let x1 = -0.1420 + 0.2812 * libm::cos(0.2698) + 0.2644;
    assert!((p[0].x - x1).abs() < 1e-12 && (p[0].x - 0.39343).abs() < 1e-5);
    // Straight 0.1 m/s: psi = 0, theta_dot = 0.1 / 0.1 = 1 rad/s on every wheel.
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(0.1, 0.0, 0.0)).unwrap();
    for i in 0..6 {
        assert!(ik.command.steer_angle_rad[i].abs() < 1e-12);
        assert!((ik.command.wheel_rate_rad_s[i] - 1.0).abs() < 1e-12);
    }
    assert_eq!(ik.icr().unwrap(), Icr::Direction { theta_o_rad: 0.0 });
    // Crab 0.1 m/s forward, 0.05 m/s right: psi = atan(0.5) = 0.46365 rad (eq. 22),
    // theta_dot = sqrt(0.0125) / 0.1 = 1.11803 rad/s.
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(0.1, 0.05, 0.0)).unwrap();
    for i in 0..6 {
        assert!((ik.command.steer_angle_rad[i] - 0.463_647_609).abs() < 1e-9);
        assert!((ik.command.wheel_rate_rad_s[i] - 1.118_033_989).abs() < 1e-9);
    }
    // Turn in place 0.2 rad/s (right): wheel i moves at yaw * (-y_i, x_i); front right
    // (0.39343, 0.3111): direction atan2(0.39343, -0.3111) = 2.2400 rad, wrapped by -pi to
    // -0.9017 rad with the rate flipped: -0.2 * sqrt(0.39343^2 + 0.3111^2) / 0.1 = -1.00311.
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(0.0, 0.0, 0.2)).unwrap();
    for i in 0..6 {
        let (x, y) = (p[i].x, p[i].y);
        let psi = -libm::atan(x / y);
        let rate = -libm::copysign(1.0, y) * 0.2 * crate::linalg::sqrt(x * x + y * y) / 0.1;
        assert!(
            (ik.command.steer_angle_rad[i] - psi).abs() < 1e-9,
            "wheel {i}"
        );
        assert!(
            (ik.command.wheel_rate_rad_s[i] - rate).abs() < 1e-9,
            "wheel {i}"
        );
    }
    assert!((ik.command.steer_angle_rad[0] + 0.9017).abs() < 1e-4);
    assert!((ik.command.wheel_rate_rad_s[0] + 1.00311).abs() < 1e-4);
    assert_eq!(ik.icr().unwrap(), Icr::Point { x_m: 0.0, y_m: 0.0 });
    // Arc: 0.1 m/s with a 2 m radius to the right: yaw = 0.05 rad/s, ICR (0, 2) (eq. 16-17).
    // Eq. 21: psi_i = atan(x_i / (2 - y_i)), theta_dot_i = 0.05 * |ICR - p_i| / 0.1.
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(0.1, 0.0, 0.05)).unwrap();
    assert_eq!(
        ik.icr().unwrap(),
        Icr::Point {
            x_m: -0.0,
            y_m: 2.0
        }
    );
    for i in 0..6 {
        let (x, y) = (p[i].x, p[i].y);
        let psi = libm::atan(x / (2.0 - y));
        let rate = 0.05 * crate::linalg::sqrt(x * x + (2.0 - y) * (2.0 - y)) / 0.1;
        assert!(
            (ik.command.steer_angle_rad[i] - psi).abs() < 1e-9,
            "wheel {i}"
        );
        assert!(
            (ik.command.wheel_rate_rad_s[i] - rate).abs() < 1e-9,
            "wheel {i}"
        );
    }
    // Front right on the inside of the turn: atan(0.39343 / (2 - 0.3111)) = 0.22884 rad.
    assert!((ik.command.steer_angle_rad[0] - 0.22884).abs() < 1e-4);
    // Level ground: no unactuated motion.
    assert!(ik.body_rates.fixed_rows::<3>(2).norm() < 1e-12);
}

/// KIN-6: steering wrap takes the equivalent angle with the least motion and flips the rate;
/// limits and impossible commands give error values.
#[test]
fn kin_6_steering_wrap_limits_and_errors() {
    // Reverse straight from psi = 0: stays at 0 with negative rates (not +-pi).
    let s = level();
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(-0.1, 0.0, 0.0)).unwrap();
    for i in 0..6 {
        assert!(ik.command.steer_angle_rad[i].abs() < 1e-12);
        assert!((ik.command.wheel_rate_rad_s[i] + 1.0).abs() < 1e-12);
    }
    // Pure crab right (90 deg): from psi = -1.5 the wheels go to -pi/2 backwards (least
    // motion), from psi = +1.5 to +pi/2 forwards.
    let mut s = level();
    s.steer_rad = [-1.5; 6];
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(0.0, 0.1, 0.0)).unwrap();
    for i in 0..6 {
        assert!((ik.command.steer_angle_rad[i] + PI / 2.0).abs() < 1e-12);
        assert!((ik.command.wheel_rate_rad_s[i] + 1.0).abs() < 1e-12);
    }
    s.steer_rad = [1.5; 6];
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(0.0, 0.1, 0.0)).unwrap();
    assert!((ik.command.steer_angle_rad[0] - PI / 2.0).abs() < 1e-12);
    assert!((ik.command.wheel_rate_rad_s[0] - 1.0).abs() < 1e-12);
    // A narrower steering range cannot crab sideways.
    let mut narrow = ROCKY8;
    narrow.limits.steer_rad = 1.0;
    assert_eq!(
        inverse_kinematics(&narrow, &level(), &cmd(0.0, 0.1, 0.0)),
        Err(KinematicsError::SteeringLimit { wheel: 0 })
    );
    // Too fast: wheel rate limit; the scaling helper makes it feasible.
    let fast = cmd(0.5, 0.0, 0.3);
    assert!(matches!(
        inverse_kinematics(&ROCKY8, &level(), &fast),
        Err(KinematicsError::WheelRateLimit { .. })
    ));
    let k = max_speed_scale(&ROCKY8, &level(), &fast, 2.0).unwrap();
    let scaled = cmd(0.5 * k, 0.0, 0.3 * k);
    let ik = inverse_kinematics(&ROCKY8, &level(), &scaled).unwrap();
    let top = ik
        .command
        .wheel_rate_rad_s
        .iter()
        .fold(0.0_f64, |m, r| m.max(r.abs()));
    assert!((top - 2.0).abs() < 1e-9);
    // Zero command: steering held, wheels stopped, no scaling limit.
    let mut s = level();
    s.steer_rad = [0.3; 6];
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(0.0, 0.0, 0.0)).unwrap();
    assert_eq!(ik.command.steer_angle_rad, [0.3; 6]);
    assert_eq!(ik.command.wheel_rate_rad_s, [0.0; 6]);
    assert_eq!(ik.icr().unwrap(), Icr::Stationary);
    assert_eq!(
        max_speed_scale(&ROCKY8, &s, &cmd(0.0, 0.0, 0.0), 2.0),
        Ok(f64::INFINITY)
    );
    // Non-finite commands and angles out of range.
    assert_eq!(
        inverse_kinematics(&ROCKY8, &level(), &cmd(f64::NAN, 0.0, 0.0)),
        Err(KinematicsError::NonFinite)
    );
    assert_eq!(
        instantaneous_centre(&cmd(0.1, f64::INFINITY, 0.0)),
        Err(KinematicsError::NonFinite)
    );
    let mut s = level();
    s.rocker_rad = 1.0;
    assert_eq!(
        inverse_kinematics(&ROCKY8, &s, &cmd(0.1, 0.0, 0.0)),
        Err(KinematicsError::JointOutOfRange)
    );
    assert_eq!(
        max_speed_scale(&ROCKY8, &level(), &cmd(0.1, 0.0, 0.0), 0.0),
        Err(KinematicsError::NonFinite)
    );
}

fn reading(t_us: u64, drive: [f64; 6], steer: [f64; 6]) -> JointState {
    JointState {
        t_us,
        drive_angle_rad: drive,
        drive_rate_rad_s: [0.0; 6],
        steer_angle_rad: steer,
        rocker_rad: 0.0,
        bogie_rad: [0.0, 0.0],
        wheel_valid: [true; 6],
        suspension_valid: true,
    }
}

/// KIN-7: vehicle odometry integrates a 1 m straight drive and a quarter turn in place to the
/// right pose, its covariance grows with distance and is symmetric positive semi-definite,
/// the vertical translation is flagged unobserved, and bad readings give error values.
#[test]
fn kin_7_odometry_straight_and_turn() {
    let mut odo = KinematicOdometry::new(ROCKY8, OdometryConfig::default());
    odo.start(&reading(0, [0.0; 6], [0.0; 6])).unwrap();
    // 100 steps of 0.1 rad = 1 m at r = 0.1 m.
    for k in 1..=100u64 {
        let a = 0.1 * k as f64;
        odo.update(&reading(k * 50_000, [a; 6], [0.0; 6])).unwrap();
    }
    let pose = odo.relative_pose().unwrap();
    assert!((pose.trans_0_1_m - Vec3::new(1.0, 0.0, 0.0)).norm() < 1e-9);
    assert!(pose.rot_0_1.angle() < 1e-12);
    assert_eq!(pose.observed, [true, true, true, true, true, false]);
    assert_eq!((pose.t0_us, pose.t1_us), (0, 5_000_000));
    let cov = pose.covariance;
    assert!((cov - cov.transpose()).norm() < 1e-15);
    assert!(cov.symmetric_eigenvalues().iter().all(|e| *e > -1e-15));
    let sx = crate::linalg::sqrt(cov[(3, 3)]);
    assert!(sx > 1e-3 && sx < 0.1, "sigma x {sx}");
    // Quarter turn in place to the right: steering tangent, wheel rates from IK.
    let ik = inverse_kinematics(&ROCKY8, &level(), &cmd(0.0, 0.0, 0.1)).unwrap();
    let steer = ik.command.steer_angle_rad;
    let mut odo = KinematicOdometry::new(ROCKY8, OdometryConfig::default());
    odo.start(&reading(0, [0.0; 6], steer)).unwrap();
    let steps = 200u64;
    let total_time = (PI / 2.0) / 0.1;
    let mut drive = [0.0; 6];
    for k in 1..=steps {
        for (d, r) in drive.iter_mut().zip(ik.command.wheel_rate_rad_s.iter()) {
            *d = r * total_time * k as f64 / steps as f64;
        }
        odo.update(&reading(k * 10_000, drive, steer)).unwrap();
    }
    let pose = odo.take().unwrap();
    let (roll, pitch, yaw) = pose.rot_0_1.euler_angles();
    assert!((yaw - PI / 2.0).abs() < 1e-9 && roll.abs() < 1e-9 && pitch.abs() < 1e-9);
    assert!(pose.trans_0_1_m.norm() < 1e-9);
    // Errors: time not advancing, NaN, invalid suspension; the interval ends after a bad step.
    assert_eq!(
        odo.update(&reading(steps * 10_000, drive, steer)),
        Err(KinematicsError::TimeNotAdvancing)
    );
    let mut nan = reading(steps * 10_000 + 1, drive, steer);
    nan.drive_angle_rad[2] = f64::NAN;
    assert_eq!(odo.update(&nan), Err(KinematicsError::NonFinite));
    assert_eq!(odo.relative_pose(), Err(KinematicsError::NotStarted));
    let mut bad = reading(0, drive, steer);
    bad.suspension_valid = false;
    assert_eq!(odo.start(&bad), Err(KinematicsError::SuspensionInvalid));
    // NaN on an invalid wheel is ignored.
    odo.start(&reading(0, [0.0; 6], [0.0; 6])).unwrap();
    let mut r = reading(10_000, [0.1; 6], [0.0; 6]);
    r.wheel_valid[4] = false;
    r.drive_angle_rad[4] = f64::NAN;
    odo.update(&r).unwrap();
    assert!((odo.relative_pose().unwrap().trans_0_1_m.x - 0.01).abs() < 1e-12);
}

/// KIN-8: planar model (H04 Fig. 17 comparison): equal to the full model on level ground; over
/// a bogie excursion (front wheel lifted over a bump and back) the planar model counts the
/// wheel's travel over the bump as forward motion while the full model does not.
#[test]
fn kin_8_planar_model_vs_full() {
    let s = level();
    let ik = inverse_kinematics(&ROCKY8, &s, &cmd(0.1, 0.02, 0.1)).unwrap();
    let planar = planar_body_rates(
        &ROCKY8,
        &ik.command.wheel_rate_rad_s,
        &ik.command.steer_angle_rad,
        &[true; 6],
    )
    .unwrap();
    assert!((planar - ik.body_rates).norm() < 1e-12);
    // Rover standing still while the right bogie swings (rho_1 from 0 to 0.4 rad): the front
    // and middle wheels roll to follow the contacts on the ground (rolling along x_C).
    let mut state = level();
    let mut full_x: f64 = 0.0;
    let mut planar_x: f64 = 0.0;
    let n = 100;
    for k in 0..n {
        let rho = 0.4 * (k as f64 + 0.5) / n as f64;
        state.bogie_rad = [rho, 0.0];
        let rates = SuspensionRates {
            rocker_rad_s: 0.0,
            bogie_rad_s: [0.4 / n as f64, 0.0],
        };
        let jac = jacobian::wheel_jacobians(&ROCKY8, &state).unwrap();
        // Zero body motion: each wheel's drive absorbs the along-track part of its contact's
        // motion relative to the body (dp/drho . x_C / r).
        let drive: [f64; 6] = core::array::from_fn(|i| {
            let b = jac[i].bogie
                * if jac[i].bogie_index == Some(0) {
                    1.0
                } else {
                    0.0
                };
            -b.dot(&jac[i].drive) / jac[i].drive.norm_squared() * rates.bogie_rad_s[0]
        });
        let full = forward_kinematics(&ROCKY8, &state, &rates, &drive, &[true; 6]).unwrap();
        let flat = planar_body_rates(&ROCKY8, &drive, &[0.0; 6], &[true; 6]).unwrap();
        full_x += full.body_rates[0];
        planar_x += flat[0];
    }
    assert!(planar_x.abs() > 1e-3, "planar {planar_x}");
    assert!(
        full_x.abs() < 0.5 * planar_x.abs(),
        "full {full_x} planar {planar_x}"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    /// KIN-9: arbitrary inputs (NaN, infinities, huge values) never panic; every function
    /// returns a value or an error, and an Ok result is finite.
    #[test]
    fn kin_9_arbitrary_inputs_never_panic(
        angles in proptest::array::uniform9(proptest::num::f64::ANY),
        rates in proptest::array::uniform9(proptest::num::f64::ANY),
        valid in proptest::array::uniform6(any::<bool>()),
        c in proptest::array::uniform3(proptest::num::f64::ANY),
    ) {
        let s = SuspensionState {
            rocker_rad: angles[0],
            bogie_rad: [angles[1], angles[2]],
            steer_rad: [angles[3], angles[4], angles[5], angles[6], angles[7], angles[8]],
        };
        let contacts = wheel_contact_points(&ROCKY8, &s);
        let angles_bad = angles.iter().any(|a| !a.is_finite());
        if angles_bad {
            prop_assert_eq!(contacts, Err(KinematicsError::NonFinite));
        }
        let sr = SuspensionRates { rocker_rad_s: rates[0], bogie_rad_s: [rates[1], rates[2]] };
        let drive = [rates[3], rates[4], rates[5], rates[6], rates[7], rates[8]];
        let fk = forward_kinematics(&ROCKY8, &s, &sr, &drive, &valid);
        if let Ok(fk) = fk {
            prop_assert!(fk.body_rates.iter().all(|x| x.is_finite()));
        }
        let valid_drive_bad = drive.iter().zip(valid.iter()).any(|(d, ok)| *ok && !d.is_finite());
        if valid_drive_bad || rates[..3].iter().any(|r| !r.is_finite()) {
            prop_assert!(fk.is_err());
        }
        let command = cmd(c[0], c[1], c[2]);
        let ik = inverse_kinematics(&ROCKY8, &s, &command);
        if angles_bad || c.iter().any(|x| !x.is_finite()) {
            prop_assert!(ik.is_err());
        }
        if let Ok(ik) = ik {
            prop_assert!(ik.command.wheel_rate_rad_s.iter().all(|x| x.is_finite()));
            prop_assert!(ik.command.steer_angle_rad.iter().all(|x| x.abs() <= ROCKY8.limits.steer_rad));
        }
        let _ = max_speed_scale(&ROCKY8, &s, &command, c[0]);
        let _ = planar_body_rates(&ROCKY8, &drive, &s.steer_rad, &valid);
        let mut odo = KinematicOdometry::new(ROCKY8, OdometryConfig::default());
        let mut j = JointState {
            t_us: 1,
            drive_angle_rad: drive,
            drive_rate_rad_s: drive,
            steer_angle_rad: s.steer_rad,
            rocker_rad: s.rocker_rad,
            bogie_rad: s.bogie_rad,
            wheel_valid: valid,
            suspension_valid: true,
        };
        let _ = odo.start(&JointState { wheel_valid: valid, ..Default::default() });
        let _ = odo.update(&j);
        j.t_us = 2;
        let _ = odo.update(&j);
        if let Ok(p) = odo.relative_pose() {
            prop_assert!(p.trans_0_1_m.iter().all(|x| x.is_finite()));
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]
    /// KIN-9: in-range angles and any finite command up to 10 m/s: inverse kinematics succeeds
    /// or reports the wheel-rate limit, and then succeeds after `max_speed_scale`.
    #[test]
    fn kin_9_in_range_inputs_always_answer(
        rocker in -0.6..0.6f64,
        bogie in proptest::array::uniform2(-1.0..1.0f64),
        steer in proptest::array::uniform6(-1.75..1.75f64),
        c in proptest::array::uniform3(-10.0..10.0f64),
    ) {
        let s = SuspensionState { rocker_rad: rocker, bogie_rad: bogie, steer_rad: steer };
        let command = cmd(c[0], c[1], c[2]);
        match inverse_kinematics(&ROCKY8, &s, &command) {
            Ok(ik) => prop_assert!(ik.command.wheel_rate_rad_s.iter().all(|r| r.abs() <= 2.0 + 1e-6)),
            Err(KinematicsError::WheelRateLimit { .. }) => {
                let k = max_speed_scale(&ROCKY8, &s, &command, 2.0).unwrap();
                let scaled = cmd(c[0] * k, c[1] * k, c[2] * k);
                prop_assert!(inverse_kinematics(&ROCKY8, &s, &scaled).is_ok());
            }
            Err(e) => prop_assert!(false, "unexpected {:?}", e),
        }
        let fk = forward_kinematics(&ROCKY8, &s, &SuspensionRates::default(), &[1.0; 6], &[true; 6]);
        prop_assert!(fk.is_ok());
    }
}

/// KIN-3: forward kinematics from a HAL joint reading uses its drive rates, angles and validity
/// flags and refuses a reading whose suspension encoders are invalid.
#[test]
fn kin_3_forward_kinematics_from_joint_reading() {
    let mut j = reading(0, [0.0; 6], [0.0; 6]);
    j.drive_rate_rad_s = [1.0; 6];
    j.wheel_valid[0] = false;
    j.drive_rate_rad_s[0] = f64::NAN;
    let none = SuspensionRates::default();
    let sol = forward_kinematics_from_joints(&ROCKY8, &j, &none).unwrap();
    assert_eq!(sol.valid_wheels, 5);
    assert!((sol.body_rates[0] - 0.1).abs() < 1e-12);
    j.suspension_valid = false;
    assert_eq!(
        forward_kinematics_from_joints(&ROCKY8, &j, &none),
        Err(KinematicsError::SuspensionInvalid)
    );
}

/// KIN-8: the planar pose increment integrates a straight step and a turn in place along the
/// arc (hand values: 0.1 rad of drive at r = 0.1 m is 1 cm; the IK turn-in-place rates for
/// 0.5 rad of yaw give dyaw = 0.5 and no translation).
#[test]
fn kin_8_planar_pose_increment() {
    let a = reading(0, [0.0; 6], [0.0; 6]);
    let b = reading(1, [0.1; 6], [0.0; 6]);
    let d = planar_pose_increment(&ROCKY8, &a, &b).unwrap();
    assert!((d[0] - 0.01).abs() < 1e-12 && d[1].abs() < 1e-12 && d[2].abs() < 1e-12);
    let ik = inverse_kinematics(&ROCKY8, &level(), &cmd(0.0, 0.0, 0.1)).unwrap();
    let steer = ik.command.steer_angle_rad;
    let drive = ik.command.wheel_rate_rad_s.map(|r| r * 5.0);
    let d = planar_pose_increment(
        &ROCKY8,
        &reading(0, [0.0; 6], steer),
        &reading(1, drive, steer),
    )
    .unwrap();
    assert!((d[2] - 0.5).abs() < 1e-9 && d[0].abs() < 1e-9 && d[1].abs() < 1e-9);
    // Arc: constant body rates (0.1, 0, 0.1) for 1 s -> chord (sin 0.1, 1 - cos 0.1).
    let ik = inverse_kinematics(&ROCKY8, &level(), &cmd(0.1, 0.0, 0.1)).unwrap();
    let steer = ik.command.steer_angle_rad;
    let d = planar_pose_increment(
        &ROCKY8,
        &reading(0, [0.0; 6], steer),
        &reading(1, ik.command.wheel_rate_rad_s, steer),
    )
    .unwrap();
    assert!((d[0] - libm::sin(0.1)).abs() < 1e-9);
    assert!((d[1] - (1.0 - libm::cos(0.1))).abs() < 1e-9);
}
