//! Inverse kinematics (H04 eq. 16-25): a command `[x_dot, y_dot, phi_dot]` in the rover frame
//! to six steering angles and six wheel rates.
//!
//! Steps (see `docs/kinematics.md` for the derivation):
//! 1. Instantaneous centre of rotation (eq. 16-19), reported in [`InverseSolution::icr`].
//! 2. Eq. 23-25 split each wheel's rows into actuated (`theta_dot_i`, and the steering
//!    direction) and unactuated parts. The only rows no wheel actuator can change are the
//!    components along each steering axis `s_i` (the rolling direction is always normal to
//!    `s_i`). The six unactuated rates `[z_dot, roll, pitch, beta_dot, rho_1_dot, rho_2_dot]`
//!    shared by all wheels are solved from these six rows together (one 6x6 Gaussian
//!    elimination with partial pivoting, the bogie rates first so that the rows of the other
//!    wheels are skipped: `eliminate`): the rover moves as a rigid body whose contacts do not
//!    move along their steering axes. On level ground they are all zero.
//! 3. Each wheel's required contact velocity `w_i` is then normal to `s_i`: the steering angle
//!    is its direction (eq. 21-22: `w_i` is perpendicular to the line from the wheel to the ICR)
//!    and the wheel rate is `|w_i| / r` (eq. 24: the actuated inverse reduces to a dot product
//!    because `x_Ci` is a unit vector normal to `s_i`).
//! 4. Steering wrap: of `psi` and `psi +- pi` (the wheel rate flipped), the angle within the
//!    steering limits closest to the current steering angle.
//!
//! Rough terrain ([`inverse_kinematics_contact`], [`max_speed_scale_contact`]; Tarokh and
//! McDermott, "Kinematics modeling and analyses of articulated rovers", IEEE T-RO 21(4) 2005;
//! Iagnemma and Dubowsky 2004): each wheel `i` touches the ground at the contact angle
//! `delta_i` in its wheel plane ([`super::contact`] for the frames and the sign). Its
//! unactuated row is the component along the contact normal
//! `n_i = cos(delta) z_Ci - sin(delta) x_Ci` of the chain's velocity at the contact point
//! `c_i(delta)` (the contact neither lifts off nor sinks), and its wheel rate is that
//! velocity's component along the tangent `t_i(delta) = cos(delta) x_Ci + sin(delta) z_Ci`
//! over `r` (equivalently: the axle's speed along the tangent over `r`, minus the chain's
//! rotation about the spin axis). `x_Ci` is taken at the current steering angle. At
//! `delta_i = 0` a wheel's rows are the ones above, computed by the same operations (bit for
//! bit). Derivation in `docs/kinematics.md`.

use super::geometry::{check_suspension, wheel_frames_trusted, RoverGeometry, WheelFrames};
use super::{BodyRates, KinematicsError, SuspensionRates, SuspensionState};
use crate::types::Vec3;
use rover_hal::{MobilityCommand, WHEEL_COUNT};

const PI: f64 = core::f64::consts::PI;
/// Below this yaw rate (rad/s) the ICR is reported in polar form (eq. 18-19).
const YAW_RATE_EPS_RAD_S: f64 = 1e-9;
/// Below this contact speed (m/s) a wheel sits at the ICR: it keeps its steering, rate 0.
const WHEEL_SPEED_EPS_M_S: f64 = 1e-9;

/// Commanded rover motion in the rover frame `R` (H04 `[x_dot y_dot phi_dot]_cmd`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VehicleCommand {
    /// Forward speed, m/s.
    pub x_dot_m_s: f64,
    /// Rightward speed, m/s.
    pub y_dot_m_s: f64,
    /// Yaw rate about `+z_R` (down; positive turns right), rad/s.
    pub yaw_rate_rad_s: f64,
}

/// Instantaneous centre of rotation in the rover frame (eq. 16-19).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Icr {
    /// Finite centre `[x_O, y_O]` in `R`, m (eq. 16-17).
    Point {
        /// `x_O = -y_dot / phi_dot`, m.
        x_m: f64,
        /// `y_O = x_dot / phi_dot`, m.
        y_m: f64,
    },
    /// Centre at infinity (pure crab or straight driving): `theta_O = -atan2(y_dot, x_dot)`,
    /// `r_O = inf` (eq. 18-19).
    Direction {
        /// `theta_O`, rad.
        theta_o_rad: f64,
    },
    /// Zero command: no centre.
    Stationary,
}

