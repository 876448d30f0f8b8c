//! Guidance unit tests (GNC-1 .. GNC-6, docs/requirements.md).

use super::control::{crab_loop, heading_loop, limit_forward_speed};
use super::*;
use proptest::prelude::*;

/// Rocky 8-like wheel contact points (x forward, y right), m.
const WHEELS: [[f64; 2]; 6] = [
    [0.5, 0.4],
    [0.5, -0.4],
    [0.0, 0.4],
    [0.0, -0.4],
    [-0.5, 0.4],
    [-0.5, -0.4],
];

fn straight_north(length: f64) -> Path<8> {
    Path::new(&[[0.0, 0.0], [length, 0.0]]).expect("valid path")
}

/// GNC-1: bad paths are refused with an error value.
#[test]
fn gnc_1_bad_paths_refused() {
    assert_eq!(Path::<4>::new(&[]).err(), Some(PathError::TooFewWaypoints));
    assert_eq!(
        Path::<4>::new(&[[0.0, 0.0]]).err(),
        Some(PathError::TooFewWaypoints)
    );
    assert_eq!(
        Path::<2>::new(&[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]).err(),
        Some(PathError::TooManyWaypoints)
    );
    assert_eq!(
        Path::<4>::new(&[[0.0, 0.0], [f64::NAN, 0.0]]).err(),
        Some(PathError::NonFinite(1))
    );
    assert_eq!(
        Path::<4>::new(&[[0.0, 0.0], [1.0, 0.0], [1.0, 0.0]]).err(),
        Some(PathError::RepeatedWaypoint(2))
    );
    let p = Path::<4>::new(&[[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]]).expect("valid");
    assert_eq!(p.length_m(), 7.0);
    assert_eq!(p.goal(), [3.0, 4.0]);
}

/// GNC-2: carrot heading, eq. 47, against a hand calculation; the radius grows when the
/// circle misses the path; the goal is the carrot once inside the circle.
#[test]
fn gnc_2_carrot_hand_calculation() {
    let path = straight_north(5.0);
    // Rover 0.2 m east of the path: circle r = 0.6 meets it at x = sqrt(0.36 - 0.04).
    let c = carrot::carrot(&path, [1.0, 0.2], 0.6).expect("carrot");
    let dx = crate::linalg::sqrt(0.36 - 0.04);
    assert!((c.point[0] - (1.0 + dx)).abs() < 1e-12);
    assert!(c.point[1].abs() < 1e-12);
    assert!((c.heading_rad - libm::atan2(-0.2, dx)).abs() < 1e-12);
    assert_eq!(c.radius_m, 0.6);
    // 2 m off the path: 0.6 -> 1.2 -> 2.4 m.
    let c = carrot::carrot(&path, [1.0, 2.0], 0.6).expect("carrot");
    assert_eq!(c.radius_m, 2.4);
    assert!((c.point[0] - (1.0 + crate::linalg::sqrt(2.4 * 2.4 - 4.0))).abs() < 1e-12);
    // Goal inside the circle.
    let c = carrot::carrot(&path, [4.7, 0.1], 0.6).expect("carrot");
    assert_eq!(c.point, [5.0, 0.0]);
    // Furthest along: an L-shaped path where the circle meets both legs.
    let l = Path::<4>::new(&[[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]]).expect("valid");
    let c = carrot::carrot(&l, [1.8, 0.0], 0.5).expect("carrot");
    assert!((c.point[0] - 2.0).abs() < 1e-12);
    assert!((c.point[1] - crate::linalg::sqrt(0.25 - 0.04)).abs() < 1e-12);
    // Non-finite input.
    assert!(carrot::carrot(&path, [f64::NAN, 0.0], 0.6).is_none());
    assert!(carrot::carrot(&path, [0.0, 0.0], 0.0).is_none());
    // Wrap.
    assert!((wrap_pi(3.0 * core::f64::consts::PI) - core::f64::consts::PI).abs() < 1e-12);
    assert!((wrap_pi(-0.5) + 0.5).abs() < 1e-15);
}

