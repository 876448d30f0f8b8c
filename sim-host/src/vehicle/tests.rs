//! Placement tests on hand-computed cases (SIM-3).

use super::geometry::{rocky8, VehicleGeometry};
use super::placement::{place, BodyPose, JointLimits, Suspension};
use crate::surface::TerrainSurface;
use crate::terrain::{BaseShape, Terrain, TerrainSpec};

/// A terrain of `base` alone (no roughness, rocks or obstacles).
pub(crate) fn terrain(base: BaseShape) -> Terrain {
    Terrain::new(
        TerrainSpec {
            base,
            roughness_m: 0.0,
            roughness_wavelength_m: 2.0,
            rocks: None,
            obstacles: Vec::new(),
        },
        0,
        &[],
    )
}

fn start(z: f64) -> BodyPose {
    BodyPose {
        pos_m: [0.0, 0.0, z],
        ..BodyPose::default()
    }
}

/// SIM-3: on flat ground every joint angle is zero, the body is level at one wheel radius
/// above the ground (the axles are at `z_R = 0`), and all six wheels touch.
#[test]
fn sim_3_flat_ground() {
    let g = rocky8();
    let t = terrain(BaseShape::Flat);
    let p = place(
        &g,
        &t,
        &start(-0.2),
        &Suspension::default(),
        &[0.0; 6],
        &JointLimits::rocky8(),
    );
    for c in p.clearance_m {
        assert!(c.abs() < 1e-9);
    }
    assert!(
        (p.pose.pos_m[2] + g.wheel_radius_m(0)).abs() < 2e-4,
        "{:?}",
        p.pose
    );
    assert!(p.pose.roll_rad.abs() < 1e-4 && p.pose.pitch_rad.abs() < 1e-3);
    assert!(p.suspension.rocker_rad.abs() < 1e-3);
}

/// SIM-3: a step of height `H` under both front wheels. Hand computation in the side plane
/// (x forward, z up), with H04 Table 2 lengths: the bogie pitch is `phi = asin(H / 0.3929)`
/// (front and middle axles 0.2644 + 0.1285 m apart at equal depth); the bogie pivot sits
/// `0.1285 sin(phi) + 0.1273 cos(phi)` above the middle axle; the rocker pitch `theta` solves
/// `0.48316 sin(theta) + 0.12726 cos(theta) = pivot height above rear axle`; then body pitch =
/// `theta`, rocker `beta = 0`, both bogies `rho = phi - theta`, roll 0.
#[test]
fn sim_3_step_under_both_front_wheels() {
    let height = 0.08;
    let g = rocky8();
    let t = terrain(BaseShape::Step {
        x_m: 0.2,
        height_m: height,
        right_only: false,
    });
    let p = place(
        &g,
        &t,
        &start(-0.1),
        &Suspension::default(),
        &[0.0; 6],
        &JointLimits::rocky8(),
    );
    for (i, c) in p.clearance_m.iter().enumerate() {
        assert!(c.abs() < 1e-8, "wheel {} clearance {c}", i + 1);
    }
    for (i, k) in p.contacts.iter().enumerate() {
        let c = k.point_w;
        let expected = if i < 2 { height } else { 0.0 };
        assert!(
            (-c[2] - expected).abs() < 1e-8,
            "wheel {} touches its ground",
            i + 1
        );
        assert!((t.height_m(c[0], c[1]) - expected).abs() < 1e-12);
    }
    let phi = (height / (0.2644 + 0.1285f64)).asin();
    let rise = 0.1285 * phi.sin() + 0.1273 * phi.cos() - 0.1273;
    // Pivot height above the rear axle: rise + (0.12726 at theta = 0 offset) - handled below.
    let (a, b) = (
        0.2812 * 0.2698f64.cos() + 0.2121,
        -0.2812 * 0.2698f64.sin() + 0.2022,
    );
    let c = rise + 0.1273;
    let theta = (c / (a * a + b * b).sqrt()).asin() - b.atan2(a);
    let rho = phi - theta;
    let tol = 5e-4; // the tabulated -2.872 rad is pi to 2e-4 rad
    assert!(
        (p.pose.pitch_rad - theta).abs() < tol,
        "pitch {} vs {theta}",
        p.pose.pitch_rad
    );
    assert!(p.suspension.rocker_rad.abs() < 1e-6);
    assert!(p.pose.roll_rad.abs() < 1e-6);
    assert!(
        (p.suspension.bogie_rad[0] - rho).abs() < tol,
        "{:?} vs {rho}",
        p.suspension
    );
    assert!((p.suspension.bogie_rad[1] - rho).abs() < tol);
}

