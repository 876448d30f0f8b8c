//! Motion estimation (H04 sec. 2 "Motion Estimation", eq. 11; H05 sec. II.D): Schonemann
//! (SVD orthogonal Procrustes) inside least-median-of-squares over random minimal subsets, then
//! maximum-likelihood refinement with per-feature covariances (Gauss-Newton on three rotation
//! angles and the translation), and the conversion of the camera motion into the rover frame.
//!
//! Eq. 11: `Q_c = R Q_p + T + e`, with `Q_p` a feature in the previous left camera frame `K0`,
//! `Q_c` the same feature in the current one `K1`; so `R` rotates `K0` vectors into `K1` and `T`
//! is in `K1`, metres.

use super::{VoConfig, VoError};
use crate::types::{Mat3, Mat6, Quat, RelativePose, Vec3};
use nalgebra::{Matrix3x6, Rotation3, UnitQuaternion, Vector6};
use rover_hal::StereoCalibration;

/// One feature seen in both stereo pairs, in the left camera frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// `Q_p`: position in `K0`, m.
    pub q_p: Vec3,
    /// Covariance of `Q_p`, m^2.
    pub cov_p: Mat3,
    /// `Q_c`: position in `K1`, m.
    pub q_c: Vec3,
    /// Covariance of `Q_c`, m^2.
    pub cov_c: Mat3,
    /// Inverse of `cov_c + R0 cov_p R0^T` for the prior rotation `R0`, used to score the
    /// least-median-of-squares hypotheses, 1/m^2.
    pub info_prior: Mat3,
}

impl Correspondence {
    /// Builds a correspondence and its scoring weight for the prior rotation `rotation_prior`
    /// (`R` of eq. 11); `None` if the combined covariance is not positive definite or a value is
    /// not finite.
    pub fn new(
        q_p: Vec3,
        cov_p: Mat3,
        q_c: Vec3,
        cov_c: Mat3,
        rotation_prior: &Mat3,
    ) -> Option<Self> {
        let combined = cov_c + rotation_prior * cov_p * rotation_prior.transpose();
        let info_prior = crate::linalg::cholesky(combined)?.inverse();
        let c = Self {
            q_p,
            cov_p,
            q_c,
            cov_c,
            info_prior,
        };
        let finite = c.q_p.iter().chain(c.q_c.iter()).all(|v| v.is_finite())
            && c.info_prior.iter().all(|v| v.is_finite());
        finite.then_some(c)
    }
}

/// Eq. 11 (H04): the rigid motion `Q_c = R Q_p + T` between the left camera frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidMotion {
    /// `R`: rotates `K0` vectors into `K1`.
    pub rotation: Mat3,
    /// `T`: translation in `K1`, m.
    pub translation_m: Vec3,
}

impl RigidMotion {
    /// No motion.
    pub fn identity() -> Self {
        Self::IDENTITY
    }

    /// No motion (as [`Self::identity`], usable in a `const`).
    pub const IDENTITY: Self = Self {
        rotation: Mat3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        translation_m: crate::types::VEC3_ZERO,
    };

    /// The eq. 11 residual `r = Q_c - R Q_p - T`, m.
    pub fn residual(&self, c: &Correspondence) -> Vec3 {
        c.q_c - self.rotation * c.q_p - self.translation_m
    }
}

/// Schonemann's orthogonal Procrustes solution (H04 sec. 2): the rotation and translation that
/// best map the `Q_p` onto the `Q_c` in the least-squares sense, from the SVD of the
/// cross-covariance with the determinant constraint. `None` for fewer than three points or
/// (nearly) collinear points.
pub fn schonemann<'a, I>(pairs: I) -> Option<RigidMotion>
where
    I: Iterator<Item = &'a Correspondence> + Clone,
{
    let mut count = 0usize;
    let mut mean_p = Vec3::zeros();
    let mut mean_c = Vec3::zeros();
    for c in pairs.clone() {
        mean_p += c.q_p;
        mean_c += c.q_c;
        count += 1;
    }
    if count < 3 {
        return None;
    }
    mean_p /= count as f64;
    mean_c /= count as f64;
    let mut h = Mat3::zeros();
    for c in pairs {
        h += (c.q_p - mean_p) * (c.q_c - mean_c).transpose();
    }
    // `h = U S V'` (decreasing singular values, `det U = +1`: `crate::linalg::svd3`); the
    // determinant constraint then only needs `det V`.
    let (u, s, v) = crate::linalg::svd3(&h)?;
    let (largest, middle) = (s.x, s.y);
    if !(largest > 1e-12 && middle > 1e-6 * largest) {
        return None;
    }
    let sign = (v * u.transpose()).determinant().signum();
    let rotation = v * Mat3::from_diagonal(&Vec3::new(1.0, 1.0, sign)) * u.transpose();
    let translation_m = mean_c - rotation * mean_p;
    let ok = rotation
        .iter()
        .chain(translation_m.iter())
        .all(|x| x.is_finite());
    ok.then_some(RigidMotion {
        rotation,
        translation_m,
    })
}

