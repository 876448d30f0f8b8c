//! # The flight software's top level
//!
//! [`Fsw`] owns every piece of flight state in fixed-size fields and the devices it reads
//! through the HAL. [`Fsw::tick`] runs one minor frame of the rate-group schedule
//! ([`SCHEDULE_GROUPS`], [`SCHEDULE_TASKS`]):
//!
//! | group | rate (default) | tasks |
//! |---|---|---|
//! | RG1 | 200 Hz | `imu`: IMU read and checks; `propagate`: EKF propagation (eq. 26-27) |
//! | RG2 | 20 Hz | `joints`: joint read and checks; `odometry`: kinematic interval, gate (eq. 46), EKF update or slip vector; `guidance`: carrot and slip loops (eq. 47-49), inverse kinematics, motor command |
//! | RG3 | 5 Hz | `stereo`: capture policy (H04 sec. 2: every 0.25 m or 10 deg of EKF motion, at the latest every 10 s; [`nav::Navigator::capture_due`]), capture trigger and clone (eq. 41); a capture not completed within [`CAPTURE_TIMEOUT_FRAMES`] is timed out |
//! | RG2B | 20 Hz, half a period after RG2 | `zupt`: the zero-velocity update of a stop the `odometry` task saw, while the command is still zero ([`nav::Navigator::zero_velocity_cycle`]); `telemetry`: status and navigation records |
//! | RG4 | 0.2 Hz | `sun`: sun read and heading update (RB sec. 5.1); `power`: power-subsystem read and checks, the battery energy used handed to the navigator (V99 sec. 3) |
//! | background | every frame | stereo polling, rectification of raw pairs, visual odometry work items, VO gate and fusion at the capture clones |
//!
//! Every device reading is checked (error, device-flagged invalid, non-finite, time stamp not
//! advancing, time going backwards) and counted in [`DeviceHealth`]; only checked readings are
//! kept and handed to the [`nav::Navigator`].

pub mod nav;

use crate::exec::{
    ExecConfig, ExecError, Executive, FrameReport, GroupConfig, TaskConfig, TaskSet,
};
use crate::guidance::Point2;
use crate::rectify::{Rectifier, RectifyConfig, RectifyMemory, RectifyProgress};
use crate::telemetry::{
    self, DeviceHealth, FrameStatus, NavTelemetry, RecordKind, MAX_RECORD_BYTES,
};
use nav::{NavConfig, NavError, Navigator};
use rover_hal::{
    CaptureStatus, Clock, ErrorKind, Imu, ImuSample, JointState, Mobility, Power, PowerReading,
    StereoCamera, SunReading, SunSensor, Telemetry,
};

/// The set of device types a platform provides (the simulator or the rover CPU).
pub trait Platform {
    /// Monotonic clock and execution counter.
    type Clock: Clock;
    /// Inertial measurement unit.
    type Imu: Imu;
    /// Joint encoders and motors.
    type Mobility: Mobility;
    /// Stereo hazcam pair.
    type Camera: StereoCamera;
    /// Sun sensor.
    type Sun: SunSensor;
    /// Power subsystem (battery energy used, bus power).
    type Power: Power;
    /// Telemetry sink.
    type Telemetry: Telemetry;
    /// Image memory of the stereo rectification (map and rectified pair; external RAM on the
    /// rover CPU). Used only when the camera has a [`rover_hal::LensCalibration`].
    type ImageMemory: RectifyMemory;
}

/// The devices, one of each kind, owned by the flight software.
pub struct Devices<P: Platform> {
    /// Clock.
    pub clock: P::Clock,
    /// IMU.
    pub imu: P::Imu,
    /// Mobility.
    pub mobility: P::Mobility,
    /// Stereo camera.
    pub camera: P::Camera,
    /// Sun sensor.
    pub sun: P::Sun,
    /// Power subsystem.
    pub power: P::Power,
    /// Telemetry sink.
    pub telemetry: P::Telemetry,
    /// Image memory of the stereo rectification ([`crate::rectify`]).
    pub image_memory: P::ImageMemory,
}

/// Number of rate groups in the flight schedule.
pub const GROUP_COUNT: usize = 5;
/// Number of tasks in the flight schedule.
pub const TASK_COUNT: usize = 10;

/// Rate-group table (ARCHITECTURE.md sec. 4). Divisors are relative to the 200 Hz minor frame.
pub const SCHEDULE_GROUPS: [GroupConfig; GROUP_COUNT] = [
    GroupConfig {
        name: "RG1",
        divisor: 1,
        offset: 0,
        enabled: true,
    },
    GroupConfig {
        name: "RG2",
        divisor: 10,
        offset: 1,
        enabled: true,
    },
    // 5 Hz: checks the distance-based capture policy often enough that a capture starts within
    // 0.2 s (1 cm at the nominal 5 cm/s) of being due.
    GroupConfig {
        name: "RG3",
        divisor: 40,
        offset: 2,
        enabled: true,
    },
    GroupConfig {
        name: "RG4",
        divisor: 1000,
        offset: 3,
        enabled: true,
    },
    // RG2's rate half a period later (offset 1 + 5): the zero-velocity update of a stop, apart
    // from the kinematic update of the same stop, and the status telemetry (issue 18: the RG2
    // release at most 100,000 instructions). Frames of phase 6 run no other
    // group but RG1 (RG3's and RG4's phases are 2 and 3 modulo 10).
    GroupConfig {
        name: "RG2B",
        divisor: 10,
        offset: 6,
        enabled: true,
    },
];