/// Eq. 16-19 (H04): the instantaneous centre of rotation of a command. Eq. 16 is printed as
/// `x_O = y_dot / phi_dot`; for a rigid body turning about `+z` the centre is at
/// `x_O = -y_dot / phi_dot` (see `docs/kinematics.md`). Eq. 18 uses `atan2` so that reverse
/// driving keeps its direction. Error: non-finite command.
pub fn instantaneous_centre(cmd: &VehicleCommand) -> Result<Icr, KinematicsError> {
    let VehicleCommand {
        x_dot_m_s: vx,
        y_dot_m_s: vy,
        yaw_rate_rad_s: wz,
    } = *cmd;
    if !(vx.is_finite() && vy.is_finite() && wz.is_finite()) {
        return Err(KinematicsError::NonFinite);
    }
    if libm::fabs(wz) > YAW_RATE_EPS_RAD_S {
        let (x_m, y_m) = (-vy / wz, vx / wz);
        if x_m.is_finite() && y_m.is_finite() {
            return Ok(Icr::Point { x_m, y_m });
        }
    }
    if vx == 0.0 && vy == 0.0 {
        if wz == 0.0 {
            return Ok(Icr::Stationary);
        }
        return Ok(Icr::Point { x_m: 0.0, y_m: 0.0 });
    }
    Ok(Icr::Direction {
        theta_o_rad: -libm::atan2(vy, vx),
    })
}

/// Result of inverse kinematics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InverseSolution {
    /// Steering angles (rad, positive right) and wheel rates (rad/s) for the motors.
    pub command: MobilityCommand,
    /// Full body rates `[x y z roll pitch yaw]` of the solution: the commanded `x, y, yaw` and
    /// the unactuated `z, roll, pitch` (m/s, rad/s, rover frame `R`).
    pub body_rates: BodyRates,
    /// Unactuated suspension rates of the solution, rad/s.
    pub suspension_rates: SuspensionRates,
}

impl InverseSolution {
    /// Instantaneous centre of rotation of the solution's command (eq. 16-19), computed on
    /// demand from the commanded `x_dot`, `y_dot` and yaw rate in [`Self::body_rates`] (the RG2
    /// inverse kinematics does not need it; it cost an `atan2` per call). Error: non-finite
    /// rates.
    pub fn icr(&self) -> Result<Icr, KinematicsError> {
        let b = &self.body_rates;
        instantaneous_centre(&VehicleCommand {
            x_dot_m_s: b[0],
            y_dot_m_s: b[1],
            yaw_rate_rad_s: b[5],
        })
    }
}

/// The wheel/terrain contact angles the rough-terrain inverse kinematics works with
/// ([`inverse_kinematics_contact`]): per wheel (index `wheel - 1`) the angle `delta_i` of the
/// contact in the wheel plane (rad, 0 below the axle, positive ahead of it: the frames and sign
/// of [`super::contact`], V99 sec. 6) with its sine and cosine, computed once by
/// [`ContactAngles::new`] (once per RG2 cycle).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactAngles {
    /// Bit `i` set: wheel `i` has a non-zero angle in use (compared first: telling a set of
    /// angles from [`Self::LEVEL`] reads one byte).
    used: u8,
    /// `sin delta` per wheel (0 for a wheel not in use).
    sin: [f64; WHEEL_COUNT],
    /// `cos delta` per wheel (1 for a wheel not in use).
    cos: [f64; WHEEL_COUNT],
}

impl ContactAngles {
    /// Every contact below its axle: the inverse kinematics of eq. 16-25 unchanged.
    pub const LEVEL: Self = ContactAngles {
        used: 0,
        sin: [0.0; WHEEL_COUNT],
        cos: [1.0; WHEEL_COUNT],
    };

    /// The contact angles `angles_rad` (rad, index `wheel - 1`). An angle that is not finite,
    /// or whose magnitude is at or above `max_angle_rad` (rad; an estimator at its clamp, or a
    /// wheel whose rate would grow by `1 / cos(delta)` beyond use), is taken as 0 for that
    /// wheel; a `max_angle_rad` that is not finite or not in `(0, pi/2)` takes every angle
    /// as 0. One `sincos` per angle in use.
    pub fn new(angles_rad: &[f64; WHEEL_COUNT], max_angle_rad: f64) -> Self {
        // Comparisons with NaN are false, and infinities fail the bounds.
        let max_ok = max_angle_rad > 0.0 && max_angle_rad < core::f64::consts::FRAC_PI_2;
        let mut out = Self::LEVEL;
        if !max_ok {
            return out;
        }
        let wheels = angles_rad
            .iter()
            .zip(out.sin.iter_mut().zip(out.cos.iter_mut()))
            .enumerate();
        for (i, (&d, (sin, cos))) in wheels {
            // Finite, non-zero and below the (finite) limit: NaN fails both comparisons.
            let m = d.abs();
            if m > 0.0 && m < max_angle_rad {
                (*sin, *cos) = libm::sincos(d);
                out.used |= 1 << i;
            }
        }
        out
    }

    /// The angles in use, rad (0 for the wheels that fell back to the level contact).
    pub fn angles_rad(&self) -> [f64; WHEEL_COUNT] {
        core::array::from_fn(|i| match self.sin_cos(i) {
            Some((s, c)) => libm::atan2(s, c),
            None => 0.0,
        })
    }

