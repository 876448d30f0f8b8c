//! Stereo matching and ray-gap triangulation with covariance (H04 sec. 2 "Feature Gap Analysis
//! and Covariance Computation", eq. 1-8; H05 sec. II.B).
//!
//! All geometry is in the left camera frame `K` (x right, y down, z optical axis); the left
//! camera centre is `C1 = 0` and the right one `C2 = (baseline, 0, 0)`.

use super::image::{
    ncc, ncc_from_sums, ncc_scan, region_stats, stats_i32, template_scale, template_stats, Image,
    TemplateRegion,
};
use super::track::{refine_warp, Affine2, WarpModel};
use super::{VoConfig, VoError, MAX_DISPARITY_PX, TEMPLATE_HALF, TEMPLATE_SIDE};
use crate::types::{Mat3, Vec3};
use nalgebra::{Matrix3x4, Vector3};
use rover_hal::StereoCalibration;

/// Intrinsics of a rectified pair (both cameras identical), pixels and metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeStereo {
    /// Focal length along x, pixels.
    pub fx_px: f64,
    /// Focal length along y, pixels.
    pub fy_px: f64,
    /// Principal point x, pixels.
    pub cx_px: f64,
    /// Principal point y, pixels.
    pub cy_px: f64,
    /// Baseline, m (right camera at `+baseline_m` along `K`'s x).
    pub baseline_m: f64,
}

impl PinholeStereo {
    /// The intrinsics of a calibration; [`VoError::InvalidCalibration`] for non-finite or
    /// non-positive focal lengths or baseline.
    pub fn from_calibration(c: &StereoCalibration) -> Result<Self, VoError> {
        let s = Self {
            fx_px: c.fx_px,
            fy_px: c.fy_px,
            cx_px: c.cx_px,
            cy_px: c.cy_px,
            baseline_m: c.baseline_m,
        };
        let finite = [s.fx_px, s.fy_px, s.cx_px, s.cy_px, s.baseline_m]
            .iter()
            .all(|v| v.is_finite());
        if finite && s.fx_px > 0.0 && s.fy_px > 0.0 && s.baseline_m > 0.0 {
            Ok(s)
        } else {
            Err(VoError::InvalidCalibration)
        }
    }

    /// Pinhole projection of a point in `K` into the left image `(x, y)` pixels, `None` behind
    /// the camera (`z <= 1e-6 m`).
    pub fn project_left(&self, p: &Vec3) -> Option<(f64, f64)> {
        if !(p.z > 1e-6) {
            return None;
        }
        Some((
            self.cx_px + self.fx_px * p.x / p.z,
            self.cy_px + self.fy_px * p.y / p.z,
        ))
    }

    /// Unit ray through pixel `(x, y)` and its derivatives with respect to `x` and `y`.
    fn ray(&self, x: f64, y: f64) -> (Vec3, Vec3, Vec3) {
        let v = Vec3::new(
            (x - self.cx_px) / self.fx_px,
            (y - self.cy_px) / self.fy_px,
            1.0,
        );
        let norm = crate::linalg::norm(&v);
        let r = v / norm;
        // d(v/|v|) = (dv - r (r . dv)) / |v|
        let dvx = Vec3::new(1.0 / self.fx_px, 0.0, 0.0);
        let dvy = Vec3::new(0.0, 1.0 / self.fy_px, 0.0);
        let drx = (dvx - r * r.dot(&dvx)) / norm;
        let dry = (dvy - r * r.dot(&dvy)) / norm;
        (r, drx, dry)
    }
}

/// A triangulated feature in the left camera frame `K`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoPoint {
    /// Position `P` (eq. 4), m.
    pub position_m: Vec3,
    /// Covariance of `P` (eq. 8 plus the gap term), m^2.
    pub covariance: Mat3,
    /// Gap: shortest distance between the two rays, m.
    pub gap_m: f64,
}

/// Why a feature was not stereo matched or triangulated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StereoReject {
    /// The template or the search leaves the image.
    OutOfImage,
    /// The best correlation is below the threshold.
    WeakCorrelation,
    /// Another disparity correlates almost as well.
    Ambiguous,
    /// The sub-pixel refinement failed or moved too far (or off the row).
    RefinementFailed,
    /// The rays are (nearly) parallel or meet behind the cameras.
    Degenerate,
    /// The ray gap is too large.
    LargeGap,
    /// The point is outside the configured range.
    OutOfRange,
    /// A non-finite number.
    NonFinite,
    /// The correlation peak is at an end of the searched disparity range (or of the part of it
    /// where the template fits in the image): no sub-pixel peak, the true one may lie outside.
    RangeEnd,
    /// Left-right consistency: matching the right template back along the left row does not
    /// land within 1 px of the left feature.
    LeftRightMismatch,
    /// The template straddles a depth discontinuity: its halves prefer different disparities.
    Discontinuity,
}

/// Floor of the matching noise of one image coordinate, pixels: the per-point covariances of the
/// flight noise model ([`triangulate_model`]) never assume less. 0.3 px: the normalised
/// cross-correlation peak refined by eq. 10 on 11x11 templates; measured on real images
/// (Middlebury 2014 motorcycle, `docs/vo.md`) the disparity error of the good matches has a
/// robust sigma of about 0.17-0.2 px, i.e. 0.12-0.14 px per coordinate, so 0.3 px leaves room for
/// tracking over time (perspective change, interpolation) that the stereo check does not see.
pub const MATCH_SIGMA_FLOOR_PX: f64 = 0.3;

