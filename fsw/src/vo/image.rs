//! Borrowed 8-bit images, image checks, bilinear sampling and normalised cross-correlation.
//!
//! Pixel coordinates: x to the right (column), y down (row), the centre of pixel `(0, 0)` at
//! `(0.0, 0.0)`. Every access is checked: a position outside the image is `None`, never a panic.

use super::{VoConfig, VoError, TEMPLATE_HALF, TEMPLATE_PIXELS, TEMPLATE_SIDE};
use rover_hal::{IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX};

/// A row-major 8-bit grey image of `IMAGE_WIDTH_PX x IMAGE_HEIGHT_PX` borrowed in place.
#[derive(Debug, Clone, Copy)]
pub struct Image<'a> {
    data: &'a [u8],
}

/// A correlation template, row-major, [`TEMPLATE_SIDE`] square, grey levels.
pub type Template = [u8; TEMPLATE_PIXELS];

/// A template sampled at a sub-pixel position, grey levels.
pub type TemplateF = [f32; TEMPLATE_PIXELS];

impl<'a> Image<'a> {
    /// Wrap a slice; [`VoError::WrongImageSize`] unless it holds exactly one image.
    pub fn new(data: &'a [u8]) -> Result<Self, VoError> {
        if data.len() == IMAGE_PIXELS {
            Ok(Self { data })
        } else {
            Err(VoError::WrongImageSize)
        }
    }

    /// Width, pixels.
    pub const fn width(&self) -> usize {
        IMAGE_WIDTH_PX
    }

    /// Height, pixels.
    pub const fn height(&self) -> usize {
        IMAGE_HEIGHT_PX
    }

