//! The resumable visual odometry pipeline: [`VisualOdometry`] owns every buffer (capacity `N`
//! features) and advances one update by a bounded number of work items per
//! [`VisualOdometry::step`], so the executive can run it in the slack of its minor frames.
//!
//! Work items (each bounded, see `docs/vo.md`): image check (2: left, right), track and stereo
//! match one previous feature (1 each), one least-median-of-squares hypothesis (1 each), one
//! maximum-likelihood iteration (1 each), carry the motion's inliers into the next keyframe
//! (chunks of 64: feature persistence, `docs/vo.md`), one image row of the Forstner operator (1
//! each, 464 rows; cells covered by the carried features skipped), compact the candidates (1),
//! build a best-first heap of them (chunks of 64 heap steps), pop and select the features (chunks
//! of 64 candidates, only until the features are found), write the
//! carried features' templates (chunks of 64), stereo match one new feature (1 each), finish (1).
//! The sequence of items depends only on the input, so the number of steps is deterministic.

mod estimate;
mod keyframe;
mod tracking;

use super::features::{ForstnerDetector, CELL_COUNT, END_ROW, FIRST_ROW};
use super::image::{CheckSums, Image, Template, CHECK_BANDS};
use super::motion::{
    CameraMount, Correspondence, Gating, Kept, Lmeds, MotionEstimate, RigidMotion, ML_ROUNDS,
};
use super::stereo::PinholeStereo;
use super::{VoConfig, VoError, VoOutput, VoQuality, TEMPLATE_PIXELS};
use crate::types::RelativePose;
use rover_hal::{StereoCalibration, StereoFrame};

/// Heap steps or candidates handled by one work item of the feature sort and selection.
const SORT_CHUNK: usize = 64;

/// Iterations of the maximum-likelihood rounds are capped at this many per round.
const MAX_ML_ITERATIONS: u8 = 50;

/// A keyframe feature: its stereo pixels and its left template. The template is centred on the
/// integer pixel nearest the left position (`round(pixels[0]), round(pixels[1])`): a newly
/// detected feature sits on that pixel, a carried one (tracked into this keyframe, see
/// `Phase::Seed`) keeps its sub-pixel position, so its offset from the template centre is at
/// most half a pixel along each axis.
#[derive(Debug, Clone, Copy)]
struct KeyFeature {
    pixels: [f32; 4],
    template: Template,
}

impl Default for KeyFeature {
    fn default() -> Self {
        NO_KEY_FEATURE
    }
}

/// An unused keyframe slot (`KeyFeature::default()`, usable in a `const`).
const NO_KEY_FEATURE: KeyFeature = KeyFeature {
    pixels: [0.0; 4],
    template: [0; TEMPLATE_PIXELS],
};

/// Where an update is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Idle,
    Check {
        band: u8,
        sums: CheckSums,
    },
    CheckRight {
        left_sum: u64,
        band: u8,
        sums: CheckSums,
    },
    Track {
        next: usize,
    },
    Hypotheses {
        done: u16,
    },
    Refine {
        round: u8,
        iteration: u8,
    },
    Seed {
        next: usize,
    },
    Detect {
        row: usize,
    },
    Select,
    Heapify {
        next: usize,
    },
    Choose {
        /// Candidates left in the best-first heap.
        left: usize,
    },
    Carry {
        next: usize,
    },
    StereoNew {
        next: usize,
    },
    Finish,
}

/// The kinds of work item of an update, in pipeline order (see the module doc), for the cost
/// accounting of [`VisualOdometry::step`] and timing reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WorkKind {
    /// Image checks (left, then right).
    Check = 0,
    /// Tracking of one keyframe feature (search, affine refinement, stereo), or the end of
    /// tracking.
    Track = 1,
    /// One least-median-of-squares hypothesis.
    Hypothesis = 2,
    /// One maximum-likelihood iteration of eq. 11 (or the final covariance).
    Refine = 3,
    /// One image row of the Forstner operator.
    Detect = 4,
    /// One chunk of the candidate sort and selection.
    Select = 5,
    /// Stereo match and triangulation of one new keyframe feature.
    Stereo = 6,
    /// Commit of the keyframe and the output.
    Finish = 7,
}

impl WorkKind {
    /// Number of kinds.
    pub const COUNT: usize = 8;
    /// All kinds, in pipeline order.
    pub const ALL: [WorkKind; Self::COUNT] = [
        WorkKind::Check,
        WorkKind::Track,
        WorkKind::Hypothesis,
        WorkKind::Refine,
        WorkKind::Detect,
        WorkKind::Select,
        WorkKind::Stereo,
        WorkKind::Finish,
    ];

