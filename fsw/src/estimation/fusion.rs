//! The measurement update shared by every aiding source (H04 App. B eq. 52-56), for a
//! measurement Jacobian `H` that is non-zero only on `C` columns of the error state (a clone's
//! attitude and position, the velocity, the gyro bias...). Work is `O(DIM^2 M)`, never
//! `O(DIM^3)`.
//!
//! - `U = P H'` (gathered from the `C` columns), `S = H P H' + R` (eq. 52);
//! - `K = U S^-1` (eq. 53), through the Cholesky factor of `S`;
//! - Joseph form `P <- (I - K H) P (I - K H)' + K R K'`, which with `H P = U'` expands exactly to
//!   `P - K U' - U K' + K S K' = P - U K' - K W'`, `W = U - K S` (eq. 54; the Joseph form holds for
//!   any gain, so the rounding error of `K` enters at second order only), evaluated on the upper triangle only and
//!   mirrored, so `P` stays exactly symmetric;
//! - `dx = K r` (eq. 55-56), injected into the nominal state ([`Ekf::inject`]).

use super::state::{Cov, ErrorVec, CLONE_DIM, CORE_DIM, DIM};
use super::{Ekf, EstError};
use nalgebra::{SMatrix, SVector};

/// Residual `r`, its covariance `S` and `H` restricted to its columns.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Innovation<const M: usize, const C: usize> {
    pub cols: [usize; C],
    pub h: SMatrix<f64, M, C>,
    pub r: SVector<f64, M>,
    pub s: SMatrix<f64, M, M>,
}

impl<const M: usize, const C: usize> Innovation<M, C> {
    /// Eq. 52: `S = H P H' + R`, with `H` non-zero on `cols` only.
    pub fn new(
        p: &Cov,
        cols: [usize; C],
        h: SMatrix<f64, M, C>,
        r: SVector<f64, M>,
        meas_cov: &SMatrix<f64, M, M>,
    ) -> Self {
        let mut pcc = SMatrix::<f64, C, C>::zeros();
        for (a, &ia) in cols.iter().enumerate() {
            for (b, &ib) in cols.iter().enumerate() {
                // An index outside the state (a programming error) poisons `S`, which the
                // gate and the update then refuse (no panic path, issue 18).
                if let Some(v) = pcc.get_mut((a, b)) {
                    *v = p.get((ia, ib)).copied().unwrap_or(f64::NAN);
                }
            }
        }
        let s = h * pcc * h.transpose() + meas_cov;
        let s = (s + s.transpose()) * 0.5;
        Self { cols, h, r, s }
    }

    /// Eq. 46: `d_m^2 = r' S^-1 r`; `None` when `S` is not positive definite.
    pub fn mahalanobis2(&self) -> Option<f64> {
        let chol = self.s.cholesky()?;
        let y = chol.solve(&self.r);
        let d2 = self.r.dot(&y);
        d2.is_finite().then_some(d2)
    }

    /// `U = P H'`, `DIM x M`.
    fn u(&self, p: &Cov) -> SMatrix<f64, DIM, M> {
        let mut u = SMatrix::<f64, DIM, M>::zeros();
        for (c, &ic) in self.cols.iter().enumerate() {
            if ic >= DIM {
                // Outside the state: a gain the update refuses (non-finite).
                u.fill(f64::NAN);
                return u;
            }
            let pcol = p.column(ic);
            for m in 0..M {
                let hmc = self.h.get((m, c)).copied().unwrap_or(f64::NAN);
                if hmc != 0.0 {
                    u.column_mut(m).axpy(hmc, &pcol, 1.0);
                }
            }
        }
        u
    }
}

impl Ekf {
    /// Indices of the live error-state components (the core and the live clones), in order,
    /// and their count.
    pub(crate) fn live_indices(&self) -> ([usize; DIM], usize) {
        let mut out = [0usize; DIM];
        let mut n = 0;
        let live = self.live_mask();
        for i in 0..DIM {
            let alive = i < CORE_DIM
                || live
                    .get((i - CORE_DIM) / CLONE_DIM)
                    .copied()
                    .unwrap_or(false);
            if alive {
                if let Some(o) = out.get_mut(n) {
                    *o = i;
                }
                n += 1;
            }
        }
        (out, n)
    }

    /// Apply an innovation (eq. 53-56, Joseph form), then run the covariance health check.
    pub(crate) fn fuse<const M: usize, const C: usize>(
        &mut self,
        inn: &Innovation<M, C>,
    ) -> Result<(), EstError> {
        let chol = inn
            .s
            .cholesky()
            .ok_or(EstError::ResidualCovarianceNotPositive)?;
        let u = inn.u(&self.p);
        // K' = S^-1 U'  (M x DIM), solved in place; K = U S^-1 is read from it as K(i, m) =
        // K'(m, i), so the gain is never stored twice (the stack frame stays small).
        let mut kt = u.transpose();
        chol.solve_mut(&mut kt);
        if kt.iter().any(|v| !v.is_finite()) {
            return Err(EstError::ResidualCovarianceNotPositive);
        }
        let dx: ErrorVec = kt.tr_mul(&inn.r);
        // Joseph form P - K U' - U K' + K S K' = P - U K' - K W' with W = U - K S (zero up to
        // rounding), evaluated on the upper triangle and mirrored: exactly symmetric. Rows and
        // columns of released clones are zero in P, hence in U, K and W: they are skipped.
        let mut w: SMatrix<f64, DIM, M> = u;
        w.gemm_tr(-1.0, &kt, &inn.s, 1.0);
        let (live, count) = self.live_indices();
        let live = live.get(..count).unwrap_or(&[]);
        for (b, &j) in live.iter().enumerate() {
            for &i in live.get(..=b).unwrap_or(&[]) {
                // Live indices are below DIM by construction; the test lets the optimiser drop
                // the matrices' own index checks (no panic path, issue 18).
                if i >= DIM || j >= DIM {
                    continue;
                }
                let mut acc = 0.0;
                for m in 0..M {
                    acc += u[(i, m)] * kt[(m, j)] + kt[(m, i)] * w[(j, m)];
                }
                let v = self.p[(i, j)] - acc;
                self.p[(i, j)] = v;
                self.p[(j, i)] = v;
            }
        }
        self.inject(&dx);
        self.check_health()
    }
}
