//! Relative-pose update by stochastic cloning (H04 eq. 28-45).
//!
//! The measurement is a [`RelativePose`] between `t0` and `t1`: `t0` must be a live clone, `t1`
//! the current state time or a live clone (a VO result that arrives frames after its capture is
//! applied at the two capture clones, exactly, eq. 41-45; the current state receives the
//! correction through the cross-covariance `F P_kk`).
//!
//! With the rover-frame attitude errors `dtheta_0`, `dtheta_1` of the two endpoints and the
//! [`RelativePose`] noise convention (`true = exp([n_theta]x) meas`, `true = meas + n_p`):
//!
//! - predicted rotation `C_01 = C_0' C_1`, translation `z_p = C_0' (p_1 - p_0)` (eq. 30);
//! - residual `r_theta = log(rot_meas C_01')`, `r_p = trans_meas - z_p` (eq. 55);
//! - `r_theta = -dtheta_0 + C_01 dtheta_1 - n_theta` (eq. 39: H04's `Xi`-projected quaternion
//!   error, here as a rotation vector in `R0`),
//!   `r_p = [z_p]x dtheta_0 - C_0' dp_0 + C_0' dp_1 - n_p` (eq. 31).
//!
//! So `H = Gamma [D1 D2]` (eq. 40) with `Gamma = diag(C_0', C_0')` folded into the blocks:
//! `D1 -> [[-I, 0], [[z_p]x, -C_0']]` on `[dtheta_0, dp_0]` and `D2 -> [[C_01, 0], [0, C_0']]`
//! on `[dtheta_1, dp_1]`. Components with `observed[k] == false` have their row of `H` and
//! residual zeroed and an identity in `S`, so they change nothing and do not count in the
//! gate's degrees of freedom.

use super::fusion::Innovation;
use super::gate::{chi2_95, GateDecision};
use super::state::{clone_index, log_quat, rot, skew, I_P, I_THETA};
use super::{Ekf, EstError};
use crate::types::{Mat3, Mat6, Quat, RelativePose, Vec3, Vec6};
use nalgebra::SMatrix;

/// One end of a relative pose: its nominal pose and the columns of its attitude and position.
struct Endpoint {
    q_nr: Quat,
    p_n: Vec3,
    i_theta: usize,
    i_p: usize,
}

impl Ekf {
    /// Eq. 46 without changing the state: the Mahalanobis test of `m` against the current
    /// estimate and clones.
    pub fn gate_relative_pose(&self, m: &RelativePose) -> Result<GateDecision, EstError> {
        let (inn, dof) = self.relative_pose_innovation(m)?;
        decision(&inn, dof)
    }

