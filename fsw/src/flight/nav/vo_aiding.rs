//! # VoAiding: capture policy, the VO pipeline, the VO gate and VO's health
//!
//! - **Capture policy** (RG3, H04 sec. 2, [`VoAiding::capture_due`]): a stereo capture is due
//!   every [`VoAidingConfig::capture_distance_m`] of EKF travel or
//!   [`VoAidingConfig::capture_angle_rad`] of rotation, at the latest after
//!   [`VoAidingConfig::capture_max_interval_us`]; its time is cloned (eq. 41) by the navigator.
//! - **Pipeline** (background): VO ([`VisualOdometry`], H04 sec. 2, H05 sec. II) runs on the
//!   captured pair in work items with the EKF's motion between the keyframe clone and the
//!   capture clone as its prior ([`VoAiding::start`], [`VoAiding::step`]).
//! - **Fusion** ([`VoAiding::finished`]): the relative pose between the two capture clones,
//!   boresight-corrected ([`Calibration::correct`]), is tested by the VO gate
//!   ([`super::vo_gate`]: eq. 46 with a slip allowance, rotation against the gyro; a forced
//!   fusion after a rejection streak) and, accepted, applied at capture time by a replay of the
//!   recorded filter operations ([`NavFilter::apply_vo`]), however many frames later it ends.
//! - **Health** ([`VoAiding::health`]): RG2 cycles since the last fused VO update; VO counts as
//!   lost after [`VoAidingConfig::timeout_cycles`] (the kinematic aiding then fuses without
//!   VO, the drive stops and goes).
//!
//! Why the VO gate and its forced fusion: note 0002.

use super::calibration::Calibration;
use super::diagnostics::Trajectories;
use super::filter::NavFilter;
use super::in_place::InPlace;
use super::kin_aiding::VoHealth;
use super::vo_gate::{
    vo_gate_test, CaptureMark, CaptureReason, VoGateStatus, VoGateVerdict, VO_FORCE_MAX_STEPS,
};
use super::{PoseEstimate, VO_FEATURES};
use crate::estimation::{CloneHandle, NominalState};
use crate::types::RelativePose;
use crate::vo::{Progress, VisualOdometry, VoConfig, VoError, VoOutput};
use rover_hal::{StereoCalibration, StereoFrame};

/// Settings of the VO aiding (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoAidingConfig {
    /// Run visual odometry on stereo captures.
    pub enabled: bool,
    /// Visual odometry tuning.
    pub pipeline: VoConfig,
    /// A fused VO relative pose whose Mahalanobis distance `d_m^2` (eq. 46, the EKF's own
    /// `S`, no slip allowance) exceeds this is counted in [`VoCounters::vo_large_d2`].
    pub warn_d2: f64,
    /// Gate VO relative poses ([`super::vo_gate`]). Off: every VO pose is fused.
    pub gate_enabled: bool,
    /// Slip allowance of the VO gate: 1-sigma per translation axis (`R0`, m) added to the
    /// gate's residual covariance, as a fraction of the EKF's travel between the clones
    /// (dimensionless). The EKF prior between captures comes from IMU and kinematics, which
    /// slip pulls away; 0.3 accepts 100 % slip at d^2 of about 7 and rejects a translation
    /// error of twice the travel.
    pub gate_slip_fraction: f64,
    /// Floor of the slip allowance, m (1-sigma per axis), for captures with little travel.
    pub gate_slip_floor_m: f64,
    /// Consecutive VO rejections that make a streak ([`VoCounters::vo_reject_streaks`],
    /// telemetry flag): the next VO pose after a streak is fused even when the gate rejects it,
    /// with its covariance inflated by the smallest factor `4^n` (n <= 10) that passes the gate
    /// ([`VoCounters::vo_forced`]), so that a wrong gate cannot lock VO out.
    pub reject_streak: u32,
    /// VO capture by distance (H04 sec. 2: images every 20-30 cm): a capture is due when the
    /// EKF position has moved this far since the last capture, m (3D distance in `N`).
    pub capture_distance_m: f64,
    /// A capture is due when the EKF attitude has rotated this much since the last capture, rad
    /// (angle of the relative rotation; on level ground the heading change).
    pub capture_angle_rad: f64,
    /// Time fallback: a capture is due this long after the last one, us (EKF time), so that a
    /// stuck or slipping-in-place rover still gets VO.
    pub capture_max_interval_us: u64,
    /// While VO has no keyframe (after a VO failure or at the start of VO), a capture is due
    /// this long after the last one, us (EKF time), whatever the motion: VO needs a keyframe
    /// before it can measure, and a failing camera is not retriggered at the RG3 rate.
    pub capture_retry_us: u64,
    /// VO counts as lost when no VO update was fused for this many RG2 cycles (VO failing,
    /// camera lost, or VO off).
    pub timeout_cycles: u32,
}