/// SplitMix64: a small deterministic pseudo-random generator (fixed seed, same sequence on
/// every platform).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator with the given seed.
    pub const fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// A number in `0..n` (`0` for `n == 0`), by multiply-shift.
    pub fn below(&mut self, n: usize) -> usize {
        ((u128::from(self.next_u64()) * n as u128) >> 64) as usize
    }
}

/// Median-of-squares for [`Lmeds`]: moves the `k`-th smallest value to `values[k]` (iterative
/// quickselect, bounded, no recursion) and returns it.
pub fn select_kth(values: &mut [f64], k: usize) -> Option<f64> {
    let (mut lo, mut hi) = (0usize, values.len().checked_sub(1)?);
    if k > hi {
        return None;
    }
    for _ in 0..values.len() {
        if lo >= hi {
            break;
        }
        let pivot = *values.get(lo + (hi - lo) / 2)?;
        let (mut i, mut j) = (lo, hi);
        for _ in 0..values.len() {
            while values.get(i).is_some_and(|&v| v < pivot) {
                i += 1;
            }
            while values.get(j).is_some_and(|&v| v > pivot) && j > 0 {
                j -= 1;
            }
            if i >= j || j >= values.len() {
                break;
            }
            values.swap(i, j);
            i += 1;
            j = j.saturating_sub(1);
        }
        if k <= j {
            hi = j;
        } else {
            lo = j + 1;
        }
    }
    values.get(k).copied()
}

/// Least-median-of-squares search (H04 sec. 2, ref. [9]): each hypothesis fits Schonemann to a
/// random minimal subset of three correspondences and scores it by the median of the squared
/// Mahalanobis residuals of all correspondences; the lowest median wins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lmeds {
    rng: SplitMix64,
    best: Option<(RigidMotion, f64)>,
}

impl Lmeds {
    /// A search with the given seed.
    pub const fn new(seed: u64) -> Self {
        Self {
            rng: SplitMix64::new(seed),
            best: None,
        }
    }

    /// One hypothesis over `pairs` (`scratch` at least as long as `pairs`).
    pub fn hypothesis(&mut self, pairs: &[Correspondence], scratch: &mut [f64]) {
        let n = pairs.len();
        if n < 3 || scratch.len() < n {
            return;
        }
        let i = self.rng.below(n);
        let mut j = self.rng.below(n - 1);
        if j >= i {
            j += 1;
        }
        let mut k = self.rng.below(n - 2);
        for taken in [i.min(j), i.max(j)] {
            if k >= taken {
                k += 1;
            }
        }
        let subset = [i, j, k];
        let Some(motion) = schonemann(subset.iter().filter_map(|&s| pairs.get(s))) else {
            return;
        };
        for (slot, c) in scratch.iter_mut().zip(pairs.iter()) {
            let r = motion.residual(c);
            *slot = (r.transpose() * c.info_prior * r)[(0, 0)];
        }
        let Some(median) = select_kth(scratch.get_mut(..n).unwrap_or(&mut []), n / 2) else {
            return;
        };
        if median.is_finite() && self.best.is_none_or(|(_, m)| median < m) {
            self.best = Some((motion, median));
        }
    }

    /// The best motion so far and its median squared Mahalanobis residual.
    pub fn best(&self) -> Option<(RigidMotion, f64)> {
        self.best
    }
}

/// Maximum-likelihood rounds: the inliers are gated again after each round but the last.
pub const ML_ROUNDS: u8 = 4;

/// Median of a chi-square variable with 3 degrees of freedom.
pub const CHI2_3_MEDIAN: f64 = 2.366;

