//! # Navigation: estimator, odometry, visual odometry and guidance wired together
//!
//! [`Navigator`] owns the error-state EKF, the kinematic odometry, the visual odometry pipeline
//! and the path follower, and runs them from the flight tasks (H04 sec. 4-5, H05 sec. IV-V):
//!
//! - **RG1** [`Navigator::propagate`]: while aligning, the IMU samples of the stationary rover
//!   are averaged (tilt from the specific force, gyro bias from the rate); afterwards each checked
//!   sample propagates the EKF (eq. 26-27).
//! - **RG2** [`Navigator::kinematic_cycle`]: the joint reading extends the kinematic interval; the
//!   interval's [`RelativePose`] (eq. 15, 5 dof) is tested by the Mahalanobis gate (eq. 46) and
//!   fused when accepted; when rejected, the slip vector is EKF minus kinematics (minus the
//!   residual). The interval starts at an EKF clone and ends at the current state.
//!   [`Navigator::guidance_cycle`] then runs guidance (eq. 47-49) on the EKF pose and the slip
//!   vector, and inverse kinematics (eq. 16-25) gives the motor command.
//! - **RG3** [`Navigator::capture_started`]: the stereo capture time is cloned (eq. 41).
//! - **background** [`Navigator::vo_start`], [`Navigator::vo_step`]: VO runs in the frames'
//!   slack, work items up to a cost quantum per frame; its relative pose between the previous
//!   and the current capture clone is applied at capture time by a replay of the recorded
//!   filter operations ([`Navigator::replay_step`], 16 operations per frame), however many
//!   frames later it ends.
//! - **RG4** [`Navigator::sun`]: the sun-sensor heading update (RB sec. 5.1).
//!
//! Fallbacks: no IMU for [`NavConfig::imu_timeout_frames`] or no joints for
//! [`NavConfig::joints_timeout_cycles`] stops the rover until the sensor returns; a VO failure
//! restarts VO at the next capture, and when no VO update was fused for
//! [`NavConfig::vo_timeout_cycles`] the kinematic intervals are fused without the gate (wheel
//! and IMU odometry: slip is then unobservable and not compensated); an EKF covariance fault
//! latches [`NavMode::Safed`] (rover stopped, ground action needed).
//!
//! With [`NavConfig::slip_compensation`] off the rover navigates as one without slip
//! compensation (H05 Fig. 9, "without compensation"): guidance steers on the kinematic dead
//! reckoning ([`Navigator::kin3d`]: wheel odometry with the IMU attitude) and the slip vector
//! is zero. The EKF, gate and VO still run and are reported, so the downhill bias between the
//! VO-aided estimate and the kinematic pose is visible.

use crate::estimation::{
    CloneHandle, CoreCov, Ekf, EkfConfig, EstError, NominalState, Recorder, ReplayProgress,
};
use crate::guidance::{
    Guidance, GuidanceCommand, GuidanceConfig, GuidanceError, Path, Point2, Pose2, SlipVector,
};
use crate::kinematics::{
    inverse_kinematics, max_speed_scale, planar_pose_increment, wheel_contact_points,
    KinematicOdometry, KinematicsError, OdometryConfig, RoverGeometry, SuspensionState,
    VehicleCommand, ROCKY8,
};
use crate::types::{Quat, RelativePose, Vec3};
use crate::vo::{Progress, VisualOdometry, VoConfig, VoError, VoOutput};
use rover_hal::{
    ImuSample, JointState, MobilityCommand, StereoCalibration, StereoFrame, SunReading,
};

/// Waypoint capacity of the path.
pub const MAX_WAYPOINTS: usize = 32;
/// Feature capacity of the visual odometry.
pub const VO_FEATURES: usize = 150;