/// Counters of the VO aiding (telemetry, [`super::NavCounters`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct VoCounters {
    /// VO updates that delivered a relative pose.
    pub vo_updates: u32,
    /// VO updates fused into the EKF.
    pub vo_fused: u32,
    /// Of those, applied at capture time and replayed to the present.
    pub vo_replayed: u32,
    /// VO attempts that failed (after the first keyframe), and VO refused at its start.
    pub vo_failures: u32,
    /// VO relative poses fused with `d_m^2 > warn_d2` (the estimate had drifted).
    pub vo_large_d2: u32,
    /// VO relative poses rejected by the VO gate and not fused.
    pub vo_rejected: u32,
    /// Of those, rejected by the rotation check against the gyro-propagated rotation.
    pub vo_rejected_rotation: u32,
    /// Streaks of [`VoAidingConfig::reject_streak`] consecutive VO rejections.
    pub vo_reject_streaks: u32,
    /// VO poses fused after a streak although the gate rejected them, with inflated covariance.
    pub vo_forced: u32,
    /// Captures skipped because no clone slot was free.
    pub captures_skipped: u32,
    /// Captures started because the EKF travelled [`VoAidingConfig::capture_distance_m`].
    pub captures_distance: u32,
    /// Captures started because the EKF attitude turned [`VoAidingConfig::capture_angle_rad`].
    pub captures_heading: u32,
    /// Captures started by the time fallback (or the first capture of VO).
    pub captures_time: u32,
}

/// VO poses after which the VO-only trajectory starts even without a sun update.
const VO_ANCHOR_MAX_POSES: u32 = 30;

/// The VO aiding component.
pub struct VoAiding {
    config: VoAidingConfig,
    pipeline: InPlace<VisualOdometry<VO_FEATURES>>,
    /// The clone of the frame VO holds as its keyframe.
    key_clone: Option<CloneHandle>,
    last_output: Option<VoOutput>,
    /// The error of the last VO update that failed (telemetry; `None` before any failure).
    last_error: Option<VoError>,
    gate: VoGateStatus,
    /// EKF pose and time of the last capture (the capture policy's reference).
    last_capture: Option<CaptureMark>,
    /// VO has held a keyframe since the start (or the drive's wait for it timed out).
    started: bool,
    /// RG2 cycles since the last fused VO update.
    cycles_since_fused: u32,
    /// A VO update was fused since the last kinematic interval's travel was checked.
    fused_since_interval: bool,
    counters: VoCounters,
}

impl VoAiding {
    /// Placeholder (the compile-time value of a static navigator before its initialisation).
    pub const EMPTY: Self = Self {
        config: VoAidingConfig {
            enabled: false,
            pipeline: VoConfig::DEFAULT,
            warn_d2: 0.0,
            gate_enabled: false,
            gate_slip_fraction: 0.0,
            gate_slip_floor_m: 0.0,
            reject_streak: 0,
            capture_distance_m: 0.0,
            capture_angle_rad: 0.0,
            capture_max_interval_us: 0,
            capture_retry_us: 0,
            timeout_cycles: 0,
        },
        pipeline: InPlace::unbuilt(VisualOdometry::EMPTY),
        key_clone: None,
        last_output: None,
        last_error: None,
        gate: VoGateStatus {
            verdict: VoGateVerdict::None,
            d2_rotation: 0.0,
            d2_pose: 0.0,
            consecutive_rejections: 0,
            streak: false,
        },
        last_capture: None,
        started: false,
        cycles_since_fused: 0,
        fused_since_interval: false,
        counters: VoCounters {
            vo_updates: 0,
            vo_fused: 0,
            vo_replayed: 0,
            vo_failures: 0,
            vo_large_d2: 0,
            vo_rejected: 0,
            vo_rejected_rotation: 0,
            vo_reject_streaks: 0,
            vo_forced: 0,
            captures_skipped: 0,
            captures_distance: 0,
            captures_heading: 0,
            captures_time: 0,
        },
    };