/// Eq. 1-8 (H04) with the flight noise model of `config`: [`triangulate_model`] with the
/// matching noise `max(config.sigma_px, MATCH_SIGMA_FLOOR_PX)` on all four coordinates and the
/// calibration term `config.sigma_calibration_px` on the disparity.
pub fn triangulate_config(
    cam: &PinholeStereo,
    pixels: [f64; 4],
    config: &VoConfig,
) -> Result<StereoPoint, StereoReject> {
    triangulate_model(
        cam,
        pixels,
        config.sigma_px.max(MATCH_SIGMA_FLOOR_PX),
        config.sigma_calibration_px,
    )
}

/// Eq. 1-8 (H04): triangulates the left pixel `(xl, yl)` and right pixel `(xr, yr)` as the
/// midpoint of the closest points of the two rays (eq. 1-4) and propagates the pixel
/// covariance `sigma_px^2 I` of both images through the Jacobian `P'` of eq. 5-7 (eq. 8). The
/// gap enters the error model as an isotropic variance `(gap / 2)^2`.
pub fn triangulate(
    cam: &PinholeStereo,
    pixels: [f64; 4],
    sigma_px: f64,
) -> Result<StereoPoint, StereoReject> {
    triangulate_model(cam, pixels, sigma_px, 0.0)
}

/// [`triangulate`] with a calibration term: eq. 8 with `Sigma_l = sigma_px^2 I` and
/// `Sigma_r = diag(sigma_px^2 + sigma_calibration_px^2, sigma_px^2)`, i.e. an extra
/// disparity error of `sigma_calibration_px` (pixels) from the calibration (rectification and
/// lens-distortion residuals along the row, the error of the principal points' difference),
/// propagated through the same Jacobian `P'` (eq. 5-7). Treated as independent per point: an
/// approximation of an error that is smooth over the image, conservative for the weights of
/// eq. 11.
pub fn triangulate_model(
    cam: &PinholeStereo,
    pixels: [f64; 4],
    sigma_px: f64,
    sigma_calibration_px: f64,
) -> Result<StereoPoint, StereoReject> {
    let [xl, yl, xr, yr] = pixels;
    let b = Vec3::new(cam.baseline_m, 0.0, 0.0); // B = C2 - C1
    let (r1, dr1x, dr1y) = cam.ray(xl, yl);
    let (r2, dr2x, dr2y) = cam.ray(xr, yr);
    let g = r1.dot(&r2); // G
    let denominator = 1.0 - g * g;
    if !(denominator > 1e-12) {
        return Err(StereoReject::Degenerate);
    }
    let b_r1 = b.dot(&r1);
    let b_r2 = b.dot(&r2);
    let numerator = b_r1 - b_r2 * g;
    let m1 = numerator / denominator; // eq. 3
    let m2 = g * m1 - b_r2; // eq. 3
    if !(m1 > 0.0 && m2 > 0.0) {
        return Err(StereoReject::Degenerate);
    }
    let p1 = r1 * m1; // eq. 1, C1 = 0
    let p2 = b + r2 * m2; // eq. 1
    let position = (p1 + p2) * 0.5; // eq. 4
    let gap = crate::linalg::norm(&(p2 - p1));
    // Jacobian P' with respect to (xl, yl, xr, yr), eq. 5-7.
    let zero = Vec3::zeros();
    let d_r1 = [dr1x, dr1y, zero, zero];
    let d_r2 = [zero, zero, dr2x, dr2y];
    let mut jacobian = Matrix3x4::<f64>::zeros();
    for (k, (dr1, dr2)) in d_r1.iter().zip(d_r2.iter()).enumerate() {
        let f = dr1.dot(&r2) + r1.dot(dr2); // F
        let d_numerator = b.dot(dr1) - b.dot(dr2) * g - b_r2 * f;
        let m1_d =
            (d_numerator * denominator + 2.0 * numerator * g * f) / (denominator * denominator); // eq. 5
        let m2_d = g * m1_d + f * m1 - b.dot(dr2); // eq. 6
        let p_d = (dr1 * m1 + r1 * m1_d + dr2 * m2 + r2 * m2_d) * 0.5; // eq. 7
        jacobian.set_column(k, &p_d);
    }
    let variance = sigma_px * sigma_px;
    // eq. 8 with Sigma_l = sigma^2 I, Sigma_r = sigma^2 I + diag(sigma_cal^2, 0).
    let xr_column = jacobian.column(2);
    let calibration =
        xr_column * xr_column.transpose() * (sigma_calibration_px * sigma_calibration_px);
    let covariance = jacobian * jacobian.transpose() * variance
        + calibration
        + Mat3::identity() * (0.25 * gap * gap);
    let finite = position.iter().all(|v| v.is_finite())
        && covariance.iter().all(|v| v.is_finite())
        && gap.is_finite();
    if !finite {
        return Err(StereoReject::NonFinite);
    }
    Ok(StereoPoint {
        position_m: position,
        covariance,
        gap_m: gap,
    })
}

