//! Forward kinematics: body rates from measured joint rates by least squares (H04 eq. 15).
//!
//! Algebraic reduction of eq. 15 (no general matrix inverse): with the contact-point rows of
//! [`super::jacobian`] the stacked system is `A v = b` with `A_i = [I, -[p_i]x]` and
//! `b_i = J_i q_dot_i`. Writing the rates at the centroid `c` of the valid contacts
//! (`q_i = p_i - c`) makes the normal matrix `A^T A` block diagonal:
//!
//! ```text
//! v_c   = mean_i b_i                                 (3 linear rates at c)
//! I_c w = sum_i q_i x b_i,   I_c = sum_i (|q_i|^2 I - q_i q_i^T)   (3x3, symmetric)
//! v     = v_c - w x c                                (rates at the origin of R)
//! ```
//!
//! `I_c` is factorised by a closed-form 3x3 Cholesky; it is singular exactly when the valid
//! contacts are collinear (fewer than three wheels), the case reported as unobservable.

use super::geometry::{check_suspension, wheel_frames_trusted, RoverGeometry};
use super::jacobian::WheelJacobian;
use super::{BodyRates, KinematicsError, SuspensionRates, SuspensionState};
use crate::types::Vec3;
use nalgebra::SMatrix;
use rover_hal::{JointState, WHEEL_COUNT};

/// Result of forward kinematics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForwardSolution {
    /// Body rates `[x_dot y_dot z_dot (m/s), roll pitch yaw (rad/s)]` in `R`.
    pub body_rates: BodyRates,
    /// Number of wheels whose rows were used.
    pub valid_wheels: u8,
    /// Which body-rate components the valid wheels determine (all six with three or more
    /// non-collinear contacts; otherwise the solver returns
    /// [`KinematicsError::Unobservable`]).
    pub observed: [bool; 6],
    /// Root-mean-square misfit of the contact-velocity rows, m/s: zero for rigid, slip-free
    /// motion; it grows with slip or encoder disagreement.
    pub residual_rms_m_s: f64,
}

/// The factorised least-squares problem for one set of contacts and valid wheels. Solving for
/// another right-hand side `b` costs a few dozen flops (used for covariance columns).
#[derive(Debug, Clone, Copy)]
pub(crate) struct ContactLeastSquares {
    valid: [bool; WHEEL_COUNT],
    count: u8,
    centroid: Vec3,
    offsets: [Vec3; WHEEL_COUNT],
    /// Lower Cholesky factor of `I_c`, entries `l11 l21 l22 l31 l32 l33`.
    chol: [f64; 6],
}

impl ContactLeastSquares {
    /// Factorise for the contact points `points` of the wheels flagged in `valid`.
    pub(crate) fn new(
        points: &[Vec3; WHEEL_COUNT],
        valid: &[bool; WHEEL_COUNT],
    ) -> Result<Self, KinematicsError> {
        let mut count: u8 = 0;
        let mut sum = Vec3::zeros();
        for (p, ok) in points.iter().zip(valid.iter()) {
            if *ok {
                count = count.saturating_add(1);
                sum += p;
            }
        }
        if count < 3 {
            return Err(KinematicsError::Unobservable {
                valid_wheels: count,
            });
        }
        let centroid = sum / f64::from(count);
        let offsets = points.map(|p| p - centroid);
        let (mut ixx, mut iyy, mut izz, mut ixy, mut ixz, mut iyz) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for (q, ok) in offsets.iter().zip(valid.iter()) {
            if *ok {
                ixx += q.y * q.y + q.z * q.z;
                iyy += q.x * q.x + q.z * q.z;
                izz += q.x * q.x + q.y * q.y;
                ixy -= q.x * q.y;
                ixz -= q.x * q.z;
                iyz -= q.y * q.z;
            }
        }
        // Closed-form Cholesky of the symmetric 3x3 `I_c`; a pivot below a relative tolerance
        // means collinear contacts (a rotation about their line is not observed).
        let tol = 1e-9 * (ixx + iyy + izz);
        let unobservable = KinematicsError::Unobservable {
            valid_wheels: count,
        };
        if ixx.is_nan() || ixx <= tol {
            return Err(unobservable);
        }
        let l11 = crate::linalg::sqrt(ixx);
        let l21 = ixy / l11;
        let l31 = ixz / l11;
        let d22 = iyy - l21 * l21;
        if d22.is_nan() || d22 <= tol {
            return Err(unobservable);
        }
        let l22 = crate::linalg::sqrt(d22);
        let l32 = (iyz - l31 * l21) / l22;
        let d33 = izz - l31 * l31 - l32 * l32;
        if d33.is_nan() || d33 <= tol {
            return Err(unobservable);
        }
        let l33 = crate::linalg::sqrt(d33);
        Ok(ContactLeastSquares {
            valid: *valid,
            count,
            centroid,
            offsets,
            chol: [l11, l21, l22, l31, l32, l33],
        })
    }