/// Minor frames a stereo capture may take to complete before it is counted as a camera
/// timeout and dropped (1 s, the former RG3 period).
pub const CAPTURE_TIMEOUT_FRAMES: u64 = 200;

/// Task table in call order, with budgets in microseconds of the rover CPU (300 MHz class;
/// `docs/timing.md` measures them).
pub const SCHEDULE_TASKS: [TaskConfig; TASK_COUNT] = [
    TaskConfig {
        name: "imu",
        group: 0,
        budget_us: 100,
    },
    TaskConfig {
        name: "propagate",
        group: 0,
        budget_us: 400,
    },
    TaskConfig {
        name: "joints",
        group: 1,
        budget_us: 100,
    },
    TaskConfig {
        name: "odometry",
        group: 1,
        budget_us: 1_500,
    },
    TaskConfig {
        name: "guidance",
        group: 1,
        budget_us: 500,
    },
    TaskConfig {
        name: "stereo",
        group: 2,
        budget_us: 200,
    },
    TaskConfig {
        name: "sun",
        group: 3,
        budget_us: 300,
    },
    TaskConfig {
        name: "power",
        group: 3,
        budget_us: 100,
    },
    TaskConfig {
        name: "zupt",
        group: 4,
        budget_us: 300,
    },
    TaskConfig {
        name: "telemetry",
        group: 4,
        budget_us: 200,
    },
];

/// Everything the flight software is configured with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FswConfig {
    /// Executive settings; `background_quantum` is the VO work per frame in cost units of
    /// about 10 000 rover-CPU instructions ([`crate::vo::VoConfig::work_cost`]).
    pub exec: ExecConfig,
    /// Navigation settings.
    pub nav: NavConfig,
    /// Plausibility limits of the device readings.
    pub plausibility: Plausibility,
    /// Stereo rectification work settings ([`crate::rectify`]).
    pub rectify: RectifyConfig,
}

/// Plausibility limits of device readings (issue 20): a finite reading outside them is refused
/// and counted in [`DeviceHealth::invalid`]; a time stamp that leaps ahead is refused and
/// counted in [`DeviceHealth::time_jumps`] so that it cannot poison the device's time base.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausibility {
    /// Largest angular rate reading, rad/s: the measurement range of a tactical MEMS IMU of the
    /// rover's class (ADIS16488-class, +-450 deg/s); a reading beyond it cannot come from the
    /// sensor working.
    pub gyro_max_rad_s: f64,
    /// Largest specific-force reading, m/s^2 (the same class: +-18 g0; wheel shocks on rocks
    /// stay inside it).
    pub accel_max_m_s2: f64,
    /// Largest wheel rate reading, as a multiple of the motor limit.
    pub drive_rate_factor: f64,
    /// Margin beyond the steering, rocker and bogie limits of the geometry, rad.
    pub angle_margin_rad: f64,
    /// A time stamp may lead the last accepted one by at most this many minor frames per frame
    /// elapsed since (plus one frame).
    pub stamp_lead_factor: u64,
    /// Readings in a row that continue a leaped time base before it is accepted as the
    /// device's new time base ([`DeviceHealth::resyncs`]).
    pub resync_readings: u32,
    /// Largest bus power, W: ten times the power MER needs to drive (100 W, NASA, "Mars
    /// Exploration Rover - Rover Energy"). A power reading above it is refused, and so is one
    /// whose energy used grew faster than this since the last accepted reading (since boot for
    /// the first): an energy leap would otherwise lock out every later reading, whose energy
    /// used must not be lower.
    pub bus_power_max_w: f64,
}

impl Default for Plausibility {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl Plausibility {
    /// The default limits (as [`Default`], usable in a `const`).
    pub const DEFAULT: Self = Self {
        gyro_max_rad_s: 450.0 * core::f64::consts::PI / 180.0,
        accel_max_m_s2: 18.0 * 9.80665,
        drive_rate_factor: 2.0,
        angle_margin_rad: 0.2,
        stamp_lead_factor: 4,
        resync_readings: 20,
        bus_power_max_w: 1_000.0,
    };
}

/// Time-base state of one device: the frame of its last accepted reading and a candidate new
/// time base after a leap.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TimeBase {
    /// Minor frame of the last accepted reading.
    pub last_tick: u64,
    /// A leaped stamp and its frame, and how many readings in a row continued it.
    pub candidate: Option<(u64, u64, u32)>,
}

impl TimeBase {
    /// A reading at minor frame `tick` passed every check and was kept.
    pub fn accept(&mut self, tick: u64) {
        self.last_tick = tick;
        self.candidate = None;
    }
}

impl FswConfig {
    /// Defaults for Rocky 8 starting at `position` (m, `N`) heading `yaw_rad` (from north): the
    /// default executive with 60 cost units of background work per minor frame (at most
    /// 0.6 M instructions plus one item; the largest frame measured with its slice takes 80 %
    /// of the 5 ms period at CPI 2.0, where 100 units took 133 %; a VO update with the
    /// rectification of its pair about 14,000 units, 1.1 s; `docs/timing.md`).
    pub fn rocky8(position: [f64; 3], yaw_rad: f64) -> Self {
        Self {
            exec: ExecConfig {
                background_quantum: 60,
                ..ExecConfig::default()
            },
            nav: NavConfig::rocky8(position, yaw_rad),
            plausibility: Plausibility::default(),
            rectify: RectifyConfig::default(),
        }
    }
}