    /// Row `y` as a slice, `None` outside the image.
    pub fn row(&self, y: usize) -> Option<&'a [u8]> {
        let start = y.checked_mul(IMAGE_WIDTH_PX)?;
        self.data.get(start..start.checked_add(IMAGE_WIDTH_PX)?)
    }

    /// Pixel at integer `(x, y)`, `None` outside the image.
    pub fn pixel(&self, x: i32, y: i32) -> Option<u8> {
        let xu = usize::try_from(x).ok()?;
        let yu = usize::try_from(y).ok()?;
        if xu >= IMAGE_WIDTH_PX {
            return None;
        }
        self.row(yu)?.get(xu).copied()
    }

    /// Bilinear grey level at `(x, y)` and its gradient `(dI/dx, dI/dy)` (the gradient of the
    /// bilinear interpolant), `None` when the 2x2 neighbourhood leaves the image or `x, y` are not
    /// finite.
    pub fn bilinear(&self, x: f64, y: f64) -> Option<(f64, f64, f64)> {
        // One range test per axis; NaN and infinities fail it. Non-negative and in range, so
        // truncation is the floor.
        if !(x >= 0.0 && x < (IMAGE_WIDTH_PX - 1) as f64 && y >= 0.0) {
            return None;
        }
        if !(y < (IMAGE_HEIGHT_PX - 1) as f64) {
            return None;
        }
        // (Through u32: one native conversion on the rover CPU.)
        let (x0, y0) = (x as u32 as usize, y as u32 as usize);
        // The 2x2 neighbourhood is the first two and the last two bytes of one span of
        // `width + 2` bytes (one bounds check; the array type makes the four reads infallible).
        let start = y0 * IMAGE_WIDTH_PX + x0;
        let q: &[u8; IMAGE_WIDTH_PX + 2] = self
            .data
            .get(start..start + IMAGE_WIDTH_PX + 2)?
            .try_into()
            .ok()?;
        let p00 = f64::from(q[0]);
        let p10 = f64::from(q[1]);
        let p01 = f64::from(q[IMAGE_WIDTH_PX]);
        let p11 = f64::from(q[IMAGE_WIDTH_PX + 1]);
        let fx = x - x0 as f64;
        let fy = y - y0 as f64;
        let top = p00 + fx * (p10 - p00);
        let bottom = p01 + fx * (p11 - p01);
        let value = top + fy * (bottom - top);
        let gx = (1.0 - fy) * (p10 - p00) + fy * (p11 - p01);
        let gy = bottom - top;
        Some((value, gx, gy))
    }

    /// [`Self::bilinear`] in single precision (the affine refinement's per-pixel sampling, H04
    /// eq. 10): bilinear grey level at `(x, y)` pixels and its gradient `(dI/dx, dI/dy)`, grey
    /// levels per pixel. `None` when the 2x2 neighbourhood leaves the image or `x, y` are not
    /// finite. Positions below 640 carry about 6e-5 px of rounding in `f32`.
    #[inline(always)]
    pub fn bilinear_f32(&self, x: f32, y: f32) -> Option<(f32, f32, f32)> {
        // One range test per axis; NaN and infinities fail it. Non-negative and in range, so
        // truncation is the floor.
        if !(x >= 0.0 && x < (IMAGE_WIDTH_PX - 1) as f32 && y >= 0.0) {
            return None;
        }
        if !(y < (IMAGE_HEIGHT_PX - 1) as f32) {
            return None;
        }
        self.bilinear_f32_inside(x, y)
    }

    /// [`Self::bilinear_f32`] without the floating-point range tests, for a caller that has
    /// checked the positions (the affine refinement tests the corners of the warped template
    /// once). Defined for every input: a negative or NaN coordinate takes the row or column 0
    /// (saturating conversion; the weight then extrapolates), a neighbourhood past the end of
    /// the image data is `None`.
    #[inline(always)]
    pub fn bilinear_f32_inside(&self, x: f32, y: f32) -> Option<(f32, f32, f32)> {
        let (x0, y0) = (x as u32, y as u32);
        let start = y0 as usize * IMAGE_WIDTH_PX + x0 as usize;
        let q: &[u8; IMAGE_WIDTH_PX + 2] = self
            .data
            .get(start..start + IMAGE_WIDTH_PX + 2)?
            .try_into()
            .ok()?;
        let p00 = f32::from(q[0]);
        let p01 = f32::from(q[IMAGE_WIDTH_PX]);
        let d_top = f32::from(q[1]) - p00;
        let d_bottom = f32::from(q[IMAGE_WIDTH_PX + 1]) - p01;
        let fx = x - x0 as f32;
        let fy = y - y0 as f32;
        let top = p00 + fx * d_top;
        let gy = (p01 + fx * d_bottom) - top;
        let value = top + fy * gy;
        let gx = d_top + fy * (d_bottom - d_top);
        Some((value, gx, gy))
    }

    /// Bilinear grey levels and gradients (as [`Self::bilinear`]) on the template grid centred
    /// on the sub-pixel position `(x, y)`, in single precision: calls `f(k, value, dI/dx,
    /// dI/dy)` for template pixel `k` (row-major) at `(x + u, y + v)`, `u, v` in
    /// `-TEMPLATE_HALF..=TEMPLATE_HALF`, grey levels and grey levels per pixel. All samples share
    /// one pair of interpolation weights in `f32` (the sub-pixel offset of `x, y` is taken in
    /// `f64` first, so it carries no rounding of the absolute position). `None` (and no call)
    /// if the grid leaves the image or `x, y` are not finite.
    #[inline]
    pub fn grid_bilinear_f32(
        &self,
        x: f64,
        y: f64,
        mut f: impl FnMut(usize, f32, f32, f32),
    ) -> Option<()> {
        let half = TEMPLATE_HALF as f64;
        let (xs, ys) = (x - half, y - half);
        let x_end = (IMAGE_WIDTH_PX - TEMPLATE_SIDE) as f64;
        let y_end = (IMAGE_HEIGHT_PX - TEMPLATE_SIDE) as f64;
        if !(xs >= 0.0 && xs < x_end && ys >= 0.0 && ys < y_end) {
            return None;
        }
        let (x0, y0) = (xs as u32 as usize, ys as u32 as usize);
        let fx = (xs - x0 as f64) as f32;
        let fy = (ys - y0 as f64) as f32;
        let span = |row: usize| -> Option<&[u8; TEMPLATE_SIDE + 1]> {
            let start = row * IMAGE_WIDTH_PX + x0;
            self.data
                .get(start..start + TEMPLATE_SIDE + 1)?
                .try_into()
                .ok()
        };
        let mut upper = span(y0)?;
        for r in 0..TEMPLATE_SIDE {
            let lower = span(y0 + r + 1)?;
            for c in 0..TEMPLATE_SIDE {
                let p00 = f32::from(upper[c]);
                let p01 = f32::from(lower[c]);
                let d_top = f32::from(upper[c + 1]) - p00;
                let d_bottom = f32::from(lower[c + 1]) - p01;
                let top = p00 + fx * d_top;
                let gy = (p01 + fx * d_bottom) - top;
                let value = top + fy * gy;
                let gx = d_top + fy * (d_bottom - d_top);
                f(r * TEMPLATE_SIDE + c, value, gx, gy);
            }
            upper = lower;
        }
        Some(())
    }

    /// The template centred on integer `(x, y)`, `None` if it leaves the image. Inlined, so
    /// that the template is built in the caller's frame (not a 121-byte copy per call).
    #[inline(always)]
    pub fn template(&self, x: i32, y: i32) -> Option<Template> {
        let half = TEMPLATE_HALF as i32;
        let x0 = usize::try_from(x.checked_sub(half)?).ok()?;
        let y0 = usize::try_from(y.checked_sub(half)?).ok()?;
        let mut out = [0u8; TEMPLATE_PIXELS];
        for (row_out, dy) in out.chunks_exact_mut(TEMPLATE_SIDE).zip(0..TEMPLATE_SIDE) {
            let row = self.row(y0 + dy)?;
            row_out.copy_from_slice(row.get(x0..x0 + TEMPLATE_SIDE)?);
        }
        Some(out)
    }

    /// The template centred on the sub-pixel position `(x, y)` by bilinear sampling in single
    /// precision ([`Self::grid_bilinear_f32`]), `None` if it leaves the image. Inlined, so that
    /// the template is built in the caller's frame (not a 484-byte copy per call).
    #[inline(always)]
    pub fn template_f(&self, x: f64, y: f64) -> Option<TemplateF> {
        let mut out = [0f32; TEMPLATE_PIXELS];
        self.grid_bilinear_f32(x, y, |k, value, _, _| {
            if let Some(slot) = out.get_mut(k) {
                *slot = value;
            }
        })?;
        Some(out)
    }

    /// Checks one image for use by the VO: [`VoError::BlankImage`] if the grey-level standard
    /// deviation is below `config.min_image_std`, [`VoError::SaturatedImage`] if more than
    /// `config.max_clipped_fraction` of the pixels are 0 or 255. Samples every 4th pixel of every
    /// 4th row ([`CHECK_ROW_STEP`]: 19,200 samples). Returns a checksum of the samples (32-bit FNV-1a, to detect a repeated frame). The
    /// same as [`Self::check_band`] over every band, then [`CheckSums::finish`].
    pub fn check(&self, config: &VoConfig) -> Result<u64, VoError> {
        let mut sums = CheckSums::default();
        for band in 0..CHECK_BANDS {
            self.check_band(band, &mut sums)?;
        }
        sums.finish(config)
    }

    /// Adds the samples of row band `band` (`0..CHECK_BANDS`, rows
    /// `band * height / CHECK_BANDS ..`, every [`CHECK_ROW_STEP`]-th row, every 4th pixel) to `sums`, so that the
    /// check can run as several bounded work items.
    pub fn check_band(&self, band: usize, sums: &mut CheckSums) -> Result<(), VoError> {
        let rows = IMAGE_HEIGHT_PX / CHECK_BANDS;
        let first = band.saturating_mul(rows);
        for y in (first..first.saturating_add(rows).min(IMAGE_HEIGHT_PX)).step_by(CHECK_ROW_STEP) {
            let row = self.row(y).ok_or(VoError::WrongImageSize)?;
            // Per-row sums of at most 160 samples: below 41 000, 10.5e6 and 160, no overflow;
            // the totals saturate.
            let (mut sum, mut sum_sq, mut count, mut clipped) = (0u32, 0u32, 0u32, 0u32);
            let mut hash = sums.hash;
            for &p in row.iter().step_by(4) {
                let v = u32::from(p);
                sum += v;
                sum_sq += v * v;
                count += 1;
                clipped += u32::from(p == 0 || p == 255);
                hash = (hash ^ u32::from(p)).wrapping_mul(0x0100_0193);
            }
            sums.sum = sums.sum.saturating_add(sum);
            sums.sum_sq = sums.sum_sq.saturating_add(sum_sq);
            sums.count = sums.count.saturating_add(count);
            sums.clipped = sums.clipped.saturating_add(clipped);
            sums.hash = hash;
        }
        Ok(())
    }
}