/// Navigation settings (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavConfig {
    /// Rover geometry for kinematics (one source of truth: [`ROCKY8`]).
    pub geometry: RoverGeometry,
    /// Start position of the rover reference point in `N` (north, east, down), m, from the
    /// ground's localisation.
    pub initial_position_n_m: [f64; 3],
    /// Start heading (yaw from north, positive towards east), rad.
    pub initial_yaw_rad: f64,
    /// 1-sigma uncertainty of the start heading, rad.
    pub initial_yaw_sigma_rad: f64,
    /// 1-sigma uncertainty of the start position, m per axis.
    pub initial_position_sigma_m: f64,
    /// IMU samples averaged at rest before the EKF starts (tilt and gyro bias alignment).
    pub align_samples: u32,
    /// EKF settings (IMU noise, gravity, sun direction in `N`).
    pub ekf: EkfConfig,
    /// Initial 1-sigma of the gyro bias after alignment, rad/s.
    pub gyro_bias_sigma_rad_s: f64,
    /// Initial 1-sigma of the accelerometer bias, m/s^2.
    pub accel_bias_sigma_m_s2: f64,
    /// Kinematic odometry noise model.
    pub odometry: OdometryConfig,
    /// Visual odometry tuning.
    pub vo: VoConfig,
    /// Run visual odometry on stereo captures.
    pub vo_enabled: bool,
    /// A VO relative pose whose Mahalanobis distance `d_m^2` exceeds this is counted in
    /// [`NavCounters::vo_large_d2`] (it is still fused: VO rejects its own outliers and is the
    /// measurement that corrects slip).
    pub vo_warn_d2: f64,
    /// Slip compensation: guidance on the EKF pose with the slip vector (on) or on kinematic
    /// dead reckoning without slip vector (off); see the module doc.
    pub slip_compensation: bool,
    /// Slip hold: after a kinematic interval is rejected, the next intervals are not fused for
    /// this many RG2 cycles even when the gate accepts them (a slipping rover produces some
    /// intervals whose slip is within the noise; fusing them would teach the filter the crab
    /// angle as a heading error). The slip vector still comes from their residual.
    pub slip_hold_cycles: u32,
    /// VO fallback: when no VO update was fused for this many RG2 cycles (VO failing, camera
    /// lost, or VO off), kinematic intervals are fused without the gate, since without VO the
    /// slip cannot be measured and the EKF would otherwise run on the IMU alone.
    pub vo_timeout_cycles: u32,
    /// Slip allowance of the VO-loss fallback, as a fraction of the kinematic step.
    pub vo_loss_slip_fraction: f64,
    /// Recorded filter operations replayed per background slice when a VO result is applied at
    /// its capture time ([`Recorder::replay_step`]): bounds the slice (an IMU propagation is
    /// about 10 000 instructions on the rover CPU, an update up to 95 000) while the replay
    /// still catches up within a few dozen frames.
    pub replay_ops_per_slice: u16,
    /// Guidance settings.
    pub guidance: GuidanceConfig,
    /// Minor frames without a checked IMU sample after which the rover is stopped.
    pub imu_timeout_frames: u32,
    /// RG2 cycles without a checked joint reading after which the rover is stopped.
    pub joints_timeout_cycles: u32,
    /// Below this measured wheel rate (rad/s, every wheel) with a zero command the rover is
    /// stopped and a zero-velocity update is applied.
    pub stopped_wheel_rate_rad_s: f64,
}

impl NavConfig {
    /// Defaults for Rocky 8 starting at `position` (m, `N`) with heading `yaw_rad`.
    pub fn rocky8(position: [f64; 3], yaw_rad: f64) -> Self {
        let xy = match wheel_contact_points(&ROCKY8, &SuspensionState::default()) {
            Ok(p) => p.map(|c| [c.x, c.y]),
            Err(_) => [[0.0; 2]; 6],
        };
        Self {
            geometry: ROCKY8,
            initial_position_n_m: position,
            initial_yaw_rad: yaw_rad,
            initial_yaw_sigma_rad: 0.01,
            initial_position_sigma_m: 0.001,
            align_samples: 400,
            ekf: EkfConfig::default(),
            gyro_bias_sigma_rad_s: 2.0e-4,
            accel_bias_sigma_m_s2: 1.0e-2,
            // Contact-angle kinematic estimation (V99 sec. 6) with the gyro rotation of each
            // joint step and the angles taken relative to their mean: on the simulator's truth
            // kinematics without slip it cuts the 3D odometry's distance error on `undulating`
            // from 1.31 % (contacts under the axles) to 0.32 % (`docs/kinematics.md`).
            odometry: OdometryConfig {
                contact_angles: true,
                ..OdometryConfig::default()
            },
            // The EKF prior predicts each feature within a few pixels over a 1 s step, so the
            // tracking window is 8 px, not the stand-alone default of 24 px (9x less work), and
            // the stereo search of a tracked feature covers +-8 px around the disparity of the
            // predicted point instead of all 128 disparities.
            vo: VoConfig {
                search_radius_px: 8,
                track_disparity_margin_px: 8,
                ..VoConfig::default()
            },
            vo_enabled: true,
            vo_warn_d2: 1.0e3,
            slip_compensation: true,
            slip_hold_cycles: 20,
            vo_timeout_cycles: 60,
            vo_loss_slip_fraction: 0.3,
            replay_ops_per_slice: 16,
            guidance: GuidanceConfig::rocky8(xy),
            imu_timeout_frames: 20,
            joints_timeout_cycles: 10,
            stopped_wheel_rate_rad_s: 0.01,
        }
    }
}

/// What the navigator is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum NavMode {
    /// Averaging IMU samples at rest; the rover is held stopped.
    #[default]
    Aligning,
    /// Following the path.
    Driving,
    /// Goal reached; stopped, zero-velocity updates.
    Arrived,
    /// Estimator fault latched; stopped until the ground resets the flight software.
    Safed,
}

/// A pose estimate in `N`: position (m) and attitude (`R` to `N`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseEstimate {
    /// Position of the rover reference point, m, `N`.
    pub p_n: Vec3,
    /// Attitude, rotates `R` vectors into `N`.
    pub q_nr: Quat,
}

