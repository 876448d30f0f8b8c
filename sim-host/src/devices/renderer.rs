//! The image source of the world's stereo camera ([`crate::devices::world::WorldStereo`]): it
//! renders a pair at each trigger from the true camera pose.
//!
//! The images come from a [`StereoRenderer`]. [`FlatGreyRenderer`] is the renderer used when no
//! terrain renderer is plugged in: it fills both images with a uniform grey (plus nothing else),
//! which exercises the capture protocol and timing but gives visual odometry nothing to track.

use crate::surface::TerrainSurface;
use rover_hal::StereoCalibration;

/// Something that renders a rectified stereo pair of the terrain.
pub trait StereoRenderer {
    /// Render the left and right images (8-bit grey, row-major, `IMAGE_PIXELS` each) for a left
    /// camera at `left_cam_pos_w` (m, frame `W`) with orientation `left_cam_rot_w_from_k`
    /// (`v_W = R * v_K`, row-major), the right camera displaced by the baseline along `x_K`.
    /// `seed` selects the image noise of this frame.
    #[allow(clippy::too_many_arguments)]
    fn render(
        &self,
        surface: &dyn TerrainSurface,
        left_cam_rot_w_from_k: [[f64; 3]; 3],
        left_cam_pos_w: [f64; 3],
        calib: &StereoCalibration,
        seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    );

    /// Light the next frames with the sun at `sun_w` (unit vector towards the sun in `W`). The
    /// default ignores it (a renderer without shading).
    fn set_sun(&self, sun_w: [f64; 3]) {
        let _ = sun_w;
    }

    /// Draw the next frames as raw images through the lenses `lens` (the true ones), or as the
    /// rectified pinhole pair when `None`. The default ignores it (a renderer without
    /// geometry).
    fn set_lens(&self, lens: Option<rover_hal::LensCalibration>) {
        let _ = lens;
    }
}

/// Uniform grey images (value 128): the stand-in used when no terrain renderer is available.
#[derive(Debug, Clone, Copy, Default)]
pub struct FlatGreyRenderer;

impl StereoRenderer for FlatGreyRenderer {
    fn render(
        &self,
        _surface: &dyn TerrainSurface,
        _rot: [[f64; 3]; 3],
        _pos: [f64; 3],
        _calib: &StereoCalibration,
        _seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) {
        left.fill(128);
        right.fill(128);
    }
}

/// The rendered hazcams: [`crate::render::StereoRenderer`] over the terrain's heights with the
/// procedural albedo texture of [`crate::render::AlbedoTexture`] and Lambertian sun shading.
///
/// Each frame is drawn with the calibration passed to [`StereoRenderer::render`] (the simulated
/// camera passes its true head) and the sun of the last [`StereoRenderer::set_sun`]; with
/// lenses ([`StereoRenderer::set_lens`]) as raw images through [`crate::render::lens_rig::LensRig`]
/// (the head's mounting and baseline from the calibration, the intrinsics from the lenses).
///
/// A render error (which only a degenerate pose or calibration can cause) gives black images,
/// which the flight software rejects as a blank frame, and is counted in [`Self::errors`].
pub struct TexturedRenderer {
    inner: std::cell::RefCell<crate::render::StereoRenderer>,
    /// Lenses of [`StereoRenderer::set_lens`], and their rig (built at the first frame).
    lens: std::cell::Cell<Option<rover_hal::LensCalibration>>,
    rig: std::cell::RefCell<Option<crate::render::lens_rig::LensRig>>,
    texture: std::sync::Arc<crate::render::AlbedoTexture>,
    sun: std::cell::Cell<crate::render::Sun>,
    errors: std::cell::Cell<u64>,
}

impl TexturedRenderer {
    /// A renderer starting with `calib`, with the texture of `texture_seed` and the sun at
    /// `sun_w` (unit vector towards the sun in `W`) until [`StereoRenderer::set_sun`].
    pub fn new(calib: StereoCalibration, texture_seed: u64, sun_w: [f64; 3]) -> Self {
        let params = crate::render::TextureParams {
            seed: texture_seed,
            ..crate::render::TextureParams::default()
        };
        Self {
            inner: std::cell::RefCell::new(crate::render::StereoRenderer::new(
                calib,
                crate::render::RenderSettings::default(),
            )),
            texture: std::sync::Arc::new(crate::render::AlbedoTexture::new(params)),
            lens: std::cell::Cell::new(None),
            rig: std::cell::RefCell::new(None),
            sun: std::cell::Cell::new(crate::render::Sun { direction_w: sun_w }),
            errors: std::cell::Cell::new(0),
        }
    }

    /// Frames that failed to render (delivered black).
    pub fn errors(&self) -> u64 {
        self.errors.get()
    }
}

/// A borrowed terrain as an owned [`TerrainSurface`] for the texture wrapper.
struct BorrowedSurface<'a>(&'a dyn TerrainSurface);

impl TerrainSurface for BorrowedSurface<'_> {
    fn height_m(&self, x_m: f64, y_m: f64) -> f64 {
        self.0.height_m(x_m, y_m)
    }
    fn albedo(&self, x_m: f64, y_m: f64) -> f64 {
        self.0.albedo(x_m, y_m)
    }
    fn normal_up(&self, x_m: f64, y_m: f64) -> [f64; 3] {
        self.0.normal_up(x_m, y_m)
    }
    fn has_edges(&self) -> bool {
        self.0.has_edges()
    }
}

impl StereoRenderer for TexturedRenderer {
    fn render(
        &self,
        surface: &dyn TerrainSurface,
        left_cam_rot_w_from_k: [[f64; 3]; 3],
        left_cam_pos_w: [f64; 3],
        calib: &StereoCalibration,
        seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) {
        let textured =
            crate::render::TexturedSurface::new(BorrowedSurface(surface), self.texture.clone());
        let pose = crate::render::CameraPose {
            rot_world_from_camera: left_cam_rot_w_from_k,
            pos_world_m: left_cam_pos_w,
        };
        let result = match self.lens.get() {
            None => {
                let mut inner = self.inner.borrow_mut();
                if inner.calibration() != calib {
                    inner.set_calibration(*calib);
                }
                inner.render(&textured, &pose, &self.sun.get(), seed, left, right)
            }
            Some(lens) => {
                let mut rig = self.rig.borrow_mut();
                if rig.as_ref().map(|r| *r.lens()) != Some(lens) {
                    let settings = *self.inner.borrow().settings();
                    *rig = crate::render::lens_rig::LensRig::new(lens, calib, settings).ok();
                }
                match rig.as_mut() {
                    Some(r) => {
                        r.set_head(calib);
                        r.render(&textured, &pose, &self.sun.get(), seed, left, right)
                    }
                    None => Err(crate::render::RenderError::BadCalibration),
                }
            }
        };
        if result.is_err() {
            self.errors.set(self.errors.get() + 1);
            left.fill(0);
            right.fill(0);
        }
    }

    fn set_sun(&self, sun_w: [f64; 3]) {
        self.sun.set(crate::render::Sun { direction_w: sun_w });
    }

    fn set_lens(&self, lens: Option<rover_hal::LensCalibration>) {
        self.lens.set(lens);
    }
}