    /// `(sin delta, cos delta)` of wheel `i` (index `wheel - 1`), `None` for a wheel not in use.
    #[inline(always)]
    fn sin_cos(&self, i: usize) -> Option<(f64, f64)> {
        if self.used & (1 << (i & 7)) == 0 {
            return None;
        }
        Some((*self.sin.get(i)?, *self.cos.get(i)?))
    }
}

/// Where each wheel touches the ground, for [`solve`]: monomorphised so that the level case
/// ([`Level`]) compiles to the eq. 23-25 code without the contact-angle branches (the timing
/// budget).
trait ContactModel {
    /// The rows of one wheel kept between the two passes of [`solve`]: `()` for level
    /// contacts, `Option<ContactRow>` with contact angles.
    type Row;
    /// The rows of wheel `i` with frames `f` (zero steering), steering angle `psi` (rad) and
    /// wheel radius `radius` (m).
    fn row(&self, i: usize, f: &WheelFrames, psi: f64, radius: f64) -> Self::Row;
    /// The contact-angle rows in `row`, `None` for a contact below the axle.
    fn get(row: &Self::Row) -> Option<&ContactRow>;
}

/// Every contact below its axle.
struct Level;

impl ContactModel for Level {
    type Row = ();
    #[inline(always)]
    fn row(&self, _: usize, _: &WheelFrames, _: f64, _: f64) {}
    #[inline(always)]
    fn get(_: &()) -> Option<&ContactRow> {
        None
    }
}

impl ContactModel for ContactAngles {
    type Row = Option<ContactRow>;
    #[inline(always)]
    fn row(&self, i: usize, f: &WheelFrames, psi: f64, radius: f64) -> Option<ContactRow> {
        self.sin_cos(i).map(|sc| contact_row(f, psi, sc, radius))
    }
    #[inline(always)]
    fn get(row: &Option<ContactRow>) -> Option<&ContactRow> {
        row.as_ref()
    }
}

/// The rows of one wheel whose contact lies at an angle `delta` (module doc).
#[derive(Debug, Clone, Copy)]
struct ContactRow {
    /// Contact normal `n_i = cos(delta) z_C - sin(delta) x_C` in `R` (unit).
    normal: Vec3,
    /// Contact point `c_i(delta) = a_i - r n_i` in `R` (`a_i` the axle centre), m.
    point: Vec3,
    /// Velocity of the chain point at `c_i` per unit rocker rate, m/rad.
    d_rocker: Vec3,
    /// Velocity of the chain point at `c_i` per unit bogie rate, m/rad (not computed, zero,
    /// for a wheel without a bogie).
    d_bogie: Vec3,
    /// `z_C` (up, along the steering axis) in `R`.
    z_c: Vec3,
    /// `sin delta`.
    sin: f64,
    /// `cos delta`.
    cos: f64,
}

/// The rows of a wheel with frames `f` (at zero steering), current steering angle `psi` (rad)
/// and contact at `(sin delta, cos delta)`.
fn contact_row(f: &WheelFrames, psi: f64, (sd, cd): (f64, f64), radius: f64) -> ContactRow {
    // Rolling direction at the current steering: positive psi turns x0 towards y0 = s x x0.
    // The contact frame's z axis and origin (the axle centre) lie on the steering axis and do
    // not turn with psi (checked in KIN-11). `sincos(0)` is `(0, 1)` exactly: a wheel steered
    // straight skips the call.
    let (sp, cp) = if psi == 0.0 {
        (0.0, 1.0)
    } else {
        libm::sincos(psi)
    };
    let x0 = f.rolling_dir;
    let x_c = x0 * cp + f.steer_axis.cross(&x0) * sp;
    let z_c = f.contact.z_axis();
    let normal = z_c * cd - x_c * sd;
    // `a + r (sin(delta) x_C - cos(delta) z_C)`: the bracket is `-n` exactly (IEEE negation
    // commutes with rounding).
    let point = f.contact.pos - normal * radius;
    let lever = point - f.contact_point_m;
    let d_bogie = match f.bogie {
        Some(_) => f.d_contact_d_bogie + f.bogie_axis.cross(&lever),
        None => Vec3::zeros(),
    };
    ContactRow {
        normal,
        point,
        d_rocker: f.d_contact_d_rocker + f.rocker_axis.cross(&lever),
        d_bogie,
        z_c,
        sin: sd,
        cos: cd,
    }
}

/// Column of the right-hand side in a row of the unactuated system
/// `A [rho1_dot rho2_dot z_dot roll pitch beta_dot]^T = rhs` ([`unactuated_row`]). The bogie
/// rates come first: each appears only in the rows of its own wheels, so Gaussian elimination
/// with partial pivoting in this column order finds exact zeros below its first two pivots and
/// skips those rows ([`eliminate`]); the last four columns are full.
const RHS: usize = 6;

