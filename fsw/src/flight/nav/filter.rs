//! # NavFilter: the navigator's error-state EKF with its replay recorder and health
//!
//! The one owner of the EKF ([`crate::estimation::Ekf`], H04 sec. 4, App. B; RB) and of the
//! [`Recorder`] of the filter operations since the last stereo capture (the exact late VO
//! update, H04 sec. 4). Every operation that changes the live filter is also recorded, here and
//! only here, so that a VO result applied at its capture time replays exactly what the live
//! filter did since ([`NavFilter::replay_slice`]).
//!
//! The aiding components ([`super::KinAiding`], [`super::VoAiding`], [`super::SunAiding`],
//! [`super::Aligner`], the goal-directed navigation) take the filter as an argument of their
//! step functions (PX4 EKF2's aid-source shape, `update(&mut Ekf, ...)`).
//!
//! **Health.** An estimator error returned by an update is counted ([`FilterCounters`]) and kept
//! ([`NavFilter::last_error`]); a covariance fault ([`EstError::Faulted`],
//! [`EstError::CovarianceUnhealthy`]) raises a safe request that the navigator turns into
//! [`super::NavMode::Safed`] at the end of the step that raised it
//! ([`NavFilter::take_safe_request`]).

use crate::estimation::{
    CloneHandle, CoreCov, Ekf, EkfConfig, EstError, GateDecision, NominalState, Recorder,
    ReplayProgress, SunUpdate,
};
use crate::types::{Quat, RelativePose, Vec3};
use rover_hal::{ImuSample, SunReading};

/// Settings of the filter (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterConfig {
    /// EKF settings (IMU noise, gravity, sun direction in `N`; [`EkfConfig`]).
    pub ekf: EkfConfig,
    /// Recorded filter operations replayed per background slice when a VO result is applied at
    /// its capture time ([`Recorder::replay_step`]): bounds the slice (an IMU propagation is
    /// about 10 000 instructions on the rover CPU, an update up to 95 000) while the replay
    /// still catches up within a few dozen frames.
    pub replay_ops_per_slice: u16,
}

/// Counters of the filter (telemetry: [`super::NavCounters::ekf_errors`],
/// [`super::NavCounters::vo_replay_lost`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FilterCounters {
    /// EKF errors on propagation, update, clone or release that no other counter counts.
    pub ekf_errors: u32,
    /// Late VO updates lost because the recording overflowed before the sliced replay caught up.
    pub replays_lost: u32,
    /// Re-anchorings of the filter's timeline after an IMU time-base change.
    pub time_rebases: u32,
}

/// The navigator's filter: EKF, recorder, IMU feed and health.
pub struct NavFilter {
    config: FilterConfig,
    /// The filter; meaningful once `running` (alignment done). Kept inline and reset in place
    /// so that starting it does not move 9 KB through the stack.
    ekf: Ekf,
    running: bool,
    /// Filter operations since the pending capture, for the exact late VO update.
    recorder: Recorder,
    /// Minor frames since the last checked IMU sample.
    imu_gap_frames: u32,
    counters: FilterCounters,
    last_error: Option<EstError>,
    /// A covariance fault since the navigator last asked ([`Self::take_safe_request`]).
    safe_request: bool,
}

impl NavFilter {
    /// Placeholder (the compile-time value of a static navigator before its initialisation).
    pub const EMPTY: Self = Self {
        config: FilterConfig {
            ekf: EkfConfig::EMPTY,
            replay_ops_per_slice: 0,
        },
        ekf: Ekf::EMPTY,
        running: false,
        recorder: Recorder::EMPTY,
        imu_gap_frames: 0,
        counters: FilterCounters {
            ekf_errors: 0,
            replays_lost: 0,
            time_rebases: 0,
        },
        last_error: None,
        safe_request: false,
    };

    /// Rewrites the filter in place for a new drive with `config`: not running (the alignment
    /// starts it, [`Self::start`]), nothing recorded, health cleared.
    pub fn init(&mut self, config: &FilterConfig) -> Result<(), EstError> {
        self.ekf.init(
            config.ekf,
            NominalState::at_rest(0),
            &(CoreCov::identity() * 1.0e-6),
        )?;
        self.config = *config;
        self.running = false;
        self.recorder.reset();
        self.imu_gap_frames = 0;
        self.counters = FilterCounters::default();
        self.last_error = None;
        self.safe_request = false;
        Ok(())
    }

