//! Fault injection, selected per scenario: dropouts, stuck values, NaN, black frames and time
//! jumps, each on one device over a time window.

use serde::Deserialize;

/// Device a fault applies to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultDevice {
    /// IMU.
    Imu,
    /// Joint encoders.
    Joints,
    /// Stereo camera.
    Camera,
    /// Sun sensor.
    Sun,
    /// Clock.
    Clock,
}

/// What goes wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// The device does not answer (`ErrorKind::Timeout`).
    Dropout,
    /// The device repeats its last values (with fresh time stamps).
    Stuck,
    /// The values are NaN.
    Nan,
    /// The camera delivers all-zero images.
    BlackFrame,
    /// The time stamps jump by `jump_s` during the window.
    TimeJump,
}

/// One injected fault.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct FaultSpec {
    /// Device.
    pub device: FaultDevice,
    /// Kind.
    pub kind: FaultKind,
    /// Start of the window, s of simulated time.
    pub start_s: f64,
    /// Length of the window, s.
    pub duration_s: f64,
    /// Time jump, s (for [`FaultKind::TimeJump`]; may be negative).
    #[serde(default)]
    pub jump_s: f64,
}

/// The faults of a run.
#[derive(Debug, Clone, Default)]
pub struct Faults {
    specs: Vec<FaultSpec>,
}

impl Faults {
    /// The faults in `specs`.
    pub fn new(specs: Vec<FaultSpec>) -> Self {
        Self { specs }
    }

    /// The fault of `kind` on `device` active at `t_us`, if any.
    pub fn active(&self, device: FaultDevice, kind: FaultKind, t_us: u64) -> Option<&FaultSpec> {
        let t = t_us as f64 * 1e-6;
        self.specs.iter().find(|f| {
            f.device == device && f.kind == kind && t >= f.start_s && t < f.start_s + f.duration_s
        })
    }

    /// Time stamp of a reading taken at `t_us` on `device`, after any active time jump.
    pub fn stamp(&self, device: FaultDevice, t_us: u64) -> u64 {
        match self.active(device, FaultKind::TimeJump, t_us) {
            Some(f) => {
                let jump = (f.jump_s * 1e6).round() as i64;
                t_us.saturating_add_signed(jump)
            }
            None => t_us,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SIM-9: a fault is active only on its device, of its kind, inside its window; time jumps
    /// shift the stamps.
    #[test]
    fn sim_9_fault_windows() {
        let f = Faults::new(vec![FaultSpec {
            device: FaultDevice::Imu,
            kind: FaultKind::TimeJump,
            start_s: 1.0,
            duration_s: 0.5,
            jump_s: -0.25,
        }]);
        assert!(f
            .active(FaultDevice::Imu, FaultKind::TimeJump, 999_999)
            .is_none());
        assert!(f
            .active(FaultDevice::Imu, FaultKind::TimeJump, 1_000_000)
            .is_some());
        assert!(f
            .active(FaultDevice::Sun, FaultKind::TimeJump, 1_200_000)
            .is_none());
        assert!(f
            .active(FaultDevice::Imu, FaultKind::Nan, 1_200_000)
            .is_none());
        assert_eq!(f.stamp(FaultDevice::Imu, 1_200_000), 950_000);
        assert_eq!(f.stamp(FaultDevice::Imu, 1_500_000), 1_500_000);
    }
}
