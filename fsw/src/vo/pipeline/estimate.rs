//! The motion stage of [`VisualOdometry`] (H04 sec. 2 "Motion Estimation"): least-median-of-
//! squares hypotheses over the tracked correspondences, one per work item, the robust inlier
//! gate, then the maximum-likelihood rounds of eq. 11, one iteration per work item, and the
//! covariance at the converged motion.

use super::{Phase, VisualOdometry, MAX_ML_ITERATIONS};
use crate::vo::motion::{
    finish_estimate, mark_inliers, ml_iteration, residual_median, robust_gate,
    robust_variance_scale, Gating, Kept, ML_ROUNDS,
};
use crate::vo::VoError;

impl<const N: usize> VisualOdometry<N> {
    /// One least-median-of-squares hypothesis; after the last one, the best of them
    /// ([`Self::after_hypotheses`]).
    #[inline(always)]
    pub(super) fn hypothesis_item(&mut self, done: u16) {
        if done < self.config.lmeds_hypotheses {
            let n = self.pair_count.min(N);
            let pairs = self.pairs.get(..n).unwrap_or(&[]);
            self.lmeds.hypothesis(pairs, &mut self.scratch);
            self.phase = Phase::Hypotheses { done: done + 1 };
        } else {
            self.after_hypotheses();
        }
    }
    /// Ends the least-median-of-squares search: best hypothesis, robust inlier gate
    /// ([`robust_gate`] of the best median).
    fn after_hypotheses(&mut self) {
        let Some((motion, median)) = self.lmeds.best() else {
            self.fail_motion(VoError::DegenerateGeometry);
            return;
        };
        self.motion = motion;
        let n = self.pair_count.min(N);
        let pairs = self.pairs.get(..n).unwrap_or(&[]);
        self.gating = Gating {
            motion,
            gate: robust_gate(self.config.inlier_gate_chi2, median, n),
        };
        let count = mark_inliers(pairs, &self.motion, self.gating.gate, &mut self.inliers);
        self.quality.inliers = count;
        if count < self.config.min_inliers {
            self.fail_motion(VoError::TooFewInliers { found: count });
        } else {
            self.phase = Phase::Refine {
                round: 0,
                iteration: 0,
            };
        }
    }

    /// Drops the running round: the previous round's motion and inlier set come back and the
    /// next item computes the covariance there. Without a completed round, fails with `error`.
    fn revert_round(&mut self, error: VoError) {
        let n = self.pair_count.min(N);
        let pairs = self.pairs.get(..n).unwrap_or(&[]);
        match self.kept {
            Some(kept) => {
                self.motion = kept.restore(pairs, &mut self.inliers);
                self.rounds_reverted = 1;
                self.phase = Phase::Refine {
                    round: ML_ROUNDS,
                    iteration: 0,
                };
            }
            None => self.fail_motion(error),
        }
    }

    /// One maximum-likelihood iteration (eq. 11); `ML_ROUNDS` rounds, each re-gated with the
    /// robust gate at its motion; a round that fails or leaves too few inliers is dropped
    /// ([`Self::revert_round`]); the last item evaluates the covariance at the converged motion
    /// (scaled by the robust scale over all correspondences, see `motion::finish_estimate`).
    pub(super) fn refine_item(&mut self, round: u8, iteration: u8) {
        let n = self.pair_count.min(N);
        let pairs = self.pairs.get(..n).unwrap_or(&[]);
        let inliers = self.inliers.get(..n).unwrap_or(&[]);
        let it = match ml_iteration(pairs, inliers, &self.motion) {
            Ok(it) => it,
            Err(e) if round < ML_ROUNDS => return self.revert_round(e),
            Err(e) => return self.fail_motion(e),
        };
        let max_iterations = self.config.ml_iterations.min(MAX_ML_ITERATIONS);
        if round >= ML_ROUNDS {
            // Covariance and quality at the converged motion (the update is not applied).
            let median =
                residual_median(pairs, &self.motion, &mut self.scratch).unwrap_or(f64::INFINITY);
            let scale = robust_variance_scale(median, n);
            match finish_estimate(self.motion, &it, scale) {
                Ok(mut estimate) => {
                    estimate.rounds_reverted = self.rounds_reverted;
                    self.quality.inliers = estimate.inliers;
                    self.quality.residual_rms_m = estimate.residual_rms_m;
                    self.quality.chi2_per_dof = estimate.chi2_per_dof;
                    self.quality.covariance_scale = estimate.covariance_scale;
                    self.quality.rounds_reverted = estimate.rounds_reverted;
                    self.estimate = Some(estimate);
                    self.carried = 0;
                    self.phase = Phase::Seed { next: 0 };
                }
                Err(e) => self.fail_motion(e),
            }
            return;
        }
        self.motion = it.motion;
        let next = iteration.saturating_add(1);
        if it.step >= 1e-12 && next < max_iterations {
            self.phase = Phase::Refine {
                round,
                iteration: next,
            };
            return;
        }
        self.kept = Some(Kept {
            solution: self.motion,
            gating: self.gating,
        });
        if round + 1 < ML_ROUNDS {
            let median =
                residual_median(pairs, &self.motion, &mut self.scratch).unwrap_or(f64::INFINITY);
            let gating = Gating {
                motion: self.motion,
                gate: robust_gate(self.config.inlier_gate_chi2, median, n),
            };
            let count = mark_inliers(pairs, &self.motion, gating.gate, &mut self.inliers);
            if count < self.config.min_inliers {
                return self.revert_round(VoError::TooFewInliers { found: count });
            }
            self.gating = gating;
            self.quality.inliers = count;
        }
        self.phase = Phase::Refine {
            round: round + 1,
            iteration: 0,
        };
    }
}