    /// Starts the filter at `x0` with core covariance `p0` (the alignment's estimates). On an
    /// error the filter stays stopped and the caller reports it ([`Self::error`]).
    pub fn start(&mut self, x0: NominalState, p0: &CoreCov) -> Result<(), EstError> {
        self.ekf.reset(x0, p0)?;
        self.running = true;
        Ok(())
    }

    /// The EKF once running.
    pub fn running(&self) -> Option<&Ekf> {
        self.running.then_some(&self.ekf)
    }

    /// True once the alignment has started the filter.
    pub fn is_running(&self) -> bool {
        self.running
    }

    /// The nominal state (the initial placeholder before the filter runs).
    pub fn state(&self) -> &NominalState {
        self.ekf.state()
    }

    /// The EKF settings.
    pub fn ekf_config(&self) -> &EkfConfig {
        &self.config.ekf
    }

    /// The pose `(R -> N rotation, position in N m)` of a live clone.
    pub fn clone_pose(&self, clone: Option<CloneHandle>) -> Option<(Quat, Vec3)> {
        self.running().and_then(|e| e.clone_pose(clone?).ok())
    }

    /// Horizontal position 1-sigma of the EKF, m (`sqrt(P_nn + P_ee)`); 0 before alignment.
    pub fn horizontal_sigma_m(&self) -> f64 {
        match self.running() {
            Some(e) => {
                let p = e.covariance();
                let i = crate::estimation::state::I_P;
                crate::linalg::sqrt((p[(i, i)] + p[(i + 1, i + 1)]).max(0.0))
            }
            None => 0.0,
        }
    }

    /// Counters.
    pub fn counters(&self) -> FilterCounters {
        self.counters
    }

    /// The last error the EKF returned, other than the `Faulted` that every call returns after
    /// a fault: after a safe request it is the cause of the fault.
    pub fn last_error(&self) -> Option<EstError> {
        self.last_error
    }

    /// An estimator error `e`: counted and kept; a covariance fault raises the safe request.
    pub fn error(&mut self, e: EstError) {
        self.counters.ekf_errors = self.counters.ekf_errors.saturating_add(1);
        // `Faulted` only repeats that an earlier error faulted the filter: keep the cause.
        if e != EstError::Faulted || self.last_error.is_none() {
            self.last_error = Some(e);
        }
        if matches!(e, EstError::Faulted | EstError::CovarianceUnhealthy { .. }) {
            self.safe_request = true;
        }
    }

    /// Whether a covariance fault happened since the last call (the navigator latches
    /// [`super::NavMode::Safed`]).
    pub fn take_safe_request(&mut self) -> bool {
        core::mem::take(&mut self.safe_request)
    }

    /// RG1: one more minor frame without a checked IMU sample.
    pub fn imu_missing(&mut self) {
        self.imu_gap_frames = self.imu_gap_frames.saturating_add(1);
    }

    /// Minor frames since the last checked IMU sample (fault protection's sensor hold).
    pub fn imu_gap_frames(&self) -> u32 {
        self.imu_gap_frames
    }

    /// RG1: a checked IMU sample arrived (the sensor hold's count restarts).
    pub fn imu_received(&mut self) {
        self.imu_gap_frames = 0;
    }

    /// RG1: one checked IMU sample propagates the running filter (eq. 26-27) and is recorded.
    /// Returns false when the filter does not run yet.
    pub fn propagate(&mut self, s: &ImuSample) -> bool {
        if !self.running {
            return false;
        }
        let result = self.ekf.propagate(s);
        self.recorder.propagate(s);
        if let Err(e) = result {
            self.error(e);
        }
        true
    }

