//! Raw images through the wide-angle lenses ([`crate::sensors::lens`]).
//!
//! Method: the pinhole pair is rendered (without noise) at a size that covers the whole raw
//! field of both cameras, with the focal length of the raw cameras' centre (so the image centre
//! is sampled at the raw density); then each raw pixel `(i, j)` of camera `c` takes the value
//! of its ray there: the ray is `lens::ray(c, i, j)` (the lens model inverted by Newton's
//! method, once per head: a map of pinhole coordinates per raw pixel), the pinhole image is
//! interpolated bilinearly at the ray's projection, and the image noise is added per raw
//! pixel (the same Gaussian table and hashing as the pinhole renderer), rounded half up and
//! clamped to `[0, 255]`.

use super::noise::{hash3, mix64};
use super::{CameraPose, FilteredAlbedo, RenderError, RenderSettings, RenderStats, Sun};
use crate::sensors::lens;
use rayon::prelude::*;
use rover_hal::{LensCalibration, RawCamera, StereoCalibration, IMAGE_HEIGHT_PX, IMAGE_WIDTH_PX};

/// Pixels sharing one noise hash (as the pinhole renderer).
const NOISE_GROUP: usize = 4;

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
                let r = lens::ray(c, i as f64, j as f64)?;
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
    /// Pinhole-image coordinates of each raw pixel, left and right (NaN where the lens model
    /// has no inverse).
    maps: [Vec<[f32; 2]>; 2],
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
                    match lens::ray(c, i as f64, j as f64) {
                        Some(r) if r[2] > 1e-6 => [
                            (cover.c_px[0] + cover.f_px * r[0] / r[2]) as f32,
                            (cover.c_px[1] + cover.f_px * r[1] / r[2]) as f32,
                        ],
                        _ => [f32::NAN; 2],
                    }
                })
                .collect()
        };
        Ok(Self {
            lens,
            cover,
            settings,
            pinhole: super::StereoRenderer::with_size(calib, quiet, w, h),
            maps: [map(&lens.left), map(&lens.right)],
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
    /// bytes each); as [`super::StereoRenderer::render`] otherwise.
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
        let (w, h) = self.cover.size;
        let sigma = self.settings.noise_sigma_dn;
        let sky = self.settings.sky_dn;
        let gauss = &self.gauss;
        let resample = |image: &[u8], map: &[[f32; 2]], out: &mut [u8], camera: u64| {
            let table_mask = (gauss.len().min(1 << 16) - 1) as u64;
            let key = hash3(noise_seed, camera, 0x006c_656e_7300);
            out.par_chunks_mut(IMAGE_WIDTH_PX)
                .zip(map.par_chunks(IMAGE_WIDTH_PX))
                .enumerate()
                .for_each(|(j, (row, map_row))| {
                    for group in (0..IMAGE_WIDTH_PX).step_by(NOISE_GROUP) {
                        let id = ((j * IMAGE_WIDTH_PX + group) / NOISE_GROUP) as u64;
                        let hash = mix64(key ^ id.wrapping_mul(0x9e37_79b9_7f4a_7c15));
                        let end = (group + NOISE_GROUP).min(IMAGE_WIDTH_PX);
                        for (q, i) in (group..end).enumerate() {
                            let clean = bilinear(image, w, h, map_row[i]).unwrap_or(sky as f32);
                            let g = gauss[((hash >> (16 * q)) & table_mask) as usize];
                            let v = f64::from(clean) + sigma * f64::from(g);
                            row[i] = (v.clamp(0.0, 255.0) + 0.5) as i32 as u8;
                        }
                    }
                });
        };
        let [ml, mr] = &self.maps;
        rayon::join(|| resample(pl, ml, left, 0), || resample(pr, mr, right, 1));
        Ok(stats)
    }
}

/// Bilinear interpolation of the `w x h` image at `p` (pixel centres at integers); `None`
/// outside the image or for NaN.
fn bilinear(image: &[u8], w: usize, h: usize, p: [f32; 2]) -> Option<f32> {
    let [x, y] = p;
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f32 && y <= (h - 1) as f32) {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (a, b) = (x - x0 as f32, y - y0 as f32);
    let px = |i: usize, j: usize| f32::from(image[j * w + i]);
    let top = px(x0, y0) + a * (px(x1, y0) - px(x0, y0));
    let bottom = px(x0, y1) + a * (px(x1, y1) - px(x0, y1));
    Some(top + b * (bottom - top))
}
