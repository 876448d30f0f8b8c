//! Visual odometry scheduling (RG3 and background): capture clones (eq. 41), the stereo state
//! machine, VO work slices, and the fusion of VO relative poses at their capture time by a
//! sliced replay of the recorded filter operations.

use super::vo_gate::{vo_gate_test, VoGateVerdict, VO_FORCE_MAX_STEPS};
use super::*;

/// Where the stereo pipeline is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum StereoStage {
    /// Nothing pending.
    Idle,
    /// Capture triggered at `t_us` and cloned; waiting for the camera.
    Capturing { clone: Option<CloneHandle> },
    /// VO running on the frame of `clone`; `items` work items done so far.
    Processing {
        clone: Option<CloneHandle>,
        items: u32,
    },
    /// A hazard map running on the held frame ([`super::hazard_nav`]); `items` work items done.
    Mapping { items: u32 },
    /// Terrain-map localization searching after a map ([`super::loc_nav`]); the frame stays
    /// held so that no capture starts meanwhile.
    Localizing,
}

/// VO poses after which the VO-only trajectory starts even without a sun update.
const VO_ANCHOR_MAX_POSES: u32 = 30;

impl Navigator {
    /// Build the visual odometry state (about 96 KB) in place, when [`NavConfig::vo_enabled`].
    /// Call once after the navigator has reached its final location (a static on the rover
    /// CPU), so that the large state is not copied through the stack by the constructors.
    /// A calibration VO refuses leaves VO off (counted in [`NavCounters::vo_failures`]).
    /// Also builds the hazard navigation ([`NavConfig::hazard_avoidance`], about 68 KB).
    pub fn start_vo(&mut self) {
        self.start_localization();
        self.start_hazard_nav();
        if !self.config.vo_enabled || self.vo.is_some() {
            return;
        }
        // Built in its storage (no 93 KB value through the stack).
        match self.vo.value.init(self.config.vo, &self.calibration) {
            Ok(()) => self.vo.built = true,
            Err(_) => self.counters.vo_failures = self.counters.vo_failures.saturating_add(1),
        }
    }

    /// True when the visual odometry state was built ([`Self::start_vo`]).
    pub fn vo_built(&self) -> bool {
        self.vo.is_some()
    }

    /// True when VO or a hazard map is running on a frame (the camera frame must stay held).
    pub fn vo_busy(&self) -> bool {
        matches!(
            self.stereo,
            StereoStage::Processing { .. } | StereoStage::Mapping { .. } | StereoStage::Localizing
        )
    }

    /// True while a VO result is being replayed from its capture time in background slices
    /// ([`Self::replay_step`]); no capture is started meanwhile.
    pub fn replaying(&self) -> bool {
        self.recorder.replaying()
    }

    /// Background: replays up to [`NavConfig::replay_ops_per_slice`] recorded filter
    /// operations of a late VO update; when the replay has caught up, the replayed filter
    /// becomes the live one (bit-identical to a one-shot replay then). Returns the operations
    /// budget used (0 when no replay is in progress).
    pub fn replay_step(&mut self) -> u32 {
        if !self.recorder.replaying() {
            return 0;
        }
        if !self.ekf_running {
            self.recorder.end();
            return 1;
        }
        let ops = self.config.replay_ops_per_slice.max(1);
        if self.recorder.replay_step(&mut self.ekf, usize::from(ops)) == ReplayProgress::Abandoned {
            self.counters.vo_replay_lost = self.counters.vo_replay_lost.saturating_add(1);
        }
        u32::from(ops)
    }

    /// True when a capture may be triggered (VO enabled and idle, no replay in progress,
    /// estimator running).
    pub fn wants_capture(&self) -> bool {
        (self.vo.is_some() || self.hazard_on())
            && self.ekf_running
            && matches!(self.stereo, StereoStage::Idle)
            && !self.recorder.replaying()
            && self.mode != NavMode::Safed
    }

    /// True when a capture is waiting for the camera.
    pub fn capture_pending(&self) -> bool {
        matches!(self.stereo, StereoStage::Capturing { .. })
    }

