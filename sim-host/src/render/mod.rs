//! Rendered stereo hazcams: a rasterizer for height-field terrain with a procedural albedo,
//! Lambertian sun shading, sky, and seeded Gaussian image noise.
//!
//! # Method
//! 1. **Mesh** (module `mesh`): the terrain is sampled once per stereo pair on a polar grid around
//!    the stereo head, with range steps that keep triangles a few pixels wide at every range
//!    ([`RenderSettings::mesh_step_px`]); each vertex gets its Lambertian shade.
//! 2. **Raster** (module `raster`): per camera, the mesh is projected with the rectified pinhole model
//!    of [`rover_hal::StereoCalibration`] and rasterized with a `1/z` depth buffer.
//! 3. **Shade**: per pixel, the world point under the pixel centre is recovered from the depth
//!    and the pixel's ray, the albedo is evaluated there (filtered to the pixel footprint), and
//!    `DN = exposure * albedo * shade + sigma * n`, `n ~ N(0, 1)`, is rounded to `u8`. Pixels no
//!    triangle covers (beyond [`RenderSettings::max_range_m`] or above the horizon) get the sky
//!    value.
//!
//! The two cameras share the mesh and are rendered in parallel (`rayon::join`); every pixel and
//! texel is a pure function of the inputs and seeds, so the bytes do not depend on the number of
//! threads.
//!
//! # Frames
//! World `W`: x north, y east, z down (the flight software's `N`). Camera `K`: x right, y down,
//! z optical axis; the right camera is the left one displaced by `baseline_m` along `x_K`.
//! Pixel `(i, j)` (column, row) has its centre at `u = i`, `v = j`.
//!
//! # Not modelled
//! Cast shadows, inter-reflection, vignetting, motion blur, exposure control. Lens distortion is
//! modelled by [`lens_rig::LensRig`]: a pinhole pair larger than the raw field, resampled through
//! each raw camera's lens.

pub mod lens_rig;
mod mesh;
mod noise;
mod raster;
mod texture;

#[cfg(test)]
mod tests;

pub use texture::{AlbedoTexture, HeightFn, TextureParams, TexturedSurface};

use crate::surface::TerrainSurface;
use mesh::{Mesh, MeshSpec};
use raster::{Frame, View};
use rover_hal::{StereoCalibration, IMAGE_HEIGHT_PX, IMAGE_WIDTH_PX};

/// Ground albedo averaged over a footprint, for anti-aliased rendering. The default method
/// point-samples [`TerrainSurface::albedo`].
pub trait FilteredAlbedo: TerrainSurface {
    /// Mean albedo in `[0, 1]` over a patch of about `footprint_m` (m) around world
    /// `(x_m, y_m)` (frame `W`).
    fn albedo_filtered(&self, x_m: f64, y_m: f64, footprint_m: f64) -> f64 {
        let _ = footprint_m;
        self.albedo(x_m, y_m)
    }

    /// [`Self::albedo_filtered`] of many points at once: `out[k]` for `(x_m[k], y_m[k],
    /// footprint_m[k])`, over the shortest of the four slices. The renderer calls this once per
    /// image row (with the row's ground pixels); override it where batching is faster (as
    /// [`TexturedSurface`] does). The default calls [`Self::albedo_filtered`] per point.
    fn albedo_filtered_batch(
        &self,
        x_m: &[f64],
        y_m: &[f64],
        footprint_m: &[f64],
        out: &mut [f64],
    ) {
        for (((o, &x), &y), &f) in out.iter_mut().zip(x_m).zip(y_m).zip(footprint_m) {
            *o = self.albedo_filtered(x, y, f);
        }
    }
}

/// Pose of the left camera in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// Rotation `W <- K` (row-major, `v_W = R_WK v_K`).
    pub rot_world_from_camera: [[f64; 3]; 3],
    /// Optical centre of the left camera in `W`, m.
    pub pos_world_m: [f64; 3],
}