/// The triangulated point of a stereo match with the flight noise model of `config`
/// ([`triangulate_config`]) after the gap and range checks of [`accept_point`].
pub fn point_from_pixels(
    cam: &PinholeStereo,
    pixels: [f64; 4],
    config: &VoConfig,
) -> Result<StereoPoint, StereoReject> {
    let point = triangulate_config(cam, pixels, config)?;
    accept_point(cam, &point, config)?;
    Ok(point)
}

/// Checks a triangulated point against the gap and range limits of `config` (H04: "features
/// with large gaps are eliminated").
pub fn accept_point(
    cam: &PinholeStereo,
    point: &StereoPoint,
    config: &VoConfig,
) -> Result<(), StereoReject> {
    let range = crate::linalg::norm(&point.position_m);
    if !(range >= config.min_range_m && range <= config.max_range_m) {
        return Err(StereoReject::OutOfRange);
    }
    if point.gap_m > config.max_gap_px * range / cam.fy_px.min(cam.fx_px) {
        return Err(StereoReject::LargeGap);
    }
    Ok(())
}

/// Stereo matching of the left feature at sub-pixel `(xl, yl)` along its epipolar line (the same
/// row of the rectified right image): normalised cross-correlation of the template over the
/// disparities `min_disparity_px..=max_disparity_px` (every `stereo_coarse_step`-th disparity,
/// then the neighbours of the best), a uniqueness check, then sub-pixel refinement of the right
/// position (translation with gain and bias, eq. 10 with a translation warp) that also measures
/// a residual vertical offset. Returns `(xr, yr)` pixels.
pub fn match_along_row(
    left: &Image,
    right: &Image,
    xl: f64,
    yl: f64,
    config: &VoConfig,
) -> Result<(f64, f64), StereoReject> {
    let range = (config.min_disparity_px, config.max_disparity_px);
    match_in_range(
        left,
        right,
        xl,
        yl,
        range,
        config.stereo_coarse_step,
        config,
    )
}

/// [`match_along_row`] over the disparities within `config.track_disparity_margin_px` of a
/// predicted disparity `predicted_px` (pixels, from the motion prior; clipped to the configured
/// range), scanned every `stereo_coarse_step`-th disparity like the full range. [`StereoReject::OutOfRange`] when the prediction is not
/// finite or the window misses the configured range.
pub fn match_along_row_near(
    left: &Image,
    right: &Image,
    xl: f64,
    yl: f64,
    predicted_px: f64,
    config: &VoConfig,
) -> Result<(f64, f64), StereoReject> {
    let margin = f64::from(config.track_disparity_margin_px);
    let (lo, hi) = (predicted_px - margin, predicted_px + margin);
    let (d_min, d_max) = (config.min_disparity_px, config.max_disparity_px);
    if !(hi >= f64::from(d_min) && lo <= f64::from(d_max)) {
        return Err(StereoReject::OutOfRange);
    }
    // Both ends are finite and within [d_min, d_max] after the clamps.
    let lo = libm::floor(lo).max(f64::from(d_min)) as u16;
    let hi = libm::ceil(hi).min(f64::from(d_max)) as u16;
    match_in_range(
        left,
        right,
        xl,
        yl,
        (lo, hi),
        config.stereo_coarse_step,
        config,
    )
}