/// Why the flight software could not be built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FswError {
    /// The executive refused the schedule.
    Schedule(ExecError),
    /// The navigator refused the path or its settings.
    Nav(NavError),
}

/// Index of each device in [`FrameStatus::health`].
#[derive(Debug, Clone, Copy)]
#[repr(usize)]
pub enum DeviceId {
    /// IMU.
    Imu = 0,
    /// Joint encoders.
    Joints = 1,
    /// Stereo camera.
    Camera = 2,
    /// Sun sensor.
    Sun = 3,
    /// Power subsystem.
    Power = 4,
}

/// Number of devices with health counters ([`DeviceId`]).
pub const DEVICE_COUNT: usize = 5;

/// Flight state apart from the devices and the executive.
#[derive(Debug, Clone, Default)]
pub struct FlightState {
    /// Last IMU sample that passed the checks.
    pub imu: Option<ImuSample>,
    /// Last joint state that passed the checks.
    pub joints: Option<JointState>,
    /// Last sun reading with the sun in view that passed the checks.
    pub sun: Option<SunReading>,
    /// Last power reading that passed the checks (valid, finite, non-negative, the energy
    /// used not lower than the previous accepted reading's).
    pub power: Option<PowerReading>,
    /// Time stamp of the capture in progress, microseconds since boot.
    pub capture_pending_t_us: Option<u64>,
    /// Minor-frame tick at which the capture in progress was triggered.
    pub capture_pending_tick: u64,
    /// Time stamp of the last completed stereo capture, microseconds since boot.
    pub last_capture_t_us: Option<u64>,
    /// Device health counters, indexed by [`DeviceId`].
    pub health: [DeviceHealth; DEVICE_COUNT],
    /// Time-base state of each device, indexed by [`DeviceId`].
    pub time_bases: [TimeBase; DEVICE_COUNT],
    /// Stereo frames completed.
    pub stereo_frames: u32,
    /// Telemetry records the sink refused.
    pub telemetry_dropped: u32,
    /// Status copied from the executive at the end of each frame, for telemetry.
    pub exec_status: (u64, bool),
    /// Motor commands sent (and refused by the device).
    pub commands_sent: u32,
    /// Motor commands or stops the device refused.
    pub commands_refused: u32,
    /// The last motor command sent (`None`: stopped).
    pub last_command: Option<rover_hal::MobilityCommand>,
    /// The camera delivers raw images with a lens calibration, and the rectification map was
    /// built: every pair is rectified before VO and the hazard mapper see it.
    pub rectifying: bool,
    /// The rectification map could not be built from the camera's lens calibration (fault
    /// flag): VO and hazard mapping stay off.
    pub rectify_fault: Option<crate::rectify::RectifyError>,
    /// Raw pairs rectified.
    pub rectified_pairs: u32,
    /// Raw pairs whose rectification failed (frame lost or changed).
    pub rectify_failures: u32,
}

impl FlightState {
    /// The state before the first frame (the same as [`Default`], usable in a `const`).
    pub const EMPTY: Self = Self {
        imu: None,
        joints: None,
        sun: None,
        power: None,
        capture_pending_t_us: None,
        capture_pending_tick: 0,
        last_capture_t_us: None,
        health: [DeviceHealth::EMPTY; DEVICE_COUNT],
        time_bases: [TimeBase {
            last_tick: 0,
            candidate: None,
        }; DEVICE_COUNT],
        stereo_frames: 0,
        telemetry_dropped: 0,
        exec_status: (0, false),
        commands_sent: 0,
        commands_refused: 0,
        last_command: None,
        rectifying: false,
        rectify_fault: None,
        rectified_pairs: 0,
        rectify_failures: 0,
    };
}

/// Readings checked in this frame and not yet used by the navigator.
#[derive(Debug, Clone, Copy, Default)]
struct Fresh {
    imu: Option<ImuSample>,
    joints: Option<JointState>,
}

/// The flight software: devices, executive and state.
///
/// About 220 KB, nearly all of it the [`Navigator`]. On the rover CPU it is a static that
/// starts as [`Fsw::EMPTY`] (a compile-time value, no code runs) and is built in place by
/// [`Fsw::init`] and [`Fsw::start_vo`], so that its construction never holds a copy of it on
/// the stack; [`Fsw::new`] builds a value (host code, tests).
pub struct Fsw<P: Platform> {
    /// The devices; `None` only before [`Fsw::init`] (a frame without them does nothing).
    devices: Option<Attached<P>>,
    exec: Executive<GROUP_COUNT, TASK_COUNT>,
    state: FlightState,
    nav: Navigator,
    fresh: Fresh,
    plausibility: Plausibility,
    rect: RectStage,
}

/// The devices owned by the flight software, the clock apart (it is lent to the executive
/// while the tasks borrow the others).
struct Attached<P: Platform> {
    devices: DevicesNoClock<P>,
    clock: P::Clock,
}

struct DevicesNoClock<P: Platform> {
    imu: P::Imu,
    mobility: P::Mobility,
    camera: P::Camera,
    sun: P::Sun,
    power: P::Power,
    telemetry: P::Telemetry,
    image_memory: P::ImageMemory,
}

/// The rectification stage between the camera and the navigator.
#[derive(Debug, Clone, Copy)]
struct RectStage {
    rectifier: Rectifier,
    /// Capture time and sequence of the raw pair being rectified.
    pending: Option<(u64, u32)>,
    /// Capture time and sequence of the rectified pair in the image memory that VO or the
    /// hazard mapper is working on.
    frame: Option<(u64, u32)>,
}

