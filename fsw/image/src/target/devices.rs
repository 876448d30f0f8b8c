//! Rover-CPU devices behind the HAL traits (HAL glue; the only `unsafe` of the project is here).
//!
//! The clock is SysTick. Two sets of sensors: those of a rover at rest on level ground (the
//! `still` run, the same situation as the host simulator's first scenario, so both
//! implementations of the HAL can be compared), and the replay devices of `rover_replay` that
//! return a recorded call tape read from the host by semihosting (the `timing` run). One
//! [`TargetPlatform`] holds either set (enum dispatch), so the image has one flight-software
//! type and one static instance of it. The stereo buffers live in the external RAM region
//! (`.extram` in `memory.x`).

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use cortex_m::peripheral::{SCB, SYST};
use fsw::rectify::{MapNode, MAP_NODES};
use rover_hal::{
    CaptureStatus, Clock, ErrorKind, Imu, ImuSample, JointState, Mobility, MobilityCommand, Power,
    PowerReading, StereoCalibration, StereoCamera, StereoFrame, SunReading, SunSensor, Telemetry,
    IMAGE_PIXELS,
};
use rover_replay::devices::{
    ReplayClock, ReplayImu, ReplayMobility, ReplayPower, ReplayStereo, ReplaySun, ReplayTelemetry,
};
use rover_replay::Player;

use super::semihost::HostFile;
use super::CORE_CLOCK_HZ;

/// Mars gravity, m/s^2.
const MARS_GRAVITY_M_S2: f64 = 3.711;
/// Minor-frame period, microseconds (simulated sensor time advances by this per SysTick).
const FRAME_US: u64 = 5_000;
/// Bus power of the rover standing awake, W: the host simulator's awake power (its truth energy
/// model, `docs/simulator.md` "Energy model (`energy.rs`)": a standing rover draws nothing for its motors),
/// rounded to 0.01 W.
const STILL_BUS_POWER_W: f64 = 98.37;

/// The rover CPU's device types.
pub struct TargetPlatform;

impl fsw::flight::Platform for TargetPlatform {
    type Clock = TargetClock;
    type Imu = TargetImu;
    type Mobility = TargetMobility;
    type Camera = TargetCamera;
    type Sun = TargetSun;
    type Power = TargetPower;
    type Telemetry = TargetTelemetry;
    type ImageMemory = TargetImageMemory;
}

/// The flight software's rectification memory: map and rectified pair in external RAM (empty
/// for the still camera, which delivers a rectified test pattern).
pub type TargetImageMemory = fsw::rectify::ImageMemory<&'static mut [MapNode], &'static mut [u8]>;

/// Rectification maps in external RAM: the flight software's and the bench's.
pub const RECTIFY_MAPS: usize = 2;

/// Rectification map nodes, in external RAM.
#[link_section = ".extram"]
static mut RECTIFY_MAP: [[MapNode; MAP_NODES]; RECTIFY_MAPS] =
    [[MapNode { u: 0, v: 0 }; MAP_NODES]; RECTIFY_MAPS];
static RECTIFY_MAP_TAKEN: AtomicBool = AtomicBool::new(false);

/// The external-RAM rectification maps (once; `None` afterwards).
pub fn take_rectify_maps() -> Option<&'static mut [[MapNode; MAP_NODES]; RECTIFY_MAPS]> {
    if RECTIFY_MAP_TAKEN.swap(true, Ordering::AcqRel) {
        return None;
    }
    // SAFETY: the flag above makes this the only reference ever made to RECTIFY_MAP.
    Some(unsafe { &mut *core::ptr::addr_of_mut!(RECTIFY_MAP) })
}

/// The replay state shared by the replay devices.
pub type Tape = &'static RefCell<Player>;

/// One image buffer in external RAM.
pub type ImageBuffer = [u8; IMAGE_PIXELS];

/// Number of image buffers in external RAM: two pairs for the replay camera, one pair for the
/// visual-odometry measurement (the bench's rectified pair), one pair for the flight
/// software's rectified images, one pair for the bench's raw images.
pub const IMAGE_BUFFERS: usize = 10;

