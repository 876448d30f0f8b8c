//! # Stereo visual odometry (H04 sec. 2; H05 sec. II)
//!
//! Estimates the rover's motion between two rectified stereo pairs of the hazcams, with its 6x6
//! covariance, as a [`RelativePose`](crate::types::RelativePose) in the rover frame `R` for the
//! estimator (H04 eq. 28-45).
//!
//! Pipeline of one update ([`VisualOdometry`], resumable, see `docs/vo.md`):
//! 1. image checks (size, blank, saturated, repeated frame) ([`image`]);
//! 2. tracking of the previous frame's features: projection with the motion prior, correlation
//!    search in a window, affine template refinement (eq. 9-10) ([`track`]), stereo matching of
//!    the tracked features and triangulation (eq. 1-8) ([`stereo`]);
//! 3. motion: Schonemann inside least-median-of-squares, then maximum likelihood (eq. 11)
//!    ([`motion`]);
//! 4. new features for the next update: Forstner interest operator, best pixel per grid cell,
//!    sort, top N with a minimum distance ([`features`]), stereo matched and triangulated.
//!
//! Frames: camera frame `K` of the left hazcam (x right, y down, z optical axis), the right camera
//! at `+baseline` along `K`'s x axis; `K0`, `K1` the left camera at the previous and the current
//! capture. Pixel coordinates: x to the right, y down, the centre of the first pixel at (0, 0).
//!
//! No allocation, no recursion, every loop bounded; every buffer is a field of
//! [`VisualOdometry`] with the capacity `N` features; failures are [`VoError`] values.

// `!(x > limit)` is used on purpose: it is true for NaN, so a non-finite value fails the check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod features;
pub mod image;
pub mod motion;
pub mod pipeline;
pub mod stereo;
pub mod track;

#[cfg(test)]
mod middlebury_tests;
#[cfg(test)]
pub(crate) mod render;
#[cfg(test)]
mod tests;

pub use pipeline::{Progress, VisualOdometry, WorkKind};

/// Side of the square correlation template, pixels (odd).
pub const TEMPLATE_SIDE: usize = 11;
/// Half side of the template, pixels.
pub const TEMPLATE_HALF: usize = TEMPLATE_SIDE / 2;
/// Pixels in a template.
pub const TEMPLATE_PIXELS: usize = TEMPLATE_SIDE * TEMPLATE_SIDE;
/// Largest stereo disparity the matcher can search, pixels (bounds a stack buffer).
pub const MAX_DISPARITY_PX: usize = 191;
/// Largest tracking search radius, pixels.
pub const MAX_SEARCH_RADIUS_PX: usize = 48;
/// Largest number of least-median-of-squares hypotheses.
pub const MAX_HYPOTHESES: u16 = 1024;

/// The nominal Rocky 8 hazcam pair (REFERENCE.md): 640x480 rectified images, 79.5 x 64.0 deg
/// field of view (`f_x = 320 / tan(39.75 deg)`, `f_y = 240 / tan(32 deg)`, pixels), principal
/// point at the image centre `(319.5, 239.5)`, 8.4 cm baseline along the camera `x`, optical
/// axis 45 deg below the rover's forward axis, left camera 0.2 m ahead of and 0.6 m above the
/// rover reference point. Camera frame `K`: x right (= rover `y`), y image down, z optical axis.
/// The one definition shared by the simulator, the tests and the benchmarks; on the rover the
/// camera device reports its own calibration.
pub fn rocky8_hazcam() -> rover_hal::StereoCalibration {
    let deg = core::f64::consts::PI / 180.0;
    let fx = 320.0 / libm::tan(39.75 * deg);
    let fy = 240.0 / libm::tan(32.0 * deg);
    let (s, c) = libm::sincos(45.0 * deg);
    rover_hal::StereoCalibration {
        fx_px: fx,
        fy_px: fy,
        cx_px: 319.5,
        cy_px: 239.5,
        baseline_m: 0.084,
        rot_rover_from_camera: [[0.0, -s, c], [1.0, 0.0, 0.0], [0.0, c, s]],
        pos_camera_in_rover_m: [0.2, 0.0, -0.6],
    }
}

