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

use super::features::{
    select_more, ForstnerDetector, BORDER_PX, CELL_COUNT, END_ROW, FIRST_ROW, GRID_COLS, GRID_PX,
};
use super::image::{CheckSums, Image, Template, CHECK_BANDS};
use super::motion::{
    finish_estimate, mark_inliers, ml_iteration, relative_pose, residual_median, robust_gate,
    robust_variance_scale, CameraMount, Correspondence, Gating, Kept, Lmeds, MotionEstimate,
    RigidMotion, ML_ROUNDS,
};
use super::stereo::{match_and_triangulate, triangulate_config, PinholeStereo};
use super::track::{refine_warp, search_near, Affine2, WarpModel};
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

    /// One work item. Returns the result when the update is finished.
    fn work_item(&mut self, left: &Image, right: &Image) -> Option<Result<VoOutput, VoError>> {
        match self.phase {
            Phase::Idle => return Some(Err(VoError::NotStarted)),
            Phase::Check { band, mut sums } => {
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
            }
            Phase::CheckRight {
                left_sum,
                band,
                mut sums,
            } => {
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
            }
            Phase::Track { next } => {
                if next < self.key_count.min(N) {
                    self.track_feature(next, left, right);
                    self.phase = Phase::Track { next: next + 1 };
                } else {
                    self.quality.tracked = self.pair_count as u16;
                    if self.pair_count < usize::from(self.config.min_tracked) {
                        self.fail_motion(VoError::TooFewTracked {
                            found: self.pair_count as u16,
                        });
                    } else {
                        self.phase = Phase::Hypotheses { done: 0 };
                    }
                }
            }
            Phase::Hypotheses { done } => {
                if done < self.config.lmeds_hypotheses {
                    let n = self.pair_count.min(N);
                    let pairs = self.pairs.get(..n).unwrap_or(&[]);
                    self.lmeds.hypothesis(pairs, &mut self.scratch);
                    self.phase = Phase::Hypotheses { done: done + 1 };
                } else {
                    self.after_hypotheses();
                }
            }
            Phase::Refine { round, iteration } => self.refine_item(round, iteration),
            Phase::Seed { next } => {
                let stop = (next + SORT_CHUNK).min(self.pair_count.min(N));
                for index in next..stop {
                    self.seed_carried(index);
                }
                self.phase = if stop < self.pair_count.min(N) {
                    Phase::Seed { next: stop }
                } else {
                    Phase::Detect { row: FIRST_ROW }
                };
            }
            Phase::Detect { row } => {
                if row < END_ROW {
                    if row == FIRST_ROW || row % GRID_PX == 0 {
                        self.skip_cells = self.skip_mask(row / GRID_PX);
                    }
                    let skip = self.skip_cells;
                    self.detector
                        .process_row_masked(left, row, &self.config, skip);
                    self.phase = Phase::Detect { row: row + 1 };
                } else {
                    self.phase = Phase::Select;
                }
            }
            Phase::Select => {
                // Sort and select in bounded chunks (at most SORT_CHUNK heap steps or
                // candidates per item), the same operations in the same order as one sort.
                let n = self.detector.compact_candidates();
                self.selected_count = self.carried.min(N);
                self.phase = Phase::Heapify { next: n / 2 };
            }
            Phase::Heapify { next } => {
                let stop = next.saturating_sub(SORT_CHUNK);
                for start in (stop..next).rev() {
                    self.detector.best_heapify_step(start);
                }
                self.phase = if stop == 0 {
                    Phase::Choose {
                        left: self.detector.candidates().len(),
                    }
                } else {
                    Phase::Heapify { next: stop }
                };
            }
            Phase::Choose { mut left } => {
                // The candidates best first, popped from the heap only as far as the greedy
                // selection needs them (the order of the full sort, `features::pop_best`).
                let mut count = self.selected_count;
                for _ in 0..SORT_CHUNK {
                    if count >= self.selected.len() {
                        break;
                    }
                    let Some(c) = self.detector.pop_best(left) else {
                        break;
                    };
                    left -= 1;
                    count = select_more(
                        core::slice::from_ref(&c),
                        self.config.min_distance_px,
                        &mut self.selected,
                        count,
                    );
                }
                self.selected_count = count;
                if left > 0 && count < self.selected.len() {
                    self.phase = Phase::Choose { left };
                    return None;
                }
                self.quality.features = count as u16;
                self.key_valid = false;
                self.key_count = 0;
                if count < usize::from(self.config.min_features) {
                    let e = VoError::TooFewFeatures {
                        found: count as u16,
                    };
                    return Some(Err(self.pending.unwrap_or(e)));
                }
                self.phase = Phase::Carry { next: 0 };
            }
            Phase::Carry { next } => {
                let end = self.carried.min(self.selected_count).min(N);
                let stop = (next + SORT_CHUNK).min(end);
                for index in next..stop {
                    self.carry_feature(index, left);
                }
                self.phase = if stop < end {
                    Phase::Carry { next: stop }
                } else {
                    Phase::StereoNew { next: end }
                };
            }
            Phase::StereoNew { next } => {
                if next < self.selected_count.min(N) {
                    self.stereo_new_feature(next, left, right);
                    self.phase = Phase::StereoNew { next: next + 1 };
                } else {
                    self.phase = Phase::Finish;
                }
            }
            Phase::Finish => return Some(self.finish()),
        }
        None
    }

    /// Tracks keyframe feature `index` into the new pair and stores the correspondence.
    fn track_feature(&mut self, index: usize, left: &Image, right: &Image) {
        let Some(feature) = self.key.get(index).copied() else {
            return;
        };
        let [xl, yl, xr, yr] = feature.pixels.map(f64::from);
        let Ok(previous) = triangulate_config(&self.camera, [xl, yl, xr, yr], &self.config) else {
            return;
        };
        // The feature's offset from its template centre (0 for a detected feature, at most half
        // a pixel for a carried one): template coordinates (du, dv) of eq. 9.
        let (du, dv) = (xl - libm::round(xl), yl - libm::round(yl));
        // Projection with the motion prior (eq. 11 without noise).
        let predicted = self.motion.rotation * previous.position_m + self.motion.translation_m;
        let Some((xp, yp)) = self.camera.project_left(&predicted) else {
            return;
        };
        if !(xp.abs() < 1e5 && yp.abs() < 1e5) {
            return;
        }
        let radius = i32::from(self.config.search_radius_px);
        let (x0, y0) = (libm::round(xp - du) as i32, libm::round(yp - dv) as i32);
        let (x0, y0) = (
            x0.saturating_add(self.flow_px.0),
            y0.saturating_add(self.flow_px.1),
        );
        let Some((xs, ys, score)) = search_near(
            &feature.template,
            left,
            x0,
            y0,
            radius,
            self.config.min_correlation,
        ) else {
            return;
        };
        if score < self.config.min_correlation {
            return;
        }
        self.flow_px = (
            (xs - x0 + self.flow_px.0).clamp(-radius, radius),
            (ys - y0 + self.flow_px.1).clamp(-radius, radius),
        );
        let template_f = feature.template.map(f32::from);
        let init = Affine2::translation(f64::from(xs), f64::from(ys));
        let Some(refined) = refine_warp(&template_f, left, init, WarpModel::Affine, 10) else {
            return;
        };
        let (xt, yt) = refined.warp.apply(du, dv);
        let shift = libm::hypot(
            refined.warp.c - f64::from(xs),
            refined.warp.f - f64::from(ys),
        );
        if !(shift <= self.config.max_refine_shift_px) {
            return;
        }
        // Disparity of the predicted point: the stereo search of a tracked feature only covers a
        // window around it (the prior already placed the feature within the tracking radius).
        let predicted_disparity = self.camera.fx_px * self.camera.baseline_m / predicted.z;
        let window = (self.config.track_disparity_margin_px > 0).then_some(predicted_disparity);
        let (current, (xr1, yr1)) = match match_and_triangulate(
            &self.camera,
            left,
            right,
            (xt, yt),
            window,
            &self.config,
        ) {
            Ok(matched) => matched,
            Err(reason) => return self.quality.stereo_rejects.count(reason),
        };
        let pair = Correspondence::new(
            previous.position_m,
            previous.covariance,
            current.position_m,
            current.covariance,
            &self.motion.rotation,
        );
        if let (Some(pair), Some(slot), Some(px)) = (
            pair,
            self.pairs.get_mut(self.pair_count),
            self.current_px.get_mut(self.pair_count),
        ) {
            *slot = pair;
            *px = [xt as f32, yt as f32, xr1 as f32, yr1 as f32];
            self.pair_count += 1;
        }
    }

    /// Feature persistence: correspondence `index`, when it is an inlier of the motion, becomes a
    /// feature of the next keyframe at its tracked position in the new pair (its stereo match
    /// there, from the tracking item, is kept), unless its template centre is within the border
    /// or it is closer than `min_distance_px` to a feature carried before it. Carried features
    /// fill `selected` and `current_px` from the front, so the detector only adds new features
    /// away from them ([`select_more`]).
    fn seed_carried(&mut self, index: usize) {
        if !self.inliers.get(index).copied().unwrap_or(false) {
            return;
        }
        let Some(&px) = self.current_px.get(index) else {
            return;
        };
        let (xc, yc) = (libm::round(f64::from(px[0])), libm::round(f64::from(px[1])));
        let border = BORDER_PX as f64;
        let inside = xc >= border
            && xc < (rover_hal::IMAGE_WIDTH_PX - BORDER_PX) as f64
            && yc >= border
            && yc < (rover_hal::IMAGE_HEIGHT_PX - BORDER_PX) as f64;
        if !inside {
            return;
        }
        let candidate = super::features::Candidate {
            interest: 1.0,
            x: xc as u16,
            y: yc as u16,
        };
        let count = self.carried.min(N);
        let kept = select_more(
            core::slice::from_ref(&candidate),
            self.config.min_distance_px,
            &mut self.selected,
            count,
        );
        if kept > count {
            // `count <= index`: the slot was read (or is this one) already.
            if let Some(slot) = self.current_px.get_mut(count) {
                *slot = px;
            }
            self.carried = kept;
        }
    }

    /// The grid cells of grid row `cell_row` (bit per grid column) that are covered by the
    /// carried features' exclusion disks: each of 9 sample pixels of the cell (a 3x3 lattice:
    /// corners, edge midpoints, centre) is closer than `min_distance_px` to some carried feature.
    /// The greedy selection ([`select_more`]) drops every candidate within those disks, so the
    /// detector need not score these cells (it could only miss a candidate in a sliver of a
    /// cell between the samples).
    fn skip_mask(&self, cell_row: usize) -> u64 {
        const OFFSETS: [usize; 3] = [0, GRID_PX / 2, GRID_PX - 1];
        let min_d = f64::from(self.config.min_distance_px);
        let min_d2 = min_d * min_d;
        let top = cell_row * GRID_PX;
        let reach = libm::ceil(min_d).min(1e4) as usize;
        let mut covered = [0u16; GRID_COLS];
        for &(x, y) in self.selected.get(..self.carried.min(N)).unwrap_or(&[]) {
            let (fx, fy) = (f64::from(x), f64::from(y));
            // Rows of the samples closer than min_d.
            let mut row_dy2 = [f64::INFINITY; 3];
            let mut any = false;
            for (slot, off) in row_dy2.iter_mut().zip(OFFSETS) {
                let dy = fy - (top + off) as f64;
                if dy * dy < min_d2 {
                    *slot = dy * dy;
                    any = true;
                }
            }
            if !any {
                continue;
            }
            let first = usize::from(x).saturating_sub(reach) / GRID_PX;
            let last = ((usize::from(x) + reach) / GRID_PX).min(GRID_COLS - 1);
            for c in first..=last {
                let Some(bits) = covered.get_mut(c) else {
                    continue;
                };
                for (i, off_x) in OFFSETS.iter().enumerate() {
                    let dx = fx - (c * GRID_PX + off_x) as f64;
                    for (j, dy2) in row_dy2.iter().enumerate() {
                        if dx * dx + dy2 < min_d2 {
                            *bits |= 1 << (3 * j + i);
                        }
                    }
                }
            }
        }
        let mut mask = 0u64;
        for (c, &bits) in covered.iter().enumerate() {
            if bits == 0x1ff && c < u64::BITS as usize {
                mask |= 1u64 << c;
            }
        }
        mask
    }

    /// Writes carried feature `index` (see [`Self::seed_carried`]) into the new keyframe: its
    /// pixels in this pair and the template around its nearest integer pixel.
    fn carry_feature(&mut self, index: usize, left: &Image) {
        let (Some(&(x, y)), Some(&pixels)) = (self.selected.get(index), self.current_px.get(index))
        else {
            return;
        };
        let Some(template) = left.template(i32::from(x), i32::from(y)) else {
            return;
        };
        if let Some(slot) = self.key.get_mut(self.key_count) {
            *slot = KeyFeature { pixels, template };
            self.key_count += 1;
        }
    }

    /// Ends the least-median-of-squares search: best hypothesis, robust inlier gate
    /// ([`robust_gate`] of the best median).
    fn after_hypotheses(&mut self) {
        let Some((motion, median)) = self.lmeds.best() else {
            self.fail_motion(VoError::DegenerateGeometry);
            return;
        };
        self.motion = motion;
        let n = self.pair_count.min(N);
        let pairs = self.pairs.get(..n).unwrap_or(&[]);
        self.gating = Gating {
            motion,
            gate: robust_gate(self.config.inlier_gate_chi2, median, n),
        };
        let count = mark_inliers(pairs, &self.motion, self.gating.gate, &mut self.inliers);
        self.quality.inliers = count;
        if count < self.config.min_inliers {
            self.fail_motion(VoError::TooFewInliers { found: count });
        } else {
            self.phase = Phase::Refine {
                round: 0,
                iteration: 0,
            };
        }
    }

    /// Drops the running round: the previous round's motion and inlier set come back and the
    /// next item computes the covariance there. Without a completed round, fails with `error`.
    fn revert_round(&mut self, error: VoError) {
        let n = self.pair_count.min(N);
        let pairs = self.pairs.get(..n).unwrap_or(&[]);
        match self.kept {
            Some(kept) => {
                self.motion = kept.restore(pairs, &mut self.inliers);
                self.rounds_reverted = 1;
                self.phase = Phase::Refine {
                    round: ML_ROUNDS,
                    iteration: 0,
                };
            }
            None => self.fail_motion(error),
        }
    }

    /// One maximum-likelihood iteration (eq. 11); `ML_ROUNDS` rounds, each re-gated with the
    /// robust gate at its motion; a round that fails or leaves too few inliers is dropped
    /// ([`Self::revert_round`]); the last item evaluates the covariance at the converged motion
    /// (scaled by the robust scale over all correspondences, see `motion::finish_estimate`).
    fn refine_item(&mut self, round: u8, iteration: u8) {
        let n = self.pair_count.min(N);
        let pairs = self.pairs.get(..n).unwrap_or(&[]);
        let inliers = self.inliers.get(..n).unwrap_or(&[]);
        let it = match ml_iteration(pairs, inliers, &self.motion) {
            Ok(it) => it,
            Err(e) if round < ML_ROUNDS => return self.revert_round(e),
            Err(e) => return self.fail_motion(e),
        };
        let max_iterations = self.config.ml_iterations.min(MAX_ML_ITERATIONS);
        if round >= ML_ROUNDS {
            // Covariance and quality at the converged motion (the update is not applied).
            let median =
                residual_median(pairs, &self.motion, &mut self.scratch).unwrap_or(f64::INFINITY);
            let scale = robust_variance_scale(median, n);
            match finish_estimate(self.motion, &it, scale) {
                Ok(mut estimate) => {
                    estimate.rounds_reverted = self.rounds_reverted;
                    self.quality.inliers = estimate.inliers;
                    self.quality.residual_rms_m = estimate.residual_rms_m;
                    self.quality.chi2_per_dof = estimate.chi2_per_dof;
                    self.quality.covariance_scale = estimate.covariance_scale;
                    self.quality.rounds_reverted = estimate.rounds_reverted;
                    self.estimate = Some(estimate);
                    self.carried = 0;
                    self.phase = Phase::Seed { next: 0 };
                }
                Err(e) => self.fail_motion(e),
            }
            return;
        }
        self.motion = it.motion;
        let next = iteration.saturating_add(1);
        if it.step >= 1e-12 && next < max_iterations {
            self.phase = Phase::Refine {
                round,
                iteration: next,
            };
            return;
        }
        self.kept = Some(Kept {
            solution: self.motion,
            gating: self.gating,
        });
        if round + 1 < ML_ROUNDS {
            let median =
                residual_median(pairs, &self.motion, &mut self.scratch).unwrap_or(f64::INFINITY);
            let gating = Gating {
                motion: self.motion,
                gate: robust_gate(self.config.inlier_gate_chi2, median, n),
            };
            let count = mark_inliers(pairs, &self.motion, gating.gate, &mut self.inliers);
            if count < self.config.min_inliers {
                return self.revert_round(VoError::TooFewInliers { found: count });
            }
            self.gating = gating;
            self.quality.inliers = count;
        }
        self.phase = Phase::Refine {
            round: round + 1,
            iteration: 0,
        };
    }

    /// Stereo matches selected feature `index` of the new left image into the keyframe.
    fn stereo_new_feature(&mut self, index: usize, left: &Image, right: &Image) {
        let Some(&(x, y)) = self.selected.get(index) else {
            return;
        };
        let (xl, yl) = (f64::from(x), f64::from(y));
        let (xr, yr) =
            match match_and_triangulate(&self.camera, left, right, (xl, yl), None, &self.config) {
                Ok((_, right_px)) => right_px,
                Err(reason) => return self.quality.stereo_rejects.count(reason),
            };
        let Some(template) = left.template(i32::from(x), i32::from(y)) else {
            return;
        };
        if let Some(slot) = self.key.get_mut(self.key_count) {
            *slot = KeyFeature {
                pixels: [xl as f32, yl as f32, xr as f32, yr as f32],
                template,
            };
            self.key_count += 1;
        }
    }

    /// Commits the new keyframe and builds the output.
    fn finish(&mut self) -> Result<VoOutput, VoError> {
        self.quality.stereo_matches = self.key_count as u16;
        let t0_us = self.key_t_us;
        let had_keyframe_motion = self.estimate;
        if self.key_count < usize::from(self.config.min_matches) {
            self.key_valid = false;
            let e = VoError::TooFewMatches {
                found: self.key_count as u16,
            };
            return Err(self.pending.unwrap_or(e));
        }
        self.key_valid = true;
        self.key_t_us = self.frame_t_us;
        self.key_checksum = self.frame_checksum;
        if let Some(e) = self.pending {
            return Err(e);
        }
        let pose = match had_keyframe_motion {
            Some(estimate) => Some(relative_pose(
                &self.mount,
                &estimate,
                t0_us,
                self.frame_t_us,
            )?),
            None => None,
        };
        Ok(VoOutput {
            pose,
            quality: self.quality,
        })
    }
}