/// Stereo image buffers, in external RAM.
#[link_section = ".extram"]
static mut IMAGES: [ImageBuffer; IMAGE_BUFFERS] = [[0; IMAGE_PIXELS]; IMAGE_BUFFERS];
static IMAGES_TAKEN: AtomicBool = AtomicBool::new(false);

/// The external-RAM image buffers (once; `None` afterwards). The region is NOLOAD: the buffers
/// hold garbage until written.
pub fn take_image_buffers() -> Option<&'static mut [ImageBuffer; IMAGE_BUFFERS]> {
    if IMAGES_TAKEN.swap(true, Ordering::AcqRel) {
        return None;
    }
    // SAFETY: the flag above makes this the only reference ever made to IMAGES.
    Some(unsafe { &mut *core::ptr::addr_of_mut!(IMAGES) })
}

/// The replay player, in `.bss` (once; `None` afterwards). Only shared references to it are
/// handed out; its `RefCell` serialises mutation.
pub fn player() -> Option<Tape> {
    let player: &'static mut RefCell<Player> =
        super::take_static!(RefCell<Player>, RefCell::new(Player::new()))?;
    Some(player)
}

/// Clock: SysTick alone (still run) or the tape's `now_us` with the SysTick counter (replay).
pub enum TargetClock {
    /// Still run.
    Systick(SystickClock),
    /// Replay.
    Replay(ReplayClock<Tape, SystickClock>),
}

/// IMU.
pub enum TargetImu {
    /// Still run.
    Still(StillImu),
    /// Replay.
    Replay(ReplayImu<Tape>),
}

/// Mobility.
pub enum TargetMobility {
    /// Still run.
    Still(StillMobility),
    /// Replay.
    Replay(ReplayMobility<Tape>),
}

/// Stereo camera.
// One instance in a static, never moved: the replay variant's size (its calibration and lens
// calibration) costs nothing, and there is no heap to box it into.
#[allow(clippy::large_enum_variant)]
pub enum TargetCamera {
    /// Still run: a fixed test pattern.
    Still(ExtramStereo),
    /// Replay: pairs read from the tape into external RAM.
    Replay(ReplayStereo<Tape, HostFile, &'static mut [u8]>),
}

/// Sun sensor.
pub enum TargetSun {
    /// Still run.
    Still(FixedSun),
    /// Replay.
    Replay(ReplaySun<Tape>),
}

/// Power subsystem.
pub enum TargetPower {
    /// Still run.
    Still(ConstantPower),
    /// Replay.
    Replay(ReplayPower<Tape>),
}

/// Telemetry sink.
pub enum TargetTelemetry {
    /// Still run: counts records.
    Counting(CountingTelemetry),
    /// Replay: results from the tape.
    Replay(ReplayTelemetry<Tape>),
}

impl Clock for TargetClock {
    type Error = ErrorKind;
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        match self {
            Self::Systick(d) => d.now_us(),
            Self::Replay(d) => d.now_us(),
        }
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        match self {
            Self::Systick(d) => d.counter(),
            Self::Replay(d) => d.counter(),
        }
    }
    fn counter_hz(&self) -> u64 {
        match self {
            Self::Systick(d) => d.counter_hz(),
            Self::Replay(d) => d.counter_hz(),
        }
    }
}

impl Imu for TargetImu {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<ImuSample, ErrorKind> {
        match self {
            Self::Still(d) => d.read(),
            Self::Replay(d) => d.read(),
        }
    }
}

impl Mobility for TargetMobility {
    type Error = ErrorKind;
    fn read_joints(&mut self) -> Result<JointState, ErrorKind> {
        match self {
            Self::Still(d) => d.read_joints(),
            Self::Replay(d) => d.read_joints(),
        }
    }
    fn command(&mut self, command: &MobilityCommand) -> Result<(), ErrorKind> {
        match self {
            Self::Still(d) => d.command(command),
            Self::Replay(d) => d.command(command),
        }
    }
    fn stop(&mut self) -> Result<(), ErrorKind> {
        match self {
            Self::Still(d) => d.stop(),
            Self::Replay(d) => d.stop(),
        }
    }
}

