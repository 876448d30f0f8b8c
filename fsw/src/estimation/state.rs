//! Nominal state, error-state layout and covariance (H04 sec. 4).
//!
//! The full error state is the 15-dimensional core `[dtheta, db_g, dv, db_a, dp]` followed by
//! [`MAX_CLONES`] clone blocks of 6 (`[dtheta_i, dp_i]`, the cloned attitude and position; H04
//! eq. 41 clones the whole state, but the relative-pose measurement, eq. 40, reads only the
//! attitude and position columns of `D1`, so only those are kept).

use super::{Ekf, EstError};
use crate::types::{Mat3, Quat, Vec3};
use nalgebra::{SMatrix, SVector, UnitQuaternion};

/// Dimension of the core error state `[dtheta, db_g, dv, db_a, dp]` (H04 sec. 4).
pub const CORE_DIM: usize = 15;
/// Dimension of one clone block `[dtheta_i, dp_i]`.
pub const CLONE_DIM: usize = 6;
/// Capacity of the clone window: the start of the kinematic interval, the previous stereo
/// capture (VO keyframe) and a capture whose VO is still running. The flight navigator skips a
/// capture while VO is busy, so three suffice (a fourth would cost 26 % more covariance work).
pub const MAX_CLONES: usize = 3;
/// Dimension of the full error state, `15 + 6 * MAX_CLONES`.
pub const DIM: usize = CORE_DIM + CLONE_DIM * MAX_CLONES;

/// Index of the attitude error `dtheta` (rad, rover frame) in the error state.
pub const I_THETA: usize = 0;
/// Index of the gyro-bias error `db_g` (rad/s).
pub const I_BG: usize = 3;
/// Index of the velocity error `dv` (m/s, `N`).
pub const I_V: usize = 6;
/// Index of the accelerometer-bias error `db_a` (m/s^2, rover frame).
pub const I_BA: usize = 9;
/// Index of the position error `dp` (m, `N`).
pub const I_P: usize = 12;

/// Full error covariance, `DIM x DIM` (rad, rad/s, m/s, m/s^2, m).
pub type Cov = SMatrix<f64, DIM, DIM>;
/// Core error covariance, 15x15.
pub type CoreCov = SMatrix<f64, CORE_DIM, CORE_DIM>;
/// A full error-state vector (a correction `dx`).
pub type ErrorVec = SVector<f64, DIM>;

/// Index of the attitude error of clone `slot` in the full error state (position follows at +3).
pub const fn clone_index(slot: usize) -> usize {
    CORE_DIM + CLONE_DIM * slot
}

/// The nominal state of H04 sec. 4, `x = [q, b_g, u, b_a, p]`, at time `t_us`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NominalState {
    /// Time of the state, microseconds since boot.
    pub t_us: u64,
    /// Attitude, rotates `R` vectors into `N` (`v_N = C(q_nr) v_R`).
    pub q_nr: Quat,
    /// Gyro bias, rad/s, rover frame.
    pub b_g: Vec3,
    /// Velocity of the rover reference point in `N`, m/s.
    pub v_n: Vec3,
    /// Accelerometer bias, m/s^2, rover frame.
    pub b_a: Vec3,
    /// Position of the rover reference point in `N`, m.
    pub p_n: Vec3,
}

impl NominalState {
    /// A rover at rest at the origin of `N`, level, heading north, biases zero, at `t_us`.
    pub fn at_rest(t_us: u64) -> Self {
        Self {
            t_us,
            q_nr: UnitQuaternion::identity(),
            b_g: Vec3::zeros(),
            v_n: Vec3::zeros(),
            b_a: Vec3::zeros(),
            p_n: Vec3::zeros(),
        }
    }

    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.q_nr.coords.iter().all(|v| v.is_finite())
            && [self.b_g, self.v_n, self.b_a, self.p_n]
                .iter()
                .all(|v| v.iter().all(|c| c.is_finite()))
    }
}

/// The last IMU sample used, held for the trapezoidal rule and for propagation to a clone time
/// between samples (zero-order hold).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ImuHold {
    pub gyro_rad_s: Vec3,
    pub accel_m_s2: Vec3,
}

/// Cross-product (skew) matrix `[o]x` (H04 sec. 4: `[o] = [[0,-o3,o2],[o3,0,-o1],[-o2,o1,0]]`).
pub fn skew(o: &Vec3) -> Mat3 {
    Mat3::new(0.0, -o.z, o.y, o.z, 0.0, -o.x, -o.y, o.x, 0.0)
}

