//! Feature tracking (H04 sec. 2 "Feature Tracking", eq. 9-10; H05 sec. II.C): correlation
//! search around the position predicted by the motion prior, then affine template refinement by
//! iterative minimisation of the grey-level differences.
//!
//! Template coordinates `(u, v)` are pixels relative to the template centre in the previous
//! image; eq. 9 maps them into the new image, `x2 = a u + b v + c`, `y2 = d u + e v + f` (eq. 9
//! with `x1, y1` taken relative to the feature, so `(c, f)` is the tracked feature position).

use super::image::{
    ncc, ncc_scan_prepared, template_stats, Image, ScanTemplate, Template, TemplateF,
};
use super::{MAX_SEARCH_RADIUS_PX, TEMPLATE_HALF, TEMPLATE_PIXELS, TEMPLATE_SIDE};
use nalgebra::{SMatrix, SVector};
use rover_hal::{IMAGE_HEIGHT_PX, IMAGE_WIDTH_PX};

/// Eq. 9 (H04): the affine map of template coordinates into the new image, pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine2 {
    /// `dx2/du`.
    pub a: f64,
    /// `dx2/dv`.
    pub b: f64,
    /// Column of the template centre in the new image, pixels.
    pub c: f64,
    /// `dy2/du`.
    pub d: f64,
    /// `dy2/dv`.
    pub e: f64,
    /// Row of the template centre in the new image, pixels.
    pub f: f64,
}

impl Affine2 {
    /// A pure translation to `(x, y)`.
    pub const fn translation(x: f64, y: f64) -> Self {
        Self {
            a: 1.0,
            b: 0.0,
            c: x,
            d: 0.0,
            e: 1.0,
            f: y,
        }
    }

    /// The image position of template coordinates `(u, v)` (eq. 9).
    pub fn apply(&self, u: f64, v: f64) -> (f64, f64) {
        (
            self.a * u + self.b * v + self.c,
            self.d * u + self.e * v + self.f,
        )
    }
}

/// Which parameters of the warp the refinement estimates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WarpModel {
    /// Translation `(c, f)` only (stereo sub-pixel refinement).
    Translation,
    /// All six affine parameters (eq. 9).
    Affine,
}

/// Result of [`refine_warp`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refined {
    /// The estimated warp.
    pub warp: Affine2,
    /// Root mean square of the grey-level residual after gain and bias, grey levels.
    pub residual_rms: f64,
    /// Photometric gain between the images.
    pub gain: f64,
}

/// Eq. 10 (H04): minimises `M = sum [I1(x1, y1) - (gain * I2(x2, y2) + bias)]^2` over the
/// template `I1` by Gauss-Newton, with `(x2, y2)` from the warp of eq. 9 and bilinear sampling
/// of the new image `I2` (gain and bias absorb exposure differences): the affine model by the
/// inverse compositional iteration ([`refine_affine`]), the translation model (stereo
/// sub-pixel refinement) by the forward-additive one ([`refine_translation`]). At most
/// `iterations` iterations; `None` when the template leaves the image, the normal matrix is
/// singular, the numbers are not finite, or the warp degenerates (scale outside 0.5..2, shear
/// above 0.5, gain outside 0.5..2).
pub fn refine_warp(
    template: &TemplateF,
    image: &Image,
    init: Affine2,
    model: WarpModel,
    iterations: u8,
) -> Option<Refined> {
    match model {
        WarpModel::Affine => refine_affine(template, image, init, iterations),
        WarpModel::Translation => refine_translation(template, image, init, iterations),
    }
}

/// The translation model of [`refine_warp`]: forward-additive Gauss-Newton on `[c, f, gain,
/// bias]` ([`translation_normal_equations`]: all samples share one pair of interpolation
/// weights, so the bilinear gradient is continuous along the iteration's short path). Stops
/// when the step moves the centre less than 0.02 px. (Kept forward-additive: the inverse
/// compositional form, whose Jacobian comes from the template's finite differences, gave
/// 6 gross disparity errors instead of 4 on the Middlebury motorcycle pair, VO-14.)
fn refine_translation(
    template: &TemplateF,
    image: &Image,
    init: Affine2,
    iterations: u8,
) -> Option<Refined> {
    let mut warp = init;
    let mut gain = 1.0f64;
    let mut bias = 0.0f64;
    let mut last_sum_sq = f64::INFINITY;
    for _ in 0..iterations.max(1) {
        let system = translation_normal_equations(template, image, &warp, gain, bias)?;
        let h = SMatrix::<f64, 4, 4>::from_fn(|r, c| system.h[r][c]);
        let g = SVector::<f64, 4>::from(system.g);
        let delta = crate::linalg::cholesky(h)?.solve(&(-g));
        last_sum_sq = system.sum_sq;
        if !delta.iter().all(|v| v.is_finite()) {
            return None;
        }
        warp.c += delta[0];
        warp.f += delta[1];
        gain += delta[2];
        bias += delta[3];
        let shape_ok = (0.5..2.0).contains(&warp.a)
            && (0.5..2.0).contains(&warp.e)
            && warp.b.abs() < 0.5
            && warp.d.abs() < 0.5
            && (0.5..2.0).contains(&gain);
        if !shape_ok {
            return None;
        }
        if delta[0].abs() < 2e-2 && delta[1].abs() < 2e-2 {
            break;
        }
    }
    Some(Refined {
        warp,
        residual_rms: libm::sqrt(last_sum_sq / template.len() as f64),
        gain,
    })
}