impl StereoCamera for TargetCamera {
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        match self {
            Self::Still(d) => d.calibration(),
            Self::Replay(d) => d.calibration(),
        }
    }
    fn lens_calibration(&self) -> Option<rover_hal::LensCalibration> {
        match self {
            Self::Still(d) => d.lens_calibration(),
            Self::Replay(d) => d.lens_calibration(),
        }
    }
    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        match self {
            Self::Still(d) => d.trigger(),
            Self::Replay(d) => d.trigger(),
        }
    }
    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        match self {
            Self::Still(d) => d.poll(),
            Self::Replay(d) => d.poll(),
        }
    }
    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        match self {
            Self::Still(d) => d.frame(),
            Self::Replay(d) => d.frame(),
        }
    }
    fn release(&mut self) -> Result<(), ErrorKind> {
        match self {
            Self::Still(d) => d.release(),
            Self::Replay(d) => d.release(),
        }
    }
}

impl SunSensor for TargetSun {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<SunReading, ErrorKind> {
        match self {
            Self::Still(d) => d.read(),
            Self::Replay(d) => d.read(),
        }
    }
}

impl Power for TargetPower {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<PowerReading, ErrorKind> {
        match self {
            Self::Still(d) => d.read(),
            Self::Replay(d) => d.read(),
        }
    }
}

impl Telemetry for TargetTelemetry {
    type Error = ErrorKind;
    fn send(&mut self, record: &[u8]) -> Result<(), ErrorKind> {
        match self {
            Self::Counting(d) => d.send(record),
            Self::Replay(d) => d.send(record),
        }
    }
}

fn frame_time_us(ticks: &AtomicU32) -> u64 {
    u64::from(ticks.load(Ordering::Relaxed)) * FRAME_US
}

/// SysTick-based clock: time from the interrupt count, the execution counter from the interrupt
/// count and the down-counting SysTick value (core clock cycles; instruction-driven in QEMU with
/// `-icount`).
#[derive(Clone, Copy)]
pub struct SystickClock {
    reload: u32,
    ticks: &'static AtomicU32,
    /// The last counter value returned (the counter never goes back).
    last: u64,
}

impl SystickClock {
    /// A clock over SysTick running with `reload` cycles per interrupt.
    pub fn new(reload: u32, ticks: &'static AtomicU32) -> Self {
        Self {
            reload,
            ticks,
            last: 0,
        }
    }
}

impl Clock for SystickClock {
    type Error = ErrorKind;
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        Ok(frame_time_us(self.ticks))
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        // The SysTick value counts down and reloads at zero, where the interrupt becomes
        // pending; the handler may run a few instructions later. Read the interrupt count on
        // both sides and the value twice: without a reload between the two value reads, a
        // pending SysTick means the reload happened before them and its tick is not counted
        // yet. Retry a bounded number of times.
        for _ in 0..4 {
            let before = self.ticks.load(Ordering::Relaxed);
            let first = SYST::get_current();
            let pending = SCB::is_pendst_pending();
            let current = SYST::get_current();
            let after = self.ticks.load(Ordering::Relaxed);
            let into_frame = u64::from(self.reload.saturating_sub(current));
            if !pending && into_frame <= RELOAD_WINDOW_COUNTS && before == after {
                // Just after a reload with no tick pending: either the handler already counted
                // it or QEMU has not raised it yet (see below). Wait until the value has left
                // the window or the tick is pending, and read again (bounded; the wait is rare
                // and deterministic, and ends as soon as the window has passed).
                for _ in 0..RELOAD_WINDOW_POLLS {
                    let now = SYST::get_current();
                    if u64::from(self.reload.saturating_sub(now)) > RELOAD_WINDOW_COUNTS
                        || SCB::is_pendst_pending()
                    {
                        break;
                    }
                }
                continue;
            }
            if before == after && current <= first {
                // A pending tick counts only once the value has reloaded: QEMU can also raise
                // the pending bit while the value still reads the end of the period (seen as an
                // RG2 release one 125,000-count period long in the timing page).
                // The handler runs within a few instructions of the reload, so a pending tick
                // with the value in the second half of the period is the reload still to come.
                let reloaded = into_frame < u64::from(self.reload / 2);
                let ticks = u64::from(before) + u64::from(pending && reloaded);
                let mut value = ticks * u64::from(self.reload) + into_frame;
                // QEMU raises the SysTick pending bit when its timer callback runs, a few
                // instructions after the counter has reloaded: a read in that window sees the
                // reloaded value without the pending tick, one period behind (it showed as
                // isolated calls of about 5 M instructions, one 125,000-count period, in
                // `docs/results/timing.md`). A reading behind the last one is that window.
                if value < self.last {
                    value += u64::from(self.reload);
                }
                self.last = value;
                return Ok(value);
            }
        }
        Err(ErrorKind::Busy)
    }
    fn counter_hz(&self) -> u64 {
        u64::from(CORE_CLOCK_HZ)
    }
}