impl PoseEstimate {
    fn identity() -> Self {
        Self {
            p_n: Vec3::zeros(),
            q_nr: Quat::identity(),
        }
    }
}

/// Counters of the navigation functions (telemetry and the simulator's summary).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct NavCounters {
    /// Kinematic intervals tested by the gate (eq. 46).
    pub kin_tested: u32,
    /// Of those, rejected (slip detected).
    pub kin_rejected: u32,
    /// Accepted by the gate but not fused because slip was detected within the hold time.
    pub kin_held: u32,
    /// Fused without the gate because VO had not updated for the VO timeout (fallback).
    pub kin_ungated: u32,
    /// Kinematic intervals that could not be formed (odometry or clone error).
    pub kin_errors: u32,
    /// Zero-velocity updates applied.
    pub zupts: u32,
    /// VO updates that delivered a relative pose.
    pub vo_updates: u32,
    /// VO updates fused into the EKF.
    pub vo_fused: u32,
    /// Of those, applied at capture time and replayed to the present ([`Recorder`]).
    pub vo_replayed: u32,
    /// Of those, lost because the recording overflowed before the sliced replay caught up.
    pub vo_replay_lost: u32,
    /// VO attempts that failed (after the first keyframe).
    pub vo_failures: u32,
    /// VO relative poses fused with `d_m^2 > vo_warn_d2` (the estimate had drifted).
    pub vo_large_d2: u32,
    /// Captures skipped because VO was still busy or no clone slot was free.
    pub captures_skipped: u32,
    /// Sun updates applied.
    pub sun_applied: u32,
    /// Sun readings refused (gate, skew, not in view).
    pub sun_refused: u32,
    /// EKF errors on propagation or update (other than the ones counted above).
    pub ekf_errors: u32,
    /// Guidance or inverse-kinematics failures (the rover was stopped for that cycle).
    pub command_errors: u32,
    /// Cycles the rover was held stopped because a sensor was lost.
    pub sensor_holds: u32,
}

/// Result of the last kinematic interval.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GateStatus {
    /// Mahalanobis squared distance (eq. 46).
    pub d2: f64,
    /// Accepted (no slip detected).
    pub accepted: bool,
    /// Degrees of freedom.
    pub dof: u8,
}

/// Sums of the stationary IMU samples during alignment.
#[derive(Debug, Clone, Copy, Default)]
struct Alignment {
    count: u32,
    gyro: [f64; 3],
    accel: [f64; 3],
}

/// Where the stereo pipeline is.
#[derive(Debug, Clone, Copy, PartialEq)]
enum StereoStage {
    /// Nothing pending.
    Idle,
    /// Capture triggered at `t_us` and cloned; waiting for the camera.
    Capturing { clone: Option<CloneHandle> },
    /// VO running on the frame of `clone`; `items` work items done so far.
    Processing {
        clone: Option<CloneHandle>,
        items: u32,
    },
}

/// The navigation state of the flight software (about 110 KB, all inline).
pub struct Navigator {
    config: NavConfig,
    mode: NavMode,
    align: Alignment,
    /// The filter; meaningful once `ekf_running` (alignment done). Kept inline and reset in
    /// place so that starting it does not move 9 KB through the stack.
    ekf: Ekf,
    ekf_running: bool,
    odometry: KinematicOdometry,
    interval: Option<CloneHandle>,
    last_joints: Option<JointState>,
    /// Body rotation since the last joint reading the odometry took, integrated from the
    /// bias-corrected gyro samples (the gyro input of the contact-angle estimator, V99 sec. 6);
    /// `None` until an interval has started or after a gap in the IMU samples.
    gyro_since_joints: Option<crate::types::Quat>,
    /// Time stamp of the last IMU sample integrated into `gyro_since_joints`, us.
    gyro_t_us: Option<u64>,
    vo: Option<VisualOdometry<VO_FEATURES>>,
    calibration: StereoCalibration,
    key_clone: Option<CloneHandle>,
    /// Filter operations since the pending capture, for the exact late VO update.
    recorder: Recorder,
    stereo: StereoStage,
    guidance: Option<Guidance<MAX_WAYPOINTS>>,
    slip: SlipVector,
    gate: GateStatus,
    command: VehicleCommand,
    last_guidance: Option<GuidanceCommand>,
    kin3d: PoseEstimate,
    kin2d: [f64; 3],
    vo_pose: Option<PoseEstimate>,
    vo_quality: Option<VoOutput>,
    counters: NavCounters,
    frames_without_imu: u32,
    cycles_without_joints: u32,
    cycles_since_reject: u32,
    cycles_since_vo: u32,
}

/// Why the navigator could not be built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NavError {
    /// The path was refused (empty, non-finite, repeated waypoints, too many).
    Path(crate::guidance::PathError),
    /// The guidance settings were refused.
    Guidance(GuidanceError),
    /// A non-finite start pose or setting.
    BadConfig,
}

fn yaw_of(q: &Quat) -> f64 {
    let c = q.to_rotation_matrix().into_inner();
    libm::atan2(c[(1, 0)], c[(0, 0)])
}

