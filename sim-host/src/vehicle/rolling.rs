//! Rolling contact: the body twist and the rocker and bogie rates solved together from the
//! six wheels (rough-terrain kinematics after Tarokh & McDermott, "Kinematics modeling and
//! analyses of articulated rovers", IEEE Trans. Robotics 21(4), 2005).
//!
//! Unknowns, in the rover frame `R`: the body velocity `v` and angular rate `w` of the rover
//! reference point and the suspension rates `q_dot = [beta_dot, rho1_dot, rho2_dot]` (9). The
//! velocity of axle `i` is `v_i = v + w x a_i + J_i q_dot` (`a_i` the axle centre, `J_i` the
//! suspension Jacobian of the linkage). For every wheel in contact with the ground
//! (clearance below [`CONTACT_TOLERANCE_M`]), with its contact normal `n_i` (from the contact
//! point to the axle), its rolling tangent `t_i` (in the wheel plane, perpendicular to `n_i`)
//! and its spin axis `l_i`:
//!
//! - `n_i . v_i = 0`: the wheel neither sinks into nor leaves the ground (weight
//!   [`NORMAL_WEIGHT`]);
//! - `t_i . v_i = (1 - s_i) r_i theta_dot_i`: the wheel centre moves along the contact tangent
//!   at the rim speed (its own radius `r_i` times its rate) reduced by the wheel's own
//!   longitudinal slip ratio `s_i`;
//! - `l_i . v_i = lateral_i`: the wheel's own sideways slip velocity.
//!
//! Least squares over all rows gives the 9 rates. A wheel in the air contributes nothing; with
//! fewer than three wheels on the ground the body does not move by rolling (the placement then
//! sets it down). Because the tangent follows the contact angle, a wheel climbing a rock moves
//! its axle upwards, which the suspension rates absorb and the body's horizontal progress
//! reflects.

use super::geometry::{on_bogie, side, TruthGeometry, WheelPose, WHEELS};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// Clearance under which a wheel counts as touching the ground, m.
pub const CONTACT_TOLERANCE_M: f64 = 0.002;
/// Weight of the non-penetration rows relative to the rolling rows.
pub const NORMAL_WEIGHT: f64 = 1000.0;
/// Weight of the lateral rows relative to the rolling rows: equal (the plain least squares of
/// Tarokh & McDermott). Where the wheels' constraints conflict (a wheel held by a step face while
/// the others roll on), the misfit is shared between rolling and sideways slip by these weights;
/// without a force balance there is no better rule (a stiffer lateral row, 10, changed the
/// flight-versus-truth figures on rough terrain by a factor of two and did not free the
/// step climb).
pub const LATERAL_WEIGHT: f64 = 1.0;

/// One wheel's contact as the rolling solve needs it, in `R`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RollingContact {
    /// Whether the wheel touches the ground.
    pub touching: bool,
    /// Unit contact normal (from the contact point to the axle).
    pub normal: Vector3<f64>,
    /// Unit rolling tangent.
    pub tangent: Vector3<f64>,
    /// Unit spin axis.
    pub spin: Vector3<f64>,
}

impl RollingContact {
    /// The contact of a wheel with spin axis `spin` (unit, `R`) whose contact normal is
    /// `normal` (`R`): the normal is made perpendicular to the spin axis and the tangent is
    /// `normal x spin` (forward on level ground).
    pub fn new(touching: bool, normal: Vector3<f64>, spin: Vector3<f64>) -> Self {
        let n = normal - spin * spin.dot(&normal);
        let len = n.norm();
        let n = if len > 1e-9 { n / len } else { -Vector3::z() };
        Self {
            touching,
            normal: n,
            tangent: n.cross(&spin),
            spin,
        }
    }
}

/// Result of the rolling solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Twist {
    /// Body velocity of the reference point in `R`, m/s.
    pub v: Vector3<f64>,
    /// Body angular rate in `R`, rad/s.
    pub w: Vector3<f64>,
    /// Rocker and bogie rates `[beta, rho1, rho2]`, rad/s.
    pub suspension_rad_s: [f64; 3],
    /// Wheels on the ground.
    pub contacts: usize,
}

/// One row of the generalised velocity `[v; w; q_dot]` (9): the velocity of a contact's material
/// point along a direction is `row . [v; w; q_dot]` (plus the wheel's own spin on the rolling row).
pub type Row = SVector<f64, 9>;