    /// Rewrites the component for a new drive with `config`; the pipeline is marked not built
    /// (its storage is kept for [`Self::build`]).
    pub fn init(&mut self, config: &VoAidingConfig) {
        self.config = *config;
        self.pipeline.built = false;
        self.key_clone = None;
        self.last_output = None;
        self.last_error = None;
        self.gate = VoGateStatus::default();
        self.last_capture = None;
        self.started = false;
        self.cycles_since_fused = 0;
        self.fused_since_interval = false;
        self.counters = VoCounters::default();
    }

    /// Build the VO pipeline (about 96 KB) in its storage when [`VoAidingConfig::enabled`],
    /// for the camera `calibration`; a calibration VO refuses leaves VO off (counted in
    /// [`VoCounters::vo_failures`]).
    pub fn build(&mut self, calibration: &StereoCalibration) {
        if !self.config.enabled || self.pipeline.is_some() {
            return;
        }
        // Built in its storage (no 93 KB value through the stack).
        match self.pipeline.value.init(self.config.pipeline, calibration) {
            Ok(()) => self.pipeline.built = true,
            Err(_) => self.counters.vo_failures = self.counters.vo_failures.saturating_add(1),
        }
    }

    /// True when the VO pipeline was built.
    pub fn built(&self) -> bool {
        self.pipeline.is_some()
    }

    /// Counters.
    pub fn counters(&self) -> VoCounters {
        self.counters
    }

    /// The VO gate's last verdict and streak state.
    pub fn gate(&self) -> VoGateStatus {
        self.gate
    }

    /// The last VO output (quality figures), if any.
    pub fn output(&self) -> Option<&VoOutput> {
        self.last_output.as_ref()
    }

    /// The error of the last failed VO update, if any.
    pub fn last_error(&self) -> Option<VoError> {
        self.last_error
    }

    /// The clone of VO's keyframe, if VO holds one.
    pub fn key_clone(&self) -> Option<CloneHandle> {
        self.key_clone
    }

    /// VO's health: RG2 cycles since the last fused update against the timeout.
    pub fn health(&self) -> VoHealth {
        VoHealth {
            enabled: self.config.enabled,
            cycles_since_fused: self.cycles_since_fused,
            timeout_cycles: self.config.timeout_cycles,
        }
    }

    /// An RG2 cycle closed a kinematic interval: one more cycle towards VO's timeout.
    pub fn count_cycle(&mut self) {
        self.cycles_since_fused = self.cycles_since_fused.saturating_add(1);
    }

    /// Whether a VO update was fused since the last call (fault protection's slip window
    /// counts the EKF travel as measured then).
    pub fn take_fused_since_interval(&mut self) -> bool {
        core::mem::take(&mut self.fused_since_interval)
    }

    /// VO has held a keyframe since the start, or the drive gave up waiting for it.
    pub fn started(&self) -> bool {
        self.started
    }

    /// The drive gave up waiting for VO's first keyframe: VO counts as started.
    pub fn start_wait_over(&mut self) {
        self.started = true;
    }

    /// The IMU's time base changed: the keyframe's clone is gone and VO starts again.
    pub fn rebase(&mut self) {
        self.key_clone = None;
        if let Some(vo) = self.pipeline.as_mut() {
            vo.reset();
        }
    }