    /// Release the clone `handle` (recorded); a refused release is counted.
    pub fn release(&mut self, handle: Option<CloneHandle>) {
        if let (Some(h), true) = (handle, self.running) {
            self.recorder.release(h.t_us());
            if self.ekf.release(h).is_err() {
                self.counters.ekf_errors = self.counters.ekf_errors.saturating_add(1);
            }
        }
    }

    /// Clone the state at `t_us` (eq. 41), recorded. The caller counts a refusal.
    pub fn clone_recorded(&mut self, t_us: u64) -> Option<Result<CloneHandle, EstError>> {
        if !self.running {
            return None;
        }
        let result = self.ekf.clone_at(t_us);
        self.recorder.clone_at(t_us);
        Some(result)
    }

    /// Clone the state at the capture time `t_us` (eq. 41) and start recording the filter's
    /// operations from here on, so that the VO result of this capture can be applied at its
    /// time exactly however late it arrives. `None` when the filter does not run.
    pub fn clone_capture(&mut self, t_us: u64) -> Option<Result<CloneHandle, EstError>> {
        if !self.running {
            return None;
        }
        let result = self.ekf.clone_at(t_us);
        if result.is_ok() {
            self.recorder.begin(&self.ekf);
        }
        Some(result)
    }

    /// Grow the velocity (m/s) and accelerometer-bias (m/s^2) 1-sigma of the running filter
    /// ([`Ekf::inflate_velocity`]), recorded; an error is reported.
    pub fn inflate_velocity(&mut self, velocity_sigma_m_s: f64, accel_bias_sigma_m_s2: f64) {
        if !self.running {
            return;
        }
        let result = self
            .ekf
            .inflate_velocity(velocity_sigma_m_s, accel_bias_sigma_m_s2);
        self.recorder
            .inflate_velocity(velocity_sigma_m_s, accel_bias_sigma_m_s2);
        if let Err(e) = result {
            self.error(e);
        }
    }

    /// Grow the heading 1-sigma (rad, [`Ekf::inflate_heading`]), recorded; an error is
    /// reported.
    pub fn inflate_heading(&mut self, sigma_rad: f64) {
        if !self.running {
            return;
        }
        let result = self.ekf.inflate_heading(sigma_rad);
        self.recorder.inflate_heading(sigma_rad);
        if let Err(e) = result {
            self.error(e);
        }
    }

    /// Grow the horizontal position 1-sigma by `delta_m` (m, [`Ekf::inflate_position`]),
    /// recorded; an error is reported.
    pub fn inflate_position(&mut self, delta_m: f64) {
        if !self.running {
            return;
        }
        let result = self.ekf.inflate_position(delta_m);
        self.recorder.inflate_position(delta_m);
        if let Err(e) = result {
            self.error(e);
        }
    }

    /// Zero-velocity update at the filter's current time ([`Ekf::update_zero_velocity`]),
    /// recorded. Returns true when applied; an error is reported. `None`: not running.
    pub fn zero_velocity(&mut self) -> Option<bool> {
        if !self.running {
            return None;
        }
        let t_us = self.ekf.time_us();
        let result = self.ekf.update_zero_velocity(t_us);
        self.recorder.zero_velocity(t_us);
        Some(match result {
            Ok(()) => true,
            Err(e) => {
                self.error(e);
                false
            }
        })
    }

    /// Sun-sensor heading update (RB sec. 5.1, [`Ekf::update_sun`]), recorded. The caller
    /// counts the outcome. `None`: not running.
    pub fn sun(&mut self, reading: &SunReading) -> Option<Result<SunUpdate, EstError>> {
        if !self.running {
            return None;
        }
        let result = self.ekf.update_sun(reading);
        self.recorder.sun(reading);
        Some(result)
    }

    /// The live filter, for the gate tests and updates the kinematic aiding makes on it and
    /// records itself ([`Self::record_relative_pose`]); `None` when not running.
    pub fn live(&mut self) -> Option<&mut Ekf> {
        self.running.then_some(&mut self.ekf)
    }

    /// Record a relative-pose update `rp` the live filter applied (ungated in the replay).
    pub fn record_relative_pose(&mut self, rp: &RelativePose) {
        self.recorder.relative_pose(rp, false);
    }