/// The three rows of wheel `i`'s contact `c`: `[normal, rolling tangent, spin axis]`. Each gives
/// the velocity of the wheel's material contact point along that direction per unit of
/// `[v; w; q_dot]`, before the wheel's own spin: the axle velocity `v + w x a + J q_dot` along
/// the direction, plus the carrying link's rotation (`k r l . w_link` on the rolling row, `k` the
/// ground-to-rim speed ratio `slip_factor`, and `-r t . w_link` on the lateral row). By virtual
/// work the same rows map a contact force along the direction to generalised forces.
pub fn contact_rows(
    geometry: &TruthGeometry,
    wheels: &[WheelPose; WHEELS],
    rocker_rad: f64,
    bogie_rad: [f64; 2],
    i: usize,
    c: &RollingContact,
    slip_factor: f64,
) -> [Row; 3] {
    let r = geometry.wheel_radius_m[i];
    let a = wheels[i].axle_m;
    let jac: Matrix3<f64> = geometry.axle_jacobian(i, rocker_rad, bogie_rad);
    // Link rotation about the spin axis per unit of [w; q_dot], times k r.
    let kr = slip_factor * r;
    let side_sign = if side(i) == 0 { 1.0 } else { -1.0 };
    // Link rotation per unit of [w; q_dot] projected on `axis`, times `scale`.
    let link = |axis: &Vector3<f64>, scale: f64| {
        let ya = axis.y * scale;
        let mut q = [side_sign * ya, 0.0, 0.0];
        if on_bogie(i) {
            q[1 + side(i)] = ya;
        }
        (axis * scale, Vector3::from(q))
    };
    let none = (Vector3::zeros(), Vector3::zeros());
    [
        (c.normal, none),
        (c.tangent, link(&c.spin, kr)),
        (c.spin, link(&c.tangent, -r)),
    ]
    .map(|(e, (link_w, link_q))| {
        // e . (v + w x a + J q_dot) = e.v + (a x e).w + (J^T e).q_dot, plus the link's
        // rotation: k r l . w_link on the rolling row, -r t . w_link on the lateral row.
        let axe = a.cross(&e) + link_w;
        let jte = jac.transpose() * e + link_q;
        Row::from_column_slice(&[e.x, e.y, e.z, axe.x, axe.y, axe.z, jte.x, jte.y, jte.z])
    })
}