    /// Number of wheels used.
    pub(crate) fn count(&self) -> u8 {
        self.count
    }

    /// Least-squares body rates for the contact velocities `b` (rows of invalid wheels unused).
    pub(crate) fn solve(&self, b: &[Vec3; WHEEL_COUNT]) -> BodyRates {
        let mut sum_b = Vec3::zeros();
        let mut moment = Vec3::zeros();
        for ((bi, q), ok) in b.iter().zip(self.offsets.iter()).zip(self.valid.iter()) {
            if *ok {
                sum_b += bi;
                moment += q.cross(bi);
            }
        }
        let v_c = sum_b / f64::from(self.count);
        let w = self.inertia_solve(&moment);
        let v = v_c - w.cross(&self.centroid);
        BodyRates::new(v.x, v.y, v.z, w.x, w.y, w.z)
    }

    /// `I_c^-1 m` by forward then back substitution with the factor.
    fn inertia_solve(&self, moment: &Vec3) -> Vec3 {
        let [l11, l21, l22, l31, l32, l33] = self.chol;
        let y1 = moment.x / l11;
        let y2 = (moment.y - l21 * y1) / l22;
        let y3 = (moment.z - l31 * y1 - l32 * y2) / l33;
        let w3 = y3 / l33;
        let w2 = (y2 - l32 * w3) / l22;
        let w1 = (y1 - l21 * w2 - l31 * w3) / l11;
        Vec3::new(w1, w2, w3)
    }

    /// The linear map of one wheel's contact velocity to the body rates: `solve(b) = M b_i`
    /// for a `b` that is zero except at wheel `i`, with the rows ordered `[omega; v]`
    /// (rotation first, the odometry covariance's order; rad/s and m/s per m/s of `b_i`).
    /// Zero for a wheel the least squares does not use. With `q_i` the wheel's offset from the
    /// contact centroid `c`: `omega = I_c^-1 [q_i]x b_i`, `v = b_i / n - omega x c` (eq. 15).
    pub(crate) fn wheel_map(&self, i: usize) -> SMatrix<f64, 6, 3> {
        let mut m = SMatrix::<f64, 6, 3>::zeros();
        let (Some(true), Some(q)) = (self.valid.get(i).copied(), self.offsets.get(i)) else {
            return m;
        };
        let n = f64::from(self.count);
        for k in 0..3 {
            let mut e = Vec3::zeros();
            if let Some(v) = e.get_mut(k) {
                *v = 1.0;
            }
            let w = self.inertia_solve(&q.cross(&e));
            let v = e / n - w.cross(&self.centroid);
            m.fixed_view_mut::<3, 1>(0, k).copy_from(&w);
            m.fixed_view_mut::<3, 1>(3, k).copy_from(&v);
        }
        m
    }

    /// Root-mean-square misfit of `b` against the rates `t`, m/s.
    pub(crate) fn residual_rms(&self, b: &[Vec3; WHEEL_COUNT], t: &BodyRates) -> f64 {
        let v = Vec3::new(t[0], t[1], t[2]);
        let w = Vec3::new(t[3], t[4], t[5]);
        let mut sum = 0.0;
        for ((bi, q), ok) in b.iter().zip(self.offsets.iter()).zip(self.valid.iter()) {
            if *ok {
                let p = q + self.centroid;
                sum += (v + w.cross(&p) - bi).norm_squared();
            }
        }
        crate::linalg::sqrt(sum / (3.0 * f64::from(self.count)))
    }
}