/// SysTick counts after a reload in which QEMU may not have raised the pending bit yet. QEMU
/// runs the timer callback at the end of a translation block, which can be hundreds of
/// instructions after the reload. 2 counts (80 instructions) was too short: at 5a90e8d the
/// one-off `localization_map` call measured 8.79 M instead of 13.79 M instructions, its end
/// read one 125,000-count period behind and its start read too long before for the
/// never-backwards rule below to notice. 32 counts are 1,280 instructions.
const RELOAD_WINDOW_COUNTS: u64 = 32;
/// Largest number of polls of the value while waiting out that window (about 10 instructions
/// each: more than the window). Reads land in the window in about 1 of 4,000 cases.
const RELOAD_WINDOW_POLLS: u32 = 256;

/// IMU of a rover at rest on level ground.
pub struct StillImu {
    ticks: &'static AtomicU32,
}

impl StillImu {
    /// An IMU stamped from the SysTick count.
    pub fn new(ticks: &'static AtomicU32) -> Self {
        Self { ticks }
    }
}

impl Imu for StillImu {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<ImuSample, ErrorKind> {
        Ok(ImuSample {
            t_us: frame_time_us(self.ticks),
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, -MARS_GRAVITY_M_S2],
            valid: true,
        })
    }
}

/// Joint encoders of a rover at rest; commands are accepted and held.
pub struct StillMobility {
    ticks: &'static AtomicU32,
    last_command: MobilityCommand,
}

impl StillMobility {
    /// A mobility system stamped from the SysTick count.
    pub fn new(ticks: &'static AtomicU32) -> Self {
        Self {
            ticks,
            last_command: MobilityCommand::default(),
        }
    }
}

