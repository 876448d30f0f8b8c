//! The kinematic aiding's settings, counters, inputs and outcome.

use crate::flight::nav::radius::RadiusScaleConfig;
use crate::kinematics::{OdometryConfig, VehicleCommand};

/// Settings of the kinematic aiding (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KinAidingConfig {
    /// Kinematic odometry noise model (eq. 15) and the contact-angle estimator.
    pub odometry: OdometryConfig,
    /// Slip hold: after a kinematic interval is rejected, the next intervals are not fused for
    /// this many RG2 cycles even when the gate accepts them (a slipping rover produces some
    /// intervals whose slip is within the noise; fusing them would teach the filter the crab
    /// angle as a heading error). Their slip vector is zero (H04: no slip when the gate
    /// accepts); they count in [`KinCounters::kin_held`]. Why: note 0016.
    pub slip_hold_cycles: u32,
    /// Statistical trigger of the slip hold: the hold starts only when at least this many of
    /// the last [`Self::slip_hold_cycles`] tested intervals (at most 32) were rejected. Flight
    /// default 1: any rejection holds. Why: note 0016.
    pub slip_hold_rejections: u32,
    /// Slip allowance of the fusion without VO, as a fraction of the kinematic step.
    pub vo_loss_slip_fraction: f64,
    /// The fusion without VO fuses the kinematic translation only (rotation from the gyro and
    /// the sun).
    pub vo_loss_translation_only: bool,
    /// Growth of the horizontal position sigma per metre of accepted travel fused without VO
    /// (a systematic slip the gate cannot see), fraction.
    pub vo_loss_drift_fraction: f64,
    /// Crab allowance of a kinematic interval fused while VO is alive: the lateral translation
    /// is fused with `(crab_allowance * |sin cross slope| * step)^2` added to its variance
    /// (m^2; `step` the interval's translation, m; the cross slope from the EKF attitude), after
    /// the gate tested the interval at its own covariance. `f64::INFINITY` does not fuse the
    /// lateral part on a slope at all. Why: note 0017.
    pub crab_allowance: f64,
    /// Gate rejections in a row, with no VO fused meanwhile, after which the filter's velocity
    /// covariance is inflated (RG2 cycles; [`policy`]'s streak recovery).
    pub reject_streak_cycles: u32,
    /// Velocity 1-sigma added by the streak recovery (and the least added in a shock's grace),
    /// m/s per axis.
    pub streak_velocity_sigma_m_s: f64,
    /// Accelerometer-bias 1-sigma added by the streak recovery, m/s^2 per axis.
    pub streak_accel_bias_sigma_m_s2: f64,
    /// RG2 cycles after the last zero-velocity update during which the IMU velocity counts as
    /// anchored in the stop-and-go drive without VO (a rejected kinematic interval is not
    /// fused; after that it is fused with the slip allowance as without stop-and-go).
    pub blind_anchor_cycles: u32,
    /// Below this measured wheel rate (rad/s, every wheel) with a zero command the rover is
    /// stopped and a zero-velocity update is applied.
    pub stopped_wheel_rate_rad_s: f64,
    /// Online estimate of the effective wheel-radius scale of eq. 15's translation.
    pub radius_scale: RadiusScaleConfig,
}

/// Counters of the kinematic aiding (telemetry, [`super::NavCounters`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct KinCounters {
    /// Kinematic intervals tested by the gate (eq. 46).
    pub kin_tested: u32,
    /// Of those, rejected (slip detected).
    pub kin_rejected: u32,
    /// Accepted by the gate but not fused because slip was detected within the hold time.
    pub kin_held: u32,
    /// Fused with the slip allowance because VO had not updated for the VO timeout.
    pub kin_ungated: u32,
    /// Streaks of gate rejections that triggered the covariance recovery.
    pub kin_streaks: u32,
    /// Kinematic intervals that could not be formed (odometry or clone error).
    pub kin_errors: u32,
    /// Zero-velocity updates applied.
    pub zupts: u32,
    /// Intervals the gate rejected without VO while a recent stop anchored the IMU velocity:
    /// not fused, the IMU carried the motion.
    pub kin_imu_carried: u32,
    /// IMU shocks ([`KinAiding::imu_shock`]).
    pub imu_shocks: u32,
}

/// VO's health as the kinematic aiding needs it (from [`super::VoAiding::health`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VoHealth {
    /// VO runs in this drive.
    pub enabled: bool,
    /// RG2 cycles since the last VO update was fused.
    pub cycles_since_fused: u32,
    /// VO counts as lost after more cycles than this without a fused update.
    pub timeout_cycles: u32,
}

impl VoHealth {
    /// VO is off or has not been fused for more than [`Self::timeout_cycles`].
    pub fn lost(&self) -> bool {
        !self.enabled || self.cycles_since_fused > self.timeout_cycles
    }
}

/// What the RG2 cycle of the kinematic aiding gets from the rest of the navigator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KinInputs {
    /// VO's health at the start of the cycle.
    pub vo: VoHealth,
    /// The stop-and-go drive without VO is configured ([`super::DriveConfig::blind_stop_interval_m`]).
    pub stop_and_go: bool,
    /// The rover command of the last guidance cycle (rover frame, m/s and rad/s): a stop needs
    /// it zero.
    pub command: VehicleCommand,
}

/// One kinematic interval's wheel and EKF travel, for fault protection's slip check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Travel {
    /// Wheel travel (the scaled kinematic translation), m.
    pub wheel_m: f64,
    /// EKF travel over the interval, m.
    pub ekf_m: f64,
    /// The stop-and-go drive's last stop anchors the IMU velocity (the EKF travel is measured
    /// without VO).
    pub imu_anchored: bool,
}

/// What one RG2 cycle of the kinematic aiding hands back to the navigator.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct KinOutcome {
    /// An interval was closed and tested: one more RG2 cycle counts towards VO's timeout.
    pub closed: bool,
    /// The interval's travel, when the EKF poses of its ends are known.
    pub travel: Option<Travel>,
}
