//! Contact-angle kinematic estimation (Volpe et al. 1999 sec. 6, after J. Balaram, "Kinematic
//! state estimation for a Mars rover", Robotica, 1999; wheel-terrain contact angles as in
//! K. Iagnemma and S. Dubowsky, "Mobile Robots in Rough Terrain", Springer 2004).
//!
//! Eq. 15 (H04, [`super::forward`]) assumes each wheel touches the ground straight below its
//! axle (contact angle 0): the wheel rolls along `x_Ci`. On rough terrain the contact lies at an
//! angle `delta_i` in the wheel plane (a wheel climbing a rock touches it ahead of the axle) and
//! the wheel centre moves along the contact tangent. With `x_Ci` (rolling direction) and `z_Ci`
//! (up, along the steering axis) of the contact frame `C_i` in `R`, `a_i` the axle centre and `r`
//! the wheel radius:
//!
//! ```text
//! c_i(delta) = a_i + r (sin(delta) x_Ci - cos(delta) z_Ci)     contact point (c_i(0) = p_i)
//! t_i(delta) = cos(delta) x_Ci + sin(delta) z_Ci               contact tangent (unit)
//! ```
//!
//! `delta > 0`: contact ahead of the axle, the centre moves forward and up (along `-z_R` on level
//! ground, because `z_Ci` points up). The brief's `cos x_C - sin z_C` is the same tangent for a
//! downward `z`; the D-H contact frames of Table 2 have `z_Ci` up.
//!
//! Per valid wheel, for the step increments (drive `dtheta_i`, rocker/bogie `dq`, body
//! displacement `dp` and rotation `dphi` in `R` at the step start), no-slip rolling about the
//! contact at `delta_i` gives three equations (two in the wheel plane, one along the spin axis:
//! no lateral motion):
//!
//! ```text
//! e_i = dp + dphi x c_i + sum_q dq_q k_q x (c_i - o_q)  -  r dtheta_i t_i(delta_i)  =  0
//! ```
//!
//! i.e. the point of the wheel's chain (body and suspension) at the contact moves along the
//! tangent by the rim travel; `k_q`, `o_q` are the rocker/bogie axes and pivots
//! ([`WheelFrames::rocker_axis`]). This is the axle-centre equation "centre moves by
//! `r dtheta t_i`" plus the chain rotation times the lever `c_i - a_i` (the encoder measures the
//! wheel relative to its chain), so at `delta = 0` it is exactly eq. 15. Unknowns: `[dp; dphi]`
//! (or only `dp` when the gyro gives `dphi`) and the six `delta_i`. The cost
//!
//! ```text
//! sum_i |e_i|^2 + sum_i w_p (delta_i - delta_i,prev)^2 + w_0 delta_i^2,
//! w_p = (sigma_e / sigma_step)^2,  w_0 = (sigma_e / sigma_level)^2
//! ```
//!
//! (`sigma_level` 1 rad with the gyro, 0.1 rad without: [`ContactConfig`]).
//!
//! is minimised by Gauss-Newton iterations (two by default, at most three) from the previous
//! step's angles. The
//! normal matrix is block-arrow shaped (each `delta_i` only meets the body unknowns), so the
//! angles are eliminated per wheel and only a 6x6 (3x3 with the gyro) Schur complement is
//! factorised. The prior `w_p` keeps the angle of a wheel that barely turns; `w_0` is a weak
//! pull toward 0 that bounds the one direction the kinematics cannot see (all angles rotated
//! together with a body heave along `z_R`, e.g. on level ground). Wheels with
//! `|dtheta_i| < min_drive_increment_rad` keep their angle; angles are clamped to
//! `+-max_angle_rad`.

use super::forward::{contact_velocities, finite_joint_inputs, ContactLeastSquares};
use super::geometry::{check_suspension, wheel_frames_trusted, RoverGeometry, WheelFrames};
use super::jacobian::WheelJacobian;
use super::{KinematicsError, SuspensionRates, SuspensionState};
use crate::types::{Mat3, Mat6, Vec3, Vec6};
use nalgebra::SMatrix;
use rover_hal::WHEEL_COUNT;

/// Largest number of Gauss-Newton iterations per step (CPU bound, RG2).
pub const MAX_CONTACT_ITERATIONS: u8 = 3;