/// GNC-3: heading and crab loops, eq. 48-49, by hand; without slip the heading loop is a pure
/// heading controller.
#[test]
fn gnc_3_slip_loops_hand_calculation() {
    // K1 = 0.02, T_S = 0.05: 0.4 rad/s per rad of heading error.
    assert!((heading_loop(0.1, 0.0, 0.02, -1.0, 0.05) - 0.04).abs() < 1e-15);
    // Yaw slip of 0.005 rad in a period, K2 = -1: oppose with -0.1 rad/s.
    assert!((heading_loop(0.0, 0.005, 0.02, -1.0, 0.05) + 0.1).abs() < 1e-15);
    // Lateral slip 1 mm to the right per 50 ms (2 cm/s downhill), K3 = -1: crab 2 cm/s left.
    assert!((crab_loop(0.001, -1.0, 0.05) + 0.02).abs() < 1e-15);
    let mut g = Guidance::new(straight_north(5.0), GuidanceConfig::rocky8(WHEELS)).expect("ok");
    let pose = Pose2 {
        x_m: 1.0,
        y_m: 0.0,
        phi_rad: 0.0,
    };
    let cmd = g.step(pose, SlipVector::default()).expect("cmd");
    assert_eq!(cmd.y_dot_m_s, 0.0);
    assert_eq!(cmd.phi_dot_rad_s, 0.0);
    assert!((cmd.x_dot_m_s - 0.08).abs() < 1e-12);
    let slip = SlipVector {
        x_m: 0.0,
        y_m: 0.001,
        phi_rad: 0.0,
    };
    let cmd = g.step(pose, slip).expect("cmd");
    assert!((cmd.y_dot_m_s + 0.02).abs() < 1e-12);
}

/// GNC-4: the forward speed is the largest that keeps every wheel within its limit.
#[test]
fn gnc_4_speed_limit_hand_calculation() {
    // Straight: the cap or the wheel limit.
    assert_eq!(
        limit_forward_speed(&WHEELS, 0.0, 0.0, 0.12, 0.08),
        Some((0.08, 0.0, 0.0))
    );
    assert_eq!(
        limit_forward_speed(&WHEELS, 0.0, 0.0, 0.12, 0.5),
        Some((0.12, 0.0, 0.0))
    );
    // Turning at 0.1 rad/s: wheel (0.5, -0.4) (left front) moves at
    // (x_dot + 0.04, 0.05); |.| <= 0.12 -> x_dot <= sqrt(0.0144 - 0.0025) - 0.04.
    let (x, _, _) = limit_forward_speed(&WHEELS, 0.0, 0.1, 0.12, 1.0).expect("feasible");
    assert!((x - (crate::linalg::sqrt(0.0144 - 0.0025) - 0.04)).abs() < 1e-12);
    // An impossible crab is shrunk until feasible.
    let (x, y, p) = limit_forward_speed(&WHEELS, 0.5, 0.0, 0.12, 0.08).expect("shrunk");
    assert_eq!(p, 0.0);
    assert!(y <= 0.12 && y > 0.119, "crab {y}");
    assert!((0.0..0.01).contains(&x), "forward {x}");
    assert_eq!(
        limit_forward_speed(&WHEELS, f64::NAN, 0.0, 0.12, 0.08),
        None
    );
    assert_eq!(limit_forward_speed(&WHEELS, 0.0, 0.0, 0.0, 0.08), None);
}

fn max_wheel_speed(x: f64, y: f64, p: f64) -> f64 {
    WHEELS
        .iter()
        .map(|w| libm::hypot(x - p * w[1], y + p * w[0]))
        .fold(0.0, f64::max)
}

proptest! {
    /// GNC-4 (property): every wheel stays within its limit for any finite command.
    #[test]
    fn gnc_4_speed_limit_never_exceeded(y in -1.0f64..1.0, p in -2.0f64..2.0, cap in 0.0f64..1.0) {
        let (x, ys, ps) = limit_forward_speed(&WHEELS, y, p, 0.12, cap).expect("finite");
        prop_assert!(x >= 0.0 && x <= cap + 1e-12);
        prop_assert!(max_wheel_speed(x, ys, ps) <= 0.12 + 1e-9);
    }

    /// GNC-6 (property): guidance never panics and gives an error or finite commands.
    #[test]
    fn gnc_6_guidance_total(x in proptest::num::f64::ANY, y in proptest::num::f64::ANY,
                            phi in proptest::num::f64::ANY, s in proptest::num::f64::ANY) {
        let mut g = Guidance::new(straight_north(5.0), GuidanceConfig::rocky8(WHEELS)).expect("ok");
        let slip = SlipVector { x_m: 0.0, y_m: s, phi_rad: 0.0 };
        if let Ok(c) = g.step(Pose2 { x_m: x, y_m: y, phi_rad: phi }, slip) {
            prop_assert!(c.x_dot_m_s.is_finite() && c.y_dot_m_s.is_finite() && c.phi_dot_rad_s.is_finite());
        }
    }
}