/// Tuning of the visual odometry (units in the names). [`VoConfig::default`] suits the Rocky 8
/// hazcams (640x480, 8.4 cm baseline) at 20-30 cm steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoConfig {
    /// Forstner: minimum interest `w = det(N) / trace(N)` of the 5x5 gradient normal matrix `N`
    /// (grey levels squared; gradients are central differences).
    pub min_interest: f32,
    /// Forstner: minimum roundness `q = 4 det(N) / trace(N)^2` (0..1; rejects edges).
    pub min_roundness: f32,
    /// Minimum distance between two selected features, pixels (larger than the 10 px grid).
    pub min_distance_px: f32,
    /// Smallest stereo disparity searched, pixels (sets the far range limit).
    pub min_disparity_px: u16,
    /// Largest stereo disparity searched, pixels (at most [`MAX_DISPARITY_PX`]).
    pub max_disparity_px: u16,
    /// Stereo: the full disparity range is scanned every this many pixels, then the two
    /// neighbours of the best (1: every disparity; 2 halves the correlation work).
    pub stereo_coarse_step: u8,
    /// Stereo of a tracked feature: half width of the disparity window around the disparity
    /// predicted by the motion prior, pixels (0: scan the full range).
    pub track_disparity_margin_px: u16,
    /// Minimum normalised cross-correlation of a stereo or tracking match (-1..1).
    pub min_correlation: f32,
    /// A stereo match is ambiguous when another disparity more than 2 px away scores within this
    /// margin of the best.
    pub uniqueness_margin: f32,
    /// Left-right consistency: largest distance between the left feature and the column found by
    /// matching the right template back along the left row, pixels.
    pub left_right_tolerance_px: f64,
    /// Left-right consistency: half width of the back-scan around the match's disparity,
    /// pixels (0: the whole searched range).
    pub left_right_window_px: u16,
    /// Left-right consistency: the back-scan samples every this many pixels, then the columns
    /// within half a step of the best (1..=4).
    pub left_right_step: u8,
    /// Depth-discontinuity rule: half window of disparities around the match over which each
    /// template half is correlated, pixels.
    pub half_window_px: u16,
    /// Depth-discontinuity rule: smallest grey-level standard deviation of a template half for
    /// it to be checked (a flat half says nothing), grey levels.
    pub half_min_std: f32,
    /// Depth-discontinuity rule: smallest correlation of a textured half at the match's
    /// disparity (-1..1).
    pub half_min_correlation: f32,
    /// Largest vertical offset between left and right match of a rectified pair, pixels.
    pub max_row_offset_px: f64,
    /// Largest ray gap (eq. 1-4) as an angle seen from the left camera, in pixels of focal length.
    pub max_gap_px: f64,
    /// Range limits of a triangulated point from the left camera, m.
    pub min_range_m: f64,
    /// Range limits of a triangulated point from the left camera, m.
    pub max_range_m: f64,
    /// Standard deviation of a matched image coordinate, pixels (Sigma_l, Sigma_r of eq. 8);
    /// values below `stereo::MATCH_SIGMA_FLOOR_PX` (0.3 px) are raised to it.
    pub sigma_px: f64,
    /// Calibration term of the point covariances: standard deviation of the disparity error
    /// left by the calibration (rectification and distortion residuals), pixels
    /// (`stereo::triangulate_model`).
    pub sigma_calibration_px: f64,
    /// Tracking: half side of the correlation search window around the predicted position, px.
    pub search_radius_px: u16,
    /// Tracking: largest motion of the affine refinement from the correlation peak, pixels.
    pub max_refine_shift_px: f64,
    /// Least-median-of-squares: number of random minimal subsets (at most [`MAX_HYPOTHESES`]).
    pub lmeds_hypotheses: u16,
    /// Seed of the deterministic random number generator of least-median-of-squares.
    pub lmeds_seed: u64,
    /// Inlier gate on the squared Mahalanobis residual of a feature (3 dof; 16.27 = 99.9 %).
    pub inlier_gate_chi2: f64,
    /// Maximum-likelihood Gauss-Newton iterations per round (eq. 11).
    pub ml_iterations: u8,
    /// Fewest selected features.
    pub min_features: u16,
    /// Fewest stereo-matched features in a new keyframe.
    pub min_matches: u16,
    /// Fewest features tracked and stereo matched in the new pair.
    pub min_tracked: u16,
    /// Fewest inliers of the motion.
    pub min_inliers: u16,
    /// Image check: smallest standard deviation of the grey levels (blank image below).
    pub min_image_std: f64,
    /// Image check: largest fraction of pixels at 0 or 255.
    pub max_clipped_fraction: f64,
    /// Cost of one work item of each [`WorkKind`] (indexed by `kind as usize`), in units of
    /// about 10 000 rover-CPU instructions: the largest item of the kind measured on the
    /// rover-CPU model (`docs/timing.md`, "VO work items"), rounded up. [`VisualOdometry::step`]
    /// runs items until their costs reach its quantum, so a background slice stays near the
    /// quantum whatever the mix of items. Values of 0 count as 1.
    pub work_cost: [u16; WorkKind::COUNT],
}