/// Tuning of the contact-angle estimator (all per joint-reading step).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactConfig {
    /// Standard deviation `sigma_e` of each component of the rolling equation `e_i`, m
    /// (encoder quantisation times the radius, plus model error). Only ratios to it matter.
    pub residual_sigma_m: f64,
    /// Random-walk standard deviation `sigma_step` of each contact angle per step, rad (the
    /// prior toward the previous angle).
    pub step_sigma_rad: f64,
    /// Standard deviation `sigma_level` of the weak prior of each angle toward 0 when the gyro
    /// gives the rotation, rad (`f64::INFINITY` switches it off).
    pub level_sigma_rad: f64,
    /// `sigma_level` for steps without the gyro, rad. Tighter: without the gyro, encoder noise
    /// and slip excite the weak body-pitch / angle-gradient direction and the angles would
    /// random-walk (KIN-10: 31 deg and 5 % distance error over 3 m of noisy level driving with
    /// 1 rad, 0.3 deg and 0.4 % with 0.1 rad).
    pub level_sigma_no_gyro_rad: f64,
    /// Wheels with a drive increment `|dtheta_i|` below this keep their angle, rad.
    pub min_drive_increment_rad: f64,
    /// Angles are clamped to `+-max_angle_rad` (below pi/2), rad.
    pub max_angle_rad: f64,
    /// Gauss-Newton iterations (1 to [`MAX_CONTACT_ITERATIONS`]; other values are clamped).
    pub iterations: u8,
    /// Used by [`super::KinematicOdometry`]: take the angles relative to their mean over the
    /// valid wheels and solve the body step along the resulting tangents. The common mode of
    /// the angles (all tangents tilted alike) is the direction of the body's motion in its own
    /// x-z plane, which the wheels observe only through second-order suspension effects; left
    /// free it wanders by tens of degrees and tilts the odometry's translation (measured on the
    /// simulator's truth kinematics: `undulating` distance error 6.6 % free, 0.32 % with the
    /// mean removed; `docs/kinematics.md`). The assumption is that the body is on average
    /// parallel to the ground under its wheels.
    pub zero_mean: bool,
    /// Used by [`super::KinematicOdometry`]: besides the estimate of every joint step, the
    /// angles are also estimated over windows of joint readings in which the valid wheels'
    /// mean rim travel `r |dtheta|` reaches this distance, m (0: no second estimate), for the
    /// rough-terrain inverse kinematics
    /// ([`super::KinematicOdometry::windowed_contact_angles_rad`]). The rolling equations of
    /// one step resolve the tangent's direction only to the potentiometers' noise over the
    /// step's travel: the rocker and bogie readings (1.55 mrad per increment, a 0.3 m lever:
    /// about 0.5 mm) against the 3 mm a wheel rolls between two 20 Hz readings at 6 cm/s leave
    /// each step's angle about 10 deg uncertain. The noise of a window's increments does not
    /// grow with its length (the readings' noise telescopes), so 10 mm of travel resolves the
    /// tangent to about 3 deg. The step estimate stays the odometry's (it follows a wheel
    /// meeting a rock within a step, and its noise averages out of the translation; the
    /// windowed angles lag by up to a window: 3D kinematics on `step-climb` 0.96 -> 1.28 % when
    /// they drove the translation, `docs/kinematics.md`).
    pub window_travel_m: f64,
}

impl Default for ContactConfig {
    /// Defaults: `sigma_e` 0.1 mm (1 mrad at r = 0.1 m), 0.1 rad random walk per step, level
    /// prior 1 rad with the gyro and 0.1 rad without, 2 mrad minimum drive increment (0.2 mm rim travel), clamp at pi/2 - 0.05,
    /// two iterations (warm-started from the previous step's angles, a third changed the KIN-10
    /// results by at most 0.03 mm and 0.1 deg and cost about 4,000 rover-CPU instructions of RG2,
    /// against the timing budget), angles relative to their mean.
    fn default() -> Self {
        ContactConfig {
            residual_sigma_m: 1e-4,
            step_sigma_rad: 0.1,
            level_sigma_rad: 1.0,
            level_sigma_no_gyro_rad: 0.1,
            min_drive_increment_rad: 2e-3,
            max_angle_rad: core::f64::consts::FRAC_PI_2 - 0.05,
            iterations: 2,
            zero_mean: true,
            window_travel_m: 0.0,
        }
    }
}

