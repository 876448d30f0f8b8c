//! Raw images through the wide-angle lenses ([`crate::sensors::hazcam_lens`]).
//!
//! Method: the pinhole pair is rendered (without noise) at a size that covers the whole raw
//! field of both cameras, with the focal length of the raw cameras' centre (so the image centre
//! is sampled at the raw density); then each raw pixel `(i, j)` of camera `c` takes the value
//! of its ray there: the ray is `hazcam_lens::ray(c, i, j)` (the lens model inverted by Newton's
//! method, once per head: a map of pinhole coordinates per raw pixel), the pinhole image is
//! interpolated bilinearly at the ray's projection, and the image noise is added per raw
//! pixel (the same Gaussian table and hashing as the pinhole renderer), rounded half up and
//! clamped to `[0, 255]`.

use super::noise::{hash3, mix64};
use super::{CameraPose, FilteredAlbedo, RenderError, RenderSettings, RenderStats, Sun};
use crate::sensors::hazcam_lens;
use rayon::prelude::*;
use rover_hal::{LensCalibration, RawCamera, StereoCalibration, IMAGE_HEIGHT_PX, IMAGE_WIDTH_PX};

/// Pixels sharing one noise hash (as the pinhole renderer).
const NOISE_GROUP: usize = 4;

/// Mask of a 16-bit field of a noise hash that indexes the Gaussian table (the table has at
/// most 2^16 entries, so the masked index is always in it).
const GAUSS_MASK: u64 = (super::noise::GAUSS_TABLE_LEN - 1) as u64;

/// `v` rounded half up to a byte, clamped to `[0, 255]`; NaN gives 0. The same byte as
/// `(v.clamp(0.0, 255.0) + 0.5) as i32 as u8` for every `v` (a NaN there also ends as 0; `-0.0`
/// and `0.0` both end as 0), with two fewer instructions per pixel pair in the vectorised loops
/// (`maxpd`/`minpd` without a NaN fix-up; the conversion itself stays per pixel on SSE2).
#[inline(always)]
#[allow(clippy::manual_clamp)] // `clamp` keeps NaN, which is the point here.
pub(super) fn quantize(v: f64) -> u8 {
    (v.max(0.0).min(255.0) + 0.5) as i32 as u8
}

/// Per-row working arrays of the resampling (one set per parallel job, reused for its rows;
/// every entry read is written first for the same row).
struct RowScratch {
    /// Noise-free value per raw pixel.
    clean: Vec<f32>,
    /// Gaussian quantile per raw pixel.
    noise: Vec<f32>,
}

impl RowScratch {
    /// Arrays for rows of `width` pixels.
    fn new(width: usize) -> Self {
        Self {
            clean: vec![0.0; width],
            noise: vec![0.0; width],
        }
    }
}

/// The pinhole image that covers both raw fields: intrinsics and size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoverImage {
    /// Focal lengths (equal), px.
    pub f_px: f64,
    /// Principal point, px.
    pub c_px: [f64; 2],
    /// Size, px (width, height).
    pub size: (usize, usize),
}

impl CoverImage {
    /// The smallest pinhole image (with a 2 px margin) at the largest raw focal length that
    /// holds the rays of every border pixel of both raw cameras (the lens is monotonic, so the
    /// border bounds the field). `None` if a border ray cannot be computed or the image would
    /// exceed 4096 px on a side.
    pub fn for_lens(lens: &LensCalibration) -> Option<Self> {
        let f = [lens.left, lens.right]
            .iter()
            .map(|c| c.fx_px.max(c.fy_px))
            .fold(0.0f64, f64::max);
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        let (w, h) = (IMAGE_WIDTH_PX, IMAGE_HEIGHT_PX);
        for c in [&lens.left, &lens.right] {
            let border = (0..w)
                .flat_map(|i| [(i, 0), (i, h - 1)])
                .chain((0..h).flat_map(|j| [(0, j), (w - 1, j)]));
            for (i, j) in border {
                let r = hazcam_lens::ray(c, i as f64, j as f64)?;
                if r[2] <= 1e-6 {
                    return None;
                }
                for k in 0..2 {
                    let t = r[k] / r[2];
                    lo[k] = lo[k].min(t);
                    hi[k] = hi[k].max(t);
                }
            }
        }
        let margin = 2.0;
        let size = [0, 1].map(|k| ((hi[k] - lo[k]) * f + 2.0 * margin).ceil() + 1.0);
        if !(f.is_finite() && f > 0.0) || size.iter().any(|s| s.is_nan() || *s > 4096.0) {
            return None;
        }
        Some(Self {
            f_px: f,
            c_px: [margin - lo[0] * f, margin - lo[1] * f],
            size: (size[0] as usize, size[1] as usize),
        })
    }
}

/// Renders raw hazcam pairs through the lens model; keeps its buffers and maps between
/// frames (one per camera device).
#[derive(Debug, Clone)]
pub struct LensRig {
    lens: LensCalibration,
    cover: CoverImage,
    settings: RenderSettings,
    pinhole: super::StereoRenderer,
    /// Where each raw pixel reads the pinhole image, left and right (from its pinhole-image
    /// coordinates; sky where the lens model has no inverse).
    taps: [Vec<Tap>; 2],
    images: [Vec<u8>; 2],
    gauss: Box<super::noise::GaussTable>,
}

