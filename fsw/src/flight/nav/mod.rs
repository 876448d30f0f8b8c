//! # Navigation: the navigator and the wiring of its components
//!
//! [`Navigator`] is wiring, not state: each concern is a component that owns its state,
//! settings (its slice of [`NavConfig`]), counters and status, and data crosses components
//! only through the arguments and return values of their step functions, in the order the
//! flight tasks run them (H04 sec. 4-5, H05 sec. IV-V, RB, V99):
//!
//! | component | concern | task entry |
//! |---|---|---|
//! | [`NavFilter`] | the error-state EKF, the replay recorder of the late VO update, filter health | RG1 [`Navigator::propagate`] (eq. 26-27) |
//! | [`Aligner`] | tilt, gyro bias and sun heading at rest; starts the filter | RG1 while aligning |
//! | [`KinAiding`] | eq. 15 kinematic interval, Mahalanobis slip gate (eq. 46) and its policy, slip vector, ZUPT trigger, radius scale | RG2 [`Navigator::kinematic_cycle`], RG2B [`Navigator::zero_velocity_cycle`] |
//! | [`VoAiding`] | capture policy, VO pipeline, VO gate, VO health | RG3 [`Navigator::capture_due`], background [`Navigator::vo_step`] |
//! | [`SunAiding`] | sun-sensor heading update (RB sec. 5.1) | RG4 [`Navigator::sun`] |
//! | [`Calibration`] | VO boresight and the dead reckoning's radius scale, learnt over capture intervals | RG2, RG3, background |
//! | [`Drive`] | guidance (eq. 47-49), inverse kinematics (eq. 16-25), fault protection, stop-and-go | RG2 [`Navigator::guidance_cycle`] |
//! | [`GoalNav`] | hazard maps and RoverBug (V99 sec. 4), localization (sec. 5), the day's targets (sec. 3) | RG2, RG4, background |
//! | [`Trajectories`] | diagnostic dead reckonings (kin2d, kin3d, gyro dead reckoning, VO-only) | RG1, RG2, background |
//!
//! The navigator itself keeps the mode ([`NavMode`]), the vehicle's geometry and camera
//! calibration, and the stage of the held stereo frame ([`StereoStage`]: which component works
//! on it). A component reports a covariance fault to the filter; the navigator latches
//! [`NavMode::Safed`] at the end of the step that raised it.
//!
//! With [`DriveConfig::slip_compensation`] off the rover navigates as one without slip
//! compensation (H05 Fig. 9, "without compensation"): guidance steers on the kinematic dead
//! reckoning ([`Navigator::kin3d`]: wheel odometry with the IMU attitude) and the slip vector
//! is zero. The EKF, gate and VO still run and are reported, so the downhill bias between the
//! VO-aided estimate and the kinematic pose is visible.

mod align;
mod boresight;
mod calibration;
mod config;
mod diagnostics;
mod drive;
mod filter;
mod goal;
pub mod hazard_nav;
mod in_place;
mod kin_aiding;
pub mod loc_nav;
pub mod mission;
pub mod protection;
mod radius;
mod status;
mod sun;
#[cfg(test)]
mod tests_vo;
mod vo_aiding;
pub mod vo_gate;
mod wiring;

pub use align::{AlignConfig, AlignCounters, Aligned, Aligner};
pub use boresight::{Boresight, BoresightConfig};
pub use calibration::{Calibration, CalibrationConfig};
pub use config::NavConfig;
pub use diagnostics::Trajectories;
pub use drive::{Drive, DriveConfig, DriveCounters, Follow, BLIND_SIGMA_FRACTION, MAX_WAYPOINTS};
pub use filter::{FilterConfig, FilterCounters, NavFilter};
pub use goal::{GoalConfig, GoalCtx, GoalNav, ModeRequest};
pub use kin_aiding::{
    KinAiding, KinAidingConfig, KinCounters, KinInputs, KinOutcome, Travel, VoHealth,
    BLIND_SKID_FACTOR, BLIND_SKID_FLOOR_M, KIN_CRAB_ALLOWANCE,
};
pub use loc_nav::{LocCounters, LocFixReport, LocNav, LocalizationSettings};
pub use mission::{MissionBudget, MissionCounters, MissionError, MissionPhase, TargetOutcome};
pub use radius::{CaptureScale, RadiusScale, RadiusScaleConfig};
pub use status::{FilterStatus, GateStatus, NavCounters, NavMode, NavStatus, PoseEstimate};
pub use sun::{SunAiding, SunConfig, SunCounters};
pub use vo_aiding::{VoAiding, VoAidingConfig, VoCounters};

use crate::estimation::CloneHandle;
use crate::guidance::{Guidance, GuidanceError, Path, Point2};
use crate::kinematics::{wheel_contact_points, RoverGeometry, SuspensionState, ROCKY8};
use crate::types::{Quat, Vec3};
use rover_hal::StereoCalibration;

