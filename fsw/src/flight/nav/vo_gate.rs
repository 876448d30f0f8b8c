//! # VO gate and capture policy (H04 sec. 2 and eq. 46)
//!
//! **Gate.** Each VO relative pose between two capture clones is tested before it is fused
//! (`docs/estimation.md` "In the navigator"; why: note 0002), on the filter it is applied to (the recorder's snapshot at
//! capture time when the result is replayed, the live filter otherwise), with the innovation
//! `r = [r_theta; r_p]` and `S = H P H' + R_vo` of eq. 42/46 ([`crate::estimation::Ekf::gate_relative_pose`]):
//!
//! 1. **Rotation against the IMU**: `d_rot^2 = r_theta' S_theta^-1 r_theta` over the rotation
//!    block. The EKF rotation between the clones is propagated from the gyro (eq. 26-27), which
//!    measures the true body rotation whether the wheels slip or not, so this check does not
//!    depend on the slip-corrupted translation. Threshold: chi-square 99.9 % for the observed
//!    rotation components (16.27 for 3).
//! 2. **Pose with a slip allowance**: `d_pose^2 = r' (S + Q_slip)^-1 r` over all observed
//!    components, `Q_slip = sigma_s^2 I` on the translation block with
//!    `sigma_s = slip_fraction |z_p| + floor` (`z_p`: EKF translation between the clones, m). The
//!    EKF prior between captures comes from the IMU and the kinematics, which slip pulls away and
//!    whose covariance does not contain the slip; the allowance does. Threshold: chi-square
//!    99.9 % for the observed components (22.46 for 6).
//!
//! A pose failing either test is not fused. After [`super::VoAidingConfig::reject_streak`]
//! consecutive rejections the next pose is fused anyway, with its covariance scaled by the
//! smallest `4^n` (`n <= 10`) that passes both tests.
//!
//! **Capture policy** ([`super::VoAiding::capture_due`]): a stereo capture is due when the EKF has
//! travelled [`super::VoAidingConfig::capture_distance_m`] or rotated [`super::VoAidingConfig::capture_angle_rad`]
//! since the last capture, or [`super::VoAidingConfig::capture_max_interval_us`] has passed (time
//! fallback); the first capture is due at once, and while VO has no keyframe (after a VO
//! failure) a capture is due every [`super::VoAidingConfig::capture_retry_us`].

use crate::estimation::gate::chi2_999;
use crate::estimation::GateDecision;
use crate::types::{Mat3, Mat6, Quat, RelativePose, Vec3};

/// Largest power `n` of the covariance scale `4^n` tried for a VO pose fused after a streak.
pub const VO_FORCE_MAX_STEPS: u32 = 10;

/// The VO gate's verdict on the last VO relative pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum VoGateVerdict {
    /// No VO pose tested yet.
    #[default]
    None,
    /// Passed both tests (or the gate is off) and fused.
    Accepted,
    /// Rejected by the rotation check against the gyro-propagated rotation (test 1).
    RejectedRotation,
    /// Rejected by the 6-dof pose test with slip allowance (test 2).
    RejectedPose,
    /// Rejected by the tests but fused after a rejection streak, with inflated covariance.
    Forced,
    /// The tests could not be evaluated (residual covariance not positive definite): not fused.
    RejectedError,
}

/// The VO gate's state (telemetry).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VoGateStatus {
    /// Verdict on the last VO pose.
    pub verdict: VoGateVerdict,
    /// `d_rot^2` of the last VO pose (rotation block, dimensionless).
    pub d2_rotation: f64,
    /// `d_pose^2` of the last VO pose (all components, slip allowance; dimensionless).
    pub d2_pose: f64,
    /// Consecutive rejections so far (0 after a fused pose).
    pub consecutive_rejections: u32,
    /// A streak of [`super::VoAidingConfig::reject_streak`] rejections was reached: the next pose the
    /// gate rejects is fused with inflated covariance ([`VoGateVerdict::Forced`]). Cleared by
    /// that forced fusion or by a pose that passes the gate.
    pub streak: bool,
}

