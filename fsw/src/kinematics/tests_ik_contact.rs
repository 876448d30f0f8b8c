//! KIN-12: rough-terrain inverse kinematics with the contact angles
//! ([`inverse_kinematics_contact`], `docs/kinematics.md` "Rough-terrain inverse kinematics").

#![allow(clippy::needless_range_loop)]

use super::forward::contact_velocities;
use super::tests::{level, random_state};
use super::*;
use crate::types::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const R: f64 = WHEEL_RADIUS_M;

fn cmd(x: f64, y: f64, yaw: f64) -> VehicleCommand {
    VehicleCommand {
        x_dot_m_s: x,
        y_dot_m_s: y,
        yaw_rate_rad_s: yaw,
    }
}

fn random_cmd(rng: &mut ChaCha8Rng) -> VehicleCommand {
    cmd(
        rng.random_range(-0.06..0.06),
        rng.random_range(-0.06..0.06),
        rng.random_range(-0.15..0.15),
    )
}

/// Every number of a solution as bits (bit-for-bit comparison, NaN-safe).
fn bits(s: &Result<InverseSolution, KinematicsError>) -> Result<[u64; 21], KinematicsError> {
    s.map(|s| {
        let mut out = [0_u64; 21];
        let all = s
            .command
            .steer_angle_rad
            .iter()
            .chain(s.command.wheel_rate_rad_s.iter())
            .chain(s.body_rates.iter())
            .chain(core::iter::once(&s.suspension_rates.rocker_rad_s))
            .chain(s.suspension_rates.bogie_rad_s.iter());
        for (o, x) in out.iter_mut().zip(all) {
            *o = x.to_bits();
        }
        out
    })
}

/// KIN-12: with every angle 0 (given as 0, non-finite, at or beyond the limit, or with an
/// unusable limit) the rough-terrain IK and speed scale equal eq. 16-25 bit for bit, over random
/// suspension states and commands (errors included).
#[test]
fn kin_12_zero_angles_equal_eq_16_25_bit_for_bit() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let zero_like = [
        ContactAngles::LEVEL,
        ContactAngles::new(&[0.0; 6], 1.0),
        ContactAngles::new(&[-0.0; 6], 1.0),
        ContactAngles::new(
            &[f64::NAN, f64::INFINITY, -f64::INFINITY, 1.0, -1.2, 3.0],
            1.0,
        ),
        ContactAngles::new(&[0.3; 6], f64::NAN),
        ContactAngles::new(&[0.3; 6], 0.0),
        ContactAngles::new(&[0.3; 6], core::f64::consts::FRAC_PI_2),
    ];
    for c in &zero_like {
        assert_eq!(c.angles_rad(), [0.0; 6]);
    }
    let mut solved = 0;
    for k in 0..3000 {
        let s = if k % 4 == 0 {
            level()
        } else {
            random_state(&mut rng)
        };
        let c = random_cmd(&mut rng);
        let c = if k % 50 == 0 { cmd(3.0, 0.0, 0.0) } else { c };
        let old = inverse_kinematics(&ROCKY8, &s, &c);
        let old_k = max_speed_scale(&ROCKY8, &s, &c, 1.9);
        solved += usize::from(old.is_ok());
        for z in &zero_like {
            assert_eq!(
                bits(&inverse_kinematics_contact(&ROCKY8, &s, &c, z)),
                bits(&old)
            );
            let k = max_speed_scale_contact(&ROCKY8, &s, &c, 1.9, z);
            assert_eq!(k.map(f64::to_bits), old_k.map(f64::to_bits));
        }
    }
    assert!(solved > 2000, "only {solved} of 3000 solved");
}

