//! Small fixed-size numerics of the flight code without a panic path: nalgebra's
//! LU and 3x3 SVD keep runtime shape assertions and `unwrap`s that the optimiser cannot
//! remove, and `f64::clamp` asserts its bounds. These replacements index only with constants or
//! checked accesses, run a fixed number of iterations and report failure as a value.
//!
//! No frame or unit of their own: they are plain linear algebra on the caller's quantities.

use crate::types::{Mat3, Mat6, Vec3, Vec6};

/// `x` limited to `[lo, hi]`, as `f64::clamp` but without its assertion `lo <= hi`: with
/// `lo > hi` the result is `lo` when `x < lo`, else `hi` when `x > hi`; a NaN `x` stays NaN
/// (so a non-finite input is still caught by the caller's finiteness checks).
pub fn clamp(x: f64, lo: f64, hi: f64) -> f64 {
    if x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}

/// Solve `m u = rhs` for a 6x6 system by Gaussian elimination with partial pivoting (the
/// inverse-kinematics solve of H04 eq. 20-25). `None` when a pivot is zero or the system is
/// not finite.
// Index loops read like the textbook elimination and compile without bounds checks.
#[allow(clippy::needless_range_loop)]
pub fn solve6(m: &Mat6, rhs: &Vec6) -> Option<Vec6> {
    // Row-major augmented copy: a[r] = [m(r, 0..6), rhs(r)]. Every index below is a loop
    // variable over a constant range, which the optimiser proves in bounds (the image's
    // panic-site count checks that it does).
    let mut a = [[0.0f64; 7]; 6];
    for (r, row) in a.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = if c < 6 { m[(r, c)] } else { rhs[r] };
        }
    }
    for k in 0..6 {
        // Pivot: the largest magnitude in column k at or below row k.
        let mut best = k;
        let mut best_abs = a[k][k].abs();
        for r in (k + 1)..6 {
            let v = a[r][k].abs();
            if v > best_abs {
                best_abs = v;
                best = r;
            }
        }
        if !(best_abs > 0.0 && best_abs.is_finite()) {
            return None;
        }
        if best != k {
            a.swap(k, best.min(5));
        }
        let pivot_row = a[k];
        let inv = 1.0 / pivot_row[k];
        for row in a.iter_mut().skip(k + 1) {
            let f = row[k] * inv;
            for c in k..7 {
                row[c] -= f * pivot_row[c];
            }
        }
    }
    let mut u = [0.0f64; 6];
    for k in (0..6).rev() {
        let mut acc = a[k][6];
        for c in (k + 1)..6 {
            acc -= a[k][c] * u[c];
        }
        u[k] = acc / a[k][k];
    }
    let u = Vec6::from_column_slice(&u);
    u.iter().all(|x| x.is_finite()).then_some(u)
}

/// Largest number of cyclic Jacobi sweeps of [`symmetric_eigen3`]; a 3x3 converges to machine
/// precision in 4 to 6.
pub const JACOBI_SWEEPS: usize = 12;

/// Eigen-decomposition of a symmetric 3x3 matrix by cyclic Jacobi rotations (Golub & Van Loan,
/// Matrix Computations, sec. 8.5): eigenvalues in decreasing order and the matching unit
/// eigenvectors as the columns of a rotation-or-reflection matrix. At most
/// [`JACOBI_SWEEPS`] sweeps. `None` for a non-finite input.
pub fn symmetric_eigen3(s: &Mat3) -> Option<(Vec3, Mat3)> {
    if !s.iter().all(|x| x.is_finite()) {
        return None;
    }
    let mut a = [
        [s.m11, 0.5 * (s.m12 + s.m21), 0.5 * (s.m13 + s.m31)],
        [0.0, s.m22, 0.5 * (s.m23 + s.m32)],
        [0.0, 0.0, s.m33],
    ];
    a[1][0] = a[0][1];
    a[2][0] = a[0][2];
    a[2][1] = a[1][2];
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let scale: f64 = a.iter().flatten().map(|x| x * x).sum();
    for _ in 0..JACOBI_SWEEPS {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        if off <= 1e-32 * scale || off == 0.0 {
            break;
        }
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            rotate(&mut a, &mut v, p, q);
        }
    }
    let mut order = [0usize, 1, 2];
    let d = [a[0][0], a[1][1], a[2][2]];
    // Three-element sort, decreasing.
    if d[order[0]] < d[order[1]] {
        order.swap(0, 1);
    }
    if d[order[1]] < d[order[2]] {
        order.swap(1, 2);
    }
    if d[order[0]] < d[order[1]] {
        order.swap(0, 1);
    }
    let mut values = Vec3::zeros();
    let mut vectors = Mat3::zeros();
    for (k, &j) in order.iter().enumerate() {
        let (Some(value), Some(out)) = (d.get(j), values.get_mut(k)) else {
            return None;
        };
        *out = *value;
        for (r, row) in v.iter().enumerate() {
            if let (Some(x), Some(dst)) = (row.get(j), vectors.get_mut((r, k))) {
                *dst = *x;
            }
        }
    }
    Some((values, vectors))
}