/// The two test statistics of one VO pose (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoGateTest {
    /// `d_rot^2`, dimensionless.
    pub d2_rotation: f64,
    /// 99.9 % chi-square threshold of the rotation test (0 when no rotation is observed).
    pub threshold_rotation: f64,
    /// `d_pose^2`, dimensionless.
    pub d2_pose: f64,
    /// 99.9 % chi-square threshold of the pose test.
    pub threshold_pose: f64,
}

impl VoGateTest {
    /// The verdict of the two tests: `Accepted`, `RejectedRotation` or `RejectedPose`.
    pub fn verdict(&self) -> VoGateVerdict {
        if self.d2_rotation > self.threshold_rotation {
            VoGateVerdict::RejectedRotation
        } else if self.d2_pose > self.threshold_pose {
            VoGateVerdict::RejectedPose
        } else {
            VoGateVerdict::Accepted
        }
    }
}

/// The VO gate's tests (module doc, tests 1 and 2) on the eq. 46 decision `d` of the VO pose
/// `m`, with the VO covariance scaled by `cov_scale` (>= 1; 1 for the plain test).
/// `slip_fraction` (dimensionless) and `slip_floor_m` (m) give the translation allowance.
/// `None` when a covariance is not positive definite or a number is not finite.
pub fn vo_gate_test(
    d: &GateDecision,
    m: &RelativePose,
    cov_scale: f64,
    slip_fraction: f64,
    slip_floor_m: f64,
) -> Option<VoGateTest> {
    if !(cov_scale.is_finite() && slip_fraction.is_finite() && slip_floor_m.is_finite()) {
        return None;
    }
    // S(k) = H P H' + k R: add (k - 1) R over the observed components.
    let mut r_meas: Mat6 = (m.covariance + m.covariance.transpose()) * 0.5;
    for (k, observed) in m.observed.iter().enumerate() {
        if !*observed {
            r_meas.row_mut(k).fill(0.0);
            r_meas.column_mut(k).fill(0.0);
        }
    }
    let mut s: Mat6 = d.residual_covariance + r_meas * (cov_scale.max(1.0) - 1.0);
    let r = d.residual;
    // Test 1: rotation block.
    let s_theta: Mat3 = s.fixed_view::<3, 3>(0, 0).into_owned();
    let r_theta = r.fixed_rows::<3>(0).into_owned();
    let dof_rot = m.observed.iter().take(3).filter(|o| **o).count();
    let d2_rotation = crate::linalg::cholesky(s_theta)?
        .solve(&r_theta)
        .dot(&r_theta);
    let threshold_rotation = chi2_999(dof_rot).unwrap_or(0.0);
    // Test 2: all components with the slip allowance on the observed translation.
    let z_p = m.trans_0_1_m - r.fixed_rows::<3>(3).into_owned();
    let sigma = slip_fraction.max(0.0) * z_p.norm() + slip_floor_m.max(0.0);
    for k in 3..6 {
        if m.observed.get(k).copied().unwrap_or(false) {
            s[(k, k)] += sigma * sigma;
        }
    }
    let d2_pose = crate::linalg::cholesky(s)?.solve(&r).dot(&r);
    let threshold_pose = chi2_999(d.dof)?;
    let finite = d2_rotation.is_finite() && d2_pose.is_finite();
    finite.then_some(VoGateTest {
        d2_rotation,
        threshold_rotation,
        d2_pose,
        threshold_pose,
    })
}

/// Why a capture is due ([`super::Navigator::capture_due`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CaptureReason {
    /// The EKF travelled [`super::VoAidingConfig::capture_distance_m`] since the last capture.
    Distance,
    /// The EKF attitude turned [`super::VoAidingConfig::capture_angle_rad`] since the last capture.
    Heading,
    /// [`super::VoAidingConfig::capture_max_interval_us`] passed, or no capture yet.
    Time,
}

/// The EKF pose and time of the last capture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureMark {
    /// EKF time of the capture, us.
    pub t_us: u64,
    /// EKF position, m, `N`.
    pub p_n: Vec3,
    /// EKF attitude (`R` to `N`).
    pub q_nr: Quat,
}
