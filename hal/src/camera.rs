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

/// One raw (unrectified) camera of the stereo head: pinhole intrinsics, the Brown-Conrady
/// radial-tangential lens distortion (the model of OpenCV and of Bouguet's calibration toolbox:
/// radial `k1, k2, k3`, tangential `p1, p2`) and the rotation between its frame and the
/// rectified camera frame.
///
/// Frames: `K` is the rectified camera frame of [`StereoCalibration`] (for the right camera:
/// `K` moved by the baseline along `x_K`); `A` is this raw camera's frame (same optical centre,
/// `x` right, `y` down, `z` optical axis). A ray `v_K` of the rectified frame maps to the raw
/// pixel `(u, v)` by
///
/// ```text
/// v_A = R_AK v_K,  x = v_A.x / v_A.z,  y = v_A.y / v_A.z,  r^2 = x^2 + y^2
/// g   = 1 + k1 r^2 + k2 r^4 + k3 r^6
/// x_d = x g + 2 p1 x y + p2 (r^2 + 2 x^2)
/// y_d = y g + p1 (r^2 + 2 y^2) + 2 p2 x y
/// u   = cx + fx x_d,  v = cy + fy y_d      (pixel centres at integers, as StereoCalibration)
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawCamera {
    /// Focal length along raw image x, pixels.
    pub fx_px: f64,
    /// Focal length along raw image y, pixels.
    pub fy_px: f64,
    /// Principal point x of the raw image, pixels.
    pub cx_px: f64,
    /// Principal point y of the raw image, pixels.
    pub cy_px: f64,
    /// Radial distortion coefficient of `r^2` (dimensionless, normalized image coordinates).
    pub k1: f64,
    /// Radial distortion coefficient of `r^4`.
    pub k2: f64,
    /// Radial distortion coefficient of `r^6`.
    pub k3: f64,
    /// Tangential (decentring) distortion coefficient `p1`.
    pub p1: f64,
    /// Tangential (decentring) distortion coefficient `p2`.
    pub p2: f64,
    /// Rotation from the rectified frame `K` to this raw camera's frame `A`, row-major
    /// (`v_A = R_AK v_K`; the identity when the raw camera is already aligned).
    pub rot_raw_from_rect: [[f64; 3]; 3],
}

/// The lens calibration of the stereo head: the two raw cameras whose images the camera
/// delivers, from which the flight software rectifies the pair into the geometry of
/// [`StereoCamera::calibration`] (H04 sec. 2 works on rectified pairs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LensCalibration {
    /// Left raw camera (its rectified frame is `K`).
    pub left: RawCamera,
    /// Right raw camera (its rectified frame is `K` moved by the baseline along `x_K`).
    pub right: RawCamera,
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

/// A synchronised stereo camera pair: rectified images, or raw images with their
/// [`LensCalibration`].
///
/// Capture is split in three calls so the flight software never blocks: [`Self::trigger`]
/// starts an exposure and returns its time stamp (the moment the EKF clones its state),
/// [`Self::poll`] reports progress, and [`Self::frame`] borrows both images in place. The images
/// stay valid until [`Self::release`] or the next trigger.
pub trait StereoCamera {
    /// Error type of this camera.
    type Error: Error;

    /// Calibration of the rectified pair (the geometry the flight software's visual odometry
    /// and hazard mapper work in).
    fn calibration(&self) -> StereoCalibration;

    /// Lens calibration of the raw cameras when [`Self::frame`] delivers raw (unrectified)
    /// images: the flight software then rectifies each pair into the geometry of
    /// [`Self::calibration`] before using it. `None` (the default): the images are already
    /// rectified (a camera that rectifies in hardware, or a test pattern).
    fn lens_calibration(&self) -> Option<LensCalibration> {
        None
    }

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
