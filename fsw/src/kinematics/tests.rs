//! Unit tests of the kinematics module (requirement ids KIN-n in `docs/requirements.md`).

#![allow(clippy::needless_range_loop)]

use super::geometry::*;
use super::*;
use crate::types::Vec3;

pub(crate) fn level() -> SuspensionState {
    SuspensionState::default()
}

/// KIN-1: the D-H reading puts every contact point where the geometry says: below its axle by
/// the wheel radius, on flat ground at beta = rho = 0, left/right mirror images, wheel order
/// as in Table 2, with a plausible wheelbase and track.
#[test]
fn kin_1_contact_points_rocky8_level() {
    let frames = wheel_frames(&ROCKY8, &level()).unwrap();
    let p = frames.map(|f| f.contact_point_m);
    for (i, f) in frames.iter().enumerate() {
        // Axle (contact frame origin) at z ~ 0, contact r below it (z down).
        assert!(
            f.contact.pos.z.abs() < 1e-3,
            "axle {i} z {}",
            f.contact.pos.z
        );
        let below = f.contact_point_m - f.contact.pos;
        assert!(
            (below - Vec3::new(0.0, 0.0, WHEEL_RADIUS_M)).norm() < 1e-3,
            "{i} {below}"
        );
        // Level rover: steering axis straight down, rolling direction forward.
        assert!(
            (f.steer_axis - Vec3::z()).norm() < 1e-3,
            "{i} {}",
            f.steer_axis
        );
        assert!(
            (f.rolling_dir - Vec3::x()).norm() < 1e-3,
            "{i} {}",
            f.rolling_dir
        );
    }
    // All six contacts on one plane z = r.
    for q in &p {
        assert!((q.z - WHEEL_RADIUS_M).abs() < 1e-3);
    }
    // Right wheels (1, 3, 5) at +y, left (2, 4, 6) at -y, mirror images.
    for k in 0..3 {
        let (r, l) = (p[2 * k], p[2 * k + 1]);
        assert!(r.y > 0.2 && l.y < -0.2);
        assert!((r - Vec3::new(l.x, -l.y, l.z)).norm() < 1e-12);
    }
    // Front, middle, rear order along x.
    assert!(p[0].x > p[2].x && p[2].x > p[4].x);
    let wheelbase = p[0].x - p[4].x;
    let track = p[0].y - p[1].y;
    assert!((0.6..0.9).contains(&wheelbase), "wheelbase {wheelbase}");
    assert!((0.5..0.8).contains(&track), "track {track}");
    // Figures from Table 2 by hand: front 0.3932 m, middle ~0, rear -0.3541 m, track 0.6222 m.
    assert!((p[0].x - (-0.1420 + 0.2812 * libm::cos(0.2698) + 0.2644)).abs() < 1e-9);
    assert!((p[4].x - (-0.1420 - 0.2121)).abs() < 1e-9);
    assert!((track - 0.6222).abs() < 1e-9);
}

/// KIN-1: joint signs. Raising the rocker (beta > 0) pitches the right rocker nose down
/// (front-right contact moves down, rear-right up) and the left side the other way; a
/// positive bogie angle moves the front wheel of that bogie down and the middle wheel up;
/// positive steering turns the rolling direction to the right. Steering never moves the
/// contact point (it lies on the steering axis).
#[test]
fn kin_1_joint_signs_and_symmetry() {
    let base = wheel_contact_points(&ROCKY8, &level()).unwrap();
    let mut s = level();
    s.rocker_rad = 0.1;
    let p = wheel_contact_points(&ROCKY8, &s).unwrap();
    // Rotation about +y_R (right-hand): a point ahead of the pivot moves to -z (up).
    assert!(p[0].z < base[0].z && p[4].z > base[4].z);
    assert!(p[1].z > base[1].z && p[5].z < base[5].z);
    let mut s = level();
    s.bogie_rad = [0.1, 0.1];
    let p = wheel_contact_points(&ROCKY8, &s).unwrap();
    assert!(p[0].z < base[0].z && p[2].z > base[2].z);
    assert!((p[0] - Vec3::new(p[1].x, -p[1].y, p[1].z)).norm() < 1e-12);
    assert!((p[4] - base[4]).norm() < 1e-12);
    let mut s = level();
    s.steer_rad = [0.3; 6];
    let f = wheel_frames(&ROCKY8, &s).unwrap();
    for (i, w) in f.iter().enumerate() {
        assert!((w.contact_point_m - base[i]).norm() < 1e-12);
        assert!(w.rolling_dir.y > 0.29 && (w.rolling_dir.y - libm::sin(0.3)).abs() < 1e-3);
    }
}