impl<P: Platform> Fsw<P> {
    /// The flight software without devices, before [`Self::init`]: a compile-time value (the
    /// initialiser of the rover CPU's static; every field an empty placeholder, no devices,
    /// an executive without schedule). [`Self::tick`] does nothing until [`Self::init`].
    pub const EMPTY: Self = Self {
        devices: None,
        exec: Executive::EMPTY,
        state: FlightState::EMPTY,
        nav: Navigator::EMPTY,
        fresh: Fresh {
            imu: None,
            joints: None,
        },
        plausibility: Plausibility::DEFAULT,
        rect: RectStage {
            rectifier: Rectifier::new(RectifyConfig { row_cost: 1 }),
            pending: None,
            frame: None,
        },
    };

    /// Build the flight software around its devices with the default schedule, to follow
    /// `path` (waypoints north, east in `N`, m): [`Self::EMPTY`] initialised by [`Self::init`].
    /// The value is about 220 KB: on the rover CPU use [`Self::init`] on a static instead.
    pub fn new(devices: Devices<P>, config: &FswConfig, path: &[Point2]) -> Result<Self, FswError> {
        let mut fsw = Self::EMPTY;
        fsw.init(devices, config, path)?;
        Ok(fsw)
    }

    /// Build the flight software in place (the rover CPU's static): around `devices`, with the
    /// default schedule, to follow `path` (waypoints north, east in `N`, m). Every field is
    /// rewritten (a used flight software is reset completely); the large navigation state is
    /// written field by field in place ([`Navigator::init`]), never built as a temporary.
    /// The visual odometry and hazard navigation come later, in place too ([`Self::start_vo`]).
    /// On error the devices are dropped and the flight software stays without devices
    /// ([`Self::tick`] does nothing).
    pub fn init(
        &mut self,
        devices: Devices<P>,
        config: &FswConfig,
        path: &[Point2],
    ) -> Result<(), FswError> {
        self.devices = None;
        self.exec = Executive::new(config.exec, SCHEDULE_GROUPS, SCHEDULE_TASKS)
            .map_err(FswError::Schedule)?;
        self.nav
            .init(&config.nav, path, &devices.camera.calibration())
            .map_err(FswError::Nav)?;
        let Devices {
            clock,
            imu,
            mobility,
            camera,
            sun,
            power,
            telemetry,
            image_memory,
        } = devices;
        self.devices = Some(Attached {
            devices: DevicesNoClock {
                imu,
                mobility,
                camera,
                sun,
                power,
                telemetry,
                image_memory,
            },
            clock,
        });
        self.state = FlightState::EMPTY;
        self.fresh = Fresh::default();
        self.plausibility = config.plausibility;
        self.rect = RectStage {
            rectifier: Rectifier::new(config.rectify),
            pending: None,
            frame: None,
        };
        Ok(())
    }

    /// Run one minor frame (call once per tick).
    pub fn tick(&mut self) -> FrameReport {
        let Some(Attached { devices, clock }) = self.devices.as_mut() else {
            return FrameReport::default();
        };
        let mut work = Work {
            limits: &self.plausibility,
            devices,
            state: &mut self.state,
            nav: &mut self.nav,
            fresh: &mut self.fresh,
            rect: &mut self.rect,
        };
        let report = self.exec.run_frame(clock, &mut work);
        self.state.exec_status = (self.exec.cycle_slips(), self.exec.timing_fault());
        report
    }

    /// The executive, for its statistics.
    pub fn executive(&self) -> &Executive<GROUP_COUNT, TASK_COUNT> {
        &self.exec
    }

    /// The flight state.
    pub fn state(&self) -> &FlightState {
        &self.state
    }

    /// Build the visual odometry state (about 96 KB) in place: call once after the flight
    /// software has reached its final location (a static on the rover CPU), before the first
    /// tick. Without it VO stays off (the EKF runs on kinematics and IMU).
    ///
    /// When the camera delivers raw images ([`rover_hal::StereoCamera::lens_calibration`]),
    /// the rectification map is built here first ([`crate::rectify`]); if the lens
    /// calibration is refused (NaN, absurd coefficients, a field the raw images do not cover),
    /// [`FlightState::rectify_fault`] is set and VO and the hazard mapping stay off: they never
    /// run on unrectified images.
    pub fn start_vo(&mut self) {
        let Some(Attached { devices, .. }) = self.devices.as_mut() else {
            return;
        };
        if let Some(lens) = devices.camera.lens_calibration() {
            let rect = devices.camera.calibration();
            match self
                .rect
                .rectifier
                .build(&lens, &rect, &mut devices.image_memory)
            {
                Ok(_) => self.state.rectifying = true,
                Err(e) => {
                    self.state.rectify_fault = Some(e);
                    return;
                }
            }
        }
        self.nav.start_vo();
    }

    /// The rectification state (map figures, pair in progress).
    pub fn rectifier(&self) -> &Rectifier {
        &self.rect.rectifier
    }

    /// The navigator (estimates, slip, guidance output).
    pub fn nav(&self) -> &Navigator {
        &self.nav
    }

    /// The storage of terrain-map localization ([`nav::LocNav`], about 82 KB): a static in
    /// external RAM on the rover CPU. Give it before [`Self::start_vo`] when the configuration
    /// enables localization (otherwise it is refused, counted).
    pub fn provide_localization_memory(&mut self, store: &'static mut nav::LocNav) {
        self.nav.provide_localization_memory(store);
    }