/// KIN-12: the assumptions of the contact rows: the contact frame's `z` axis and origin (axle
/// centre) do not turn with the steering, `z_C` is `-s` (up along the steering axis), and the
/// rolling direction at `psi` is `cos(psi) x0 + sin(psi) (s x x0)`.
#[test]
fn kin_12_contact_frame_follows_the_steering_as_assumed() {
    let mut rng = ChaCha8Rng::seed_from_u64(121);
    for _ in 0..200 {
        let s = random_state(&mut rng);
        let zero = SuspensionState {
            steer_rad: [0.0; 6],
            ..s
        };
        let f0 = wheel_frames(&ROCKY8, &zero).unwrap();
        let f = wheel_frames(&ROCKY8, &s).unwrap();
        for i in 0..6 {
            let psi = s.steer_rad[i];
            let x0 = f0[i].rolling_dir;
            let x = x0 * psi.cos() + f0[i].steer_axis.cross(&x0) * psi.sin();
            assert!((x - f[i].rolling_dir).norm() < 1e-12);
            assert!((f[i].contact.z_axis() - f0[i].contact.z_axis()).norm() < 1e-12);
            assert!((f[i].contact.z_axis() + f[i].steer_axis).norm() < 1e-12);
            assert!((f[i].contact.pos - f0[i].contact.pos).norm() < 1e-12);
        }
    }
}

/// KIN-12, level ground, straight command `x_dot`, all six contacts at the same angle `delta`:
/// the rover must climb along the tangent as a rigid body, so exactly `z_dot = -x_dot tan delta`
/// (z down), no rotation, no suspension motion, and every wheel rate is the level rate
/// `x_dot / r` over `cos delta` (derivation in `docs/kinematics.md`).
#[test]
fn kin_12_all_wheels_at_one_angle_climb_rigidly() {
    let vx = 0.1;
    for delta in [-0.6, -0.3, 0.1, 0.3, 0.6, 0.9] {
        let contact = ContactAngles::new(&[delta; 6], 1.2);
        let sol =
            inverse_kinematics_contact(&ROCKY8, &level(), &cmd(vx, 0.0, 0.0), &contact).unwrap();
        let old = inverse_kinematics(&ROCKY8, &level(), &cmd(vx, 0.0, 0.0)).unwrap();
        let want_z = -vx * libm::tan(delta);
        assert!((sol.body_rates[2] - want_z).abs() < 1e-12, "z_dot");
        for j in [3, 4] {
            assert!(sol.body_rates[j].abs() < 1e-12, "rotation {j}");
        }
        assert!(sol.suspension_rates.rocker_rad_s.abs() < 1e-12);
        assert!(sol
            .suspension_rates
            .bogie_rad_s
            .iter()
            .all(|b| b.abs() < 1e-12));
        for i in 0..6 {
            let want = old.command.wheel_rate_rad_s[i] / libm::cos(delta);
            assert!((sol.command.wheel_rate_rad_s[i] - want).abs() < 1e-12 * want.abs());
            assert!((sol.command.wheel_rate_rad_s[i] - vx / (R * libm::cos(delta))).abs() < 1e-12);
            assert!(sol.command.steer_angle_rad[i].abs() < 1e-12);
        }
    }
}

/// The velocity of the chain point at `q` of wheel `f` for the solution `sol`, and the
/// chain's angular velocity (rover frame, m/s and rad/s).
fn chain_motion(f: &WheelFrames, sol: &InverseSolution, q: &Vec3) -> (Vec3, Vec3) {
    let b = &sol.body_rates;
    let (v, w) = (Vec3::new(b[0], b[1], b[2]), Vec3::new(b[3], b[4], b[5]));
    let rho = match f.bogie {
        Some(k) => sol.suspension_rates.bogie_rad_s[k],
        None => 0.0,
    };
    let beta = sol.suspension_rates.rocker_rad_s;
    let lever = q - f.contact_point_m;
    let vel = v
        + w.cross(q)
        + (f.d_contact_d_rocker + f.rocker_axis.cross(&lever)) * beta
        + (f.d_contact_d_bogie + f.bogie_axis.cross(&lever)) * rho;
    (vel, w + f.rocker_axis * beta + f.bogie_axis * rho)
}

