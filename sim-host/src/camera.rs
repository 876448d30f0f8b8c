//! Stereo camera device: renders a pair at each trigger from the true camera pose.
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