/// The affine model of [`refine_warp`] (eq. 9-10) by the inverse compositional Gauss-Newton
/// algorithm (Baker & Matthews, "Lucas-Kanade 20 years on: a unifying framework", IJCV 2004,
/// sec. 3.2, with the linear appearance change on the template side): the residual
/// `e = I2(W(x; p)) - (alpha I1(x) + beta)` is linearised in a warp `W(x; dp)` of the template,
/// so its Jacobian `[alpha grad I1 dW/dp, I1, 1]` comes from the template alone and the normal
/// matrix is factored once per call ([`template_system`]); each iteration samples `I2` (bilinear
/// values, no gradients: [`residual_sums`]), solves with the stored factor and composes
/// `W(p) <- W(p) o W(dp)^-1` ([`compose`]). `alpha = 1 / gain`, `beta = -bias / gain`: the
/// same model as eq. 10, its residual scaled by `1 / gain`. A forward-additive iteration
/// rebuilds the 8x8 normal matrix from the bilinear gradient of `I2`, which jumps at pixel
/// boundaries: with it 27 % of the tracks on the real tilt pairs cycle between two warps until
/// the iteration limit.
///
/// A step that raises the sum of squares is taken back and halved (the bilinear surface is
/// only piecewise smooth); a halved step whose centre move is below 0.02 px ends the iteration
/// at the best state. Stops when the template centre moves less than 0.01 px, after at
/// most `iterations` evaluations.
fn refine_affine(
    template: &TemplateF,
    image: &Image,
    init: Affine2,
    iterations: u8,
) -> Option<Refined> {
    let system = template_system(template)?;
    // State [a, b, c, d, e, f, alpha, beta]; `best` is the last evaluated state whose sum of
    // squares did not rise and `step` the state change taken from it.
    let start = [init.a, init.b, init.c, init.d, init.e, init.f, 1.0, 0.0];
    let mut state = start;
    let mut best = (start, f64::INFINITY);
    let mut step = [0.0f64; 8];
    for _ in 0..iterations.max(1) {
        let [a, b, c, d, e, f, alpha, beta] = state;
        let warp = Affine2 { a, b, c, d, e, f };
        let (sums, sum_sq) = residual_sums(template, &system, image, &warp, alpha, beta)?;
        let next = if sum_sq > best.1 {
            // The last step raised the sum of squares: half of it from the best state.
            step = step.map(|v| 0.5 * v);
            state = best.0;
            if step[2].abs() < 2e-2 && step[5].abs() < 2e-2 {
                break;
            }
            add(state, step)
        } else {
            best = (state, sum_sq);
            let y = system.factor.solve(&SVector::from(sums));
            compose(state, y.into())?
        };
        let moved = [next[2] - state[2], next[5] - state[5]];
        step = sub(next, state);
        state = next;
        let [a, b, _, d, e, _, alpha, _] = state;
        let shape_ok = (0.5..2.0).contains(&a)
            && (0.5..2.0).contains(&e)
            && b.abs() < 0.5
            && d.abs() < 0.5
            && (0.5..2.0).contains(&alpha);
        if !shape_ok {
            return None;
        }
        if moved[0].abs() < 1e-2 && moved[1].abs() < 1e-2 {
            break;
        }
    }
    let [a, b, c, d, e, f, alpha, _] = state;
    Some(Refined {
        warp: Affine2 { a, b, c, d, e, f },
        residual_rms: libm::sqrt(best.1 / template.len() as f64) / best.0[6],
        gain: 1.0 / alpha,
    })
}

/// `a + b` element by element.
fn add(a: [f64; 8], b: [f64; 8]) -> [f64; 8] {
    let mut out = a;
    for (o, v) in out.iter_mut().zip(b) {
        *o += v;
    }
    out
}

/// `a - b` element by element.
fn sub(a: [f64; 8], b: [f64; 8]) -> [f64; 8] {
    let mut out = a;
    for (o, v) in out.iter_mut().zip(b) {
        *o -= v;
    }
    out
}