/// Row bands of the image check ([`Image::check_band`]).
pub const CHECK_BANDS: usize = 4;

/// Rows between the rows the image check samples (every 4th: 19,200 samples of a 640x480 image,
/// plenty for its mean, spread and clipped fraction and for the repeated-frame checksum; every
/// 2nd row would be twice the work).
pub const CHECK_ROW_STEP: usize = 4;

/// Running sums of the image check ([`Image::check_band`]). The sample count, sum and sum of
/// squares of one 640x480 image fit in `u32` (19 200 samples, at most 1.3e9).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CheckSums {
    sum: u32,
    sum_sq: u32,
    count: u32,
    clipped: u32,
    /// 32-bit FNV-1a of the samples (a 64-bit one costs a 64-bit multiply per sample on the
    /// 32-bit core: twice the check; a repeated-frame false alarm stays at 2^-32).
    hash: u32,
}

impl Default for CheckSums {
    fn default() -> Self {
        Self {
            sum: 0,
            sum_sq: 0,
            count: 0,
            clipped: 0,
            hash: 0x811c_9dc5,
        }
    }
}

impl CheckSums {
    /// The verdict of [`Image::check`] from the sums of all bands: the checksum, or
    /// [`VoError::BlankImage`] / [`VoError::SaturatedImage`].
    pub fn finish(&self, config: &VoConfig) -> Result<u64, VoError> {
        let n = f64::from(self.count.max(1));
        let mean = f64::from(self.sum) / n;
        let variance = (f64::from(self.sum_sq) / n - mean * mean).max(0.0);
        if crate::linalg::sqrt(variance) < config.min_image_std {
            return Err(VoError::BlankImage);
        }
        if f64::from(self.clipped) > config.max_clipped_fraction * n {
            return Err(VoError::SaturatedImage);
        }
        Ok(u64::from(self.hash))
    }
}

