//! The measurement update shared by every aiding source (H04 App. B eq. 52-56), for a
//! measurement Jacobian `H` that is non-zero only on `C` columns of the error state (a clone's
//! attitude and position, the velocity, the gyro bias...). Work is `O(DIM^2 M)`, never
//! `O(DIM^3)`.
//!
//! - `U = P H'` (gathered from the `C` columns), `S = H P H' + R` (eq. 52);
//! - `K = U S^-1` (eq. 53), through the Cholesky factor `S = L L'`: with `V = U L'^-1`,
//!   `K = V L^-1`;
//! - `P <- P - K S K' = P - V V'` (eq. 54 with the optimal gain: the Joseph form
//!   `(I - K H) P (I - K H)' + K R K'` equals it exactly for `K = U S^-1`), a rank-`M` downdate
//!   evaluated on the upper triangle of the live rows only and mirrored, so `P` stays exactly
//!   symmetric. The expanded Joseph form, `P - U K' - K W'` with `W = U - K S`, takes twice
//!   the products for the same result up to rounding (the gain here is always the optimal
//!   one, computed from the same factor);
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
                // gate and the update then refuse (no panic path).
                if let Some(v) = pcc.get_mut((a, b)) {
                    *v = p.get((ia, ib)).copied().unwrap_or(f64::NAN);
                }
            }
        }
        // `H Pcc H'` over the non-zero entries of `H` only (the relative-pose `H` is half
        // zeros): `A = H Pcc` row by row, then `S = A H'`.
        let mut a = SMatrix::<f64, M, C>::zeros();
        for m in 0..M {
            for c in 0..C {
                let hmc = h.get((m, c)).copied().unwrap_or(f64::NAN);
                if hmc != 0.0 {
                    for k in 0..C {
                        if let (Some(dst), Some(&pv)) = (a.get_mut((m, k)), pcc.get((c, k))) {
                            *dst += hmc * pv;
                        }
                    }
                }
            }
        }
        let mut s = *meas_cov;
        for n in 0..M {
            for c in 0..C {
                let hnc = h.get((n, c)).copied().unwrap_or(f64::NAN);
                if hnc != 0.0 {
                    for m in 0..M {
                        if let (Some(dst), Some(&av)) = (s.get_mut((m, n)), a.get((m, c))) {
                            *dst += av * hnc;
                        }
                    }
                }
            }
        }
        let s = (s + s.transpose()) * 0.5;
        Self { cols, h, r, s }
    }

    /// Eq. 46: `d_m^2 = r' S^-1 r`; `None` when `S` is not positive definite.
    pub fn mahalanobis2(&self) -> Option<f64> {
        mahalanobis2(&self.s, &self.r)
    }

    /// `U = P H'` (`DIM x M`) written row by row into `rows` (row `i` of `U` is `rows[i]`,
    /// the layout the forward substitution and the downdate read): one pass over a column of
    /// `P` per non-zero entry of `H`. Rows of released clones come out zero (their rows of
    /// `P` are). `false` when a column lies outside the state (a programming error the update
    /// refuses).
    fn u_rows(&self, p: &Cov, rows: &mut [[f64; M]; DIM]) -> bool {
        for (c, &ic) in self.cols.iter().enumerate() {
            let Some(pcol) = ic
                .checked_mul(DIM)
                .and_then(|start| p.as_slice().get(start..start.saturating_add(DIM)))
            else {
                return false;
            };
            for m in 0..M {
                let hmc = self.h.get((m, c)).copied().unwrap_or(f64::NAN);
                if hmc != 0.0 {
                    for (row, pv) in rows.iter_mut().zip(pcol.iter()) {
                        if let Some(dst) = row.get_mut(m) {
                            *dst += hmc * pv;
                        }
                    }
                }
            }
        }
        true
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

    /// Apply an innovation (eq. 53-56), then run the covariance health check. With the
    /// Cholesky factor `S = L L'` and `V = U L'^-1` (`DIM x M`): `K = V L^-1`, so
    /// `K S K' = V V'` and the update `P - K S K'` (eq. 54 with the optimal gain) is the
    /// rank-`M` downdate `P - V V'`, evaluated on the upper triangle of the live rows and
    /// mirrored (exactly symmetric); `dx = K r = V (L^-1 r)` (eq. 55-56).
    pub(crate) fn fuse<const M: usize, const C: usize>(
        &mut self,
        inn: &Innovation<M, C>,
    ) -> Result<(), EstError> {
        let chol = crate::linalg::cholesky(inn.s).ok_or(EstError::ResidualCovarianceNotPositive)?;
        self.touch();
        let l = chol.l_dirty();
        // Reciprocals of the factor's diagonal (positive: the factorisation succeeded).
        let mut inv_diag = [0.0; M];
        for (k, v) in inv_diag.iter_mut().enumerate() {
            *v = 1.0 / l.get((k, k)).copied().unwrap_or(f64::NAN);
        }
        // Rows and columns of released clones are zero in P, hence in U and V: they are skipped.
        let (live, count) = self.live_indices();
        let live = live.get(..count).unwrap_or(&[]);
        // Row i of V = U L'^-1 (`V' = L^-1 U'`), for the live rows only (the others stay
        // zero): `U = P H'` straight into this layout, then a forward substitution per row. `v * 0` is 0 for a finite entry and NaN otherwise: one
        // multiplication and one addition per entry, no branch.
        let mut vt = [[0.0; M]; DIM];
        if !inn.u_rows(&self.p, &mut vt) {
            return Err(EstError::ResidualCovarianceNotPositive);
        }
        let mut probe = 0.0;
        for &i in live {
            let Some(row) = vt.get_mut(i) else {
                return Err(EstError::ResidualCovarianceNotPositive);
            };
            forward_substitute(l, &inv_diag, row);
            for v in row.iter() {
                probe += v * 0.0;
            }
        }
        let mut y = [0.0; M];
        for (dst, v) in y.iter_mut().zip(inn.r.iter()) {
            *dst = *v;
        }
        forward_substitute(l, &inv_diag, &mut y);
        for v in y.iter() {
            probe += v * 0.0;
        }
        if probe != 0.0 {
            return Err(EstError::ResidualCovarianceNotPositive);
        }
        // `dx = K r = V (L^-1 r)`, live rows (the others zero).
        let mut dx = ErrorVec::zeros();
        for &i in live {
            if let (Some(d), Some(vi)) = (dx.get_mut(i), vt.get(i)) {
                let mut acc = 0.0;
                for (a, b) in vi.iter().zip(y.iter()) {
                    acc += a * b;
                }
                *d = acc;
            }
        }
        // The downdate two columns `j0`, `j1` at a time: each row `i` of `V` is loaded once for
        // both products (the two columns' rows of `V` stay in registers). Every entry is the
        // same sum in the same order as one column at a time, so the result is bit-identical.
        let row = |k: usize| -> Option<[f64; M]> { vt.get(k).copied() };
        let mut b = 0;
        while b < live.len() {
            let Some(&j0) = live.get(b) else {
                break;
            };
            let j1 = live.get(b + 1).copied();
            let (Some(v0), v1) = (row(j0), j1.and_then(row)) else {
                b += 1;
                continue;
            };
            for &i in live.get(..=b).unwrap_or(&[]) {
                let Some(vi) = row(i) else {
                    continue;
                };
                let mut acc0 = 0.0;
                for (a, c) in vi.iter().zip(v0.iter()) {
                    acc0 += a * c;
                }
                self.downdate(i, j0, acc0);
                if let (Some(j1), Some(v1)) = (j1, v1) {
                    let mut acc1 = 0.0;
                    for (a, c) in vi.iter().zip(v1.iter()) {
                        acc1 += a * c;
                    }
                    self.downdate(i, j1, acc1);
                }
            }
            match (j1, v1) {
                (Some(j1), Some(v1)) => {
                    let mut acc = 0.0;
                    for (a, c) in v1.iter().zip(v1.iter()) {
                        acc += a * c;
                    }
                    self.downdate(j1, j1, acc);
                    b += 2;
                }
                _ => b += 1,
            }
        }
        self.inject(&dx);
        self.check_health()
    }
}

