//! Fault injection, selected per scenario: each fault acts on one device (or one wheel of it)
//! over a time window. Sensor faults act in the device layer ([`crate::devices::world`]: what the flight
//! software reads); physical faults act on the simulator's truth ([`crate::world`]: a stalled wheel
//! does not turn and the vehicle drags it; a slip override holds the wheels' ground speed).
//!
//! | device | kind | effect | `value` (default) |
//! |---|---|---|---|
//! | any sensor | `dropout` | `ErrorKind::Timeout` | |
//! | imu, joints, sun, power | `stuck` | last values repeated with fresh stamps (joints with `wheel`: that wheel's drive and steering values only) | |
//! | imu, joints, sun, power | `nan` | NaN values (imu: gyro; joints: the wheel's drive angle, rate and steering, all wheels and the rocker without `wheel`; sun: vector; power: energy used and bus power) | |
//! | imu, joints, power | `invalid` | the device's own validity flag false (imu `valid`, joints `wheel_valid[wheel]`, all wheels without `wheel`, power `valid`) | |
//! | imu | `gyro_bias` | `value` added to the gyro axis `axis` (all axes without `axis`) | rad/s (0.01) |
//! | imu | `accel_bias` | `value` added to the accelerometer axis `axis` (all without) | m/s^2 (0.5) |
//! | imu | `gyro_saturation` | gyro axes clipped to `+-value` | rad/s (0.1) |
//! | imu | `accel_saturation` | accelerometer axes clipped to `+-value` | m/s^2 (2.0) |
//! | any device | `time_jump` | `jump_s` added to the device's time stamps (may be negative) | |
//! | clock | `time_jump` | the common time base jumps: `jump_s` added to `now_us` and to every device's stamps | |
//! | clock | `stuck` | the common time base stops at the window start: `now_us` and every stamp frozen | |
//! | clock | `dropout` | `now_us` fails (`Timeout`) | |
//! | sun | `wrong_direction` | the vector rotated by `value` about the rover's `z` (a heading error; still unit length) | rad (0.5) |
//! | sun | `non_unit` | the vector scaled by `value` | factor (2.0) |
//! | camera | `black_frame` | all-zero images | |
//! | camera | `lost_capture` | a trigger is accepted, the capture is lost (`poll` answers `Idle`) | |
//! | camera | `never_complete` | a trigger is accepted, the capture never completes (`poll` answers `InProgress` until the next trigger) | |
//! | camera | `noise` | uniform noise of `+-value` grey levels added to the rendered images | grey levels (255) |
//! | camera | `stripes` | every other band of 16 rows saturated (255) | |
//! | motors | `stall` | truth: the wheel (all without `wheel`) does not turn although commanded; its rate is 0, the vehicle drags it | |
//! | motors | `refuse` | `Mobility::command` answers `ErrorKind::Hardware` (the rover keeps the last accepted command; `stop` still works) | |
//! | ground | `slip` | truth: the wheel's (all without `wheel`) ground speed is `(1 - value)` times its rim speed, lateral slip scaled alike; 1 = the wheels spin, the rover does not move | slip ratio in [0, 1] (1.0) |
//! | telemetry | `refuse` | `Telemetry::send` answers `ErrorKind::Busy` | |
//! | telemetry | `dropout` | `Telemetry::send` answers `ErrorKind::Timeout` | |

use serde::Deserialize;

/// Number of wheels a `wheel` index may address.
pub const FAULT_WHEELS: usize = 6;

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
    /// Clock (the common time base of every device).
    Clock,
    /// Drive motors (truth) and the motor command interface.
    Motors,
    /// The ground under the wheels (truth slip).
    Ground,
    /// Telemetry sink.
    Telemetry,
    /// Power subsystem (battery energy used, bus power).
    Power,
}

