//! The devices of a rover standing still on level ground (the `still` command).
//!
//! Time is simulated: the simulator advances [`SimTime`] by one minor frame per tick, and every
//! device stamps its readings from it. The execution counter is the host's monotonic clock in
//! nanoseconds, used for timing statistics only.

use super::{hazcam_calibration, CaptureProtocol};
use rover_hal::{
    CaptureStatus, Clock, ErrorKind, Imu, ImuSample, JointState, Mobility, MobilityCommand, Power,
    PowerReading, StereoCalibration, StereoCamera, StereoFrame, SunReading, SunSensor,
    IMAGE_PIXELS,
};
use std::cell::Cell;
use std::rc::Rc;
use std::time::Instant;

/// Mars gravity, m/s^2 (REFERENCE.md).
pub const MARS_GRAVITY_M_S2: f64 = 3.711;

/// Shared simulated time, microseconds since boot.
#[derive(Clone, Default)]
pub struct SimTime(Rc<Cell<u64>>);

impl SimTime {
    /// Current simulated time, microseconds.
    pub fn now_us(&self) -> u64 {
        self.0.get()
    }
    /// Advance simulated time by `dt_us` microseconds.
    pub fn advance(&self, dt_us: u64) {
        self.0.set(self.0.get().saturating_add(dt_us));
    }
}

/// Clock: simulated time plus the host's nanosecond counter for execution-time statistics.
pub struct SimClock {
    time: SimTime,
    origin: Instant,
}

impl SimClock {
    /// A clock reading `time`.
    pub fn new(time: SimTime) -> Self {
        Self {
            time,
            origin: Instant::now(),
        }
    }
}

impl Clock for SimClock {
    type Error = ErrorKind;
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        Ok(self.time.now_us())
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        Ok(u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX))
    }
    fn counter_hz(&self) -> u64 {
        1_000_000_000
    }
}

/// IMU of a rover at rest on level ground: zero rate, specific force `-g` along `z` (down).
pub struct StillImu {
    time: SimTime,
}

impl StillImu {
    /// An IMU reading `time`.
    pub fn new(time: SimTime) -> Self {
        Self { time }
    }
}

impl Imu for StillImu {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<ImuSample, ErrorKind> {
        Ok(ImuSample {
            t_us: self.time.now_us(),
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, -MARS_GRAVITY_M_S2],
            valid: true,
        })
    }
}

/// Mobility of a rover at rest: joints hold their angles; commands are stored.
pub struct StillMobility {
    time: SimTime,
    /// Last accepted command.
    pub last_command: Option<MobilityCommand>,
}

impl StillMobility {
    /// A mobility system reading `time`.
    pub fn new(time: SimTime) -> Self {
        Self {
            time,
            last_command: None,
        }
    }
}

impl Mobility for StillMobility {
    type Error = ErrorKind;
    fn read_joints(&mut self) -> Result<JointState, ErrorKind> {
        Ok(JointState {
            t_us: self.time.now_us(),
            wheel_valid: [true; 6],
            suspension_valid: true,
            ..JointState::default()
        })
    }
    fn command(&mut self, command: &MobilityCommand) -> Result<(), ErrorKind> {
        let finite = command
            .steer_angle_rad
            .iter()
            .chain(command.wheel_rate_rad_s.iter())
            .all(|v| v.is_finite());
        if !finite {
            return Err(ErrorKind::InvalidRequest);
        }
        self.last_command = Some(*command);
        Ok(())
    }
    fn stop(&mut self) -> Result<(), ErrorKind> {
        self.last_command = Some(MobilityCommand::default());
        Ok(())
    }
}

/// A stereo pair that completes each capture `latency_polls` polls after its trigger, with a
/// uniform grey image (the standing-still rover of the `still` command).
pub struct GreyStereo {
    time: SimTime,
    left: Vec<u8>,
    right: Vec<u8>,
    capture: CaptureProtocol,
}

impl GreyStereo {
    /// A camera reading `time` whose captures complete after `latency_polls` polls.
    pub fn new(time: SimTime, latency_polls: u32) -> Self {
        Self {
            time,
            left: vec![128; IMAGE_PIXELS],
            right: vec![128; IMAGE_PIXELS],
            capture: CaptureProtocol::new(latency_polls),
        }
    }
}

impl StereoCamera for GreyStereo {
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        hazcam_calibration()
    }
    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        let t = self.time.now_us();
        self.capture.trigger(t);
        Ok(t)
    }
    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        Ok(self.capture.poll())
    }
    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        self.capture.frame(&self.left, &self.right)
    }
    fn release(&mut self) -> Result<(), ErrorKind> {
        self.capture.release();
        Ok(())
    }
}

/// Sun sensor with the sun fixed 30 deg above the horizon, straight ahead of the rover.
pub struct FixedSun {
    time: SimTime,
}

impl FixedSun {
    /// A sun sensor reading `time`.
    pub fn new(time: SimTime) -> Self {
        Self { time }
    }
}

impl SunSensor for FixedSun {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<SunReading, ErrorKind> {
        let (s, c) = (30f64).to_radians().sin_cos();
        Ok(SunReading {
            t_us: self.time.now_us(),
            sun_dir_rover: [c, 0.0, -s],
            sun_in_view: true,
        })
    }
}

/// Power subsystem of a rover standing awake: a constant bus power integrated over the
/// simulated time (`energy_used_j = P t`), `P` the truth energy model's awake power
/// ([`crate::energy::AWAKE_POWER_W`]: a standing rover draws nothing for its motors).
pub struct ConstantPower {
    time: SimTime,
    power_w: f64,
}

impl ConstantPower {
    /// A power subsystem reading `time`, drawing [`crate::energy::AWAKE_POWER_W`].
    pub fn new(time: SimTime) -> Self {
        Self {
            time,
            power_w: crate::energy::AWAKE_POWER_W,
        }
    }
}

impl Power for ConstantPower {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<PowerReading, ErrorKind> {
        let t_us = self.time.now_us();
        Ok(PowerReading {
            t_us,
            energy_used_j: self.power_w * t_us as f64 * 1e-6,
            bus_power_w: self.power_w,
            valid: true,
        })
    }
}