/// Sums of a template for normalised cross-correlation: `(sum, n * sum_sq - sum^2)`.
pub fn template_stats(template: &Template) -> (i64, i64) {
    // 121 grey levels: the sum is at most 30,855 and the sum of squares 7,868,025 (u32).
    let (mut s, mut s2) = (0u32, 0u32);
    for &p in template.iter() {
        let v = u32::from(p);
        s += v;
        s2 += v * v;
    }
    let (s, s2) = (i64::from(s), i64::from(s2));
    (s, TEMPLATE_PIXELS as i64 * s2 - s * s)
}

/// `1 / sqrt(x)` in single precision for `x` in `1..=2^31` (the variances of [`ncc_from_sums`]),
/// relative error below 3e-7 (`vo_11_inverse_square_root_is_accurate`): the classic bit-level
/// first estimate (relative error below 3.5 %) and three Newton steps `y (1.5 - x/2 y^2)`
/// (1.8e-3, 4.7e-6, then the f32 rounding). The rover CPU has no hardware square root
/// reachable from `no_std` Rust, and `libm::sqrt` is a software routine of about 100
/// instructions; this is 15. Plain IEEE single-precision
/// operations, so host and target give the same bits.
#[inline(always)]
pub(super) fn inv_sqrt(x: f32) -> f32 {
    let y = f32::from_bits(0x5f37_5a86_u32.wrapping_sub(x.to_bits() >> 1));
    let half = 0.5 * x;
    let y = y * (1.5 - half * y * y);
    let y = y * (1.5 - half * y * y);
    y * (1.5 - half * y * y)
}

/// The template factor of [`ncc_from_sums`]: `1 / sqrt(tvar)` for the template's
/// `n sum_sq - sum^2`, `None` when the template has no contrast (`tvar <= 0`).
#[inline(always)]
pub(super) fn template_scale(tvar: i32) -> Option<f32> {
    (tvar > 0).then(|| inv_sqrt(tvar as f32))
}

/// Zero-mean normalised cross-correlation (-1..1) from the integer sums of `n` pixel pairs
/// (`n` at most [`TEMPLATE_PIXELS`]): window sum `s`, sum of squares `s2`, sum of products with
/// the template `st`, the template's sum `ts` and its factor `t_scale` ([`template_scale`]).
/// `None` when the window has no contrast. With `n <= 121` and grey levels up to 255 every
/// product and difference (`n s2`, `s^2`, `n st`, `ts s`: at most 121^2 * 255^2 = 952,031,025)
/// fits in `i32`, so the sums need no 64-bit arithmetic. The normalisation is single precision
/// with [`inv_sqrt`] (relative error of the score below 1e-6; clamped to -1..1).
#[inline(always)]
pub(super) fn ncc_from_sums(
    n: i32,
    (s, s2, st): (u32, u32, u32),
    ts: i32,
    t_scale: f32,
) -> Option<f32> {
    let (s, s2, st) = (s as i32, s2 as i32, st as i32);
    let ivar = n * s2 - s * s;
    if ivar <= 0 {
        return None;
    }
    let cov = n * st - ts * s;
    Some((cov as f32 * (inv_sqrt(ivar as f32) * t_scale)).clamp(-1.0, 1.0))
}

/// The template sums of [`template_stats`] / [`region_stats`] as `i32` (they are at most
/// 30,855 and 952,031,025 for a template of grey levels), `None` outside that range.
#[inline(always)]
pub(super) fn stats_i32(ts: i64, tvar: i64) -> Option<(i32, i32)> {
    Some((i32::try_from(ts).ok()?, i32::try_from(tvar).ok()?))
}

/// Zero-mean normalised cross-correlation (-1..1) of `template` (with its [`template_stats`])
/// against the image window centred on integer `(x, y)`; `None` if the window leaves the image or
/// either patch has no contrast.
pub fn ncc(image: &Image, template: &Template, stats: (i64, i64), x: i32, y: i32) -> Option<f32> {
    let half = TEMPLATE_HALF as i32;
    let x0 = usize::try_from(x.checked_sub(half)?).ok()?;
    let y0 = usize::try_from(y.checked_sub(half)?).ok()?;
    let mut s = 0u32;
    let mut s2 = 0u32;
    let mut st = 0u32;
    for (t_row, dy) in template.chunks_exact(TEMPLATE_SIDE).zip(0..TEMPLATE_SIDE) {
        let row = image.row(y0 + dy)?.get(x0..x0 + TEMPLATE_SIDE)?;
        for (&p, &t) in row.iter().zip(t_row.iter()) {
            let p = u32::from(p);
            s += p;
            s2 += p * p;
            st += p * u32::from(t);
        }
    }
    let (ts, tvar) = stats_i32(stats.0, stats.1)?;
    ncc_from_sums(
        TEMPLATE_PIXELS as i32,
        (s, s2, st),
        ts,
        template_scale(tvar)?,
    )
}