/// Feature capacity of the visual odometry.
pub const VO_FEATURES: usize = 150;

/// Period of the RG2 rate group that runs the kinematic and guidance cycles (20 Hz), s.
pub const RG2_PERIOD_S: f64 = 0.05;

/// The forward hazcam pair the navigator's mission and hazard-navigation tests build their
/// navigator with: 385 px focal length, principal point at the image centre, 84 mm baseline,
/// camera axes (x right, y down, z forward) in the rover frame (x forward, y right, z down),
/// the left camera 0.2 m ahead of and 1.0 m above the rover's reference point.
#[cfg(test)]
pub(crate) fn test_hazcam_calibration() -> StereoCalibration {
    StereoCalibration {
        fx_px: 385.0,
        fy_px: 385.0,
        cx_px: 319.5,
        cy_px: 239.5,
        baseline_m: 0.084,
        rot_rover_from_camera: [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        pos_camera_in_rover_m: [0.2, 0.0, -1.0],
    }
}

/// Which component works on the held stereo frame (the camera frame, or the rectified pair in
/// the image memory, stays held while one does).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StereoStage {
    /// Nothing pending.
    Idle,
    /// Capture triggered and cloned (`clone`, eq. 41); waiting for the camera.
    Capturing {
        /// The capture's clone.
        clone: Option<CloneHandle>,
    },
    /// VO running on the frame of `clone`; `items` work items done so far.
    Processing {
        /// The capture's clone.
        clone: Option<CloneHandle>,
        /// Work items done so far.
        items: u32,
    },
    /// A hazard map running on the held frame ([`hazard_nav`]); `items` work items done.
    Mapping {
        /// Work items done so far.
        items: u32,
    },
    /// Terrain-map localization searching after a map ([`loc_nav`]); the frame stays held so
    /// that no capture starts meanwhile.
    Localizing,
}

/// The navigation state of the flight software (about 110 KB, all inline): its components.
pub struct Navigator {
    mode: NavMode,
    geometry: RoverGeometry,
    calibration: StereoCalibration,
    filter: NavFilter,
    align: Aligner,
    kin: KinAiding,
    vo: VoAiding,
    sun: SunAiding,
    cal: Calibration,
    drive: Drive,
    goal: GoalNav,
    diag: Trajectories,
    stereo: StereoStage,
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

/// Yaw (rad, from north towards east) of the attitude `q` (`R` to `N`).
pub(super) fn yaw_of(q: &Quat) -> f64 {
    let c = q.to_rotation_matrix().into_inner();
    libm::atan2(c[(1, 0)], c[(0, 0)])
}

impl Navigator {
    /// A navigator for `path` (waypoints north, east in `N`, m) with `config` and the camera
    /// `calibration`: [`Self::EMPTY`] initialised by [`Self::init`]. VO is not built here (see
    /// [`Self::start_vo`]). The value is about 210 KB: on the rover CPU use [`Self::init`] on
    /// a static instead.
    pub fn new(
        config: NavConfig,
        path: &[Point2],
        calibration: &StereoCalibration,
    ) -> Result<Self, NavError> {
        let mut nav = Self::EMPTY;
        nav.init(&config, path, calibration)?;
        Ok(nav)
    }

    /// A placeholder navigator (zero settings, no path, VO and hazard navigation not built):
    /// the compile-time value of a statically allocated navigator before [`Self::init`]
    /// (`crate::flight::Fsw::EMPTY`). Not meant to run: its mode is [`NavMode::Safed`].
    pub const EMPTY: Self = Self {
        mode: NavMode::Safed,
        geometry: ROCKY8,
        calibration: StereoCalibration {
            fx_px: 0.0,
            fy_px: 0.0,
            cx_px: 0.0,
            cy_px: 0.0,
            baseline_m: 0.0,
            rot_rover_from_camera: [[0.0; 3]; 3],
            pos_camera_in_rover_m: [0.0; 3],
        },
        filter: NavFilter::EMPTY,
        align: Aligner::EMPTY,
        kin: KinAiding::EMPTY,
        vo: VoAiding::EMPTY,
        sun: SunAiding::EMPTY,
        cal: Calibration::EMPTY,
        drive: Drive::EMPTY,
        goal: GoalNav::EMPTY,
        diag: Trajectories::EMPTY,
        stereo: StereoStage::Idle,
    };