/// Quaternion renormalization (numerical care: keeps `|q| = 1` after products); `sqrt` through
/// `libm`.
pub fn renormalize(q: &Quat) -> Quat {
    let c = q.coords;
    let n = crate::linalg::sqrt(c.dot(&c));
    if n > 0.0 && n.is_finite() {
        UnitQuaternion::new_unchecked(nalgebra::Quaternion::from(c / n))
    } else {
        UnitQuaternion::identity()
    }
}

/// Rotation by the rotation vector `theta` (rad), `exp([theta]x)` as a quaternion.
pub fn exp_quat(theta: &Vec3) -> Quat {
    let angle = crate::linalg::sqrt(theta.dot(theta));
    if angle < 1.0e-12 {
        let h = theta * 0.5;
        return renormalize(&UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
            1.0, h.x, h.y, h.z,
        )));
    }
    let half = 0.5 * angle;
    let s = libm::sin(half) / angle;
    UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
        libm::cos(half),
        theta.x * s,
        theta.y * s,
        theta.z * s,
    ))
}

/// Rotation vector of `q` (rad), the inverse of [`exp_quat`], with the angle in `[0, pi]`.
pub fn log_quat(q: &Quat) -> Vec3 {
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let s = crate::linalg::sqrt(v.dot(&v));
    if s < 1.0e-12 {
        return v * 2.0;
    }
    let angle = 2.0 * libm::atan2(s, w);
    v * (angle / s)
}

/// Rotation matrix of a unit quaternion.
pub fn rot(q: &Quat) -> Mat3 {
    q.to_rotation_matrix().into_inner()
}

impl Ekf {
    /// Error injection after an update (H04 eq. 56): `q <- q (x) exp(dtheta)` (rover-frame
    /// perturbation), biases, velocity and position additive; the same for each live clone.
    /// The reset Jacobian `I - [dtheta/2]x` is taken as identity (first order).
    pub(crate) fn inject(&mut self, dx: &ErrorVec) {
        let v3 = |i: usize| Vec3::new(dx[i], dx[i + 1], dx[i + 2]);
        self.x.q_nr = renormalize(&(self.x.q_nr * exp_quat(&v3(I_THETA))));
        self.x.b_g += v3(I_BG);
        self.x.v_n += v3(I_V);
        self.x.b_a += v3(I_BA);
        self.x.p_n += v3(I_P);
        for (slot, c) in self.clones.iter_mut().enumerate() {
            if let Some(c) = c {
                let i = clone_index(slot);
                c.q_nr = renormalize(&(c.q_nr * exp_quat(&v3(i))));
                c.p_n += v3(i + 3);
            }
        }
    }

    /// Covariance health check: every live diagonal entry finite and non-negative, attitude and
    /// position variances below their configured limits. A failure latches [`Ekf::fault`].
    pub fn check_health(&mut self) -> Result<(), EstError> {
        let att = self.config.max_attitude_var_rad2;
        let pos = self.config.max_position_var_m2;
        // Limit of each core component (attitude, position; the others unbounded), and of a
        // clone block `[dtheta_i, dp_i]` (the core's attitude and position limits).
        let core_limit = |i: usize| {
            if i < 3 {
                att
            } else if (I_P..I_P + 3).contains(&i) {
                pos
            } else {
                f64::INFINITY
            }
        };
        let unhealthy = |d: f64, limit: f64| !d.is_finite() || d < 0.0 || d > limit;
        let diag = |i: usize| self.p.get((i, i)).copied().unwrap_or(f64::NAN);
        let mut bad = (0..CORE_DIM).find(|&i| unhealthy(diag(i), core_limit(i)));
        if bad.is_none() {
            for (slot, c) in self.clones.iter().enumerate() {
                if c.is_none() {
                    continue;
                }
                let base = clone_index(slot);
                bad = (0..CLONE_DIM).map(|k| base + k).find(|&i| {
                    let limit = if i - base < 3 { att } else { pos };
                    unhealthy(diag(i), limit)
                });
                if bad.is_some() {
                    break;
                }
            }
        }
        match bad {
            Some(index) => {
                self.fault = true;
                Err(EstError::CovarianceUnhealthy { index })
            }
            None => Ok(()),
        }
    }
}
