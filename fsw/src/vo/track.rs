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
use super::{MAX_SEARCH_RADIUS_PX, TEMPLATE_HALF, TEMPLATE_SIDE};
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
/// template by Gauss-Newton, with `(x2, y2)` from the warp of eq. 9 and bilinear sampling of the
/// new image (gain and bias absorb exposure differences). At most `iterations` iterations;
/// `None` when the template leaves the image, the normal matrix is singular, the numbers are not
/// finite, or the warp degenerates (scale outside 0.5..2, shear above 0.5, gain outside
/// 0.5..2).
pub fn refine_warp(
    template: &TemplateF,
    image: &Image,
    init: Affine2,
    model: WarpModel,
    iterations: u8,
) -> Option<Refined> {
    let mut warp = init;
    let mut gain = 1.0f64;
    let mut bias = 0.0f64;
    let mut last_sum_sq = f64::INFINITY;
    for _ in 0..iterations.max(1) {
        // Parameters: [a, b, c, d, e, f, gain, bias]; the translation model estimates only
        // [c, f, gain, bias] from a 4x4 system.
        let (delta, sum_sq) = match model {
            WarpModel::Affine => {
                let system = affine_normal_equations(template, image, &warp, gain, bias)?;
                let h = SMatrix::<f64, 8, 8>::from_fn(|r, c| system.h[r][c]);
                let g = SVector::<f64, 8>::from(system.g);
                (crate::linalg::cholesky(h)?.solve(&(-g)), system.sum_sq)
            }
            WarpModel::Translation => {
                let system = translation_normal_equations(template, image, &warp, gain, bias)?;
                let h = SMatrix::<f64, 4, 4>::from_fn(|r, c| system.h[r][c]);
                let g = SVector::<f64, 4>::from(system.g);
                let ds = crate::linalg::cholesky(h)?.solve(&(-g));
                let delta =
                    SVector::<f64, 8>::from([0.0, 0.0, ds[0], 0.0, 0.0, ds[1], ds[2], ds[3]]);
                (delta, system.sum_sq)
            }
        };
        last_sum_sq = sum_sq;
        if !delta.iter().all(|v| v.is_finite()) {
            return None;
        }
        warp.a += delta[0];
        warp.b += delta[1];
        warp.c += delta[2];
        warp.d += delta[3];
        warp.e += delta[4];
        warp.f += delta[5];
        gain += delta[6];
        bias += delta[7];
        let shape_ok = (0.5..2.0).contains(&warp.a)
            && (0.5..2.0).contains(&warp.e)
            && warp.b.abs() < 0.5
            && warp.d.abs() < 0.5
            && (0.5..2.0).contains(&gain);
        if !shape_ok {
            return None;
        }
        if delta[2].abs() < 2e-2 && delta[5].abs() < 2e-2 {
            break;
        }
    }
    Some(Refined {
        warp,
        residual_rms: libm::sqrt(last_sum_sq / template.len() as f64),
        gain,
    })
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

/// Margin of the corners of the warped template inside the bilinear sampling range of
/// [`affine_normal_equations`], pixels.
const CORNER_MARGIN_PX: f64 = 1.0 / 64.0;

/// Eq. 10 normal equations of the affine warp (eq. 9) with gain and bias, at `warp`: the
/// Jacobian of the residual `gain * I2(x2, y2) + bias - I1` per template pixel `(u, v)` is
/// `J = [jx u, jx v, jx, jy u, jy v, jy, I2, 1]` with `(jx, jy) = gain * grad I2`. The 36
/// distinct entries of `sum J J^T` are sums of 11 per-pixel products times monomials in
/// `(u, v)`, accumulated per template row ([`Moments`]). The per-pixel work (warp, bilinear
/// sample [`Image::bilinear_f32`], products, sums) is single precision (the rover CPU's FPU has
/// 32 single registers against 16 double ones, so the accumulators stay in registers); the
/// sums are returned in `f64`. `None` if the warped template leaves the image.
pub fn affine_normal_equations(
    template: &TemplateF,
    image: &Image,
    warp: &Affine2,
    gain: f64,
    bias: f64,
) -> Option<NormalEquations<8>> {
    let half = TEMPLATE_HALF as f32;
    let (a, b, c) = (warp.a as f32, warp.b as f32, warp.c as f32);
    let (d, e, f) = (warp.d as f32, warp.e as f32, warp.f as f32);
    let (gain, bias) = (gain as f32, bias as f32);
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
    // Per-pixel products with their u-moments: jx^2, jx jy, jy^2 (up to u^2); jx I2, jy I2,
    // jx, jy, jx r, jy r (up to u); I2^2, I2, I2 r, r, r^2 (plain sums).
    let (mut xx, mut xy, mut yy) = (Moments::default(), Moments::default(), Moments::default());
    let (mut xi, mut yi, mut x1, mut y1) = (
        Moments::default(),
        Moments::default(),
        Moments::default(),
        Moments::default(),
    );
    let (mut xr, mut yr) = (Moments::default(), Moments::default());
    let (mut ii, mut i1, mut ir, mut r1, mut rr) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    // The samples of one row, overwritten whole by every row (zeroed once per call: zeroing it
    // per row was a 176-byte `memclr` per row on the rover CPU, issue 18).
    let mut samples = [[0.0f32; 4]; TEMPLATE_SIDE];
    for (row, t_row) in template.chunks_exact(TEMPLATE_SIDE).enumerate() {
        let v = row as f32 - half;
        // Eq. 9 at (0, v); each column adds (a, d) times u.
        let (x_row, y_row) = (b * v + c, e * v + f);
        // Pass 1: the samples of the row, [I2, jx, jy, r] per pixel. Passes 2 and 3 accumulate
        // them in two groups, so each group's accumulators stay in registers.
        let mut u = -half;
        for (sample, &t) in samples.iter_mut().zip(t_row.iter()) {
            let (value, gx, gy) = image.bilinear_f32_inside(a * u + x_row, d * u + y_row)?;
            *sample = [value, gain * gx, gain * gy, gain * value + bias - t];
            u += 1.0;
        }
        let mut rows = [[0.0f32; 3]; 3];
        let mut u = -half;
        for &[value, jx, jy, residual] in samples.iter() {
            for (acc, p) in rows.iter_mut().zip([jx * jx, jx * jy, jy * jy]) {
                let pu = p * u;
                acc[0] += p;
                acc[1] += pu;
                acc[2] += pu * u;
            }
            ii += value * value;
            i1 += value;
            ir += value * residual;
            r1 += residual;
            rr += residual * residual;
            u += 1.0;
        }
        let mut rows1 = [[0.0f32; 2]; 6];
        let mut u = -half;
        for &[value, jx, jy, residual] in samples.iter() {
            for (acc, p) in
                rows1
                    .iter_mut()
                    .zip([jx * value, jy * value, jx, jy, jx * residual, jy * residual])
            {
                acc[0] += p;
                acc[1] += p * u;
            }
            u += 1.0;
        }
        let [rxx, rxy, ryy] = rows;
        xx.add_row(rxx, v);
        xy.add_row(rxy, v);
        yy.add_row(ryy, v);
        let [rxi, ryi, rx1, ry1, rxr, ryr] = rows1.map(|[s0, s1]| [s0, s1, 0.0]);
        xi.add_row(rxi, v);
        yi.add_row(ryi, v);
        x1.add_row(rx1, v);
        y1.add_row(ry1, v);
        xr.add_row(rxr, v);
        yr.add_row(ryr, v);
    }
    let n = template.len() as f32;
    // Upper triangle, J = [jx u, jx v, jx, jy u, jy v, jy, I2, 1].
    let upper = [
        [xx.suu, xx.suv, xx.su, xy.suu, xy.suv, xy.su, xi.su, x1.su],
        [0.0, xx.svv, xx.sv, xy.suv, xy.svv, xy.sv, xi.sv, x1.sv],
        [0.0, 0.0, xx.s, xy.su, xy.sv, xy.s, xi.s, x1.s],
        [0.0, 0.0, 0.0, yy.suu, yy.suv, yy.su, yi.su, y1.su],
        [0.0, 0.0, 0.0, 0.0, yy.svv, yy.sv, yi.sv, y1.sv],
        [0.0, 0.0, 0.0, 0.0, 0.0, yy.s, yi.s, y1.s],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ii, i1],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, n],
    ];
    let mut h = [[0.0; 8]; 8];
    for r in 0..8 {
        for c in 0..8 {
            h[r][c] = f64::from(if c >= r { upper[r][c] } else { upper[c][r] });
        }
    }
    Some(NormalEquations {
        h,
        g: [xr.su, xr.sv, xr.s, yr.su, yr.sv, yr.s, ir, r1].map(f64::from),
        sum_sq: f64::from(rr),
    })
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

    /// The normal equations by the textbook sum over pixels of `J J^T` and `J r` in `f64`, and
    /// the same sums of the terms' magnitudes (the scale of the single-precision rounding).
    #[allow(clippy::type_complexity)]
    fn direct_sums(
        t: &TemplateF,
        image: &Image,
        w: &Affine2,
        gain: f64,
        bias: f64,
    ) -> (([[f64; 8]; 8], [f64; 8], f64), ([[f64; 8]; 8], [f64; 8])) {
        let (mut h, mut g, mut ss) = ([[0.0; 8]; 8], [0.0; 8], 0.0);
        let (mut h_mag, mut g_mag) = ([[0.0; 8]; 8], [0.0; 8]);
        for (k, &tv) in t.iter().enumerate() {
            let u = (k % TEMPLATE_SIDE) as f64 - TEMPLATE_HALF as f64;
            let v = (k / TEMPLATE_SIDE) as f64 - TEMPLATE_HALF as f64;
            let (x, y) = w.apply(u, v);
            let (value, gx, gy) = image.bilinear(x, y).unwrap();
            let r = gain * value + bias - f64::from(tv);
            let (jx, jy) = (gain * gx, gain * gy);
            let j = [jx * u, jx * v, jx, jy * u, jy * v, jy, value, 1.0];
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
        ((h, g, ss), (h_mag, g_mag))
    }

    #[test]
    fn vo_5_normal_equations_equal_the_direct_sums() {
        let img = render(|x, y| (x, y));
        let i = Image::new(&img).unwrap();
        let t = i.template_f(200.3, 150.7).unwrap();
        // (No sample within 1e-3 px of a pixel boundary, where the bilinear gradient is
        // one-sided and the f32 and f64 positions could take different sides.)
        let w = Affine2 {
            a: 1.0513,
            b: 0.1037,
            c: 203.41,
            d: -0.0711,
            e: 0.9319,
            f: 148.23,
        };
        let (gain, bias) = (1.1, -4.0);
        let ((h, g, ss), (h_mag, g_mag)) = direct_sums(&t, &i, &w, gain, bias);
        // Single-precision sums: within 1e-5 of the sum of the terms' magnitudes (the f32
        // rounding of 121 terms, of the positions and of the bilinear samples; measured up to
        // 2.4e-6, the residual's cancellation `gain I2 + bias - I1`); a wrong term would be off
        // by its whole size.
        let close = |a: f64, b: f64, mag: f64| (a - b).abs() <= 1e-5 * mag + 1e-6;
        let affine = affine_normal_equations(&t, &i, &w, gain, bias).unwrap();
        let mut worst = 0.0f64;
        for (a, (row, expected)) in affine.h.iter().zip(&h).enumerate() {
            for (b, (&x, &y)) in row.iter().zip(expected).enumerate() {
                worst = worst.max((x - y).abs() / h_mag[a][b]);
                assert!(close(x, y, h_mag[a][b]), "H[{a}][{b}] {x} {y}");
            }
            worst = worst.max((affine.g[a] - g[a]).abs() / g_mag[a]);
            assert!(
                close(affine.g[a], g[a], g_mag[a]),
                "g[{a}] {} {} {}",
                affine.g[a],
                g[a],
                g_mag[a]
            );
        }
        println!("VO-5 normal equations: largest error / magnitude {worst:.2e}");
        assert!(close(affine.sum_sq, ss, ss));
        // The translation system is the [c, f, gain, bias] block of the affine one.
        let shift = Affine2::translation(w.c, w.f);
        let ((h, g, ss), (h_mag, g_mag)) = direct_sums(&t, &i, &shift, gain, bias);
        let tr = translation_normal_equations(&t, &i, &shift, gain, bias).unwrap();
        let idx = [2, 5, 6, 7];
        for (a, &ia) in idx.iter().enumerate() {
            for (b, &ib) in idx.iter().enumerate() {
                assert!(close(tr.h[a][b], h[ia][ib], h_mag[ia][ib]), "H[{a}][{b}]");
            }
            assert!(close(tr.g[a], g[ia], g_mag[ia]), "g[{a}]");
        }
        assert!(close(tr.sum_sq, ss, ss));
        assert!(
            affine_normal_equations(&t, &i, &Affine2::translation(3.0, 3.0), 1.0, 0.0).is_none()
        );
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