/// Squared Mahalanobis residual `r^T (cov_c + R cov_p R^T)^-1 r` of eq. 11 of one
/// correspondence under `motion` (3 degrees of freedom), `None` if the combined covariance is not
/// positive definite.
pub fn mahalanobis2(c: &Correspondence, motion: &RigidMotion) -> Option<f64> {
    let r = motion.residual(c);
    let combined = c.cov_c + motion.rotation * c.cov_p * motion.rotation.transpose();
    crate::linalg::cholesky(combined).map(|ch| (r.transpose() * ch.inverse() * r)[(0, 0)])
}

/// Marks as inliers the correspondences whose squared Mahalanobis residual under `motion` (with
/// the exact combined covariance `cov_c + R cov_p R^T`) is within `gate`. Returns the count.
pub fn mark_inliers(
    pairs: &[Correspondence],
    motion: &RigidMotion,
    gate: f64,
    inliers: &mut [bool],
) -> u16 {
    let mut count = 0u16;
    for (flag, c) in inliers.iter_mut().zip(pairs.iter()) {
        *flag = mahalanobis2(c, motion).is_some_and(|d2| d2 <= gate);
        if *flag {
            count = count.saturating_add(1);
        }
    }
    count
}

/// Median of the squared Mahalanobis residuals ([`mahalanobis2`]) of ALL correspondences
/// under `motion` (a pair without a positive definite covariance counts as infinite), by
/// quickselect in `scratch` (at least as long as `pairs`). `None` for no pairs.
pub fn residual_median(
    pairs: &[Correspondence],
    motion: &RigidMotion,
    scratch: &mut [f64],
) -> Option<f64> {
    let n = pairs.len();
    let values = scratch.get_mut(..n)?;
    for (slot, c) in values.iter_mut().zip(pairs.iter()) {
        *slot = mahalanobis2(c, motion).unwrap_or(f64::INFINITY);
    }
    select_kth(values, n / 2)
}

/// Robust variance scale of the point covariances (Rousseeuw and Leroy 1987, the LMedS scale
/// `s0 = 1.4826 (1 + 5 / (n - p)) sqrt(median r^2)` carried over to 3-dof Mahalanobis residuals):
/// `k = (1 + 5 / (n - 3))^2 median(d^2) / CHI2_3_MEDIAN`, where `d^2` are the squared
/// Mahalanobis residuals of all `n` correspondences and [`CHI2_3_MEDIAN`] (2.366) is the median
/// of `d^2` when the covariances are right (the 1-D `1.4826^2 = 1 / 0.4549` becomes `1 / 2.366`
/// for 3 dof; `p = 3` correspondences make a minimal subset). Never below 1: the data only ever
/// widen the covariances, never narrow them below the noise model. 1 for non-finite input.
pub fn robust_variance_scale(median_d2: f64, n: usize) -> f64 {
    let small_sample = 1.0 + 5.0 / (n.saturating_sub(3).max(1) as f64);
    let k = small_sample * small_sample * median_d2 / CHI2_3_MEDIAN;
    if k.is_finite() {
        k.max(1.0)
    } else {
        1.0
    }
}

/// Sums of one maximum-likelihood iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MlIteration {
    /// The updated motion.
    pub motion: RigidMotion,
    /// Information matrix `sum J^T W J` over `[theta; T]` at the motion before the update.
    pub information: Mat6,
    /// `sum r^T W r` before the update.
    pub chi2: f64,
    /// Sum of squared residual norms before the update, m^2.
    pub sum_sq_m2: f64,
    /// Correspondences used.
    pub count: u16,
    /// Norm of the update `[delta_theta (rad); delta_T (m)]`.
    pub step: f64,
}

