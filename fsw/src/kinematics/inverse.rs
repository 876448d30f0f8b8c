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

use super::geometry::{check_suspension, wheel_frames_trusted, RoverGeometry};
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

/// Eq. 16-25 without the wheel-rate limit (the steering limit applies).
fn solve(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    cmd: &VehicleCommand,
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
    // Unactuated rows: s_i . (w_cmd_i + M_i u) = 0, u = [z_dot roll pitch beta rho1 rho2].
    let mut m = Mat6::zeros();
    let mut rhs = Vec6::zeros();
    for (i, f) in frames.iter().enumerate() {
        let (s, p) = (f.steer_axis, f.contact_point_m);
        let bogie_col = match f.bogie {
            Some(1) => 5,
            Some(_) => 4,
            None => 3,
        };
        let cols = [
            s.z,
            s.dot(&Vec3::x().cross(&p)),
            s.dot(&Vec3::y().cross(&p)),
            s.dot(&f.d_contact_d_rocker),
        ];
        for (j, c) in cols.iter().enumerate() {
            m[(i, j)] = *c;
        }
        if bogie_col > 3 {
            m[(i, bogie_col)] = s.dot(&f.d_contact_d_bogie);
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
        let bogie_rate = match f.bogie {
            Some(1) => u[5],
            Some(_) => u[4],
            None => 0.0,
        };
        let p = f.contact_point_m;
        let contact_v =
            v + w.cross(&p) + f.d_contact_d_rocker * u[3] + f.d_contact_d_bogie * bogie_rate;
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
            let rate = speed / geometry.wheel_radius_m;
            let candidates = [(raw, rate), (raw - PI, -rate), (raw + PI, -rate)];
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
    let solution = solve(geometry, state, cmd)?;
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
    let solution = solve(geometry, state, cmd)?;
    let fastest = solution
        .command
        .wheel_rate_rad_s
        .iter()
        .fold(0.0_f64, |m, r| m.max(libm::fabs(*r)));
    if fastest <= 0.0 {
        return Ok(f64::INFINITY);
    }
    Ok(max_wheel_rate_rad_s / fastest)
}