/// The rough-terrain IK with the steering at the solution's own angles (the contact rows use
/// the current steering): iterated to a fixed point (steering change below 1e-14 rad within 60
/// solves). Returns the state and the solution, `None` when it fails or does not converge.
fn steady(
    start: &SuspensionState,
    c: &VehicleCommand,
    contact: &ContactAngles,
) -> Option<(SuspensionState, InverseSolution)> {
    let mut s = *start;
    for _ in 0..60 {
        let next = inverse_kinematics_contact(&ROCKY8, &s, c, contact).ok()?;
        let moved = next
            .command
            .steer_angle_rad
            .iter()
            .zip(s.steer_rad.iter())
            .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
        s.steer_rad = next.command.steer_angle_rad;
        if moved < 1e-14 {
            return Some((s, next));
        }
    }
    None
}

/// KIN-12, level ground, straight command, only wheel `k` at angle `delta` (steering at its
/// fixed point): the exact expectation. The wheel rolls about its contact `c = a - r n`: the
/// chain's velocity there is `r theta_dot t` (no motion along the normal `n` nor the spin axis
/// `y_C`), and, written with the axle centre's velocity `v_a` and the chain's angular velocity
/// `Omega`, `r theta_dot = t . v_a - r Omega . y_C` (`n x t = y_C`; the encoder turns relative to
/// the chain). The first-order guess `theta_dot = x_dot / (r cos(delta))` (the axle carrying the
/// body's speed along the tangent) does not hold for one wheel: the suspension articulates and
/// moves every axle relative to the body. Measured and printed: the axle's speed along `t`
/// differs from `x_dot / cos(delta)` by up to 25 %, the chain term is up to 15 % of it and the
/// other wheels' rates move by up to 42 % from the level rate (|delta| <= 0.5); asserted as
/// bounds (30 %, 20 %, 50 %) and as a real effect (the other wheels move by more than 10 %).
#[test]
fn kin_12_one_wheel_at_an_angle() {
    let vx = 0.1;
    let mut worst_first_order: f64 = 0.0;
    let (mut worst_chain, mut worst_other): (f64, f64) = (0.0, 0.0);
    for k in 0..6 {
        for delta in [-0.5, -0.2, 0.2, 0.5] {
            let mut angles = [0.0; 6];
            angles[k] = delta;
            let contact = ContactAngles::new(&angles, 1.2);
            let (state, sol) = steady(&level(), &cmd(vx, 0.0, 0.0), &contact).unwrap();
            let frames = wheel_frames(&ROCKY8, &state).unwrap();
            let f = &frames[k];
            let (x_c, z_c) = (f.rolling_dir, f.contact.z_axis());
            let y_c = z_c.cross(&x_c);
            let (s, c) = (libm::sin(delta), libm::cos(delta));
            let t = x_c * c + z_c * s;
            let n = z_c * c - x_c * s;
            let axle = f.contact.pos;
            let contact_point = axle - n * R;
            let (v_a, omega) = chain_motion(f, &sol, &axle);
            let (v_c, _) = chain_motion(f, &sol, &contact_point);
            let rate = sol.command.wheel_rate_rad_s[k];
            // Exact: rolling about the contact.
            let exact = (t.dot(&v_a) - R * omega.dot(&y_c)) / R;
            assert!(
                (rate - exact).abs() < 1e-12,
                "wheel {k} delta {delta}: {rate} {exact} t.v_c/r {} n.v_c {} y.v_c {}",
                t.dot(&v_c) / R,
                n.dot(&v_c),
                y_c.dot(&v_c)
            );
            assert!(v_c.dot(&n).abs() < 1e-12 && v_c.dot(&y_c).abs() < 1e-12);
            assert!((v_c - t * (rate * R)).norm() < 1e-12);
            // First order: the axle's speed along the tangent carries the body's forward speed,
            // `t . v_a = x_dot / cos(delta)`; the chain's rotation is the remaining term.
            let first = vx / c;
            let dev = (t.dot(&v_a) / first - 1.0).abs();
            worst_first_order = worst_first_order.max(dev);
            worst_chain = worst_chain.max((R * omega.dot(&y_c) / first).abs());
            for i in (0..6).filter(|i| *i != k) {
                let other = sol.command.wheel_rate_rad_s[i];
                worst_other = worst_other.max((other * R / vx - 1.0).abs());
            }
        }
    }
    assert!(worst_first_order < 0.3 && worst_chain < 0.2);
    assert!(worst_other > 0.1 && worst_other < 0.5);
    println!(
        "axle speed along t vs x_dot / cos(delta): {worst_first_order:.4}; chain rotation term \
         r Omega.y_C / (x_dot / cos delta) up to {worst_chain:.4}; other wheels' rates vs level: \
         {worst_other:.4}"
    );
}