/// Eq. 11 (H04): one Gauss-Newton iteration of the maximum-likelihood motion, minimising
/// `sum r_j^T W_j r_j` with `r_j = Q_cj - R Q_pj - T` and `W_j = (cov_c + R cov_p R^T)^-1`, over
/// three rotation angles `theta` (`R <- exp([theta]x) R`) and the translation `T`.
pub fn ml_iteration(
    pairs: &[Correspondence],
    inliers: &[bool],
    motion: &RigidMotion,
) -> Result<MlIteration, VoError> {
    let mut information = Mat6::zeros();
    let mut gradient = Vector6::<f64>::zeros();
    let mut chi2 = 0.0;
    let mut sum_sq = 0.0;
    let mut count = 0u16;
    for (c, _) in pairs.iter().zip(inliers.iter()).filter(|(_, &f)| f) {
        let rq = motion.rotation * c.q_p;
        let r = c.q_c - rq - motion.translation_m;
        let combined = c.cov_c + motion.rotation * c.cov_p * motion.rotation.transpose();
        let w = crate::linalg::cholesky(combined)
            .ok_or(VoError::NonFinite)?
            .inverse();
        // dr/dtheta = [R Q_p]x, dr/dT = -I
        let mut j = Matrix3x6::<f64>::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&rq.cross_matrix());
        j.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-Mat3::identity()));
        let jtw = j.transpose() * w;
        information += jtw * j;
        gradient += jtw * r;
        chi2 += (r.transpose() * w * r)[(0, 0)];
        sum_sq += r.norm_squared();
        count = count.saturating_add(1);
    }
    if count < 3 {
        return Err(VoError::DegenerateGeometry);
    }
    let cholesky = crate::linalg::cholesky(information).ok_or(VoError::DegenerateGeometry)?;
    let delta = cholesky.solve(&(-gradient));
    if !delta.iter().all(|v| v.is_finite()) || !chi2.is_finite() {
        return Err(VoError::NonFinite);
    }
    let theta = Vec3::new(delta[0], delta[1], delta[2]);
    let rotation = Rotation3::new(theta).into_inner() * motion.rotation;
    let translation_m = motion.translation_m + Vec3::new(delta[3], delta[4], delta[5]);
    Ok(MlIteration {
        motion: RigidMotion {
            rotation,
            translation_m,
        },
        information,
        chi2,
        sum_sq_m2: sum_sq,
        count,
        step: delta.norm(),
    })
}

/// Mounting of the left camera on the rover: `v_R = rot * v_K + pos`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraMount {
    /// Rotation from `K` to `R`.
    pub rot_rover_from_camera: Mat3,
    /// Left camera centre in `R`, m.
    pub pos_camera_in_rover_m: Vec3,
}

impl CameraMount {
    /// The mounting of a calibration; [`VoError::InvalidCalibration`] unless the rotation is
    /// orthonormal with determinant +1 (to 1e-6) and all values are finite.
    pub fn from_calibration(c: &StereoCalibration) -> Result<Self, VoError> {
        let m = c.rot_rover_from_camera;
        let rot = Mat3::new(
            m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2],
        );
        let p = c.pos_camera_in_rover_m;
        let pos = Vec3::new(p[0], p[1], p[2]);
        let finite = rot.iter().chain(pos.iter()).all(|v| v.is_finite());
        let orthonormal = (rot.transpose() * rot - Mat3::identity()).amax() < 1e-6
            && (rot.determinant() - 1.0).abs() < 1e-6;
        if finite && orthonormal {
            Ok(Self {
                rot_rover_from_camera: rot,
                pos_camera_in_rover_m: pos,
            })
        } else {
            Err(VoError::InvalidCalibration)
        }
    }

    /// The camera motion of eq. 11 implied by a rover relative pose (`rot_0_1`, `trans_0_1_m`
    /// in `R0`, see [`RelativePose`]).
    pub fn camera_motion(&self, rot_0_1: &Mat3, trans_0_1_m: &Vec3) -> RigidMotion {
        let r_rk = self.rot_rover_from_camera;
        let t_rk = self.pos_camera_in_rover_m;
        let rot_k01 = r_rk.transpose() * rot_0_1 * r_rk;
        let p_k = r_rk.transpose() * (rot_0_1 * t_rk + trans_0_1_m - t_rk);
        let rotation = rot_k01.transpose();
        RigidMotion {
            rotation,
            translation_m: -(rotation * p_k),
        }
    }

    /// The rover relative pose (`rot_0_1`, `trans_0_1_m`) of a camera motion of eq. 11, and the
    /// Jacobian `M` of its error `[delta_theta; delta_p]` (the [`RelativePose`] convention)
    /// with respect to the motion's error `[theta; delta_T]` (`R <- exp([theta]x) R`).
    pub fn rover_motion(&self, motion: &RigidMotion) -> (Mat3, Vec3, Mat6) {
        let r_rk = self.rot_rover_from_camera;
        let t_rk = self.pos_camera_in_rover_m;
        let r = motion.rotation;
        let t = motion.translation_m;
        let rot_k01 = r.transpose();
        let p_k = -(rot_k01 * t);
        let rot_0_1 = r_rk * rot_k01 * r_rk.transpose();
        let trans = r_rk * p_k + t_rk - rot_0_1 * t_rk;
        // delta_theta_R = A theta; delta_trans = C theta + D delta_T.
        let a = -(r_rk * rot_k01);
        let c =
            -(r_rk * (rot_k01 * t).cross_matrix() * rot_k01) + (rot_0_1 * t_rk).cross_matrix() * a;
        let d = -(r_rk * rot_k01);
        let mut m = Mat6::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&a);
        m.fixed_view_mut::<3, 3>(3, 0).copy_from(&c);
        m.fixed_view_mut::<3, 3>(3, 3).copy_from(&d);
        (rot_0_1, trans, m)
    }
}