/// Matching over the disparities `range.0..=range.1` scanned every `step` (then the two
/// neighbours of the best); see [`match_along_row`].
fn match_in_range(
    left: &Image,
    right: &Image,
    xl: f64,
    yl: f64,
    range: (u16, u16),
    step: u8,
    config: &VoConfig,
) -> Result<(f64, f64), StereoReject> {
    if !(xl.is_finite() && yl.is_finite()) {
        return Err(StereoReject::NonFinite);
    }
    let xi = libm::round(xl) as i32;
    let yi = libm::round(yl) as i32;
    let template = left.template(xi, yi).ok_or(StereoReject::OutOfImage)?;
    let stats = template_stats(&template);
    let step = usize::from(step.max(1));
    let d_min = usize::from(range.0);
    let d_max = usize::from(range.1).min(MAX_DISPARITY_PX);
    // Scan the right row from x = xi - d_max towards xi - d_min; scan[k] is disparity
    // d_max - k * step.
    let mut scan = [f32::NEG_INFINITY; MAX_DISPARITY_PX + 1];
    let count = d_max.saturating_sub(d_min) / step + 1;
    if let Some(window) = scan.get_mut(..count) {
        ncc_scan(right, &template, stats, yi, xi - d_max as i32, step, window);
    }
    let disparity = |k: usize| d_max.saturating_sub(k * step);
    let mut best = (f32::NEG_INFINITY, 0usize);
    for (k, &score) in scan.iter().take(count).enumerate() {
        if score > best.0 {
            best = (score, disparity(k));
        }
    }
    // Scores computed off the scan grid (the neighbours of the coarse peak): (disparity, score
    // or -inf).
    let mut extra = [(usize::MAX, f32::NEG_INFINITY); 2];
    if step > 1 {
        // The peak lies within step / 2 of the best sample: try its neighbours.
        let centre = best.1;
        for (slot, d) in [centre.wrapping_sub(1), centre + 1].into_iter().enumerate() {
            if d < d_min || d > d_max {
                continue;
            }
            let score = ncc(right, &template, stats, xi - d as i32, yi);
            if let Some(e) = extra.get_mut(slot) {
                *e = (d, score.unwrap_or(f32::NEG_INFINITY));
            }
            if let Some(score) = score {
                if score > best.0 {
                    best = (score, d);
                }
            }
        }
    }
    // The score at disparity d if computed above (on the scan grid or a neighbour).
    let known = |d: usize| -> Option<f32> {
        if let Some(&(_, score)) = extra.iter().find(|&&(e, _)| e == d) {
            return Some(score);
        }
        let offset = d_max.checked_sub(d)?;
        if d < d_min || offset % step != 0 {
            return None;
        }
        scan.get(offset / step).copied()
    };
    let (best_score, best_d) = best;
    if !(best_score >= config.min_correlation) {
        return Err(StereoReject::WeakCorrelation);
    }
    let rival = scan
        .iter()
        .take(count)
        .enumerate()
        .filter(|&(k, _)| disparity(k).abs_diff(best_d) > 2)
        .map(|(_, &s)| s)
        .fold(f32::NEG_INFINITY, f32::max);
    if rival > best_score - config.uniqueness_margin {
        return Err(StereoReject::Ambiguous);
    }
    let lo = d_min;
    check_range_end(
        right,
        &template,
        stats,
        (xi, yi),
        best_d,
        (lo, d_max),
        known,
    )?;
    check_discontinuity(right, &template, (xi, yi), best_d, (lo, d_max), config)?;
    let template_f = left.template_f(xl, yl).ok_or(StereoReject::OutOfImage)?;
    let x0 = xl - best_d as f64;
    let init = Affine2::translation(x0, yl);
    let refined = refine_warp(&template_f, right, init, WarpModel::Translation, 8)
        .ok_or(StereoReject::RefinementFailed)?;
    let (xr, yr) = (refined.warp.c, refined.warp.f);
    if !((xr - x0).abs() <= 1.5 && (yr - yl).abs() <= config.max_row_offset_px) {
        return Err(StereoReject::RefinementFailed);
    }
    if !(xl - xr >= f64::from(config.min_disparity_px) - 1.0) {
        return Err(StereoReject::Degenerate);
    }
    check_left_right(left, right, (xi, yi), xr, (lo, d_max), config)?;
    Ok((xr, yr))
}

/// Range-end rule: the integer correlation peak `best_d` must have both neighbouring disparities
/// strictly inside the searched range `range` and with the template inside the image, so that
/// it is a true (sub-pixel) peak. A peak at an end of the range is the slope of a peak outside
/// it (measured on the Middlebury pairs: a disparity of 2.00 where the truth is 52); rejected as
/// [`StereoReject::RangeEnd`].
fn check_range_end(
    right: &Image,
    template: &super::image::Template,
    stats: (i64, i64),
    (xi, yi): (i32, i32),
    best_d: usize,
    (lo, hi): (usize, usize),
    known: impl Fn(usize) -> Option<f32>,
) -> Result<(), StereoReject> {
    if best_d <= lo || best_d >= hi {
        return Err(StereoReject::RangeEnd);
    }
    // A score already computed by the scan is reused (-inf: window outside or no contrast).
    let inside = |d: usize| match known(d) {
        Some(score) => score > f32::NEG_INFINITY,
        None => ncc(right, template, stats, xi - d as i32, yi).is_some(),
    };
    if inside(best_d - 1) && inside(best_d + 1) {
        Ok(())
    } else {
        Err(StereoReject::RangeEnd)
    }
}

/// The regions of the depth-discontinuity rule: the four halves of the template (left, right,
/// top, bottom; 6 of the 11 columns or rows each, the centre line shared) and the central 5x5
/// window (the Forstner window of the feature, textured by construction).
const HALVES: [TemplateRegion; 5] = [
    TemplateRegion {
        rows: (TEMPLATE_HALF - 2, TEMPLATE_HALF + 3),
        cols: (TEMPLATE_HALF - 2, TEMPLATE_HALF + 3),
    },
    TemplateRegion {
        rows: (0, TEMPLATE_SIDE),
        cols: (0, TEMPLATE_HALF + 1),
    },
    TemplateRegion {
        rows: (0, TEMPLATE_SIDE),
        cols: (TEMPLATE_HALF, TEMPLATE_SIDE),
    },
    TemplateRegion {
        rows: (0, TEMPLATE_HALF + 1),
        cols: (0, TEMPLATE_SIDE),
    },
    TemplateRegion {
        rows: (TEMPLATE_HALF, TEMPLATE_SIDE),
        cols: (0, TEMPLATE_SIDE),
    },
];