/// KIN-1: out-of-range and non-finite angles are refused.
#[test]
fn kin_1_bad_angles_refused() {
    let mut s = level();
    s.rocker_rad = f64::NAN;
    assert_eq!(
        wheel_contact_points(&ROCKY8, &s),
        Err(KinematicsError::NonFinite)
    );
    let mut s = level();
    s.bogie_rad[1] = 2.0;
    assert_eq!(
        wheel_contact_points(&ROCKY8, &s),
        Err(KinematicsError::JointOutOfRange)
    );
    let mut s = level();
    s.steer_rad[3] = f64::INFINITY;
    assert_eq!(
        wheel_contact_points(&ROCKY8, &s),
        Err(KinematicsError::NonFinite)
    );
}

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub(crate) fn random_state(rng: &mut ChaCha8Rng) -> SuspensionState {
    SuspensionState {
        rocker_rad: rng.random_range(-0.4..0.4),
        bogie_rad: [rng.random_range(-0.6..0.6), rng.random_range(-0.6..0.6)],
        steer_rad: core::array::from_fn(|_| rng.random_range(-1.5..1.5)),
    }
}

/// KIN-2: the wheel Jacobian columns (eq. 13-14) agree with central finite differences of the
/// eq. 12 transforms to 1e-6, over random suspension states.
#[test]
fn kin_2_jacobians_match_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let h = 1e-6;
    let mut worst: f64 = 0.0;
    for _ in 0..200 {
        let s = random_state(&mut rng);
        let jac = jacobian::wheel_jacobians(&ROCKY8, &s).unwrap();
        let frames = wheel_frames(&ROCKY8, &s).unwrap();
        for i in 0..6 {
            // Rocker column: -dp/dbeta.
            let (mut sp, mut sm) = (s, s);
            sp.rocker_rad += h;
            sm.rocker_rad -= h;
            let fd = (wheel_contact_points(&ROCKY8, &sp).unwrap()[i]
                - wheel_contact_points(&ROCKY8, &sm).unwrap()[i])
                / (2.0 * h);
            worst = worst.max((jac[i].rocker + fd).norm());
            // Bogie column of the wheel's own bogie; the other bogie does not move it.
            for k in 0..2 {
                let (mut sp, mut sm) = (s, s);
                sp.bogie_rad[k] += h;
                sm.bogie_rad[k] -= h;
                let fd = (wheel_contact_points(&ROCKY8, &sp).unwrap()[i]
                    - wheel_contact_points(&ROCKY8, &sm).unwrap()[i])
                    / (2.0 * h);
                let expect = if jac[i].bogie_index == Some(k) {
                    jac[i].bogie
                } else {
                    Vec3::zeros()
                };
                worst = worst.max((expect + fd).norm());
            }
            // Steering: the rolling direction turns about the steering axis.
            let (mut sp, mut sm) = (s, s);
            sp.steer_rad[i] += h;
            sm.steer_rad[i] -= h;
            let fd = (wheel_frames(&ROCKY8, &sp).unwrap()[i].rolling_dir
                - wheel_frames(&ROCKY8, &sm).unwrap()[i].rolling_dir)
                / (2.0 * h);
            let analytic = frames[i].steer_axis.cross(&frames[i].rolling_dir);
            worst = worst.max((analytic - fd).norm());
            // Drive column is r times the unit rolling direction, normal to the steering axis.
            assert!((jac[i].drive.norm() - WHEEL_RADIUS_M).abs() < 1e-12);
            assert!(jac[i].drive.dot(&frames[i].steer_axis).abs() < 1e-12);
        }
    }
    assert!(worst < 1e-6, "worst Jacobian error {worst}");
}

/// Body rates that a rigid motion plus suspension rates imply at each contact (test oracle):
/// the drive rates that make eq. 14 hold exactly when the steering points along the motion.
fn consistent_drive(
    s: &SuspensionState,
    t: &BodyRates,
    rates: &SuspensionRates,
) -> Option<[f64; 6]> {
    let jac = jacobian::wheel_jacobians(&ROCKY8, s).unwrap();
    let v = Vec3::new(t[0], t[1], t[2]);
    let w = Vec3::new(t[3], t[4], t[5]);
    let mut drive = [0.0; 6];
    for i in 0..6 {
        let bogie = match jac[i].bogie_index {
            Some(k) => rates.bogie_rad_s[k],
            None => 0.0,
        };
        let need = v + w.cross(&jac[i].contact_point_m)
            - jac[i].rocker * rates.rocker_rad_s
            - jac[i].bogie * bogie;
        // Must lie along the rolling direction.
        let along = need.dot(&jac[i].drive) / jac[i].drive.norm_squared();
        if (need - jac[i].drive * along).norm() > 1e-9 {
            return None;
        }
        drive[i] = along;
    }
    Some(drive)
}