/// The inverse compositional update of `state` `[a, b, c, d, e, f, alpha, beta]` by the solution
/// `y` of `H0 y = b0` ([`TemplateSystem`], [`residual_sums`]): the template warp `dp = y[..6] / alpha`
/// (the Jacobian's warp columns carry `alpha`), `A <- A (I + dA)^-1`, `t <- t - A' dt`, and
/// `alpha += y[6]`, `beta += y[7]`. `None` if the numbers are not finite.
fn compose(state: [f64; 8], y: [f64; 8]) -> Option<[f64; 8]> {
    let [a, b, c, d, e, f, alpha, beta] = state;
    let [da, db, dc, dd, de, df, dalpha, dbeta] = y;
    let k = 1.0 / alpha;
    let (da, db, dc, dd, de, df) = (k * da, k * db, k * dc, k * dd, k * de, k * df);
    // (I + dA)^-1 = [[1 + de, -db], [-dd, 1 + da]] / det.
    let det = (1.0 + da) * (1.0 + de) - db * dd;
    let (m00, m01, m10, m11) = ((1.0 + de) / det, -db / det, -dd / det, (1.0 + da) / det);
    let (a2, b2) = (a * m00 + b * m10, a * m01 + b * m11);
    let (d2, e2) = (d * m00 + e * m10, d * m01 + e * m11);
    let next = [
        a2,
        b2,
        c - (a2 * dc + b2 * df),
        d2,
        e2,
        f - (d2 * dc + e2 * df),
        alpha + dalpha,
        beta + dbeta,
    ];
    next.iter().all(|v| v.is_finite()).then_some(next)
}

/// The template side of the inverse compositional iteration ([`refine_affine`]): the template
/// gradients and the Cholesky factor of the normal matrix `H0 = sum J0 J0^T` with
/// `J0 = [Tx u, Tx v, Tx, Ty u, Ty v, Ty, T, 1]`, `T` the template, `(Tx, Ty)` its gradient,
/// `(u, v)` template coordinates.
struct TemplateSystem {
    /// `dT/du` per template pixel (central differences, one-sided at the edges), grey levels/px.
    tx: TemplateF,
    /// `dT/dv` per template pixel, grey levels/px.
    ty: TemplateF,
    /// Factor of `H0`.
    factor: nalgebra::linalg::Cholesky<f64, nalgebra::Const<8>>,
}

/// Central-difference gradients of the template (`(T(u + 1) - T(u - 1)) / 2`, one-sided
/// differences on the template's edge rows and columns), grey levels per pixel.
fn template_gradients(template: &TemplateF) -> (TemplateF, TemplateF) {
    let mut tx = [0.0f32; TEMPLATE_PIXELS];
    let mut ty = [0.0f32; TEMPLATE_PIXELS];
    let at = |r: usize, c: usize| template.get(r * TEMPLATE_SIDE + c).copied().unwrap_or(0.0);
    let last = TEMPLATE_SIDE - 1;
    // The neighbours of index `i` along one axis and the factor of their difference.
    let span = |i: usize| {
        let (lo, hi) = (i.saturating_sub(1), (i + 1).min(last));
        (lo, hi, if hi - lo == 2 { 0.5 } else { 1.0 })
    };
    for r in 0..TEMPLATE_SIDE {
        let (r0, r1, ky) = span(r);
        for c in 0..TEMPLATE_SIDE {
            let (c0, c1, kx) = span(c);
            let k = r * TEMPLATE_SIDE + c;
            if let (Some(sx), Some(sy)) = (tx.get_mut(k), ty.get_mut(k)) {
                *sx = kx * (at(r, c1) - at(r, c0));
                *sy = ky * (at(r1, c) - at(r0, c));
            }
        }
    }
    (tx, ty)
}

/// Sums of a per-pixel quantity `p` over the template weighted by the monomials of the
/// template coordinates: `[sum p, sum p u, sum p v, sum p u^2, sum p u v, sum p v^2]`, built
/// from per-row sums `sum_u p`, `sum_u p u`, `sum_u p u^2` (so the per-pixel work does not grow
/// with the number of monomials). Single precision: the per-pixel terms are below 1e7 and a
/// template has 121 of them, so a sum carries a relative rounding error of about 1e-5 of the
/// sum of magnitudes, far below what the Gauss-Newton step of eq. 10 needs.
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    s: f32,
    su: f32,
    sv: f32,
    suu: f32,
    suv: f32,
    svv: f32,
}

impl Moments {
    /// Adds the row sums `r = [sum p, sum p u, sum p u^2]` of template row `v`.
    #[inline(always)]
    fn add_row(&mut self, r: [f32; 3], v: f32) {
        self.s += r[0];
        self.su += r[1];
        self.suu += r[2];
        self.sv += v * r[0];
        self.suv += v * r[1];
        self.svv += v * v * r[0];
    }
}

