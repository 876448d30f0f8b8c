//! # Navigation status: what the navigator reports
//!
//! [`NavStatus`] is the navigation telemetry record (sent every RG2B cycle), composed by
//! [`super::Navigator::status`] from the components' statuses; [`NavCounters`] is the flat
//! set of every component's counters (telemetry and the simulator's summary). The telemetry
//! encoding ([`crate::telemetry`]) takes the record as it is.

use super::protection::FaultResponse;
use super::vo_gate::{VoGateStatus, VoGateVerdict};
use crate::estimation::GateDecision;
use crate::types::{Quat, Vec3};
use serde::{Deserialize, Serialize};

/// What the navigator is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
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
    /// Stopped by fault protection ([`super::Navigator::fault_response`] says why); latched until the
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
    /// At the origin, level, heading north.
    pub fn identity() -> Self {
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

/// Counters of the navigation functions (telemetry and the simulator's summary).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
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
    /// Of those, applied at capture time and replayed to the present ([`crate::estimation::Recorder`]).
    pub vo_replayed: u32,
    /// Of those, lost because the recording overflowed before the sliced replay caught up.
    pub vo_replay_lost: u32,
    /// VO attempts that failed (after the first keyframe).
    pub vo_failures: u32,
    /// VO relative poses fused with `d_m^2 > vo_warn_d2` (the estimate had drifted).
    pub vo_large_d2: u32,
    /// VO relative poses rejected by the VO gate and not fused ([`super::vo_gate`]); the rejections
    /// by the 6-dof pose test are `vo_rejected - vo_rejected_rotation`.
    pub vo_rejected: u32,
    /// Of those, rejected by the rotation check against the gyro-propagated rotation.
    pub vo_rejected_rotation: u32,
    /// Streaks of [`super::VoAidingConfig::reject_streak`] consecutive VO rejections.
    pub vo_reject_streaks: u32,
    /// VO poses fused after a streak although the gate rejected them, with inflated covariance.
    pub vo_forced: u32,
    /// Captures skipped because no clone slot was free ([`super::Navigator::capture_skipped`]); a
    /// capture due while VO is busy waits for it instead.
    pub captures_skipped: u32,
    /// Captures started because the EKF travelled [`super::VoAidingConfig::capture_distance_m`].
    pub captures_distance: u32,
    /// Captures started because the EKF attitude turned [`super::VoAidingConfig::capture_angle_rad`].
    pub captures_heading: u32,
    /// Captures started by the time fallback [`super::VoAidingConfig::capture_max_interval_us`] (or the
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
    /// Fault-protection stops (see [`super::Navigator::fault_response`]).
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
    /// Stops of the stop-and-go drive without VO ([`super::DriveConfig::blind_stop_interval_m`]).
    pub blind_stops: u32,
    /// Kinematic intervals the gate rejected without VO while the IMU velocity was anchored
    /// by a recent zero-velocity update: not fused, the IMU carried the motion.
    pub kin_imu_carried: u32,
    /// IMU shocks: accelerometer samples saturated at or refused beyond the sensor's range
    /// ([`super::KinAiding::imu_shock`]); the velocity variance was inflated.
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

impl GateStatus {
    /// No gate verdict yet (as [`Default`], usable in a `const`).
    pub const EMPTY: Self = Self {
        d2: 0.0,
        accepted: false,
        dof: 0,
        residual: [0.0; 6],
        sigma: [0.0; 6],
    };

    /// The status of the gate decision `d` (eq. 46).
    pub fn of(d: &GateDecision) -> Self {
        Self {
            d2: d.d2,
            accepted: d.accepted,
            dof: d.dof as u8,
            residual: core::array::from_fn(|k| d.residual.get(k).copied().unwrap_or(0.0)),
            sigma: core::array::from_fn(|k| {
                crate::linalg::sqrt(
                    d.residual_covariance
                        .get((k, k))
                        .copied()
                        .unwrap_or(0.0)
                        .max(0.0),
                )
            }),
        }
    }
}

impl Default for PoseEstimate {
    fn default() -> Self {
        Self::identity()
    }
}

/// Navigation status, sent every RG2 cycle (single precision: telemetry, not state).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct NavStatus {
    /// Minor-frame tick.
    pub tick: u64,
    /// Navigation mode.
    pub mode: NavMode,
    /// EKF position, m, `N` (north, east, down).
    pub position_n_m: [f32; 3],
    /// EKF roll, pitch, yaw (`R` to `N`, z-y-x), rad.
    pub rpy_rad: [f32; 3],
    /// EKF velocity, m/s, `N`.
    pub velocity_n_m_s: [f32; 3],
    /// 1-sigma of the position, m, per `N` axis.
    pub position_sigma_m: [f32; 3],
    /// 1-sigma of the heading, rad.
    pub heading_sigma_rad: f32,
    /// Slip vector `[x m, y m, yaw rad]` of the last RG2 cycle (EKF minus kinematics, `R`).
    pub slip: [f32; 3],
    /// Mahalanobis `d_m^2` of the last kinematic interval (eq. 46).
    pub gate_d2: f32,
    /// The gate accepted the last kinematic interval.
    pub gate_accepted: bool,
    /// Rover command `[x_dot m/s, y_dot m/s, yaw rate rad/s]`, `R`.
    pub command: [f32; 3],
    /// Distance from the path, m (estimated pose).
    pub cross_track_m: f32,
    /// Distance to the goal, m (estimated pose).
    pub goal_distance_m: f32,
    /// VO gate verdict on the last VO pose (the reason of the last rejection while it is one).
    pub vo_gate_verdict: VoGateVerdict,
    /// VO gate statistics of the last VO pose: `[d_rot^2, d_pose^2]` (dimensionless).
    pub vo_gate_d2: [f32; 2],
    /// Consecutive VO rejections.
    pub vo_consecutive_rejections: u32,
    /// A VO rejection streak was reached (the next rejected pose is fused inflated).
    pub vo_reject_streak: bool,
    /// Why fault protection stopped the drive (`None` unless the mode is `Stopped`).
    pub fault_response: FaultResponse,
    /// Navigation counters.
    pub counters: NavCounters,
}