    /// [`Self::new`] in place: this navigator becomes the one `new(*config, path,
    /// calibration)` returns, for `path` (waypoints north, east in `N`, m) with `config` and
    /// the camera `calibration`. Every component is rewritten, the large ones (filter,
    /// recorder) in place; VO, hazard navigation and localization are marked not built (their
    /// storage is kept for [`Self::start_vo`]). Errors: [`NavError::BadConfig`] (non-finite
    /// start, no alignment samples, a filter setting refused), [`NavError::Path`],
    /// [`NavError::Guidance`]; after an error the navigator must not be used until an `init`
    /// succeeds (its mode is then [`NavMode::Safed`]).
    pub fn init(
        &mut self,
        config: &NavConfig,
        path: &[Point2],
        calibration: &StereoCalibration,
    ) -> Result<(), NavError> {
        self.mode = NavMode::Safed;
        let points = wheel_contact_points(&config.geometry, &SuspensionState::default()).ok();
        self.vo.init(&config.vo);
        self.goal.init(&config.goal, points, &config.geometry);
        let a = &config.align;
        let start = [
            a.initial_position_n_m[0],
            a.initial_position_n_m[1],
            a.initial_position_n_m[2],
            a.initial_yaw_rad,
            a.initial_yaw_sigma_rad,
            a.initial_position_sigma_m,
        ];
        if start.iter().any(|v| !v.is_finite()) || a.samples == 0 {
            return Err(NavError::BadConfig);
        }
        let path = Path::<MAX_WAYPOINTS>::new(path).map_err(NavError::Path)?;
        self.filter
            .init(&config.filter)
            .map_err(|_| NavError::BadConfig)?;
        let guidance = Guidance::new(path, config.drive.guidance).map_err(NavError::Guidance)?;
        let p0 = Vec3::from(a.initial_position_n_m);
        self.geometry = config.geometry;
        self.calibration = *calibration;
        self.align = Aligner::new(config.align);
        self.kin.init(&config.kin, &config.geometry);
        self.sun = SunAiding::new(config.sun);
        self.cal = Calibration::new(config.calibration);
        self.drive.init(&config.drive, guidance);
        self.diag = Trajectories::new(p0, a.initial_yaw_rad, &config.geometry, config.track);
        self.stereo = StereoStage::Idle;
        self.mode = NavMode::Aligning;
        Ok(())
    }

    /// Build the visual odometry state (about 96 KB) in place when VO is enabled, and the
    /// goal-directed navigation's hazard navigation (about 68 KB) and localization. Call once
    /// after the navigator has reached its final location (a static on the rover CPU), so
    /// that the large state is not copied through the stack by the constructors. A calibration
    /// VO refuses leaves VO off (counted in [`NavCounters::vo_failures`]).
    pub fn start_vo(&mut self) {
        self.goal.build(self.drive.goal(), &self.calibration);
        self.vo.build(&self.calibration);
    }

    /// The current mode.
    pub fn mode(&self) -> NavMode {
        self.mode
    }

    /// The rover's geometry (kinematics, joint limits).
    pub fn geometry(&self) -> &RoverGeometry {
        &self.geometry
    }

    /// The filter component (EKF, health).
    pub fn filter(&self) -> &NavFilter {
        &self.filter
    }

    /// The kinematic aiding (gate, slip, radius scale).
    pub fn kin(&self) -> &KinAiding {
        &self.kin
    }

    /// The VO aiding (VO output, gate, health).
    pub fn vo(&self) -> &VoAiding {
        &self.vo
    }

    /// The calibration learnt over capture intervals (boresight, dead-reckoning scale).
    pub fn calibration(&self) -> &Calibration {
        &self.cal
    }

    /// The drive (guidance, fault protection, command).
    pub fn drive(&self) -> &Drive {
        &self.drive
    }

    /// The goal-directed navigation (hazard navigation, localization, mission).
    pub fn goal(&self) -> &GoalNav {
        &self.goal
    }

    /// The diagnostic trajectories.
    pub fn trajectories(&self) -> &Trajectories {
        &self.diag
    }

    /// The EKF, once aligned.
    pub fn ekf(&self) -> Option<&crate::estimation::Ekf> {
        self.filter.running()
    }

    /// Why fault protection stopped the drive ([`protection::FaultResponse::None`] unless
    /// [`NavMode::Stopped`]).
    pub fn fault_response(&self) -> protection::FaultResponse {
        self.drive.fault_response()
    }

    /// The slip vector of the last RG2 cycle (EKF minus kinematics, rover frame; zero when the
    /// gate accepted the kinematics).
    pub fn slip(&self) -> crate::guidance::SlipVector {
        self.kin.slip()
    }

    /// The gate result of the last kinematic interval.
    pub fn gate(&self) -> GateStatus {
        self.kin.gate()
    }

    /// The rover command of the last RG2 cycle (rover frame, m/s and rad/s).
    pub fn command(&self) -> crate::kinematics::VehicleCommand {
        self.drive.command()
    }