/// KIN-12: consistency with the forward rolling equations of [`super::contact`]: for random
/// suspension states, angles (|delta| < 0.7) and commands, with the steering at the solution's
/// own angles (fixed point: the contact rows use the current steering), the IK's body rates,
/// suspension rates and wheel rates satisfy `e_i = v + w x c_i - J_i(delta_i) q_dot_i = 0`
/// (all three rows, `contact_jacobians` at the angles) to 1e-9, and they return the command.
#[test]
fn kin_12_solution_satisfies_the_contact_rolling_equations() {
    let mut rng = ChaCha8Rng::seed_from_u64(122);
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for _ in 0..1500 {
        let mut s = random_state(&mut rng);
        s.steer_rad = [0.0; 6];
        let s = s;
        let angles: [f64; 6] = core::array::from_fn(|_| rng.random_range(-0.7..0.7));
        let contact = ContactAngles::new(&angles, 1.0);
        let c = random_cmd(&mut rng);
        let Some((s, sol)) = steady(&s, &c, &contact) else {
            continue;
        };
        checked += 1;
        let frames = wheel_frames(&ROCKY8, &s).unwrap();
        let jac = contact_jacobians(&frames, R, &angles);
        let b = contact_velocities(&jac, &sol.suspension_rates, &sol.command.wheel_rate_rad_s);
        let br = &sol.body_rates;
        let (v, w) = (
            Vec3::new(br[0], br[1], br[2]),
            Vec3::new(br[3], br[4], br[5]),
        );
        for i in 0..6 {
            let e = v + w.cross(&jac[i].contact_point_m) - b[i];
            worst = worst.max(e.norm());
        }
        assert_eq!(
            [br[0], br[1], br[5]],
            [c.x_dot_m_s, c.y_dot_m_s, c.yaw_rate_rad_s]
        );
    }
    assert!(checked > 1000, "only {checked} of 1500 converged");
    assert!(worst < 1e-9, "worst rolling residual {worst} m/s");
}