/// The filter's part of [`NavStatus`]: pose, velocity and their uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterStatus {
    /// The navigation pose (`N`).
    pub pose: super::PoseEstimate,
    /// EKF velocity, m/s, `N` (zero before the filter runs).
    pub velocity_n_m_s: [f32; 3],
    /// 1-sigma of the position, m, per `N` axis (zero before the filter runs).
    pub position_sigma_m: [f32; 3],
    /// 1-sigma of the heading, rad (zero before the filter runs).
    pub heading_sigma_rad: f32,
}

impl NavStatus {
    /// The record at `tick` from the parts the components report.
    #[allow(clippy::too_many_arguments)]
    pub fn compose(
        tick: u64,
        mode: NavMode,
        filter: &FilterStatus,
        slip: &crate::guidance::SlipVector,
        gate: &GateStatus,
        command: &crate::kinematics::VehicleCommand,
        guidance: Option<&crate::guidance::GuidanceCommand>,
        vo_gate: &VoGateStatus,
        fault_response: FaultResponse,
        counters: NavCounters,
    ) -> Self {
        let pose = filter.pose;
        let (roll, pitch, yaw) = pose.q_nr.euler_angles();
        let (cross, goal) = match guidance {
            Some(g) => (g.projection.cross_track_m as f32, g.goal_distance_m as f32),
            None => (0.0, 0.0),
        };
        Self {
            tick,
            mode,
            position_n_m: [pose.p_n.x as f32, pose.p_n.y as f32, pose.p_n.z as f32],
            rpy_rad: [roll as f32, pitch as f32, yaw as f32],
            velocity_n_m_s: filter.velocity_n_m_s,
            position_sigma_m: filter.position_sigma_m,
            heading_sigma_rad: filter.heading_sigma_rad,
            slip: [slip.x_m as f32, slip.y_m as f32, slip.phi_rad as f32],
            gate_d2: gate.d2 as f32,
            gate_accepted: gate.accepted,
            command: [
                command.x_dot_m_s as f32,
                command.y_dot_m_s as f32,
                command.yaw_rate_rad_s as f32,
            ],
            cross_track_m: cross,
            goal_distance_m: goal,
            vo_gate_verdict: vo_gate.verdict,
            vo_gate_d2: [vo_gate.d2_rotation as f32, vo_gate.d2_pose as f32],
            vo_consecutive_rejections: vo_gate.consecutive_rejections,
            vo_reject_streak: vo_gate.streak,
            fault_response,
            counters,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::telemetry::{encode, RecordKind, MAX_RECORD_BYTES};

    /// TLM-2: the navigation record with every counter and field at its largest encoding fits
    /// MAX_RECORD_BYTES and decodes back to itself.
    #[test]
    fn tlm_2_nav_status_worst_case_fits() {
        let c = u32::MAX;
        let counters = NavCounters {
            track_matched: c,
            track_unmatched: c,
            kin_tested: c,
            kin_rejected: c,
            kin_held: c,
            kin_ungated: c,
            kin_streaks: c,
            kin_errors: c,
            zupts: c,
            vo_updates: c,
            vo_fused: c,
            vo_replayed: c,
            vo_replay_lost: c,
            vo_failures: c,
            vo_large_d2: c,
            vo_rejected: c,
            vo_rejected_rotation: c,
            vo_reject_streaks: c,
            vo_forced: c,
            captures_skipped: c,
            captures_distance: c,
            captures_heading: c,
            captures_time: c,
            sun_applied: c,
            sun_refused: c,
            sun_streaks: c,
            fault_stops: c,
            time_rebases: c,
            vo_start_holds: c,
            vo_start_timeouts: c,
            align_restarts: c,
            heading_from_sun: c,
            heading_from_plan: c,
            ekf_errors: c,
            command_errors: c,
            sensor_holds: c,
            blind_stops: c,
            kin_imu_carried: c,
            imu_shocks: c,
        };
        let record = NavStatus {
            tick: u64::MAX,
            mode: NavMode::Safed,
            gate_accepted: true,
            vo_gate_verdict: VoGateVerdict::RejectedError,
            vo_consecutive_rejections: c,
            vo_reject_streak: true,
            fault_response: FaultResponse::MotorStall { wheel: 5 },
            counters,
            ..NavStatus::default()
        };
        let mut buffer = [0u8; MAX_RECORD_BYTES];
        let bytes = match encode(RecordKind::NavStatus, &record, &mut buffer) {
            Ok(b) => b,
            Err(e) => panic!("encode failed: {e:?}"),
        };
        let decoded: NavStatus = match postcard::from_bytes(&bytes[1..]) {
            Ok(d) => d,
            Err(e) => panic!("decode failed: {e:?}"),
        };
        assert_eq!(decoded, record);
        // Headroom left for the fields other changes add (reported when this test runs).
        std::println!(
            "NavStatus worst case: {} of {MAX_RECORD_BYTES} bytes",
            bytes.len()
        );
    }
}