/// One Jacobi rotation zeroing `a[p][q]` (`p < q`, constant indices below 3), accumulated into
/// `v`.
fn rotate(a: &mut [[f64; 3]; 3], v: &mut [[f64; 3]; 3], p: usize, q: usize) {
    let (Some(&apq), Some(&app), Some(&aqq)) = (
        a.get(p).and_then(|r| r.get(q)),
        a.get(p).and_then(|r| r.get(p)),
        a.get(q).and_then(|r| r.get(q)),
    ) else {
        return;
    };
    if apq == 0.0 {
        return;
    }
    let theta = (aqq - app) / (2.0 * apq);
    let t = if theta >= 0.0 {
        1.0 / (theta + crate::linalg::sqrt(theta * theta + 1.0))
    } else {
        -1.0 / (-theta + crate::linalg::sqrt(theta * theta + 1.0))
    };
    let c = 1.0 / crate::linalg::sqrt(t * t + 1.0);
    let s = t * c;
    // A <- J' A J with J the rotation in the (p, q) plane.
    for k in 0..3 {
        let (Some(akp), Some(akq)) = (
            a.get(k).and_then(|r| r.get(p)).copied(),
            a.get(k).and_then(|r| r.get(q)).copied(),
        ) else {
            return;
        };
        if let Some(row) = a.get_mut(k) {
            if let Some(x) = row.get_mut(p) {
                *x = c * akp - s * akq;
            }
            if let Some(x) = row.get_mut(q) {
                *x = s * akp + c * akq;
            }
        }
    }
    for k in 0..3 {
        let (Some(apk), Some(aqk)) = (
            a.get(p).and_then(|r| r.get(k)).copied(),
            a.get(q).and_then(|r| r.get(k)).copied(),
        ) else {
            return;
        };
        if let Some(x) = a.get_mut(p).and_then(|r| r.get_mut(k)) {
            *x = c * apk - s * aqk;
        }
        if let Some(x) = a.get_mut(q).and_then(|r| r.get_mut(k)) {
            *x = s * apk + c * aqk;
        }
    }
    for row in v.iter_mut() {
        let (Some(vp), Some(vq)) = (row.get(p).copied(), row.get(q).copied()) else {
            return;
        };
        if let Some(x) = row.get_mut(p) {
            *x = c * vp - s * vq;
        }
        if let Some(x) = row.get_mut(q) {
            *x = s * vp + c * vq;
        }
    }
}