/// Result of one contact-angle step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactStep {
    /// Body displacement `[dp (m); dphi (rad)]` of the step, in `R` at the step start (the
    /// gyro's `dphi` when it was given).
    pub body_step: Vec6,
    /// Contact angles `delta_i` after the step, rad, index `wheel - 1` (unchanged for invalid
    /// or non-turning wheels).
    pub contact_angles_rad: [f64; WHEEL_COUNT],
    /// Which angles were estimated this step (valid wheel with enough drive increment).
    pub estimated: [bool; WHEEL_COUNT],
    /// Number of wheels whose equations were used.
    pub valid_wheels: u8,
    /// Root-mean-square of the rolling equations `e_i` at the solution, m (slip indicator).
    pub residual_rms_m: f64,
}

/// Per-wheel data of one step that does not depend on the unknowns.
#[derive(Debug, Clone, Copy)]
struct WheelStep {
    axle: Vec3,
    x_c: Vec3,
    z_c: Vec3,
    /// `sum_q dq_q k_q`: rotation of the wheel's chain relative to the body over the step.
    suspension_rotation: Vec3,
}

/// Contact point `c(delta)`, tangent `t(delta)` and `dt/ddelta` of one wheel.
fn contact_geometry(w: &WheelStep, radius: f64, delta: f64) -> (Vec3, Vec3, Vec3) {
    let (s, c) = (libm::sin(delta), libm::cos(delta));
    let point = w.axle + (w.x_c * s - w.z_c * c) * radius;
    let tangent = w.x_c * c + w.z_c * s;
    let d_tangent = w.z_c * c - w.x_c * s;
    (point, tangent, d_tangent)
}

/// Wheel Jacobians (eq. 14 form, [`WheelJacobian`]) with each contact at angle `delta_i`:
/// contact point `c_i(delta_i)`, suspension columns `-k_q x (c_i - o_q)`, drive column
/// `r t_i(delta_i)`. At `delta = 0` they equal [`WheelJacobian::from_frames`]. Used for the
/// covariance of the contact-angle odometry (the least squares at the solved angles).
pub fn contact_jacobians(
    frames: &[WheelFrames; WHEEL_COUNT],
    wheel_radius_m: f64,
    contact_angles_rad: &[f64; WHEEL_COUNT],
) -> [WheelJacobian; WHEEL_COUNT] {
    // `from_fn` only calls with `i < WHEEL_COUNT`, the length of both arrays.
    core::array::from_fn(|i| {
        let f = &frames[i];
        let w = WheelStep {
            axle: f.contact.pos,
            x_c: f.rolling_dir,
            z_c: f.contact.z_axis(),
            suspension_rotation: Vec3::zeros(),
        };
        let (point, tangent, _) = contact_geometry(&w, wheel_radius_m, contact_angles_rad[i]);
        let lever = point - f.contact_point_m;
        WheelJacobian {
            contact_point_m: point,
            rocker: -(f.d_contact_d_rocker + f.rocker_axis.cross(&lever)),
            bogie: -(f.d_contact_d_bogie + f.bogie_axis.cross(&lever)),
            drive: tangent * wheel_radius_m,
            bogie_index: f.bogie,
        }
    })
}

fn skew(v: &Vec3) -> Mat3 {
    Mat3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The inputs of one contact-angle step that stay fixed over its Gauss-Newton iterations.
struct StepProblem<'a> {
    frames: &'a [WheelFrames; WHEEL_COUNT],
    wheels: &'a [WheelStep; WHEEL_COUNT],
    increments: &'a SuspensionRates,
    valid: &'a [bool; WHEEL_COUNT],
    estimated: &'a [bool; WHEEL_COUNT],
    drive: &'a [f64; WHEEL_COUNT],
    prior: &'a [f64; WHEEL_COUNT],
    radius: f64,
    w_prev: f64,
    w_level: f64,
}