/// One row of the unactuated system of the wheel with frames `f` and, with a contact angle, rows
/// `c`: `s . (v_cmd + w_cmd x p + M u) = 0` (eq. 23-25, module doc) with the unactuated
/// direction `s` (steering axis, or contact normal), the point `p` (contact point, m) and the
/// chain velocities per joint rate at `p` (m/rad). The products with the zero components of the
/// unit vectors and of `v_cmd = [x_dot y_dot 0]`, `w_cmd = [0 0 phi_dot]` are left out:
/// `s . (x x p) = s_z p_y - s_y p_z`, `s . (y x p) = s_x p_z - s_z p_x`.
#[inline(always)]
fn unactuated_row(f: &WheelFrames, c: Option<&ContactRow>, cmd: &VehicleCommand) -> [f64; 7] {
    let (s, p, d_rocker, d_bogie) = match c {
        None => (
            &f.steer_axis,
            &f.contact_point_m,
            &f.d_contact_d_rocker,
            &f.d_contact_d_bogie,
        ),
        Some(c) => (&c.normal, &c.point, &c.d_rocker, &c.d_bogie),
    };
    let (rho1, rho2) = match f.bogie {
        Some(1) => (0.0, s.dot(d_bogie)),
        Some(_) => (s.dot(d_bogie), 0.0),
        None => (0.0, 0.0),
    };
    let wz = cmd.yaw_rate_rad_s;
    [
        rho1,
        rho2,
        s.z,
        s.z * p.y - s.y * p.z,
        s.x * p.z - s.z * p.x,
        s.dot(d_rocker),
        -(s.x * (cmd.x_dot_m_s - wz * p.y) + s.y * (cmd.y_dot_m_s + wz * p.x)),
    ]
}

/// The body and suspension motion of a solution: body velocity `v` (m/s) and angular velocity
/// `w` (rad/s) in `R`, rocker and bogie rates (rad/s).
struct Motion {
    v: Vec3,
    w: Vec3,
    beta: f64,
    rho: [f64; 2],
}

/// Steering angle (rad) and wheel rate (rad/s) of the wheel with frames `f`, contact-angle rows
/// `c`, current steering angle `current` (rad) for the motion `m` (eq. 21-22, 24 and the
/// steering wrap; module doc). Errors: [`KinematicsError::NonFinite`] for a non-finite contact
/// velocity, [`KinematicsError::SteeringLimit`] (wheel index 0, the caller sets it) when no
/// steering candidate lies within `limit` (rad).
#[inline(always)]
fn wheel_command(
    f: &WheelFrames,
    c: Option<&ContactRow>,
    current: f64,
    m: &Motion,
    limit: f64,
    radius: f64,
) -> Result<(f64, f64), KinematicsError> {
    let (p, d_rocker) = match c {
        None => (&f.contact_point_m, &f.d_contact_d_rocker),
        Some(c) => (&c.point, &c.d_rocker),
    };
    let contact_v = m.v + m.w.cross(p) + d_rocker * m.beta;
    let contact_v = match (f.bogie, c) {
        (Some(k), None) => contact_v + f.d_contact_d_bogie * m.rho[usize::from(k == 1)],
        (Some(k), Some(c)) => contact_v + c.d_bogie * m.rho[usize::from(k == 1)],
        (None, _) => contact_v,
    };
    let x0 = f.rolling_dir;
    let y0 = f.steer_axis.cross(&x0);
    let (a, b) = (contact_v.dot(&x0), contact_v.dot(&y0));
    let speed = crate::linalg::sqrt(a * a + b * b);
    if !speed.is_finite() {
        return Err(KinematicsError::NonFinite);
    }
    if speed <= WHEEL_SPEED_EPS_M_S {
        return Ok((current, 0.0));
    }
    // For `a > 0`, `atan2(b, a)` is `atan(b / a)` bit for bit (libm's `atan2` takes that
    // branch and `atan` is odd; KIN-12 checks it): one call less.
    let raw = if a > 0.0 {
        libm::atan(b / a)
    } else {
        libm::atan2(b, a)
    };
    // Rim speed along the tangent t = cos(delta) x_C + sin(delta) z_C, with x_C along (+) or
    // against (-) the contact's horizontal velocity; at delta = 0 `+-speed`.
    let (forward, backward) = match c {
        None => {
            let rate = speed / radius;
            (rate, -rate)
        }
        Some(c) => {
            let climb = contact_v.dot(&c.z_c) * c.sin;
            let along = speed * c.cos;
            ((along + climb) / radius, (climb - along) / radius)
        }
    };
    let candidates = [(raw, forward), (raw - PI, backward), (raw + PI, backward)];
    let mut best: Option<(f64, f64)> = None;
    for (psi, r) in candidates {
        let better = match best {
            None => true,
            Some((b_psi, _)) => libm::fabs(psi - current) < libm::fabs(b_psi - current),
        };
        if libm::fabs(psi) <= limit && better {
            best = Some((psi, r));
        }
    }
    best.ok_or(KinematicsError::SteeringLimit { wheel: 0 })
}

