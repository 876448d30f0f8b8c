//! The navigator's task entry points: what each flight task hands to which component, in
//! which order (module doc of [`super`]).

use super::goal::{GoalCtx, ModeRequest};
use super::kin_aiding::KinInputs;
use super::protection::FaultResponse;
use super::vo_gate::CaptureReason;
use super::{
    Follow, LocNav, MissionBudget, MissionError, NavMode, Navigator, PoseEstimate, StereoStage,
};
use crate::guidance::{Pose2, SlipVector};
use crate::kinematics::VehicleCommand;
use crate::types::{Quat, Vec3};
use crate::vo::Progress;
use rover_hal::{ImuSample, JointState, MobilityCommand, PowerReading, StereoFrame, SunReading};

impl Navigator {
    /// A covariance fault raised during the step just run latches [`NavMode::Safed`].
    fn latch_safe(&mut self) {
        if self.filter.take_safe_request() {
            self.mode = NavMode::Safed;
        }
    }

    /// Latch a fault-protection stop (only while driving).
    fn fault_stop(&mut self, response: FaultResponse) {
        if self.mode == NavMode::Driving {
            self.mode = NavMode::Stopped;
            self.drive.latch(response);
        }
    }

    /// Apply the mode change the goal-directed navigation asked for.
    fn apply(&mut self, request: Option<ModeRequest>) {
        match request {
            Some(ModeRequest::Arrived) => self.mode = NavMode::Arrived,
            Some(ModeRequest::Stop(r)) => self.fault_stop(r),
            Some(ModeRequest::Resume) if self.mode == NavMode::Arrived => {
                self.mode = NavMode::Driving;
            }
            Some(ModeRequest::Resume) | None => {}
        }
    }

    /// RG1: one checked IMU sample (`None`: no new sample this frame). While aligning the
    /// [`super::Aligner`] takes it (and starts the filter when the alignment is complete);
    /// afterwards it propagates the filter (eq. 26-27), the contact-angle estimator's gyro
    /// integral and the gyro dead reckoning.
    #[inline(never)]
    pub fn propagate(&mut self, sample: Option<&ImuSample>) {
        let Some(s) = sample else {
            self.filter.imu_missing();
            return;
        };
        self.filter.imu_received();
        if self.mode == NavMode::Aligning {
            if let Some(a) = self.align.add_imu(s, &mut self.filter) {
                self.diag.aligned(a.pose, a.b_g, a.t_us);
                self.mode = NavMode::Driving;
                self.kin.anchor_at_rest();
            }
            self.latch_safe();
            return;
        }
        if self.filter.propagate(s) {
            let b_g = self.filter.state().b_g;
            self.kin.gyro(s, &b_g);
            self.diag.gyro(s);
        }
        self.latch_safe();
    }

    /// An IMU shock (an accelerometer sample at or beyond the sensor's range;
    /// [`super::KinAiding::imu_shock`]), with `velocity_sigma_m_s` the velocity it may have
    /// left unknown, m/s.
    pub fn imu_shock(&mut self, velocity_sigma_m_s: f64) {
        self.kin.imu_shock(velocity_sigma_m_s, &mut self.filter);
        self.latch_safe();
    }

    /// The IMU's time base changed (a time-stamp leap that persisted and was accepted): the
    /// filter's timeline is re-anchored at `t_us` (the state and its core covariance are kept,
    /// the clones, the kinematic interval, the VO keyframe and any recording or replay are
    /// dropped, since their times belong to the old base), so that the filter never propagates
    /// across the leap. The clock jumped, the rover did not: the drive goes on.
    pub fn imu_time_rebase(&mut self, t_us: u64) {
        if self.filter.rebase(t_us) {
            self.kin.rebase();
            self.stereo = StereoStage::Idle;
            self.vo.rebase();
        }
        self.latch_safe();
    }