/// SIM-3: a step under the right front wheel only: every wheel touches, the differential
/// splits the right rocker's pitch between body pitch and rocker (`pitch = beta` because the
/// left rocker stays level), the right bogie tilts by about the symmetric case's angle, and the
/// body rolls towards the left (the right rocker pivot is lifted).
#[test]
fn sim_3_step_under_right_front_wheel() {
    let height = 0.08;
    let g = rocky8();
    let t = terrain(BaseShape::Step {
        x_m: 0.2,
        height_m: height,
        right_only: true,
    });
    let p = place(
        &g,
        &t,
        &start(-0.1),
        &Suspension::default(),
        &[0.0; 6],
        &JointLimits::rocky8(),
    );
    for c in p.clearance_m {
        assert!(c.abs() < 1e-8);
    }
    let (pitch, beta) = (p.pose.pitch_rad, p.suspension.rocker_rad);
    assert!(pitch > 0.0 && (pitch - beta).abs() < 2e-3, "{pitch} {beta}");
    assert!(p.pose.roll_rad < 0.0);
    // Left side is flat: left rocker (pitch - beta) and bogie level.
    assert!(p.suspension.bogie_rad[1].abs() < 2e-3);
    let phi = (height / 0.3929f64).asin();
    assert!((p.suspension.bogie_rad[0] + pitch + beta - phi).abs() < 5e-3);
}

/// SIM-3: on a 15 deg cross slope the body rolls by the slope and the joints stay at zero.
#[test]
fn sim_3_planar_slope() {
    let g = rocky8();
    let t = terrain(BaseShape::Plane {
        slope_deg: 15.0,
        downhill_azimuth_deg: 90.0,
    });
    let p = place(
        &g,
        &t,
        &start(-0.1),
        &Suspension::default(),
        &[0.0; 6],
        &JointLimits::rocky8(),
    );
    for c in p.clearance_m {
        assert!(c.abs() < 1e-8);
    }
    assert!(
        (p.pose.roll_rad - 15f64.to_radians()).abs() < 1e-3,
        "{}",
        p.pose.roll_rad
    );
    assert!(p.suspension.rocker_rad.abs() < 1e-3);
    let _ = g.wheel_radius_m(0);
}

/// SIM-3: at a mechanical stop the joint is held at its limit, no wheel penetrates the ground,
/// and the wheels that cannot follow lift off (here a 0.2 m step under the right front wheel
/// with +-0.05 rad stops).
#[test]
fn sim_3_joint_stops_hold_and_wheels_lift() {
    let g = rocky8();
    let t = terrain(BaseShape::Step {
        x_m: 0.2,
        height_m: 0.2,
        right_only: true,
    });
    let limits = JointLimits {
        rocker_rad: 0.05,
        bogie_rad: 0.05,
    };
    let p = place(
        &g,
        &t,
        &start(-0.1),
        &Suspension::default(),
        &[0.0; 6],
        &limits,
    );
    assert!(p.at_limit);
    assert!(p.suspension.rocker_rad.abs() <= 0.05 + 1e-12);
    assert!(p
        .suspension
        .bogie_rad
        .iter()
        .all(|b| b.abs() <= 0.05 + 1e-12));
    assert!(
        p.clearance_m.iter().all(|c| *c > -1e-6),
        "{:?}",
        p.clearance_m
    );
    let touching = p.clearance_m.iter().filter(|c| c.abs() < 1e-3).count();
    let lifted = p.clearance_m.iter().filter(|c| **c > 1e-3).count();
    assert!(touching >= 1 && lifted >= 1, "{:?}", p.clearance_m);
}
