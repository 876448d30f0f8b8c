//! # Telemetry records
//!
//! Fixed-size records, serialised with `postcard` into a caller-provided buffer (no allocation)
//! and handed to the HAL [`rover_hal::Telemetry`] sink. Each record starts with a one-byte
//! [`RecordKind`] tag so a ground tool can split a mixed stream.

use crate::flight::nav::vo_gate::VoGateVerdict;
use crate::flight::nav::{NavCounters, NavMode, Navigator};
use serde::{Deserialize, Serialize};

/// Largest encoded record, bytes. Every record type is checked against it in the tests.
pub const MAX_RECORD_BYTES: usize = 320;

/// Tag byte that starts every record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[repr(u8)]
pub enum RecordKind {
    /// [`FrameStatus`].
    FrameStatus = 1,
    /// [`NavTelemetry`].
    NavStatus = 2,
}

/// Device health counters (FDIR inputs), one set per device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DeviceHealth {
    /// Successful reads that passed the checks.
    pub good: u32,
    /// Calls that returned an error.
    pub errors: u32,
    /// Readings with a repeated time stamp (stale).
    pub stale: u32,
    /// Readings with a time stamp earlier than the previous one.
    pub time_backwards: u32,
    /// Readings flagged invalid by the device or containing non-finite or out-of-range values.
    pub invalid: u32,
    /// Readings whose time stamp leapt ahead of the device's time base (refused).
    pub time_jumps: u32,
    /// Changes of the device's time base accepted after a leap persisted.
    pub resyncs: u32,
}

impl DeviceHealth {
    /// All counters zero (as [`Default`], usable in a `const`).
    pub const EMPTY: Self = Self {
        good: 0,
        errors: 0,
        stale: 0,
        time_backwards: 0,
        invalid: 0,
        time_jumps: 0,
        resyncs: 0,
    };

    /// Total number of bad readings of any kind.
    pub fn faults(&self) -> u32 {
        self.errors
            .saturating_add(self.stale)
            .saturating_add(self.time_backwards)
            .saturating_add(self.invalid)
            .saturating_add(self.time_jumps)
    }
}

/// Periodic status record (RG2): executive counters, device health and the power subsystem's
/// last accepted reading.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FrameStatus {
    /// Minor-frame tick of the record.
    pub tick: u64,
    /// Frames whose execution exceeded the minor-frame period.
    pub cycle_slips: u64,
    /// Latched timing fault (consecutive cycle slips).
    pub timing_fault: bool,
    /// Health of the IMU, joints, stereo camera, sun sensor and power subsystem, in that order
    /// ([`crate::flight::DeviceId`]).
    pub health: [DeviceHealth; crate::flight::DEVICE_COUNT],
    /// Stereo frames completed since boot.
    pub stereo_frames: u32,
    /// Telemetry records the sink refused (counted, then dropped).
    pub telemetry_dropped: u32,
    /// Battery energy used since boot of the last accepted power reading, J (0 before the
    /// first; [`rover_hal::PowerReading::energy_used_j`]). Double precision: a sol's drive is
    /// about 10^6 J, which single precision would round to 0.1 J.
    pub energy_used_j: f64,
    /// Bus power of the last accepted power reading, W (0 before the first; single precision:
    /// telemetry).
    pub bus_power_w: f32,
}

/// Navigation status, sent every RG2 cycle (single precision: telemetry, not state).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct NavTelemetry {
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
    pub fault_response: crate::flight::nav::protection::FaultResponse,
    /// Navigation counters.
    pub counters: NavCounters,
}

