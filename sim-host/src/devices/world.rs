//! The `rover-hal` devices of the simulated rover, reading the shared [`World`] and applying
//! the scenario's injected faults. The flight software sees only these readings.

use crate::devices::renderer::StereoRenderer;
use crate::devices::CaptureProtocol;
use crate::sensors::faults::{FaultDevice, FaultKind};
use crate::world::World;
use nalgebra::Vector3;
use rover_hal::{
    CaptureStatus, Clock, ErrorKind, Imu, ImuSample, JointState, Mobility, MobilityCommand, Power,
    PowerReading, StereoCalibration, StereoCamera, StereoFrame, SunReading, SunSensor,
    IMAGE_PIXELS,
};
use std::cell::RefCell;
use std::rc::Rc;
use std::time::Instant;

/// Rows per band of the `stripes` camera fault.
const STRIPE_ROWS: usize = 16;

/// The world shared by the simulation loop and the devices.
pub type SharedWorld = Rc<RefCell<World>>;

/// What the clock's execution counter counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CounterMode {
    /// Host nanoseconds: real execution times of the flight code on this host (varies run to
    /// run).
    Host,
    /// Simulated time in nanoseconds: every task measures 0 us, so every output is
    /// reproducible bit for bit.
    SimTime,
}

/// Clock device.
pub struct WorldClock {
    world: SharedWorld,
    mode: CounterMode,
    origin: Instant,
}

impl WorldClock {
    /// A clock on `world`.
    pub fn new(world: SharedWorld, mode: CounterMode) -> Self {
        Self {
            world,
            mode,
            origin: Instant::now(),
        }
    }
}

impl Clock for WorldClock {
    type Error = ErrorKind;
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        let w = self.world.borrow();
        if w.faults
            .active(FaultDevice::Clock, FaultKind::Dropout, w.truth.t_us)
            .is_some()
        {
            return Err(ErrorKind::Timeout);
        }
        Ok(w.faults.stamp(FaultDevice::Clock, w.truth.t_us))
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        Ok(match self.mode {
            CounterMode::Host => {
                let elapsed = u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX);
                // Time spent rendering images inside the camera device is the simulator's,
                // not the flight software's.
                elapsed.saturating_sub(self.world.borrow().sim_overhead_ns.get())
            }
            CounterMode::SimTime => self.world.borrow().truth.t_us.saturating_mul(1000),
        })
    }
    fn counter_hz(&self) -> u64 {
        1_000_000_000
    }
}

/// Common fault handling of a sampled device: dropout, stuck, NaN, time jump.
fn faulted<T: Copy>(
    world: &World,
    device: FaultDevice,
    fresh: T,
    last: &mut Option<T>,
    nan: impl Fn(&mut T),
    stamp: impl Fn(&mut T, u64),
) -> Result<T, ErrorKind> {
    let t = world.truth.t_us;
    if world.faults.active(device, FaultKind::Dropout, t).is_some() {
        return Err(ErrorKind::Timeout);
    }
    let mut out = match (world.faults.active(device, FaultKind::Stuck, t), *last) {
        (Some(_), Some(previous)) => previous,
        _ => fresh,
    };
    if world.faults.active(device, FaultKind::Nan, t).is_some() {
        nan(&mut out);
    }
    *last = Some(out);
    let mut stamped = out;
    stamp(&mut stamped, world.faults.stamp(device, t));
    Ok(stamped)
}

/// IMU device (200 Hz, one sample per minor frame).
pub struct WorldImu {
    world: SharedWorld,
    last: Option<ImuSample>,
}

impl WorldImu {
    /// An IMU on `world`.
    pub fn new(world: SharedWorld) -> Self {
        Self { world, last: None }
    }
}

impl Imu for WorldImu {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<ImuSample, ErrorKind> {
        let w = self.world.borrow();
        let fresh = imu_faults(&w, w.imu_sample);
        faulted(
            &w,
            FaultDevice::Imu,
            fresh,
            &mut self.last,
            |s| s.gyro_rad_s = [f64::NAN; 3],
            |s, t| s.t_us = t,
        )
    }
}