/// Singular value decomposition `h = U diag(sigma) V'` of a 3x3 matrix from the eigen-
/// decomposition of `h' h` (the method of nalgebra's own 3x3 SVD, McAdams et al. 2011):
/// singular values in decreasing order, `u_k = h v_k / sigma_k` for the two largest and
/// `u_3 = u_1 x u_2` (so `det U = +1`). `None` for a non-finite input or when the second
/// singular value is zero (the caller's rank test needs at least two directions).
pub fn svd3(h: &Mat3) -> Option<(Mat3, Vec3, Mat3)> {
    let (lambda, v) = symmetric_eigen3(&(h.transpose() * h))?;
    let sigma = lambda.map(|l| crate::linalg::sqrt(l.max(0.0)));
    let (v1, v2) = (v.column(0).into_owned(), v.column(1).into_owned());
    if sigma.y.is_nan() || sigma.y <= 0.0 {
        return None;
    }
    let u1 = (h * v1) / sigma.x;
    let u2 = h * v2;
    // Gram-Schmidt against u1 keeps U orthonormal when sigma_2 is small.
    let u2 = u2 - u1 * u1.dot(&u2);
    let n2 = u2.norm();
    if n2.is_nan() || n2 <= 0.0 {
        return None;
    }
    let u2 = u2 / n2;
    let u3 = u1.cross(&u2);
    let u = Mat3::from_columns(&[u1, u2, u3]);
    let ok = u.iter().chain(sigma.iter()).all(|x| x.is_finite());
    ok.then_some((u, sigma, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clamp_matches_core_for_ordered_bounds_and_keeps_nan() {
        for x in [-3.0, -1.0, 0.2, 1.0, 7.0] {
            assert_eq!(clamp(x, -1.0, 1.0), x.clamp(-1.0, 1.0));
        }
        assert!(clamp(f64::NAN, -1.0, 1.0).is_nan());
        // Reversed bounds: no panic, a defined value.
        assert_eq!(clamp(0.0, 1.0, -1.0), 1.0);
    }

    #[test]
    fn solve6_matches_nalgebra_lu_and_refuses_singular() {
        let m = Mat6::from_fn(|r, c| {
            let x = (r * 7 + c * 3) as f64;
            libm::sin(x) + if r == c { 3.0 } else { 0.0 }
        });
        let rhs = Vec6::from_fn(|r, _| (r as f64) - 2.5);
        let u = solve6(&m, &rhs).unwrap();
        let reference = m.lu().solve(&rhs).unwrap();
        assert!((u - reference).norm() < 1e-12, "{u} {reference}");
        assert!((m * u - rhs).norm() < 1e-12);
        let mut singular = m;
        singular.set_row(3, &m.row(1).into_owned());
        assert!(solve6(&singular, &rhs).is_none_or(|u| !u.iter().all(|x| x.abs() < 1e6)));
        assert!(solve6(&Mat6::zeros(), &rhs).is_none());
        let mut nan = m;
        nan[(2, 2)] = f64::NAN;
        assert!(solve6(&nan, &rhs).is_none());
    }

    #[test]
    fn svd3_reconstructs_and_orders() {
        for seed in 0..50u32 {
            let h = Mat3::from_fn(|r, c| libm::sin(f64::from(seed) * 1.3 + (r * 3 + c) as f64));
            let (u, s, v) = svd3(&h).unwrap();
            assert!(s.x >= s.y && s.y >= s.z && s.z >= 0.0, "{s}");
            let back = u * Mat3::from_diagonal(&s) * v.transpose();
            // det U = +1 by construction, so a negative det h shows up as the sign of the
            // third column of V: reconstruct with that sign.
            let sign = (h.determinant() * v.determinant()).signum();
            let back_signed =
                u * Mat3::from_diagonal(&Vec3::new(s.x, s.y, sign * s.z)) * v.transpose();
            // The smallest singular value comes from an eigenvalue of h'h, so it carries an
            // error of about eps sigma_1^2 / sigma_3: 1e-7 covers these conditionings.
            assert!(
                (back - h).norm() < 1e-7 || (back_signed - h).norm() < 1e-7,
                "{h} {back} {back_signed}"
            );
            assert!((u.transpose() * u - Mat3::identity()).norm() < 1e-12);
            assert!((v.transpose() * v - Mat3::identity()).norm() < 1e-12);
            let reference = h.svd(false, false).singular_values;
            let mut r = [reference.x, reference.y, reference.z];
            r.sort_by(|a, b| b.total_cmp(a));
            assert!((s - Vec3::new(r[0], r[1], r[2])).norm() < 1e-7 * (1.0 + s.x));
        }
        assert!(svd3(&Mat3::zeros()).is_none());
    }
}

/// Square root, correctly rounded: the FPU's `vsqrt.f64` on the rover CPU, `libm::sqrt` on the
/// host (bit-identical, [`rover_hal::fpu`]). Any unit: the root of the caller's quantity.
#[inline(always)]
pub fn sqrt(x: f64) -> f64 {
    rover_hal::fpu::sqrt(x)
}

/// Euclidean norm of a vector or matrix (frame and unit of the caller's quantity): nalgebra's
/// `norm` (the root of `norm_squared`) with the FPU's square root ([`sqrt`]), bit-identical.
#[inline(always)]
pub fn norm<const R: usize, const C: usize>(v: &nalgebra::SMatrix<f64, R, C>) -> f64 {
    sqrt(v.norm_squared())
}

/// Cholesky factor `m = L L'` of a symmetric positive-definite `N x N` matrix (its lower
/// triangle is read; any frame and unit), computed operation for operation as nalgebra's
/// `Cholesky::new` (column `j` less `L(j, k)` times column `k` for every `k < j`, the root of
/// the pivot, the column below it divided by the root), so the factor is bit-identical to it,
/// with the FPU's square root ([`sqrt`]) instead of `libm`'s emulation (the timing budget). `None` when
/// a pivot is zero, negative or NaN, as nalgebra. The result is nalgebra's `Cholesky`, so its
/// `solve`, `inverse` and `l_dirty` are nalgebra's own.
// Index loops over constant ranges: the optimiser proves them in bounds (the image's
// panic-site count checks that it does).
#[allow(clippy::needless_range_loop)]
pub fn cholesky<const N: usize>(
    m: nalgebra::SMatrix<f64, N, N>,
) -> Option<nalgebra::linalg::Cholesky<f64, nalgebra::Const<N>>> {
    let mut a = m;
    for j in 0..N {
        for k in 0..j {
            let factor = -a[(j, k)];
            for i in j..N {
                // nalgebra's `axpy(factor, col_k, 1)`: `factor * x + 1 * y`; `1 * y` is `y` and
                // the addition commutes exactly.
                a[(i, j)] += factor * a[(i, k)];
            }
        }
        let diag = a[(j, j)];
        if diag <= 0.0 || diag.is_nan() {
            return None;
        }
        let denom = sqrt(diag);
        a[(j, j)] = denom;
        for i in j + 1..N {
            a[(i, j)] /= denom;
        }
    }
    Some(nalgebra::linalg::Cholesky::pack_dirty(a))
}

#[cfg(test)]
mod cholesky_tests {
    use super::*;
    use nalgebra::SMatrix;
    use rand::{Rng, SeedableRng};

    fn check<const N: usize>(rng: &mut rand_chacha::ChaCha8Rng) {
        let a = SMatrix::<f64, N, N>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let m = a * a.transpose() + SMatrix::<f64, N, N>::identity() * 1e-3;
        let ours = cholesky(m).expect("positive definite");
        let theirs = m.cholesky().expect("positive definite");
        for (x, y) in ours.l_dirty().iter().zip(theirs.l_dirty().iter()) {
            assert_eq!(x.to_bits(), y.to_bits());
        }
        let b = SMatrix::<f64, N, 1>::from_fn(|r, _| r as f64 - 0.5);
        assert_eq!(ours.solve(&b), theirs.solve(&b));
    }

    #[test]
    fn factor_is_nalgebras_bit_for_bit_and_refuses_what_it_refuses() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(18);
        for _ in 0..200 {
            check::<1>(&mut rng);
            check::<3>(&mut rng);
            check::<6>(&mut rng);
        }
        let mut m = Mat3::identity();
        m[(1, 1)] = 0.0;
        assert!(cholesky(m).is_none() && m.cholesky().is_none());
        m[(1, 1)] = -1.0;
        assert!(cholesky(m).is_none());
        m[(1, 1)] = f64::NAN;
        assert!(cholesky(m).is_none());
        assert_eq!(norm(&Vec3::new(3.0, 4.0, 12.0)), 13.0);
    }
}