    /// RG2: one checked joint reading (`None`: none this cycle): the kinematic interval, gate,
    /// fusion or slip vector, dead reckoning ([`super::KinAiding::cycle`]); fault protection's
    /// slip window on the interval's travel.
    #[inline(never)]
    pub fn kinematic_cycle(&mut self, joints: Option<&JointState>) {
        let inputs = KinInputs {
            vo: self.vo.health(),
            stop_and_go: self.drive.config().blind_stop_interval_m > 0.0,
            command: self.drive.command(),
        };
        let out = self.kin.cycle(
            joints,
            &inputs,
            &self.geometry,
            &mut self.filter,
            &mut self.diag,
            &mut self.cal,
        );
        if let Some(t) = out.travel {
            let vo_fused = self.vo.take_fused_since_interval();
            if let Some(r) = self
                .drive
                .travel(t.wheel_m, t.ekf_m, vo_fused || t.imu_anchored)
            {
                self.fault_stop(r);
            }
        }
        if out.closed {
            self.vo.count_cycle();
        }
        self.latch_safe();
    }

    /// RG2B, half an RG2 period after [`Self::kinematic_cycle`]: the zero-velocity update of
    /// the stop the last kinematic cycle saw ([`super::KinAiding::zero_velocity_cycle`]).
    pub fn zero_velocity_cycle(&mut self) {
        self.kin
            .zero_velocity_cycle(&self.drive.command(), &mut self.filter);
        self.latch_safe();
    }

    /// RG2, after [`Self::kinematic_cycle`]: guidance and inverse kinematics. Returns the motor
    /// command, or `None` when the rover must be stopped (aligning, arrived, safed, a sensor
    /// lost, waiting for VO's first keyframe, a stop, or a guidance/kinematics failure).
    ///
    /// With VO running the rover does not start before VO holds its first keyframe (at most
    /// [`super::DriveConfig::vo_start_timeout_cycles`], then it drives without VO): the first
    /// metres on a slope are where slip, unseen without VO, is learnt as a heading error.
    pub fn guidance_cycle(&mut self) -> Option<MobilityCommand> {
        let commanded = self.drive.begin_cycle();
        self.goal
            .mission_book(commanded.iter().any(|r| *r != 0.0), &self.filter);
        if self.mode != NavMode::Driving {
            return None;
        }
        let joints = self.kin.last_joints();
        let sigma_h = self.filter.horizontal_sigma_m();
        let gaps = (self.filter.imu_gap_frames(), self.kin.joint_gap_cycles());
        match self
            .drive
            .protect(gaps.0, gaps.1, joints.as_ref(), &commanded, sigma_h)
        {
            Err(Some(r)) => {
                self.fault_stop(r);
                return None;
            }
            Err(None) => return None,
            Ok(()) => {}
        }
        if self.vo.built() && !self.vo.started() {
            if self.drive.wait_for_vo() {
                return None;
            }
            self.vo.start_wait_over();
        }
        let vo_lost = self.vo.health().lost();
        let radius = self.geometry.wheel_radius_m;
        if self
            .drive
            .blind_stop_due(vo_lost, joints.as_ref(), sigma_h, radius)
        {
            return None;
        }
        // A localization stop (path drives, V99 sec. 5): hold, or turn in place to a view.
        let max_sigma = self.drive.config().protection.max_position_sigma_m;
        if let Some(turn) = self.goal.loc_command(&self.filter, max_sigma, vo_lost) {
            return self.hold_or_turn(turn);
        }
        // The day's targets: hold for a plan, or stand at a target for its dwell (V99 sec. 3).
        if self.goal.mission_command(&self.filter).is_some() {
            return None;
        }
        // Goal-directed driving: hold for a map, or turn in place for a gaze (V99 sec. 4).
        if self.goal.config().hazard_avoidance && !self.goal.hazard_on() {
            self.drive.command_error();
            return None;
        }
        if let Some(turn) = self.goal.hazard_command(&self.filter) {
            return self.hold_or_turn(turn);
        }
        let (Some(ekf), Some(j)) = (self.filter.running(), joints) else {
            return None;
        };
        let (nav_pose, slip) = if self.drive.config().slip_compensation {
            let x = ekf.state();
            let pose = PoseEstimate {
                p_n: x.p_n,
                q_nr: x.q_nr,
            };
            (pose, self.kin.slip())
        } else {
            (self.diag.kin3d(), SlipVector::default())
        };
        let pose = Pose2 {
            x_m: nav_pose.p_n.x,
            y_m: nav_pose.p_n.y,
            phi_rad: super::yaw_of(&nav_pose.q_nr),
        };
        match self.drive.follow(pose, slip) {
            Follow::Hold => None,
            Follow::Reached { distance_m } => {
                // The end of a planned path short of the goal: hold and map again.
                if self.goal.hazard_subgoal_reached() {
                    return None;
                }
                if self.drive.arrival_supported(distance_m, sigma_h) {
                    // With targets: the dwell at this one, then on to the next.
                    if !self.goal.mission_arrived(&self.filter) {
                        self.mode = NavMode::Arrived;
                    }
                } else {
                    self.fault_stop(FaultResponse::ArrivedUncertain);
                }
                None
            }
            Follow::Drive(cmd) => {
                let angles = self.kin.windowed_contact_angles_rad();
                self.drive.motor(cmd, &j, angles, &self.geometry)
            }
        }
    }

