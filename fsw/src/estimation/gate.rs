//! Mahalanobis gate (H04 eq. 46, "Mahalanobis comparator").
//!
//! `d_m^2 = r' S^-1 r` follows a chi-square distribution with as many degrees of freedom as the
//! measurement observes; a measurement is accepted when `d_m^2 <= chi2_95(dof)` (kinematic
//! odometry observes 5 DOF: threshold 11.07). When a kinematic measurement is rejected, wheel
//! slip has been detected and the residual is what guidance turns into the slip vector.

use crate::types::{Mat6, Vec6};

/// 95% quantiles of the chi-square distribution for 0 to 6 degrees of freedom (index = dof;
/// dof 0 is never used for a decision).
pub const CHI2_95: [f64; 7] = [0.0, 3.841, 5.991, 7.815, 9.488, 11.070, 12.592];

/// The 95% chi-square threshold for `dof` degrees of freedom (1 to 6), or `None`.
pub fn chi2_95(dof: usize) -> Option<f64> {
    match dof {
        1..=6 => CHI2_95.get(dof).copied(),
        _ => None,
    }
}

/// 99.9% quantiles of the chi-square distribution for 0 to 6 degrees of freedom (index = dof;
/// dof 0 is never used for a decision). The VO gate uses them (`docs/estimation.md`, "VO gate"):
/// VO is the slip-correcting measurement, so a false rejection costs more than a 3-4 sigma pose.
pub const CHI2_999: [f64; 7] = [0.0, 10.828, 13.816, 16.266, 18.467, 20.515, 22.458];

/// The 99.9% chi-square threshold for `dof` degrees of freedom (1 to 6), or `None`.
pub fn chi2_999(dof: usize) -> Option<f64> {
    match dof {
        1..=6 => CHI2_999.get(dof).copied(),
        _ => None,
    }
}

/// The outcome of the Mahalanobis test for one relative-pose measurement (eq. 46).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GateDecision {
    /// True when `d_m^2 <= threshold`.
    pub accepted: bool,
    /// Mahalanobis squared distance `d_m^2 = r' S^-1 r`.
    pub d2: f64,
    /// Degrees of freedom: the number of observed components.
    pub dof: usize,
    /// The chi-square 95% threshold used.
    pub threshold: f64,
    /// Residual `r = [r_theta (rad, R0); r_p (m, R0)]`, measured minus predicted in the
    /// [`crate::types::RelativePose`] convention: `r_theta = log(rot_meas * rot_pred')`,
    /// `r_p = trans_meas - trans_pred`. Unobserved components are zero. For a rejected kinematic
    /// measurement, `-r` over the interval is the slip of the wheels relative to the estimate.
    pub residual: Vec6,
    /// Residual covariance `S` (eq. 42) over the same components (unobserved rows and columns
    /// replaced by the identity).
    pub residual_covariance: Mat6,
    /// True when the update was applied to the state.
    pub applied: bool,
}