/// Solves the 6x6 system `a` (right-hand side in column [`RHS`]) in place by Gaussian
/// elimination with partial pivoting (largest magnitude, first on ties), skipping the rows whose
/// multiplier is exactly zero (below the pivots of the two bogie columns that come first, see
/// [`RHS`]): about 40 multiply-subtracts instead of about 110. `None` when a pivot is zero or not
/// finite, or the solution is not finite. The unknowns come back in the column order
/// `[rho1_dot rho2_dot z_dot roll pitch beta_dot]`.
fn eliminate(a: &mut [[f64; 7]; 6]) -> Option<[f64; 6]> {
    // One step per column, each with its column as a constant: the loops below unroll fully.
    pivot_step::<0>(a)?;
    pivot_step::<1>(a)?;
    pivot_step::<2>(a)?;
    pivot_step::<3>(a)?;
    pivot_step::<4>(a)?;
    pivot_step::<5>(a)?;
    let [r0, r1, r2, r3, r4, r5] = a;
    let u5 = r5[RHS] / r5[5];
    let u4 = (r4[RHS] - r4[5] * u5) / r4[4];
    let u3 = (r3[RHS] - r3[4] * u4 - r3[5] * u5) / r3[3];
    let u2 = (r2[RHS] - r2[3] * u3 - r2[4] * u4 - r2[5] * u5) / r2[2];
    let u1 = (r1[RHS] - r1[2] * u2 - r1[3] * u3 - r1[4] * u4 - r1[5] * u5) / r1[1];
    let u0 = (r0[RHS] - r0[1] * u1 - r0[2] * u2 - r0[3] * u3 - r0[4] * u4 - r0[5] * u5) / r0[0];
    let u = [u0, u1, u2, u3, u4, u5];
    u.iter().all(|x| x.is_finite()).then_some(u)
}

/// Step `K` of [`eliminate`]: the pivot of column `K` (rows `K..6`) swapped into row `K`, and
/// column `K` eliminated from the rows below (only columns `K+1..7` are updated; column `K`
/// below the pivot is not read again). `None` for a zero or non-finite pivot.
// A constant index range over a fixed-size array: the optimiser proves it in bounds and
// unrolls it.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn pivot_step<const K: usize>(a: &mut [[f64; 7]; 6]) -> Option<()> {
    let (head, tail) = a.split_at_mut(K + 1);
    let pivot = head.last_mut()?;
    // `f64::abs` (exact, as `libm::fabs`) compiles to the FPU's `vabs`.
    let mut best_abs = pivot.get(K)?.abs();
    let mut best: Option<&mut [f64; 7]> = None;
    for row in tail.iter_mut() {
        let v = row.get(K)?.abs();
        if v > best_abs {
            best_abs = v;
            best = Some(row);
        }
    }
    if !(best_abs > 0.0 && best_abs.is_finite()) {
        return None;
    }
    if let Some(row) = best {
        core::mem::swap(pivot, row);
    }
    let inv = 1.0 / *pivot.get(K)?;
    for row in tail.iter_mut() {
        let f = *row.get(K)? * inv;
        if f != 0.0 {
            for c in (K + 1)..7 {
                row[c] -= f * pivot[c];
            }
        }
    }
    Some(())
}