/// A rectangle of template pixels: rows `rows.0..rows.1`, columns `cols.0..cols.1` (template
/// coordinates, `0..TEMPLATE_SIDE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TemplateRegion {
    /// First and one-past-last row.
    pub rows: (usize, usize),
    /// First and one-past-last column.
    pub cols: (usize, usize),
}

/// Grey-level variance times the pixel count squared (`n sum_sq - sum^2`) of a region of a
/// template, and the pixel count `n`.
pub fn region_stats(template: &Template, region: TemplateRegion) -> (i64, i64, i64) {
    let (mut s, mut s2, mut n) = (0i64, 0i64, 0i64);
    for row in template
        .chunks_exact(TEMPLATE_SIDE)
        .skip(region.rows.0)
        .take(region.rows.1.saturating_sub(region.rows.0))
    {
        for &p in row.get(region.cols.0..region.cols.1).unwrap_or(&[]) {
            let v = i64::from(p);
            s += v;
            s2 += v * v;
            n += 1;
        }
    }
    (s, n * s2 - s * s, n)
}

/// Zero-mean normalised cross-correlation (-1..1) of a region of `template` (with its
/// [`region_stats`]) against the same region of the image window centred on integer `(x, y)`;
/// `None` if the window leaves the image or either patch has no contrast.
pub fn region_ncc(
    image: &Image,
    template: &Template,
    region: TemplateRegion,
    stats: (i64, i64, i64),
    x: i32,
    y: i32,
) -> Option<f32> {
    let half = TEMPLATE_HALF as i32;
    let x0 = usize::try_from(x.checked_sub(half)?).ok()? + region.cols.0;
    let y0 = usize::try_from(y.checked_sub(half)?).ok()? + region.rows.0;
    let width = region.cols.1.checked_sub(region.cols.0)?;
    let height = region.rows.1.checked_sub(region.rows.0)?;
    let (mut s, mut s2, mut st) = (0u32, 0u32, 0u32);
    let t_rows = template.chunks_exact(TEMPLATE_SIDE).skip(region.rows.0);
    for (t_row, dy) in t_rows.zip(0..height) {
        let row = image.row(y0 + dy)?.get(x0..x0 + width)?;
        let t_row = t_row.get(region.cols.0..region.cols.1)?;
        for (&p, &t) in row.iter().zip(t_row.iter()) {
            let p = u32::from(p);
            s += p;
            s2 += p * p;
            st += p * u32::from(t);
        }
    }
    let (ts, tvar, n) = stats;
    let (ts, tvar) = stats_i32(ts, tvar)?;
    if !(1..=TEMPLATE_PIXELS as i64).contains(&n) {
        return None;
    }
    ncc_from_sums(n as i32, (s, s2, st), ts, template_scale(tvar)?)
}

/// Largest number of columns [`ncc_scan`] covers in one call.
pub const SCAN_MAX_COLUMNS: usize = 256;

/// Largest step between the scanned positions of [`ncc_scan`] (larger steps are refused).
pub const SCAN_MAX_STEP: usize = 4;

/// Width of a packed template row of [`ScanTemplate`]: two windows `step` apart.
const PACKED_WIDTH: usize = TEMPLATE_SIDE + SCAN_MAX_STEP;

/// Bits of the low lane of a packed dot product: a sum of 121 products of grey levels is at
/// most 121 * 255^2 = 7,868,025 < 2^23, so it cannot carry into the high lane.
const LANE_BITS: u32 = 24;

/// A template prepared for [`ncc_scan_prepared`] at one scan step: its sums
/// ([`template_stats`]) and its rows packed for two neighbouring positions at once. Word `j`
/// of row `r` is `t[r][j] + (t[r][j - step] << 24)` (a term is 0 where its column is outside
/// `0..TEMPLATE_SIDE`), so one 32 x 32 -> 64-bit multiply-accumulate of image pixel
/// `x0 + j` (`umlal` on the rover CPU) adds its product with the template of the window at
/// `x0` to the low 24 bits and with that of the window at `x0 + step` to the high bits: two
/// correlation terms per instruction, exact (each lane's sum stays below 2^23).
#[derive(Debug, Clone)]
pub struct ScanTemplate {
    packed: [[u32; PACKED_WIDTH]; TEMPLATE_SIDE],
    step: usize,
    ts: i32,
    t_scale: f32,
}

impl ScanTemplate {
    /// Prepares `template` for scans every `step` pixels (`1..=SCAN_MAX_STEP`; `None`
    /// otherwise, or when the template has no contrast).
    pub fn new(template: &Template, step: usize) -> Option<Self> {
        Self::with_stats(template, template_stats(template), step)
    }

