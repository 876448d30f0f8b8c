//! Inverse kinematics (H04 eq. 16-25): a command `[x_dot, y_dot, phi_dot]` in the rover frame
//! to six steering angles and six wheel rates.
//!
//! Steps (see `docs/kinematics.md` for the derivation):
//! 1. Instantaneous centre of rotation (eq. 16-19), reported in [`InverseSolution::icr`].
//! 2. Eq. 23-25 split each wheel's rows into actuated (`theta_dot_i`, and the steering
//!    direction) and unactuated parts. The only rows no wheel actuator can change are the
//!    components along each steering axis `s_i` (the rolling direction is always normal to
//!    `s_i`). The six unactuated rates `[z_dot, roll, pitch, beta_dot, rho_1_dot, rho_2_dot]`
//!    shared by all wheels are solved from these six rows together (one 6x6 LU solve): the rover
//!    moves as a rigid body whose contacts do not move along their steering axes. On level
//!    ground they are all zero.
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
use crate::types::{Mat6, Vec3, Vec6};
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
/// [`ContactAngles::new`] (once per RG2 cycle for both the speed scaling and the inverse).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactAngles {
    /// `Some((sin delta, cos delta))` for a wheel with a non-zero angle in use, `None` for a
    /// wheel whose contact is taken below its axle (angle 0).
    sin_cos: [Option<(f64, f64)>; WHEEL_COUNT],
}

impl ContactAngles {
    /// Every contact below its axle: the inverse kinematics of eq. 16-25 unchanged.
    pub const LEVEL: Self = ContactAngles {
        sin_cos: [None; WHEEL_COUNT],
    };

    /// The contact angles `angles_rad` (rad, index `wheel - 1`). An angle that is not finite,
    /// or whose magnitude is at or above `max_angle_rad` (rad; an estimator at its clamp, or a
    /// wheel whose rate would grow by `1 / cos(delta)` beyond use), is taken as 0 for that
    /// wheel; a `max_angle_rad` that is not finite or not in `(0, pi/2)` takes every angle
    /// as 0. Six `sin/cos` pairs.
    pub fn new(angles_rad: &[f64; WHEEL_COUNT], max_angle_rad: f64) -> Self {
        let max_ok = max_angle_rad.is_finite()
            && max_angle_rad > 0.0
            && max_angle_rad < core::f64::consts::FRAC_PI_2;
        if !max_ok {
            return Self::LEVEL;
        }
        ContactAngles {
            sin_cos: angles_rad.map(|d| {
                if d.is_finite() && d != 0.0 && libm::fabs(d) < max_angle_rad {
                    Some(libm::sincos(d))
                } else {
                    None
                }
            }),
        }
    }

    /// The angles in use, rad (0 for the wheels that fell back to the level contact).
    pub fn angles_rad(&self) -> [f64; WHEEL_COUNT] {
        self.sin_cos
            .map(|sc| sc.map_or(0.0, |(s, c)| libm::atan2(s, c)))
    }
}

/// Where each wheel touches the ground, for [`solve`]: monomorphised so that the level case
/// ([`Level`]) compiles to the eq. 23-25 code without the contact-angle branches (issue 18's
/// instruction budget).
trait ContactModel {
    /// The per-wheel rows of the wheels with a contact angle.
    type Rows;
    /// The rows for frames `frames` (zero steering), steering angles `steer_rad` (rad) and
    /// wheel radius `radius` (m).
    fn rows(
        &self,
        frames: &[WheelFrames; WHEEL_COUNT],
        steer_rad: &[f64; WHEEL_COUNT],
        radius: f64,
    ) -> Self::Rows;
    /// The rows of wheel `i`, `None` for a contact below the axle.
    fn row(rows: &Self::Rows, i: usize) -> Option<&ContactRow>;
}

/// Every contact below its axle.
struct Level;

impl ContactModel for Level {
    type Rows = ();
    #[inline(always)]
    fn rows(&self, _: &[WheelFrames; WHEEL_COUNT], _: &[f64; WHEEL_COUNT], _: f64) {}
    #[inline(always)]
    fn row(_: &(), _: usize) -> Option<&ContactRow> {
        None
    }
}

impl ContactModel for ContactAngles {
    type Rows = [Option<ContactRow>; WHEEL_COUNT];
    fn rows(
        &self,
        frames: &[WheelFrames; WHEEL_COUNT],
        steer_rad: &[f64; WHEEL_COUNT],
        radius: f64,
    ) -> Self::Rows {
        // `from_fn` only calls with `i < WHEEL_COUNT`, the length of the three arrays.
        core::array::from_fn(|i| {
            self.sin_cos[i].map(|sc| contact_row(&frames[i], steer_rad[i], sc, radius))
        })
    }
    #[inline]
    fn row(rows: &Self::Rows, i: usize) -> Option<&ContactRow> {
        rows.get(i).and_then(Option::as_ref)
    }
}

/// The rows of one wheel whose contact lies at an angle `delta` (module doc).
#[derive(Debug, Clone, Copy)]
struct ContactRow {
    /// Contact normal `n_i = cos(delta) z_C - sin(delta) x_C` in `R` (unit).
    normal: Vec3,
    /// Contact point `c_i(delta)` in `R`, m.
    point: Vec3,
    /// Velocity of the chain point at `c_i` per unit rocker rate, m/rad.
    d_rocker: Vec3,
    /// Velocity of the chain point at `c_i` per unit bogie rate, m/rad.
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
    // not turn with psi (checked in KIN-11).
    let (sp, cp) = libm::sincos(psi);
    let x0 = f.rolling_dir;
    let x_c = x0 * cp + f.steer_axis.cross(&x0) * sp;
    let z_c = f.contact.z_axis();
    let point = f.contact.pos + (x_c * sd - z_c * cd) * radius;
    let lever = point - f.contact_point_m;
    ContactRow {
        normal: z_c * cd - x_c * sd,
        point,
        d_rocker: f.d_contact_d_rocker + f.rocker_axis.cross(&lever),
        d_bogie: f.d_contact_d_bogie + f.bogie_axis.cross(&lever),
        z_c,
        sin: sd,
        cos: cd,
    }
}

