//! Stereo camera pair (Rocky 8 hazcams, H04 sec. 2).

use crate::Error;

/// Image width, pixels (Rocky 8 hazcam).
pub const IMAGE_WIDTH_PX: usize = 640;
/// Image height, pixels (Rocky 8 hazcam).
pub const IMAGE_HEIGHT_PX: usize = 480;
/// Pixels per image (8-bit grey, row-major, no padding).
pub const IMAGE_PIXELS: usize = IMAGE_WIDTH_PX * IMAGE_HEIGHT_PX;

/// Calibration of a rectified stereo pair: identical pinhole intrinsics for both cameras, the
/// right camera displaced by `baseline_m` along the left camera's `x` axis, and the mounting of
/// the left camera on the rover.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoCalibration {
    /// Focal length along image x, pixels.
    pub fx_px: f64,
    /// Focal length along image y, pixels.
    pub fy_px: f64,
    /// Principal point x, pixels (0 at the left edge of the first pixel's centre).
    pub cx_px: f64,
    /// Principal point y, pixels.
    pub cy_px: f64,
    /// Stereo baseline, m (right camera at `+baseline_m` along the left camera's `x`).
    pub baseline_m: f64,
    /// Rotation from the left camera frame `K` to the rover frame `R`, row-major 3x3
    /// (`v_R = R_RK * v_K`).
    pub rot_rover_from_camera: [[f64; 3]; 3],
    /// Position of the left camera's optical centre in the rover frame `R`, m.
    pub pos_camera_in_rover_m: [f64; 3],
}

/// State of the current capture.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CaptureStatus {
    /// No capture was triggered, or the last one was released.
    Idle,
    /// Exposure or readout still in progress.
    InProgress,
    /// Both images are ready to borrow with [`StereoCamera::frame`].
    Ready,
}

/// A stereo pair borrowed in place from the camera's buffers (no copies).
#[derive(Debug, Clone, Copy)]
pub struct StereoFrame<'a> {
    /// Left image, 8-bit grey, row-major, `IMAGE_WIDTH_PX * IMAGE_HEIGHT_PX` bytes.
    pub left: &'a [u8],
    /// Right image, same layout.
    pub right: &'a [u8],
    /// Time at which both images were exposed, microseconds since boot (the EKF clone time).
    pub capture_t_us: u64,
    /// Capture sequence number, incremented by each trigger.
    pub sequence: u32,
}

/// A synchronised, rectified stereo camera pair.
///
/// Capture is split in three calls so the flight software never blocks: [`Self::trigger`]
/// starts an exposure and returns its time stamp (the moment the EKF clones its state),
/// [`Self::poll`] reports progress, and [`Self::frame`] borrows both images in place. The images
/// stay valid until [`Self::release`] or the next trigger.
pub trait StereoCamera {
    /// Error type of this camera.
    type Error: Error;

    /// Calibration of the rectified pair.
    fn calibration(&self) -> StereoCalibration;

    /// Start a synchronised exposure of both cameras. Returns the exposure time, microseconds
    /// since boot.
    fn trigger(&mut self) -> Result<u64, Self::Error>;

    /// Progress of the current capture.
    fn poll(&mut self) -> Result<CaptureStatus, Self::Error>;

    /// Borrow the completed pair. [`crate::ErrorKind::NotReady`] if the capture is not complete.
    fn frame(&self) -> Result<StereoFrame<'_>, Self::Error>;

    /// Give the buffers back to the camera.
    fn release(&mut self) -> Result<(), Self::Error>;
}