    /// Lower-case name for reports.
    pub const fn name(self) -> &'static str {
        match self {
            WorkKind::Check => "check",
            WorkKind::Track => "track",
            WorkKind::Hypothesis => "hypothesis",
            WorkKind::Refine => "refine",
            WorkKind::Detect => "detect",
            WorkKind::Select => "select",
            WorkKind::Stereo => "stereo",
            WorkKind::Finish => "finish",
        }
    }
}

/// What [`VisualOdometry::step`] reports ([`crate::exec::Progress`]: working, or finished with
/// the update's result; the pipeline is idle again then).
pub type Progress = crate::exec::Progress<Result<VoOutput, VoError>>;

/// Stereo visual odometry with all buffers preallocated for up to `N` features (H04 sec. 2).
///
/// Use: [`Self::start`] with a stereo frame and the motion prior from vehicle odometry, then
/// [`Self::step`] with the same frame until it reports [`Progress::Finished`] (or
/// [`Self::run_to_completion`]). The first frame (or the first after a failure) only builds the
/// keyframe and reports no pose.
#[derive(Debug, Clone)]
pub struct VisualOdometry<const N: usize> {
    config: VoConfig,
    camera: PinholeStereo,
    mount: CameraMount,
    key: [KeyFeature; N],
    key_count: usize,
    key_valid: bool,
    key_t_us: u64,
    key_checksum: u64,
    pairs: [Correspondence; N],
    pair_count: usize,
    inliers: [bool; N],
    scratch: [f64; N],
    selected: [(u16, u16); N],
    selected_count: usize,
    detector: ForstnerDetector,
    lmeds: Lmeds,
    motion: RigidMotion,
    gating: Gating,
    kept: Option<Kept>,
    rounds_reverted: u8,
    estimate: Option<MotionEstimate>,
    pending: Option<VoError>,
    phase: Phase,
    frame_t_us: u64,
    frame_sequence: u32,
    frame_checksum: u64,
    quality: VoQuality,
    /// Left and right pixels in the new pair of each stored correspondence (`pairs` index);
    /// after the motion, the first `carried` hold the inliers carried into the next keyframe.
    current_px: [[f32; 4]; N],
    /// Inliers carried into the next keyframe (the first `carried` entries of `selected` and
    /// `current_px`).
    carried: usize,
    /// Grid cells of the current grid row the detector skips (bit per grid column): cells
    /// entirely within `min_distance_px` of one carried feature, where no candidate could be
    /// selected ([`Self::skip_mask`]).
    skip_cells: u64,
    /// Offset of the last tracked feature from its predicted position in this update, pixels
    /// (added to the next prediction: the prior's error is mostly common to all features).
    flow_px: (i32, i32),
}

/// An unused correspondence slot (zero points and covariances, usable in a `const`).
const ZERO_CORRESPONDENCE: Correspondence = Correspondence {
    q_p: crate::types::VEC3_ZERO,
    cov_p: crate::types::zero_matrix::<3, 3>(),
    q_c: crate::types::VEC3_ZERO,
    cov_c: crate::types::zero_matrix::<3, 3>(),
    info_prior: crate::types::zero_matrix::<3, 3>(),
};

fn rotation_and_translation_finite(prior: &RelativePose) -> bool {
    prior.rot_0_1.coords.iter().all(|v| v.is_finite())
        && prior.trans_0_1_m.iter().all(|v| v.is_finite())
        && (prior.rot_0_1.coords.norm() - 1.0).abs() < 1e-6
}

impl<const N: usize> crate::exec::FrameJob for VisualOdometry<N> {
    type Error = VoError;
    const NOT_STARTED: VoError = VoError::NotStarted;
    const FRAME_CHANGED: VoError = VoError::FrameChanged;

    fn running(&self) -> bool {
        self.phase != Phase::Idle
    }

    fn frame(&self) -> crate::exec::FrameKey {
        crate::exec::FrameKey {
            capture_t_us: self.frame_t_us,
            sequence: self.frame_sequence,
        }
    }

    fn stop(&mut self) {
        self.phase = Phase::Idle;
    }

    fn items(&self) -> u32 {
        self.quality.work_items
    }
}