impl LensRig {
    /// A rig for the (true) lenses `lens` on the head `head` (its baseline; the intrinsics are
    /// the lenses'), with the image `settings`.
    pub fn new(
        lens: LensCalibration,
        head: &StereoCalibration,
        settings: RenderSettings,
    ) -> Result<Self, RenderError> {
        let cover = CoverImage::for_lens(&lens).ok_or(RenderError::BadCalibration)?;
        let (w, h) = cover.size;
        let calib = StereoCalibration {
            fx_px: cover.f_px,
            fy_px: cover.f_px,
            cx_px: cover.c_px[0],
            cy_px: cover.c_px[1],
            ..*head
        };
        let quiet = RenderSettings {
            noise_sigma_dn: 0.0,
            ..settings
        };
        let map = |c: &RawCamera| -> Vec<[f32; 2]> {
            (0..IMAGE_WIDTH_PX * IMAGE_HEIGHT_PX)
                .into_par_iter()
                .map(|n| {
                    let (i, j) = (n % IMAGE_WIDTH_PX, n / IMAGE_WIDTH_PX);
                    match hazcam_lens::ray(c, i as f64, j as f64) {
                        Some(r) if r[2] > 1e-6 => [
                            (cover.c_px[0] + cover.f_px * r[0] / r[2]) as f32,
                            (cover.c_px[1] + cover.f_px * r[1] / r[2]) as f32,
                        ],
                        _ => [f32::NAN; 2],
                    }
                })
                .collect()
        };
        let taps = [map(&lens.left), map(&lens.right)]
            .map(|m| m.iter().map(|&p| Tap::new(w, h, p)).collect::<Vec<_>>());
        let mut pinhole = super::StereoRenderer::with_size(calib, quiet, w, h);
        pinhole.set_used_pixels([0, 1].map(|c| Some(used_pixels(&taps[c], w, h))));
        Ok(Self {
            lens,
            cover,
            settings,
            pinhole,
            taps,
            images: [vec![0; w * h], vec![0; w * h]],
            gauss: super::noise::gaussian_table(),
        })
    }

    /// The lenses this rig renders with.
    pub fn lens(&self) -> &LensCalibration {
        &self.lens
    }

    /// The pinhole image that is resampled.
    pub fn cover(&self) -> &CoverImage {
        &self.cover
    }

    /// Use the head `head` (baseline) for the next frames.
    pub fn set_head(&mut self, head: &StereoCalibration) {
        let c = *self.pinhole.calibration();
        self.pinhole.set_calibration(StereoCalibration {
            baseline_m: head.baseline_m,
            rot_rover_from_camera: head.rot_rover_from_camera,
            pos_camera_in_rover_m: head.pos_camera_in_rover_m,
            ..c
        });
    }