/// KIN-12: the wheel-rate limit and the speed scale with contact angles: a scaled command
/// solves with its fastest wheel at the limit; inputs that are not finite give error values.
#[test]
fn kin_12_speed_scale_and_errors() {
    let mut rng = ChaCha8Rng::seed_from_u64(123);
    for _ in 0..500 {
        let s = random_state(&mut rng);
        let angles: [f64; 6] = core::array::from_fn(|_| rng.random_range(-0.8..0.8));
        let contact = ContactAngles::new(&angles, 1.0);
        let c = random_cmd(&mut rng);
        let Ok(k) = max_speed_scale_contact(&ROCKY8, &s, &c, 2.0, &contact) else {
            continue;
        };
        let scaled = cmd(c.x_dot_m_s * k, c.y_dot_m_s * k, c.yaw_rate_rad_s * k);
        let sol = inverse_kinematics_contact(&ROCKY8, &s, &scaled, &contact).unwrap();
        let fastest = sol
            .command
            .wheel_rate_rad_s
            .iter()
            .fold(0.0_f64, |m, r| m.max(r.abs()));
        assert!((fastest - 2.0).abs() < 1e-9);
        let faster = cmd(
            scaled.x_dot_m_s * 1.01,
            scaled.y_dot_m_s * 1.01,
            scaled.yaw_rate_rad_s * 1.01,
        );
        assert!(matches!(
            inverse_kinematics_contact(&ROCKY8, &s, &faster, &contact),
            Err(KinematicsError::WheelRateLimit { .. })
        ));
    }
    let contact = ContactAngles::new(&[0.3; 6], 1.0);
    let bad = cmd(f64::NAN, 0.0, 0.0);
    assert_eq!(
        inverse_kinematics_contact(&ROCKY8, &level(), &bad, &contact),
        Err(KinematicsError::NonFinite)
    );
    assert_eq!(
        max_speed_scale_contact(&ROCKY8, &level(), &cmd(0.1, 0.0, 0.0), f64::NAN, &contact),
        Err(KinematicsError::NonFinite)
    );
    let mut s = level();
    s.rocker_rad = 2.0;
    assert_eq!(
        inverse_kinematics_contact(&ROCKY8, &s, &cmd(0.1, 0.0, 0.0), &contact),
        Err(KinematicsError::JointOutOfRange)
    );
    let angles = [0.3, -0.2, f64::NAN, 1.0, 0.99, -0.0];
    let c = ContactAngles::new(&angles, 1.0);
    let used = c.angles_rad();
    assert!((used[0] - 0.3).abs() < 1e-15 && (used[1] + 0.2).abs() < 1e-15);
    assert!((used[4] - 0.99).abs() < 1e-15);
    assert_eq!([used[2], used[3], used[5]], [0.0; 3]);
}