/// Depth-discontinuity rule: a template across a depth edge matches at the disparity of its
/// dominant (often the foreground) side, while the feature may lie on the other. Each half of
/// the template ([`HALVES`]) with texture (grey-level standard deviation at least
/// `config.half_min_std`) is correlated on its own at the integer disparities
/// `best_d +- config.half_window_px` (inside `range`); the match is rejected
/// ([`StereoReject::Discontinuity`]) when a half peaks more than 1 px away from `best_d`, or
/// correlates below `config.half_min_correlation` at `best_d`.
fn check_discontinuity(
    right: &Image,
    template: &super::image::Template,
    (xi, yi): (i32, i32),
    best_d: usize,
    (lo, hi): (usize, usize),
    config: &VoConfig,
) -> Result<(), StereoReject> {
    let window = usize::from(config.half_window_px);
    let (d_lo, d_hi) = (
        best_d.saturating_sub(window).max(lo),
        (best_d + window).min(hi),
    );
    let min_var = f64::from(config.half_min_std) * f64::from(config.half_min_std);
    // The regions with texture, with their template sums.
    let mut textured = [None; HALVES.len()];
    for (slot, region) in textured.iter_mut().zip(HALVES) {
        let stats = region_stats(template, region);
        let (ts, var_n2, n) = stats;
        if n <= 0 || !(var_n2 as f64 >= min_var * (n * n) as f64) {
            continue;
        }
        // A textured region without contrast (possible with `half_min_std` 0) never scores, so
        // it fails the rule.
        let (ts, tvar) = stats_i32(ts, var_n2).ok_or(StereoReject::Discontinuity)?;
        let t_scale = template_scale(tvar).ok_or(StereoReject::Discontinuity)?;
        *slot = Some((ts, t_scale, n as i32));
    }
    if textured.iter().all(Option::is_none) {
        return Ok(());
    }
    let mut best = [(f32::NEG_INFINITY, best_d); HALVES.len()];
    let mut at_match = [f32::NEG_INFINITY; HALVES.len()];
    for d in d_lo..=d_hi {
        let Some(sums) = halves_sums(right, template, xi - d as i32, yi) else {
            continue;
        };
        for (((stats, sums), best), at_match) in textured
            .iter()
            .zip(sums)
            .zip(best.iter_mut())
            .zip(at_match.iter_mut())
        {
            let Some((ts, t_scale, n)) = *stats else {
                continue;
            };
            let Some(score) = ncc_from_sums(n, sums, ts, t_scale) else {
                continue;
            };
            if d == best_d {
                *at_match = score;
            }
            if score > best.0 {
                *best = (score, d);
            }
        }
    }
    for ((stats, best), at_match) in textured.iter().zip(best).zip(at_match) {
        if stats.is_some()
            && (best.1.abs_diff(best_d) > 1 || !(at_match >= config.half_min_correlation))
        {
            return Err(StereoReject::Discontinuity);
        }
    }
    Ok(())
}

/// The window sums `(sum p, sum p^2, sum p t)` of the image window centred on integer `(x, y)`
/// against `template` over each region of [`HALVES`] (in that order), in one pass over the
/// 11x11 window: every row is split into the column segments 0..3, 3..5, 5, 6..8, 8..11 that
/// the regions are made of. The same sums as [`super::image::region_ncc`] forms per region; `None` if the
/// window leaves the image.
fn halves_sums(
    image: &Image,
    template: &super::image::Template,
    x: i32,
    y: i32,
) -> Option<[(u32, u32, u32); 5]> {
    const C: usize = TEMPLATE_HALF;
    let half = TEMPLATE_HALF as i32;
    let x0 = usize::try_from(x.checked_sub(half)?).ok()?;
    let y0 = usize::try_from(y.checked_sub(half)?).ok()?;
    let add = |a: (u32, u32, u32), b: (u32, u32, u32)| (a.0 + b.0, a.1 + b.1, a.2 + b.2);
    let zero = (0u32, 0u32, 0u32);
    let (mut centre, mut left, mut right, mut top, mut bottom) = (zero, zero, zero, zero, zero);
    for (r, t_row) in template.chunks_exact(TEMPLATE_SIDE).enumerate() {
        let pixels: &[u8; TEMPLATE_SIDE] = image
            .row(y0 + r)?
            .get(x0..x0 + TEMPLATE_SIDE)?
            .try_into()
            .ok()?;
        let segment = |cols: core::ops::Range<usize>| {
            let mut acc = zero;
            for c in cols {
                let p = u32::from(pixels.get(c).copied().unwrap_or(0));
                let t = u32::from(t_row.get(c).copied().unwrap_or(0));
                acc = (acc.0 + p, acc.1 + p * p, acc.2 + p * t);
            }
            acc
        };
        let (s0, s1, s2) = (segment(0..C - 2), segment(C - 2..C), segment(C..C + 1));
        let (s3, s4) = (segment(C + 1..C + 3), segment(C + 3..TEMPLATE_SIDE));
        let l = add(add(s0, s1), s2);
        let rr = add(add(s2, s3), s4);
        let row = add(l, add(s3, s4));
        left = add(left, l);
        right = add(right, rr);
        if r <= C {
            top = add(top, row);
        }
        if r >= C {
            bottom = add(bottom, row);
        }
        if (C - 2..=C + 2).contains(&r) {
            centre = add(centre, add(add(s1, s2), s3));
        }
    }
    Some([centre, left, right, top, bottom])
}