    /// Ground command: uplink the global map of terrain-map localization (V99 sec. 5):
    /// occupied world points `[x north, y east]` (`N`, m) in a 38.4 m square centred on
    /// `centre_m` ([`Navigator::uplink_global_map`]; call after [`Self::start_vo`], while the
    /// rover stands: the distance transform takes about 13.5 M rover-CPU instructions).
    /// Returns the points inserted; `None` when localization is off.
    pub fn uplink_global_map(&mut self, centre_m: [f64; 2], points: &[[f64; 2]]) -> Option<usize> {
        self.nav.uplink_global_map(centre_m, points)
    }

    /// Ground command: the day's science targets (`N`, m), the sequencer's resource model and
    /// the budget (V99 sec. 3, [`Navigator::uplink_targets`]); call after [`Self::start_vo`]
    /// with goal-directed driving on.
    pub fn uplink_targets(
        &mut self,
        targets: &[crate::sequencer::Target],
        model: crate::sequencer::ResourceModel,
        budget: nav::MissionBudget,
    ) -> Result<(), nav::MissionError> {
        self.nav.uplink_targets(targets, model, budget)
    }

    /// The clock (for drivers that need the time base); `None` before [`Self::init`].
    pub fn clock_mut(&mut self) -> Option<&mut P::Clock> {
        self.devices.as_mut().map(|a| &mut a.clock)
    }
}

struct Work<'a, P: Platform> {
    limits: &'a Plausibility,
    devices: &'a mut DevicesNoClock<P>,
    state: &'a mut FlightState,
    nav: &'a mut Navigator,
    fresh: &'a mut Fresh,
    rect: &'a mut RectStage,
}

/// Frame period of the schedule, us (200 Hz).
const FRAME_PERIOD_US: u64 = 5_000;

/// Fraction of the accelerometer's range at which a reading counts as saturated (clipped by
/// the sensor): an IMU shock ([`nav::Navigator::imu_shock`]).
const IMU_SATURATION: f64 = 0.999;

/// Check a time stamp against the previous accepted one at minor frame `tick`: stale or
/// backwards are faults; a stamp that leads the previous one by more than
/// `stamp_lead_factor` frames per elapsed frame (plus a frame) is a leap, refused and counted,
/// unless `resync_readings` readings in a row continue it (a real change of the device's time
/// base, accepted and counted in [`DeviceHealth::resyncs`]). The caller records a reading that
/// passes every check with [`TimeBase::accept`].
fn check_time(
    health: &mut DeviceHealth,
    base: &mut TimeBase,
    previous: Option<u64>,
    t_us: u64,
    tick: u64,
    limits: &Plausibility,
) -> bool {
    let Some(p) = previous else {
        return true;
    };
    if t_us == p {
        health.stale = health.stale.saturating_add(1);
        return false;
    }
    if t_us < p {
        health.time_backwards = health.time_backwards.saturating_add(1);
        return false;
    }
    let frames = tick.saturating_sub(base.last_tick).saturating_add(1);
    let allowed = frames
        .saturating_mul(limits.stamp_lead_factor)
        .saturating_mul(FRAME_PERIOD_US)
        .saturating_add(FRAME_PERIOD_US);
    if t_us - p <= allowed {
        return true;
    }
    // A leap: does it continue a candidate time base?
    let continues = match base.candidate {
        Some((c_t, c_tick, _)) if t_us > c_t => {
            let f = tick.saturating_sub(c_tick).saturating_add(1);
            t_us - c_t
                <= f.saturating_mul(limits.stamp_lead_factor)
                    .saturating_mul(FRAME_PERIOD_US)
                    .saturating_add(FRAME_PERIOD_US)
        }
        _ => false,
    };
    let count = match (continues, base.candidate) {
        (true, Some((_, _, n))) => n.saturating_add(1),
        _ => 1,
    };
    if count >= limits.resync_readings {
        health.resyncs = health.resyncs.saturating_add(1);
        return true;
    }
    base.candidate = Some((t_us, tick, count));
    health.time_jumps = health.time_jumps.saturating_add(1);
    false
}

/// Stale or backwards time stamps (the camera, whose stamps are its trigger times).
fn check_order(health: &mut DeviceHealth, previous: Option<u64>, t_us: u64) -> bool {
    match previous {
        Some(p) if t_us == p => {
            health.stale = health.stale.saturating_add(1);
            false
        }
        Some(p) if t_us < p => {
            health.time_backwards = health.time_backwards.saturating_add(1);
            false
        }
        _ => true,
    }
}

fn all_finite(values: &[f64]) -> bool {
    values.iter().all(|v| v.is_finite())
}

fn count_invalid(health: &mut DeviceHealth) {
    health.invalid = health.invalid.saturating_add(1);
}

fn count_error(health: &mut DeviceHealth, kind: ErrorKind) {
    // A poll with no new data is not a fault; everything else is.
    if kind != ErrorKind::NotReady {
        health.errors = health.errors.saturating_add(1);
    }
}