impl<const N: usize> VisualOdometry<N> {
    /// A pipeline for `calibration` with `config`; [`VoError::InvalidConfig`] or
    /// [`VoError::InvalidCalibration`] when they are out of range, [`VoError::InvalidConfig`]
    /// when `N` is below 3 or above `u16::MAX`.
    pub fn new(config: VoConfig, calibration: &StereoCalibration) -> Result<Self, VoError> {
        let mut vo = Self::EMPTY;
        vo.init(config, calibration)?;
        Ok(vo)
    }

    /// A placeholder without calibration or keyframe (default tuning, zero camera): the
    /// compile-time value of a statically allocated navigator's VO slot before [`Self::init`].
    /// Not meant to run ([`Self::init`] first).
    pub const EMPTY: Self = Self {
        config: VoConfig::DEFAULT,
        camera: PinholeStereo {
            fx_px: 0.0,
            fy_px: 0.0,
            cx_px: 0.0,
            cy_px: 0.0,
            baseline_m: 0.0,
        },
        mount: CameraMount {
            rot_rover_from_camera: crate::types::zero_matrix::<3, 3>(),
            pos_camera_in_rover_m: crate::types::VEC3_ZERO,
        },
        key: [NO_KEY_FEATURE; N],
        key_count: 0,
        key_valid: false,
        key_t_us: 0,
        key_checksum: 0,
        pairs: [ZERO_CORRESPONDENCE; N],
        pair_count: 0,
        inliers: [false; N],
        scratch: [0.0; N],
        selected: [(0, 0); N],
        selected_count: 0,
        detector: ForstnerDetector::EMPTY,
        lmeds: Lmeds::new(0),
        motion: RigidMotion::IDENTITY,
        gating: Gating {
            motion: RigidMotion::IDENTITY,
            gate: 0.0,
        },
        kept: None,
        rounds_reverted: 0,
        estimate: None,
        pending: None,
        phase: Phase::Idle,
        frame_t_us: 0,
        frame_sequence: 0,
        frame_checksum: 0,
        quality: VoQuality::EMPTY,
        current_px: [[0.0; 4]; N],
        carried: 0,
        skip_cells: 0,
        flow_px: (0, 0),
    };

    /// [`Self::new`] in place: this VO becomes the one `new(config, calibration)` returns
    /// (every field rewritten, the feature arrays in loops: no 93 KB temporary on the stack).
    /// Errors as [`Self::new`]; on error nothing is changed.
    pub fn init(
        &mut self,
        config: VoConfig,
        calibration: &StereoCalibration,
    ) -> Result<(), VoError> {
        if !config.is_valid() || N < 3 || N > usize::from(u16::MAX) {
            return Err(VoError::InvalidConfig);
        }
        let camera = PinholeStereo::from_calibration(calibration)?;
        let mount = CameraMount::from_calibration(calibration)?;
        self.config = config;
        self.camera = camera;
        self.mount = mount;
        for k in self.key.iter_mut() {
            *k = NO_KEY_FEATURE;
        }
        self.key_count = 0;
        self.key_valid = false;
        self.key_t_us = 0;
        self.key_checksum = 0;
        for p in self.pairs.iter_mut() {
            *p = ZERO_CORRESPONDENCE;
        }
        self.pair_count = 0;
        self.inliers.fill(false);
        self.scratch.fill(0.0);
        self.selected.fill((0, 0));
        self.selected_count = 0;
        self.detector.reset();
        self.lmeds = Lmeds::new(config.lmeds_seed);
        self.motion = RigidMotion::IDENTITY;
        self.gating = Gating {
            motion: RigidMotion::IDENTITY,
            gate: 0.0,
        };
        self.kept = None;
        self.rounds_reverted = 0;
        self.estimate = None;
        self.pending = None;
        self.phase = Phase::Idle;
        self.frame_t_us = 0;
        self.frame_sequence = 0;
        self.frame_checksum = 0;
        self.quality = VoQuality::EMPTY;
        for c in self.current_px.iter_mut() {
            *c = [0.0; 4];
        }
        self.carried = 0;
        self.skip_cells = 0;
        self.flow_px = (0, 0);
        Ok(())
    }

    /// True while an update is running.
    pub fn is_busy(&self) -> bool {
        self.phase != Phase::Idle
    }

    /// Number of features in the keyframe (0 without a keyframe).
    pub fn keyframe_features(&self) -> usize {
        if self.key_valid {
            self.key_count
        } else {
            0
        }
    }