/// Left-right consistency rule: the right template at the match (integer column nearest `xr`,
/// row `yi`) is matched back along the left row over the disparities of `range` within
/// `config.left_right_window_px` of the match's (all of `range` for 0): a scan every
/// `config.left_right_step` pixels, then the columns within half a step of the best. The left
/// column found must be within `config.left_right_tolerance_px` (1 px) of the feature's `xi`,
/// otherwise [`StereoReject::LeftRightMismatch`] (typically an occlusion: the background seen in
/// the left image is hidden by the foreground in the right one, whose patch belongs to another
/// left column). Run only at the matched features (one scan each).
fn check_left_right(
    left: &Image,
    right: &Image,
    (xi, yi): (i32, i32),
    xr: f64,
    (lo, hi): (usize, usize),
    config: &VoConfig,
) -> Result<(), StereoReject> {
    let xri = libm::round(xr) as i32;
    let d_match = usize::try_from(xi - xri).unwrap_or(0);
    let window = usize::from(config.left_right_window_px);
    let (lo, hi) = if window == 0 {
        (lo, hi)
    } else {
        (
            d_match.saturating_sub(window).max(lo),
            (d_match + window).min(hi),
        )
    };
    let back = right.template(xri, yi).ok_or(StereoReject::OutOfImage)?;
    let stats = template_stats(&back);
    let step = usize::from(config.left_right_step.max(1));
    let mut scan = [f32::NEG_INFINITY; MAX_DISPARITY_PX + 1];
    let count = hi.saturating_sub(lo) / step + 1;
    if let Some(samples) = scan.get_mut(..count) {
        // samples[k] is the left column xri + lo + k * step (disparity lo + k * step).
        ncc_scan(left, &back, stats, yi, xri + lo as i32, step, samples);
    }
    let mut best = (f32::NEG_INFINITY, lo);
    for (k, &score) in scan.iter().take(count).enumerate() {
        if score > best.0 {
            best = (score, lo + k * step);
        }
    }
    // The peak lies within half a step of the best sample.
    let centre = best.1;
    let half = step / 2;
    for d in centre.saturating_sub(half).max(lo)..=(centre + half).min(hi) {
        if d == centre {
            continue;
        }
        if let Some(score) = ncc(left, &back, stats, xri + d as i32, yi) {
            if score > best.0 {
                best = (score, d);
            }
        }
    }
    let x_back = f64::from(xri) + best.1 as f64;
    if best.0 > f32::NEG_INFINITY
        && (x_back - f64::from(xi)).abs() <= config.left_right_tolerance_px
    {
        Ok(())
    } else {
        Err(StereoReject::LeftRightMismatch)
    }
}

/// Matches and triangulates one left feature: [`match_along_row`] (or [`match_along_row_near`]
/// when a predicted disparity in pixels is given), [`triangulate`], [`accept_point`]. Returns the
/// point and the right pixel.
pub fn match_and_triangulate(
    cam: &PinholeStereo,
    left: &Image,
    right: &Image,
    (xl, yl): (f64, f64),
    predicted_disparity_px: Option<f64>,
    config: &VoConfig,
) -> Result<(StereoPoint, (f64, f64)), StereoReject> {
    let (xr, yr) = match predicted_disparity_px {
        Some(d) => match_along_row_near(left, right, xl, yl, d, config)?,
        None => match_along_row(left, right, xl, yl, config)?,
    };
    let point = point_from_pixels(cam, [xl, yl, xr, yr], config)?;
    Ok((point, (xr, yr)))
}