impl CameraPose {
    /// Left-camera pose from the rover pose (`R_WR`, rover reference point in `W`) and the
    /// camera mounting in `calib`: `R_WK = R_WR R_RK`, `C = p_R + R_WR t_RK`.
    pub fn from_rover(
        rot_world_from_rover: [[f64; 3]; 3],
        pos_rover_world_m: [f64; 3],
        calib: &StereoCalibration,
    ) -> Self {
        let r = rot_world_from_rover;
        let k = calib.rot_rover_from_camera;
        let mut rot = [[0.0; 3]; 3];
        for (i, row) in rot.iter_mut().enumerate() {
            for (j, out) in row.iter_mut().enumerate() {
                *out = (0..3).map(|m| r[i][m] * k[m][j]).sum();
            }
        }
        let t = calib.pos_camera_in_rover_m;
        let mut pos = pos_rover_world_m;
        for (i, p) in pos.iter_mut().enumerate() {
            *p += (0..3).map(|m| r[i][m] * t[m]).sum::<f64>();
        }
        Self {
            rot_world_from_camera: rot,
            pos_world_m: pos,
        }
    }

    /// Pose of the right camera: the left one moved by `baseline_m` along `x_K`.
    pub fn right(&self, baseline_m: f64) -> Self {
        let r = &self.rot_world_from_camera;
        let p = self.pos_world_m;
        Self {
            rot_world_from_camera: *r,
            pos_world_m: [
                p[0] + baseline_m * r[0][0],
                p[1] + baseline_m * r[1][0],
                p[2] + baseline_m * r[2][0],
            ],
        }
    }
}

/// Direction of the sun.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sun {
    /// Unit vector from the ground towards the sun in `W` (a sun above the horizon has a
    /// negative `z`).
    pub direction_w: [f64; 3],
}

impl Sun {
    /// Sun at `azimuth_rad` (from north towards east) and `elevation_rad` above the horizon.
    pub fn from_azimuth_elevation(azimuth_rad: f64, elevation_rad: f64) -> Self {
        let (sa, ca) = azimuth_rad.sin_cos();
        let (se, ce) = elevation_rad.sin_cos();
        Self {
            direction_w: [ce * ca, ce * sa, -se],
        }
    }
}

/// Image formation and meshing parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// DN of a surface of albedo 1 facing the sun (shade 1).
    pub exposure_dn: f64,
    /// Share of the light that is ambient (sky), `[0, 1]`: `shade = ambient + (1 - ambient) *
    /// max(0, n . s)`.
    pub ambient: f64,
    /// DN of the sky (pixels that see no terrain).
    pub sky_dn: f64,
    /// Standard deviation of the Gaussian image noise, DN (added before quantization).
    pub noise_sigma_dn: f64,
    /// Largest range of rendered terrain, m (beyond it: sky).
    pub max_range_m: f64,
    /// Mesh step as seen from the cameras, pixels (smaller = finer relief, slower).
    pub mesh_step_px: f64,
    /// Sine of the grazing angle down to which slopes keep the full mesh resolution.
    pub sin_min_grazing: f64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            exposure_dn: 500.0,
            ambient: 0.3,
            sky_dn: 190.0,
            noise_sigma_dn: 2.0,
            max_range_m: 60.0,
            mesh_step_px: 8.0,
            sin_min_grazing: 0.25,
        }
    }
}

/// Why a pair could not be rendered.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RenderError {
    /// An output buffer does not hold `width * height` bytes.
    BufferSize {
        /// Bytes required.
        expected: usize,
        /// Bytes in the left buffer.
        left: usize,
        /// Bytes in the right buffer.
        right: usize,
    },
    /// The camera pose has a non-finite value or its rotation is not orthonormal.
    BadPose,
    /// The sun direction is not a finite unit vector.
    BadSun,
    /// The calibration has non-finite or non-positive focal lengths, or a non-finite baseline.
    BadCalibration,
    /// A setting is non-finite or out of range.
    BadSettings,
}

/// Figures of one rendered pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RenderStats {
    /// Mesh vertices (shared by both cameras).
    pub vertices: usize,
    /// Triangles that reached the pixel loop, left and right.
    pub triangles: [usize; 2],
    /// Pixels that saw no terrain, left and right.
    pub sky_pixels: [usize; 2],
}