    /// Render the raw pair seen from `left_pose` into `left` and `right` (`IMAGE_PIXELS`
    /// bytes each); as [`super::StereoRenderer::render`] otherwise. (Never inlined: one call
    /// per pair, and a symbol of its own for profiles.)
    #[inline(never)]
    pub fn render<S: FilteredAlbedo + ?Sized>(
        &mut self,
        surface: &S,
        left_pose: &CameraPose,
        sun: &Sun,
        noise_seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<RenderStats, RenderError> {
        let expected = IMAGE_WIDTH_PX * IMAGE_HEIGHT_PX;
        if left.len() != expected || right.len() != expected {
            return Err(RenderError::BufferSize {
                expected,
                left: left.len(),
                right: right.len(),
            });
        }
        let [pl, pr] = &mut self.images;
        let stats = self
            .pinhole
            .render(surface, left_pose, sun, noise_seed, pl, pr)?;
        let sigma = self.settings.noise_sigma_dn;
        let sky = self.settings.sky_dn;
        let gauss = &self.gauss;
        let resample = |image: &[u8], taps: &[Tap], out: &mut [u8], camera: u64| {
            let key = hash3(noise_seed, camera, 0x006c_656e_7300);
            // Per row, three passes: the noise-free values (the taps), the noise quantiles
            // (one hash per group of pixels), and the sums, rounded (plain arithmetic over
            // whole arrays, which the compiler vectorises); the same operations per pixel as a
            // single pass, so the same bytes.
            out.par_chunks_mut(IMAGE_WIDTH_PX)
                .zip(taps.par_chunks(IMAGE_WIDTH_PX))
                .enumerate()
                .for_each_init(
                    || RowScratch::new(IMAGE_WIDTH_PX),
                    |s, (j, (row, taps_row))| {
                        let n = row.len().min(taps_row.len());
                        let (clean, noise) = (&mut s.clean[..n], &mut s.noise[..n]);
                        for (c, t) in clean.iter_mut().zip(taps_row) {
                            *c = t.sample(image).unwrap_or(sky as f32);
                        }
                        for (g, quantiles) in noise.chunks_mut(NOISE_GROUP).enumerate() {
                            let group = g * NOISE_GROUP;
                            let id = ((j * IMAGE_WIDTH_PX + group) / NOISE_GROUP) as u64;
                            let hash = mix64(key ^ id.wrapping_mul(0x9e37_79b9_7f4a_7c15));
                            for (q, o) in quantiles.iter_mut().enumerate() {
                                *o = gauss[((hash >> (16 * q)) & GAUSS_MASK) as usize];
                            }
                        }
                        for ((o, &c), &g) in row.iter_mut().zip(clean.iter()).zip(noise.iter()) {
                            let v = f64::from(c) + sigma * f64::from(g);
                            *o = quantize(v);
                        }
                    },
                );
        };
        let [ml, mr] = &self.taps;
        rayon::join(|| resample(pl, ml, left, 0), || resample(pr, mr, right, 1));
        Ok(stats)
    }
}

#[cfg(test)]
impl LensRig {
    /// Shade every pinhole pixel from now on (drops the used-pixel masks): the reference of
    /// SIM-LENS-5.
    pub(crate) fn shade_every_pixel(&mut self) {
        self.pinhole.set_used_pixels([None, None]);
    }
}

/// The pixels of a `w x h` pinhole image that `taps` read (`w * h` flags, row-major): the raw
/// images depend on no other pixel.
fn used_pixels(taps: &[Tap], w: usize, h: usize) -> Vec<bool> {
    let mut used = vec![false; w * h];
    for t in taps.iter().filter(|t| t.base != Tap::SKY) {
        let k = t.base as usize;
        let (dx, dy) = (t.dx as usize, t.dy as usize);
        for n in [k, k + dx, k + dy, k + dy + dx] {
            if let Some(u) = used.get_mut(n) {
                *u = true;
            }
        }
    }
    used
}

/// Where a raw pixel reads the pinhole image: the bilinear interpolation of the `w x h` image
/// at a point `p` (pixel centres at integers), with the storage index of its upper left tap,
/// the offsets of the others and the weights computed once (the same values as a lookup at `p`
/// computes them).
#[derive(Debug, Clone, Copy)]
struct Tap {
    /// Index of the upper left tap `(x0, y0)`, or [`Tap::SKY`] outside the image or for NaN.
    base: u32,
    /// `x1 - x0` (0 on the last column).
    dx: u32,
    /// `(y1 - y0) * w` (0 on the last row).
    dy: u32,
    /// Weight of the right taps, `x - x0`.
    a: f32,
    /// Weight of the lower taps, `y - y0`.
    b: f32,
}

impl Tap {
    /// [`Tap::base`] of a point outside the image.
    const SKY: u32 = u32::MAX;

    /// The lookup at `p` in a `w x h` image (`w * h` below `u32::MAX`: the cover image has at
    /// most 4096 px on a side).
    fn new(w: usize, h: usize, p: [f32; 2]) -> Self {
        match bilinear_taps(w, h, p) {
            Some([x0, y0, x1, y1]) => {
                let [x, y] = p;
                Self {
                    base: (y0 * w + x0) as u32,
                    dx: (x1 - x0) as u32,
                    dy: ((y1 - y0) * w) as u32,
                    a: x - x0 as f32,
                    b: y - y0 as f32,
                }
            }
            None => Self {
                base: Self::SKY,
                dx: 0,
                dy: 0,
                a: 0.0,
                b: 0.0,
            },
        }
    }

    /// The interpolated value in `image`; `None` for a point outside the image.
    #[inline(always)]
    fn sample(&self, image: &[u8]) -> Option<f32> {
        if self.base == Self::SKY {
            return None;
        }
        let k = self.base as usize;
        let (dx, dy) = (self.dx as usize, self.dy as usize);
        let (a, b) = (self.a, self.b);
        // The four taps from one bounds check (the offsets are at most `dy + dx`; the sums
        // of three `u32` cannot overflow); a tap outside the image reads 0.
        let (p00, p01, p10, p11) = match image.get(k..k + dy + dx + 1) {
            Some(q) => (
                f32::from(q[0]),
                f32::from(q[dx]),
                f32::from(q[dy]),
                f32::from(q[dy + dx]),
            ),
            None => {
                let px = |n: usize| image.get(n).copied().map_or(0.0, f32::from);
                (px(k), px(k + dx), px(k + dy), px(k + dy + dx))
            }
        };
        let top = p00 + a * (p01 - p00);
        let bottom = p10 + a * (p11 - p10);
        Some(top + b * (bottom - top))
    }
}

/// Columns and rows `[x0, y0, x1, y1]` of the four pixels of a bilinear lookup at `p` in a
/// `w x h` image; `None` outside the image or for NaN.
#[inline(always)]
fn bilinear_taps(w: usize, h: usize, p: [f32; 2]) -> Option<[usize; 4]> {
    let [x, y] = p;
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f32 && y <= (h - 1) as f32) {
        return None;
    }
    // floor(x) for x >= 0 is the truncation (no libm call; `floorf` was 4 % of a run).
    let (x0, y0) = (x as usize, y as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    Some([x0, y0, x1, y1])
}