/// The rough-terrain inverse kinematics written plainly, without the single-pass shortcuts of
/// `inverse.rs`: per-wheel rows copied into arrays, the unactuated rates from
/// `linalg::solve6` in the column order `[z roll pitch beta rho1 rho2]`, `atan2` per wheel.
/// `angles` and `max` as [`ContactAngles::new`]. The reference of
/// `kin_12_matches_the_two_pass_reference`.
fn reference_ik(
    s: &SuspensionState,
    c: &VehicleCommand,
    angles: &[f64; 6],
    max: f64,
) -> Result<InverseSolution, KinematicsError> {
    use crate::types::{Mat6, Vec6};
    use core::f64::consts::PI;
    use rover_hal::MobilityCommand;
    let g = &ROCKY8;
    let max_ok = max.is_finite() && max > 0.0 && max < core::f64::consts::FRAC_PI_2;
    let sin_cos = angles.map(|d| {
        (max_ok && d.is_finite() && d != 0.0 && libm::fabs(d) < max).then(|| libm::sincos(d))
    });
    if !(c.x_dot_m_s.is_finite() && c.y_dot_m_s.is_finite() && c.yaw_rate_rad_s.is_finite()) {
        return Err(KinematicsError::NonFinite);
    }
    // The state check of `solve`, then the frames at zero steering.
    wheel_frames(g, s)?;
    let frames = wheel_frames(
        g,
        &SuspensionState {
            steer_rad: [0.0; 6],
            ..*s
        },
    )?;
    // (normal, point, d_rocker, d_bogie, z_c, sin, cos) per wheel with an angle.
    type Rows = (Vec3, Vec3, Vec3, Vec3, Vec3, f64, f64);
    let rows: [Option<Rows>; 6] = core::array::from_fn(|i| {
        sin_cos[i].map(|(sd, cd)| {
            let f = &frames[i];
            let (sp, cp) = libm::sincos(s.steer_rad[i]);
            let x0 = f.rolling_dir;
            let x_c = x0 * cp + f.steer_axis.cross(&x0) * sp;
            let z_c = f.contact.z_axis();
            let point = f.contact.pos + (x_c * sd - z_c * cd) * R;
            let lever = point - f.contact_point_m;
            (
                z_c * cd - x_c * sd,
                point,
                f.d_contact_d_rocker + f.rocker_axis.cross(&lever),
                f.d_contact_d_bogie + f.bogie_axis.cross(&lever),
                z_c,
                sd,
                cd,
            )
        })
    });
    let v_cmd = Vec3::new(c.x_dot_m_s, c.y_dot_m_s, 0.0);
    let w_cmd = Vec3::new(0.0, 0.0, c.yaw_rate_rad_s);
    let mut m = Mat6::zeros();
    let mut rhs = Vec6::zeros();
    for (i, f) in frames.iter().enumerate() {
        let (sv, p, dr, db) = match rows[i] {
            None => (
                f.steer_axis,
                f.contact_point_m,
                f.d_contact_d_rocker,
                f.d_contact_d_bogie,
            ),
            Some(r) => (r.0, r.1, r.2, r.3),
        };
        m[(i, 0)] = sv.z;
        m[(i, 1)] = sv.dot(&Vec3::x().cross(&p));
        m[(i, 2)] = sv.dot(&Vec3::y().cross(&p));
        m[(i, 3)] = sv.dot(&dr);
        match f.bogie {
            Some(1) => m[(i, 5)] = sv.dot(&db),
            Some(_) => m[(i, 4)] = sv.dot(&db),
            None => {}
        }
        rhs[i] = -sv.dot(&(v_cmd + w_cmd.cross(&p)));
    }
    let u = crate::linalg::solve6(&m, &rhs).ok_or(KinematicsError::Singular)?;
    let v = Vec3::new(c.x_dot_m_s, c.y_dot_m_s, u[0]);
    let w = Vec3::new(u[1], u[2], c.yaw_rate_rad_s);
    let mut command = MobilityCommand::default();
    for (i, f) in frames.iter().enumerate() {
        let rate_b = match f.bogie {
            Some(1) => u[5],
            Some(_) => u[4],
            None => 0.0,
        };
        let (p, dr, db) = match rows[i] {
            None => (f.contact_point_m, f.d_contact_d_rocker, f.d_contact_d_bogie),
            Some(r) => (r.1, r.2, r.3),
        };
        let cv = v + w.cross(&p) + dr * u[3] + db * rate_b;
        let x0 = f.rolling_dir;
        let (a, b) = (cv.dot(&x0), cv.dot(&f.steer_axis.cross(&x0)));
        let speed = crate::linalg::sqrt(a * a + b * b);
        let current = s.steer_rad[i];
        let (psi, rate) = if speed <= 1e-9 {
            (current, 0.0)
        } else {
            let raw = libm::atan2(b, a);
            let (fw, bw) = match rows[i] {
                None => (speed / R, -speed / R),
                Some(r) => {
                    let climb = cv.dot(&r.4) * r.5;
                    ((speed * r.6 + climb) / R, (climb - speed * r.6) / R)
                }
            };
            let mut best: Option<(f64, f64)> = None;
            for (psi, rt) in [(raw, fw), (raw - PI, bw), (raw + PI, bw)] {
                let better =
                    best.is_none_or(|(bp, _)| (psi - current).abs() < (bp - current).abs());
                if psi.abs() <= g.limits.steer_rad && better {
                    best = Some((psi, rt));
                }
            }
            best.ok_or(KinematicsError::SteeringLimit { wheel: i as u8 })?
        };
        command.steer_angle_rad[i] = psi;
        command.wheel_rate_rad_s[i] = rate;
    }
    let limit = g.limits.wheel_rate_rad_s * (1.0 + 1e-9);
    if let Some(i) = command
        .wheel_rate_rad_s
        .iter()
        .position(|r| r.abs() > limit)
    {
        return Err(KinematicsError::WheelRateLimit { wheel: i as u8 });
    }
    Ok(InverseSolution {
        command,
        body_rates: BodyRates::new(v.x, v.y, v.z, w.x, w.y, w.z),
        suspension_rates: SuspensionRates {
            rocker_rad_s: u[3],
            bogie_rad_s: [u[4], u[5]],
        },
    })
}