/// Eq. 16-25 with the contacts at `contact` (module doc): the steering limit applies, and with
/// `rate_check` the drive limit too ([`KinematicsError::WheelRateLimit`] for a wheel rate above
/// it, with a relative tolerance of 1e-9 so that a command scaled by [`max_speed_scale`] to the
/// limit passes). The six wheels are written out one by one, and the solution is checked in
/// place (no per-wheel arrays to clear, no copies of the solution: the timing
/// budget).
fn solve<C: ContactModel>(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    cmd: &VehicleCommand,
    contact: &C,
    rate_check: bool,
) -> Result<InverseSolution, KinematicsError> {
    let finite_cmd =
        cmd.x_dot_m_s.is_finite() && cmd.y_dot_m_s.is_finite() && cmd.yaw_rate_rad_s.is_finite();
    if !finite_cmd {
        return Err(KinematicsError::NonFinite);
    }
    check_suspension(geometry, state)?;
    // Contact points and axes do not depend on steering; `x0` is the rolling direction at
    // `psi = 0` and `y0 = s x x0` the direction a positive `psi` turns it towards.
    let level_steer = SuspensionState {
        steer_rad: [0.0; WHEEL_COUNT],
        ..*state
    };
    let frames = wheel_frames_trusted(geometry, &level_steer);
    let radius = geometry.wheel_radius_m;
    let [f0, f1, f2, f3, f4, f5] = &frames;
    let [q0, q1, q2, q3, q4, q5] = state.steer_rad;
    let c0 = contact.row(0, f0, q0, radius);
    let c1 = contact.row(1, f1, q1, radius);
    let c2 = contact.row(2, f2, q2, radius);
    let c3 = contact.row(3, f3, q3, radius);
    let c4 = contact.row(4, f4, q4, radius);
    let c5 = contact.row(5, f5, q5, radius);
    // Unactuated rows: s_i . (w_cmd_i + M_i u) = 0 (with a contact angle: n_i at the contact
    // point c_i).
    let mut a = [
        unactuated_row(f0, C::get(&c0), cmd),
        unactuated_row(f1, C::get(&c1), cmd),
        unactuated_row(f2, C::get(&c2), cmd),
        unactuated_row(f3, C::get(&c3), cmd),
        unactuated_row(f4, C::get(&c4), cmd),
        unactuated_row(f5, C::get(&c5), cmd),
    ];
    let [rho1, rho2, z_dot, roll, pitch, beta] =
        eliminate(&mut a).ok_or(KinematicsError::Singular)?;
    let m = Motion {
        v: Vec3::new(cmd.x_dot_m_s, cmd.y_dot_m_s, z_dot),
        w: Vec3::new(roll, pitch, cmd.yaw_rate_rad_s),
        beta,
        rho: [rho1, rho2],
    };
    let limit = geometry.limits.steer_rad;
    let wheel = |k: u8, r: Result<(f64, f64), KinematicsError>| {
        r.map_err(|e| match e {
            KinematicsError::SteeringLimit { .. } => KinematicsError::SteeringLimit { wheel: k },
            e => e,
        })
    };
    let w0 = wheel(0, wheel_command(f0, C::get(&c0), q0, &m, limit, radius))?;
    let w1 = wheel(1, wheel_command(f1, C::get(&c1), q1, &m, limit, radius))?;
    let w2 = wheel(2, wheel_command(f2, C::get(&c2), q2, &m, limit, radius))?;
    let w3 = wheel(3, wheel_command(f3, C::get(&c3), q3, &m, limit, radius))?;
    let w4 = wheel(4, wheel_command(f4, C::get(&c4), q4, &m, limit, radius))?;
    let w5 = wheel(5, wheel_command(f5, C::get(&c5), q5, &m, limit, radius))?;
    let wheel_rate_rad_s = [w0.1, w1.1, w2.1, w3.1, w4.1, w5.1];
    if rate_check {
        let rate_limit = geometry.limits.wheel_rate_rad_s * (1.0 + 1e-9);
        for (i, rate) in wheel_rate_rad_s.iter().enumerate() {
            if libm::fabs(*rate) > rate_limit {
                return Err(KinematicsError::WheelRateLimit { wheel: i as u8 });
            }
        }
    }
    Ok(InverseSolution {
        command: MobilityCommand {
            steer_angle_rad: [w0.0, w1.0, w2.0, w3.0, w4.0, w5.0],
            wheel_rate_rad_s,
        },
        body_rates: BodyRates::new(m.v.x, m.v.y, m.v.z, m.w.x, m.w.y, m.w.z),
        suspension_rates: SuspensionRates {
            rocker_rad_s: beta,
            bogie_rad_s: [rho1, rho2],
        },
    })
}

/// Eq. 16-25 (H04): steering angles (rad, positive right, within the steering limits, wrapped
/// to the least steering motion from `state.steer_rad`) and wheel rates (rad/s) that realise
/// `cmd` (rover frame `R`) at the suspension state `state`. Errors: non-finite input, angles
/// out of range, a singular geometry, a wheel that cannot steer to its direction
/// ([`KinematicsError::SteeringLimit`]) or a wheel rate above the drive limit
/// ([`KinematicsError::WheelRateLimit`]; scale the command with [`max_speed_scale`]).
pub fn inverse_kinematics(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    cmd: &VehicleCommand,
) -> Result<InverseSolution, KinematicsError> {
    solve(geometry, state, cmd, &Level, true)
}

/// Rough-terrain inverse kinematics (Tarokh and McDermott 2005; module doc): as
/// [`inverse_kinematics`] (frames, units and errors the same), with each wheel touching the
/// ground at its contact angle in `contact` (rad, [`ContactAngles`]; the angles the odometry
/// estimates, V99 sec. 6). Per wheel the unactuated row is the contact normal `n_i` at the
/// contact point `c_i` instead of the steering axis, and the wheel rate is the chain's velocity
/// at `c_i` along the contact tangent `t_i` over `r` (`docs/kinematics.md`, "Rough-terrain
/// inverse kinematics"); the steering angle keeps the velocity's component along the spin axis
/// at zero. A wheel at angle 0 gives exactly (bit for bit) the rows of [`inverse_kinematics`];
/// [`ContactAngles::LEVEL`] is [`inverse_kinematics`].
pub fn inverse_kinematics_contact(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    cmd: &VehicleCommand,
    contact: &ContactAngles,
) -> Result<InverseSolution, KinematicsError> {
    solve(geometry, state, cmd, contact, true)
}