impl NavTelemetry {
    /// The record for `nav` at `tick`.
    pub fn from_navigator(tick: u64, nav: &Navigator) -> Self {
        let pose = nav.pose();
        let (roll, pitch, yaw) = pose.q_nr.euler_angles();
        let (velocity, sigma, heading_sigma) = match nav.ekf() {
            Some(e) => {
                let p = e.covariance();
                let i = crate::estimation::state::I_P;
                let s = |k: usize| crate::linalg::sqrt(p[(i + k, i + k)].max(0.0)) as f32;
                let v = e.state().v_n;
                (
                    [v.x as f32, v.y as f32, v.z as f32],
                    [s(0), s(1), s(2)],
                    e.heading_sigma_rad() as f32,
                )
            }
            None => ([0.0; 3], [0.0; 3], 0.0),
        };
        let slip = nav.slip();
        let gate = nav.gate();
        let cmd = nav.command();
        let vo_gate = nav.vo_gate();
        let (cross, goal) = match nav.guidance_output() {
            Some(g) => (g.projection.cross_track_m as f32, g.goal_distance_m as f32),
            None => (0.0, 0.0),
        };
        Self {
            tick,
            mode: nav.mode(),
            position_n_m: [pose.p_n.x as f32, pose.p_n.y as f32, pose.p_n.z as f32],
            rpy_rad: [roll as f32, pitch as f32, yaw as f32],
            velocity_n_m_s: velocity,
            position_sigma_m: sigma,
            heading_sigma_rad: heading_sigma,
            slip: [slip.x_m as f32, slip.y_m as f32, slip.phi_rad as f32],
            gate_d2: gate.d2 as f32,
            gate_accepted: gate.accepted,
            command: [
                cmd.x_dot_m_s as f32,
                cmd.y_dot_m_s as f32,
                cmd.yaw_rate_rad_s as f32,
            ],
            cross_track_m: cross,
            goal_distance_m: goal,
            vo_gate_verdict: vo_gate.verdict,
            vo_gate_d2: [vo_gate.d2_rotation as f32, vo_gate.d2_pose as f32],
            vo_consecutive_rejections: vo_gate.consecutive_rejections,
            vo_reject_streak: vo_gate.streak,
            fault_response: nav.fault_response(),
            counters: *nav.counters(),
        }
    }
}

/// Encoding failed: the buffer is too small for the record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EncodeError;

/// Encode a record with its tag into `buffer`; returns the used prefix.
pub fn encode<'a, T: Serialize>(
    kind: RecordKind,
    record: &T,
    buffer: &'a mut [u8],
) -> Result<&'a [u8], EncodeError> {
    let (tag, body) = buffer.split_first_mut().ok_or(EncodeError)?;
    *tag = kind as u8;
    let used = postcard::to_slice(record, body)
        .map_err(|_| EncodeError)?
        .len();
    buffer.get(..used + 1).ok_or(EncodeError)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// TLM-1: the largest record fits MAX_RECORD_BYTES and decodes back to itself.
    #[test]
    fn tlm_1_frame_status_round_trip() {
        let record = FrameStatus {
            tick: u64::MAX,
            cycle_slips: u64::MAX,
            timing_fault: true,
            health: [DeviceHealth {
                good: u32::MAX,
                errors: u32::MAX,
                stale: u32::MAX,
                time_backwards: u32::MAX,
                invalid: u32::MAX,
                time_jumps: u32::MAX,
                resyncs: u32::MAX,
            }; crate::flight::DEVICE_COUNT],
            stereo_frames: u32::MAX,
            telemetry_dropped: u32::MAX,
            energy_used_j: f64::MAX,
            bus_power_w: f32::MAX,
        };
        let mut buffer = [0u8; MAX_RECORD_BYTES];
        let bytes = match encode(RecordKind::FrameStatus, &record, &mut buffer) {
            Ok(b) => b,
            Err(e) => panic!("encode failed: {e:?}"),
        };
        assert_eq!(bytes[0], RecordKind::FrameStatus as u8);
        let decoded: FrameStatus = match postcard::from_bytes(&bytes[1..]) {
            Ok(d) => d,
            Err(e) => panic!("decode failed: {e:?}"),
        };
        assert_eq!(decoded, record);
        // Headroom left for the fields other changes add (reported when this test runs).
        std::println!(
            "FrameStatus worst case: {} of {MAX_RECORD_BYTES} bytes",
            bytes.len()
        );
        let mut small = [0u8; 8];
        assert_eq!(
            encode(RecordKind::FrameStatus, &record, &mut small),
            Err(EncodeError)
        );
        assert_eq!(
            encode(RecordKind::FrameStatus, &record, &mut []),
            Err(EncodeError)
        );
    }

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
        let record = NavTelemetry {
            tick: u64::MAX,
            mode: NavMode::Safed,
            gate_accepted: true,
            vo_gate_verdict: VoGateVerdict::RejectedError,
            vo_consecutive_rejections: c,
            vo_reject_streak: true,
            fault_response: crate::flight::nav::protection::FaultResponse::MotorStall { wheel: 5 },
            counters,
            ..NavTelemetry::default()
        };
        let mut buffer = [0u8; MAX_RECORD_BYTES];
        let bytes = match encode(RecordKind::NavStatus, &record, &mut buffer) {
            Ok(b) => b,
            Err(e) => panic!("encode failed: {e:?}"),
        };
        let decoded: NavTelemetry = match postcard::from_bytes(&bytes[1..]) {
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