/// The IMU's own faults on a fresh sample: bias jumps, saturation, the invalid flag.
fn imu_faults(w: &World, mut s: ImuSample) -> ImuSample {
    let t = w.truth.t_us;
    let f = &w.faults;
    for spec in f.all_active(FaultDevice::Imu, FaultKind::GyroBias, t) {
        for k in (0..3).filter(|&k| spec.applies_to_axis(k)) {
            s.gyro_rad_s[k] += spec.value();
        }
    }
    for spec in f.all_active(FaultDevice::Imu, FaultKind::AccelBias, t) {
        for k in (0..3).filter(|&k| spec.applies_to_axis(k)) {
            s.accel_m_s2[k] += spec.value();
        }
    }
    if let Some(spec) = f.active(FaultDevice::Imu, FaultKind::GyroSaturation, t) {
        let l = spec.value().abs();
        s.gyro_rad_s = s.gyro_rad_s.map(|v| v.clamp(-l, l));
    }
    if let Some(spec) = f.active(FaultDevice::Imu, FaultKind::AccelSaturation, t) {
        let l = spec.value().abs();
        s.accel_m_s2 = s.accel_m_s2.map(|v| v.clamp(-l, l));
    }
    if f.active(FaultDevice::Imu, FaultKind::Invalid, t).is_some() {
        s.valid = false;
    }
    s
}

/// Mobility device: joint encoders and motor commands.
pub struct WorldMobility {
    world: SharedWorld,
    last: Option<JointState>,
}

impl WorldMobility {
    /// Mobility on `world`.
    pub fn new(world: SharedWorld) -> Self {
        Self { world, last: None }
    }
}

impl Mobility for WorldMobility {
    type Error = ErrorKind;
    fn read_joints(&mut self) -> Result<JointState, ErrorKind> {
        let w = self.world.borrow();
        let t = w.truth.t_us;
        // Per-wheel encoder faults on the fresh reading: a stuck wheel repeats its last drive
        // and steering values, a NaN wheel reads NaN, an invalid wheel is flagged.
        let mut fresh = w.joints;
        for i in 0..rover_hal::WHEEL_COUNT {
            let wheel = |kind| {
                w.faults
                    .active_wheel(FaultDevice::Joints, kind, t, i)
                    .is_some_and(|f| f.wheel.is_some())
            };
            if wheel(FaultKind::Stuck) {
                if let Some(previous) = self.last {
                    fresh.drive_angle_rad[i] = previous.drive_angle_rad[i];
                    fresh.drive_rate_rad_s[i] = previous.drive_rate_rad_s[i];
                    fresh.steer_angle_rad[i] = previous.steer_angle_rad[i];
                }
            }
            if wheel(FaultKind::Nan) {
                fresh.drive_angle_rad[i] = f64::NAN;
                fresh.drive_rate_rad_s[i] = f64::NAN;
                fresh.steer_angle_rad[i] = f64::NAN;
            }
            if w.faults
                .active_wheel(FaultDevice::Joints, FaultKind::Invalid, t, i)
                .is_some()
            {
                fresh.wheel_valid[i] = false;
            }
        }
        faulted(
            &w,
            FaultDevice::Joints,
            fresh,
            &mut self.last,
            |j| {
                j.rocker_rad = f64::NAN;
                j.drive_angle_rad = [f64::NAN; rover_hal::WHEEL_COUNT];
                j.drive_rate_rad_s = [f64::NAN; rover_hal::WHEEL_COUNT];
                j.steer_angle_rad = [f64::NAN; rover_hal::WHEEL_COUNT];
            },
            |j, t| j.t_us = t,
        )
    }
    fn command(&mut self, command: &MobilityCommand) -> Result<(), ErrorKind> {
        {
            let w = self.world.borrow();
            if w.faults
                .active(FaultDevice::Motors, FaultKind::Refuse, w.truth.t_us)
                .is_some()
            {
                return Err(ErrorKind::Hardware);
            }
        }
        let finite = command
            .steer_angle_rad
            .iter()
            .chain(command.wheel_rate_rad_s.iter())
            .all(|v| v.is_finite());
        if !finite {
            return Err(ErrorKind::InvalidRequest);
        }
        self.world.borrow_mut().flight_command = Some(*command);
        Ok(())
    }
    fn stop(&mut self) -> Result<(), ErrorKind> {
        let mut w = self.world.borrow_mut();
        let steer = w.truth.steer_rad;
        w.flight_command = Some(MobilityCommand {
            steer_angle_rad: steer,
            wheel_rate_rad_s: [0.0; 6],
        });
        Ok(())
    }
}

/// Sun sensor device.
pub struct WorldSun {
    world: SharedWorld,
    last: Option<SunReading>,
}

impl WorldSun {
    /// A sun sensor on `world`.
    pub fn new(world: SharedWorld) -> Self {
        Self { world, last: None }
    }
}