impl Navigator {
    /// A navigator for `path` (waypoints north, east in `N`, m) with `config` and the camera
    /// `calibration`. VO is not built here (see [`Self::start_vo`]).
    pub fn new(
        config: NavConfig,
        path: &[Point2],
        calibration: &StereoCalibration,
    ) -> Result<Self, NavError> {
        let start = [
            config.initial_position_n_m[0],
            config.initial_position_n_m[1],
            config.initial_position_n_m[2],
            config.initial_yaw_rad,
            config.initial_yaw_sigma_rad,
            config.initial_position_sigma_m,
        ];
        if start.iter().any(|v| !v.is_finite()) || config.align_samples == 0 {
            return Err(NavError::BadConfig);
        }
        let path = Path::<MAX_WAYPOINTS>::new(path).map_err(NavError::Path)?;
        let ekf = Ekf::new(
            config.ekf,
            NominalState::at_rest(0),
            &(CoreCov::identity() * 1.0e-6),
        )
        .map_err(|_| NavError::BadConfig)?;
        let guidance = Guidance::new(path, config.guidance).map_err(NavError::Guidance)?;
        let counters = NavCounters::default();
        let p0 = Vec3::from(config.initial_position_n_m);
        let q0 = Quat::from_euler_angles(0.0, 0.0, config.initial_yaw_rad);
        Ok(Self {
            config,
            mode: NavMode::Aligning,
            align: Alignment::default(),
            ekf,
            ekf_running: false,
            odometry: KinematicOdometry::new(config.geometry, config.odometry),
            interval: None,
            last_joints: None,
            gyro_since_joints: None,
            gyro_t_us: None,
            vo: None,
            calibration: *calibration,
            key_clone: None,
            recorder: Recorder::new(),
            stereo: StereoStage::Idle,
            guidance: Some(guidance),
            slip: SlipVector::default(),
            gate: GateStatus::default(),
            command: VehicleCommand::default(),
            last_guidance: None,
            kin3d: PoseEstimate { p_n: p0, q_nr: q0 },
            kin2d: [p0.x, p0.y, config.initial_yaw_rad],
            vo_pose: None,
            vo_quality: None,
            counters,
            frames_without_imu: 0,
            cycles_without_joints: 0,
            cycles_since_reject: u32::MAX,
            cycles_since_vo: 0,
        })
    }

    /// Build the visual odometry state (about 96 KB) in place, when [`NavConfig::vo_enabled`].
    /// Call once after the navigator has reached its final location (a static on the rover
    /// CPU), so that the large state is not copied through the stack by the constructors.
    /// A calibration VO refuses leaves VO off (counted in [`NavCounters::vo_failures`]).
    pub fn start_vo(&mut self) {
        if !self.config.vo_enabled || self.vo.is_some() {
            return;
        }
        match VisualOdometry::new(self.config.vo, &self.calibration) {
            Ok(v) => self.vo = Some(v),
            Err(_) => self.counters.vo_failures = self.counters.vo_failures.saturating_add(1),
        }
    }

    /// The current mode.
    pub fn mode(&self) -> NavMode {
        self.mode
    }

    /// The EKF, once aligned.
    pub fn ekf(&self) -> Option<&Ekf> {
        self.ekf_running.then_some(&self.ekf)
    }

    /// Counters.
    pub fn counters(&self) -> &NavCounters {
        &self.counters
    }

    /// The slip vector of the last RG2 cycle (EKF minus kinematics, rover frame; zero when the
    /// gate accepted the kinematics).
    pub fn slip(&self) -> SlipVector {
        self.slip
    }

    /// The gate result of the last kinematic interval.
    pub fn gate(&self) -> GateStatus {
        self.gate
    }

    /// The rover command of the last RG2 cycle (rover frame, m/s and rad/s).
    pub fn command(&self) -> VehicleCommand {
        self.command
    }

    /// The last guidance output (carrot, cross-track projection, goal distance).
    pub fn guidance_output(&self) -> Option<&GuidanceCommand> {
        self.last_guidance.as_ref()
    }

    /// Dead reckoning with the rocker-bogie kinematic translation (eq. 15) rotated by the
    /// estimator's attitude at each interval start ("3D kinematics"), `N`.
    pub fn kin3d(&self) -> PoseEstimate {
        self.kin3d
    }

    /// Planar wheel odometry `[north m, east m, yaw rad]` with its own heading from the wheels,
    /// ignoring the suspension and the terrain ("2D kinematics").
    pub fn kin2d(&self) -> [f64; 3] {
        self.kin2d
    }

    /// The VO-only pose: VO relative poses chained from the EKF pose of the first keyframe
    /// after the start or after a VO outage; `None` before the first VO update.
    pub fn vo_pose(&self) -> Option<PoseEstimate> {
        self.vo_pose
    }

    /// The last VO output (quality figures), if any.
    pub fn vo_output(&self) -> Option<&VoOutput> {
        self.vo_quality.as_ref()
    }