    /// Capture time of the keyframe (microseconds since boot), `None` without a keyframe.
    pub fn keyframe_time_us(&self) -> Option<u64> {
        self.key_valid.then_some(self.key_t_us)
    }

    /// Forgets the keyframe and abandons a running update.
    pub fn reset(&mut self) {
        self.key_valid = false;
        self.key_count = 0;
        self.phase = Phase::Idle;
    }

    /// Starts an update with `frame` and the rover motion `prior` since the keyframe (from
    /// vehicle odometry; `None` means no motion). Errors: [`VoError::Busy`],
    /// [`VoError::WrongImageSize`], [`VoError::TimeNotIncreasing`], [`VoError::InvalidPrior`]
    /// (non-finite or non-unit rotation, non-finite translation, `t1_us < t0_us`).
    pub fn start(
        &mut self,
        frame: &StereoFrame,
        prior: Option<&RelativePose>,
    ) -> Result<(), VoError> {
        if self.is_busy() {
            return Err(VoError::Busy);
        }
        Image::new(frame.left)?;
        Image::new(frame.right)?;
        if self.key_valid && frame.capture_t_us <= self.key_t_us {
            return Err(VoError::TimeNotIncreasing);
        }
        self.motion = match prior {
            Some(p) => {
                if !rotation_and_translation_finite(p) || p.t1_us < p.t0_us {
                    return Err(VoError::InvalidPrior);
                }
                let rot = p.rot_0_1.to_rotation_matrix().into_inner();
                self.mount.camera_motion(&rot, &p.trans_0_1_m)
            }
            None => RigidMotion::identity(),
        };
        self.frame_t_us = frame.capture_t_us;
        self.frame_sequence = frame.sequence;
        self.quality = VoQuality::default();
        self.pair_count = 0;
        self.selected_count = 0;
        self.carried = 0;
        self.flow_px = (0, 0);
        self.estimate = None;
        self.kept = None;
        self.rounds_reverted = 0;
        self.pending = None;
        self.lmeds = Lmeds::new(self.config.lmeds_seed);
        self.phase = Phase::Check {
            band: 0,
            sums: CheckSums::default(),
        };
        Ok(())
    }

    /// The kind of the next work item, `None` when no update is running.
    pub fn next_work(&self) -> Option<WorkKind> {
        Some(match self.phase {
            Phase::Idle => return None,
            Phase::Check { .. } | Phase::CheckRight { .. } => WorkKind::Check,
            Phase::Track { .. } => WorkKind::Track,
            Phase::Hypotheses { .. } => WorkKind::Hypothesis,
            Phase::Refine { .. } => WorkKind::Refine,
            Phase::Detect { .. } => WorkKind::Detect,
            Phase::Seed { .. }
            | Phase::Select
            | Phase::Heapify { .. }
            | Phase::Choose { .. }
            | Phase::Carry { .. } => WorkKind::Select,
            Phase::StereoNew { .. } => WorkKind::Stereo,
            Phase::Finish => WorkKind::Finish,
        })
    }

    /// Advances the running update by work items until their costs
    /// ([`VoConfig::work_cost`], units of about 10 000 rover-CPU instructions) reach `quantum`
    /// units: at least one item, and the last item may go past the quantum by its own cost.
    /// The items run depend only on the inputs, never on time. `frame` must be the frame given
    /// to [`Self::start`] ([`VoError::FrameChanged`] otherwise, which abandons the update).
    pub fn step(&mut self, frame: &StereoFrame, quantum: u32) -> Progress {
        crate::exec::step_frame_job(
            self,
            frame,
            quantum,
            || match (Image::new(frame.left), Image::new(frame.right)) {
                (Ok(left), Ok(right)) => Some((left, right)),
                _ => None,
            },
            |vo, (left, right)| {
                let cost = vo
                    .next_work()
                    .and_then(|k| vo.config.work_cost.get(k as usize).copied())
                    .unwrap_or(1);
                vo.quality.work_items = vo.quality.work_items.saturating_add(1);
                (cost, vo.work_item(left, right))
            },
        )
    }