/// [`TemplateSystem`] of `template`: its gradients and the factor of `H0`. The 36 distinct
/// entries of the affine `H0` are sums of 9 per-pixel products times monomials in `(u, v)`,
/// accumulated per template row ([`Moments`]) in single precision and factored in `f64`.
/// `None` if `H0` is not positive definite (a template without texture in some direction).
fn template_system(template: &TemplateF) -> Option<TemplateSystem> {
    let (tx, ty) = template_gradients(template);
    let half = TEMPLATE_HALF as f32;
    let (mut xx, mut xy, mut yy) = (Moments::default(), Moments::default(), Moments::default());
    let (mut xt, mut yt, mut x1, mut y1) = (
        Moments::default(),
        Moments::default(),
        Moments::default(),
        Moments::default(),
    );
    let (mut tt, mut t1) = (0.0f32, 0.0f32);
    let rows = template
        .chunks_exact(TEMPLATE_SIDE)
        .zip(tx.chunks_exact(TEMPLATE_SIDE))
        .zip(ty.chunks_exact(TEMPLATE_SIDE));
    for (row, ((t_row, x_row), y_row)) in rows.enumerate() {
        let v = row as f32 - half;
        let mut r = [[0.0f32; 3]; 7];
        let mut u = -half;
        for ((&t, &gx), &gy) in t_row.iter().zip(x_row).zip(y_row) {
            for (acc, p) in r
                .iter_mut()
                .zip([gx * gx, gx * gy, gy * gy, gx * t, gy * t, gx, gy])
            {
                let pu = p * u;
                acc[0] += p;
                acc[1] += pu;
                acc[2] += pu * u;
            }
            tt += t * t;
            t1 += t;
            u += 1.0;
        }
        let [rxx, rxy, ryy, rxt, ryt, rx1, ry1] = r;
        xx.add_row(rxx, v);
        xy.add_row(rxy, v);
        yy.add_row(ryy, v);
        xt.add_row(rxt, v);
        yt.add_row(ryt, v);
        x1.add_row(rx1, v);
        y1.add_row(ry1, v);
    }
    let n = template.len() as f32;
    // Upper triangle, J0 = [Tx u, Tx v, Tx, Ty u, Ty v, Ty, T, 1].
    let upper = [
        [xx.suu, xx.suv, xx.su, xy.suu, xy.suv, xy.su, xt.su, x1.su],
        [0.0, xx.svv, xx.sv, xy.suv, xy.svv, xy.sv, xt.sv, x1.sv],
        [0.0, 0.0, xx.s, xy.su, xy.sv, xy.s, xt.s, x1.s],
        [0.0, 0.0, 0.0, yy.suu, yy.suv, yy.su, yt.su, y1.su],
        [0.0, 0.0, 0.0, 0.0, yy.svv, yy.sv, yt.sv, y1.sv],
        [0.0, 0.0, 0.0, 0.0, 0.0, yy.s, yt.s, y1.s],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, tt, t1],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, n],
    ];
    let h = SMatrix::<f64, 8, 8>::from_fn(|r, c| {
        let (i, j) = if c >= r { (r, c) } else { (c, r) };
        f64::from(
            upper
                .get(i)
                .and_then(|row| row.get(j))
                .copied()
                .unwrap_or(0.0),
        )
    });
    Some(TemplateSystem {
        tx,
        ty,
        factor: crate::linalg::cholesky(h)?,
    })
}

/// Margin of the corners of the warped template inside the bilinear sampling range of
/// [`residual_sums`], pixels.
const CORNER_MARGIN_PX: f64 = 1.0 / 64.0;