    /// [`Self::new`] with the template's [`template_stats`] already at hand. Inlined, so that
    /// the packed rows are built in the caller's frame rather than copied out of this one (a
    /// 660-byte `memcpy` per scan on the rover CPU).
    #[inline(always)]
    pub fn with_stats(template: &Template, stats: (i64, i64), step: usize) -> Option<Self> {
        if !(1..=SCAN_MAX_STEP).contains(&step) {
            return None;
        }
        let (ts, tvar) = stats_i32(stats.0, stats.1)?;
        let t_scale = template_scale(tvar)?;
        let mut packed = [[0u32; PACKED_WIDTH]; TEMPLATE_SIDE];
        for (out, t_row) in packed.iter_mut().zip(template.chunks_exact(TEMPLATE_SIDE)) {
            for (word, &t) in out.iter_mut().zip(t_row) {
                *word = u32::from(t);
            }
            for (word, &t) in out.iter_mut().skip(step).zip(t_row) {
                *word |= u32::from(t) << LANE_BITS;
            }
        }
        Some(Self {
            packed,
            step,
            ts,
            t_scale,
        })
    }
}

/// Normalised cross-correlation of `template` along image row `y` at the columns
/// `x_first + k * step` for `k` in `0..out.len()`, written to `out[k]` (`-inf` where the window
/// leaves the image, has no contrast, or the span exceeds [`SCAN_MAX_COLUMNS`] or the step
/// [`SCAN_MAX_STEP`]). Same values as [`ncc`]. [`ncc_scan_prepared`] with a template prepared
/// for this call; a caller scanning several rows with one template prepares it once.
pub fn ncc_scan(
    image: &Image,
    template: &Template,
    stats: (i64, i64),
    y: i32,
    x_first: i32,
    step: usize,
    out: &mut [f32],
) {
    match ScanTemplate::with_stats(template, stats, step) {
        Some(prepared) => ncc_scan_prepared(image, &prepared, y, x_first, out),
        None => out.iter_mut().for_each(|v| *v = f32::NEG_INFINITY),
    }
}

/// [`ncc_scan`] with a prepared template (its step). The window sums come from column sums of
/// the scanned span (one pass, column by column, sums in registers) through prefix sums; the
/// template products from the packed template, two neighbouring positions per pass
/// ([`ScanTemplate`]).
pub fn ncc_scan_prepared(
    image: &Image,
    template: &ScanTemplate,
    y: i32,
    x_first: i32,
    out: &mut [f32],
) {
    match template.step {
        1 => scan_rows::<1>(image, template, y, x_first, out),
        2 => scan_rows::<2>(image, template, y, x_first, out),
        3 => scan_rows::<3>(image, template, y, x_first, out),
        _ => scan_rows::<4>(image, template, y, x_first, out),
    }
}

/// [`ncc_scan_prepared`] at the compile-time step `STEP` (so the packed inner loops have
/// constant trip counts, `TEMPLATE_SIDE + STEP`).
#[inline(always)]
fn scan_rows<const STEP: usize>(
    image: &Image,
    template: &ScanTemplate,
    y: i32,
    x_first: i32,
    out: &mut [f32],
) {
    out.iter_mut().for_each(|v| *v = f32::NEG_INFINITY);
    if template.step != STEP {
        return;
    }
    let half = TEMPLATE_HALF as i32;
    let Some(y0) = y.checked_sub(half).and_then(|v| usize::try_from(v).ok()) else {
        return;
    };
    if y0 + TEMPLATE_SIDE > IMAGE_HEIGHT_PX {
        return;
    }
    // Columns [c_lo, c_hi) of the image covered by all windows, clipped to the image.
    let span = out.len().saturating_sub(1).saturating_mul(STEP) + TEMPLATE_SIDE;
    let c_first = x_first.saturating_sub(half);
    let c_lo = c_first.max(0) as usize;
    let c_hi = (i64::from(c_first) + span as i64).clamp(0, IMAGE_WIDTH_PX as i64) as usize;
    if span > SCAN_MAX_COLUMNS || c_lo + TEMPLATE_SIDE > c_hi {
        return;
    }
    let width = c_hi - c_lo;
    // Pixel (row r, column c_lo + j) of the window rows is block[r * W + j].
    const ROWS_SPAN: usize = (TEMPLATE_SIDE - 1) * IMAGE_WIDTH_PX;
    let base = y0 * IMAGE_WIDTH_PX + c_lo;
    let Some(block) = image.data.get(base..base + ROWS_SPAN + width) else {
        return;
    };
    // Prefix sums over the span of the column sums of p and p^2: pre[j] sums columns 0..j; in
    // arrays sized for short spans when the span is short (zeroing the full-size arrays costs
    // about 1,400 instructions per call on the rover CPU, more than a short scan itself).
    if width <= SHORT_SPAN {
        scan_span::<STEP, { SHORT_SPAN + 1 }>(template, (c_first, c_lo, c_hi), block, out);
    } else if width <= MEDIUM_SPAN {
        scan_span::<STEP, { MEDIUM_SPAN + 1 }>(template, (c_first, c_lo, c_hi), block, out);
    } else {
        scan_span::<STEP, { SCAN_MAX_COLUMNS + 1 }>(template, (c_first, c_lo, c_hi), block, out);
    }
}