/// Eq. 14 right-hand sides `b_i = J_i q_dot_i` of all wheels.
pub(crate) fn contact_velocities(
    jacobians: &[WheelJacobian; WHEEL_COUNT],
    rates: &SuspensionRates,
    drive_rad_s: &[f64; WHEEL_COUNT],
) -> [Vec3; WHEEL_COUNT] {
    let mut b = [Vec3::zeros(); WHEEL_COUNT];
    for ((bi, jac), drive) in b.iter_mut().zip(jacobians.iter()).zip(drive_rad_s.iter()) {
        let bogie_rate = match jac.bogie_index {
            Some(1) => rates.bogie_rad_s[1],
            Some(_) => rates.bogie_rad_s[0],
            None => 0.0,
        };
        *bi = jac.measured_velocity(rates.rocker_rad_s, bogie_rate, *drive);
    }
    b
}

/// True when the rocker and bogie rates (or increments) and the drive rates (or increments) of
/// the valid wheels are finite: the input check of eq. 15 and of the contact-angle step.
pub(crate) fn finite_joint_inputs(
    rates: &SuspensionRates,
    drive: &[f64; WHEEL_COUNT],
    wheel_valid: &[bool; WHEEL_COUNT],
) -> bool {
    let suspension = [
        rates.rocker_rad_s,
        rates.bogie_rad_s[0],
        rates.bogie_rad_s[1],
    ];
    let drive_ok = drive
        .iter()
        .zip(wheel_valid.iter())
        .all(|(d, ok)| !*ok || d.is_finite());
    drive_ok && suspension.iter().all(|r| r.is_finite())
}

/// Eq. 15 (H04): least-squares body rates `[x_dot y_dot z_dot roll pitch yaw]` (rover frame `R`,
/// m/s and rad/s) from the suspension angles and rates and the six drive rates (rad/s). Rows of
/// wheels with `wheel_valid[i] == false` are dropped. Errors: non-finite input, angles out of
/// range, or fewer than three valid wheels.
pub fn forward_kinematics(
    geometry: &RoverGeometry,
    state: &SuspensionState,
    rates: &SuspensionRates,
    drive_rad_s: &[f64; WHEEL_COUNT],
    wheel_valid: &[bool; WHEEL_COUNT],
) -> Result<ForwardSolution, KinematicsError> {
    // An invalid wheel's steering encoder is not used (its steering may be garbage).
    let mut state = *state;
    for (steer, ok) in state.steer_rad.iter_mut().zip(wheel_valid.iter()) {
        if !*ok {
            *steer = 0.0;
        }
    }
    check_suspension(geometry, &state)?;
    if !finite_joint_inputs(rates, drive_rad_s, wheel_valid) {
        return Err(KinematicsError::NonFinite);
    }
    let frames = wheel_frames_trusted(geometry, &state);
    let jacobians = frames.map(|f| WheelJacobian::from_frames(&f, geometry.wheel_radius_m));
    let points = frames.map(|f| f.contact_point_m);
    let lsq = ContactLeastSquares::new(&points, wheel_valid)?;
    let b = contact_velocities(&jacobians, rates, drive_rad_s);
    let body_rates = lsq.solve(&b);
    if body_rates.iter().any(|x| !x.is_finite()) {
        return Err(KinematicsError::NonFinite);
    }
    Ok(ForwardSolution {
        body_rates,
        valid_wheels: lsq.count(),
        observed: [true; 6],
        residual_rms_m_s: lsq.residual_rms(&b, &body_rates),
    })
}

/// Eq. 15 (H04) from a HAL joint reading: drive rates `drive_rate_rad_s`, steering and
/// suspension angles, wheel validity flags; the suspension rates come from the caller (the
/// encoders give angles). Error [`KinematicsError::SuspensionInvalid`] when the reading flags
/// its rocker/bogie encoders invalid.
pub fn forward_kinematics_from_joints(
    geometry: &RoverGeometry,
    joints: &JointState,
    rates: &SuspensionRates,
) -> Result<ForwardSolution, KinematicsError> {
    if !joints.suspension_valid {
        return Err(KinematicsError::SuspensionInvalid);
    }
    forward_kinematics(
        geometry,
        &SuspensionState::from_joints(joints),
        rates,
        &joints.drive_rate_rad_s,
        &joints.wheel_valid,
    )
}