/// What goes wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// The device does not answer (`ErrorKind::Timeout`).
    Dropout,
    /// The device repeats its last values (with fresh time stamps); on the clock: time stops.
    Stuck,
    /// The values are NaN.
    Nan,
    /// The camera delivers all-zero images.
    BlackFrame,
    /// The time stamps jump by `jump_s` during the window.
    TimeJump,
    /// The device flags its reading invalid.
    Invalid,
    /// Gyro bias jump of `value` rad/s.
    GyroBias,
    /// Accelerometer bias jump of `value` m/s^2.
    AccelBias,
    /// Gyro axes clipped to `+-value` rad/s.
    GyroSaturation,
    /// Accelerometer axes clipped to `+-value` m/s^2.
    AccelSaturation,
    /// Sun vector rotated by `value` rad about the rover's `z` axis.
    WrongDirection,
    /// Sun vector scaled by `value`.
    NonUnit,
    /// Camera capture lost after its trigger (`poll` answers `Idle`).
    LostCapture,
    /// Camera capture never completes (`poll` answers `InProgress`).
    NeverComplete,
    /// Uniform noise of `+-value` grey levels on the images.
    Noise,
    /// Saturated horizontal stripes on the images.
    Stripes,
    /// A wheel does not turn although commanded (truth).
    Stall,
    /// The device refuses requests (motor commands: `Hardware`; telemetry: `Busy`).
    Refuse,
    /// Slip override on the truth: ground speed `(1 - value)` times the rim speed.
    Slip,
}

impl FaultKind {
    /// Default of `value` for this kind (0 for kinds without a value).
    pub fn default_value(self) -> f64 {
        match self {
            FaultKind::GyroBias => 0.01,
            FaultKind::AccelBias => 0.5,
            FaultKind::GyroSaturation => 0.1,
            FaultKind::AccelSaturation => 2.0,
            FaultKind::WrongDirection => 0.5,
            FaultKind::NonUnit => 2.0,
            FaultKind::Noise => 255.0,
            FaultKind::Slip => 1.0,
            _ => 0.0,
        }
    }

    /// The devices this kind may be applied to.
    fn devices(self) -> &'static [FaultDevice] {
        use FaultDevice::*;
        match self {
            FaultKind::Dropout => &[Imu, Joints, Camera, Sun, Clock, Telemetry, Power],
            FaultKind::Stuck => &[Imu, Joints, Camera, Sun, Clock, Power],
            FaultKind::Nan => &[Imu, Joints, Sun, Power],
            FaultKind::BlackFrame
            | FaultKind::LostCapture
            | FaultKind::NeverComplete
            | FaultKind::Noise
            | FaultKind::Stripes => &[Camera],
            FaultKind::TimeJump => &[Imu, Joints, Camera, Sun, Clock, Power],
            FaultKind::Invalid => &[Imu, Joints, Power],
            FaultKind::GyroBias
            | FaultKind::AccelBias
            | FaultKind::GyroSaturation
            | FaultKind::AccelSaturation => &[Imu],
            FaultKind::WrongDirection | FaultKind::NonUnit => &[Sun],
            FaultKind::Stall => &[Motors],
            FaultKind::Refuse => &[Motors, Telemetry],
            FaultKind::Slip => &[Ground],
        }
    }

    /// Kinds that may target one wheel.
    fn per_wheel(self) -> bool {
        matches!(
            self,
            FaultKind::Stuck
                | FaultKind::Nan
                | FaultKind::Invalid
                | FaultKind::Stall
                | FaultKind::Slip
        )
    }
}

/// One injected fault.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
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
    /// Wheel index 0-5 (H04 numbering minus one) for the per-wheel kinds on `joints`, `motors`
    /// and `ground`; without it the fault applies to every wheel (joints `stuck`: the whole
    /// device).
    #[serde(default)]
    pub wheel: Option<usize>,
    /// Axis 0-2 (`x`, `y`, `z` of `R`) of the IMU bias kinds; without it every axis.
    #[serde(default)]
    pub axis: Option<usize>,
    /// The kind's parameter in SI units (see the module table); default
    /// [`FaultKind::default_value`].
    #[serde(default)]
    pub value: Option<f64>,
}

impl FaultSpec {
    /// A fault of `kind` on `device` over `[start_s, start_s + duration_s)` with every optional
    /// field at its default.
    pub fn new(device: FaultDevice, kind: FaultKind, start_s: f64, duration_s: f64) -> Self {
        Self {
            device,
            kind,
            start_s,
            duration_s,
            jump_s: 0.0,
            wheel: None,
            axis: None,
            value: None,
        }
    }