/// Renders rectified stereo pairs of a terrain; keeps its buffers between frames.
#[derive(Debug, Clone)]
pub struct StereoRenderer {
    calib: StereoCalibration,
    settings: RenderSettings,
    width: usize,
    height: usize,
    mesh: Mesh,
    frames: [Frame; 2],
    /// Mesh vertices projected into the left and right cameras.
    proj: [Vec<[f64; 3]>; 2],
    gauss: Box<noise::GaussTable>,
}

impl StereoRenderer {
    /// A renderer for `IMAGE_WIDTH_PX x IMAGE_HEIGHT_PX` images with the calibration `calib`.
    pub fn new(calib: StereoCalibration, settings: RenderSettings) -> Self {
        Self::with_size(calib, settings, IMAGE_WIDTH_PX, IMAGE_HEIGHT_PX)
    }

    /// A renderer for `width x height` pinhole images (at least 2 x 2; the lens model renders
    /// a pinhole image larger than the raw field, [`lens_rig::LensRig`]).
    pub fn with_size(
        calib: StereoCalibration,
        settings: RenderSettings,
        width: usize,
        height: usize,
    ) -> Self {
        let (width, height) = (width.max(2), height.max(2));
        Self {
            calib,
            settings,
            width,
            height,
            mesh: Mesh::default(),
            frames: [Frame::new(width, height), Frame::new(width, height)],
            proj: [Vec::new(), Vec::new()],
            gauss: noise::gaussian_table(),
        }
    }

    /// The settings in use.
    pub fn settings(&self) -> &RenderSettings {
        &self.settings
    }

    /// Change the settings (for example the noise level) for the next frames.
    pub fn set_settings(&mut self, settings: RenderSettings) {
        self.settings = settings;
    }

    /// The calibration in use.
    pub fn calibration(&self) -> &StereoCalibration {
        &self.calib
    }

    /// Draw the next frames with `calib`.
    pub fn set_calibration(&mut self, calib: StereoCalibration) {
        self.calib = calib;
    }