/// Drive a holonomic point rover along the path with a constant downhill drift (east, +y) of
/// `drift_m_s`, measured as slip each cycle when `compensate`; returns (max cross-track after
/// the first metre, goal miss, cycles).
fn drive(drift_m_s: f64, compensate: bool) -> (f64, f64, usize) {
    let path = Path::<8>::new(&[[0.0, 0.0], [4.5, 0.0]]).expect("valid");
    let config = GuidanceConfig::rocky8(WHEELS);
    let t_s = config.sample_period_s;
    let mut g = Guidance::new(path, config).expect("ok");
    let mut pose = Pose2 {
        x_m: 0.0,
        y_m: 0.0,
        phi_rad: 0.0,
    };
    let mut slip = SlipVector::default();
    let mut max_ct: f64 = 0.0;
    for cycle in 0..4000 {
        let cmd = g.step(pose, slip).expect("cmd");
        if cmd.goal_reached {
            return (max_ct, cmd.goal_distance_m, cycle);
        }
        let (s, c) = (libm::sin(pose.phi_rad), libm::cos(pose.phi_rad));
        // Commanded body velocity to N, plus the drift east.
        let vx = c * cmd.x_dot_m_s - s * cmd.y_dot_m_s;
        let vy = s * cmd.x_dot_m_s + c * cmd.y_dot_m_s + drift_m_s;
        pose.x_m += vx * t_s;
        pose.y_m += vy * t_s;
        pose.phi_rad += cmd.phi_dot_rad_s * t_s;
        if compensate {
            // Slip = true motion minus commanded motion, in the rover frame.
            slip = SlipVector {
                x_m: s * drift_m_s * t_s,
                y_m: c * drift_m_s * t_s,
                phi_rad: 0.0,
            };
        }
        if pose.x_m > 1.0 {
            max_ct = max_ct.max(g.path().project([pose.x_m, pose.y_m]).cross_track_m.abs());
        }
    }
    (max_ct, f64::INFINITY, 4000)
}

/// GNC-5: with a 2 cm/s downhill drift, the crab loop keeps the rover on the path; the heading
/// controller alone leaves the steady offset `r * v_drift / v` the carrot geometry predicts.
#[test]
fn gnc_5_slip_compensation_removes_downhill_offset() {
    let (ct_comp, miss_comp, _) = drive(0.02, true);
    let (ct_plain, _, _) = drive(0.02, false);
    assert!(ct_comp < 0.01, "compensated cross-track {ct_comp}");
    assert!(miss_comp <= 0.05, "goal miss {miss_comp}");
    // Carrot radius 0.6 m, drift 0.02 m/s, speed 0.08 m/s: about 0.15 m.
    assert!(ct_plain > 0.1, "uncompensated cross-track {ct_plain}");
    let (ct_none, miss_none, _) = drive(0.0, false);
    assert!(ct_none < 1e-9 && miss_none <= 0.05);
}

/// GNC-6: non-finite inputs are errors; after the goal the command stays zero.
#[test]
fn gnc_6_bad_inputs_and_goal_latch() {
    let mut g = Guidance::new(straight_north(1.0), GuidanceConfig::rocky8(WHEELS)).expect("ok");
    let nan_pose = Pose2 {
        x_m: f64::NAN,
        y_m: 0.0,
        phi_rad: 0.0,
    };
    assert_eq!(
        g.step(nan_pose, SlipVector::default()).err(),
        Some(GuidanceError::NonFiniteInput)
    );
    let at_goal = Pose2 {
        x_m: 0.98,
        y_m: 0.0,
        phi_rad: 0.0,
    };
    assert!(
        g.step(at_goal, SlipVector::default())
            .expect("cmd")
            .goal_reached
    );
    let moved = Pose2 {
        x_m: 0.5,
        ..at_goal
    };
    let cmd = g.step(moved, SlipVector::default()).expect("cmd");
    assert!(cmd.goal_reached && cmd.x_dot_m_s == 0.0);
    let mut bad = GuidanceConfig::rocky8(WHEELS);
    bad.sample_period_s = 0.0;
    assert_eq!(
        Guidance::new(straight_north(1.0), bad).err(),
        Some(GuidanceError::BadConfig)
    );
}