impl Default for VoConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl VoConfig {
    /// The default tuning (as [`Default`], usable in a `const`).
    pub const DEFAULT: Self = Self {
        min_interest: 50.0,
        min_roundness: 0.3,
        min_distance_px: 20.0,
        min_disparity_px: 1,
        max_disparity_px: 128,
        stereo_coarse_step: 2,
        track_disparity_margin_px: 0,
        min_correlation: 0.8,
        uniqueness_margin: 0.02,
        max_row_offset_px: 1.5,
        left_right_tolerance_px: 1.0,
        left_right_window_px: 0,
        left_right_step: 2,
        half_window_px: 2,
        half_min_std: 4.0,
        half_min_correlation: 0.5,
        max_gap_px: 1.5,
        min_range_m: 0.2,
        max_range_m: 30.0,
        sigma_px: 0.3,
        sigma_calibration_px: 0.2,
        search_radius_px: 24,
        max_refine_shift_px: 3.0,
        lmeds_hypotheses: 64,
        lmeds_seed: 0x005e_ed0f_5107_0d0e,
        inlier_gate_chi2: 16.27,
        ml_iterations: 10,
        min_features: 12,
        min_matches: 10,
        min_tracked: 8,
        min_inliers: 6,
        min_image_std: 3.0,
        max_clipped_fraction: 0.5,
        work_cost: [6, 34, 7, 28, 9, 14, 16, 1],
    };
}

impl VoConfig {
    /// True when every field is finite and within its documented range.
    pub fn is_valid(&self) -> bool {
        let finite = [
            self.max_row_offset_px,
            self.left_right_tolerance_px,
            self.max_gap_px,
            self.min_range_m,
            self.max_range_m,
            self.sigma_px,
            self.sigma_calibration_px,
            self.max_refine_shift_px,
            self.inlier_gate_chi2,
            self.min_image_std,
            self.max_clipped_fraction,
        ]
        .iter()
        .all(|v| v.is_finite())
            && [
                self.min_interest,
                self.min_roundness,
                self.min_distance_px,
                self.min_correlation,
                self.uniqueness_margin,
                self.half_min_std,
                self.half_min_correlation,
            ]
            .iter()
            .all(|v| v.is_finite());
        finite
            && self.min_interest > 0.0
            && (0.0..=1.0).contains(&self.min_roundness)
            && self.min_distance_px >= 1.0
            && self.min_disparity_px >= 1
            && self.min_disparity_px < self.max_disparity_px
            && usize::from(self.max_disparity_px) <= MAX_DISPARITY_PX
            && (1..=4).contains(&self.stereo_coarse_step)
            && (-1.0..1.0).contains(&self.min_correlation)
            && self.uniqueness_margin >= 0.0
            && self.max_row_offset_px > 0.0
            && self.left_right_tolerance_px >= 0.0
            && (1..=4).contains(&self.left_right_step)
            && self.half_window_px >= 2
            && usize::from(self.half_window_px) <= MAX_DISPARITY_PX
            && self.half_min_std >= 0.0
            && (-1.0..=1.0).contains(&self.half_min_correlation)
            && self.max_gap_px > 0.0
            && self.min_range_m > 0.0
            && self.max_range_m > self.min_range_m
            && self.sigma_px > 0.0
            && self.sigma_calibration_px >= 0.0
            && self.search_radius_px >= 1
            && usize::from(self.search_radius_px) <= MAX_SEARCH_RADIUS_PX
            && self.max_refine_shift_px > 0.0
            && self.lmeds_hypotheses >= 1
            && self.lmeds_hypotheses <= MAX_HYPOTHESES
            && self.inlier_gate_chi2 > 0.0
            && self.ml_iterations >= 1
            && self.min_features >= 3
            && self.min_matches >= 3
            && self.min_tracked >= 3
            && self.min_inliers >= 3
            && self.min_image_std >= 0.0
            && self.max_clipped_fraction > 0.0
    }
}

/// Why a visual odometry update produced no motion (every failure is a value, never a panic).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VoError {
    /// The configuration is out of range ([`VoConfig::is_valid`]).
    InvalidConfig,
    /// The calibration has a non-finite or non-positive focal length or baseline, or a mounting
    /// rotation that is not a rotation.
    InvalidCalibration,
    /// An image is not `IMAGE_WIDTH_PX * IMAGE_HEIGHT_PX` bytes.
    WrongImageSize,
    /// An image has (almost) no contrast (black, white or uniform).
    BlankImage,
    /// Too many pixels of an image are clipped at 0 or 255.
    SaturatedImage,
    /// The left image is bit-identical to the previous frame's (a stuck camera).
    RepeatedFrame,
    /// The capture time does not increase over the previous frame's.
    TimeNotIncreasing,
    /// The motion prior has non-finite values or a time interval not ending at this frame.
    InvalidPrior,
    /// [`VisualOdometry::start`] was called while an update is running.
    Busy,
    /// [`VisualOdometry::step`] was called without a started update.
    NotStarted,
    /// The frame passed to [`VisualOdometry::step`] is not the one the update started with.
    FrameChanged,
    /// Too few features passed the interest operator.
    TooFewFeatures {
        /// Features found.
        found: u16,
    },
    /// Too few features were stereo matched in the new keyframe.
    TooFewMatches {
        /// Matches found.
        found: u16,
    },
    /// Too few previous features were tracked into the new pair.
    TooFewTracked {
        /// Features tracked and stereo matched.
        found: u16,
    },
    /// Too few features agree with the motion.
    TooFewInliers {
        /// Inliers found.
        found: u16,
    },
    /// The features do not constrain the motion (collinear or coincident points, singular
    /// normal matrix).
    DegenerateGeometry,
    /// A computation produced a non-finite number.
    NonFinite,
}

