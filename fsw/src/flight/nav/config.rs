//! The navigator's settings: one slice per component, and the Rocky 8 flight values with their
//! sources.

use super::align::AlignConfig;
use super::boresight::BoresightConfig;
use super::calibration::CalibrationConfig;
use super::drive::DriveConfig;
use super::filter::FilterConfig;
use super::goal::GoalConfig;
use super::kin_aiding::{KinAidingConfig, KIN_CRAB_ALLOWANCE};
use super::loc_nav::LocalizationSettings;
use super::protection::ProtectionConfig;
use super::radius::RadiusScaleConfig;
use super::sun::SunConfig;
use super::vo_aiding::VoAidingConfig;
use crate::estimation::EkfConfig;
use crate::guidance::GuidanceConfig;
use crate::kinematics::track::TrackConfig;
use crate::kinematics::{
    wheel_contact_points, OdometryConfig, RoverGeometry, SuspensionState, ROCKY8,
};
use crate::vo::VoConfig;

/// Navigation settings (constant during a drive): the vehicle, then each component's slice.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavConfig {
    /// Rover geometry for kinematics (one source of truth: [`ROCKY8`]).
    pub geometry: RoverGeometry,
    /// The filter ([`super::NavFilter`]).
    pub filter: FilterConfig,
    /// The alignment at rest and the drive's start ([`super::Aligner`]).
    pub align: AlignConfig,
    /// The kinematic aiding ([`super::KinAiding`]).
    pub kin: KinAidingConfig,
    /// The VO aiding ([`super::VoAiding`]).
    pub vo: VoAidingConfig,
    /// The sun aiding ([`super::SunAiding`]).
    pub sun: SunConfig,
    /// The calibration learnt over capture intervals ([`super::Calibration`]).
    pub calibration: CalibrationConfig,
    /// The drive ([`super::Drive`]).
    pub drive: DriveConfig,
    /// The goal-directed navigation ([`super::GoalNav`]).
    pub goal: GoalConfig,
    /// Track memory of the 3D kinematic dead reckoning ([`super::Navigator::kin3d`]): the
    /// body's heave from the path of the front axles ([`crate::kinematics::track`]). Used only
    /// with the contact-angle translation ([`OdometryConfig::contact_translation`]).
    pub track: TrackConfig,
}

impl NavConfig {
    /// Defaults for Rocky 8 starting at `position` (m, `N`) with heading `yaw_rad`: each
    /// component's flight settings.
    pub fn rocky8(position: [f64; 3], yaw_rad: f64) -> Self {
        let xy = match wheel_contact_points(&ROCKY8, &SuspensionState::default()) {
            Ok(p) => p.map(|c| [c.x, c.y]),
            Err(_) => [[0.0; 2]; 6],
        };
        Self {
            geometry: ROCKY8,
            filter: FilterConfig::rocky8(),
            align: AlignConfig::rocky8(position, yaw_rad),
            kin: KinAidingConfig::rocky8(),
            vo: VoAidingConfig::rocky8(),
            sun: SunConfig { streak: 3 },
            calibration: CalibrationConfig::rocky8(),
            drive: DriveConfig::rocky8(xy),
            goal: GoalConfig::rocky8(),
            track: TrackConfig::DEFAULT,
        }
    }
}

impl FilterConfig {
    /// The flight filter: the EKF defaults (IMU noise of the rover's class, Mars gravity) and 16 replayed operations per background slice.
    pub fn rocky8() -> Self {
        Self {
            ekf: EkfConfig::default(),
            replay_ops_per_slice: 16,
        }
    }
}

impl AlignConfig {
    /// The flight alignment for a drive starting at `position` (m, `N`) with the plan's heading `yaw_rad`.
    pub fn rocky8(position: [f64; 3], yaw_rad: f64) -> Self {
        Self {
            initial_position_n_m: position,
            initial_yaw_rad: yaw_rad,
            // The ground's knowledge of the start: heading from the end of the previous
            // drive (a few degrees), position from orbital/ground localisation (5 cm here,
            // relative to the drive's own map frame).
            initial_yaw_sigma_rad: 0.05,
            initial_position_sigma_m: 0.05,
            samples: 400,
            // Ten times the per-sample noise of the rover's IMU class (1 mrad/s, 5 mm/s^2
            // at 200 Hz): a rover at rest passes, a spike of 0.2 rad/s or 3 m/s^2 in one of
            // 400 samples does not.
            max_gyro_std_rad_s: 0.01,
            max_accel_std_m_s2: 0.1,
            // One RG4 period (5 s) and a second of margin.
            sun_wait_samples: 1200,
            accel_bias_sigma_m_s2: 1.0e-2,
        }
    }
}