/// KIN-3: forward kinematics (eq. 15) recovers a straight drive and a turn in place exactly on
/// level ground, drops invalid wheels, refuses fewer than three valid wheels, and reports the
/// misfit of inconsistent (slipping) wheels.
#[test]
fn kin_3_forward_kinematics_cases_and_masks() {
    let s = level();
    let none = SuspensionRates::default();
    // Straight: all wheels 1 rad/s -> 0.1 m/s forward.
    let sol = forward_kinematics(&ROCKY8, &s, &none, &[1.0; 6], &[true; 6]).unwrap();
    let expect = BodyRates::new(0.1, 0.0, 0.0, 0.0, 0.0, 0.0);
    assert!(
        (sol.body_rates - expect).norm() < 1e-12,
        "{}",
        sol.body_rates
    );
    assert!(sol.residual_rms_m_s < 1e-12);
    assert_eq!(sol.observed, [true; 6]);
    // Yaw at 0.2 rad/s about the origin, steering tangent: built from the oracle.
    let t = BodyRates::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.2);
    let mut st = s;
    let p = wheel_contact_points(&ROCKY8, &s).unwrap();
    for i in 0..6 {
        st.steer_rad[i] = libm::atan2(p[i].x, -p[i].y);
        if st.steer_rad[i].abs() > 1.6 {
            st.steer_rad[i] -= core::f64::consts::PI * st.steer_rad[i].signum();
        }
    }
    let drive = consistent_drive(&st, &t, &none).unwrap();
    let sol = forward_kinematics(&ROCKY8, &st, &none, &drive, &[true; 6]).unwrap();
    assert!((sol.body_rates - t).norm() < 1e-12);
    // Invalid wheel with a garbage rate: dropped, same answer.
    let mut bad = drive;
    bad[3] = f64::NAN;
    let mut valid = [true; 6];
    valid[3] = false;
    let sol = forward_kinematics(&ROCKY8, &st, &none, &bad, &valid).unwrap();
    assert_eq!(sol.valid_wheels, 5);
    assert!((sol.body_rates - t).norm() < 1e-12);
    // Two valid wheels: unobservable.
    let valid = [true, true, false, false, false, false];
    assert_eq!(
        forward_kinematics(&ROCKY8, &st, &none, &drive, &valid),
        Err(KinematicsError::Unobservable { valid_wheels: 2 })
    );
    // A slipping wheel (spinning twice as fast) shows in the residual.
    let mut slip = [1.0; 6];
    slip[0] = 2.0;
    let sol = forward_kinematics(&ROCKY8, &s, &none, &slip, &[true; 6]).unwrap();
    assert!(sol.residual_rms_m_s > 0.01);
}

/// KIN-3: over random suspension states, suspension rates and rigid body rates, forward
/// kinematics returns the body rates that generated the joint rates (1e-9), including the
/// unactuated z, roll and pitch.
#[test]
fn kin_3_forward_kinematics_recovers_rigid_motion() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut worst: f64 = 0.0;
    let mut tested = 0;
    for _ in 0..300 {
        let s0 = random_state(&mut rng);
        let cmd = VehicleCommand {
            x_dot_m_s: rng.random_range(-0.1..0.1),
            y_dot_m_s: rng.random_range(-0.1..0.1),
            yaw_rate_rad_s: rng.random_range(-0.3..0.3),
        };
        // IK supplies steering and unactuated rates (z, roll, pitch, suspension) consistent
        // with the contacts; the drive rates come from the independent oracle above.
        let k = inverse::max_speed_scale(&ROCKY8, &s0, &cmd, 1.9)
            .unwrap()
            .min(1.0);
        let cmd = VehicleCommand {
            x_dot_m_s: cmd.x_dot_m_s * k,
            y_dot_m_s: cmd.y_dot_m_s * k,
            yaw_rate_rad_s: cmd.yaw_rate_rad_s * k,
        };
        let ik = inverse::inverse_kinematics(&ROCKY8, &s0, &cmd).unwrap();
        let mut s = s0;
        s.steer_rad = ik.command.steer_angle_rad;
        let t = ik.body_rates;
        let Some(drive) = consistent_drive(&s, &t, &ik.suspension_rates) else {
            panic!("oracle failed");
        };
        let sol =
            forward_kinematics(&ROCKY8, &s, &ik.suspension_rates, &drive, &[true; 6]).unwrap();
        worst = worst.max((sol.body_rates - t).norm());
        tested += 1;
    }
    assert!(tested > 250);
    assert!(worst < 1e-9, "worst {worst}");
}