    /// Runs a whole update ([`Self::start`], then [`Self::step`] until finished). For tests and
    /// for callers without a time budget.
    pub fn run_to_completion(
        &mut self,
        frame: &StereoFrame,
        prior: Option<&RelativePose>,
    ) -> Result<VoOutput, VoError> {
        self.start(frame, prior)?;
        // Every update finishes within this many items (see the module doc).
        let bound = 4 * N
            + usize::from(super::MAX_HYPOTHESES)
            + (usize::from(ML_ROUNDS) + 1) * usize::from(MAX_ML_ITERATIONS)
            + END_ROW
            + 3 * CELL_COUNT / SORT_CHUNK
            + 16;
        for _ in 0..bound {
            // One item per call whatever the costs: `bound` counts items.
            if let Progress::Finished(result) = self.step(frame, 1) {
                return result;
            }
        }
        self.phase = Phase::Idle;
        Err(VoError::NonFinite)
    }

    /// Records a failure of the motion stage and goes on to build the new keyframe.
    fn fail_motion(&mut self, error: VoError) {
        self.pending = Some(error);
        self.carried = 0;
        self.selected_count = 0;
        self.phase = Phase::Detect { row: FIRST_ROW };
    }

    /// One work item, by the phase of the update (the items of each phase in the module doc).
    /// Returns the result when the update is finished.
    fn work_item(&mut self, left: &Image, right: &Image) -> Option<Result<VoOutput, VoError>> {
        match self.phase {
            Phase::Idle => return Some(Err(VoError::NotStarted)),
            Phase::Check { band, sums } => return self.check_left_item(left, band, sums),
            Phase::CheckRight {
                left_sum,
                band,
                sums,
            } => return self.check_right_item(right, left_sum, band, sums),
            Phase::Track { next } => self.track_item(next, left, right),
            Phase::Hypotheses { done } => self.hypothesis_item(done),
            Phase::Refine { round, iteration } => self.refine_item(round, iteration),
            Phase::Seed { next } => self.seed_item(next),
            Phase::Detect { row } => self.detect_item(row, left),
            Phase::Select => self.select_item(),
            Phase::Heapify { next } => self.heapify_item(next),
            Phase::Choose { left } => return self.choose_item(left),
            Phase::Carry { next } => self.carry_item(next, left),
            Phase::StereoNew { next } => self.stereo_item(next, left, right),
            Phase::Finish => return Some(self.finish()),
        }
        None
    }

    /// One band of the left image's check ([`Image::check_band`]); after the last band, the
    /// whole image's checks ([`CheckSums::finish`]), then on to the right image. A failed check
    /// ends the update and forgets the keyframe.
    #[inline(always)]
    fn check_left_item(
        &mut self,
        left: &Image,
        band: u8,
        mut sums: CheckSums,
    ) -> Option<Result<VoOutput, VoError>> {
        let checked = left
            .check_band(usize::from(band), &mut sums)
            .and_then(|()| {
                if usize::from(band) + 1 < CHECK_BANDS {
                    Ok(None)
                } else {
                    sums.finish(&self.config).map(Some)
                }
            });
        match checked {
            Ok(None) => {
                self.phase = Phase::Check {
                    band: band + 1,
                    sums,
                }
            }
            Ok(Some(left_sum)) => {
                self.phase = Phase::CheckRight {
                    left_sum,
                    band: 0,
                    sums: CheckSums::default(),
                }
            }
            Err(e) => {
                self.key_valid = false;
                return Some(Err(e));
            }
        }
        None
    }

    /// One band of the right image's check; after the last band, the whole image's checks and
    /// the repeated-frame test of the left image's checksum against the keyframe's, then on to
    /// tracking (or, without a keyframe, to detection). A failed check ends the update and
    /// forgets the keyframe.
    #[inline(always)]
    fn check_right_item(
        &mut self,
        right: &Image,
        left_sum: u64,
        band: u8,
        mut sums: CheckSums,
    ) -> Option<Result<VoOutput, VoError>> {
        let checked = right.check_band(usize::from(band), &mut sums);
        if checked.is_ok() && usize::from(band) + 1 < CHECK_BANDS {
            self.phase = Phase::CheckRight {
                left_sum,
                band: band + 1,
                sums,
            };
            return None;
        }
        let checks = checked
            .and_then(|()| sums.finish(&self.config))
            .map(|_| left_sum);
        match checks {
            Ok(sum) if self.key_valid && sum == self.key_checksum => {
                self.key_valid = false;
                return Some(Err(VoError::RepeatedFrame));
            }
            Ok(sum) => {
                self.frame_checksum = sum;
                self.phase = if self.key_valid {
                    Phase::Track { next: 0 }
                } else {
                    Phase::Detect { row: FIRST_ROW }
                };
            }
            Err(e) => {
                self.key_valid = false;
                return Some(Err(e));
            }
        }
        None
    }
}