    /// A stop's or a gaze's say: `None` holds the rover still, `Some(turn)` turns it in place.
    fn hold_or_turn(&mut self, turn: Option<VehicleCommand>) -> Option<MobilityCommand> {
        let turn = turn?;
        let joints = self.kin.last_joints()?;
        let angles = self.kin.windowed_contact_angles_rad();
        self.drive.motor(turn, &joints, angles, &self.geometry)
    }

    /// RG4: one checked sun reading with the sun in view: the alignment's heading while
    /// aligning, the sun-sensor update afterwards ([`super::SunAiding::update`]).
    pub fn sun(&mut self, reading: &SunReading) {
        if self.mode == NavMode::Aligning {
            self.align.sun(reading);
            return;
        }
        self.sun.update(reading, &mut self.filter);
        self.latch_safe();
    }

    /// RG4: a checked power reading (V99 sec. 3's "current power reserves";
    /// [`super::GoalNav::power`]).
    pub fn power(&mut self, reading: &PowerReading) {
        self.goal.power(reading, &self.filter);
    }

    /// True when a capture may be triggered (VO or a hazard mapper built and the pipeline
    /// idle, no replay in progress, estimator running, not safed).
    pub fn wants_capture(&self) -> bool {
        (self.vo.built() || self.goal.hazard_on())
            && self.filter.is_running()
            && matches!(self.stereo, StereoStage::Idle)
            && !self.filter.replaying()
            && self.mode != NavMode::Safed
    }

    /// RG3: whether a stereo capture is due now, and why ([`super::VoAiding::capture_due`]).
    /// `None` when no capture may start ([`Self::wants_capture`]) or none is due.
    pub fn capture_due(&self) -> Option<CaptureReason> {
        if !self.wants_capture() {
            return None;
        }
        self.vo
            .capture_due(self.filter.state(), self.goal.map_wanted_now())
    }

    /// True when a capture is waiting for the camera.
    pub fn capture_pending(&self) -> bool {
        matches!(self.stereo, StereoStage::Capturing { .. })
    }

    /// True when VO, a hazard map or a localization search is running on a frame (the camera
    /// frame must stay held).
    pub fn vo_busy(&self) -> bool {
        matches!(
            self.stereo,
            StereoStage::Processing { .. } | StereoStage::Mapping { .. } | StereoStage::Localizing
        )
    }

    /// True while a VO result is being replayed from its capture time in background slices
    /// ([`Self::replay_step`]); no capture is started meanwhile.
    pub fn replaying(&self) -> bool {
        self.filter.replaying()
    }

    /// Background: one slice of the replay of a late VO update ([`super::NavFilter::replay_slice`]).
    pub fn replay_step(&mut self) -> u32 {
        self.filter.replay_slice()
    }