    /// RG3: whether a stereo capture is due now for the filter state `x`, and why (module doc;
    /// the caller checks that a capture may start). `map_wanted_now`: the rover stands
    /// waiting for a hazard map, so a capture is due at once.
    pub fn capture_due(&self, x: &NominalState, map_wanted_now: bool) -> Option<CaptureReason> {
        // No capture yet: at once.
        let Some(last) = self.last_capture else {
            return Some(CaptureReason::Time);
        };
        // The rover stands waiting for a hazard map (hazard navigation): at once.
        if map_wanted_now {
            return Some(CaptureReason::Time);
        }
        let elapsed = x.t_us.saturating_sub(last.t_us);
        // VO lost its keyframe (failure, outage): the next VO pose needs a keyframe first, so
        // the next capture is due after the retry interval, whatever the motion.
        if self.key_clone.is_none() {
            let due = elapsed >= self.config.capture_retry_us;
            return due.then_some(CaptureReason::Time);
        }
        let moved = (x.p_n - last.p_n).norm();
        let turned = (last.q_nr.inverse() * x.q_nr).angle();
        if moved >= self.config.capture_distance_m {
            Some(CaptureReason::Distance)
        } else if turned >= self.config.capture_angle_rad {
            Some(CaptureReason::Heading)
        } else if elapsed >= self.config.capture_max_interval_us {
            Some(CaptureReason::Time)
        } else {
            None
        }
    }

    /// RG3: a capture started at the filter state `x` because it was due for `reason`: the
    /// capture policy's new reference, counted by reason.
    pub fn capture_started(&mut self, x: &NominalState, reason: CaptureReason) {
        self.last_capture = Some(CaptureMark {
            t_us: x.t_us,
            p_n: x.p_n,
            q_nr: x.q_nr,
        });
        let c = &mut self.counters;
        let counter = match reason {
            CaptureReason::Distance => &mut c.captures_distance,
            CaptureReason::Heading => &mut c.captures_heading,
            CaptureReason::Time => &mut c.captures_time,
        };
        *counter = counter.saturating_add(1);
    }

    /// A capture was skipped (no clone slot free, or RG3 found VO busy): counted.
    pub fn capture_skipped(&mut self) {
        self.counters.captures_skipped = self.counters.captures_skipped.saturating_add(1);
    }

    /// The capture was lost while VO worked on it: VO starts again at the next capture, its
    /// keyframe's clone released.
    pub fn capture_lost(&mut self, filter: &mut NavFilter) {
        if let Some(vo) = self.pipeline.as_mut() {
            if vo.is_busy() {
                vo.reset();
                let key = self.key_clone.take();
                filter.release(key);
            }
        }
    }

    /// Background: VO starts on the captured `frame` of clone `capture`, with the EKF's motion
    /// between the keyframe clone and the capture clone as the prior. False: VO refused the
    /// frame (counted; its keyframe is dropped, the caller loses the capture).
    pub fn start(
        &mut self,
        frame: &StereoFrame,
        capture: Option<CloneHandle>,
        filter: &mut NavFilter,
    ) -> bool {
        let prior = ekf_relative_pose(filter, self.key_clone, capture);
        let Some(vo) = self.pipeline.as_mut() else {
            return false;
        };
        match vo.start(frame, prior.as_ref()) {
            Ok(()) => true,
            Err(_) => {
                self.counters.vo_failures = self.counters.vo_failures.saturating_add(1);
                if let Some(vo) = self.pipeline.as_mut() {
                    vo.reset();
                }
                let key = self.key_clone.take();
                filter.release(key);
                false
            }
        }
    }

    /// Background: advance VO on `frame` by at most `quantum` work items; `None` when the
    /// pipeline was not built.
    pub fn step(&mut self, frame: &StereoFrame, quantum: u32) -> Option<Progress> {
        self.pipeline.as_mut().map(|vo| vo.step(frame, quantum))
    }