impl Mobility for StillMobility {
    type Error = ErrorKind;
    fn read_joints(&mut self) -> Result<JointState, ErrorKind> {
        Ok(JointState {
            t_us: frame_time_us(self.ticks),
            steer_angle_rad: self.last_command.steer_angle_rad,
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
        self.last_command = *command;
        Ok(())
    }
    fn stop(&mut self) -> Result<(), ErrorKind> {
        self.last_command.wheel_rate_rad_s = [0.0; 6];
        Ok(())
    }
}

/// Stereo pair whose images live in the `.extram` region; a capture completes one poll after
/// its trigger.
pub struct ExtramStereo {
    buffers: [&'static mut ImageBuffer; 2],
    ticks: &'static AtomicU32,
    pending: Option<u64>,
    ready: Option<u64>,
    sequence: u32,
}

impl ExtramStereo {
    /// A camera on two external-RAM buffers, filled here with a test pattern (the region is
    /// NOLOAD, so it is written before any read): a hashed random texture in 2x2 pixel blocks,
    /// the right image the left one shifted by [`TEST_PATTERN_DISPARITY_PX`] (a plane at one
    /// depth). Random, not periodic: VO's left-right check rightly refuses the matches of a
    /// periodic pattern as ambiguous.
    pub fn new(buffers: [&'static mut ImageBuffer; 2], ticks: &'static AtomicU32) -> Self {
        let [left, right] = buffers;
        let width = rover_hal::IMAGE_WIDTH_PX;
        for (i, px) in left.iter_mut().enumerate() {
            *px = test_pattern(i % width, i / width);
        }
        for (i, px) in right.iter_mut().enumerate() {
            *px = test_pattern(i % width + TEST_PATTERN_DISPARITY_PX, i / width);
        }
        let buffers = [left, right];
        Self {
            buffers,
            ticks,
            pending: None,
            ready: None,
            sequence: 0,
        }
    }
}

/// Disparity of the still camera's test pattern, px (a plane about 2.7 m from the hazcam).
const TEST_PATTERN_DISPARITY_PX: usize = 12;

/// The still camera's texture at pixel `(x, y)`: a 32-bit integer hash of the 2x2 block.
fn test_pattern(x: usize, y: usize) -> u8 {
    let (bx, by) = ((x / 2) as u32, (y / 2) as u32);
    let mut v = bx.wrapping_mul(0x9e37_79b1) ^ by.wrapping_mul(0x85eb_ca77);
    v ^= v >> 15;
    v = v.wrapping_mul(0x2c1b_3c6d);
    v ^= v >> 12;
    (v >> 24) as u8
}

impl StereoCamera for ExtramStereo {
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        // Rocky 8 hazcam: fx = 320 / tan(39.75 deg), fy = 240 / tan(32 deg), 8.4 cm baseline,
        // 45 deg down (same model as sim-host's hazcam_calibration).
        let h = core::f64::consts::FRAC_1_SQRT_2;
        StereoCalibration {
            fx_px: 384.791_625_3,
            fy_px: 384.079_510_6,
            cx_px: 319.5,
            cy_px: 239.5,
            baseline_m: 0.084,
            rot_rover_from_camera: [[0.0, -h, h], [1.0, 0.0, 0.0], [0.0, h, h]],
            pos_camera_in_rover_m: [0.2, 0.0, -0.6],
        }
    }
    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        let t = frame_time_us(self.ticks);
        self.pending = Some(t);
        self.ready = None;
        self.sequence = self.sequence.wrapping_add(1);
        Ok(t)
    }
    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        if self.ready.is_some() {
            return Ok(CaptureStatus::Ready);
        }
        match self.pending.take() {
            Some(t) => {
                self.ready = Some(t);
                Ok(CaptureStatus::InProgress)
            }
            None => Ok(CaptureStatus::Idle),
        }
    }
    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        let t = self.ready.ok_or(ErrorKind::NotReady)?;
        Ok(StereoFrame {
            left: &self.buffers[0][..],
            right: &self.buffers[1][..],
            capture_t_us: t,
            sequence: self.sequence,
        })
    }
    fn release(&mut self) -> Result<(), ErrorKind> {
        self.ready = None;
        self.pending = None;
        Ok(())
    }
}

/// Sun sensor with the sun 30 deg above the horizon straight ahead.
pub struct FixedSun {
    ticks: &'static AtomicU32,
}

impl FixedSun {
    /// A sun sensor stamped from the SysTick count.
    pub fn new(ticks: &'static AtomicU32) -> Self {
        Self { ticks }
    }
}

impl SunSensor for FixedSun {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<SunReading, ErrorKind> {
        Ok(SunReading {
            t_us: frame_time_us(self.ticks),
            sun_dir_rover: [0.866_025_403_784_438_6, 0.0, -0.5],
            sun_in_view: true,
        })
    }
}

/// Power subsystem of a rover standing awake: a constant bus power
/// ([`STILL_BUS_POWER_W`]) integrated over the SysTick time, `energy_used_j = P t`.
pub struct ConstantPower {
    ticks: &'static AtomicU32,
}

impl ConstantPower {
    /// A power subsystem stamped from the SysTick count.
    pub fn new(ticks: &'static AtomicU32) -> Self {
        Self { ticks }
    }
}

impl Power for ConstantPower {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<PowerReading, ErrorKind> {
        let t_us = frame_time_us(self.ticks);
        Ok(PowerReading {
            t_us,
            energy_used_j: STILL_BUS_POWER_W * t_us as f64 * 1e-6,
            bus_power_w: STILL_BUS_POWER_W,
            valid: true,
        })
    }
}

/// Telemetry sink that counts records and bytes (the downlink is not modelled).
#[derive(Default)]
pub struct CountingTelemetry {
    /// Records received.
    pub records: u32,
    /// Bytes received.
    pub bytes: u32,
}

impl Telemetry for CountingTelemetry {
    type Error = ErrorKind;
    fn send(&mut self, record: &[u8]) -> Result<(), ErrorKind> {
        self.records = self.records.saturating_add(1);
        self.bytes = self
            .bytes
            .saturating_add(u32::try_from(record.len()).unwrap_or(u32::MAX));
        Ok(())
    }
}