/// One Gauss-Newton iteration of the contact-angle step when the gyro gives `dphi`: the
/// unknowns are `dp` and the angles. With `J_b = [I, -[c_i]x]` restricted to its `dp` columns
/// (the identity) the block-arrow normal matrix of the module doc reduces to 3-vectors: per
/// wheel `h_bd = j_d`, and the Schur complement is `S = n I - sum j_d j_d' / h_dd`,
/// `g = sum e_i - sum j_d g_d / h_dd` (the same operations, in the same order, as the 6x6 form's
/// translation block, without the products by the zero and identity entries). Returns the
/// `dp` increment and updates `delta` by the angle increments (unclamped).
fn translation_step(
    pr: &StepProblem,
    dp: Vec3,
    dphi: Vec3,
    delta: &mut [f64; WHEEL_COUNT],
) -> Result<Vec3, KinematicsError> {
    let mut n = 0.0;
    let mut g = Vec3::zeros();
    let mut j_d = [Vec3::zeros(); WHEEL_COUNT];
    let mut h_dd = [1.0; WHEEL_COUNT];
    let mut g_d = [0.0; WHEEL_COUNT];
    for i in 0..WHEEL_COUNT {
        if !pr.valid[i] {
            continue;
        }
        n += 1.0;
        // The wheel's Jacobian at `delta_i` (`contact_jacobians`) and its contact velocity
        // (`contact_velocities`), with one sine and cosine for the point and the tangents.
        let f = &pr.frames[i];
        let (point, tangent, d_tangent) = contact_geometry(&pr.wheels[i], pr.radius, delta[i]);
        let lever = point - f.contact_point_m;
        let jac = WheelJacobian {
            contact_point_m: point,
            rocker: -(f.d_contact_d_rocker + f.rocker_axis.cross(&lever)),
            bogie: -(f.d_contact_d_bogie + f.bogie_axis.cross(&lever)),
            drive: tangent * pr.radius,
            bogie_index: f.bogie,
        };
        let bogie_rate = match jac.bogie_index {
            Some(1) => pr.increments.bogie_rad_s[1],
            Some(_) => pr.increments.bogie_rad_s[0],
            None => 0.0,
        };
        let b = jac.measured_velocity(pr.increments.rocker_rad_s, bogie_rate, pr.drive[i]);
        let e = dp + dphi.cross(&point) - b;
        g += e;
        if pr.estimated[i] {
            let rim = pr.radius * pr.drive[i];
            let jd = (dphi + pr.wheels[i].suspension_rotation).cross(&(tangent * pr.radius))
                - d_tangent * rim;
            h_dd[i] = jd.dot(&jd) + pr.w_prev + pr.w_level;
            g_d[i] = jd.dot(&e) + pr.w_prev * (delta[i] - pr.prior[i]) + pr.w_level * delta[i];
            j_d[i] = jd;
        }
    }
    let mut s = Mat3::identity() * n;
    for i in 0..WHEEL_COUNT {
        if pr.estimated[i] {
            s -= j_d[i] * j_d[i].transpose() / h_dd[i];
            g -= j_d[i] * (g_d[i] / h_dd[i]);
        }
    }
    let chol = crate::linalg::cholesky(s).ok_or(KinematicsError::Singular)?;
    let d = chol.solve(&(-g));
    for i in 0..WHEEL_COUNT {
        if pr.estimated[i] {
            delta[i] += -(g_d[i] + j_d[i].dot(&d)) / h_dd[i];
        }
    }
    Ok(d)
}