/// The image side of one inverse compositional iteration ([`refine_affine`]) at `warp`: the
/// residual `e = I2(W(u, v)) - (alpha T + beta)` per template pixel (bilinear values of the
/// new image `I2` at the warp of eq. 9) and `b0 = sum J0 e`, `J0 = [Tx u, Tx v, Tx, Ty u, Ty v,
/// Ty, T, 1]`, with `sum e^2` (grey levels^2). Per-pixel work and sums in single precision
/// (the rover CPU's FPU has 32 single registers against 16 double ones), returned in `f64`.
/// `None` if the warped template leaves the image.
fn residual_sums(
    template: &TemplateF,
    system: &TemplateSystem,
    image: &Image,
    warp: &Affine2,
    alpha: f64,
    beta: f64,
) -> Option<([f64; 8], f64)> {
    let (alpha, beta) = (alpha as f32, beta as f32);
    let half = TEMPLATE_HALF as f32;
    let (a, b, c) = (warp.a as f32, warp.b as f32, warp.c as f32);
    let (d, e, f) = (warp.d as f32, warp.e as f32, warp.f as f32);
    // The warped template is the parallelogram spanned by its four corners (eq. 9 is affine):
    // with the corners at least `CORNER_MARGIN_PX` inside the sampling range, every pixel's
    // 2x2 neighbourhood is in the image (the margin covers the f32 rounding of the per-pixel
    // positions, below 1e-4 px), so the pixel loop needs no floating-point range tests. NaN
    // parameters fail the test.
    let x_hi = (IMAGE_WIDTH_PX - 1) as f64 - CORNER_MARGIN_PX;
    let y_hi = (IMAGE_HEIGHT_PX - 1) as f64 - CORNER_MARGIN_PX;
    let h64 = TEMPLATE_HALF as f64;
    for (u, v) in [(-h64, -h64), (h64, -h64), (-h64, h64), (h64, h64)] {
        let (x, y) = warp.apply(u, v);
        if !(x >= CORNER_MARGIN_PX && x < x_hi && y >= CORNER_MARGIN_PX && y < y_hi) {
            return None;
        }
    }
    let (mut xe, mut ye) = (Moments::default(), Moments::default());
    let (mut te, mut e1, mut ee) = (0.0f32, 0.0f32, 0.0f32);
    // The bilinear values of one row, overwritten whole by every row (zeroed once per call).
    let mut values = [0.0f32; TEMPLATE_SIDE];
    let rows = template
        .chunks_exact(TEMPLATE_SIDE)
        .zip(system.tx.chunks_exact(TEMPLATE_SIDE))
        .zip(system.ty.chunks_exact(TEMPLATE_SIDE));
    for (row, ((t_row, x_row), y_row)) in rows.enumerate() {
        let v = row as f32 - half;
        // Eq. 9 at (0, v); each column adds (a, d) times u.
        let (x_row0, y_row0) = (b * v + c, e * v + f);
        // Pass 1: the row's samples (independent of each other, so an out-of-order core
        // overlaps their load and interpolation chains); pass 2: the sums.
        let mut u = -half;
        for value in values.iter_mut() {
            *value = image.bilinear_f32_inside(a * u + x_row0, d * u + y_row0)?.0;
            u += 1.0;
        }
        let mut r = [[0.0f32; 3]; 2];
        let mut u = -half;
        for (((&t, &gx), &gy), &value) in t_row.iter().zip(x_row).zip(y_row).zip(values.iter()) {
            let res = value - (alpha * t + beta);
            for (acc, p) in r.iter_mut().zip([gx * res, gy * res]) {
                acc[0] += p;
                acc[1] += p * u;
            }
            te += t * res;
            e1 += res;
            ee += res * res;
            u += 1.0;
        }
        let [[sx, sxu, _], [sy, syu, _]] = r;
        xe.add_row([sx, sxu, 0.0], v);
        ye.add_row([sy, syu, 0.0], v);
    }
    Some((
        [xe.su, xe.sv, xe.s, ye.su, ye.sv, ye.s, te, e1].map(f64::from),
        f64::from(ee),
    ))
}

/// Gauss-Newton normal equations `H delta = -g` of eq. 10 at one warp (full matrix `h`,
/// gradient `g`), and the sum of squared residuals, grey levels^2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalEquations<const P: usize> {
    /// `H = sum J J^T`.
    pub h: [[f64; P]; P],
    /// `g = sum J r`.
    pub g: [f64; P],
    /// `sum r^2`.
    pub sum_sq: f64,
}

/// Eq. 10 normal equations of a translation warp (`(c, f)` only) with gain and bias:
/// `J = [jx, jy, I2, 1]`. Per-pixel work and sums in single precision
/// ([`Image::grid_bilinear_f32`]: one pair of interpolation weights for the whole template),
/// returned in `f64`. `None` if the template leaves the image.
pub fn translation_normal_equations(
    template: &TemplateF,
    image: &Image,
    warp: &Affine2,
    gain: f64,
    bias: f64,
) -> Option<NormalEquations<4>> {
    let (gain, bias) = (gain as f32, bias as f32);
    let mut s = [0.0f32; 9];
    let (mut g, mut sum_sq) = ([0.0f32; 4], 0.0f32);
    image.grid_bilinear_f32(warp.c, warp.f, |k, value, gx, gy| {
        let t = template.get(k).copied().unwrap_or(0.0);
        let residual = gain * value + bias - t;
        let (jx, jy) = (gain * gx, gain * gy);
        let products = [
            jx * jx,
            jx * jy,
            jx * value,
            jx,
            jy * jy,
            jy * value,
            jy,
            value * value,
            value,
        ];
        for (acc, p) in s.iter_mut().zip(products) {
            *acc += p;
        }
        for (acc, j) in g.iter_mut().zip([jx, jy, value, 1.0]) {
            *acc += j * residual;
        }
        sum_sq += residual * residual;
    })?;
    let s = s.map(f64::from);
    let n = template.len() as f64;
    let h = [
        [s[0], s[1], s[2], s[3]],
        [s[1], s[4], s[5], s[6]],
        [s[2], s[5], s[7], s[8]],
        [s[3], s[6], s[8], n],
    ];
    Some(NormalEquations {
        h,
        g: g.map(f64::from),
        sum_sq: f64::from(sum_sq),
    })
}