    /// Re-anchor the filter's timeline at `t_us` after the IMU's time base changed (counted):
    /// the state and its core covariance are kept, the clones and any recording or replay
    /// dropped. Returns false when the filter does not run yet (nothing to re-anchor).
    pub fn rebase(&mut self, t_us: u64) -> bool {
        self.counters.time_rebases = self.counters.time_rebases.saturating_add(1);
        if !self.running {
            return false;
        }
        let mut x = *self.ekf.state();
        x.t_us = t_us;
        let p = self.ekf.core_covariance();
        self.recorder.end();
        if let Err(e) = self.ekf.reset(x, &p) {
            self.error(e);
        }
        true
    }

    /// True while a VO result is being replayed from its capture time in background slices.
    pub fn replaying(&self) -> bool {
        self.recorder.replaying()
    }

    /// True while the operations since a capture are being recorded.
    pub fn recording(&self) -> bool {
        self.recorder.active()
    }

    /// Drop the recording (its capture is lost or its result is not fused), unless it is being
    /// replayed.
    pub fn end_recording(&mut self) {
        if !self.recorder.replaying() {
            self.recorder.end();
        }
    }

    /// The filter a VO result of the pending capture is judged on: the recorder's snapshot at
    /// capture time while the recording is complete (the decision an instantaneous VO would
    /// have had), the live filter otherwise.
    pub fn capture_filter(&self) -> &Ekf {
        match self.recorder.snapshot().filter(|_| self.recorder.active()) {
            Some(snapshot) => snapshot,
            None => &self.ekf,
        }
    }

    /// Apply the VO relative pose `rp` (already gated): at capture time and replayed to now in
    /// background slices when the recording since the capture is complete (exact), otherwise
    /// at the capture clones of the live filter (exact there, first order now). Returns the
    /// update's decision and whether it is replayed.
    pub fn apply_vo(&mut self, rp: &RelativePose) -> (Result<GateDecision, EstError>, bool) {
        if self.recorder.active() {
            (self.recorder.start_late(rp, false), true)
        } else {
            self.recorder.end();
            (self.ekf.update_relative_pose(rp, false), false)
        }
    }

    /// Background: replays up to [`FilterConfig::replay_ops_per_slice`] recorded operations of
    /// a late VO update; when the replay has caught up the replayed filter becomes the live one
    /// (bit-identical to a one-shot replay). Returns the operations budget used (0 when no
    /// replay is in progress).
    pub fn replay_slice(&mut self) -> u32 {
        if !self.recorder.replaying() {
            return 0;
        }
        if !self.running {
            self.recorder.end();
            return 1;
        }
        let ops = self.config.replay_ops_per_slice.max(1);
        if self.recorder.replay_step(&mut self.ekf, usize::from(ops)) == ReplayProgress::Abandoned {
            self.counters.replays_lost = self.counters.replays_lost.saturating_add(1);
        }
        u32::from(ops)
    }

    /// The gate and update of an absolute pose applied at its clone (terrain-map localization,
    /// V99 sec. 5): possible only while nothing is recorded or replayed (an update there could
    /// not be replayed). `None` when not possible or refused.
    pub fn absolute_pose(
        &mut self,
        m: &crate::estimation::absolute_pose::AbsolutePose,
        gated: bool,
    ) -> Option<GateDecision> {
        let quiet = !self.recorder.active() && !self.recorder.replaying();
        if !(self.running && quiet) {
            return None;
        }
        self.ekf.update_absolute_pose(m, gated).ok()
    }
}

#[cfg(test)]
impl NavFilter {
    /// The EKF itself (tests set up its state).
    pub(crate) fn ekf_mut(&mut self) -> &mut Ekf {
        &mut self.ekf
    }

    /// Mark the filter running after a test reset its EKF by hand.
    pub(crate) fn set_running(&mut self) {
        self.running = true;
    }

    /// The recorder (tests start recordings by hand).
    pub(crate) fn recorder_mut(&mut self) -> &mut Recorder {
        &mut self.recorder
    }

    /// Start recording at the live filter (tests).
    pub(crate) fn begin_recording(&mut self) {
        self.recorder.begin(&self.ekf);
    }
}
