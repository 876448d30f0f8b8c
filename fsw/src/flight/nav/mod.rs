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
//! - **RG2B** [`Navigator::zero_velocity_cycle`], half an RG2 period later: the zero-velocity
//!   update of a stop the kinematic cycle saw (apart from RG2 so that a stop's two EKF updates
//!   never share a release).
//! - **RG3** [`Navigator::capture_due`], [`Navigator::capture_started`]: a stereo capture is
//!   due every [`NavConfig::vo_capture_distance_m`] of EKF travel or
//!   [`NavConfig::vo_capture_angle_rad`] of rotation, at the latest after
//!   [`NavConfig::vo_capture_max_interval_us`] (H04 sec. 2); its time is cloned (eq. 41).
//! - **background** [`Navigator::vo_start`], [`Navigator::vo_step`]: VO runs in the frames'
//!   slack, work items up to a cost quantum per frame; its relative pose between the previous
//!   and the current capture clone is tested by the VO gate ([`vo_gate`]: eq. 46 with a slip
//!   allowance, rotation against the gyro) and, when accepted, applied at capture time by a replay of the recorded
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

mod align;
mod boresight;
mod diagnostics;
mod empty;
mod guidance_adapter;
pub mod hazard_nav;
mod kin_aiding;
pub mod loc_nav;
pub mod mission;
pub mod protection;
mod radius;
#[cfg(test)]
mod tests_vo;