    /// RG3: a capture was triggered at `t_us` (camera time base = IMU time base) because it was
    /// due for `reason`. Clones the state there (eq. 41), starts recording the filter's
    /// operations and makes the current EKF pose the capture policy's reference. Returns false
    /// when the capture cannot be used (no clone slot: counted).
    pub fn capture_started(&mut self, t_us: u64, reason: CaptureReason) -> bool {
        match self.filter.clone_capture(t_us) {
            None => false,
            Some(Ok(h)) => {
                self.stereo = StereoStage::Capturing { clone: Some(h) };
                self.cal.capture(t_us);
                self.vo.capture_started(self.filter.state(), reason);
                true
            }
            Some(Err(_)) => {
                self.vo.capture_skipped();
                self.stereo = StereoStage::Idle;
                false
            }
        }
    }

    /// RG3 found VO still busy: the capture is skipped (counted).
    pub fn capture_skipped(&mut self) {
        self.vo.capture_skipped();
    }

    /// The capture was lost (camera error or timeout): its clone is released, a search in
    /// progress abandoned, VO restarted.
    pub fn capture_lost(&mut self) {
        self.filter.end_recording();
        let clone = match self.stereo {
            StereoStage::Capturing { clone } | StereoStage::Processing { clone, .. } => clone,
            StereoStage::Idle | StereoStage::Mapping { .. } => None,
            StereoStage::Localizing => {
                self.goal.loc_abandon(&self.filter);
                None
            }
        };
        self.filter.release(clone);
        self.vo.capture_lost(&mut self.filter);
        self.stereo = StereoStage::Idle;
    }

    /// Background: the captured `frame` is ready. Starts VO with the EKF's motion between the
    /// keyframe clone and this capture's clone as the prior; with VO off the frame serves the
    /// hazard map alone. Returns false when nothing started (the caller releases the frame).
    pub fn vo_start(&mut self, frame: &StereoFrame) -> bool {
        let StereoStage::Capturing { clone } = self.stereo else {
            return false;
        };
        if !self.vo.built() {
            // VO off: the frame serves the hazard map alone (if one is due); localization
            // keeps the capture's clone of a map to apply its fix there.
            let pose = self.filter.clone_pose(clone);
            self.stereo = StereoStage::Idle;
            self.filter.end_recording();
            let started = self.start_map(frame, pose);
            if started && self.goal.loc_on() {
                let old = self.goal.loc_keep_clone(clone);
                self.filter.release(old);
            } else {
                self.filter.release(clone);
            }
            return started;
        }
        if self.vo.start(frame, clone, &mut self.filter) {
            self.stereo = StereoStage::Processing { clone, items: 0 };
            true
        } else {
            self.capture_lost();
            false
        }
    }