/// KIN-12: the single-pass inverse kinematics (bogie columns first in the
/// elimination, products with structural zeros left out, `atan(b / a)` for `a > 0`) gives the
/// results of the reference above to rounding: same outcome (solution or the same error) and
/// every steering angle, wheel rate, body and suspension rate within 1e-12 (rad, rad/s, m/s;
/// relative to 1 rad/s for the rates), over random suspension states, commands (a fiftieth
/// beyond the wheel-rate limit) and contact angles (some zero, non-finite or beyond the limit).
/// Measured: the largest difference is printed (5.3e-15).
#[test]
fn kin_12_matches_the_two_pass_reference() {
    let mut rng = ChaCha8Rng::seed_from_u64(126);
    let (mut solved, mut refused) = (0, 0);
    let mut worst: f64 = 0.0;
    for k in 0..4000 {
        let s = if k % 7 == 0 {
            level()
        } else {
            random_state(&mut rng)
        };
        let c = if k % 50 == 0 {
            cmd(3.0, 0.0, 0.1)
        } else {
            random_cmd(&mut rng)
        };
        let angles: [f64; 6] = core::array::from_fn(|_| match rng.random_range(0..10) {
            0 => 0.0,
            1 => f64::NAN,
            2 => 1.2,
            _ => rng.random_range(-0.9..0.9),
        });
        let want = reference_ik(&s, &c, &angles, 1.0);
        let got = inverse_kinematics_contact(&ROCKY8, &s, &c, &ContactAngles::new(&angles, 1.0));
        match (want, got) {
            (Ok(w), Ok(g)) => {
                solved += 1;
                let pairs = w
                    .command
                    .steer_angle_rad
                    .iter()
                    .zip(g.command.steer_angle_rad.iter())
                    .chain(
                        w.command
                            .wheel_rate_rad_s
                            .iter()
                            .zip(g.command.wheel_rate_rad_s.iter()),
                    )
                    .chain(w.body_rates.iter().zip(g.body_rates.iter()))
                    .chain(core::iter::once((
                        &w.suspension_rates.rocker_rad_s,
                        &g.suspension_rates.rocker_rad_s,
                    )))
                    .chain(
                        w.suspension_rates
                            .bogie_rad_s
                            .iter()
                            .zip(g.suspension_rates.bogie_rad_s.iter()),
                    );
                for (a, b) in pairs {
                    worst = worst.max((a - b).abs() / a.abs().max(1.0));
                }
            }
            (w, g) => {
                refused += 1;
                assert_eq!(w.map(|_| ()), g.map(|_| ()), "case {k}");
            }
        }
    }
    println!("single pass vs reference: {solved} solved, {refused} refused, largest difference {worst:.2e}");
    assert!(
        solved > 3000 && refused > 50,
        "{solved} solved, {refused} refused"
    );
    assert!(worst < 1e-12, "largest difference {worst}");
}

