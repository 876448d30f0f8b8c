//! Unit tests of the kinematics module (requirement ids KIN-n in `docs/requirements.md`).

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