    /// Background: advance the work on the held `frame` (VO, a hazard map or a localization
    /// search) by at most `quantum` work items. Returns the items used and whether the work on
    /// the frame finished (the caller then releases it).
    pub fn vo_step(&mut self, frame: &StereoFrame, quantum: u32) -> (u32, bool) {
        match self.stereo {
            StereoStage::Mapping { items } => return self.map_step(frame, items, quantum),
            StereoStage::Localizing => return self.loc_step(quantum),
            _ => {}
        }
        let StereoStage::Processing { clone, items } = self.stereo else {
            return (0, true);
        };
        let Some(progress) = self.vo.step(frame, quantum) else {
            self.capture_lost();
            return (0, true);
        };
        match progress {
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
                let pose = self.filter.clone_pose(clone);
                self.stereo = StereoStage::Idle;
                let heading_known = self.heading_known();
                let fused = self.vo.finished(
                    clone,
                    result,
                    heading_known,
                    &mut self.filter,
                    &mut self.diag,
                    &mut self.cal,
                );
                self.after_vo(fused);
                if self.start_map(frame, pose) {
                    return (quantum.max(1), false);
                }
                (quantum.max(1), true)
            }
        }
    }

    /// The EKF heading has had its first sun update, or the drive has no sun sensor (the
    /// VO-only trajectory is anchored only then).
    fn heading_known(&self) -> bool {
        self.filter.ekf_config().sun.is_none() || self.sun.counters().sun_applied > 0
    }

    /// After a VO update: a fused pose ends the kinematic aiding's rejection streak; a filter
    /// fault it raised latches the safe mode.
    fn after_vo(&mut self, fused: bool) {
        if fused {
            self.kin.vo_fused();
        }
        self.latch_safe();
    }

    /// The goal-directed navigation's view of the rest of the navigator for one step.
    fn goal_ctx(&mut self) -> (&mut super::GoalNav, GoalCtx<'_>) {
        (
            &mut self.goal,
            GoalCtx {
                filter: &mut self.filter,
                drive: &mut self.drive,
                stage: &mut self.stereo,
                key_clone: self.vo.key_clone(),
                calibration: &self.calibration,
                mode: None,
            },
        )
    }

    /// Background: start a hazard map on `frame` taken at `pose` (rotation `R -> N`, position
    /// in `N`, from the capture clone) when one is due. Returns true when it runs.
    #[inline(never)]
    fn start_map(&mut self, frame: &StereoFrame, pose: Option<(Quat, Vec3)>) -> bool {
        let (goal, mut ctx) = self.goal_ctx();
        goal.start_map(frame, pose, &mut ctx)
    }

    #[inline(never)]
    fn map_step(&mut self, frame: &StereoFrame, items: u32, quantum: u32) -> (u32, bool) {
        let (goal, mut ctx) = self.goal_ctx();
        let step = goal.map_step(frame, items, quantum, &mut ctx);
        let request = ctx.mode;
        self.apply(request);
        step
    }

    #[inline(never)]
    fn loc_step(&mut self, quantum: u32) -> (u32, bool) {
        let (goal, mut ctx) = self.goal_ctx();
        goal.loc_step(quantum, &mut ctx)
    }

    /// True when a replan of the day's targets waits for the background.
    pub fn mission_replan_due(&self) -> bool {
        self.goal.mission_replan_due(&self.filter)
    }

    /// Background: the replan of the day's targets ([`super::GoalNav::mission_background`]).
    /// Returns the work units used (one slice).
    pub fn mission_background(&mut self, quantum: u32) -> u32 {
        let (goal, mut ctx) = self.goal_ctx();
        let used = goal.mission_background(quantum, &mut ctx);
        let request = ctx.mode;
        self.apply(request);
        used
    }

    /// The storage of terrain-map localization (about 82 KB; external RAM on the rover CPU).
    /// Without it, an enabled localization is refused by [`Self::start_vo`] (counted).
    pub fn provide_localization_memory(&mut self, store: &'static mut LocNav) {
        self.goal.provide_localization_memory(store);
    }

    /// Ground command: the global map of terrain-map localization
    /// ([`super::GoalNav::uplink_global_map`]). `None` when localization is off.
    pub fn uplink_global_map(&mut self, centre_m: [f64; 2], points: &[[f64; 2]]) -> Option<usize> {
        self.goal.uplink_global_map(centre_m, points)
    }

    /// Ground command: the day's targets ([`super::GoalNav::uplink_targets`]).
    pub fn uplink_targets(
        &mut self,
        targets: &[crate::sequencer::Target],
        model: crate::sequencer::ResourceModel,
        budget: MissionBudget,
    ) -> Result<(), MissionError> {
        self.goal.uplink_targets(targets, model, budget)
    }
}

#[cfg(test)]
impl Navigator {
    /// A VO relative pose `raw` between VO's keyframe and the pending capture, fused as at the
    /// end of a VO update (tests of the VO gate and the late update).
    pub(super) fn vo_fuse(&mut self, raw: &crate::types::RelativePose) {
        let heading_known = self.heading_known();
        let fused = self.vo.fuse(
            raw,
            heading_known,
            &mut self.filter,
            &mut self.diag,
            &mut self.cal,
        );
        self.after_vo(fused);
    }
}