/// Columns of a short scan span ([`scan_rows`]): the tracking search and the windowed stereo of
/// a tracked feature scan 19-27 columns.
const SHORT_SPAN: usize = 32;

/// Columns of a medium scan span ([`scan_rows`]): the stereo scans of a disparity range up to
/// about 100 px, whose prefix arrays are zeroed at this size, not at [`SCAN_MAX_COLUMNS`]
/// (at the larger size the zeroing is 3 % of the hazard mapper's instructions).
const MEDIUM_SPAN: usize = 112;

/// The scan of [`scan_rows`] over the span `[c_lo, c_hi)` (window columns `c_first + k * STEP`)
/// of `block` (pixel `(r, j)` of the span at `block[r * W + j]`), with prefix-sum arrays of
/// `N >= c_hi - c_lo + 1` entries.
#[inline(always)]
fn scan_span<const STEP: usize, const N: usize>(
    template: &ScanTemplate,
    (c_first, c_lo, c_hi): (i32, usize, usize),
    block: &[u8],
    out: &mut [f32],
) {
    const ROWS_SPAN: usize = (TEMPLATE_SIDE - 1) * IMAGE_WIDTH_PX;
    let width = c_hi - c_lo;
    if width + 1 > N {
        return;
    }
    let mut pre_s = [0u32; N];
    let mut pre_s2 = [0u32; N];
    let (mut run_s, mut run_s2) = (0u32, 0u32);
    for (j, (ps, ps2)) in pre_s
        .iter_mut()
        .zip(pre_s2.iter_mut())
        .skip(1)
        .take(width)
        .enumerate()
    {
        let Some(column) = block.get(j..j + ROWS_SPAN + 1) else {
            return;
        };
        for r in 0..TEMPLATE_SIDE {
            let p = u32::from(column.get(r * IMAGE_WIDTH_PX).copied().unwrap_or(0));
            run_s += p;
            run_s2 += p * p;
        }
        *ps = run_s;
        *ps2 = run_s2;
    }
    // Positions k_lo..k_hi have their window inside [c_lo, c_hi): x0(k) = c_first + k * step.
    let k_lo = (c_lo as i64 - i64::from(c_first)).div_euclid(STEP as i64)
        + i64::from((c_lo as i64 - i64::from(c_first)).rem_euclid(STEP as i64) != 0);
    let k_hi = ((c_hi - TEMPLATE_SIDE) as i64 - i64::from(c_first)).div_euclid(STEP as i64) + 1;
    let (k_lo, k_hi) = (
        k_lo.max(0) as usize,
        k_hi.clamp(0, out.len() as i64) as usize,
    );
    let sums = |local: usize| -> Option<(u32, u32)> {
        let (a, b) = (pre_s.get(local)?, pre_s.get(local + TEMPLATE_SIDE)?);
        let (a2, b2) = (pre_s2.get(local)?, pre_s2.get(local + TEMPLATE_SIDE)?);
        Some((b.wrapping_sub(*a), b2.wrapping_sub(*a2)))
    };
    let n = TEMPLATE_PIXELS as i32;
    let (ts, t_scale) = (template.ts, template.t_scale);
    for k in (k_lo..k_hi).step_by(2) {
        // k_lo >= 0 and x0 >= c_lo by construction of k_lo.
        let x0 = (i64::from(c_first) + (k * STEP) as i64) as usize;
        let local = x0 - c_lo;
        let Some(window) = block.get(local..) else {
            continue;
        };
        let pair = k + 1 < k_hi;
        let acc = if pair {
            dot_packed(window, &template.packed, TEMPLATE_SIDE + STEP)
        } else {
            dot_packed(window, &template.packed, TEMPLATE_SIDE)
        };
        let Some(acc) = acc else {
            continue;
        };
        let lanes = [
            (k, local, (acc & ((1 << LANE_BITS) - 1)) as u32),
            (k + 1, local + STEP, (acc >> LANE_BITS) as u32),
        ];
        for (kk, ll, st) in lanes.into_iter().take(if pair { 2 } else { 1 }) {
            let (Some((s, s2)), Some(value)) = (sums(ll), out.get_mut(kk)) else {
                continue;
            };
            if let Some(score) = ncc_from_sums(n, (s, s2, st), ts, t_scale) {
                *value = score;
            }
        }
    }
}