impl KinAidingConfig {
    /// The flight kinematic aiding.
    pub fn rocky8() -> Self {
        Self {
            // Eq. 15 kinematics (contacts below the axles) with the calibrated noise model
            // for the gate and the EKF. The contact-angle estimator (V99 sec. 6) runs as the
            // translation of the 3D kinematic dead reckoning (`contact_translation`) only:
            // its step takes the gyro rotation as an input and its covariance does not
            // describe its residuals (note 0029). The rough-terrain
            // inverse kinematics gets the angles estimated over 10 mm windows of travel
            // (`ContactConfig::window_travel_m`).
            odometry: OdometryConfig {
                contact_translation: true,
                contact: crate::kinematics::ContactConfig {
                    window_travel_m: 0.01,
                    ..crate::kinematics::ContactConfig::default()
                },
                ..OdometryConfig::default()
            },
            slip_hold_cycles: 20,
            slip_hold_rejections: 1,
            vo_loss_slip_fraction: 0.3,
            vo_loss_translation_only: true,
            // Slip below the gate's detection on firm ground (about 8 % of a step,
            // docs/results/slip-detection.md).
            vo_loss_drift_fraction: 0.05,
            crab_allowance: KIN_CRAB_ALLOWANCE,
            // 4 s of rejections with no VO fused: longer than the rover goes without a VO
            // update while slipping with VO alive (a capture every 0.1 m, 1-2 s).
            reject_streak_cycles: 80,
            streak_velocity_sigma_m_s: 0.01,
            streak_accel_bias_sigma_m_s2: 0.01,
            blind_anchor_cycles: 300,
            stopped_wheel_rate_rad_s: 0.01,
            radius_scale: RadiusScaleConfig::default(),
        }
    }
}

impl VoAidingConfig {
    /// The flight VO aiding.
    pub fn rocky8() -> Self {
        Self {
            enabled: true,
            // The EKF prior predicts each feature within a few pixels over a 1 s step, so
            // the tracking window is 8 px, not the stand-alone default of 24 px (9x less
            // work), and the stereo search of a tracked feature covers +-8 px around the
            // disparity of the predicted point instead of all 128 disparities.
            pipeline: VoConfig {
                search_radius_px: 8,
                track_disparity_margin_px: 8,
                ..VoConfig::default()
            },
            warn_d2: 1.0e3,
            gate_enabled: true,
            gate_slip_fraction: 0.3,
            gate_slip_floor_m: 0.02,
            reject_streak: 3,
            capture_distance_m: 0.10,
            capture_angle_rad: 10.0_f64.to_radians(),
            capture_max_interval_us: 10_000_000,
            capture_retry_us: 1_000_000,
            timeout_cycles: 60,
        }
    }
}

impl CalibrationConfig {
    /// The flight calibration: the boresight estimate and the dead reckoning's scale on, 1 m windows within 4 %.
    pub fn rocky8() -> Self {
        Self {
            boresight: BoresightConfig::default(),
            dr_scale: true,
            dr_scale_estimate: RadiusScaleConfig::default(),
        }
    }
}

impl DriveConfig {
    /// The flight drive for guidance on the wheel contact points `wheel_xy_m` (m, `R`, zero suspension state).
    pub fn rocky8(wheel_xy_m: [[f64; 2]; 6]) -> Self {
        Self {
            guidance: GuidanceConfig::rocky8(wheel_xy_m),
            protection: ProtectionConfig::default(),
            slip_compensation: true,
            blind_stop_interval_m: 1.0,
            blind_stop_cycles: 60,
            imu_timeout_frames: 20,
            joints_timeout_cycles: 10,
            vo_start_timeout_cycles: 600,
            // Rough-terrain IK on (note 0031).
            ik_contact_angles: true,
            ik_contact_max_angle_rad: 1.0,
            ik_contact_min_angle_rad: 0.1,
        }
    }
}

impl GoalConfig {
    /// The flight goal-directed navigation (off: path drives).
    pub fn rocky8() -> Self {
        Self {
            hazard_avoidance: false,
            // The hazard cells of a rock end where its flank is still below the step and
            // slope limits; its skirt reaches about 0.1 m further, so the margin over the
            // half-width is 0.3 m (note 0034).
            perception: crate::perception::PerceptionConfig {
                grow_margin_m: 0.3,
                ..crate::perception::PerceptionConfig::default()
            },
            // Guidance follows the planner's polyline with a carrot, which cuts the corners
            // of a path round an obstacle: the clearance over the grown obstacles covers
            // it. A path the planner hands over ends at least twice guidance's stopping
            // tolerance (0.05 m) away: a path ending within the tolerance is arrived at
            // before it is driven.
            planner: crate::planning::PlannerConfig {
                clearance_m: 0.15,
                min_reach_m: 0.1,
                ..crate::planning::PlannerConfig::default()
            },
            map_interval_m: 1.0,
            localization: LocalizationSettings::DEFAULT,
        }
    }
}