    /// True when VO is running on a frame (the camera frame must stay held).
    pub fn vo_busy(&self) -> bool {
        matches!(self.stereo, StereoStage::Processing { .. })
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
        self.vo.is_some()
            && self.ekf_running
            && matches!(self.stereo, StereoStage::Idle)
            && !self.recorder.replaying()
            && self.mode != NavMode::Safed
    }

    /// True when a capture is waiting for the camera.
    pub fn capture_pending(&self) -> bool {
        matches!(self.stereo, StereoStage::Capturing { .. })
    }

    fn ekf_error(&mut self, e: EstError) {
        self.counters.ekf_errors = self.counters.ekf_errors.saturating_add(1);
        if matches!(e, EstError::Faulted | EstError::CovarianceUnhealthy { .. }) {
            self.mode = NavMode::Safed;
        }
    }

    /// RG1: one checked IMU sample (`None`: no new sample this frame).
    pub fn propagate(&mut self, sample: Option<&ImuSample>) {
        let Some(s) = sample else {
            self.frames_without_imu = self.frames_without_imu.saturating_add(1);
            return;
        };
        self.frames_without_imu = 0;
        if self.mode == NavMode::Aligning {
            self.accumulate_alignment(s);
            return;
        }
        if self.ekf_running {
            let result = self.ekf.propagate(s);
            self.recorder.propagate(s);
            if let Err(e) = result {
                self.ekf_error(e);
            }
            if self.config.odometry.contact_angles {
                self.integrate_gyro(s);
            }
        }
    }

    /// Adds one IMU sample's bias-corrected rotation to the rotation since the last joint
    /// reading. A sample that does not follow the previous one by 0 to 50 ms (a gap, time going
    /// backwards) or is not finite drops the integral: the next joint step then has no gyro
    /// input and the estimator uses the contacts alone.
    fn integrate_gyro(&mut self, s: &ImuSample) {
        let previous = self.gyro_t_us.replace(s.t_us);
        let dt_us = previous.and_then(|p| s.t_us.checked_sub(p));
        let b_g = self.ekf.state().b_g;
        let w = Vec3::new(
            s.gyro_rad_s[0] - b_g.x,
            s.gyro_rad_s[1] - b_g.y,
            s.gyro_rad_s[2] - b_g.z,
        );
        match (self.gyro_since_joints, dt_us) {
            (Some(q), Some(dt)) if dt <= 50_000 && w.iter().all(|v| v.is_finite()) => {
                let step = crate::types::Quat::from_scaled_axis(w * (dt as f64 * 1e-6));
                self.gyro_since_joints = Some(q * step);
            }
            _ => self.gyro_since_joints = None,
        }
    }

    fn accumulate_alignment(&mut self, s: &ImuSample) {
        let a = &mut self.align;
        a.count = a.count.saturating_add(1);
        for k in 0..3 {
            a.gyro[k] += s.gyro_rad_s[k];
            a.accel[k] += s.accel_m_s2[k];
        }
        if a.count < self.config.align_samples {
            return;
        }
        let n = f64::from(a.count);
        let f = Vec3::new(a.accel[0] / n, a.accel[1] / n, a.accel[2] / n);
        let g = f.norm();
        if !(g.is_finite() && g > 0.1) {
            // No usable gravity reference: start again.
            self.align = Alignment::default();
            return;
        }
        // At rest f = -C' g_N: the rover-frame down axis is -f / |f| (eq. 26 with v = 0).
        let pitch = libm::asin((f.x / g).clamp(-1.0, 1.0));
        let roll = libm::atan2(-f.y, -f.z);
        let q = Quat::from_euler_angles(roll, pitch, self.config.initial_yaw_rad);
        let x0 = NominalState {
            t_us: s.t_us,
            q_nr: q,
            b_g: Vec3::new(a.gyro[0] / n, a.gyro[1] / n, a.gyro[2] / n),
            v_n: Vec3::zeros(),
            b_a: Vec3::zeros(),
            p_n: Vec3::from(self.config.initial_position_n_m),
        };
        let c = &self.config;
        let tilt_sigma = c.accel_bias_sigma_m_s2 / g;
        let gyro_avg_sigma = c.ekf.imu_noise.gyro_rad_s_sqrt_hz * libm::sqrt(200.0 / n) + 1.0e-6;
        let mut p0 = CoreCov::zeros();
        let diag = [
            tilt_sigma,
            tilt_sigma,
            c.initial_yaw_sigma_rad,
            gyro_avg_sigma,
            gyro_avg_sigma,
            gyro_avg_sigma,
            c.ekf.zupt_sigma_m_s,
            c.ekf.zupt_sigma_m_s,
            c.ekf.zupt_sigma_m_s,
            c.accel_bias_sigma_m_s2,
            c.accel_bias_sigma_m_s2,
            c.accel_bias_sigma_m_s2,
            c.initial_position_sigma_m,
            c.initial_position_sigma_m,
            c.initial_position_sigma_m,
        ];
        for (i, s) in diag.iter().enumerate() {
            p0[(i, i)] = s * s;
        }
        match self.ekf.reset(x0, &p0) {
            Ok(()) => {
                self.kin3d = PoseEstimate {
                    p_n: x0.p_n,
                    q_nr: x0.q_nr,
                };
                self.ekf_running = true;
                self.mode = NavMode::Driving;
            }
            Err(e) => {
                self.align = Alignment::default();
                self.ekf_error(e);
            }
        }
    }