    /// RG3: a capture was triggered at `t_us` (camera time base = IMU time base) because it was
    /// due for `reason` ([`Self::capture_due`]). Clones the state there (eq. 41) and makes the
    /// current EKF pose the capture policy's reference. Returns false when the capture cannot be
    /// used (no clone slot).
    pub fn capture_started(&mut self, t_us: u64, reason: super::vo_gate::CaptureReason) -> bool {
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return false;
        };
        match ekf.clone_at(t_us) {
            Ok(h) => {
                self.stereo = StereoStage::Capturing { clone: Some(h) };
                // Record from here on, so that the VO result can be applied at capture time
                // exactly (replay) however late it arrives.
                self.recorder.begin(&self.ekf);
                self.boresight.capture(t_us);
                self.kin3d_scale.capture(t_us);
                self.mark_capture(reason);
                true
            }
            Err(_) => {
                self.counters.captures_skipped = self.counters.captures_skipped.saturating_add(1);
                self.stereo = StereoStage::Idle;
                false
            }
        }
    }

    /// RG3 found VO still busy: the capture is skipped (counted).
    pub fn capture_skipped(&mut self) {
        self.counters.captures_skipped = self.counters.captures_skipped.saturating_add(1);
    }

    /// The capture was lost (camera error or timeout): its clone is released.
    pub fn capture_lost(&mut self) {
        if !self.recorder.replaying() {
            self.recorder.end();
        }
        let clone = match self.stereo {
            StereoStage::Capturing { clone } | StereoStage::Processing { clone, .. } => clone,
            StereoStage::Idle | StereoStage::Mapping { .. } => None,
            StereoStage::Localizing => {
                self.loc_abandon();
                None
            }
        };
        self.release(clone);
        if let Some(vo) = self.vo.as_mut() {
            if vo.is_busy() {
                vo.reset();
                let key = self.key_clone.take();
                self.release(key);
            }
        }
        self.stereo = StereoStage::Idle;
    }

    /// Background: the captured `frame` is ready. Starts VO with the EKF's motion between the
    /// keyframe clone and this capture's clone as the prior. Returns false when VO did not
    /// start (the caller releases the frame).
    pub fn vo_start(&mut self, frame: &StereoFrame) -> bool {
        let StereoStage::Capturing { clone } = self.stereo else {
            return false;
        };
        let prior = self.ekf_relative_pose(self.key_clone, clone);
        let Some(vo) = self.vo.as_mut() else {
            // VO off: the frame serves the hazard map alone (if one is due); localization
            // keeps the capture's clone of a map to apply its fix there.
            let pose = self.clone_pose_of(clone);
            self.stereo = StereoStage::Idle;
            if !self.recorder.replaying() {
                self.recorder.end();
            }
            let started = self.start_map(frame, pose);
            if started && self.loc_on() {
                self.loc_keep_clone(clone);
            } else {
                self.release(clone);
            }
            return started;
        };
        match vo.start(frame, prior.as_ref()) {
            Ok(()) => {
                self.stereo = StereoStage::Processing { clone, items: 0 };
                true
            }
            Err(_) => {
                self.counters.vo_failures = self.counters.vo_failures.saturating_add(1);
                self.vo_keyframe_lost();
                self.capture_lost();
                false
            }
        }
    }

    /// The EKF pose (rotation `R -> N`, position in `N`) of `clone`, if it is live.
    pub(super) fn clone_pose_of(&self, clone: Option<CloneHandle>) -> Option<(Quat, Vec3)> {
        let ekf = self.ekf_running.then_some(&self.ekf)?;
        ekf.clone_pose(clone?).ok()
    }

    pub(super) fn vo_keyframe_lost(&mut self) {
        if let Some(vo) = self.vo.as_mut() {
            vo.reset();
        }
        let key = self.key_clone.take();
        self.release(key);
    }

    /// The EKF's relative pose between two clones (the VO motion prior), in the
    /// [`RelativePose`] convention.
    pub(super) fn ekf_relative_pose(
        &self,
        from: Option<CloneHandle>,
        to: Option<CloneHandle>,
    ) -> Option<RelativePose> {
        let ekf = self.ekf_running.then_some(&self.ekf)?;
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

    /// Background: advance VO on `frame` by at most `quantum` work items. Returns the items
    /// used and whether the update finished (the caller then releases the frame).
    pub fn vo_step(&mut self, frame: &StereoFrame, quantum: u32) -> (u32, bool) {
        if let StereoStage::Mapping { items } = self.stereo {
            return self.map_step(frame, items, quantum);
        }
        if self.stereo == StereoStage::Localizing {
            return self.loc_step(quantum);
        }
        let StereoStage::Processing { clone, items } = self.stereo else {
            return (0, true);
        };
        let Some(vo) = self.vo.as_mut() else {
            self.capture_lost();
            return (0, true);
        };
        match vo.step(frame, quantum) {
            Progress::Working { items: total } => {
                self.stereo = StereoStage::Processing {
                    clone,
                    items: total,
                };
                (total.saturating_sub(items), false)
            }
            Progress::Finished(result) => {
                // The capture's pose, for a hazard map of the same frame (before VO's
                // bookkeeping releases the clone).
                let pose = self.clone_pose_of(clone);
                self.vo_finished(clone, result);
                if self.start_map(frame, pose) {
                    return (quantum.max(1), false);
                }
                (quantum.max(1), true)
            }
        }
    }

    pub(super) fn vo_finished(
        &mut self,
        capture: Option<CloneHandle>,
        result: Result<VoOutput, VoError>,
    ) {
        self.stereo = StereoStage::Idle;
        let had_key = self.key_clone.is_some();
        match result {
            Ok(out) => {
                self.vo_quality = Some(out);
                match out.pose {
                    Some(rp) => {
                        self.counters.vo_updates = self.counters.vo_updates.saturating_add(1);
                        self.vo_fuse(&rp);
                    }
                    // A new keyframe without a previous one (start, or after a VO outage): the
                    // VO-only trajectory is anchored again at the EKF pose of this keyframe.
                    None => self.traj.vo = None,
                }
            }
            Err(e) => {
                if had_key {
                    self.counters.vo_failures = self.counters.vo_failures.saturating_add(1);
                    self.last_vo_error = Some(e);
                }
            }
        }
        // Keep the clone of whichever frame VO now holds as its keyframe.
        let key_t = self.vo.as_ref().and_then(|v| v.keyframe_time_us());
        let old_key = self.key_clone.take();
        let (keep, drop) = match (key_t, capture, old_key) {
            (Some(t), Some(c), _) if c.t_us() == t => (Some(c), old_key),
            (Some(t), _, Some(k)) if k.t_us() == t => (Some(k), capture),
            _ => {
                self.release(old_key);
                (None, capture)
            }
        };
        self.release(drop);
        self.key_clone = keep;
        if keep.is_some() {
            self.vo_started = true;
        }
        if keep.is_none() {
            if let Some(vo) = self.vo.as_mut() {
                // A keyframe without its clone cannot be used: rebuild at the next capture.
                vo.reset();
            }
        }
    }

    pub(super) fn vo_fuse(&mut self, raw: &RelativePose) {
        // VO's translation boresight (boresight.rs) removed before anything uses the pose.
        let corrected = self.boresight.correct(&self.config.vo_boresight, raw);
        let rp = &corrected;
        let (Some(key), Some(ekf)) = (self.key_clone, self.ekf_running.then_some(&mut self.ekf))
        else {
            return;
        };
        // VO-only dead reckoning, started at the EKF pose of a keyframe. It chains every VO
        // pose, rejected ones too: it is the diagnostic of VO alone, independent of the gate
        // (whose verdicts are in the counters and telemetry). It starts once the EKF heading
        // has had its first sun update (or the drive has no sun sensor, or after
        // `VO_ANCHOR_MAX_POSES` poses): anchored before it, the trajectory carries the
        // alignment's heading error (25 mrad on `flat-firm`, 0.36 m across 20 m) for good, which
        // looked like a VO drift once VO results came in before the first sun update (5 s).
        let heading_ready = self.config.ekf.sun.is_none()
            || self.counters.sun_applied > 0
            || self.counters.vo_updates >= VO_ANCHOR_MAX_POSES;
        if heading_ready || self.traj.vo.is_some() {
            let anchor = ekf
                .clone_pose(key)
                .ok()
                .map(|(q, p)| PoseEstimate { p_n: p, q_nr: q });
            self.traj.vo_step(anchor, rp);
        }
        // The VO gate (vo_gate.rs) decides once, before anything is applied, on the filter the
        // pose is applied to: the recorder's snapshot at capture time when the result is
        // replayed (so the decision is the one an instantaneous VO would have had), the live
        // filter otherwise. The pose is then applied without eq. 46's own gate.
        let Some(fused) = self.vo_gate_decide(rp) else {
            // Rejected: not fused, counted. The recording since the capture is not needed.
            if !self.recorder.replaying() {
                self.recorder.end();
            }
            return;
        };
        // Applied at capture time and replayed to now when the recording since the capture is
        // complete (exact); otherwise at the capture clones (exact there, first order now). The
        // replay runs in background slices (replay_step): the live filter takes the result when
        // the replay has caught up.
        // An accepted pose teaches the boresight (from its raw translation) when the wheels'
        // motion over the same capture interval is clean.
        self.boresight.learn(&self.config.vo_boresight, raw);
        // And the dead reckoning's radius scale, from the same clean capture interval.
        let t = rp.trans_0_1_m;
        self.kin3d_scale.learn(
            &self.config.radius_scale,
            rp.t0_us,
            rp.t1_us,
            &[t.x, t.y, t.z],
        );
        let result = if self.recorder.active() {
            self.counters.vo_replayed = self.counters.vo_replayed.saturating_add(1);
            self.recorder.start_late(&fused, false)
        } else {
            self.recorder.end();
            self.ekf.update_relative_pose(&fused, false)
        };
        match result {
            Ok(d) => {
                self.counters.vo_fused = self.counters.vo_fused.saturating_add(1);
                if d.d2 > self.config.vo_warn_d2 {
                    self.counters.vo_large_d2 = self.counters.vo_large_d2.saturating_add(1);
                }
                self.cycles_since_vo = 0;
                self.reject_streak = 0;
                self.vo_fused_since_interval = true;
            }
            Err(e) => self.ekf_error(e),
        }
    }

    /// The VO gate (module `vo_gate`): returns the pose to fuse (`rp`, or `rp` with an inflated
    /// covariance after a rejection streak), or `None` when it is rejected (counted, verdict
    /// and streak in [`Self::vo_gate`]). An estimator error on the test (clone missing...) is
    /// counted in [`NavCounters::ekf_errors`] and the pose is not fused.
    fn vo_gate_decide(&mut self, rp: &RelativePose) -> Option<RelativePose> {
        if !self.config.vo_gate_enabled {
            self.vo_gate.verdict = VoGateVerdict::Accepted;
            return Some(*rp);
        }
        let filter = match self.recorder.snapshot().filter(|_| self.recorder.active()) {
            Some(snapshot) => snapshot,
            None => &self.ekf,
        };
        let decision = match filter.gate_relative_pose(rp) {
            Ok(d) => d,
            Err(e) => {
                self.ekf_error(e);
                return None;
            }
        };
        let (frac, floor) = (
            self.config.vo_gate_slip_fraction,
            self.config.vo_gate_slip_floor_m,
        );
        let test = vo_gate_test(&decision, rp, 1.0, frac, floor);
        let verdict = test.map_or(VoGateVerdict::RejectedError, |t| t.verdict());
        if let Some(t) = test {
            self.vo_gate.d2_rotation = t.d2_rotation;
            self.vo_gate.d2_pose = t.d2_pose;
        }
        if verdict == VoGateVerdict::Accepted {
            self.vo_gate.verdict = verdict;
            self.vo_gate.consecutive_rejections = 0;
            self.vo_gate.streak = false;
            return Some(*rp);
        }
        // After a streak the pose is fused with the smallest covariance scale 4^n that passes.
        if self.vo_gate.streak && verdict != VoGateVerdict::RejectedError {
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
            self.vo_gate.verdict = VoGateVerdict::Forced;
            // The streak is over: another one is needed before the next forced fusion (at most
            // one pose in `vo_reject_streak + 1` is forced when VO is consistently wrong).
            self.vo_gate.consecutive_rejections = 0;
            self.vo_gate.streak = false;
            let mut forced = *rp;
            forced.covariance *= scale;
            return Some(forced);
        }
        let c = &mut self.counters;
        c.vo_rejected = c.vo_rejected.saturating_add(1);
        if verdict == VoGateVerdict::RejectedRotation {
            c.vo_rejected_rotation = c.vo_rejected_rotation.saturating_add(1);
        }
        self.vo_gate.verdict = verdict;
        self.vo_gate.consecutive_rejections = self.vo_gate.consecutive_rejections.saturating_add(1);
        if self.vo_gate.consecutive_rejections >= self.config.vo_reject_streak.max(1)
            && !self.vo_gate.streak
        {
            self.vo_gate.streak = true;
            c.vo_reject_streaks = c.vo_reject_streaks.saturating_add(1);
        }
        None
    }
}