    /// Image size, pixels (width, height).
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Shade only the pixels whose value is used, per camera (left, right: `width * height`
    /// flags, row-major; `None` or a mask of another size: every pixel). The used pixels get
    /// the same values as without the masks, the others arbitrary ones; the statistics still
    /// count every pixel.
    pub(crate) fn set_used_pixels(&mut self, masks: [Option<Vec<bool>>; 2]) {
        for (frame, mask) in self.frames.iter_mut().zip(masks) {
            frame.set_used(mask);
        }
    }

    /// Render the pair seen from `left_pose` into `left` and `right` (`width * height` bytes
    /// each, row-major; `IMAGE_PIXELS` for [`Self::new`]), with the albedo filtered to each pixel's footprint. `noise_seed` selects
    /// the image noise (use a different seed per frame).
    pub fn render<S: FilteredAlbedo + ?Sized>(
        &mut self,
        surface: &S,
        left_pose: &CameraPose,
        sun: &Sun,
        noise_seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<RenderStats, RenderError> {
        let albedo = |x: &[f64], y: &[f64], f: &[f64], out: &mut [f64]| {
            surface.albedo_filtered_batch(x, y, f, out)
        };
        self.render_with(surface, &albedo, left_pose, sun, noise_seed, left, right)
    }

    /// As [`Self::render`], for any [`TerrainSurface`], with the albedo point-sampled at each
    /// pixel centre (distant texture aliases).
    pub fn render_point_sampled<S: TerrainSurface + ?Sized>(
        &mut self,
        surface: &S,
        left_pose: &CameraPose,
        sun: &Sun,
        noise_seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<RenderStats, RenderError> {
        let albedo = |x: &[f64], y: &[f64], _f: &[f64], out: &mut [f64]| {
            for ((o, &x), &y) in out.iter_mut().zip(x).zip(y) {
                *o = surface.albedo(x, y);
            }
        };
        self.render_with(surface, &albedo, left_pose, sun, noise_seed, left, right)
    }

    #[allow(clippy::too_many_arguments)]
    fn render_with<S, A>(
        &mut self,
        surface: &S,
        albedo: &A,
        left_pose: &CameraPose,
        sun: &Sun,
        noise_seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<RenderStats, RenderError>
    where
        S: TerrainSurface + ?Sized,
        A: Fn(&[f64], &[f64], &[f64], &mut [f64]) + Sync,
    {
        self.check(left_pose, sun, left.len(), right.len())?;
        let views = self.views(left_pose);
        let spec = mesh_spec(surface, &views, &self.settings, self.width, self.height);
        self.mesh.build(surface, &spec, sun, self.settings.ambient);
        // Project the mesh once: the right camera is the left one moved by the baseline along
        // x_K, so u_r = u_l - f_x B / z with the same v and 1/z.
        let [proj_l, proj_r] = &mut self.proj;
        let disparity_scale = views[0].fx * self.calib.baseline_m;
        proj_l.clear();
        proj_r.clear();
        for &p in &self.mesh.pos {
            let q = views[0].project(p).unwrap_or([0.0, 0.0, -1.0]);
            proj_l.push(q);
            proj_r.push([q[0] - disparity_scale * q[2], q[1], q[2]]);
        }
        let (mesh, settings, gauss) = (&self.mesh, &self.settings, &self.gauss);
        let [frame_l, frame_r] = &mut self.frames;
        let camera =
            |frame: &mut Frame, view: &View, proj: &[[f64; 3]], out: &mut [u8], index: u64| {
                frame.rasterize(mesh, proj);
                let sky = frame.shade_into(view, settings, albedo, (noise_seed, index), gauss, out);
                (frame.triangles_drawn, sky)
            };
        let ((tl, sl), (tr, sr)) = rayon::join(
            || camera(frame_l, &views[0], &self.proj[0], left, 0),
            || camera(frame_r, &views[1], &self.proj[1], right, 1),
        );
        Ok(RenderStats {
            vertices: self.mesh.pos.len(),
            triangles: [tl, tr],
            sky_pixels: [sl, sr],
        })
    }

    fn check(
        &self,
        pose: &CameraPose,
        sun: &Sun,
        left: usize,
        right: usize,
    ) -> Result<(), RenderError> {
        let expected = self.width * self.height;
        if left != expected || right != expected {
            return Err(RenderError::BufferSize {
                expected,
                left,
                right,
            });
        }
        let c = &self.calib;
        let calib_ok = [c.fx_px, c.fy_px].iter().all(|f| f.is_finite() && *f > 0.0)
            && [c.cx_px, c.cy_px, c.baseline_m]
                .iter()
                .all(|v| v.is_finite());
        if !calib_ok {
            return Err(RenderError::BadCalibration);
        }
        let r = &pose.rot_world_from_camera;
        let finite = r
            .iter()
            .flatten()
            .chain(pose.pos_world_m.iter())
            .all(|v| v.is_finite());
        let orthonormal = (0..3).all(|i| {
            (0..3).all(|j| {
                let dot: f64 = (0..3).map(|m| r[m][i] * r[m][j]).sum();
                (dot - if i == j { 1.0 } else { 0.0 }).abs() < 1e-6
            })
        });
        if !finite || !orthonormal {
            return Err(RenderError::BadPose);
        }
        let s = sun.direction_w;
        let norm = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
        if !norm.is_finite() || (norm - 1.0).abs() > 1e-6 {
            return Err(RenderError::BadSun);
        }
        let st = &self.settings;
        let settings_ok = [st.exposure_dn, st.sky_dn, st.noise_sigma_dn]
            .iter()
            .all(|v| v.is_finite() && *v >= 0.0)
            && (0.0..=1.0).contains(&st.ambient)
            && st.max_range_m.is_finite()
            && st.max_range_m > 0.0
            && st.mesh_step_px.is_finite()
            && st.mesh_step_px >= 0.25
            && st.sin_min_grazing.is_finite()
            && st.sin_min_grazing > 0.0;
        if !settings_ok {
            return Err(RenderError::BadSettings);
        }
        Ok(())
    }

    fn views(&self, left_pose: &CameraPose) -> [View; 2] {
        let c = &self.calib;
        let view = |pose: &CameraPose| View {
            rot_w_from_k: pose.rot_world_from_camera,
            center_w: pose.pos_world_m,
            fx: c.fx_px,
            fy: c.fy_px,
            cx: c.cx_px,
            cy: c.cy_px,
        };
        [view(left_pose), view(&left_pose.right(c.baseline_m))]
    }
}

/// Footprint of the mesh for the two views: centre below the middle of the head, azimuth span
/// from the image borders cast onto the level plane through the ground below the head (a full
/// circle when the nadir or zenith is in view).
fn mesh_spec<S: TerrainSurface + ?Sized>(
    surface: &S,
    views: &[View; 2],
    settings: &RenderSettings,
    width: usize,
    height: usize,
) -> MeshSpec {
    let (a, b) = (views[0].center_w, views[1].center_w);
    let center = [
        0.5 * (a[0] + b[0]),
        0.5 * (a[1] + b[1]),
        0.5 * (a[2] + b[2]),
    ];
    let ground_z = -surface.height_m(center[0], center[1]);
    let head_height = ground_z - center[2];
    let step_rad = settings.mesh_step_px / views[0].fx.max(views[0].fy);
    let mut spec = MeshSpec {
        center_xy: [center[0], center[1]],
        head_height_m: head_height.max(0.05),
        azimuth_min_rad: 0.0,
        azimuth_max_rad: std::f64::consts::TAU,
        full_circle: true,
        step_rad,
        sin_min: settings.sin_min_grazing,
        max_range_m: settings.max_range_m,
    };
    let (w, h) = (width as f64, height as f64);
    // A pole within this margin of the image gives a full circle. The level hazcam has the
    // nadir 144 px (20 deg) below its image: with a margin of a quarter of the width it
    // got a full circle, 2.3 times the vertices it needs.
    let margin_px = 0.1 * w;
    let sees_pole = views.iter().any(|v| {
        [1.0, -1.0].iter().any(|&sign| {
            // Vertical direction in K: sign * third row of R_WK.
            let r = &v.rot_w_from_k;
            let d = [sign * r[2][0], sign * r[2][1], sign * r[2][2]];
            if d[2] <= 1e-9 {
                return false;
            }
            let u = v.cx + v.fx * d[0] / d[2];
            let vv = v.cy + v.fy * d[1] / d[2];
            u > -margin_px && u < w + margin_px && vv > -margin_px && vv < h + margin_px
        })
    });
    if sees_pole {
        return spec;
    }
    let axis = views[0].ray_w(views[0].cx, views[0].cy);
    let reference = axis[1].atan2(axis[0]);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    const PER_EDGE: usize = 24;
    for view in views {
        for k in 0..=PER_EDGE {
            let t = k as f64 / PER_EDGE as f64;
            let border = [
                (t * (w - 1.0), 0.0),
                (t * (w - 1.0), h - 1.0),
                (0.0, t * (h - 1.0)),
                (w - 1.0, t * (h - 1.0)),
            ];
            for (u, v) in border {
                let ray = view.ray_w(u, v);
                let c = view.center_w;
                let hits = ray[2] > 1e-9 && (ground_z - c[2]) / ray[2] > 0.0;
                let (dx, dy) = if hits {
                    let s = (ground_z - c[2]) / ray[2];
                    (c[0] + s * ray[0] - center[0], c[1] + s * ray[1] - center[1])
                } else {
                    (ray[0], ray[1])
                };
                if dx.hypot(dy) < 1e-9 {
                    return spec;
                }
                let rel = wrap_pi(dy.atan2(dx) - reference);
                lo = lo.min(rel);
                hi = hi.max(rel);
            }
        }
    }
    let margin = 6f64.to_radians();
    if hi - lo + 2.0 * margin < 0.9 * std::f64::consts::TAU {
        spec.full_circle = false;
        spec.azimuth_min_rad = reference + lo - margin;
        spec.azimuth_max_rad = reference + hi + margin;
    }
    spec
}

/// Angle wrapped to `(-pi, pi]`.
fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let w = a - t * (a / t).round();
    if w <= -std::f64::consts::PI {
        w + t
    } else {
        w
    }
}
