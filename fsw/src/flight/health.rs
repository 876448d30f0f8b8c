//! Device health and the frame status record (telemetry, [`crate::telemetry`]).

use serde::{Deserialize, Serialize};

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
    /// ([`super::DeviceId`]).
    pub health: [DeviceHealth; super::DEVICE_COUNT],
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::telemetry::{encode, EncodeError, RecordKind, MAX_RECORD_BYTES};

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
            }; super::super::DEVICE_COUNT],
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
}