/// One Gauss-Newton iteration of the contact-angle step without the gyro: the unknowns are
/// `[dp; dphi]` and the angles, the block-arrow normal matrix of the module doc with the angles
/// eliminated per wheel and the 6x6 Schur complement factorised. Updates `dp`, `dphi` and
/// `delta` (angles clamped to `+-max_angle`); `valid_wheels` is the error value of a singular
/// complement ([`KinematicsError::Unobservable`]).
fn body_step(
    pr: &StepProblem,
    max_angle: f64,
    valid_wheels: u8,
    dp: &mut Vec3,
    dphi: &mut Vec3,
    delta: &mut [f64; WHEEL_COUNT],
) -> Result<(), KinematicsError> {
    let jac = contact_jacobians(pr.frames, pr.radius, delta);
    let b = contact_velocities(&jac, pr.increments, pr.drive);
    let mut h_bb = Mat6::zeros();
    let mut g_b = Vec6::zeros();
    let mut h_bd = [Vec6::zeros(); WHEEL_COUNT];
    let mut h_dd = [1.0; WHEEL_COUNT];
    let mut g_d = [0.0; WHEEL_COUNT];
    for i in 0..WHEEL_COUNT {
        if !pr.valid[i] {
            continue;
        }
        let c = jac[i].contact_point_m;
        let e = *dp + dphi.cross(&c) - b[i];
        let mut j_b = SMatrix::<f64, 3, 6>::zeros();
        j_b.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Mat3::identity());
        j_b.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&c)));
        h_bb += j_b.transpose() * j_b;
        g_b += j_b.transpose() * e;
        if pr.estimated[i] {
            let (_, tangent, d_tangent) = contact_geometry(&pr.wheels[i], pr.radius, delta[i]);
            let rim = pr.radius * pr.drive[i];
            let j_d = (*dphi + pr.wheels[i].suspension_rotation).cross(&(tangent * pr.radius))
                - d_tangent * rim;
            h_bd[i] = j_b.transpose() * j_d;
            h_dd[i] = j_d.dot(&j_d) + pr.w_prev + pr.w_level;
            g_d[i] = j_d.dot(&e) + pr.w_prev * (delta[i] - pr.prior[i]) + pr.w_level * delta[i];
        }
    }
    // Schur complement: eliminate the angles (block-arrow normal matrix).
    let mut s = h_bb;
    let mut g = g_b;
    for i in 0..WHEEL_COUNT {
        if pr.estimated[i] {
            s -= h_bd[i] * h_bd[i].transpose() / h_dd[i];
            g -= h_bd[i] * (g_d[i] / h_dd[i]);
        }
    }
    let chol = crate::linalg::cholesky(s).ok_or(KinematicsError::Unobservable { valid_wheels })?;
    let step_body: Vec6 = chol.solve(&(-g));
    *dp += Vec3::new(step_body[0], step_body[1], step_body[2]);
    *dphi += Vec3::new(step_body[3], step_body[4], step_body[5]);
    for i in 0..WHEEL_COUNT {
        if pr.estimated[i] {
            let dd = -(g_d[i] + h_bd[i].dot(&step_body)) / h_dd[i];
            delta[i] = crate::linalg::clamp(delta[i] + dd, -max_angle, max_angle);
        }
    }
    if dp.iter().chain(dphi.iter()).any(|x| !x.is_finite()) || delta.iter().any(|x| !x.is_finite())
    {
        return Err(KinematicsError::NonFinite);
    }
    Ok(())
}

/// The checks of [`contact_step_frames`]: a finite, positive configuration and wheel radius,
/// finite joint inputs, gyro rotation and previous angles ([`KinematicsError::NonFinite`]),
/// and at least three valid wheels ([`KinematicsError::Unobservable`]). Returns the number of
/// valid wheels.
fn check_step_inputs(
    config: &ContactConfig,
    radius: f64,
    increments: &SuspensionRates,
    drive_increment_rad: &[f64; WHEEL_COUNT],
    wheel_valid: &[bool; WHEEL_COUNT],
    gyro_rad: Option<Vec3>,
    previous_rad: &[f64; WHEEL_COUNT],
) -> Result<u8, KinematicsError> {
    let cfg_values = [
        config.residual_sigma_m,
        config.step_sigma_rad,
        config.min_drive_increment_rad,
        config.max_angle_rad,
        radius,
    ];
    if cfg_values.iter().any(|v| !v.is_finite() || *v < 0.0)
        || config.residual_sigma_m <= 0.0
        || config.step_sigma_rad <= 0.0
        || config.level_sigma_rad.is_nan()
        || config.level_sigma_rad <= 0.0
        || config.level_sigma_no_gyro_rad.is_nan()
        || config.level_sigma_no_gyro_rad <= 0.0
    {
        return Err(KinematicsError::NonFinite);
    }
    let gyro_ok = match gyro_rad {
        Some(g) => g.iter().all(|x| x.is_finite()),
        None => true,
    };
    if !finite_joint_inputs(increments, drive_increment_rad, wheel_valid)
        || !gyro_ok
        || previous_rad.iter().any(|x| !x.is_finite())
    {
        return Err(KinematicsError::NonFinite);
    }
    let mut count: u8 = 0;
    for ok in wheel_valid.iter() {
        if *ok {
            count = count.saturating_add(1);
        }
    }
    if count < 3 {
        return Err(KinematicsError::Unobservable {
            valid_wheels: count,
        });
    }
    Ok(count)
}