    /// `value`, or the kind's default.
    pub fn value(&self) -> f64 {
        self.value.unwrap_or_else(|| self.kind.default_value())
    }

    /// Whether the fault is active at `t_us`.
    pub fn active_at(&self, t_us: u64) -> bool {
        let t = t_us as f64 * 1e-6;
        t >= self.start_s && t < self.start_s + self.duration_s
    }

    /// Whether the fault applies to wheel `i` (no `wheel`: every wheel).
    pub fn applies_to_wheel(&self, i: usize) -> bool {
        self.wheel.is_none_or(|w| w == i)
    }

    /// Whether axis `k` is affected (no `axis`: every axis).
    pub fn applies_to_axis(&self, k: usize) -> bool {
        self.axis.is_none_or(|a| a == k)
    }

    /// Check the fault: device and kind fit, window finite, indices and value in range.
    pub fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.kind.devices().contains(&self.device),
            "fault kind {:?} does not apply to device {:?}",
            self.kind,
            self.device
        );
        anyhow::ensure!(
            self.start_s.is_finite() && self.duration_s.is_finite() && self.duration_s >= 0.0,
            "fault window must be finite with duration_s >= 0"
        );
        anyhow::ensure!(self.jump_s.is_finite(), "jump_s must be finite");
        if let Some(w) = self.wheel {
            anyhow::ensure!(w < FAULT_WHEELS, "wheel must be 0-5, got {w}");
            anyhow::ensure!(
                self.kind.per_wheel()
                    && matches!(
                        self.device,
                        FaultDevice::Joints | FaultDevice::Motors | FaultDevice::Ground
                    ),
                "fault kind {:?} on {:?} takes no wheel",
                self.kind,
                self.device
            );
        }
        if let Some(a) = self.axis {
            anyhow::ensure!(a < 3, "axis must be 0-2, got {a}");
        }
        let v = self.value();
        anyhow::ensure!(v.is_finite(), "value must be finite");
        if self.kind == FaultKind::Slip {
            anyhow::ensure!((0.0..=1.0).contains(&v), "slip value must be in [0, 1]");
        }
        Ok(())
    }
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

    /// The fault of `kind` on the whole `device` (no `wheel`) active at `t_us`, if any.
    pub fn active(&self, device: FaultDevice, kind: FaultKind, t_us: u64) -> Option<&FaultSpec> {
        self.specs.iter().find(|f| {
            f.device == device && f.kind == kind && f.wheel.is_none() && f.active_at(t_us)
        })
    }

    /// The fault of `kind` on `device` that applies to wheel `wheel` (a fault with that index
    /// or without one) active at `t_us`, if any.
    pub fn active_wheel(
        &self,
        device: FaultDevice,
        kind: FaultKind,
        t_us: u64,
        wheel: usize,
    ) -> Option<&FaultSpec> {
        self.specs.iter().find(|f| {
            f.device == device && f.kind == kind && f.applies_to_wheel(wheel) && f.active_at(t_us)
        })
    }

    /// Every fault of `kind` on `device` active at `t_us` (several axes or wheels).
    pub fn all_active(
        &self,
        device: FaultDevice,
        kind: FaultKind,
        t_us: u64,
    ) -> impl Iterator<Item = &FaultSpec> {
        self.specs
            .iter()
            .filter(move |f| f.device == device && f.kind == kind && f.active_at(t_us))
    }

    /// Time stamp of a reading taken at `t_us` on `device`, after any clock fault (the common
    /// time base stuck or jumping) and any time jump of the device itself.
    pub fn stamp(&self, device: FaultDevice, t_us: u64) -> u64 {
        let mut t = t_us;
        if let Some(f) = self.active(FaultDevice::Clock, FaultKind::Stuck, t_us) {
            t = (f.start_s.max(0.0) * 1e6).round() as u64;
        }
        if let Some(f) = self.active(FaultDevice::Clock, FaultKind::TimeJump, t_us) {
            t = t.saturating_add_signed((f.jump_s * 1e6).round() as i64);
        }
        if device != FaultDevice::Clock {
            if let Some(f) = self.active(device, FaultKind::TimeJump, t_us) {
                t = t.saturating_add_signed((f.jump_s * 1e6).round() as i64);
            }
        }
        t
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
            jump_s: -0.25,
            ..FaultSpec::new(FaultDevice::Imu, FaultKind::TimeJump, 1.0, 0.5)
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

    /// SIM-20: per-wheel faults apply to their wheel only, a wheel fault without an index to
    /// every wheel; a whole-device lookup ignores wheel-specific faults.
    #[test]
    fn sim_20_per_wheel_targeting() {
        let f = Faults::new(vec![
            FaultSpec {
                wheel: Some(2),
                ..FaultSpec::new(FaultDevice::Motors, FaultKind::Stall, 1.0, 1.0)
            },
            FaultSpec::new(FaultDevice::Ground, FaultKind::Slip, 1.0, 1.0),
        ]);
        for i in 0..FAULT_WHEELS {
            let stalled = f
                .active_wheel(FaultDevice::Motors, FaultKind::Stall, 1_500_000, i)
                .is_some();
            assert_eq!(stalled, i == 2);
            assert!(f
                .active_wheel(FaultDevice::Ground, FaultKind::Slip, 1_500_000, i)
                .is_some());
            assert!(f
                .active_wheel(FaultDevice::Ground, FaultKind::Slip, 2_000_000, i)
                .is_none());
        }
        assert!(f
            .active(FaultDevice::Motors, FaultKind::Stall, 1_500_000)
            .is_none());
    }

    /// SIM-21: clock faults move the common time base: a clock time jump shifts every device's
    /// stamps, a stuck clock freezes them at the window start; both only inside the window.
    #[test]
    fn sim_21_clock_faults_move_every_stamp() {
        let f = Faults::new(vec![
            FaultSpec {
                jump_s: 3600.0,
                ..FaultSpec::new(FaultDevice::Clock, FaultKind::TimeJump, 1.0, 1.0)
            },
            FaultSpec::new(FaultDevice::Clock, FaultKind::Stuck, 5.0, 1.0),
        ]);
        for d in [
            FaultDevice::Imu,
            FaultDevice::Joints,
            FaultDevice::Camera,
            FaultDevice::Sun,
            FaultDevice::Clock,
        ] {
            assert_eq!(f.stamp(d, 900_000), 900_000);
            assert_eq!(f.stamp(d, 1_500_000), 3_601_500_000);
            assert_eq!(f.stamp(d, 2_000_000), 2_000_000);
            assert_eq!(f.stamp(d, 5_700_000), 5_000_000);
            assert_eq!(f.stamp(d, 6_000_000), 6_000_000);
        }
    }

    /// SIM-20: the scenario checks refuse a kind on the wrong device, a wheel out of range or
    /// on a kind without wheels, an axis out of range and a slip outside [0, 1].
    #[test]
    fn sim_20_fault_specs_are_checked() {
        let ok = FaultSpec::new(FaultDevice::Motors, FaultKind::Stall, 0.0, 1.0);
        assert!(ok.check().is_ok());
        let bad = [
            FaultSpec::new(FaultDevice::Imu, FaultKind::Stall, 0.0, 1.0),
            FaultSpec {
                wheel: Some(6),
                ..ok
            },
            FaultSpec {
                wheel: Some(1),
                ..FaultSpec::new(FaultDevice::Imu, FaultKind::Nan, 0.0, 1.0)
            },
            FaultSpec {
                axis: Some(3),
                ..FaultSpec::new(FaultDevice::Imu, FaultKind::GyroBias, 0.0, 1.0)
            },
            FaultSpec {
                value: Some(1.5),
                ..FaultSpec::new(FaultDevice::Ground, FaultKind::Slip, 0.0, 1.0)
            },
            FaultSpec::new(FaultDevice::Camera, FaultKind::Refuse, 0.0, 1.0),
        ];
        for b in bad {
            assert!(b.check().is_err(), "{b:?}");
        }
    }
}