    /// Eq. 28-45: gate the relative pose (eq. 46) and apply it when `gated` is false or the
    /// gate accepts it. Use `gated = true` for kinematic odometry (a rejection means slip) and
    /// for VO when outliers are possible. The returned decision says whether it was applied.
    pub fn update_relative_pose(
        &mut self,
        m: &RelativePose,
        gated: bool,
    ) -> Result<GateDecision, EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        let (inn, dof) = self.relative_pose_innovation(m)?;
        let mut d = decision(&inn, dof)?;
        if d.accepted || !gated {
            self.fuse(&inn)?;
            d.applied = true;
        }
        Ok(d)
    }

    /// Eq. 46 on all observed components of `m` at their own covariance, then, when the gate
    /// accepts, eq. 28-45 with `fuse_variance[k]` added to the measurement variance of
    /// component `k` (rad^2 or m^2; an infinite value drops the component: its row of `H` and
    /// its residual zeroed, an identity in `S`, exactly as if `m` had not observed it). The
    /// kinematic aiding gates the whole interval (the slip detector's statistics stay those of
    /// eq. 46) and fuses the lateral translation with a crab allowance: a lateral slip too small
    /// for one interval's test would otherwise be learnt as a heading error.
    pub fn update_relative_pose_allowance(
        &mut self,
        m: &RelativePose,
        fuse_variance: [f64; 6],
    ) -> Result<GateDecision, EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        if fuse_variance.iter().any(|v| v.is_nan() || *v < 0.0) {
            return Err(EstError::InvalidMeasurement);
        }
        let (mut inn, dof) = self.relative_pose_innovation(m)?;
        let mut d = decision(&inn, dof)?;
        if d.accepted {
            for (k, (observed, extra)) in m.observed.iter().zip(fuse_variance.iter()).enumerate() {
                if !*observed || *extra == 0.0 {
                    continue;
                }
                if extra.is_finite() {
                    if let Some(s) = inn.s.get_mut((k, k)) {
                        *s += *extra;
                    }
                } else {
                    inn.h.row_mut(k).fill(0.0);
                    if let Some(r) = inn.r.get_mut(k) {
                        *r = 0.0;
                    }
                    inn.s.row_mut(k).fill(0.0);
                    inn.s.column_mut(k).fill(0.0);
                    if let Some(s) = inn.s.get_mut((k, k)) {
                        *s = 1.0;
                    }
                }
            }
            self.fuse(&inn)?;
            d.applied = true;
        }
        Ok(d)
    }

    fn endpoint(&self, t_us: u64, allow_current: bool) -> Result<Endpoint, EstError> {
        if allow_current && t_us == self.x.t_us {
            return Ok(Endpoint {
                q_nr: self.x.q_nr,
                p_n: self.x.p_n,
                i_theta: I_THETA,
                i_p: I_P,
            });
        }
        let (slot, c) = self
            .find_clone(t_us)
            .ok_or(EstError::NoStateAtTime { t_us })?;
        let i = clone_index(slot);
        Ok(Endpoint {
            q_nr: c.q_nr,
            p_n: c.p_n,
            i_theta: i,
            i_p: i + 3,
        })
    }

    pub(crate) fn relative_pose_innovation(
        &self,
        m: &RelativePose,
    ) -> Result<(Innovation<6, 12>, usize), EstError> {
        let finite = m.rot_0_1.coords.iter().all(|v| v.is_finite())
            && m.trans_0_1_m.iter().all(|v| v.is_finite())
            && m.covariance.iter().all(|v| v.is_finite());
        if !finite {
            return Err(EstError::NonFiniteInput);
        }
        let dof = m.observed.iter().filter(|o| **o).count();
        let bad_variance = m
            .observed
            .iter()
            .enumerate()
            .any(|(k, o)| *o && m.covariance[(k, k)] <= 0.0);
        if m.t0_us >= m.t1_us || dof == 0 || bad_variance {
            return Err(EstError::InvalidMeasurement);
        }
        let e0 = self.endpoint(m.t0_us, false)?;
        let e1 = self.endpoint(m.t1_us, true)?;
        let c0t = rot(&e0.q_nr).transpose();
        let q01 = e0.q_nr.inverse() * e1.q_nr;
        let z_p = c0t * (e1.p_n - e0.p_n);
        let r_theta = log_quat(&(m.rot_0_1 * q01.inverse()));
        let r_p = m.trans_0_1_m - z_p;

        // Columns [dtheta_0, dp_0, dtheta_1, dp_1].
        let mut h = SMatrix::<f64, 6, 12>::zeros();
        h.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(-Mat3::identity()));
        h.fixed_view_mut::<3, 3>(0, 6).copy_from(&rot(&q01));
        h.fixed_view_mut::<3, 3>(3, 0).copy_from(&skew(&z_p));
        h.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-c0t));
        h.fixed_view_mut::<3, 3>(3, 9).copy_from(&c0t);
        let mut r = Vec6::zeros();
        r.fixed_rows_mut::<3>(0).copy_from(&r_theta);
        r.fixed_rows_mut::<3>(3).copy_from(&r_p);
        let mut cov: Mat6 = (m.covariance + m.covariance.transpose()) * 0.5;
        for (k, observed) in m.observed.iter().enumerate() {
            if !*observed {
                h.row_mut(k).fill(0.0);
                r[k] = 0.0;
                cov.row_mut(k).fill(0.0);
                cov.column_mut(k).fill(0.0);
                cov[(k, k)] = 1.0;
            }
        }
        let mut cols = [0usize; 12];
        for k in 0..3 {
            cols[k] = e0.i_theta + k;
            cols[3 + k] = e0.i_p + k;
            cols[6 + k] = e1.i_theta + k;
            cols[9 + k] = e1.i_p + k;
        }
        Ok((Innovation::new(&self.p, cols, h, r, &cov), dof))
    }
}

/// Eq. 46 on an innovation with `dof` observed components.
fn decision(inn: &Innovation<6, 12>, dof: usize) -> Result<GateDecision, EstError> {
    let d2 = inn
        .mahalanobis2()
        .ok_or(EstError::ResidualCovarianceNotPositive)?;
    let threshold = chi2_95(dof).ok_or(EstError::InvalidMeasurement)?;
    Ok(GateDecision {
        accepted: d2 <= threshold,
        d2,
        dof,
        threshold,
        residual: inn.r,
        residual_covariance: inn.s,
        applied: false,
    })
}