/// The largest factor `k` such that the command `k * cmd` keeps every wheel rate at or below
/// `max_wheel_rate_rad_s` (wheel rates are linear in the command at a fixed suspension state;
/// the steering angles do not change with `k > 0`). Returns `f64::INFINITY` when `cmd` needs no
/// wheel motion. Errors: as [`inverse_kinematics`] (without the rate limit), and
/// [`KinematicsError::NonFinite`] for a non-finite or non-positive `max_wheel_rate_rad_s`.
pub fn max_speed_scale(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    cmd: &VehicleCommand,
    max_wheel_rate_rad_s: f64,
) -> Result<f64, KinematicsError> {
    if !(max_wheel_rate_rad_s.is_finite() && max_wheel_rate_rad_s > 0.0) {
        return Err(KinematicsError::NonFinite);
    }
    let solution = solve(geometry, state, cmd, &Level, false)?;
    Ok(scale_of(&solution, max_wheel_rate_rad_s))
}

/// [`max_speed_scale`] for the rough-terrain inverse kinematics with the contact angles
/// `contact` ([`inverse_kinematics_contact`]; the wheel rates are still linear in the command).
pub fn max_speed_scale_contact(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    cmd: &VehicleCommand,
    max_wheel_rate_rad_s: f64,
    contact: &ContactAngles,
) -> Result<f64, KinematicsError> {
    if !(max_wheel_rate_rad_s.is_finite() && max_wheel_rate_rad_s > 0.0) {
        return Err(KinematicsError::NonFinite);
    }
    let solution = solve(geometry, state, cmd, contact, false)?;
    Ok(scale_of(&solution, max_wheel_rate_rad_s))
}

/// Inverse kinematics scaled to the drive limit in one solve (the timing budget: the navigator's
/// [`max_speed_scale_contact`] then [`inverse_kinematics_contact`] on the scaled command is two
/// solves per RG2 cycle). With `contact` the rough-terrain inverse kinematics
/// ([`inverse_kinematics_contact`]), with `None` eq. 16-25 ([`inverse_kinematics`]); frames,
/// units and errors as there, and [`KinematicsError::NonFinite`] for a non-finite or
/// non-positive `max_wheel_rate_rad_s` (rad/s).
///
/// Returns the solution for `k * cmd` and `k = min(1, max_wheel_rate_rad_s / fastest wheel
/// rate)` (1 when no wheel turns): at a fixed suspension state the wheel rates, body rates and
/// suspension rates are linear in the command and the steering angles do not change for
/// `k > 0` (see [`max_speed_scale`]), so the solution for `cmd` is solved once and its rates are
/// multiplied by `k`. It differs from solving `k * cmd` again only by rounding (about 1e-15
/// relative, KIN-12), with one exception: a wheel whose contact speed falls below 1e-9 m/s only
/// through the scaling keeps the direction of `cmd` (with a rate below 1e-8 rad/s) instead of
/// its current steering angle. The fastest wheel ends at the limit to rounding; no rate check
/// follows.
pub fn inverse_kinematics_scaled(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    cmd: &VehicleCommand,
    contact: Option<&ContactAngles>,
    max_wheel_rate_rad_s: f64,
) -> Result<(InverseSolution, f64), KinematicsError> {
    if !(max_wheel_rate_rad_s.is_finite() && max_wheel_rate_rad_s > 0.0) {
        return Err(KinematicsError::NonFinite);
    }
    let mut solution = match contact {
        Some(c) => solve(geometry, state, cmd, c, false)?,
        None => solve(geometry, state, cmd, &Level, false)?,
    };
    let k = scale_of(&solution, max_wheel_rate_rad_s);
    if k >= 1.0 {
        return Ok((solution, 1.0));
    }
    for rate in solution.command.wheel_rate_rad_s.iter_mut() {
        *rate *= k;
    }
    solution.body_rates *= k;
    solution.suspension_rates.rocker_rad_s *= k;
    for rate in solution.suspension_rates.bogie_rad_s.iter_mut() {
        *rate *= k;
    }
    Ok((solution, k))
}