/// Result of the motion estimation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionEstimate {
    /// The motion of eq. 11.
    pub motion: RigidMotion,
    /// Covariance of `[theta (rad); T (m)]`: the inverse information matrix of eq. 11 times
    /// [`MotionEstimate::covariance_scale`].
    pub covariance: Mat6,
    /// Inliers used by the final fit.
    pub inliers: u16,
    /// Root mean square of the inliers' residuals, m.
    pub residual_rms_m: f64,
    /// Chi-square of the inliers per degree of freedom.
    pub chi2_per_dof: f64,
    /// Factor applied to the inverse information matrix (>= 1): the larger of the inliers'
    /// chi-square per degree of freedom and the robust scale over all correspondences
    /// ([`robust_variance_scale`]).
    pub covariance_scale: f64,
    /// Maximum-likelihood rounds dropped because their fit failed or their re-gating left too
    /// few inliers (the previous round's solution and inlier set were kept): 0 or 1.
    pub rounds_reverted: u8,
}

/// Finishes an estimate from the last maximum-likelihood iteration's sums (evaluated at
/// `motion`). The covariance is the inverse information matrix of eq. 11 scaled by
/// `max(1, chi2 / dof of the inliers, robust_scale)`, where `robust_scale` is
/// [`robust_variance_scale`] of the residuals of ALL correspondences at `motion` (the inliers'
/// chi-square alone is biased low by the gate).
pub fn finish_estimate(
    motion: RigidMotion,
    last: &MlIteration,
    robust_scale: f64,
) -> Result<MotionEstimate, VoError> {
    let dof = (3 * usize::from(last.count)).saturating_sub(6).max(1) as f64;
    let chi2_per_dof = last.chi2 / dof;
    let inverse = crate::linalg::cholesky(last.information)
        .ok_or(VoError::DegenerateGeometry)?
        .inverse();
    let robust = if robust_scale.is_finite() {
        robust_scale
    } else {
        1.0
    };
    let covariance_scale = chi2_per_dof.max(robust).max(1.0);
    let covariance = inverse * covariance_scale;
    let residual_rms_m = crate::linalg::sqrt(last.sum_sq_m2 / f64::from(last.count.max(1)));
    if !covariance.iter().all(|v| v.is_finite()) {
        return Err(VoError::NonFinite);
    }
    Ok(MotionEstimate {
        motion,
        covariance,
        inliers: last.count,
        residual_rms_m,
        chi2_per_dof,
        covariance_scale,
        rounds_reverted: 0,
    })
}

/// The inlier gate of a round on the squared Mahalanobis residual (3 dof): `gate_chi2` (16.27,
/// 99.9 %) times the robust variance scale ([`robust_variance_scale`]) of all `n`
/// correspondences' residuals at the round's motion (`median_d2`), so that covariances too small
/// for the real noise widen the gate instead of emptying the inlier set.
pub fn robust_gate(gate_chi2: f64, median_d2: f64, n: usize) -> f64 {
    gate_chi2 * robust_variance_scale(median_d2, n)
}

/// How an inlier set was gated: the motion and the gate (so that the set can be rebuilt
/// exactly without a second buffer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gating {
    /// Motion the residuals were evaluated at (eq. 11).
    pub motion: RigidMotion,
    /// Gate on the squared Mahalanobis residual (3 dof).
    pub gate: f64,
}

/// The solution of the last completed maximum-likelihood round and how its inliers were gated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kept {
    /// Motion at the end of the round (eq. 11).
    pub solution: RigidMotion,
    /// Gating of the round's inlier set.
    pub gating: Gating,
}