    /// Background: VO finished on the frame of clone `capture` with `result`. A relative pose
    /// is fused through the VO gate (module doc) and chained into the VO-only trajectory of
    /// `diag`; the keyframe bookkeeping keeps the clone of whichever frame VO now holds.
    /// `heading_known`: the EKF heading has had its first sun update, or the drive has no sun
    /// sensor (the VO-only trajectory is anchored only then). Returns true when a pose was
    /// fused.
    #[inline(never)]
    pub fn finished(
        &mut self,
        capture: Option<CloneHandle>,
        result: Result<VoOutput, VoError>,
        heading_known: bool,
        filter: &mut NavFilter,
        diag: &mut Trajectories,
        cal: &mut Calibration,
    ) -> bool {
        let had_key = self.key_clone.is_some();
        let mut fused = false;
        match result {
            Ok(out) => {
                self.last_output = Some(out);
                match out.pose {
                    Some(rp) => {
                        self.counters.vo_updates = self.counters.vo_updates.saturating_add(1);
                        fused = self.fuse(&rp, heading_known, filter, diag, cal);
                    }
                    // A new keyframe without a previous one (start, or after a VO outage): the
                    // VO-only trajectory is anchored again at the EKF pose of this keyframe.
                    None => diag.vo_restart(),
                }
            }
            Err(e) => {
                if had_key {
                    self.counters.vo_failures = self.counters.vo_failures.saturating_add(1);
                    self.last_error = Some(e);
                }
            }
        }
        // Keep the clone of whichever frame VO now holds as its keyframe.
        let key_t = self.pipeline.as_ref().and_then(|v| v.keyframe_time_us());
        let old_key = self.key_clone.take();
        let (keep, drop) = match (key_t, capture, old_key) {
            (Some(t), Some(c), _) if c.t_us() == t => (Some(c), old_key),
            (Some(t), _, Some(k)) if k.t_us() == t => (Some(k), capture),
            _ => {
                filter.release(old_key);
                (None, capture)
            }
        };
        filter.release(drop);
        self.key_clone = keep;
        if keep.is_some() {
            self.started = true;
        }
        if keep.is_none() {
            if let Some(vo) = self.pipeline.as_mut() {
                // A keyframe without its clone cannot be used: rebuild at the next capture.
                vo.reset();
            }
        }
        fused
    }

    /// The VO pose `raw` between the keyframe and the capture: boresight-corrected, chained
    /// into the VO-only trajectory, gated, and fused at capture time (module doc). Returns true
    /// when fused.
    pub(super) fn fuse(
        &mut self,
        raw: &RelativePose,
        heading_known: bool,
        filter: &mut NavFilter,
        diag: &mut Trajectories,
        cal: &mut Calibration,
    ) -> bool {
        // VO's translation boresight removed before anything uses the pose.
        let corrected = cal.correct(raw);
        let rp = &corrected;
        let (Some(key), true) = (self.key_clone, filter.is_running()) else {
            return false;
        };
        // VO-only dead reckoning, started at the EKF pose of a keyframe. It chains every VO
        // pose, rejected ones too: it is the diagnostic of VO alone, independent of the gate
        // (whose verdicts are in the counters and telemetry). It starts once the EKF heading
        // has had its first sun update (or the drive has no sun sensor, or after
        // `VO_ANCHOR_MAX_POSES` poses): anchored before it, the trajectory would carry the
        // alignment's heading error for good.
        let heading_ready = heading_known || self.counters.vo_updates >= VO_ANCHOR_MAX_POSES;
        if heading_ready || diag.vo_started() {
            let anchor = filter
                .clone_pose(Some(key))
                .map(|(q, p)| PoseEstimate { p_n: p, q_nr: q });
            diag.vo_step(anchor, rp);
        }
        // The VO gate decides once, before anything is applied, on the filter the pose is
        // applied to (the recorder's snapshot at capture time when the result is replayed, the
        // live filter otherwise). The pose is then applied without eq. 46's own gate.
        let Some(fused) = self.gate_decide(rp, filter) else {
            // Rejected: not fused, counted. The recording since the capture is not needed.
            filter.end_recording();
            return false;
        };
        // An accepted pose teaches the boresight (from its raw translation) and the dead
        // reckoning's radius scale when the wheels' motion over the same capture interval is
        // clean.
        cal.learn(raw, rp);
        let (result, replayed) = filter.apply_vo(&fused);
        if replayed {
            self.counters.vo_replayed = self.counters.vo_replayed.saturating_add(1);
        }
        match result {
            Ok(d) => {
                self.counters.vo_fused = self.counters.vo_fused.saturating_add(1);
                if d.d2 > self.config.warn_d2 {
                    self.counters.vo_large_d2 = self.counters.vo_large_d2.saturating_add(1);
                }
                self.cycles_since_fused = 0;
                self.fused_since_interval = true;
                true
            }
            Err(e) => {
                filter.error(e);
                false
            }
        }
    }