/// Packed dot product of the 11 template rows with the image pixels `window[r * W + j]`,
/// `j < cols` (`TEMPLATE_SIDE + step` for two windows, `TEMPLATE_SIDE` for the first only: its
/// low lane is exact either way; a constant at each inlined call, so the loops unroll). `None`
/// if the rows leave `window`.
#[inline(always)]
fn dot_packed(
    window: &[u8],
    packed: &[[u32; PACKED_WIDTH]; TEMPLATE_SIDE],
    cols: usize,
) -> Option<u64> {
    let mut acc = 0u64;
    for (r, words) in packed.iter().enumerate() {
        let start = r * IMAGE_WIDTH_PX;
        let pixels = window.get(start..start + cols)?;
        for (&p, &w) in pixels.iter().zip(words.iter()) {
            acc += u64::from(p) * u64::from(w);
        }
    }
    Some(acc)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> [u8; IMAGE_PIXELS] {
        let mut img = [0u8; IMAGE_PIXELS];
        for (k, p) in img.iter_mut().enumerate() {
            let (x, y) = (k % IMAGE_WIDTH_PX, k / IMAGE_WIDTH_PX);
            *p = ((x + 2 * y) % 251) as u8;
        }
        img
    }

    #[test]
    fn vo_11_image_access_is_checked() {
        let img = ramp();
        let image = Image::new(&img).unwrap();
        assert_eq!(image.pixel(3, 2), Some(7));
        assert_eq!(image.pixel(-1, 0), None);
        assert_eq!(image.pixel(640, 0), None);
        assert_eq!(image.pixel(0, 480), None);
        assert!(image.bilinear(639.0, 0.0).is_none());
        assert!(image.bilinear(f64::NAN, 0.0).is_none());
        let (v, gx, gy) = image.bilinear(10.25, 20.5).unwrap();
        assert!((v - (10.25 + 41.0)).abs() < 1e-12);
        assert!((gx - 1.0).abs() < 1e-12 && (gy - 2.0).abs() < 1e-12);
        assert!(image.template(5, 5).is_some());
        assert!(image.template(4, 5).is_none());
        assert!(image.template(634, 474).is_some());
        assert!(image.template(635, 474).is_none());
        assert_eq!(Image::new(&img[1..]).err(), Some(VoError::WrongImageSize));
    }

    #[test]
    fn vo_11_inverse_square_root_is_accurate() {
        // Every power of two and 20,000 values spread over the range of the NCC variances.
        let mut worst = 0.0f64;
        let mut x = 1.0f64;
        for k in 0..20_000 {
            let v = if k < 32 { f64::from(1u32 << k) } else { x };
            let got = f64::from(inv_sqrt(v as f32));
            let exact = 1.0 / crate::linalg::sqrt(f64::from(v as f32));
            worst = worst.max((got - exact).abs() / exact);
            x = (x * 1.001_07).min(2.147e9);
        }
        println!("VO-11 inverse square root: largest relative error {worst:.2e}");
        assert!(worst < 3e-7, "{worst}");
    }

    #[test]
    fn vo_11_ncc_is_one_on_itself() {
        let img = ramp();
        let image = Image::new(&img).unwrap();
        let t = image.template(100, 100).unwrap();
        let stats = template_stats(&t);
        let c = ncc(&image, &t, stats, 100, 100).unwrap();
        assert!((c - 1.0).abs() < 1e-6);
        assert!(ncc(&image, &t, stats, 2, 100).is_none());
    }

    #[test]
    fn vo_11_ncc_scan_equals_ncc() {
        let mut img = ramp();
        for (k, p) in img.iter_mut().enumerate() {
            *p = p.wrapping_mul(37).wrapping_add((k / 7 % 13) as u8);
        }
        let image = Image::new(&img).unwrap();
        let t = image.template(300, 200).unwrap();
        let stats = template_stats(&t);
        // Every step (the packed kernel pairs positions `step` apart), odd and even counts,
        // windows leaving the image on either side and at the last rows.
        let mut compared = 0;
        for (y, x_first) in [
            (200, 250),
            (203, -3),
            (470, 600),
            (4, 10),
            (474, 560),
            (5, -20),
        ] {
            for step in 1..=SCAN_MAX_STEP {
                for len in [1usize, 2, 5, 9, 60] {
                    let mut out = [0f32; 60];
                    let out = &mut out[..len];
                    ncc_scan(&image, &t, stats, y, x_first, step, out);
                    for (k, &v) in out.iter().enumerate() {
                        let x = x_first + (k * step) as i32;
                        let expected = ncc(&image, &t, stats, x, y).unwrap_or(f32::NEG_INFINITY);
                        assert_eq!(v, expected, "y {y} x {x} step {step} len {len}");
                        compared += usize::from(v > f32::NEG_INFINITY);
                    }
                }
            }
        }
        assert!(compared > 1000, "{compared}");
        // Steps the packed kernel does not take are refused.
        let mut out = [0f32; 4];
        ncc_scan(&image, &t, stats, 200, 250, SCAN_MAX_STEP + 1, &mut out);
        assert!(out.iter().all(|&v| v == f32::NEG_INFINITY));
    }
}