impl<P: Platform> Work<'_, P> {
    #[inline(never)]
    fn read_imu(&mut self, tick: u64) {
        let health = &mut self.state.health[DeviceId::Imu as usize];
        let base = &mut self.state.time_bases[DeviceId::Imu as usize];
        match self.devices.imu.read() {
            Err(e) => count_error(health, rover_hal::Error::kind(&e)),
            Ok(s) => {
                let previous = self.state.imu.map(|p| p.t_us);
                let resyncs = health.resyncs;
                if !check_time(health, base, previous, s.t_us, tick, self.limits) {
                    return;
                }
                let rebased = health.resyncs != resyncs;
                let l = self.limits;
                let in_range = |v: &[f64; 3], max: f64| {
                    all_finite(v) && v.iter().all(|x| libm::fabs(*x) <= max)
                };
                let accel_ok = in_range(&s.accel_m_s2, l.accel_max_m_s2);
                // A shock: an accelerometer axis at its range (clipped) or beyond it (refused
                // below); that sample's velocity increment is unknown up to the range over one
                // frame (`Navigator::imu_shock`).
                let shock = all_finite(&s.accel_m_s2)
                    && s.accel_m_s2
                        .iter()
                        .any(|a| libm::fabs(*a) >= IMU_SATURATION * l.accel_max_m_s2);
                let shock_sigma_m_s = l.accel_max_m_s2 * FRAME_PERIOD_US as f64 * 1e-6;
                if !s.valid || !in_range(&s.gyro_rad_s, l.gyro_max_rad_s) || !accel_ok {
                    count_invalid(health);
                    if s.valid && shock {
                        self.nav.imu_shock(shock_sigma_m_s);
                    }
                    return;
                }
                health.good = health.good.saturating_add(1);
                base.accept(tick);
                if rebased {
                    // The filter's timeline restarts one frame before this sample.
                    self.nav
                        .imu_time_rebase(s.t_us.saturating_sub(FRAME_PERIOD_US));
                }
                if shock {
                    self.nav.imu_shock(shock_sigma_m_s);
                }
                self.state.imu = Some(s);
                self.fresh.imu = Some(s);
            }
        }
    }

    #[inline(never)]
    fn read_joints(&mut self, tick: u64) {
        let health = &mut self.state.health[DeviceId::Joints as usize];
        let base = &mut self.state.time_bases[DeviceId::Joints as usize];
        match self.devices.mobility.read_joints() {
            Err(e) => count_error(health, rover_hal::Error::kind(&e)),
            Ok(j) => {
                let previous = self.state.joints.map(|p| p.t_us);
                if !check_time(health, base, previous, j.t_us, tick, self.limits) {
                    return;
                }
                let finite = all_finite(&j.drive_angle_rad)
                    && all_finite(&j.drive_rate_rad_s)
                    && all_finite(&j.steer_angle_rad)
                    && all_finite(&j.bogie_rad)
                    && j.rocker_rad.is_finite();
                let limits = &self.nav.config().geometry.limits;
                let (l, m) = (self.limits, self.limits.angle_margin_rad);
                let rate_max = l.drive_rate_factor * limits.wheel_rate_rad_s;
                let plausible = j
                    .drive_rate_rad_s
                    .iter()
                    .all(|r| libm::fabs(*r) <= rate_max)
                    && j.steer_angle_rad
                        .iter()
                        .all(|a| libm::fabs(*a) <= limits.steer_rad + m)
                    && libm::fabs(j.rocker_rad) <= limits.rocker_rad + m
                    && j.bogie_rad
                        .iter()
                        .all(|a| libm::fabs(*a) <= limits.bogie_rad + m);
                if !finite || !plausible || !j.suspension_valid {
                    count_invalid(health);
                    return;
                }
                health.good = health.good.saturating_add(1);
                base.accept(tick);
                self.state.joints = Some(j);
                self.fresh.joints = Some(j);
            }
        }
    }

    fn send(&mut self, kind: RecordKind, record: &impl serde::Serialize) {
        let mut buffer = [0u8; MAX_RECORD_BYTES];
        let sent = match telemetry::encode(kind, record, &mut buffer) {
            Ok(bytes) => self.devices.telemetry.send(bytes).is_ok(),
            Err(_) => false,
        };
        if !sent {
            self.state.telemetry_dropped = self.state.telemetry_dropped.saturating_add(1);
        }
    }

    #[inline(never)]
    fn send_status(&mut self, tick: u64) {
        let record = FrameStatus {
            tick,
            cycle_slips: self.state.exec_status.0,
            timing_fault: self.state.exec_status.1,
            health: self.state.health,
            stereo_frames: self.state.stereo_frames,
            telemetry_dropped: self.state.telemetry_dropped,
            energy_used_j: self.state.power.map_or(0.0, |p| p.energy_used_j),
            bus_power_w: self.state.power.map_or(0.0, |p| p.bus_power_w as f32),
        };
        self.send(RecordKind::FrameStatus, &record);
        let nav = NavTelemetry::from_navigator(tick, self.nav);
        self.send(RecordKind::NavStatus, &nav);
    }

    #[inline(never)]
    fn command_motors(&mut self) {
        let result = match self.nav.guidance_cycle() {
            Some(command) => {
                self.state.last_command = Some(command);
                self.devices.mobility.command(&command)
            }
            None => {
                self.state.last_command = None;
                self.devices.mobility.stop()
            }
        };
        match result {
            Ok(()) => self.state.commands_sent = self.state.commands_sent.saturating_add(1),
            Err(_) => {
                self.state.commands_refused = self.state.commands_refused.saturating_add(1);
                // A refused command must not leave the rover moving: stop (best effort).
                let _ = self.devices.mobility.stop();
            }
        }
    }

    #[inline(never)]
    fn trigger_stereo(&mut self, tick: u64) {
        let health = &mut self.state.health[DeviceId::Camera as usize];
        if self.state.capture_pending_t_us.is_some() {
            if tick.saturating_sub(self.state.capture_pending_tick) < CAPTURE_TIMEOUT_FRAMES {
                return;
            }
            // The capture has not completed within the timeout: count, drop and retry when due.
            count_error(health, ErrorKind::Timeout);
            if self.devices.camera.release().is_err() {
                count_error(health, ErrorKind::Hardware);
            }
            self.state.capture_pending_t_us = None;
            self.nav.capture_lost();
        }
        // The navigator decides (capture policy). No capture is triggered that VO cannot use:
        // while VO works on the last frame (held) or its result is replayed, a due capture
        // waits (the condition persists) and starts at the first RG3 after VO is idle.
        let Some(reason) = self.nav.capture_due() else {
            return;
        };
        match self.devices.camera.trigger() {
            Ok(t_us) => {
                self.state.capture_pending_t_us = Some(t_us);
                self.state.capture_pending_tick = tick;
                self.nav.capture_started(t_us, reason);
            }
            Err(e) => count_error(health, rover_hal::Error::kind(&e)),
        }
    }

    fn release_frame(&mut self) {
        if self.devices.camera.release().is_err() {
            let health = &mut self.state.health[DeviceId::Camera as usize];
            count_error(health, ErrorKind::Hardware);
        }
    }

    /// Background: rectify rows of the raw pair in the camera's buffers into the image
    /// memory ([`crate::rectify`]); when the pair is done the camera frame is released and VO
    /// (or the hazard mapper) starts on the rectified pair. Returns the units used.
    fn rectify_step(&mut self, quantum: u32) -> u32 {
        let progress = match self.devices.camera.frame() {
            Ok(frame) => self
                .rect
                .rectifier
                .step(&frame, &mut self.devices.image_memory, quantum),
            Err(e) => {
                let health = &mut self.state.health[DeviceId::Camera as usize];
                count_error(health, rover_hal::Error::kind(&e));
                RectifyProgress::Finished(Err(crate::rectify::RectifyError::FrameChanged))
            }
        };
        let result = match progress {
            RectifyProgress::Working { .. } => return quantum.max(1),
            RectifyProgress::Finished(result) => result,
        };
        // The raw pair is no longer needed either way.
        self.release_frame();
        let pending = self.rect.pending.take();
        match (result, pending) {
            (Ok(()), Some((t_us, sequence))) => {
                self.state.rectified_pairs = self.state.rectified_pairs.saturating_add(1);
                let (left, right) = self.devices.image_memory.images();
                let frame = rover_hal::StereoFrame {
                    left,
                    right,
                    capture_t_us: t_us,
                    sequence,
                };
                if self.nav.vo_start(&frame) {
                    self.rect.frame = Some((t_us, sequence));
                } else {
                    self.nav.capture_lost();
                }
            }
            _ => {
                self.rect.rectifier.reset();
                self.state.rectify_failures = self.state.rectify_failures.saturating_add(1);
                self.nav.capture_lost();
            }
        }
        quantum.max(1)
    }

    fn poll_stereo(&mut self, quantum: u32) -> u32 {
        // A replan of the day's targets takes the slice (V99 sec. 3).
        if self.nav.mission_replan_due() {
            return self.nav.mission_background(quantum);
        }
        if self.nav.replaying() {
            return self.nav.replay_step();
        }
        if self.rect.rectifier.is_busy() {
            return self.rectify_step(quantum);
        }
        if self.nav.vo_busy() {
            if let Some((t_us, sequence)) = self.rect.frame {
                // VO or the hazard mapper on the rectified pair in the image memory (the raw
                // pair was released when it was rectified).
                let (left, right) = self.devices.image_memory.images();
                let frame = rover_hal::StereoFrame {
                    left,
                    right,
                    capture_t_us: t_us,
                    sequence,
                };
                let (used, done) = self.nav.vo_step(&frame, quantum);
                if done {
                    self.rect.frame = None;
                }
                return used;
            }
            let (used, done) = match self.devices.camera.frame() {
                Ok(frame) => self.nav.vo_step(&frame, quantum),
                Err(e) => {
                    let health = &mut self.state.health[DeviceId::Camera as usize];
                    count_error(health, rover_hal::Error::kind(&e));
                    self.nav.capture_lost();
                    (1, true)
                }
            };
            if done {
                self.release_frame();
            }
            return used;
        }
        // VO went idle without finishing on the rectified pair (capture lost): forget it.
        self.rect.frame = None;
        let Some(t_us) = self.state.capture_pending_t_us else {
            return 0;
        };
        let health = &mut self.state.health[DeviceId::Camera as usize];
        match self.devices.camera.poll() {
            Ok(CaptureStatus::Ready) => {
                self.state.capture_pending_t_us = None;
                let mut vo_started = false;
                match self.devices.camera.frame() {
                    Ok(frame) if frame.capture_t_us == t_us => {
                        let size_ok = frame.left.len() == rover_hal::IMAGE_PIXELS
                            && frame.right.len() == rover_hal::IMAGE_PIXELS;
                        if size_ok && check_order(health, self.state.last_capture_t_us, t_us) {
                            health.good = health.good.saturating_add(1);
                            self.state.stereo_frames = self.state.stereo_frames.saturating_add(1);
                            self.state.last_capture_t_us = Some(t_us);
                            if self.nav.capture_pending() {
                                if self.state.rectifying {
                                    // Raw pair: rectified in the next background slices,
                                    // then handed to VO (rectify_step).
                                    vo_started = self.rect.rectifier.start(&frame).is_ok();
                                    if vo_started {
                                        self.rect.pending = Some((t_us, frame.sequence));
                                    } else {
                                        self.state.rectify_failures =
                                            self.state.rectify_failures.saturating_add(1);
                                    }
                                } else {
                                    vo_started = self.nav.vo_start(&frame);
                                }
                            }
                        } else if !size_ok {
                            count_invalid(health);
                        }
                    }
                    Ok(_) => count_invalid(health),
                    Err(e) => count_error(health, rover_hal::Error::kind(&e)),
                }
                if !vo_started {
                    self.nav.capture_lost();
                    self.release_frame();
                }
                1
            }
            Ok(CaptureStatus::InProgress) => 1,
            Ok(CaptureStatus::Idle) => {
                // The camera lost the capture.
                count_error(health, ErrorKind::Other);
                self.state.capture_pending_t_us = None;
                self.nav.capture_lost();
                1
            }
            Err(e) => {
                count_error(health, rover_hal::Error::kind(&e));
                1
            }
        }
    }

    #[inline(never)]
    fn read_sun(&mut self, tick: u64) {
        let health = &mut self.state.health[DeviceId::Sun as usize];
        let base = &mut self.state.time_bases[DeviceId::Sun as usize];
        match self.devices.sun.read() {
            Err(e) => count_error(health, rover_hal::Error::kind(&e)),
            Ok(r) => {
                let previous = self.state.sun.map(|p| p.t_us);
                if !check_time(health, base, previous, r.t_us, tick, self.limits) {
                    return;
                }
                let norm2: f64 = r.sun_dir_rover.iter().map(|v| v * v).sum();
                if !r.sun_in_view {
                    return;
                }
                if !all_finite(&r.sun_dir_rover) || !(0.81..=1.21).contains(&norm2) {
                    count_invalid(health);
                    return;
                }
                health.good = health.good.saturating_add(1);
                base.accept(tick);
                self.state.sun = Some(r);
                self.nav.sun(&r);
            }
        }
    }

    /// RG4 `power`: read the power subsystem (V99 sec. 3: the "current power reserves" the
    /// sequencer monitors). A call error is counted; a time stamp that does not advance goes
    /// through [`check_time`]; a reading the device flags invalid, with a non-finite or
    /// negative energy or bus power, with less energy used than the last accepted reading
    /// (the battery's discharge integral never decreases), or beyond
    /// [`Plausibility::bus_power_max_w`] (the bus power, or the growth of the energy used
    /// since the last accepted reading) is counted invalid and not passed on. A reading that
    /// passes is kept ([`FlightState::power`]) and handed to [`Navigator::power`].
    #[inline(never)]
    fn read_power(&mut self, tick: u64) {
        let health = &mut self.state.health[DeviceId::Power as usize];
        let base = &mut self.state.time_bases[DeviceId::Power as usize];
        match self.devices.power.read() {
            Err(e) => count_error(health, rover_hal::Error::kind(&e)),
            Ok(r) => {
                let previous = self.state.power;
                if !check_time(
                    health,
                    base,
                    previous.map(|p| p.t_us),
                    r.t_us,
                    tick,
                    self.limits,
                ) {
                    return;
                }
                let (t0_us, e0_j) = previous.map_or((0, 0.0), |p| (p.t_us, p.energy_used_j));
                let elapsed_s = r.t_us.saturating_sub(t0_us) as f64 * 1e-6;
                let max_w = self.limits.bus_power_max_w;
                let plausible = r.valid
                    && r.energy_used_j.is_finite()
                    && r.bus_power_w.is_finite()
                    && r.energy_used_j >= e0_j
                    && r.energy_used_j - e0_j <= max_w * elapsed_s
                    && r.bus_power_w >= 0.0
                    && r.bus_power_w <= max_w;
                if !plausible {
                    count_invalid(health);
                    return;
                }
                health.good = health.good.saturating_add(1);
                base.accept(tick);
                self.state.power = Some(r);
                self.nav.power(&r);
            }
        }
    }
}

// The tasks and the background are `#[inline(never)]` (here, in `Work` and in the navigator's
// task entry points): inlined into `Fsw::tick` their locals shared one 14 KB frame that was on
// the stack under every task (issue 18, `cargo xtask stack`); apart, the frame of the one task
// running is. No effect on the numerics (no FP contraction in Rust).
impl<P: Platform> TaskSet for Work<'_, P> {
    #[inline(never)]
    fn run_task(&mut self, task: usize, tick: u64) {
        match task {
            0 => self.read_imu(tick),
            1 => self.nav.propagate(self.fresh.imu.take().as_ref()),
            2 => self.read_joints(tick),
            3 => self.nav.kinematic_cycle(self.fresh.joints.take().as_ref()),
            4 => self.command_motors(),
            5 => self.trigger_stereo(tick),
            6 => self.read_sun(tick),
            7 => self.read_power(tick),
            8 => self.nav.zero_velocity_cycle(),
            9 => self.send_status(tick),
            _ => {}
        }
    }

    #[inline(never)]
    fn background(&mut self, quantum: u32, _tick: u64) -> u32 {
        if quantum == 0 {
            return 0;
        }
        self.poll_stereo(quantum)
    }
}

#[cfg(test)]
mod tests;