/// KIN-12: [`inverse::inverse_kinematics_scaled`] (one solve, rates scaled) gives
/// what two solves give ([`max_speed_scale_contact`], then
/// [`inverse_kinematics_contact`] on the scaled command; [`max_speed_scale`] and
/// [`inverse_kinematics`] without contact angles) to rounding: the same outcome, the same scale
/// to 1e-12 relative, steering angles, wheel, body and suspension rates within 1e-12 (relative to
/// 1 rad/s), the fastest wheel at the limit; a scale of 1 leaves the solution of `cmd` bit for
/// bit. A limit that is not finite or not positive is refused.
#[test]
fn kin_12_scaled_inverse_matches_two_solves() {
    let mut rng = ChaCha8Rng::seed_from_u64(127);
    let limit = ROCKY8.limits.wheel_rate_rad_s;
    let (mut scaled, mut unscaled) = (0, 0);
    let mut worst: f64 = 0.0;
    for k in 0..3000 {
        let s = random_state(&mut rng);
        let c = random_cmd(&mut rng);
        // A third of the commands five times faster: above the limit.
        let c = if k % 3 == 0 {
            cmd(c.x_dot_m_s * 5.0, c.y_dot_m_s * 5.0, c.yaw_rate_rad_s * 5.0)
        } else {
            c
        };
        let angles: [f64; 6] = core::array::from_fn(|_| rng.random_range(-0.8..0.8));
        let contact = ContactAngles::new(&angles, 1.0);
        let use_contact = k % 2 == 0;
        let one = inverse::inverse_kinematics_scaled(
            &ROCKY8,
            &s,
            &c,
            use_contact.then_some(&contact),
            limit,
        );
        let two = if use_contact {
            max_speed_scale_contact(&ROCKY8, &s, &c, limit, &contact)
        } else {
            max_speed_scale(&ROCKY8, &s, &c, limit)
        }
        .and_then(|k2| {
            let k2 = k2.min(1.0);
            let c2 = cmd(c.x_dot_m_s * k2, c.y_dot_m_s * k2, c.yaw_rate_rad_s * k2);
            let sol = if use_contact {
                inverse_kinematics_contact(&ROCKY8, &s, &c2, &contact)
            } else {
                inverse_kinematics(&ROCKY8, &s, &c2)
            };
            sol.map(|sol| (sol, k2))
        });
        match (one, two) {
            (Ok((a, ka)), Ok((b, kb))) => {
                assert!((ka - kb).abs() <= 1e-12 * kb, "scale {ka} {kb}");
                let fastest = a
                    .command
                    .wheel_rate_rad_s
                    .iter()
                    .fold(0.0_f64, |m, r| m.max(r.abs()));
                if ka < 1.0 {
                    scaled += 1;
                    assert!((fastest - limit).abs() < 1e-12 * limit);
                } else {
                    unscaled += 1;
                    assert!(fastest <= limit);
                    let direct = if use_contact {
                        inverse_kinematics_contact(&ROCKY8, &s, &c, &contact)
                    } else {
                        inverse_kinematics(&ROCKY8, &s, &c)
                    };
                    assert_eq!(bits(&Ok(a)), bits(&direct));
                }
                let pairs = a
                    .command
                    .steer_angle_rad
                    .iter()
                    .zip(b.command.steer_angle_rad.iter())
                    .chain(
                        a.command
                            .wheel_rate_rad_s
                            .iter()
                            .zip(b.command.wheel_rate_rad_s.iter()),
                    )
                    .chain(a.body_rates.iter().zip(b.body_rates.iter()))
                    .chain(core::iter::once((
                        &a.suspension_rates.rocker_rad_s,
                        &b.suspension_rates.rocker_rad_s,
                    )))
                    .chain(
                        a.suspension_rates
                            .bogie_rad_s
                            .iter()
                            .zip(b.suspension_rates.bogie_rad_s.iter()),
                    );
                for (x, y) in pairs {
                    worst = worst.max((x - y).abs() / y.abs().max(1.0));
                }
            }
            (one, two) => assert_eq!(one.map(|_| ()), two.map(|_| ()), "case {k}"),
        }
    }
    println!(
        "one solve vs two: {scaled} scaled, {unscaled} unscaled, largest difference {worst:.2e}"
    );
    assert!(
        scaled > 500 && unscaled > 1000,
        "{scaled} scaled, {unscaled} unscaled"
    );
    assert!(worst < 1e-12, "largest difference {worst}");
    for bad in [f64::NAN, 0.0, -1.0, f64::INFINITY] {
        assert_eq!(
            inverse::inverse_kinematics_scaled(&ROCKY8, &level(), &cmd(0.1, 0.0, 0.0), None, bad),
            Err(KinematicsError::NonFinite)
        );
    }
}