/// The clamp of the angles (`max_angle_rad`, below pi/2) and the prior weights of the cost
/// relative to the rolling equations (scaled by `sigma_e^2`): `w_p` toward the previous angle
/// and `w_0` toward 0 (the gyro's `sigma_level` when `with_gyro`).
fn step_weights(config: &ContactConfig, with_gyro: bool) -> (f64, f64, f64) {
    let max_angle = if config.max_angle_rad < core::f64::consts::FRAC_PI_2 {
        config.max_angle_rad
    } else {
        core::f64::consts::FRAC_PI_2 - 1e-3
    };
    let w_prev = {
        let k = config.residual_sigma_m / config.step_sigma_rad;
        k * k
    };
    let w_level = {
        let sigma = if with_gyro {
            config.level_sigma_rad
        } else {
            config.level_sigma_no_gyro_rad
        };
        let k = config.residual_sigma_m / sigma;
        k * k
    };
    (max_angle, w_prev, w_level)
}

/// The per-wheel data of a step ([`WheelStep`]): axle, contact-frame axes and the chain's
/// rotation `sum_q dq_q k_q` over the step.
fn wheel_steps(
    frames: &[WheelFrames; WHEEL_COUNT],
    increments: &SuspensionRates,
) -> [WheelStep; WHEEL_COUNT] {
    core::array::from_fn(|i| {
        let f = &frames[i];
        let bogie_inc = match f.bogie {
            Some(1) => increments.bogie_rad_s[1],
            Some(_) => increments.bogie_rad_s[0],
            None => 0.0,
        };
        WheelStep {
            axle: f.contact.pos,
            x_c: f.rolling_dir,
            z_c: f.contact.z_axis(),
            suspension_rotation: f.rocker_axis * increments.rocker_rad_s + f.bogie_axis * bogie_inc,
        }
    })
}

/// Root-mean-square of the rolling equations `e_i` of the valid wheels at the solution
/// `(dp, dphi, delta)`, m.
fn residual_rms(
    pr: &StepProblem,
    valid_wheels: u8,
    dp: Vec3,
    dphi: Vec3,
    delta: &[f64; WHEEL_COUNT],
) -> Result<f64, KinematicsError> {
    let jac = contact_jacobians(pr.frames, pr.radius, delta);
    let b = contact_velocities(&jac, pr.increments, pr.drive);
    let mut sum = 0.0;
    for i in 0..WHEEL_COUNT {
        if pr.valid[i] {
            sum += (dp + dphi.cross(&jac[i].contact_point_m) - b[i]).norm_squared();
        }
    }
    let rms = crate::linalg::sqrt(sum / (3.0 * f64::from(valid_wheels)));
    if !rms.is_finite() {
        return Err(KinematicsError::NonFinite);
    }
    Ok(rms)
}