/// Eq. 16-25 without the wheel-rate limit (the steering limit applies), with the contacts at
/// `contact` (module doc).
fn solve<C: ContactModel>(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    cmd: &VehicleCommand,
    contact: &C,
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
    let v_cmd = Vec3::new(cmd.x_dot_m_s, cmd.y_dot_m_s, 0.0);
    let w_cmd = Vec3::new(0.0, 0.0, cmd.yaw_rate_rad_s);
    let radius = geometry.wheel_radius_m;
    let rows = contact.rows(&frames, &state.steer_rad, radius);
    // Unactuated rows: s_i . (w_cmd_i + M_i u) = 0, u = [z_dot roll pitch beta rho1 rho2]
    // (with a contact angle: n_i at the contact point c_i).
    let mut m = Mat6::zeros();
    let mut rhs = Vec6::zeros();
    for (i, f) in frames.iter().enumerate() {
        let row = C::row(&rows, i);
        let (s, p, d_rocker, d_bogie) = match row {
            None => (
                f.steer_axis,
                f.contact_point_m,
                f.d_contact_d_rocker,
                f.d_contact_d_bogie,
            ),
            Some(c) => (c.normal, c.point, c.d_rocker, c.d_bogie),
        };
        let bogie_col = match f.bogie {
            Some(1) => 5,
            Some(_) => 4,
            None => 3,
        };
        let cols = [
            s.z,
            s.dot(&Vec3::x().cross(&p)),
            s.dot(&Vec3::y().cross(&p)),
            s.dot(&d_rocker),
        ];
        for (j, c) in cols.iter().enumerate() {
            m[(i, j)] = *c;
        }
        if bogie_col > 3 {
            m[(i, bogie_col)] = s.dot(&d_bogie);
        }
        rhs[i] = -s.dot(&(v_cmd + w_cmd.cross(&p)));
    }
    let u = crate::linalg::solve6(&m, &rhs).ok_or(KinematicsError::Singular)?;
    if u.iter().any(|x| !x.is_finite()) {
        return Err(KinematicsError::NonFinite);
    }
    let v = Vec3::new(cmd.x_dot_m_s, cmd.y_dot_m_s, u[0]);
    let w = Vec3::new(u[1], u[2], cmd.yaw_rate_rad_s);
    let suspension_rates = SuspensionRates {
        rocker_rad_s: u[3],
        bogie_rad_s: [u[4], u[5]],
    };
    let mut command = MobilityCommand::default();
    let limit = geometry.limits.steer_rad;
    for (i, f) in frames.iter().enumerate() {
        let row = C::row(&rows, i);
        let bogie_rate = match f.bogie {
            Some(1) => u[5],
            Some(_) => u[4],
            None => 0.0,
        };
        let contact_v = match row {
            None => {
                let p = f.contact_point_m;
                v + w.cross(&p) + f.d_contact_d_rocker * u[3] + f.d_contact_d_bogie * bogie_rate
            }
            Some(c) => v + w.cross(&c.point) + c.d_rocker * u[3] + c.d_bogie * bogie_rate,
        };
        let x0 = f.rolling_dir;
        let y0 = f.steer_axis.cross(&x0);
        let (a, b) = (contact_v.dot(&x0), contact_v.dot(&y0));
        let speed = libm::sqrt(a * a + b * b);
        if !speed.is_finite() {
            return Err(KinematicsError::NonFinite);
        }
        let current = state.steer_rad[i];
        let (psi, rate) = if speed <= WHEEL_SPEED_EPS_M_S {
            (current, 0.0)
        } else {
            let raw = libm::atan2(b, a);
            // Rim speed along the tangent t = cos(delta) x_C + sin(delta) z_C, with x_C along
            // (+) or against (-) the contact's horizontal velocity; at delta = 0 `+-speed`.
            let (forward, backward) = match row {
                None => {
                    let rate = speed / geometry.wheel_radius_m;
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
            best.ok_or(KinematicsError::SteeringLimit { wheel: i as u8 })?
        };
        command.steer_angle_rad[i] = psi;
        command.wheel_rate_rad_s[i] = rate;
    }
    Ok(InverseSolution {
        command,
        body_rates: BodyRates::new(v.x, v.y, v.z, w.x, w.y, w.z),
        suspension_rates,
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
    checked_rates(geometry, solve(geometry, state, cmd, &Level)?)
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
    checked_rates(geometry, solve(geometry, state, cmd, contact)?)
}

/// [`KinematicsError::WheelRateLimit`] for a solution with a wheel rate above the drive limit.
fn checked_rates(
    geometry: &RoverGeometry,
    solution: InverseSolution,
) -> Result<InverseSolution, KinematicsError> {
    // Relative tolerance so that a command scaled by `max_speed_scale` to the limit passes.
    let limit = geometry.limits.wheel_rate_rad_s * (1.0 + 1e-9);
    for (i, rate) in solution.command.wheel_rate_rad_s.iter().enumerate() {
        if libm::fabs(*rate) > limit {
            return Err(KinematicsError::WheelRateLimit { wheel: i as u8 });
        }
    }
    Ok(solution)
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
    let solution = solve(geometry, state, cmd, &Level)?;
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
    let solution = solve(geometry, state, cmd, contact)?;
    Ok(scale_of(&solution, max_wheel_rate_rad_s))
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