impl Ekf {
    /// `P(i, j) = P(j, i) = P(i, j) - acc`: one entry of the downdate, mirrored.
    #[inline(always)]
    fn downdate(&mut self, i: usize, j: usize, acc: f64) {
        // Live indices are below DIM by construction; the test lets the optimiser drop the
        // matrix's own index checks (no panic path).
        if i >= DIM || j >= DIM {
            return;
        }
        let v = self.p[(i, j)] - acc;
        self.p[(i, j)] = v;
        self.p[(j, i)] = v;
    }
}

/// Eq. 46: `d_m^2 = r' S^-1 r`; `None` when `S` is not positive definite.
pub(crate) fn mahalanobis2<const M: usize>(
    s: &SMatrix<f64, M, M>,
    r: &SVector<f64, M>,
) -> Option<f64> {
    let chol = crate::linalg::cholesky(*s)?;
    let y = chol.solve(r);
    let d2 = r.dot(&y);
    d2.is_finite().then_some(d2)
}

/// `x <- L^-1 x` for the lower-triangular `L` (entries above the diagonal ignored) with the
/// reciprocals `inv_diag` of its diagonal: forward substitution, `M (M - 1) / 2` products.
fn forward_substitute<const M: usize>(
    l: &SMatrix<f64, M, M>,
    inv_diag: &[f64; M],
    x: &mut [f64; M],
) {
    for i in 0..M {
        let mut s = x[i];
        for k in 0..i {
            s -= l[(i, k)] * x[k];
        }
        x[i] = s * inv_diag[i];
    }
}