/// Correlation search: the integer position within `radius` pixels of `(x0, y0)` where the
/// template correlates best, with its normalised cross-correlation; `None` if no window fits in
/// the image. Coarse to fine: every second position first, then the 8 neighbours of the best
/// (a quarter of the cost of the full search; the affine refinement then converges from within
/// one pixel).
pub fn search_window(
    template: &Template,
    image: &Image,
    x0: i32,
    y0: i32,
    radius: i32,
) -> Option<(i32, i32, f32)> {
    let stats = template_stats(template);
    let mut best: Option<(i32, i32, f32)> = None;
    let consider = |x: i32, y: i32, best: &mut Option<(i32, i32, f32)>| {
        if let Some(score) = ncc(image, template, stats, x, y) {
            if best.is_none_or(|(_, _, s)| score > s) {
                *best = Some((x, y, score));
            }
        }
    };
    let (y_lo, y_hi) = (y0.saturating_sub(radius), y0.saturating_add(radius));
    let (x_lo, x_hi) = (x0.saturating_sub(radius), x0.saturating_add(radius));
    let columns = (x_hi - x_lo) as usize / 2 + 1;
    let mut scan = [f32::NEG_INFINITY; MAX_SEARCH_RADIUS_PX + 1];
    let window = scan.get_mut(..columns).unwrap_or(&mut []);
    let prepared = ScanTemplate::with_stats(template, stats, 2)?;
    for y in (y_lo..=y_hi).step_by(2) {
        ncc_scan_prepared(image, &prepared, y, x_lo, window);
        for (k, &score) in window.iter().enumerate() {
            if score > f32::NEG_INFINITY && best.is_none_or(|(_, _, s)| score > s) {
                best = Some((x_lo + 2 * k as i32, y, score));
            }
        }
    }
    let (xc, yc, _) = best?;
    for (dx, dy) in [
        (-1, -1),
        (0, -1),
        (1, -1),
        (-1, 0),
        (1, 0),
        (-1, 1),
        (0, 1),
        (1, 1),
    ] {
        consider(xc.saturating_add(dx), yc.saturating_add(dy), &mut best);
    }
    best
}

/// Radius of the first, local stage of [`search_near`], pixels.
pub const LOCAL_SEARCH_RADIUS: i32 = 4;