/// Solve the rolling constraints of all wheels on the ground for the body twist and the
/// suspension rates. `wheels` are the wheel poses in `R` at `rocker_rad`, `bogie_rad`;
/// `ground_speed[i]` is the wheel's rim speed `r_i theta_dot_i` after its slip (m/s along the
/// tangent), `slip_factor[i]` the ratio of ground speed to rim speed (`1 - s_i` when driving;
/// it scales the link-rotation term too), `lateral[i]` the sideways slip velocity along the
/// spin axis (m/s); the link-rotation terms use each wheel's own radius `r_i` from `geometry`.
#[allow(clippy::too_many_arguments)]
pub fn solve_rolling(
    geometry: &TruthGeometry,
    wheels: &[WheelPose; WHEELS],
    rocker_rad: f64,
    bogie_rad: [f64; 2],
    contacts: &[RollingContact; WHEELS],
    ground_speed: &[f64; WHEELS],
    slip_factor: &[f64; WHEELS],
    lateral: &[f64; WHEELS],
) -> Twist {
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    let mut atb = SVector::<f64, 9>::zeros();
    let mut touching = 0;
    for i in 0..WHEELS {
        let c = &contacts[i];
        if !c.touching {
            continue;
        }
        touching += 1;
        let rows = contact_rows(
            geometry,
            wheels,
            rocker_rad,
            bogie_rad,
            i,
            c,
            slip_factor[i],
        );
        for (row, target, weight) in [
            (rows[0], 0.0, NORMAL_WEIGHT),
            (rows[1], ground_speed[i], 1.0),
            (rows[2], lateral[i], LATERAL_WEIGHT),
        ] {
            let w2 = weight * weight;
            ata += row * row.transpose() * w2;
            atb += row * (target * w2);
        }
    }
    let zero = Twist {
        v: Vector3::zeros(),
        w: Vector3::zeros(),
        suspension_rad_s: [0.0; 3],
        contacts: touching,
    };
    if touching < 3 {
        return zero;
    }
    // A small damping keeps the system defined when the contacts leave a rate unobserved.
    let ata = ata + SMatrix::<f64, 9, 9>::identity() * 1e-9;
    let Some(x) = ata.cholesky().map(|c| c.solve(&atb)) else {
        return zero;
    };
    Twist {
        v: Vector3::new(x[0], x[1], x[2]),
        w: Vector3::new(x[3], x[4], x[5]),
        suspension_rad_s: [x[6], x[7], x[8]],
        contacts: touching,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vehicle::geometry::{rocky8, VehicleGeometry};

    fn level_contacts(wheels: &[WheelPose; WHEELS]) -> [RollingContact; WHEELS] {
        std::array::from_fn(|i| RollingContact::new(true, -Vector3::z(), wheels[i].spin_axis))
    }

    /// SIM-15: on level ground, equal wheel speeds give a pure forward twist at the rim speed
    /// with no suspension motion; a turn in place (Ackermann-free: wheels tangent to circles
    /// about the centre) gives a pure yaw rate.
    #[test]
    fn sim_15_level_ground_twists() {
        let g = rocky8();
        let w = g.wheels(0.0, [0.0, 0.0], &[0.0; 6]).unwrap();
        let t = solve_rolling(
            &g,
            &w,
            0.0,
            [0.0; 2],
            &level_contacts(&w),
            &[0.1; 6],
            &[1.0; 6],
            &[0.0; 6],
        );
        assert!((t.v - Vector3::new(0.1, 0.0, 0.0)).norm() < 1e-9, "{:?}", t);
        assert!(t.w.norm() < 1e-9 && t.suspension_rad_s.iter().all(|q| q.abs() < 1e-9));
        // Turn in place at 0.2 rad/s: each wheel steered tangent to its circle about R.
        let omega = 0.2;
        let base = g.wheels(0.0, [0.0, 0.0], &[0.0; 6]).unwrap();
        let steer: [f64; 6] = std::array::from_fn(|i| {
            let a = base[i].axle_m;
            // Velocity of the axle: omega z x a = omega (-a.y, a.x).
            let (vx, vy) = (-omega * a.y, omega * a.x);
            let s = vy.atan2(vx);
            // Keep steering within +-90 deg by driving backwards.
            if s > std::f64::consts::FRAC_PI_2 {
                s - std::f64::consts::PI
            } else if s < -std::f64::consts::FRAC_PI_2 {
                s + std::f64::consts::PI
            } else {
                s
            }
        });
        let w = g.wheels(0.0, [0.0, 0.0], &steer).unwrap();
        let speed: [f64; 6] = std::array::from_fn(|i| {
            let a = w[i].axle_m;
            let v = Vector3::new(-omega * a.y, omega * a.x, 0.0);
            v.dot(&w[i].rolling_dir)
        });
        let t = solve_rolling(
            &g,
            &w,
            0.0,
            [0.0; 2],
            &level_contacts(&w),
            &speed,
            &[1.0; 6],
            &[0.0; 6],
        );
        assert!((t.w.z - omega).abs() < 1e-9 && t.v.norm() < 1e-9, "{:?}", t);
    }

    /// SIM-15: when the right front wheel climbs at 45 deg (its contact normal tilted back)
    /// while all wheels turn at the same rate, the right bogie turns, the body advances less
    /// than the rim speed, and fewer than three wheels on the ground give no motion.
    #[test]
    fn sim_15_climbing_wheel_moves_the_bogie() {
        let g = rocky8();
        let w = g.wheels(0.0, [0.0, 0.0], &[0.0; 6]).unwrap();
        let mut c = level_contacts(&w);
        let n = Vector3::new(-1.0, 0.0, -1.0).normalize();
        c[0] = RollingContact::new(true, n, w[0].spin_axis);
        assert!(c[0].tangent.z < 0.0 && c[0].tangent.x > 0.0);
        let t = solve_rolling(&g, &w, 0.0, [0.0; 2], &c, &[0.1; 6], &[1.0; 6], &[0.0; 6]);
        assert!(t.v.x < 0.1 && t.v.x > 0.05, "{:?}", t);
        assert!(t.suspension_rad_s[1].abs() > 0.01, "{:?}", t);
        let mut air = c;
        for k in air.iter_mut().skip(2) {
            k.touching = false;
        }
        let t = solve_rolling(&g, &w, 0.0, [0.0; 2], &air, &[0.1; 6], &[1.0; 6], &[0.0; 6]);
        assert_eq!(t.contacts, 2);
        assert!(t.v.norm() == 0.0);
    }
}