/// A 3-vector helper for tests and callers: the point `p` in `K` seen in the right camera
/// (pixels), `None` behind the camera.
pub fn project_right(cam: &PinholeStereo, p: &Vec3) -> Option<(f64, f64)> {
    cam.project_left(&Vector3::new(p.x - cam.baseline_m, p.y, p.z))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hazcam() -> PinholeStereo {
        PinholeStereo {
            fx_px: 384.8,
            fy_px: 384.0,
            cx_px: 319.5,
            cy_px: 239.5,
            baseline_m: 0.084,
        }
    }

    fn pixels_of(cam: &PinholeStereo, p: &Vec3) -> [f64; 4] {
        let (xl, yl) = cam.project_left(p).unwrap();
        let (xr, yr) = project_right(cam, p).unwrap();
        [xl, yl, xr, yr]
    }

    #[test]
    fn vo_2_triangulation_recovers_points_exactly() {
        let cam = hazcam();
        for p in [
            Vec3::new(0.3, -0.2, 0.6),
            Vec3::new(-1.0, 0.5, 3.0),
            Vec3::new(0.0, 0.0, 5.0),
        ] {
            let s = triangulate(&cam, pixels_of(&cam, &p), 0.3).unwrap();
            assert!(
                (s.position_m - p).norm() < 1e-9,
                "{p:?} -> {:?}",
                s.position_m
            );
            assert!(s.gap_m < 1e-9);
        }
    }

    #[test]
    fn vo_3_jacobian_matches_finite_differences() {
        // Covariance of eq. 8 equals J J^T sigma^2 with J from central differences.
        let cam = hazcam();
        let mut px = pixels_of(&cam, &Vec3::new(0.4, 0.3, 2.0));
        px[3] += 0.4; // a ray gap, so that every term of eq. 5-7 is exercised
        let sigma = 0.5;
        let s = triangulate(&cam, px, sigma).unwrap();
        let h = 1e-5;
        let mut j = Matrix3x4::<f64>::zeros();
        for k in 0..4 {
            let mut a = px;
            let mut b = px;
            a[k] += h;
            b[k] -= h;
            let pa = triangulate(&cam, a, sigma).unwrap().position_m;
            let pb = triangulate(&cam, b, sigma).unwrap().position_m;
            j.set_column(k, &((pa - pb) / (2.0 * h)));
        }
        let expected =
            j * j.transpose() * sigma * sigma + Mat3::identity() * (0.25 * s.gap_m * s.gap_m);
        let scale = expected.norm();
        assert!((s.covariance - expected).norm() < 1e-6 * scale);
        assert!(s.gap_m > 0.0);
    }

    #[test]
    fn vo_3_covariance_matches_monte_carlo() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let cam = hazcam();
        let p = Vec3::new(-0.3, 0.2, 2.5);
        let px = pixels_of(&cam, &p);
        let sigma = 0.3;
        let nominal = triangulate(&cam, px, sigma).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, sigma).unwrap();
        let n = 20000;
        let mut mean = Vec3::zeros();
        let mut samples = std::vec::Vec::with_capacity(n);
        for _ in 0..n {
            let mut q = px;
            for v in q.iter_mut() {
                *v += noise.sample(&mut rng);
            }
            let s = triangulate(&cam, q, sigma).unwrap().position_m;
            mean += s;
            samples.push(s);
        }
        mean /= n as f64;
        let mut cov = Mat3::zeros();
        for s in &samples {
            cov += (s - mean) * (s - mean).transpose();
        }
        cov /= (n - 1) as f64;
        // The gap term adds (gap/2)^2 per sample, so compare against the first-order part.
        let first_order = nominal.covariance;
        let zz = (cov[(2, 2)] / first_order[(2, 2)]).sqrt();
        let xx = (cov[(0, 0)] / first_order[(0, 0)]).sqrt();
        assert!((zz - 1.0).abs() < 0.1, "depth sigma ratio {zz}");
        assert!((xx - 1.0).abs() < 0.1, "lateral sigma ratio {xx}");
    }

    #[test]
    fn vo_2_degenerate_and_far_points_are_rejected() {
        let cam = hazcam();
        // Zero disparity: parallel rays.
        assert_eq!(
            triangulate(&cam, [300.0, 200.0, 300.0, 200.0], 0.3).err(),
            Some(StereoReject::Degenerate)
        );
        // Negative disparity: the rays meet behind the cameras.
        assert_eq!(
            triangulate(&cam, [300.0, 200.0, 305.0, 200.0], 0.3).err(),
            Some(StereoReject::Degenerate)
        );
        assert_eq!(
            triangulate(&cam, [f64::NAN, 200.0, 290.0, 200.0], 0.3).err(),
            Some(StereoReject::Degenerate)
        );
        // A large vertical offset is a large gap.
        let config = VoConfig::default();
        let s = triangulate(&cam, [300.0, 200.0, 280.0, 204.0], 0.3).unwrap();
        assert_eq!(
            accept_point(&cam, &s, &config).err(),
            Some(StereoReject::LargeGap)
        );
    }

    /// A 640x480 test pair: a textured background plane at disparity 10 px (texture amplitude
    /// `bg_amp`) and, right of left-image column 300, a strongly textured foreground at
    /// disparity 20 px; the foreground hides the background in the right image.
    fn step_pair(bg_amp: f64) -> (std::vec::Vec<u8>, std::vec::Vec<u8>) {
        use rover_hal::{IMAGE_HEIGHT_PX as H, IMAGE_WIDTH_PX as W};
        let noise = |x: i64, y: i64| -> f64 {
            let mut h = (x as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
                ^ (y as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f);
            h ^= h >> 29;
            h = h.wrapping_mul(0xbf58_476d_1ce4_e5b9);
            h ^= h >> 32;
            (h % 1000) as f64 / 1000.0 - 0.5
        };
        // Smoothed noise (2x2 box) so that the sub-pixel refinement has gradients.
        let texture = |x: i64, y: i64| {
            (noise(x, y) + noise(x + 1, y) + noise(x, y + 1) + noise(x + 1, y + 1)) / 2.0
        };
        let edge = 300i64;
        let scene = |xl: i64, y: i64| -> f64 {
            if xl >= edge {
                128.0 + 90.0 * texture(xl, y)
            } else {
                128.0 + bg_amp * texture(xl + 7919, y)
            }
        };
        let mut left = std::vec![0u8; W * H];
        let mut right = std::vec![0u8; W * H];
        for y in 0..H as i64 {
            for x in 0..W as i64 {
                let i = y as usize * W + x as usize;
                left[i] = scene(x, y).clamp(0.0, 255.0) as u8;
                // Right pixel x sees the foreground at left column x + 20 when that is in the
                // foreground, else the background at left column x + 10.
                let v = if x + 20 >= edge {
                    scene(x + 20, y)
                } else {
                    scene(x + 10, y)
                };
                right[i] = v.clamp(0.0, 255.0) as u8;
            }
        }
        (left, right)
    }

    /// Background texture amplitude of the depth-step test: a grey-level standard deviation of
    /// about 6, above `half_min_std` (a flatter background gives the rule nothing to see).
    const BG_AMPLITUDE: f64 = 20.0;

    #[test]
    fn vo_2_templates_across_a_depth_step_are_rejected() {
        let (l, r) = step_pair(BG_AMPLITUDE);
        let (left, right) = (Image::new(&l).unwrap(), Image::new(&r).unwrap());
        let config = VoConfig::default();
        // Away from the step both depths match exactly.
        for (x, d) in [(250.0, 10.0), (360.0, 20.0)] {
            for y in [100.0, 240.0, 380.0] {
                let (xr, _) = match_along_row(&left, &right, x, y, &config).unwrap();
                assert!((x - xr - d).abs() < 0.3, "({x}, {y}): {}", x - xr);
            }
        }
        // Background features 1-4 px left of the step: the template's foreground columns
        // dominate the correlation. No match may lock onto the foreground disparity.
        let no_rule = VoConfig {
            half_min_std: 1e6,
            ..config
        };
        let (mut locked_without, mut rejected) = (0, 0);
        for x in [296.0, 297.0, 298.0, 299.0] {
            for y in (60..420).step_by(15) {
                let y = f64::from(y);
                let locked = |m: Result<(f64, f64), StereoReject>| {
                    m.is_ok_and(|(xr, _)| (x - xr - 20.0).abs() < 2.0)
                };
                locked_without +=
                    usize::from(locked(match_along_row(&left, &right, x, y, &no_rule)));
                let with_rule = match_along_row(&left, &right, x, y, &config);
                assert!(!locked(with_rule), "({x}, {y}) locked onto the foreground");
                rejected += usize::from(with_rule == Err(StereoReject::Discontinuity));
            }
        }
        println!("VO-2 depth step: {locked_without} foreground locks without the rule, {rejected} rejected with it");
        assert!(locked_without > 0, "the pair does not exercise the rule");
        assert!(rejected > 0);
    }

    #[test]
    fn vo_2_peaks_at_the_range_ends_are_rejected() {
        let (l, r) = step_pair(40.0);
        let (left, right) = (Image::new(&l).unwrap(), Image::new(&r).unwrap());
        // Foreground at disparity 20, range 1..=19: the best is the slope at 19.
        let short = VoConfig {
            max_disparity_px: 19,
            stereo_coarse_step: 1,
            min_correlation: -0.99,
            uniqueness_margin: 0.0,
            ..VoConfig::default()
        };
        let mut range_end = 0;
        for y in (60..420).step_by(20) {
            let m = match_along_row(&left, &right, 400.0, f64::from(y), &short);
            if let Ok((xr, _)) = m {
                assert!(
                    400.0 - xr < 16.0,
                    "y {y}: accepted the range end {}",
                    400.0 - xr
                );
            }
            range_end += usize::from(m == Err(StereoReject::RangeEnd));
        }
        assert!(range_end > 10, "{range_end}");
        // A window around a prediction 9 px short of the truth ends at 19: rejected too.
        let windowed = VoConfig {
            track_disparity_margin_px: 8,
            max_disparity_px: 128,
            ..short
        };
        assert_eq!(
            match_along_row_near(&left, &right, 400.0, 200.0, 11.0, &windowed),
            Err(StereoReject::RangeEnd)
        );
        assert!(match_along_row_near(&left, &right, 400.0, 200.0, 18.0, &windowed).is_ok());
    }

    #[test]
    fn vo_2_one_pass_half_sums_equal_region_ncc() {
        use super::super::image::region_ncc;
        let (l, r) = step_pair(40.0);
        let (left, right) = (Image::new(&l).unwrap(), Image::new(&r).unwrap());
        let mut compared = 0;
        for (x, y) in [
            (200, 240),
            (296, 100),
            (310, 300),
            (5, 5),
            (634, 474),
            (4, 200),
        ] {
            let Some(template) = left.template(x, y) else {
                continue;
            };
            for d in 0..30 {
                let sums = halves_sums(&right, &template, x - d, y);
                for (k, region) in HALVES.into_iter().enumerate() {
                    let stats = region_stats(&template, region);
                    let expected = region_ncc(&right, &template, region, stats, x - d, y);
                    let (ts, tvar) = stats_i32(stats.0, stats.1).unwrap();
                    let got = sums.and_then(|s| {
                        ncc_from_sums(stats.2 as i32, s[k], ts, template_scale(tvar)?)
                    });
                    assert_eq!(got, expected, "({x}, {y}) d {d} region {k}");
                    compared += usize::from(got.is_some());
                }
            }
        }
        assert!(compared > 400, "{compared}");
    }

    #[test]
    fn vo_2_left_right_check_rejects_a_wrong_match() {
        let (l, r) = step_pair(40.0);
        let (left, right) = (Image::new(&l).unwrap(), Image::new(&r).unwrap());
        let config = VoConfig::default();
        let range = (1usize, 128usize);
        // The true match (disparity 10 on the background) comes back to the feature.
        assert_eq!(
            check_left_right(&left, &right, (200, 240), 190.0, range, &config),
            Ok(())
        );
        // A match 6 px off comes back 6 px away.
        assert_eq!(
            check_left_right(&left, &right, (200, 240), 184.0, range, &config),
            Err(StereoReject::LeftRightMismatch)
        );
        // The occluded background strip (left columns 290-299, hidden in the right image):
        // its best right match belongs to another left column.
        let occluded = (290..300)
            .filter(|&x| {
                check_left_right(&left, &right, (x, 240), f64::from(x) - 10.0, range, &config)
                    .is_err()
            })
            .count();
        assert!(occluded >= 8, "{occluded}");
    }
}