/// Stereo matches rejected in one update, per reason ([`stereo::StereoReject`]), over the
/// tracked features' and the new keyframe's matches. Counts saturate at `u16::MAX`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StereoRejectCounts {
    /// Template or search outside the image.
    pub out_of_image: u16,
    /// Best correlation below `min_correlation`.
    pub weak_correlation: u16,
    /// A rival peak within `uniqueness_margin`.
    pub ambiguous: u16,
    /// Sub-pixel refinement failed or moved too far.
    pub refinement_failed: u16,
    /// Peak at an end of the disparity search range.
    pub range_end: u16,
    /// Left-right consistency check failed (more than 1 px).
    pub left_right: u16,
    /// Template across a depth discontinuity (its halves disagree).
    pub discontinuity: u16,
    /// Degenerate rays, large gap, out of range or non-finite triangulation.
    pub triangulation: u16,
}

impl StereoRejectCounts {
    /// Counts one rejection.
    pub fn count(&mut self, reason: stereo::StereoReject) {
        use stereo::StereoReject as R;
        let slot = match reason {
            R::OutOfImage => &mut self.out_of_image,
            R::WeakCorrelation => &mut self.weak_correlation,
            R::Ambiguous => &mut self.ambiguous,
            R::RefinementFailed => &mut self.refinement_failed,
            R::RangeEnd => &mut self.range_end,
            R::LeftRightMismatch => &mut self.left_right,
            R::Discontinuity => &mut self.discontinuity,
            R::Degenerate | R::LargeGap | R::OutOfRange | R::NonFinite => &mut self.triangulation,
        };
        *slot = slot.saturating_add(1);
    }
}

/// Quality figures of one update (for telemetry and for the estimator's trust).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VoQuality {
    /// Features selected in the new left image (Forstner, after the minimum distance).
    pub features: u16,
    /// Of those, stereo matched and triangulated (the next keyframe).
    pub stereo_matches: u16,
    /// Previous features tracked into the new pair and stereo matched.
    pub tracked: u16,
    /// Tracked features that agree with the motion (used by the maximum-likelihood fit).
    pub inliers: u16,
    /// Root mean square of the inliers' 3D residuals `Q_c - R Q_p - T` (eq. 11), m.
    pub residual_rms_m: f64,
    /// Sum of squared Mahalanobis residuals of the inliers per degree of freedom.
    pub chi2_per_dof: f64,
    /// Factor applied to the motion covariance (>= 1; `motion::finish_estimate`).
    pub covariance_scale: f64,
    /// Maximum-likelihood rounds dropped to keep the previous round's solution (0 or 1).
    pub rounds_reverted: u8,
    /// Stereo matches rejected, per reason (tracked and new features).
    pub stereo_rejects: StereoRejectCounts,
    /// Work items this update used (a deterministic function of the input).
    pub work_items: u32,
}

impl VoQuality {
    /// No update yet (as [`Default`], usable in a `const`).
    pub const EMPTY: Self = Self {
        features: 0,
        stereo_matches: 0,
        tracked: 0,
        inliers: 0,
        residual_rms_m: 0.0,
        chi2_per_dof: 0.0,
        covariance_scale: 0.0,
        rounds_reverted: 0,
        stereo_rejects: StereoRejectCounts {
            out_of_image: 0,
            weak_correlation: 0,
            ambiguous: 0,
            refinement_failed: 0,
            range_end: 0,
            left_right: 0,
            discontinuity: 0,
            triangulation: 0,
        },
        work_items: 0,
    };
}

/// Result of a completed update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoOutput {
    /// Motion of the rover between the previous frame and this one, in the rover frame, with its
    /// covariance. `None` for the first frame (or the first after a failure), which only sets up
    /// the keyframe.
    pub pose: Option<crate::types::RelativePose>,
    /// Quality figures.
    pub quality: VoQuality,
}
