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
        decision_inn(&inn, dof)
    }

    /// [`Self::gate_relative_pose`], keeping the innovation of every component (eq. 28-40, the
    /// costly `H P H'`) so that the interval can then be fused with other observed components
    /// or added variances by [`Self::fuse_kept_relative_pose`] without computing it again
    /// (the kinematic aiding without VO gates the interval at its own covariance, then fuses
    /// it with a slip allowance).
    pub fn gate_relative_pose_kept(
        &self,
        m: &RelativePose,
    ) -> Result<(GateDecision, KeptRelativePose), EstError> {
        let (full, dof) = self.relative_pose_full(m, &[true; 6])?;
        // The gate's `S` and `r` only (the kept innovation stays whole).
        let (mut s, mut r) = (full.s, full.r);
        mask_sr(&mut s, &mut r, &m.observed);
        let d = decision(&s, &r, dof)?;
        Ok((
            d,
            KeptRelativePose {
                full,
                generation: self.generation,
            },
        ))
    }

    /// Eq. 28-45, ungated, on a relative pose kept by [`Self::gate_relative_pose_kept`] with
    /// the components `observed` and `extra_variance[k]` (rad^2 or m^2, finite, non-negative)
    /// added to the measurement variance of component `k`: exactly
    /// [`Self::update_relative_pose`] (ungated) on the same measurement with those components
    /// observed and that covariance, up to rounding. Refused with
    /// [`EstError::StaleMeasurement`] when the filter changed since the gate (a propagation,
    /// update, clone or release in between), and with [`EstError::InvalidMeasurement`] when
    /// nothing is observed or a variance is invalid.
    pub fn fuse_kept_relative_pose(
        &mut self,
        kept: &KeptRelativePose,
        observed: [bool; 6],
        extra_variance: [f64; 6],
    ) -> Result<(), EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        if kept.generation != self.generation {
            return Err(EstError::StaleMeasurement);
        }
        let bad = extra_variance.iter().any(|v| !v.is_finite() || *v < 0.0);
        if bad || !observed.iter().any(|o| *o) {
            return Err(EstError::InvalidMeasurement);
        }
        let mut inn = kept.full;
        mask(&mut inn, &observed, &extra_variance);
        let positive = (0..6).all(|k| !observed[k] || inn.s.get((k, k)).is_some_and(|v| *v > 0.0));
        if !positive {
            return Err(EstError::InvalidMeasurement);
        }
        self.fuse(&inn)
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
        let mut d = decision_inn(&inn, dof)?;
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
        let mut d = decision_inn(&inn, dof)?;
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

    /// The innovation of `m` on its observed components (the others: row of `H` and residual
    /// zero, an identity in `S`), and their number.
    pub(crate) fn relative_pose_innovation(
        &self,
        m: &RelativePose,
    ) -> Result<(Innovation<6, 12>, usize), EstError> {
        // Rows of `H` that are masked anyway are not multiplied (`H P H'` skips zeros).
        let (mut inn, dof) = self.relative_pose_full(m, &m.observed)?;
        mask(&mut inn, &m.observed, &[0.0; 6]);
        Ok((inn, dof))
    }

    /// The innovation of `m` on the six components (eq. 28-40) at the symmetric part of its
    /// covariance, the rows of `H` of the components not in `rows` zeroed (their rows of `S`
    /// are then meaningless: [`mask`] them), after the checks of a valid measurement (finite,
    /// `t0 < t1`, at least one observed component, positive variances of the observed ones);
    /// and the number of observed components.
    fn relative_pose_full(
        &self,
        m: &RelativePose,
        rows: &[bool; 6],
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
        for (k, keep) in rows.iter().enumerate() {
            if !keep {
                h.row_mut(k).fill(0.0);
            }
        }
        let mut r = Vec6::zeros();
        r.fixed_rows_mut::<3>(0).copy_from(&r_theta);
        r.fixed_rows_mut::<3>(3).copy_from(&r_p);
        let cov: Mat6 = (m.covariance + m.covariance.transpose()) * 0.5;
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

/// A relative pose gated by [`Ekf::gate_relative_pose_kept`]: its innovation on all six
/// components (eq. 28-40) and the filter generation it belongs to, for
/// [`Ekf::fuse_kept_relative_pose`].
#[derive(Debug, Clone, Copy)]
pub struct KeptRelativePose {
    full: Innovation<6, 12>,
    generation: u32,
}

/// `inn` (on all six components) restricted in place to the components `observed` (the
/// others: row of `H` and residual zero, row and column of `S` zero with a 1 on the diagonal,
/// so they change nothing), with `extra[k]` added to `S(k, k)` of each observed component
/// (`H P H' + R` is linear in `R`). The observed entries are those of the innovation computed
/// on the masked measurement, bit for bit: row `k` of `S` depends only on rows of `H` that are
/// kept.
fn mask(inn: &mut Innovation<6, 12>, observed: &[bool; 6], extra: &[f64; 6]) {
    for (k, (o, e)) in observed.iter().zip(extra.iter()).enumerate() {
        if *o {
            if *e != 0.0 {
                if let Some(s) = inn.s.get_mut((k, k)) {
                    *s += *e;
                }
            }
        } else {
            inn.h.row_mut(k).fill(0.0);
        }
    }
    mask_sr(&mut inn.s, &mut inn.r, observed);
}

/// The residual and its covariance of [`mask`] (without added variances).
fn mask_sr(s: &mut Mat6, r: &mut Vec6, observed: &[bool; 6]) {
    for (k, o) in observed.iter().enumerate() {
        if *o {
            continue;
        }
        if let Some(v) = r.get_mut(k) {
            *v = 0.0;
        }
        s.row_mut(k).fill(0.0);
        s.column_mut(k).fill(0.0);
        if let Some(v) = s.get_mut((k, k)) {
            *v = 1.0;
        }
    }
}

/// Eq. 46 on an innovation with `dof` observed components.
fn decision_inn(inn: &Innovation<6, 12>, dof: usize) -> Result<GateDecision, EstError> {
    decision(&inn.s, &inn.r, dof)
}

/// Eq. 46 on the residual `r` and its covariance `s` with `dof` observed components.
fn decision(s: &Mat6, r: &Vec6, dof: usize) -> Result<GateDecision, EstError> {
    let d2 = super::fusion::mahalanobis2(s, r).ok_or(EstError::ResidualCovarianceNotPositive)?;
    let threshold = chi2_95(dof).ok_or(EstError::InvalidMeasurement)?;
    Ok(GateDecision {
        accepted: d2 <= threshold,
        d2,
        dof,
        threshold,
        residual: *r,
        residual_covariance: *s,
        applied: false,
    })
}