    /// Dead reckoning with the rocker-bogie kinematic translation rotated by the estimator's
    /// attitude at each interval start ("3D kinematics"), `N`.
    pub fn kin3d(&self) -> PoseEstimate {
        self.diag.kin3d()
    }

    /// Planar wheel odometry `[north m, east m, yaw rad]` with its own heading from the wheels,
    /// ignoring the suspension and the terrain ("2D kinematics").
    pub fn kin2d(&self) -> [f64; 3] {
        self.diag.kin2d()
    }

    /// Dead reckoning (RB sec. 6 baseline): the planar wheel-odometry step rotated by the gyro
    /// attitude, integrated from the aligned attitude with the alignment's gyro bias; no
    /// filter, no sun, no VO. `N`, m.
    pub fn dead_reckoning(&self) -> PoseEstimate {
        self.diag.dead_reckoning()
    }

    /// The VO-only pose: VO relative poses chained from the EKF pose of the first keyframe
    /// after the start or after a VO outage; `None` before the first VO update.
    pub fn vo_pose(&self) -> Option<PoseEstimate> {
        self.diag.vo()
    }

    /// The EKF pose, or the configured start pose before alignment.
    pub fn pose(&self) -> PoseEstimate {
        match self.filter.running() {
            Some(e) => PoseEstimate {
                p_n: e.state().p_n,
                q_nr: e.state().q_nr,
            },
            None => self.align.start_pose(),
        }
    }

    /// Every component's counters as one record (telemetry and the simulator's summary).
    pub fn counters(&self) -> NavCounters {
        let f = self.filter.counters();
        let a = self.align.counters();
        let k = self.kin.counters();
        let v = self.vo.counters();
        let s = self.sun.counters();
        let d = self.drive.counters();
        let (track_matched, track_unmatched) = self.diag.track_steps();
        NavCounters {
            kin_tested: k.kin_tested,
            kin_rejected: k.kin_rejected,
            kin_held: k.kin_held,
            kin_ungated: k.kin_ungated,
            kin_streaks: k.kin_streaks,
            kin_errors: k.kin_errors,
            zupts: k.zupts,
            vo_updates: v.vo_updates,
            vo_fused: v.vo_fused,
            vo_replayed: v.vo_replayed,
            vo_replay_lost: f.replays_lost,
            vo_failures: v.vo_failures,
            vo_large_d2: v.vo_large_d2,
            vo_rejected: v.vo_rejected,
            vo_rejected_rotation: v.vo_rejected_rotation,
            vo_reject_streaks: v.vo_reject_streaks,
            vo_forced: v.vo_forced,
            captures_skipped: v.captures_skipped,
            captures_distance: v.captures_distance,
            captures_heading: v.captures_heading,
            captures_time: v.captures_time,
            sun_applied: s.sun_applied,
            sun_refused: s.sun_refused,
            vo_start_holds: d.vo_start_holds,
            vo_start_timeouts: d.vo_start_timeouts,
            fault_stops: d.fault_stops,
            time_rebases: f.time_rebases,
            sun_streaks: s.sun_streaks,
            align_restarts: a.align_restarts,
            heading_from_sun: a.heading_from_sun,
            heading_from_plan: a.heading_from_plan,
            ekf_errors: f.ekf_errors,
            command_errors: d.command_errors.saturating_add(self.goal.build_errors()),
            sensor_holds: d.sensor_holds,
            blind_stops: d.blind_stops,
            kin_imu_carried: k.kin_imu_carried,
            imu_shocks: k.imu_shocks,
            track_matched,
            track_unmatched,
        }
    }

    /// The navigation telemetry record at `tick`, composed from the components' statuses.
    pub fn status(&self, tick: u64) -> NavStatus {
        let pose = self.pose();
        let filter = match self.filter.running() {
            Some(e) => {
                let p = e.covariance();
                let i = crate::estimation::state::I_P;
                let s = |k: usize| crate::linalg::sqrt(p[(i + k, i + k)].max(0.0)) as f32;
                let v = e.state().v_n;
                FilterStatus {
                    pose,
                    velocity_n_m_s: [v.x as f32, v.y as f32, v.z as f32],
                    position_sigma_m: [s(0), s(1), s(2)],
                    heading_sigma_rad: e.heading_sigma_rad() as f32,
                }
            }
            None => FilterStatus {
                pose,
                velocity_n_m_s: [0.0; 3],
                position_sigma_m: [0.0; 3],
                heading_sigma_rad: 0.0,
            },
        };
        NavStatus::compose(
            tick,
            self.mode,
            &filter,
            &self.kin.slip(),
            &self.kin.gate(),
            &self.drive.command(),
            self.drive.guidance_output(),
            &self.vo.gate(),
            self.drive.fault_response(),
            self.counters(),
        )
    }
}