/// The contact-angle step for frames already evaluated at the mid-point configuration (the
/// odometry's entry point; see [`contact_kinematics`] for the equations and the checks).
/// `ContactStep::residual_rms_m` is computed only `with_residual` (0 otherwise).
#[allow(clippy::too_many_arguments)]
pub(crate) fn contact_step_frames(
    geometry: &RoverGeometry,
    frames: &[WheelFrames; WHEEL_COUNT],
    increments: &SuspensionRates,
    drive_increment_rad: &[f64; WHEEL_COUNT],
    wheel_valid: &[bool; WHEEL_COUNT],
    gyro_rad: Option<Vec3>,
    previous_rad: &[f64; WHEEL_COUNT],
    config: &ContactConfig,
    with_residual: bool,
) -> Result<ContactStep, KinematicsError> {
    let radius = geometry.wheel_radius_m;
    let count = check_step_inputs(
        config,
        radius,
        increments,
        drive_increment_rad,
        wheel_valid,
        gyro_rad,
        previous_rad,
    )?;
    let (max_angle, w_prev, w_level) = step_weights(config, gyro_rad.is_some());
    let clamp = |d: f64| crate::linalg::clamp(d, -max_angle, max_angle);
    let estimated: [bool; WHEEL_COUNT] = core::array::from_fn(|i| {
        wheel_valid[i] && libm::fabs(drive_increment_rad[i]) >= config.min_drive_increment_rad
    });
    let wheels = wheel_steps(frames, increments);
    let prior: [f64; WHEEL_COUNT] = previous_rad.map(clamp);
    if gyro_rad.is_none() {
        // Without the gyro all six body DOF come from the contacts: the eq. 15 test for
        // collinear contacts applies (the angles add no rotational information).
        let points = contact_jacobians(frames, radius, &prior).map(|j| j.contact_point_m);
        ContactLeastSquares::new(&points, wheel_valid)?;
    }
    let mut delta = prior;
    let mut dp = Vec3::zeros();
    let mut dphi = gyro_rad.unwrap_or_else(Vec3::zeros);
    let iterations = config.iterations.clamp(1, MAX_CONTACT_ITERATIONS);
    let drive: [f64; WHEEL_COUNT] = core::array::from_fn(|i| {
        if wheel_valid[i] {
            drive_increment_rad[i]
        } else {
            0.0
        }
    });
    let problem = StepProblem {
        frames,
        wheels: &wheels,
        increments,
        valid: wheel_valid,
        estimated: &estimated,
        drive: &drive,
        prior: &prior,
        radius,
        w_prev,
        w_level,
    };
    for _ in 0..iterations {
        let Some(gyro) = gyro_rad else {
            body_step(&problem, max_angle, count, &mut dp, &mut dphi, &mut delta)?;
            continue;
        };
        // The rotation is the gyro's: only `dp` and the angles are unknown, and every
        // block of the normal matrix that meets `dphi` drops out (`translation_step`).
        let d = translation_step(&problem, dp, gyro, &mut delta)?;
        dp += d;
        delta = delta.map(clamp);
        if dp.iter().any(|x| !x.is_finite()) || delta.iter().any(|x| !x.is_finite()) {
            return Err(KinematicsError::NonFinite);
        }
    }
    // Misfit at the solution (only when asked: the odometry does not use it).
    let residual_rms_m = if with_residual {
        residual_rms(&problem, count, dp, dphi, &delta)?
    } else {
        0.0
    };
    Ok(ContactStep {
        body_step: Vec6::new(dp.x, dp.y, dp.z, dphi.x, dphi.y, dphi.z),
        contact_angles_rad: delta,
        estimated,
        valid_wheels: count,
        residual_rms_m,
    })
}

/// Contact-angle kinematic estimator (V99 sec. 6, Balaram 1999): for one joint-reading step,
/// the body displacement `[dp (m); dphi (rad)]` in the rover frame `R` at the step start and
/// the six contact angles `delta_i` (rad, in each wheel plane, positive = contact ahead of the
/// axle, centre moving forward and up), by at most three Gauss-Newton iterations on
/// `e_i = dp + dphi x c_i(delta_i) + sum_q dq_q k_q x (c_i - o_q) - r dtheta_i t_i(delta_i) = 0`
/// with a prior toward `previous_rad` (module doc for the full formulation).
///
/// Inputs as for [`super::KinematicOdometry::update`]: the suspension and steering angles at the
/// step mid-point `state`, the rocker/bogie increments `increments` (rad, in the fields named
/// `_rad_s`), the drive increments `drive_increment_rad` and the wheel validity; optionally the
/// body rotation increment of the same step from the gyro `gyro_rad` (rad, in `R`), which is
/// then trusted and only `dp` and the angles are solved. Errors: non-finite input or config,
/// angles out of range, fewer than three valid wheels or collinear contacts without the gyro
/// (`Unobservable`), a singular reduced system.
#[allow(clippy::too_many_arguments)]
pub fn contact_kinematics(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    increments: &SuspensionRates,
    drive_increment_rad: &[f64; WHEEL_COUNT],
    wheel_valid: &[bool; WHEEL_COUNT],
    gyro_rad: Option<Vec3>,
    previous_rad: &[f64; WHEEL_COUNT],
    config: &ContactConfig,
) -> Result<ContactStep, KinematicsError> {
    let mut state = *state;
    for (steer, ok) in state.steer_rad.iter_mut().zip(wheel_valid.iter()) {
        if !*ok {
            *steer = 0.0;
        }
    }
    check_suspension(geometry, &state)?;
    let frames = wheel_frames_trusted(geometry, &state);
    contact_step_frames(
        geometry,
        &frames,
        increments,
        drive_increment_rad,
        wheel_valid,
        gyro_rad,
        previous_rad,
        config,
        true,
    )
}