impl Kept {
    /// Rebuilds the round's inlier set in `inliers` (same motion, same gate, so the same flags)
    /// and returns the round's solution.
    pub fn restore(&self, pairs: &[Correspondence], inliers: &mut [bool]) -> RigidMotion {
        mark_inliers(pairs, &self.gating.motion, self.gating.gate, inliers);
        self.solution
    }
}

/// The whole motion stage in one call (the pipeline runs the same pieces one work item at a
/// time, in the same order): `config.lmeds_hypotheses` least-median-of-squares draws; inliers
/// within the robust gate of the best hypothesis' median ([`robust_gate`]); [`ML_ROUNDS`]
/// maximum-likelihood rounds of eq. 11, each re-gated with the robust gate at its motion. A round
/// whose fit fails, or whose re-gating leaves fewer than `config.min_inliers`, is dropped: the
/// previous round's motion and inlier set are kept and the estimate finishes there.
/// `inliers` and `scratch` at least as long as `pairs`.
pub fn estimate_motion(
    pairs: &[Correspondence],
    config: &VoConfig,
    inliers: &mut [bool],
    scratch: &mut [f64],
) -> Result<MotionEstimate, VoError> {
    let n = pairs.len();
    let mut lmeds = Lmeds::new(config.lmeds_seed);
    for _ in 0..config.lmeds_hypotheses {
        lmeds.hypothesis(pairs, scratch);
    }
    let (start, median) = lmeds.best().ok_or(VoError::DegenerateGeometry)?;
    let mut motion = start;
    let mut gating = Gating {
        motion: start,
        gate: robust_gate(config.inlier_gate_chi2, median, n),
    };
    let count = mark_inliers(pairs, &motion, gating.gate, inliers);
    if count < config.min_inliers {
        return Err(VoError::TooFewInliers { found: count });
    }
    let mut kept: Option<Kept> = None;
    let mut reverted = 0u8;
    'rounds: for round in 0..ML_ROUNDS {
        for _ in 0..config.ml_iterations {
            match ml_iteration(pairs, inliers, &motion) {
                Ok(it) => {
                    motion = it.motion;
                    if it.step < 1e-12 {
                        break;
                    }
                }
                Err(e) => match kept {
                    Some(k) => {
                        motion = k.restore(pairs, inliers);
                        reverted = 1;
                        break 'rounds;
                    }
                    None => return Err(e),
                },
            }
        }
        kept = Some(Kept {
            solution: motion,
            gating,
        });
        if round + 1 < ML_ROUNDS {
            let median = residual_median(pairs, &motion, scratch).unwrap_or(f64::INFINITY);
            gating = Gating {
                motion,
                gate: robust_gate(config.inlier_gate_chi2, median, n),
            };
            if mark_inliers(pairs, &motion, gating.gate, inliers) < config.min_inliers {
                if let Some(k) = kept {
                    motion = k.restore(pairs, inliers);
                    reverted = 1;
                }
                break;
            }
        }
    }
    let final_sums = ml_iteration(pairs, inliers, &motion)?;
    let median = residual_median(pairs, &motion, scratch).unwrap_or(f64::INFINITY);
    let mut estimate = finish_estimate(motion, &final_sums, robust_variance_scale(median, n))?;
    estimate.rounds_reverted = reverted;
    Ok(estimate)
}

/// Builds the [`RelativePose`] for the estimator from a motion estimate.
pub fn relative_pose(
    mount: &CameraMount,
    estimate: &MotionEstimate,
    t0_us: u64,
    t1_us: u64,
) -> Result<RelativePose, VoError> {
    let (rot, trans, m) = mount.rover_motion(&estimate.motion);
    let covariance = m * estimate.covariance * m.transpose();
    let covariance = (covariance + covariance.transpose()) * 0.5;
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rot));
    let rot_0_1: Quat = UnitQuaternion::new_normalize(*q.quaternion());
    let finite = trans.iter().chain(covariance.iter()).all(|v| v.is_finite())
        && rot_0_1.coords.iter().all(|v| v.is_finite());
    if !finite {
        return Err(VoError::NonFinite);
    }
    Ok(RelativePose {
        t0_us,
        t1_us,
        rot_0_1,
        trans_0_1_m: trans,
        covariance,
        observed: [true; 6],
    })
}