    /// RG2: one checked joint reading (`None`: none this cycle). Kinematic interval, gate,
    /// fusion or slip vector, dead reckoning; zero-velocity update when stopped.
    pub fn kinematic_cycle(&mut self, joints: Option<&JointState>) {
        let Some(j) = joints else {
            self.cycles_without_joints = self.cycles_without_joints.saturating_add(1);
            return;
        };
        self.cycles_without_joints = 0;
        let previous = self.last_joints.replace(*j);
        if let Some(prev) = previous {
            if let Ok([dx, dy, dyaw]) = planar_pose_increment(&self.config.geometry, &prev, j) {
                let yaw = self.kin2d[2] + 0.5 * dyaw;
                let (s, c) = (libm::sin(yaw), libm::cos(yaw));
                self.kin2d[0] += dx * c - dy * s;
                self.kin2d[1] += dx * s + dy * c;
                self.kin2d[2] = crate::guidance::wrap_pi(self.kin2d[2] + dyaw);
            }
        }
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        let t_us = ekf.time_us();
        let Some(start) = self.interval else {
            self.restart_interval(j, t_us);
            return;
        };
        // Body rotation over the joint step from the gyro, in R at the step start.
        let gyro = self
            .gyro_since_joints
            .replace(crate::types::Quat::identity())
            .map(|q| crate::estimation::state::log_quat(&q));
        let pose = self
            .odometry
            .update_with_gyro(j, gyro)
            .and_then(|()| self.odometry.take());
        let mut rp = match pose {
            Ok(rp) => rp,
            Err(KinematicsError::TimeNotAdvancing) => return,
            Err(_) => {
                self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
                self.release(Some(start));
                self.interval = None;
                self.restart_interval(j, t_us);
                return;
            }
        };
        if start.t_us() == t_us {
            // No IMU time has passed: keep the interval open.
            return;
        }
        // The interval is labelled with the EKF times of its ends (the joint reading and the
        // IMU sample of a frame carry the same time stamp on this rover).
        rp.t0_us = start.t_us();
        rp.t1_us = t_us;
        if let Ok((q0, _)) = ekf.clone_pose(start) {
            self.kin3d.p_n += q0.to_rotation_matrix() * rp.trans_0_1_m;
            self.kin3d.q_nr = ekf.state().q_nr;
        }
        self.cycles_since_vo = self.cycles_since_vo.saturating_add(1);
        let vo_lost = self.cycles_since_vo > self.config.vo_timeout_cycles;
        let holding = self.cycles_since_reject < self.config.slip_hold_cycles;
        let result = if vo_lost {
            self.counters.kin_ungated = self.counters.kin_ungated.saturating_add(1);
            // Without VO the slip is unobservable: the kinematics is fused without the gate but
            // with a slip allowance (`vo_loss_slip_fraction` of the step on x, y and yaw), so
            // that slip is not learnt as a heading error; and since nothing else observes the
            // vertical, with the ground vehicle's constraint that it does not move along its
            // own z axis (1-sigma 20 % of the step plus 0.5 mm; H04 sec. 3 leaves it unobserved).
            let step = rp.trans_0_1_m.norm();
            let yaw = libm::fabs(crate::estimation::state::log_quat(&rp.rot_0_1).z);
            let f = self.config.vo_loss_slip_fraction;
            let sigma_z = 0.2 * step + 5.0e-4;
            if let Some(o) = rp.observed.get_mut(5) {
                *o = true;
            }
            rp.covariance[(5, 5)] += sigma_z * sigma_z;
            rp.covariance[(3, 3)] += (f * step) * (f * step);
            rp.covariance[(4, 4)] += (f * step) * (f * step);
            rp.covariance[(2, 2)] += (f * yaw) * (f * yaw) + 1.0e-8;
            self.recorder.relative_pose(&rp, false);
            ekf.update_relative_pose(&rp, false)
        } else if holding {
            ekf.gate_relative_pose(&rp)
        } else {
            self.recorder.relative_pose(&rp, true);
            ekf.update_relative_pose(&rp, true)
        };
        match result {
            Ok(d) => {
                self.counters.kin_tested = self.counters.kin_tested.saturating_add(1);
                self.gate = GateStatus {
                    d2: d.d2,
                    accepted: d.accepted,
                    dof: d.dof as u8,
                };
                if d.accepted {
                    self.cycles_since_reject = self.cycles_since_reject.saturating_add(1);
                } else {
                    self.counters.kin_rejected = self.counters.kin_rejected.saturating_add(1);
                    self.cycles_since_reject = 0;
                }
                if d.applied {
                    self.slip = SlipVector::default();
                } else {
                    if d.accepted {
                        self.counters.kin_held = self.counters.kin_held.saturating_add(1);
                    }
                    // Slip = EKF minus kinematics = -(measured - predicted), rover frame R0.
                    self.slip = SlipVector {
                        x_m: -d.residual[3],
                        y_m: -d.residual[4],
                        phi_rad: -d.residual[2],
                    };
                }
            }
            Err(e) => {
                self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
                self.ekf_error(e);
            }
        }
        if self.is_stopped(j) {
            if let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) {
                let result = ekf.update_zero_velocity(t_us);
                self.recorder.zero_velocity(t_us);
                match result {
                    Ok(()) => self.counters.zupts = self.counters.zupts.saturating_add(1),
                    Err(e) => self.ekf_error(e),
                }
            }
        }
        self.release(Some(start));
        self.interval = None;
        if let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) {
            let result = ekf.clone_at(t_us);
            self.recorder.clone_at(t_us);
            match result {
                Ok(h) => self.interval = Some(h),
                Err(_) => {
                    self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
                }
            }
        }
    }

    fn restart_interval(&mut self, j: &JointState, t_us: u64) {
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        if self.odometry.start(j).is_err() {
            self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
            return;
        }
        self.gyro_since_joints = Some(crate::types::Quat::identity());
        let result = ekf.clone_at(t_us);
        self.recorder.clone_at(t_us);
        match result {
            Ok(h) => self.interval = Some(h),
            Err(_) => self.counters.kin_errors = self.counters.kin_errors.saturating_add(1),
        }
    }

    fn is_stopped(&self, j: &JointState) -> bool {
        let commanded_zero = self.command.x_dot_m_s == 0.0
            && self.command.y_dot_m_s == 0.0
            && self.command.yaw_rate_rad_s == 0.0;
        commanded_zero
            && j.drive_rate_rad_s
                .iter()
                .all(|r| libm::fabs(*r) < self.config.stopped_wheel_rate_rad_s)
    }

    fn release(&mut self, handle: Option<CloneHandle>) {
        if let (Some(h), Some(ekf)) = (handle, self.ekf_running.then_some(&mut self.ekf)) {
            self.recorder.release(h.t_us());
            if ekf.release(h).is_err() {
                self.counters.ekf_errors = self.counters.ekf_errors.saturating_add(1);
            }
        }
    }

    /// RG2, after [`Self::kinematic_cycle`]: guidance and inverse kinematics. Returns the motor
    /// command, or `None` when the rover must be stopped (aligning, arrived, safed, a sensor
    /// lost, or a guidance/kinematics failure).
    pub fn guidance_cycle(&mut self) -> Option<MobilityCommand> {
        self.command = VehicleCommand::default();
        if self.mode != NavMode::Driving {
            return None;
        }
        if self.frames_without_imu >= self.config.imu_timeout_frames
            || self.cycles_without_joints >= self.config.joints_timeout_cycles
        {
            self.counters.sensor_holds = self.counters.sensor_holds.saturating_add(1);
            return None;
        }
        let (ekf, guidance, joints) = match (
            self.ekf_running.then_some(&self.ekf),
            self.guidance.as_mut(),
            &self.last_joints,
        ) {
            (Some(e), Some(g), Some(j)) => (e, g, *j),
            _ => return None,
        };
        let (nav_pose, slip) = if self.config.slip_compensation {
            let x = ekf.state();
            (
                PoseEstimate {
                    p_n: x.p_n,
                    q_nr: x.q_nr,
                },
                self.slip,
            )
        } else {
            (self.kin3d, SlipVector::default())
        };
        let pose = Pose2 {
            x_m: nav_pose.p_n.x,
            y_m: nav_pose.p_n.y,
            phi_rad: yaw_of(&nav_pose.q_nr),
        };
        let out = match guidance.step(pose, slip) {
            Ok(o) => o,
            Err(_) => {
                self.counters.command_errors = self.counters.command_errors.saturating_add(1);
                return None;
            }
        };
        self.last_guidance = Some(out);
        if out.goal_reached {
            self.mode = NavMode::Arrived;
            return None;
        }
        let mut cmd = VehicleCommand {
            x_dot_m_s: out.x_dot_m_s,
            y_dot_m_s: out.y_dot_m_s,
            yaw_rate_rad_s: out.phi_dot_rad_s,
        };
        let geometry = &self.config.geometry;
        let state = SuspensionState::from_joints(&joints);
        let limit = geometry.limits.wheel_rate_rad_s;
        match max_speed_scale(geometry, &state, &cmd, limit) {
            Ok(k) if k < 1.0 => {
                cmd.x_dot_m_s *= k;
                cmd.y_dot_m_s *= k;
                cmd.yaw_rate_rad_s *= k;
            }
            Ok(_) => {}
            Err(_) => {
                self.counters.command_errors = self.counters.command_errors.saturating_add(1);
                return None;
            }
        }
        match inverse_kinematics(geometry, &state, &cmd) {
            Ok(solution) => {
                self.command = cmd;
                Some(solution.command)
            }
            Err(_) => {
                self.counters.command_errors = self.counters.command_errors.saturating_add(1);
                None
            }
        }
    }

    /// RG3: a capture was triggered at `t_us` (camera time base = IMU time base). Clones the
    /// state there (eq. 41). Returns false when the capture cannot be used (no clone slot).
    pub fn capture_started(&mut self, t_us: u64) -> bool {
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return false;
        };
        match ekf.clone_at(t_us) {
            Ok(h) => {
                self.stereo = StereoStage::Capturing { clone: Some(h) };
                // Record from here on, so that the VO result can be applied at capture time
                // exactly (replay) however late it arrives.
                self.recorder.begin(&self.ekf);
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
            StereoStage::Idle => None,
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
            self.capture_lost();
            return false;
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

    fn vo_keyframe_lost(&mut self) {
        if let Some(vo) = self.vo.as_mut() {
            vo.reset();
        }
        let key = self.key_clone.take();
        self.release(key);
    }

    /// The EKF's relative pose between two clones (the VO motion prior), in the
    /// [`RelativePose`] convention.
    fn ekf_relative_pose(
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
                self.vo_finished(clone, result);
                (quantum.max(1), true)
            }
        }
    }

    fn vo_finished(&mut self, capture: Option<CloneHandle>, result: Result<VoOutput, VoError>) {
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
                    None => self.vo_pose = None,
                }
            }
            Err(_) => {
                if had_key {
                    self.counters.vo_failures = self.counters.vo_failures.saturating_add(1);
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
        if keep.is_none() {
            if let Some(vo) = self.vo.as_mut() {
                // A keyframe without its clone cannot be used: rebuild at the next capture.
                vo.reset();
            }
        }
    }

    fn vo_fuse(&mut self, rp: &RelativePose) {
        let (Some(key), Some(ekf)) = (self.key_clone, self.ekf_running.then_some(&mut self.ekf))
        else {
            return;
        };
        // VO-only dead reckoning, started at the first keyframe's EKF pose.
        if self.vo_pose.is_none() {
            if let Ok((q, p)) = ekf.clone_pose(key) {
                self.vo_pose = Some(PoseEstimate { p_n: p, q_nr: q });
            }
        }
        if let Some(v) = self.vo_pose.as_mut() {
            v.p_n += v.q_nr.transform_vector(&rp.trans_0_1_m);
            v.q_nr = crate::estimation::state::renormalize(&(v.q_nr * rp.rot_0_1));
        }
        // VO is fused without the gate: it rejects its own outliers (LMedS, H04 sec. 2) and it
        // is the measurement that corrects an estimate slip has pulled away; a large distance
        // is counted for the ground.
        // Applied at capture time and replayed to now when the recording since the capture is
        // complete (exact); otherwise at the capture clones (exact there, first order now). The
        // replay runs in background slices (replay_step): the live filter takes the result when
        // the replay has caught up.
        let result = if self.recorder.active() {
            self.counters.vo_replayed = self.counters.vo_replayed.saturating_add(1);
            self.recorder.start_late(rp, false)
        } else {
            self.recorder.end();
            ekf.update_relative_pose(rp, false)
        };
        match result {
            Ok(d) => {
                self.counters.vo_fused = self.counters.vo_fused.saturating_add(1);
                if d.d2 > self.config.vo_warn_d2 {
                    self.counters.vo_large_d2 = self.counters.vo_large_d2.saturating_add(1);
                }
                self.cycles_since_vo = 0;
            }
            Err(e) => self.ekf_error(e),
        }
    }

    /// RG4: one checked sun reading with the sun in view.
    pub fn sun(&mut self, reading: &SunReading) {
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        let result = ekf.update_sun(reading);
        self.recorder.sun(reading);
        match result {
            Ok(u) if u.applied => {
                self.counters.sun_applied = self.counters.sun_applied.saturating_add(1)
            }
            Ok(_) | Err(_) => {
                self.counters.sun_refused = self.counters.sun_refused.saturating_add(1)
            }
        }
    }

    /// The EKF pose, or the configured start pose before alignment.
    pub fn pose(&self) -> PoseEstimate {
        match self.ekf_running.then_some(&self.ekf) {
            Some(e) => PoseEstimate {
                p_n: e.state().p_n,
                q_nr: e.state().q_nr,
            },
            None => PoseEstimate {
                p_n: Vec3::from(self.config.initial_position_n_m),
                q_nr: Quat::from_euler_angles(0.0, 0.0, self.config.initial_yaw_rad),
            },
        }
    }

    /// The configuration.
    pub fn config(&self) -> &NavConfig {
        &self.config
    }
}

impl Default for PoseEstimate {
    fn default() -> Self {
        Self::identity()
    }
}