impl SunSensor for WorldSun {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<SunReading, ErrorKind> {
        let w = self.world.borrow();
        let t = w.truth.t_us;
        let mut fresh = w.sun_reading;
        if let Some(f) = w
            .faults
            .active(FaultDevice::Sun, FaultKind::WrongDirection, t)
        {
            let (sn, cs) = f.value().sin_cos();
            let [x, y, z] = fresh.sun_dir_rover;
            fresh.sun_dir_rover = [cs * x - sn * y, sn * x + cs * y, z];
        }
        if let Some(f) = w.faults.active(FaultDevice::Sun, FaultKind::NonUnit, t) {
            fresh.sun_dir_rover = fresh.sun_dir_rover.map(|v| v * f.value());
        }
        faulted(
            &w,
            FaultDevice::Sun,
            fresh,
            &mut self.last,
            |s| s.sun_dir_rover = [f64::NAN; 3],
            |s, t| s.t_us = t,
        )
    }
}

/// Power subsystem device: the truth energy model's battery energy used since boot
/// ([`crate::energy`], integrated by the world every step) and the mean bus power since the
/// previous reading it returned (since boot for the first), `valid` true; the scenario's
/// `power` faults (dropout, stuck, NaN, invalid, time jump) apply.
pub struct WorldPower {
    world: SharedWorld,
    last: Option<PowerReading>,
    /// Truth time and energy of the previous reading returned, for its mean power.
    previous: (u64, f64),
}

impl WorldPower {
    /// A power subsystem on `world`.
    pub fn new(world: SharedWorld) -> Self {
        Self {
            world,
            last: None,
            previous: (0, 0.0),
        }
    }
}

impl Power for WorldPower {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<PowerReading, ErrorKind> {
        let w = self.world.borrow();
        let t = w.truth.t_us;
        let energy_j = w.energy.energy_j();
        let (t0, e0) = self.previous;
        let bus_power_w = if t > t0 {
            (energy_j - e0) / ((t - t0) as f64 * 1e-6)
        } else {
            w.energy.power_w()
        };
        let fresh = PowerReading {
            t_us: t,
            energy_used_j: energy_j,
            bus_power_w,
            valid: w
                .faults
                .active(FaultDevice::Power, FaultKind::Invalid, t)
                .is_none(),
        };
        let reading = faulted(
            &w,
            FaultDevice::Power,
            fresh,
            &mut self.last,
            |p| {
                p.energy_used_j = f64::NAN;
                p.bus_power_w = f64::NAN;
            },
            |p, t| p.t_us = t,
        )?;
        self.previous = (t, energy_j);
        Ok(reading)
    }
}

/// Stereo camera device: renders the pair at the trigger from the true camera pose with the
/// true head (the world's [`crate::sensors::hazcam::HazcamModel::truth`], this seed's
/// calibration errors included) and the sun at the trigger time, and completes
/// `latency_polls` polls later. [`StereoCamera::calibration`] gives the nominal head (what the
/// ground calibration file says), never the true one; with lenses the images are raw (through
/// the true lenses) and [`StereoCamera::lens_calibration`] gives the nominal lenses.
pub struct WorldStereo {
    world: SharedWorld,
    renderer: Box<dyn StereoRenderer>,
    /// The nominal head (given to the flight software).
    calib: StereoCalibration,
    /// The true head (used to render).
    truth: StereoCalibration,
    /// The nominal lenses (given to the flight software); `None` with ideal lenses.
    lens: Option<rover_hal::LensCalibration>,
    left: Vec<u8>,
    right: Vec<u8>,
    capture: CaptureProtocol,
    seed: u64,
    /// The capture in progress was started inside a `never_complete` window: it never
    /// completes (until the next trigger or release).
    never_completes: bool,
    /// Frames rendered.
    pub rendered: u32,
}

impl WorldStereo {
    /// A camera on `world` drawing with `renderer`.
    pub fn new(
        world: SharedWorld,
        renderer: Box<dyn StereoRenderer>,
        latency_polls: u32,
        seed: u64,
    ) -> Self {
        let (calib, truth, lens) = {
            let w = world.borrow();
            (w.hazcam.nominal, w.hazcam.truth, w.hazcam.lens)
        };
        renderer.set_lens(lens.map(|l| l.truth));
        Self {
            world,
            renderer,
            calib,
            truth,
            lens: lens.map(|l| l.nominal),
            left: vec![0; IMAGE_PIXELS],
            right: vec![0; IMAGE_PIXELS],
            capture: CaptureProtocol::new(latency_polls),
            seed,
            never_completes: false,
            rendered: 0,
        }
    }
}

