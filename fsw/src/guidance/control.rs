//! Slip-compensation loops (H04 eq. 48-49, H05 eq. 20-21) and the forward-speed limit from the
//! drive-motor constraint (H04 sec. 5: "x_dot_cmd ... the maximum value allowed that keeps the
//! rover within its operational constraints").

/// Bisection steps used to shrink the steering part of a command that no forward speed can
/// satisfy.
const SHRINK_STEPS: u32 = 24;

/// Heading loop, eq. 48 (H04): `phi_dot_cmd = (K1 * phi_err + K2 * phi_slip) / T_S`.
///
/// `phi_slip_rad` is the yaw slip accumulated over the last sample period (EKF minus
/// kinematics, rad); with that sign convention `k2` is negative to oppose the slip (the paper
/// leaves the sign to the gain). Result in rad/s, positive turning right (z down).
pub fn heading_loop(phi_err_rad: f64, phi_slip_rad: f64, k1: f64, k2: f64, t_s: f64) -> f64 {
    (k1 * phi_err_rad + k2 * phi_slip_rad) / t_s
}

/// Crab loop, eq. 49 (H04): `y_dot_cmd = K3 * y_slip / T_S`.
///
/// `y_slip_m` is the lateral slip in the rover frame accumulated over the last sample period
/// (EKF minus kinematics, m, positive to the right); `k3` negative opposes it. Result in m/s
/// along the rover's y axis (right).
pub fn crab_loop(y_slip_m: f64, k3: f64, t_s: f64) -> f64 {
    k3 * y_slip_m / t_s
}

/// Largest forward speed `x_dot` (m/s, at most `x_dot_cap`) such that every wheel's ground
/// speed `|(x_dot - phi_dot * y_i, y_dot + phi_dot * x_i)|` stays within `v_wheel_max` (m/s),
/// for wheel contact points `(x_i, y_i)` in the rover frame (m). Rigid-body velocity of a
/// point in the rover frame with z down: `v + omega x p`, `omega = (0, 0, phi_dot)`.
///
/// Returns the command `(x_dot, y_dot, phi_dot)`: when no forward speed `>= 0` is feasible the
/// steering part `(y_dot, phi_dot)` is scaled down (bisection) until one is. `None` for
/// non-finite inputs or a non-positive wheel limit.
pub fn limit_forward_speed(
    wheel_xy_m: &[[f64; 2]; 6],
    y_dot: f64,
    phi_dot: f64,
    v_wheel_max: f64,
    x_dot_cap: f64,
) -> Option<(f64, f64, f64)> {
    let finite = y_dot.is_finite()
        && phi_dot.is_finite()
        && v_wheel_max.is_finite()
        && x_dot_cap.is_finite()
        && wheel_xy_m.iter().flatten().all(|v| v.is_finite());
    if !finite || v_wheel_max <= 0.0 {
        return None;
    }
    let cap = x_dot_cap.max(0.0);
    if let Some(x) = max_x_dot(wheel_xy_m, y_dot, phi_dot, v_wheel_max, cap) {
        return Some((x, y_dot, phi_dot));
    }
    // Shrink the steering part: scale s in [0, 1], s = 0 is always feasible (x_dot = 0).
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..SHRINK_STEPS {
        let mid = 0.5 * (lo + hi);
        if max_x_dot(wheel_xy_m, mid * y_dot, mid * phi_dot, v_wheel_max, cap).is_some() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let x = max_x_dot(wheel_xy_m, lo * y_dot, lo * phi_dot, v_wheel_max, cap).unwrap_or(0.0);
    Some((x, lo * y_dot, lo * phi_dot))
}

/// Largest `x_dot` in `[0, cap]` meeting every wheel's speed limit, if any.
fn max_x_dot(
    wheel_xy_m: &[[f64; 2]; 6],
    y_dot: f64,
    phi_dot: f64,
    v_max: f64,
    cap: f64,
) -> Option<f64> {
    let mut upper = cap;
    let mut lower: f64 = 0.0;
    for w in wheel_xy_m {
        let lateral = y_dot + phi_dot * w[0];
        let room = v_max * v_max - lateral * lateral;
        if room < 0.0 {
            return None;
        }
        let half = crate::linalg::sqrt(room);
        let centre = phi_dot * w[1];
        upper = upper.min(centre + half);
        lower = lower.max(centre - half);
    }
    (upper >= lower).then_some(upper)
}