/// The forward hazcam pair the navigator's mission and hazard-navigation tests build their
/// navigator with: 385 px focal length, principal point at the image centre, 84 mm baseline,
/// camera axes (x right, y down, z forward) in the rover frame (x forward, y right, z down),
/// the left camera 0.2 m ahead of and 1.0 m above the rover's reference point.
#[cfg(test)]
pub(crate) fn test_hazcam_calibration() -> rover_hal::StereoCalibration {
    rover_hal::StereoCalibration {
        fx_px: 385.0,
        fy_px: 385.0,
        cx_px: 319.5,
        cy_px: 239.5,
        baseline_m: 0.084,
        rot_rover_from_camera: [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        pos_camera_in_rover_m: [0.2, 0.0, -1.0],
    }
}
pub mod vo_gate;
mod vo_sched;

use align::Alignment;
pub use boresight::{Boresight, BoresightConfig};
use diagnostics::Trajectories;
pub use loc_nav::{LocCounters, LocFixReport, LocNav, LocalizationSettings};
pub use mission::{MissionBudget, MissionCounters, MissionError, MissionPhase, TargetOutcome};
use protection::{FaultResponse, Protection, ProtectionConfig};
pub use radius::{CaptureScale, RadiusScale, RadiusScaleConfig};
use vo_gate::{CaptureMark, VoGateStatus};
use vo_sched::StereoStage;

use crate::estimation::{
    CloneHandle, CoreCov, Ekf, EkfConfig, EstError, NominalState, Recorder, ReplayProgress,
};
use crate::guidance::{
    Guidance, GuidanceCommand, GuidanceConfig, GuidanceError, Path, Point2, Pose2, SlipVector,
};
use crate::kinematics::inverse::inverse_kinematics_scaled;
use crate::kinematics::track::TrackConfig;
use crate::kinematics::{
    planar_pose_increment, wheel_contact_points, ContactAngles, KinematicOdometry, KinematicsError,
    OdometryConfig, RoverGeometry, SuspensionState, VehicleCommand, ROCKY8,
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
    /// ground's localisation (the drive plan), not measured on board.
    pub initial_position_n_m: [f64; 3],
    /// Start heading of the plan (yaw from north, positive towards east), rad: used only when
    /// the alignment gets no sun heading (see [`NavCounters::heading_from_plan`]).
    pub initial_yaw_rad: f64,
    /// 1-sigma uncertainty of the plan's start heading, rad.
    pub initial_yaw_sigma_rad: f64,
    /// 1-sigma uncertainty of the start position, m per axis.
    pub initial_position_sigma_m: f64,
    /// IMU samples averaged at rest before the EKF starts (tilt and gyro bias alignment).
    pub align_samples: u32,
    /// Largest standard deviation of any gyro axis over the alignment, rad/s (the rover must be
    /// at rest; a larger dispersion restarts the alignment).
    pub align_max_gyro_std_rad_s: f64,
    /// Largest standard deviation of any accelerometer axis over the alignment, m/s^2.
    pub align_max_accel_std_m_s2: f64,
    /// IMU samples the alignment waits beyond `align_samples` for a sun reading (heading)
    /// before it starts with the plan's heading [`Self::initial_yaw_rad`].
    pub align_sun_wait_samples: u32,
    /// EKF settings (IMU noise, gravity, sun direction in `N`).
    pub ekf: EkfConfig,
    /// Initial 1-sigma of the gyro bias after alignment, rad/s.
    pub gyro_bias_sigma_rad_s: f64,
    /// Initial 1-sigma of the accelerometer bias, m/s^2.
    pub accel_bias_sigma_m_s2: f64,
    /// Kinematic odometry noise model.
    pub odometry: OdometryConfig,
    /// Track memory of the 3D kinematic dead reckoning ([`Navigator::kin3d`]): the body's
    /// heave from the path of the front axles ([`crate::kinematics::track`]). Used only with
    /// the contact-angle translation ([`OdometryConfig::contact_translation`]).
    pub track: TrackConfig,
    /// Visual odometry tuning.
    pub vo: VoConfig,
    /// Run visual odometry on stereo captures.
    pub vo_enabled: bool,
    /// A fused VO relative pose whose Mahalanobis distance `d_m^2` (eq. 46, the EKF's own
    /// `S`, no slip allowance) exceeds this is counted in [`NavCounters::vo_large_d2`].
    pub vo_warn_d2: f64,
    /// Gate VO relative poses (eq. 46 with a slip allowance, and the rotation against the
    /// gyro-propagated rotation between the capture clones; [`vo_gate`] and
    /// `docs/estimation.md` "VO gate"). Off: every VO pose is fused (the former behaviour).
    pub vo_gate_enabled: bool,
    /// Slip allowance of the VO gate: 1-sigma per translation axis (`R0`, m) added to the
    /// gate's residual covariance, as a fraction of the EKF's travel between the clones
    /// (dimensionless). The EKF prior between captures comes from IMU and kinematics, which
    /// slip pulls away; 0.3 accepts 100 % slip at d^2 of about 7 and rejects a translation
    /// error of twice the travel.
    pub vo_gate_slip_fraction: f64,
    /// Floor of the slip allowance, m (1-sigma per axis), for captures with little travel.
    pub vo_gate_slip_floor_m: f64,
    /// Consecutive VO rejections that make a streak ([`NavCounters::vo_reject_streaks`],
    /// telemetry flag): the next VO pose after a streak is fused even when the gate rejects it,
    /// with its covariance inflated by the smallest factor `4^n` (n <= 10) that passes the gate
    /// ([`NavCounters::vo_forced`]), so that a wrong gate cannot lock VO out.
    pub vo_reject_streak: u32,
    /// VO capture by distance (H04 sec. 2: images every 20-30 cm): a capture is due when the
    /// EKF position has moved this far since the last capture, m (3D distance in `N`).
    pub vo_capture_distance_m: f64,
    /// A capture is due when the EKF attitude has rotated this much since the last capture, rad
    /// (angle of the relative rotation; on level ground the heading change).
    pub vo_capture_angle_rad: f64,
    /// Time fallback: a capture is due this long after the last one, us (EKF time), so that a
    /// stuck or slipping-in-place rover still gets VO.
    pub vo_capture_max_interval_us: u64,
    /// While VO has no keyframe (after a VO failure or at the start of VO), a capture is due
    /// this long after the last one, us (EKF time), whatever the motion: VO needs a keyframe
    /// before it can measure, and a failing camera is not retriggered at the RG3 rate.
    pub vo_capture_retry_us: u64,
    /// Slip compensation: guidance on the EKF pose with the slip vector (on) or on kinematic
    /// dead reckoning without slip vector (off); see the module doc.
    pub slip_compensation: bool,
    /// Slip hold: after a kinematic interval is rejected, the next intervals are not fused for
    /// this many RG2 cycles even when the gate accepts them (a slipping rover produces some
    /// intervals whose slip is within the noise; fusing them would teach the filter the crab
    /// angle as a heading error). Their slip vector is zero (H04: no slip when the gate
    /// accepts); they count in [`NavCounters::kin_held`]. Measured effect in
    /// `docs/estimation.md`.
    pub slip_hold_cycles: u32,
    /// Statistical trigger of the slip hold: the hold starts only when at least this many of
    /// the last [`NavConfig::slip_hold_cycles`] tested intervals (at most 32) were rejected.
    /// Flight default 1: any rejection holds. The gate (eq. 46, chi-square 95 %) rejects about
    /// 5 % of the intervals of a rover that does not slip, and each such false alarm stops the
    /// kinematic fusion for a second, so the false alarms cluster (8.4 % on `flat-firm`
    /// without slip, seed 1). With 3 (of 20) they fall to 3.2 % (mean of seeds 1-10; 4.1 %
    /// with one), but the EKF's final error on the same runs grows from 0.52 % to 0.79 % (worse on all
    /// ten seeds): the extra kinematic fusion speeds up a gyro-bias error of the heading
    /// (`docs/estimation.md`, "Statistical trigger of the hold"), so the default stays 1.
    pub slip_hold_rejections: u32,
    /// VO fallback: when no VO update was fused for this many RG2 cycles (VO failing, camera
    /// lost, or VO off), kinematic intervals are fused without the gate, since without VO the
    /// slip cannot be measured and the EKF would otherwise run on the IMU alone.
    pub vo_timeout_cycles: u32,
    /// Slip allowance of the VO-loss fallback, as a fraction of the kinematic step.
    pub vo_loss_slip_fraction: f64,
    /// The VO-loss fallback fuses the kinematic translation only (rotation from the gyro and
    /// the sun).
    pub vo_loss_translation_only: bool,
    /// Growth of the horizontal position sigma per metre of accepted travel fused without VO
    /// (a systematic slip the gate cannot see), fraction.
    pub vo_loss_drift_fraction: f64,
    /// Crab allowance of a kinematic interval fused while VO is alive: the lateral translation
    /// is fused with `(kin_crab_allowance * |sin cross slope| * step)^2` added to its variance
    /// (m^2; `step` the interval's translation, m; the cross slope from the EKF attitude), after
    /// the gate tested the interval at its own covariance. `f64::INFINITY` does not fuse the
    /// lateral part on a slope at all.
    pub kin_crab_allowance: f64,
    /// RG2 cycles the rover waits at the start for VO's first keyframe (VO running) before it
    /// drives without VO.
    pub vo_start_timeout_cycles: u32,
    /// Sun readings refused by the sun's gate in a row after which the heading covariance is
    /// inflated (see [`Navigator::sun`]).
    pub sun_streak: u32,
    /// Goal-directed driving with hazard avoidance (V99 sec. 4, [`hazard_nav`]): the last
    /// waypoint is the goal; hazard maps from the hazcams feed the RoverBug planner, whose paths
    /// replace the guidance path. Off: the waypoints are followed as a path.
    pub hazard_avoidance: bool,
    /// Hazard mapping from the hazcam pair ([`crate::perception`]).
    pub perception: crate::perception::PerceptionConfig,
    /// RoverBug planner ([`crate::planning`]).
    pub planner: crate::planning::PlannerConfig,
    /// EKF travel between hazard maps while driving a planned path, m (the hazcams see about
    /// 0.3-2.8 m ahead, so a map each metre keeps the next obstacle in view twice).
    pub map_interval_m: f64,
    /// Terrain-map localization against an uplinked global map (V99 sec. 5, [`loc_nav`]).
    /// Off by default.
    pub localization: LocalizationSettings,
    /// Stop-and-go without VO (RB sec. 5, H04 sec. 2): while VO is off or lost, the rover stops
    /// after every `blind_stop_interval_m` of wheel travel for [`Self::blind_stop_cycles`], so
    /// that zero-velocity updates re-anchor the IMU velocity; between stops a kinematic
    /// interval the gate rejects is not fused and the IMU carries the motion (the slip is then
    /// measured against the IMU, eq. 46). 0 disables it (the VO-loss fallback fuses every
    /// interval with the slip allowance). m.
    pub blind_stop_interval_m: f64,
    /// RG2 cycles of each stop of the stop-and-go drive without VO.
    pub blind_stop_cycles: u32,
    /// RG2 cycles after the last zero-velocity update during which the IMU velocity counts as
    /// anchored (a rejected kinematic interval is not fused; after that it is fused with the
    /// slip allowance as before).
    pub blind_anchor_cycles: u32,
    /// Gate rejections in a row, with no VO fused meanwhile, after which the filter's velocity
    /// covariance is inflated (RG2 cycles; see `kin_aiding`'s streak recovery).
    pub reject_streak_cycles: u32,
    /// Velocity 1-sigma added by the streak recovery, m/s per axis.
    pub streak_velocity_sigma_m_s: f64,
    /// Accelerometer-bias 1-sigma added by the streak recovery, m/s^2 per axis.
    pub streak_accel_bias_sigma_m_s2: f64,
    /// Recorded filter operations replayed per background slice when a VO result is applied at
    /// its capture time ([`Recorder::replay_step`]): bounds the slice (an IMU propagation is
    /// about 10 000 instructions on the rover CPU, an update up to 95 000) while the replay
    /// still catches up within a few dozen frames.
    pub replay_ops_per_slice: u16,
    /// Guidance settings.
    pub guidance: GuidanceConfig,
    /// Fault-protection limits (slip, stall, uncertainty, arrival, sensor loss).
    pub protection: ProtectionConfig,
    /// Online estimate of the effective wheel-radius scale.
    pub radius_scale: RadiusScaleConfig,
    /// Online estimate of VO's translation boresight in yaw ([`Boresight`]).
    pub vo_boresight: BoresightConfig,
    /// Minor frames without a checked IMU sample after which the rover is stopped.
    pub imu_timeout_frames: u32,
    /// RG2 cycles without a checked joint reading after which the rover is stopped.
    pub joints_timeout_cycles: u32,
    /// Below this measured wheel rate (rad/s, every wheel) with a zero command the rover is
    /// stopped and a zero-velocity update is applied.
    pub stopped_wheel_rate_rad_s: f64,
    /// Rough-terrain inverse kinematics: the motor command is computed with the odometry's
    /// current windowed contact angles ([`KinematicOdometry::windowed_contact_angles_rad`],
    /// `ContactConfig::window_travel_m`; V99 sec. 6, relative
    /// to their mean; [`crate::kinematics::inverse_kinematics_contact`], Tarokh and McDermott
    /// 2005) instead of contacts below the axles (eq. 16-25). Needs the odometry's contact
    /// angles ([`OdometryConfig::contact_translation`] or `contact_angles`). A failing
    /// rough-terrain solve falls back to eq. 16-25 for that cycle. Measured (seed 1, 3D
    /// kinematics error / distance, `docs/kinematics.md`): `rough-kinematics` 5.31 -> 2.83 %,
    /// without slip and with exact dimensions 2.03 -> 0.93 %, `rock-crawl` 2.73 -> 0.80 %,
    /// `step-climb` 3.89 -> 3.67 %, flat and 10 deg slope unchanged, but `undulating` 0.97 ->
    /// 1.48 % (worse on seeds 1-3: the zero-mean angles miss the heave's common mode).
    pub ik_contact_angles: bool,
    /// Contact angles at or beyond this magnitude (rad) are taken as 0 by the rough-terrain
    /// inverse kinematics ([`crate::kinematics::ContactAngles::new`]).
    pub ik_contact_max_angle_rad: f64,
    /// Contact angles below this magnitude (rad) are taken as 0 by the rough-terrain inverse
    /// kinematics, and turns in place always use eq. 16-25: on flat ground among rocks the
    /// estimated angles are noise, and feeding them to the inverse kinematics made the wheels
    /// fight (SIL-HAZ-3 `unreachable`: two collisions during turns, then `SlipLimit` instead
    /// of `GoalUnreachable`; SIL-HAZ-2 one collision). With 0.1 rad and level turns: no
    /// collision, `rough-kinematics` 2.86 % (0.91 % without slip and with exact dimensions).
    pub ik_contact_min_angle_rad: f64,
    /// The 3D kinematic dead reckoning (`kin3d`, V99 sec. 6: the contact-angle step with the
    /// track memory) scaled by its own effective wheel-radius scale: the ratio of VO's
    /// translation to the dead reckoning's over capture intervals the slip gate accepted
    /// throughout ([`CaptureScale`]; settings [`Self::radius_scale`]: 1 m windows, within 4 %).
    /// It calibrates
    /// the wheels' true radius (and the small slip the gate lets through) into the dead
    /// reckoning, which is the navigation pose when VO is lost. A scale of its own because the
    /// EKF's (eq. 15's) ratio also absorbs eq. 15's contact model error on rough ground, which
    /// the contact-angle step does not have (that scale on `kin3d` made `undulating` 0.77 ->
    /// 1.53 %, `docs/kinematics.md`), and the EKF's travel over an interval mostly repeats the
    /// kinematics it fused before. Without VO the scale stays 1.
    pub kin3d_radius_scale: bool,
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
            // The ground's knowledge of the start: heading from the end of the previous drive
            // (a few degrees), position from orbital/ground localisation (5 cm here, relative to
            // the drive's own map frame).
            initial_yaw_sigma_rad: 0.05,
            initial_position_sigma_m: 0.05,
            align_samples: 400,
            // Ten times the per-sample noise of the rover's IMU class (1 mrad/s, 5 mm/s^2 at
            // 200 Hz): a rover at rest passes, a spike of 0.2 rad/s or 3 m/s^2 in one of 400
            // samples does not.
            align_max_gyro_std_rad_s: 0.01,
            align_max_accel_std_m_s2: 0.1,
            // One RG4 period (5 s) and a second of margin.
            align_sun_wait_samples: 1200,
            ekf: EkfConfig::default(),
            gyro_bias_sigma_rad_s: 2.0e-4,
            accel_bias_sigma_m_s2: 1.0e-2,
            // Eq. 15 kinematics (contacts below the axles) with the calibrated noise model for
            // the gate and the EKF. The contact-angle estimator (V99 sec. 6) cuts the 3D
            // odometry's distance error on `undulating` from 1.31 % to 0.32 %, but its step
            // takes the gyro rotation as an input and its covariance does not describe its
            // residuals (the gate rejected 54 % of the intervals on firm flat ground without
            // slip, `docs/kinematics.md`): it runs as the diagnostic translation of the 3D
            // kinematic dead reckoning (`contact_translation`) only. The rough-terrain inverse
            // kinematics gets the angles estimated over 10 mm windows of travel (2.4-4.8 deg rms
            // against the truth's contacts instead of 5.8-8.9 deg per step, seed 1 without slip;
            // `ContactConfig::window_travel_m`).
            odometry: OdometryConfig {
                contact_translation: true,
                contact: crate::kinematics::ContactConfig {
                    window_travel_m: 0.01,
                    ..crate::kinematics::ContactConfig::default()
                },
                ..OdometryConfig::default()
            },
            track: TrackConfig::DEFAULT,
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
            vo_gate_enabled: true,
            vo_gate_slip_fraction: 0.3,
            vo_gate_slip_floor_m: 0.02,
            vo_reject_streak: 3,
            vo_capture_distance_m: 0.10,
            vo_capture_angle_rad: 10.0_f64.to_radians(),
            vo_capture_max_interval_us: 10_000_000,
            vo_capture_retry_us: 1_000_000,
            slip_compensation: true,
            slip_hold_cycles: 20,
            slip_hold_rejections: 1,
            vo_timeout_cycles: 60,
            vo_loss_slip_fraction: 0.3,
            vo_loss_translation_only: true,
            // Slip below the gate's detection on firm ground (about 8 % of a step,
            // docs/slip-detection.md).
            vo_loss_drift_fraction: 0.05,
            kin_crab_allowance: kin_aiding::KIN_CRAB_ALLOWANCE,
            // 4 s of rejections with no VO fused: longer than the rover goes without a VO
            // update while slipping with VO alive (a capture every 0.1 m, 1-2 s).
            reject_streak_cycles: 80,
            hazard_avoidance: false,
            // The hazard cells of a rock end where its flank is still below the step and slope
            // limits; its skirt reaches about 0.1 m further (the simulator's smooth caps:
            // SIL-HAZ-1's truth contact with the default 0.1 m margin), so the margin over the
            // half-width is 0.2 m.
            perception: crate::perception::PerceptionConfig {
                grow_margin_m: 0.3,
                ..crate::perception::PerceptionConfig::default()
            },
            // Guidance follows the planner's polyline with a carrot, which cuts the corners of
            // a path round an obstacle: the clearance over the grown obstacles covers it.
            // A path the planner hands over ends at least twice guidance's stopping tolerance
            // (0.05 m) away: a path ending within the tolerance is arrived at before it is driven.
            planner: crate::planning::PlannerConfig {
                clearance_m: 0.15,
                min_reach_m: 0.1,
                ..crate::planning::PlannerConfig::default()
            },
            map_interval_m: 1.0,
            localization: LocalizationSettings::DEFAULT,
            blind_stop_interval_m: 1.0,
            blind_stop_cycles: 60,
            blind_anchor_cycles: 300,
            sun_streak: 3,
            vo_start_timeout_cycles: 600,
            streak_velocity_sigma_m_s: 0.01,
            streak_accel_bias_sigma_m_s2: 0.01,
            replay_ops_per_slice: 16,
            guidance: GuidanceConfig::rocky8(xy),
            protection: ProtectionConfig::default(),
            radius_scale: RadiusScaleConfig::default(),
            vo_boresight: BoresightConfig::default(),
            imu_timeout_frames: 20,
            joints_timeout_cycles: 10,
            stopped_wheel_rate_rad_s: 0.01,
            // Rough-terrain IK on: KIN-1/2/3/5 better, flat and slope unchanged, undulating
            // worse (field doc).
            ik_contact_angles: true,
            ik_contact_max_angle_rad: 1.0,
            ik_contact_min_angle_rad: 0.1,
            kin3d_radius_scale: true,
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
    /// Stopped by fault protection ([`Navigator::fault_response`] says why); latched until the
    /// ground resets the flight software, the estimator keeps running.
    Stopped,
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

    /// At the origin, level, heading north (as `default()`, usable in a `const`).
    pub const EMPTY: Self = Self {
        p_n: crate::types::VEC3_ZERO,
        q_nr: crate::types::QUAT_IDENTITY,
    };
}

/// Storage of a large part of the navigator that is built in place after the navigator
/// (visual odometry, hazard navigation): the value always exists (a placeholder until built,
/// so that building it writes into this storage instead of moving a new value in), `built`
/// says whether it is in use. Reads like an `Option`.
struct InPlace<T> {
    value: T,
    built: bool,
}

impl<T> InPlace<T> {
    /// `value` as the placeholder, not built.
    const fn unbuilt(value: T) -> Self {
        Self {
            value,
            built: false,
        }
    }

    /// The part when built.
    fn as_ref(&self) -> Option<&T> {
        self.built.then_some(&self.value)
    }

    /// The part when built, mutable.
    fn as_mut(&mut self) -> Option<&mut T> {
        self.built.then_some(&mut self.value)
    }

    /// True when built.
    fn is_some(&self) -> bool {
        self.built
    }
}

/// Period of the RG2 rate group that runs the kinematic and guidance cycles (20 Hz), s.
pub const RG2_PERIOD_S: f64 = 0.05;

/// Counters of the navigation functions (telemetry and the simulator's summary).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct NavCounters {
    /// Kinematic intervals tested by the gate (eq. 46).
    pub kin_tested: u32,
    /// Of those, rejected (slip detected).
    pub kin_rejected: u32,
    /// Accepted by the gate but not fused because slip was detected within the hold time.
    pub kin_held: u32,
    /// Fused with the slip allowance because VO had not updated for the VO timeout (fallback;
    /// each is also a gated test in `kin_tested`).
    pub kin_ungated: u32,
    /// Streaks of gate rejections that triggered the covariance recovery.
    pub kin_streaks: u32,
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
    /// VO relative poses rejected by the VO gate and not fused ([`vo_gate`]); the rejections
    /// by the 6-dof pose test are `vo_rejected - vo_rejected_rotation`.
    pub vo_rejected: u32,
    /// Of those, rejected by the rotation check against the gyro-propagated rotation.
    pub vo_rejected_rotation: u32,
    /// Streaks of [`NavConfig::vo_reject_streak`] consecutive VO rejections.
    pub vo_reject_streaks: u32,
    /// VO poses fused after a streak although the gate rejected them, with inflated covariance.
    pub vo_forced: u32,
    /// Captures skipped because no clone slot was free ([`Navigator::capture_skipped`]); a
    /// capture due while VO is busy waits for it instead.
    pub captures_skipped: u32,
    /// Captures started because the EKF travelled [`NavConfig::vo_capture_distance_m`].
    pub captures_distance: u32,
    /// Captures started because the EKF attitude turned [`NavConfig::vo_capture_angle_rad`].
    pub captures_heading: u32,
    /// Captures started by the time fallback [`NavConfig::vo_capture_max_interval_us`] (or the
    /// first capture of VO).
    pub captures_time: u32,
    /// Sun updates applied.
    pub sun_applied: u32,
    /// Sun readings refused (gate, skew, not in view).
    pub sun_refused: u32,
    /// RG2 cycles the rover was held at the start waiting for VO's first keyframe.
    pub vo_start_holds: u32,
    /// Starts that gave up waiting for VO's first keyframe.
    pub vo_start_timeouts: u32,
    /// Fault-protection stops (see [`Navigator::fault_response`]).
    pub fault_stops: u32,
    /// Re-anchorings of the filter's timeline after an IMU time-base change.
    pub time_rebases: u32,
    /// Streaks of sun readings refused by the gate that inflated the heading covariance.
    pub sun_streaks: u32,
    /// Alignments restarted because the IMU samples were not those of a rover at rest.
    pub align_restarts: u32,
    /// Alignments whose heading came from the sun sensor.
    pub heading_from_sun: u32,
    /// Alignments that took the plan's heading (no usable sun reading in time).
    pub heading_from_plan: u32,
    /// EKF errors on propagation or update (other than the ones counted above).
    pub ekf_errors: u32,
    /// Guidance or inverse-kinematics failures (the rover was stopped for that cycle).
    pub command_errors: u32,
    /// Cycles the rover was held stopped because a sensor was lost.
    pub sensor_holds: u32,
    /// Stops of the stop-and-go drive without VO ([`NavConfig::blind_stop_interval_m`]).
    pub blind_stops: u32,
    /// Kinematic intervals the gate rejected without VO while the IMU velocity was anchored
    /// by a recent zero-velocity update: not fused, the IMU carried the motion.
    pub kin_imu_carried: u32,
    /// IMU shocks: accelerometer samples saturated at or refused beyond the sensor's range
    /// ([`Navigator::imu_shock`]); the velocity variance was inflated.
    pub imu_shocks: u32,
    /// Kinematic steps of the 3D dead reckoning whose vertical the track memory corrected
    /// (a middle or rear axle over its front axle's remembered path; V99 sec. 6,
    /// [`crate::kinematics::track`]).
    pub track_matched: u32,
    /// Kinematic steps without a match (memory still filling after a start, turns, side
    /// steps): the dead reckoning took the zero-mean contact-angle step as it is.
    pub track_unmatched: u32,
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
    /// Residual `[r_theta (rad); r_p (m)]` in `R0`, measured minus predicted (eq. 46 input).
    pub residual: [f64; 6],
    /// Square roots of the residual covariance's diagonal, same units (`residual / sigma` is the
    /// per-axis normalised residual the ground uses to see which axis slipped).
    pub sigma: [f64; 6],
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
    vo: InPlace<VisualOdometry<VO_FEATURES>>,
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
    /// Diagnostic trajectories (kin2d, kin3d, dead reckoning, VO-only).
    traj: Trajectories,
    vo_quality: Option<VoOutput>,
    /// The error of the last VO update that failed (telemetry; `None` before any failure).
    last_vo_error: Option<crate::vo::VoError>,
    /// The VO gate's last verdict and rejection streak.
    vo_gate: VoGateStatus,
    /// EKF pose and time of the last capture (the capture policy's reference).
    last_capture: Option<CaptureMark>,
    counters: NavCounters,
    frames_without_imu: u32,
    cycles_without_joints: u32,
    /// Gate verdicts of the last 32 tested intervals, newest in bit 0 (1: rejected).
    reject_history: u32,
    /// Gate rejections in a row with no VO fused meanwhile.
    reject_streak: u32,
    /// Kinematic intervals still to come that may carry an IMU shock's velocity error
    /// ([`Self::imu_shock`]): their rejections are not slip (no hold, not in
    /// `reject_history`); the grace ends early at the first interval the gate accepts.
    shock_grace: u8,
    /// Intervals of the shock's grace accepted in a row ([`SHOCK_SETTLED_INTERVALS`] end it).
    shock_accepted: u8,
    /// Sun readings refused by the sun's gate in a row.
    sun_rejections: u32,
    /// VO has held a keyframe since the start (or its start wait timed out).
    vo_started: bool,
    /// Fault-protection state.
    protection: Protection,
    /// Effective wheel-radius scale estimate.
    radius_scale: RadiusScale,
    /// The 3D kinematic dead reckoning's own radius scale ([`NavConfig::kin3d_radius_scale`]).
    kin3d_scale: CaptureScale,
    /// VO translation boresight estimate.
    boresight: Boresight,
    /// Why fault protection stopped the drive.
    fault_response: FaultResponse,
    /// A VO update was fused since the last kinematic interval.
    vo_fused_since_interval: bool,
    /// Wheel rates of the last motor command, rad/s (stall check).
    last_wheel_rates: [f64; 6],
    /// RG2 cycles the rover waited for VO's first keyframe.
    cycles_waiting_vo: u32,
    cycles_since_vo: u32,
    /// Stop-and-go without VO: wheel travel since the last stop, m, RG2 cycles left in the
    /// current stop, and RG2 cycles since the last zero-velocity update.
    blind_travel_m: f64,
    blind_hold_left: u32,
    cycles_since_zupt: u32,
    /// The last kinematic cycle saw a stop: [`Self::zero_velocity_cycle`] applies its ZUPT.
    zupt_due: bool,
    /// The last EKF error (telemetry: what the `ekf_errors` counter counted last).
    last_ekf_error: Option<EstError>,
    /// Goal-directed driving with hazard avoidance (built in place by [`Self::start_vo`]).
    hazard: InPlace<hazard_nav::HazardNav>,
    /// Terrain-map localization (built in place by [`Self::start_vo`]).
    loc: loc_nav::LocSlot,
    /// The day's targets and the power telemetry ([`mission`]).
    mission: mission::Mission,
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
/// Most kinematic intervals after an IMU shock whose rejections are not slip
/// ([`Navigator::imu_shock`]): 20 intervals (1 s of RG2), one slip-hold window of the flight
/// configuration. The grace ends earlier once [`SHOCK_SETTLED_INTERVALS`] intervals in a row
/// were accepted (and fused): the velocity is anchored again. Until session 21 it was the
/// interval in progress and the next one only: on `rock-field-crawl` (seed 1, three clipped
/// samples, 0.88 m/s each) the third interval still carried 1.6 m/s of the shock's lateral
/// velocity error, its rejection started a slip hold, the hold kept the accepted intervals from
/// being fused, and the horizontal sigma grew at 2 m/s to the 1 m fault-protection stop
/// (`PositionUncertain`).
const SHOCK_GRACE_INTERVALS: u8 = 20;

/// Intervals accepted in a row that end an IMU shock's grace: two, so that the interval after
/// the first correction confirms it.
const SHOCK_SETTLED_INTERVALS: u8 = 2;

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
        config: empty::EMPTY_CONFIG,
        mode: NavMode::Safed,
        align: Alignment::EMPTY,
        ekf: Ekf::EMPTY,
        ekf_running: false,
        odometry: KinematicOdometry::new(ROCKY8, empty::EMPTY_CONFIG.odometry),
        interval: None,
        last_joints: None,
        gyro_since_joints: None,
        gyro_t_us: None,
        vo: InPlace::unbuilt(VisualOdometry::EMPTY),
        calibration: empty::NO_CALIBRATION,
        key_clone: None,
        recorder: Recorder::EMPTY,
        stereo: StereoStage::Idle,
        guidance: None,
        slip: SlipVector {
            x_m: 0.0,
            y_m: 0.0,
            phi_rad: 0.0,
        },
        gate: empty::NO_GATE,
        command: VehicleCommand {
            x_dot_m_s: 0.0,
            y_dot_m_s: 0.0,
            yaw_rate_rad_s: 0.0,
        },
        last_guidance: None,
        traj: Trajectories::EMPTY,
        vo_quality: None,
        last_vo_error: None,
        vo_gate: empty::NO_VO_GATE,
        last_capture: None,
        counters: empty::NO_COUNTERS,
        frames_without_imu: 0,
        cycles_without_joints: 0,
        reject_history: 0,
        reject_streak: 0,
        shock_grace: 0,
        shock_accepted: 0,
        sun_rejections: 0,
        vo_started: false,
        protection: Protection::EMPTY,
        radius_scale: RadiusScale::new(),
        kin3d_scale: CaptureScale::new(),
        boresight: Boresight::new(),
        fault_response: FaultResponse::None,
        vo_fused_since_interval: false,
        last_wheel_rates: [0.0; 6],
        cycles_waiting_vo: 0,
        cycles_since_vo: 0,
        blind_travel_m: 0.0,
        blind_hold_left: 0,
        cycles_since_zupt: u32::MAX,
        zupt_due: false,
        last_ekf_error: None,
        hazard: InPlace::unbuilt(hazard_nav::HazardNav::EMPTY),
        loc: loc_nav::LocSlot::NONE,
        mission: mission::Mission::EMPTY,
    };

    /// [`Self::new`] in place: this navigator becomes the one `new(*config, path,
    /// calibration)` returns, for `path` (waypoints north, east in `N`, m) with `config` and
    /// the camera `calibration`. Every field is rewritten, the large ones (filter, recorder)
    /// in place; VO and hazard navigation are marked not built (their storage is kept for
    /// [`Self::start_vo`]). Errors: [`NavError::BadConfig`] (non-finite start, no alignment
    /// samples, a filter setting refused), [`NavError::Path`], [`NavError::Guidance`]; after an
    /// error the navigator must not be used until an `init` succeeds (its mode is then
    /// [`NavMode::Safed`]).
    pub fn init(
        &mut self,
        config: &NavConfig,
        path: &[Point2],
        calibration: &StereoCalibration,
    ) -> Result<(), NavError> {
        self.mode = NavMode::Safed;
        self.vo.built = false;
        self.hazard.built = false;
        self.loc.unbuild();
        self.mission = mission::Mission::EMPTY;
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
        self.ekf
            .init(
                config.ekf,
                NominalState::at_rest(0),
                &(CoreCov::identity() * 1.0e-6),
            )
            .map_err(|_| NavError::BadConfig)?;
        let guidance = Guidance::new(path, config.guidance).map_err(NavError::Guidance)?;
        let p0 = Vec3::from(config.initial_position_n_m);
        self.config = *config;
        self.mode = NavMode::Aligning;
        self.align = Alignment::default();
        self.ekf_running = false;
        self.odometry = KinematicOdometry::new(config.geometry, config.odometry);
        self.interval = None;
        self.last_joints = None;
        self.gyro_since_joints = None;
        self.gyro_t_us = None;
        self.calibration = *calibration;
        self.key_clone = None;
        self.recorder.reset();
        self.stereo = StereoStage::Idle;
        self.guidance = Some(guidance);
        self.slip = SlipVector::default();
        self.gate = GateStatus::default();
        self.command = VehicleCommand::default();
        self.last_guidance = None;
        self.traj = Trajectories::new(p0, config.initial_yaw_rad, &config.geometry, config.track);
        self.vo_quality = None;
        self.last_vo_error = None;
        self.vo_gate = VoGateStatus::default();
        self.last_capture = None;
        self.counters = NavCounters::default();
        self.frames_without_imu = 0;
        self.cycles_without_joints = 0;
        self.reject_history = 0;
        self.reject_streak = 0;
        self.shock_grace = 0;
        self.shock_accepted = 0;
        self.sun_rejections = 0;
        self.vo_started = false;
        self.protection = Protection::default();
        self.radius_scale = RadiusScale::new();
        self.kin3d_scale = CaptureScale::new();
        self.boresight = Boresight::new();
        self.fault_response = FaultResponse::None;
        self.vo_fused_since_interval = false;
        self.last_wheel_rates = [0.0; 6];
        self.cycles_waiting_vo = 0;
        self.cycles_since_vo = 0;
        self.blind_travel_m = 0.0;
        self.blind_hold_left = 0;
        self.cycles_since_zupt = u32::MAX;
        self.zupt_due = false;
        self.last_ekf_error = None;
        Ok(())
    }

    /// The current mode.
    pub fn mode(&self) -> NavMode {
        self.mode
    }

    /// Why fault protection stopped the drive ([`FaultResponse::None`] unless
    /// [`NavMode::Stopped`]).
    pub fn fault_response(&self) -> FaultResponse {
        self.fault_response
    }

    /// The effective wheel-radius scale applied to the kinematic translation (1 = nominal).
    pub fn radius_scale(&self) -> f64 {
        self.radius_scale.scale
    }

    /// The effective wheel-radius scale applied to the 3D kinematic dead reckoning's steps
    /// ([`NavConfig::kin3d_radius_scale`]; 1 = nominal or off) and the 1 m windows it was
    /// learnt from.
    pub fn kin3d_radius_scale(&self) -> (f64, u32) {
        if self.config.kin3d_radius_scale {
            (self.kin3d_scale.scale.scale, self.kin3d_scale.scale.updates)
        } else {
            (1.0, 0)
        }
    }

    /// The VO translation boresight removed from each VO pose (rad about `z_R`, positive from
    /// `x_R` towards `y_R`) and the number of samples it was learnt from ([`Boresight`]).
    pub fn vo_boresight(&self) -> (f64, u32) {
        (self.boresight.yaw_rad, self.boresight.updates)
    }

    /// The slip measured over the last complete fault-protection window (1 - EKF travel /
    /// wheel travel), fraction.
    pub fn window_slip(&self) -> f64 {
        self.protection.last_slip
    }

    /// The IMU's time base changed (a time-stamp leap that persisted and was accepted,
    /// [`crate::telemetry::DeviceHealth::resyncs`]): the filter's timeline is re-anchored at
    /// `t_us` (the state and its core covariance are kept, the clones, the kinematic interval,
    /// the VO keyframe and any recording or replay are dropped, since their times belong to
    /// the old base), so that the filter never propagates across the leap. Counted in
    /// [`NavCounters::time_rebases`]. The clock jumped, the rover did not: the drive goes on.
    pub fn imu_time_rebase(&mut self, t_us: u64) {
        self.counters.time_rebases = self.counters.time_rebases.saturating_add(1);
        if !self.ekf_running {
            return;
        }
        let mut x = *self.ekf.state();
        x.t_us = t_us;
        let p = self.ekf.core_covariance();
        self.recorder.end();
        if let Err(e) = self.ekf.reset(x, &p) {
            self.ekf_error(e);
        }
        self.interval = None;
        self.key_clone = None;
        self.stereo = StereoStage::Idle;
        if let Some(vo) = self.vo.as_mut() {
            vo.reset();
        }
        self.gyro_since_joints = None;
        self.gyro_t_us = None;
    }

    /// Latch a fault-protection stop.
    fn fault_stop(&mut self, response: FaultResponse) {
        if self.mode == NavMode::Driving {
            self.mode = NavMode::Stopped;
            self.fault_response = response;
            self.counters.fault_stops = self.counters.fault_stops.saturating_add(1);
        }
    }

    /// The EKF, once aligned.
    pub fn ekf(&self) -> Option<&Ekf> {
        self.ekf_running.then_some(&self.ekf)
    }

    /// Counters.
    pub fn counters(&self) -> &NavCounters {
        &self.counters
    }

    /// The last error the EKF returned (propagation, update, clone), if any, other than the
    /// `Faulted` that every call returns after a fault: after [`NavMode::Safed`] it is the
    /// cause of the fault.
    pub fn last_ekf_error(&self) -> Option<EstError> {
        self.last_ekf_error
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
        self.traj.kin3d
    }

    /// Planar wheel odometry `[north m, east m, yaw rad]` with its own heading from the wheels,
    /// ignoring the suspension and the terrain ("2D kinematics").
    pub fn kin2d(&self) -> [f64; 3] {
        self.traj.kin2d
    }

    /// Dead reckoning (RB sec. 6 baseline): the planar wheel-odometry step rotated by the gyro
    /// attitude, integrated from the aligned attitude with the alignment's gyro bias; no
    /// filter, no sun, no VO. `N`, m.
    pub fn dead_reckoning(&self) -> PoseEstimate {
        self.traj.dr
    }

    /// The VO-only pose: VO relative poses chained from the EKF pose of the first keyframe
    /// after the start or after a VO outage; `None` before the first VO update.
    pub fn vo_pose(&self) -> Option<PoseEstimate> {
        self.traj.vo
    }

    /// The last VO output (quality figures), if any.
    pub fn vo_output(&self) -> Option<&VoOutput> {
        self.vo_quality.as_ref()
    }

    /// The error of the last failed VO update ([`NavCounters::vo_failures`]), if any.
    pub fn last_vo_error(&self) -> Option<crate::vo::VoError> {
        self.last_vo_error
    }

    fn ekf_error(&mut self, e: EstError) {
        self.counters.ekf_errors = self.counters.ekf_errors.saturating_add(1);
        // `Faulted` only repeats that an earlier error faulted the filter: keep the cause.
        if e != EstError::Faulted || self.last_ekf_error.is_none() {
            self.last_ekf_error = Some(e);
        }
        if matches!(e, EstError::Faulted | EstError::CovarianceUnhealthy { .. }) {
            self.mode = NavMode::Safed;
        }
    }

    /// An IMU shock (found on `cul-de-sac` seed 2: a wheel dropping off a rock edge): an
    /// accelerometer sample saturated at the sensor's range or refused beyond it. The samples of
    /// a shock sum to the small true velocity change only when every one of them is integrated
    /// at its true value; a clipped or missing one leaves up to the range times the sample period
    /// (0.88 m/s for 18 g0 over 5 ms) in the velocity, which the kinematic gate then reads as
    /// slip and refuses to correct (the filter ran away at 1.5 m/s there). The velocity
    /// variances grow by `velocity_sigma_m_s^2` (m/s; recorded for the late-VO replay) so that
    /// the next kinematic interval or VO pose re-anchors the velocity; the intervals that span
    /// the shock are gated at that covariance without a slip hold (a hold in progress ends) and
    /// their rejections are not counted as slip.
    /// Counted in [`NavCounters::imu_shocks`].
    pub fn imu_shock(&mut self, velocity_sigma_m_s: f64) {
        self.counters.imu_shocks = self.counters.imu_shocks.saturating_add(1);
        // The intervals from the one in progress until the kinematics re-anchors the velocity
        // carry the shock's error: the wheels and the IMU disagree because of it, not because
        // of slip. A hold it already started ends.
        self.shock_grace = SHOCK_GRACE_INTERVALS;
        self.shock_accepted = 0;
        self.reject_history = 0;
        self.reject_streak = 0;
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        if !(velocity_sigma_m_s.is_finite() && velocity_sigma_m_s > 0.0) {
            return;
        }
        let result = ekf.inflate_velocity(velocity_sigma_m_s, 0.0);
        self.recorder.inflate_velocity(velocity_sigma_m_s, 0.0);
        if let Err(e) = result {
            self.ekf_error(e);
        }
    }

    /// RG1: one checked IMU sample (`None`: no new sample this frame).
    #[inline(never)]
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
            if self.config.odometry.contact_angles || self.config.odometry.contact_translation {
                self.integrate_gyro(s);
            }
            self.traj.gyro(s);
        }
    }

    fn release(&mut self, handle: Option<CloneHandle>) {
        if let (Some(h), Some(ekf)) = (handle, self.ekf_running.then_some(&mut self.ekf)) {
            self.recorder.release(h.t_us());
            if ekf.release(h).is_err() {
                self.counters.ekf_errors = self.counters.ekf_errors.saturating_add(1);
            }
        }
    }

    /// RG4: one checked sun reading with the sun in view (RB sec. 5.1). While aligning it is
    /// kept for the heading. Afterwards it updates the EKF; [`NavConfig::sun_streak`] refusals
    /// in a row by the sun's gate (the filter's heading drifted beyond its covariance, e.g.
    /// kinematic yaw fused while the wheels slip) inflate the heading covariance by the last
    /// residual angle (at least 0.01 rad) so that the next reading corrects it; counted in
    /// [`NavCounters::sun_streaks`].
    pub fn sun(&mut self, reading: &SunReading) {
        if self.mode == NavMode::Aligning {
            self.align.add_sun(reading);
            return;
        }
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        let result = ekf.update_sun(reading);
        self.recorder.sun(reading);
        match result {
            Ok(u) if u.applied => {
                self.sun_rejections = 0;
                self.counters.sun_applied = self.counters.sun_applied.saturating_add(1)
            }
            Ok(u) => {
                self.counters.sun_refused = self.counters.sun_refused.saturating_add(1);
                self.sun_rejections = self.sun_rejections.saturating_add(1);
                if self.sun_rejections >= self.config.sun_streak {
                    self.sun_rejections = 0;
                    let angle = crate::linalg::sqrt(
                        u.residual[0] * u.residual[0] + u.residual[1] * u.residual[1],
                    );
                    let sigma = if angle.is_finite() {
                        angle.clamp(0.01, 1.0)
                    } else {
                        0.01
                    };
                    self.counters.sun_streaks = self.counters.sun_streaks.saturating_add(1);
                    let r = ekf.inflate_heading(sigma);
                    self.recorder.inflate_heading(sigma);
                    if let Err(e) = r {
                        self.ekf_error(e);
                    }
                }
            }
            Err(_) => self.counters.sun_refused = self.counters.sun_refused.saturating_add(1),
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