impl StereoCamera for WorldStereo {
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        self.calib
    }
    fn lens_calibration(&self) -> Option<rover_hal::LensCalibration> {
        self.lens
    }
    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        let w = self.world.borrow();
        let t = w.truth.t_us;
        if w.faults
            .active(FaultDevice::Camera, FaultKind::Dropout, t)
            .is_some()
        {
            return Err(ErrorKind::Timeout);
        }
        // The sequence number this capture will get (the protocol assigns it at the end).
        let sequence = self.capture.sequence().wrapping_add(1);
        let stuck = w
            .faults
            .active(FaultDevice::Camera, FaultKind::Stuck, t)
            .is_some();
        if w.faults
            .active(FaultDevice::Camera, FaultKind::BlackFrame, t)
            .is_some()
        {
            self.left.fill(0);
            self.right.fill(0);
        } else if !(stuck && self.rendered > 0) {
            let rot = w.truth.pose.rot_w_from_r();
            let head = &self.truth;
            let r_rk = nalgebra::Matrix3::from_fn(|i, j| head.rot_rover_from_camera[i][j]);
            let r_wk = rot.matrix() * r_rk;
            let pos =
                Vector3::from(w.truth.pose.pos_m) + rot * Vector3::from(head.pos_camera_in_rover_m);
            let sun = w.sun_w();
            self.renderer.set_sun([sun.x, sun.y, sun.z]);
            let rows = [0, 1, 2].map(|i| [r_wk[(i, 0)], r_wk[(i, 1)], r_wk[(i, 2)]]);
            let render_start = Instant::now();
            self.renderer.render(
                &w.terrain,
                rows,
                [pos.x, pos.y, pos.z],
                head,
                self.seed ^ u64::from(sequence).wrapping_mul(0x9E37_79B9),
                &mut self.left,
                &mut self.right,
            );
            let spent = u64::try_from(render_start.elapsed().as_nanos()).unwrap_or(u64::MAX);
            w.sim_overhead_ns
                .set(w.sim_overhead_ns.get().saturating_add(spent));
            self.rendered += 1;
        }
        if let Some(f) = w.faults.active(FaultDevice::Camera, FaultKind::Noise, t) {
            let amplitude = f.value().abs().min(255.0);
            let mut state =
                (self.seed ^ u64::from(sequence).wrapping_mul(0xD1B5_4A32_D192_ED03)) | 1;
            for p in self.left.iter_mut().chain(self.right.iter_mut()) {
                // xorshift64: uniform noise in [-amplitude, amplitude].
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let u = (state >> 11) as f64 / (1u64 << 53) as f64;
                let v = f64::from(*p) + amplitude * (2.0 * u - 1.0);
                *p = v.round().clamp(0.0, 255.0) as u8;
            }
        }
        if w.faults
            .active(FaultDevice::Camera, FaultKind::Stripes, t)
            .is_some()
        {
            for image in [&mut self.left, &mut self.right] {
                for (row, pixels) in image.chunks_mut(rover_hal::IMAGE_WIDTH_PX).enumerate() {
                    if (row / STRIPE_ROWS) % 2 == 1 {
                        pixels.fill(255);
                    }
                }
            }
        }
        let stamp = w.faults.stamp(FaultDevice::Camera, t);
        self.capture.trigger(stamp);
        self.never_completes = w
            .faults
            .active(FaultDevice::Camera, FaultKind::NeverComplete, t)
            .is_some();
        if w.faults
            .active(FaultDevice::Camera, FaultKind::LostCapture, t)
            .is_some()
        {
            // Accepted, then lost: the camera forgets the capture (poll answers Idle).
            self.capture.release();
        }
        Ok(stamp)
    }
    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        if self.never_completes {
            return Ok(CaptureStatus::InProgress);
        }
        Ok(self.capture.poll())
    }
    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        if self.never_completes {
            return Err(ErrorKind::NotReady);
        }
        self.capture.frame(&self.left, &self.right)
    }
    fn release(&mut self) -> Result<(), ErrorKind> {
        self.never_completes = false;
        self.capture.release();
        Ok(())
    }
}

/// The telemetry faults of `world` as a [`crate::devices::CountingTelemetry`] refusal hook: `refuse` answers
/// `ErrorKind::Busy`, `dropout` `ErrorKind::Timeout`, inside their windows.
pub fn telemetry_faults(world: SharedWorld) -> crate::devices::TelemetryRefusal {
    Box::new(move || {
        let w = world.borrow();
        let t = w.truth.t_us;
        if w.faults
            .active(FaultDevice::Telemetry, FaultKind::Refuse, t)
            .is_some()
        {
            Some(ErrorKind::Busy)
        } else if w
            .faults
            .active(FaultDevice::Telemetry, FaultKind::Dropout, t)
            .is_some()
        {
            Some(ErrorKind::Timeout)
        } else {
            None
        }
    })
}
