//! Tests of the world: per-wheel radii, scrub.

use super::*;
use crate::vehicle::geometry::VehicleGeometry;
use std::path::Path;

/// `flat-firm` without slip, with the given 1-sigma dimension and per-wheel radius errors.
fn flat(dimension_error_m: f64, wheel_radius_error_m: f64) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/flat-firm.toml");
    let mut s = Scenario::load(&path).unwrap();
    s.slip = false;
    s.sensors.dimension_error_m = dimension_error_m;
    s.sensors.wheel_radius_error_m = wheel_radius_error_m;
    s
}

/// Drive the truth vehicle with wheel radii `radii` (published dimensions otherwise) on flat
/// ground, all six wheels straight at 1 rad/s for 2 s after 1.5 s of spin-up (the motor's rate limit and lag): distance
/// travelled and yaw change over the 2 s.
fn drive(radii: [f64; WHEELS]) -> (f64, f64) {
    let mut w = World::new(&flat(0.0, 0.0), 1).unwrap();
    w.geometry.wheel_radius_m = radii;
    w.command.wheel_rate_rad_s = [1.0; WHEELS];
    for _ in 0..300 {
        w.step();
    }
    let (d0, yaw0) = (w.truth.distance_m, w.truth.pose.yaw_rad);
    for _ in 0..400 {
        w.step();
    }
    (
        w.truth.distance_m - d0,
        wrap_pi(w.truth.pose.yaw_rad - yaw0),
    )
}

/// SIM-18: without dimension and wheel-radius errors all six radii are the published
/// 0.10 m; the per-wheel errors make them differ, from their own stream (the other
/// dimensions are the same draws with and without them).
#[test]
fn sim_18_wheel_radii_per_seed() {
    let exact = World::new(&flat(0.0, 0.0), 3).unwrap();
    assert_eq!(exact.geometry.wheel_radius_m, [0.10; WHEELS]);
    let common = World::new(&flat(0.002, 0.0), 3).unwrap().geometry;
    let own = World::new(&flat(0.002, 0.0005), 3).unwrap().geometry;
    assert_eq!(own.axle_m, common.axle_m);
    assert_eq!(own.rocker_pivot_m, common.rocker_pivot_m);
    assert_eq!(own.bogie_pivot_m, common.bogie_pivot_m);
    assert!(common
        .wheel_radius_m
        .iter()
        .all(|r| *r == common.wheel_radius_m[0]));
    let spread = own.wheel_radius_m.iter().fold(0.0f64, |m, r| m.max(*r))
        - own.wheel_radius_m.iter().fold(1.0f64, |m, r| m.min(*r));
    assert!(spread > 1e-5 && spread < 0.005, "{:?}", own.wheel_radius_m);
    for i in 0..WHEELS {
        assert!((own.wheel_radius_m(i) - common.wheel_radius_m(i)).abs() < 0.0025);
    }
}

/// SIM-18: on flat ground without slip a larger wheel advances more per rotation (radii
/// 1 % larger: 1 % more distance), and with the right wheels (1, 3, 5) 1 mm larger than the
/// left ones the rover yaws towards the smaller (left) side at the rate of the rolling
/// solve's least squares on level ground, `w_z = -sum(y_i r_i theta_dot) / (sum(y_i^2) +
/// sum((x_i - mean x)^2))` (tangent rows `v_x - y_i w_z = r_i theta_dot`, lateral rows
/// `v_y + x_i w_z = 0`).
#[test]
fn sim_18_larger_wheel_advances_more() {
    let (d_nominal, yaw_nominal) = drive([0.10; WHEELS]);
    let (d_large, _) = drive([0.101; WHEELS]);
    assert!((d_nominal - 0.2).abs() < 2e-3, "{d_nominal}");
    assert!(yaw_nominal.abs() < 1e-6, "{yaw_nominal}");
    assert!(
        (d_large / d_nominal - 1.01).abs() < 1e-3,
        "{d_large} / {d_nominal}"
    );
    let right_larger: [f64; WHEELS] =
        std::array::from_fn(|i| if i % 2 == 0 { 0.101 } else { 0.100 });
    let (_, yaw) = drive(right_larger);
    let g = rocky8();
    let mean_x = g.axle_m.iter().map(|a| a.x).sum::<f64>() / WHEELS as f64;
    let den: f64 = g
        .axle_m
        .iter()
        .map(|a| a.y * a.y + (a.x - mean_x).powi(2))
        .sum();
    let num: f64 = (0..WHEELS).map(|i| g.axle_m[i].y * right_larger[i]).sum();
    let expected = -num / den * 2.0;
    assert!(yaw < 0.0, "turns left (towards the smaller wheels): {yaw}");
    assert!(
        (yaw - expected).abs() < 0.01 * expected.abs(),
        "{yaw} vs {expected}"
    );
}

/// SIM-31: the truth's scrub diagnostic. Six equal wheel rates on flat ground without slip
/// roll without sliding (scrub below 0.2 % of the driven travel); one wheel driven 30 %
/// faster than the other five cannot roll with them: whatever the body does, the six
/// contacts together slide at least `0.3 r theta_dot` per `6.3 r theta_dot` of drive, 4.8 %.
#[test]
fn sim_31_scrub_of_mismatched_wheel_rates() {
    let scrub = |rates: [f64; WHEELS]| {
        let mut w = World::new(&flat(0.0, 0.0), 1).unwrap();
        w.command.wheel_rate_rad_s = rates;
        for _ in 0..300 {
            w.step();
        }
        let (s0, n0, d0) = (w.scrub_m, w.scrub_net_m, w.driven_m);
        for _ in 0..400 {
            w.step();
        }
        let driven = w.driven_m - d0;
        assert!((driven - 6.0 * 0.2).abs() < 0.3, "{driven}");
        (
            100.0 * (w.scrub_m - s0) / driven,
            100.0 * (w.scrub_net_m - n0) / driven,
        )
    };
    let (equal, equal_net) = scrub([1.0; WHEELS]);
    assert!(equal < 0.2 && equal_net.abs() < 0.2, "{equal} {equal_net}");
    let mut one_fast = [1.0; WHEELS];
    one_fast[2] = 1.3;
    let (fast, fast_net) = scrub(one_fast);
    assert!((4.5..15.0).contains(&fast), "{fast}");
    assert!(fast_net.abs() <= fast, "{fast_net}");
}