    /// The VO gate ([`super::vo_gate`]): returns the pose to fuse (`rp`, or `rp` with an
    /// inflated covariance after a rejection streak), or `None` when it is rejected (counted,
    /// verdict and streak in [`Self::gate`]). An estimator error on the test (clone
    /// missing...) is reported to the filter and the pose is not fused.
    fn gate_decide(&mut self, rp: &RelativePose, filter: &mut NavFilter) -> Option<RelativePose> {
        if !self.config.gate_enabled {
            self.gate.verdict = VoGateVerdict::Accepted;
            return Some(*rp);
        }
        let decision = match filter.capture_filter().gate_relative_pose(rp) {
            Ok(d) => d,
            Err(e) => {
                filter.error(e);
                return None;
            }
        };
        let (frac, floor) = (
            self.config.gate_slip_fraction,
            self.config.gate_slip_floor_m,
        );
        let test = vo_gate_test(&decision, rp, 1.0, frac, floor);
        let verdict = test.map_or(VoGateVerdict::RejectedError, |t| t.verdict());
        if let Some(t) = test {
            self.gate.d2_rotation = t.d2_rotation;
            self.gate.d2_pose = t.d2_pose;
        }
        if verdict == VoGateVerdict::Accepted {
            self.gate.verdict = verdict;
            self.gate.consecutive_rejections = 0;
            self.gate.streak = false;
            return Some(*rp);
        }
        // After a streak the pose is fused with the smallest covariance scale 4^n that passes.
        if self.gate.streak && verdict != VoGateVerdict::RejectedError {
            let mut scale = 1.0;
            for _ in 0..VO_FORCE_MAX_STEPS {
                scale *= 4.0;
                let passes = vo_gate_test(&decision, rp, scale, frac, floor)
                    .is_some_and(|t| t.verdict() == VoGateVerdict::Accepted);
                if passes {
                    break;
                }
            }
            self.counters.vo_forced = self.counters.vo_forced.saturating_add(1);
            self.gate.verdict = VoGateVerdict::Forced;
            // The streak is over: another one is needed before the next forced fusion (at most
            // one pose in `reject_streak + 1` is forced when VO is consistently wrong).
            self.gate.consecutive_rejections = 0;
            self.gate.streak = false;
            let mut forced = *rp;
            forced.covariance *= scale;
            return Some(forced);
        }
        let c = &mut self.counters;
        c.vo_rejected = c.vo_rejected.saturating_add(1);
        if verdict == VoGateVerdict::RejectedRotation {
            c.vo_rejected_rotation = c.vo_rejected_rotation.saturating_add(1);
        }
        self.gate.verdict = verdict;
        self.gate.consecutive_rejections = self.gate.consecutive_rejections.saturating_add(1);
        if self.gate.consecutive_rejections >= self.config.reject_streak.max(1) && !self.gate.streak
        {
            self.gate.streak = true;
            c.vo_reject_streaks = c.vo_reject_streaks.saturating_add(1);
        }
        None
    }
}

/// The EKF's relative pose between two clones (the VO motion prior), in the [`RelativePose`]
/// convention.
fn ekf_relative_pose(
    filter: &NavFilter,
    from: Option<CloneHandle>,
    to: Option<CloneHandle>,
) -> Option<RelativePose> {
    let ekf = filter.running()?;
    let (q0, p0) = ekf.clone_pose(from?).ok()?;
    let (q1, p1) = ekf.clone_pose(to?).ok()?;
    Some(RelativePose {
        t0_us: from?.t_us(),
        t1_us: to?.t_us(),
        rot_0_1: q0.inverse() * q1,
        trans_0_1_m: q0.inverse_transform_vector(&(p1 - p0)),
        covariance: crate::types::Mat6::zeros(),
        observed: [true; 6],
    })
}

#[cfg(test)]
impl VoAiding {
    /// The settings (tests change them).
    pub(crate) fn config_mut(&mut self) -> &mut VoAidingConfig {
        &mut self.config
    }

    /// VO's keyframe clone (tests set it).
    pub(crate) fn key_clone_mut(&mut self) -> &mut Option<CloneHandle> {
        &mut self.key_clone
    }
}