/// `max_wheel_rate_rad_s` over the solution's fastest wheel rate (infinite for none).
fn scale_of(solution: &InverseSolution, max_wheel_rate_rad_s: f64) -> f64 {
    let fastest = solution
        .command
        .wheel_rate_rad_s
        .iter()
        .fold(0.0_f64, |m, r| m.max(libm::fabs(*r)));
    if fastest <= 0.0 {
        return f64::INFINITY;
    }
    max_wheel_rate_rad_s / fastest
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::{Mat6, Vec6};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// KIN-12: [`eliminate`] (bogie columns first, zero multipliers skipped) solves the systems
    /// of the unactuated rows as `linalg::solve6` (the 6x6 elimination it replaced) does, to
    /// rounding: relative residual below 1e-12 and agreement below 1e-10 relative over random
    /// systems with the bogie pattern (two rows per bogie column) and dense ones; refuses a
    /// zero column, a non-finite entry and dependent rows.
    #[test]
    fn kin_12_eliminate_matches_solve6() {
        let mut rng = ChaCha8Rng::seed_from_u64(124);
        let mut worst_residual: f64 = 0.0;
        let mut worst_diff: f64 = 0.0;
        for k in 0..5000 {
            let mut a = [[0.0; 7]; 6];
            for (r, row) in a.iter_mut().enumerate() {
                for (c, x) in row.iter_mut().enumerate() {
                    *x = rng.random_range(-1.0..1.0);
                    // Bogie pattern: rho1 in rows 0 and 2, rho2 in rows 1 and 3 (except in
                    // every fifth, dense, system).
                    let structural_zero =
                        (c == 0 && r != 0 && r != 2) || (c == 1 && r != 1 && r != 3);
                    if k % 5 != 0 && structural_zero {
                        *x = 0.0;
                    }
                }
            }
            // The reference's column order: [z roll pitch beta rho1 rho2].
            let m = Mat6::from_fn(|r, c| a[r][(c + 2) % 6]);
            let rhs = Vec6::from_fn(|r, _| a[r][RHS]);
            let Some(old) = crate::linalg::solve6(&m, &rhs) else {
                continue;
            };
            let mut work = a;
            let u = eliminate(&mut work).unwrap();
            let new = Vec6::from_fn(|c, _| u[(c + 2) % 6]);
            let scale = old.amax().max(1.0);
            worst_diff = worst_diff.max((new - old).amax() / scale);
            let residual = (m * new - rhs).amax() / (m.amax() * new.amax() + rhs.amax());
            worst_residual = worst_residual.max(residual);
        }
        println!("eliminate vs solve6: residual {worst_residual:.2e}, difference {worst_diff:.2e}");
        assert!(worst_residual < 1e-12, "residual {worst_residual}");
        assert!(worst_diff < 1e-10, "difference {worst_diff}");
        let mut zero_col = [[1.0, 0.0, 2.0, 3.0, 4.0, 5.0, 1.0]; 6];
        for (r, row) in zero_col.iter_mut().enumerate() {
            row[2 + r % 4] += 1.0 + r as f64;
        }
        assert_eq!(eliminate(&mut zero_col.clone()), None);
        let mut nan = good_system();
        nan[3][4] = f64::NAN;
        assert_eq!(eliminate(&mut nan), None);
        // Two equal rows.
        let mut dependent = good_system();
        dependent[5] = dependent[1];
        assert_eq!(eliminate(&mut dependent), None);
        assert!(eliminate(&mut good_system()).is_some());
    }

    /// A regular system: 2 on the diagonal, 0.5 elsewhere.
    fn good_system() -> [[f64; 7]; 6] {
        let mut a = [[0.5; 7]; 6];
        for (r, row) in a.iter_mut().enumerate() {
            row[r] = 2.0;
        }
        a
    }

    /// KIN-12: for `a > 0` libm's `atan(b / a)` is `atan2(b, a)` bit for bit (the steering angle
    /// without the `atan2` call), over random ratios from 1e-30 to 1e30, both signs, zeros and
    /// the `a = 1` and huge-ratio branches of `atan2`.
    #[test]
    fn kin_12_atan_of_ratio_is_atan2_for_positive_a() {
        let mut rng = ChaCha8Rng::seed_from_u64(125);
        let mut cases = 0;
        for _ in 0..200_000 {
            let a = libm::pow(10.0, rng.random_range(-12.0..12.0));
            let ratio = libm::pow(10.0, rng.random_range(-30.0..30.0));
            let b = if rng.random_bool(0.5) {
                a * ratio
            } else {
                -a * ratio
            };
            assert_eq!(
                libm::atan(b / a).to_bits(),
                libm::atan2(b, a).to_bits(),
                "{b} {a}"
            );
            cases += 1;
        }
        for (b, a) in [
            (0.0, 1.0),
            (-0.0, 1.0),
            (0.3, 1.0),
            (-0.3, 1.0),
            (1e300, 1e-10),
            (-1e300, 1e-10),
            (1e-300, 1e10),
            (f64::MAX, 1.0),
            (1.0, f64::MIN_POSITIVE),
        ] {
            assert_eq!(
                libm::atan(b / a).to_bits(),
                libm::atan2(b, a).to_bits(),
                "{b} {a}"
            );
        }
        assert_eq!(cases, 200_000);
    }
}