/// Correlation search in two stages: first [`search_window`] with a radius of
/// [`LOCAL_SEARCH_RADIUS`] (4 px: 25 positions every second pixel, then the 8 neighbours of the
/// best); when its coarse peak is an interior one (the match within 3 px of the prediction
/// `(x0, y0)` along both axes, so the coarse samples around it were all scored) and correlates at
/// least `min_correlation`, it is the match. Otherwise (the prediction is off by more than about
/// 3 px, or no peak) the full search of `radius` pixels runs. With a good motion prior most
/// features stop after the first stage, at about a third of the cost of the full search.
pub fn search_near(
    template: &Template,
    image: &Image,
    x0: i32,
    y0: i32,
    radius: i32,
    min_correlation: f32,
) -> Option<(i32, i32, f32)> {
    if radius > LOCAL_SEARCH_RADIUS {
        let local = search_window(template, image, x0, y0, LOCAL_SEARCH_RADIUS);
        if let Some((x, y, score)) = local {
            let inside = x.abs_diff(x0) < LOCAL_SEARCH_RADIUS as u32
                && y.abs_diff(y0) < LOCAL_SEARCH_RADIUS as u32;
            if inside && score >= min_correlation {
                return local;
            }
        }
    }
    search_window(template, image, x0, y0, radius)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rover_hal::{IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX};
    use std::vec::Vec;

    /// A smooth texture sampled at continuous positions.
    fn texture(x: f64, y: f64) -> f64 {
        128.0
            + 40.0 * libm::sin(0.31 * x + 0.17 * y)
            + 30.0 * libm::cos(0.23 * y - 0.11 * x)
            + 20.0 * libm::sin(0.05 * x * 0.7 + 0.45 * y)
    }

    fn render(map: impl Fn(f64, f64) -> (f64, f64)) -> Vec<u8> {
        let mut img = vec![0u8; IMAGE_PIXELS];
        for y in 0..IMAGE_HEIGHT_PX {
            for x in 0..IMAGE_WIDTH_PX {
                let (sx, sy) = map(x as f64, y as f64);
                img[y * IMAGE_WIDTH_PX + x] = texture(sx, sy).round().clamp(0.0, 255.0) as u8;
            }
        }
        img
    }

    #[test]
    fn vo_5_affine_refinement_recovers_rotation_and_scale() {
        // Image 2 is image 1 rotated by 10 deg and scaled by 1.1 about (300, 200), brighter.
        let img1 = render(|x, y| (x, y));
        let (s, c) = libm::sincos(10f64.to_radians());
        let k = 1.1;
        // p2 = centre + k R (p1 - centre)  <=>  p1 = centre + R^T (p2 - centre) / k
        let img2: Vec<u8> = render(|x, y| {
            let (dx, dy) = (x - 300.0, y - 200.0);
            (
                300.0 + (c * dx + s * dy) / k,
                200.0 + (-s * dx + c * dy) / k,
            )
        })
        .iter()
        .map(|&p| (p as f64 * 0.9 + 10.0) as u8)
        .collect();
        let i1 = Image::new(&img1).unwrap();
        let i2 = Image::new(&img2).unwrap();
        let (x1, y1) = (320.0, 215.0);
        let t = i1.template_f(x1, y1).unwrap();
        let truth = (
            300.0 + k * (c * 20.0 - s * 15.0),
            200.0 + k * (s * 20.0 + c * 15.0),
        );
        let tu8 = i1.template(320, 215).unwrap();
        let (xs, ys, score) =
            search_window(&tu8, &i2, truth.0 as i32 + 3, truth.1 as i32 - 2, 8).unwrap();
        assert!(score > 0.8);
        let init = Affine2::translation(xs as f64, ys as f64);
        let r = refine_warp(&t, &i2, init, WarpModel::Affine, 20).unwrap();
        let err = ((r.warp.c - truth.0).powi(2) + (r.warp.f - truth.1).powi(2)).sqrt();
        assert!(err < 0.1, "position error {err} px ({r:?})");
        assert!((r.warp.a - k * c).abs() < 0.05 && (r.warp.b + k * s).abs() < 0.05);
        assert!((r.warp.d - k * s).abs() < 0.05 && (r.warp.e - k * c).abs() < 0.05);
        // Translation-only refinement is worse under rotation and scale.
        let rt = refine_warp(&t, &i2, init, WarpModel::Translation, 20);
        if let Some(rt) = rt {
            assert!(rt.residual_rms > r.residual_rms);
        }
    }

    /// The inverse compositional sums by the textbook sums over pixels in `f64`: `H0 = sum J0
    /// J0^T`, `b0 = sum J0 e`, `sum e^2` with `J0 = [Tx u, Tx v, Tx, Ty u, Ty v, Ty, T, 1]` and
    /// `e = I2(W(u, v)) - (alpha T + beta)`, with the same sums of the terms' magnitudes (the
    /// scale of the single-precision rounding).
    #[allow(clippy::type_complexity)]
    fn direct_sums(
        t: &TemplateF,
        image: &Image,
        w: &Affine2,
        alpha: f64,
        beta: f64,
    ) -> (([[f64; 8]; 8], [f64; 8], f64), ([[f64; 8]; 8], [f64; 8])) {
        let (mut h, mut g, mut ss) = ([[0.0; 8]; 8], [0.0; 8], 0.0);
        let (mut h_mag, mut g_mag) = ([[0.0; 8]; 8], [0.0; 8]);
        let at = |r: usize, c: usize| f64::from(t[r * TEMPLATE_SIDE + c]);
        let last = TEMPLATE_SIDE - 1;
        for (k, &tv) in t.iter().enumerate() {
            let (c, r) = (k % TEMPLATE_SIDE, k / TEMPLATE_SIDE);
            let u = c as f64 - TEMPLATE_HALF as f64;
            let v = r as f64 - TEMPLATE_HALF as f64;
            // Central differences, one-sided on the edges.
            let tx = match c {
                0 => at(r, 1) - at(r, 0),
                c if c == last => at(r, last) - at(r, last - 1),
                c => 0.5 * (at(r, c + 1) - at(r, c - 1)),
            };
            let ty = match r {
                0 => at(1, c) - at(0, c),
                r if r == last => at(last, c) - at(last - 1, c),
                r => 0.5 * (at(r + 1, c) - at(r - 1, c)),
            };
            let (x, y) = w.apply(u, v);
            let (value, _, _) = image.bilinear(x, y).unwrap();
            let e = value - (alpha * f64::from(tv) + beta);
            let j = [tx * u, tx * v, tx, ty * u, ty * v, ty, f64::from(tv), 1.0];
            for (a, ja) in j.into_iter().enumerate() {
                for (b, jb) in j.into_iter().enumerate() {
                    h[a][b] += ja * jb;
                    h_mag[a][b] += (ja * jb).abs();
                }
                g[a] += ja * e;
                g_mag[a] += (ja * e).abs();
            }
            ss += e * e;
        }
        ((h, g, ss), (h_mag, g_mag))
    }

    #[test]
    fn vo_5_inverse_compositional_sums_equal_the_direct_sums() {
        let img = render(|x, y| (x, y));
        let i = Image::new(&img).unwrap();
        let t = i.template_f(200.3, 150.7).unwrap();
        // (No sample within 1e-3 px of a pixel boundary, where the f32 and f64 positions could
        // take different sides.)
        let w = Affine2 {
            a: 1.0513,
            b: 0.1037,
            c: 203.41,
            d: -0.0711,
            e: 0.9319,
            f: 148.23,
        };
        let (alpha, beta) = (0.9, 4.0);
        let ((h, g, ss), (h_mag, g_mag)) = direct_sums(&t, &i, &w, alpha, beta);
        // Single-precision sums: within 1e-5 of the sum of the terms' magnitudes (the f32
        // rounding of 121 terms, of the positions and of the bilinear samples); a wrong term
        // would be off by its whole size.
        let close = |a: f64, b: f64, mag: f64| (a - b).abs() <= 1e-5 * mag + 1e-6;
        let system = template_system(&t).unwrap();
        let l = system.factor.l();
        let h0 = l * l.transpose();
        let (b0, sum_sq) = residual_sums(&t, &system, &i, &w, alpha, beta).unwrap();
        let mut worst = 0.0f64;
        for a in 0..8 {
            for b in 0..8 {
                worst = worst.max((h0[(a, b)] - h[a][b]).abs() / h_mag[a][b]);
                assert!(close(h0[(a, b)], h[a][b], h_mag[a][b]), "H0[{a}][{b}]");
            }
            worst = worst.max((b0[a] - g[a]).abs() / g_mag[a]);
            assert!(close(b0[a], g[a], g_mag[a]), "b0[{a}] {} {}", b0[a], g[a]);
        }
        println!("VO-5 inverse compositional sums: largest error / magnitude {worst:.2e}");
        assert!(close(sum_sq, ss, ss));
        // The template leaving the image.
        let border = Affine2::translation(3.0, 3.0);
        assert!(residual_sums(&t, &system, &i, &border, 1.0, 0.0).is_none());
        // The translation model's forward-additive normal equations (J = [gain grad I2, I2, 1],
        // r = gain I2 + bias - T) against their direct sums.
        let shift = Affine2::translation(w.c, w.f);
        let (gain, bias) = (1.1, -4.0);
        let tr = translation_normal_equations(&t, &i, &shift, gain, bias).unwrap();
        let (mut h, mut g, mut ss) = ([[0.0f64; 4]; 4], [0.0f64; 4], 0.0f64);
        let (mut h_mag, mut g_mag) = ([[0.0f64; 4]; 4], [0.0f64; 4]);
        for (k, &tv) in t.iter().enumerate() {
            let u = (k % TEMPLATE_SIDE) as f64 - TEMPLATE_HALF as f64;
            let v = (k / TEMPLATE_SIDE) as f64 - TEMPLATE_HALF as f64;
            let (value, gx, gy) = i.bilinear(shift.c + u, shift.f + v).unwrap();
            let r = gain * value + bias - f64::from(tv);
            let j = [gain * gx, gain * gy, value, 1.0];
            for (a, ja) in j.into_iter().enumerate() {
                for (b, jb) in j.into_iter().enumerate() {
                    h[a][b] += ja * jb;
                    h_mag[a][b] += (ja * jb).abs();
                }
                g[a] += ja * r;
                g_mag[a] += (ja * r).abs();
            }
            ss += r * r;
        }
        for a in 0..4 {
            for b in 0..4 {
                assert!(close(tr.h[a][b], h[a][b], h_mag[a][b]), "H[{a}][{b}]");
            }
            assert!(close(tr.g[a], g[a], g_mag[a]), "g[{a}]");
        }
        assert!(close(tr.sum_sq, ss, ss));
        // A flat template has no factor.
        assert!(template_system(&[100.0; TEMPLATE_PIXELS]).is_none());
    }

    /// Both models converge from an integer start to a sub-pixel shift with a photometric
    /// change: position within 0.05 px, eq. 10's gain within 0.02 of the test image's, and a
    /// residual below one grey level (the image's rounding to integers).
    #[test]
    fn vo_5_refinement_recovers_shift_and_gain() {
        // Image 2: image 1 shifted by (1.37, -0.62) px, gain 0.9, bias 10.
        let img1 = render(|x, y| (x, y));
        let img2: Vec<u8> = render(|x, y| (x - 1.37, y + 0.62))
            .iter()
            .map(|&p| (p as f64 * 0.9 + 10.0) as u8)
            .collect();
        let (i1, i2) = (Image::new(&img1).unwrap(), Image::new(&img2).unwrap());
        let t = i1.template_f(250.0, 180.0).unwrap();
        for model in [WarpModel::Affine, WarpModel::Translation] {
            let r = refine_warp(&t, &i2, Affine2::translation(251.0, 179.0), model, 20).unwrap();
            let err = ((r.warp.c - 251.37).powi(2) + (r.warp.f - 179.38).powi(2)).sqrt();
            assert!(err < 0.05, "{model:?}: position error {err} px ({r:?})");
            // The test image is I2 = 0.9 I1 + 10, so eq. 10's gain (I1 = gain I2 + bias) is
            // 1 / 0.9 (within the rounding of the image to integers).
            assert!(
                (r.gain - 1.0 / 0.9).abs() < 0.02,
                "{model:?}: gain {}",
                r.gain
            );
            assert!(
                r.residual_rms < 1.0,
                "{model:?}: residual {}",
                r.residual_rms
            );
        }
    }

    #[test]
    fn vo_5_refinement_fails_cleanly_at_the_border() {
        let img = render(|x, y| (x, y));
        let i = Image::new(&img).unwrap();
        let t = i.template_f(100.0, 100.0).unwrap();
        let r = refine_warp(&t, &i, Affine2::translation(2.0, 2.0), WarpModel::Affine, 5);
        assert!(r.is_none());
        let r = refine_warp(
            &t,
            &i,
            Affine2::translation(f64::NAN, 2.0),
            WarpModel::Affine,
            5,
        );
        assert!(r.is_none());
    }
}
