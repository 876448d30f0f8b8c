//! # The flight software's top level
//!
//! [`Fsw`] owns every piece of flight state in fixed-size fields and the devices it reads
//! through the HAL. [`Fsw::tick`] runs one minor frame of the rate-group schedule
//! ([`Group`], [`Task`]: [`SCHEDULE_GROUPS`], [`SCHEDULE_TASKS`]):
//!
//! | group | rate (default) | tasks |
//! |---|---|---|
//! | RG1 | 200 Hz | `imu`: IMU read and checks; `propagate`: EKF propagation (eq. 26-27) |
//! | RG2 | 20 Hz | `joints`: joint read and checks; `odometry`: kinematic interval, gate (eq. 46), EKF update or slip vector; `guidance`: carrot and slip loops (eq. 47-49), inverse kinematics, motor command |
//! | RG3 | 5 Hz | `stereo`: capture policy (H04 sec. 2: every 0.10 m or 10 deg of EKF motion, at the latest every 10 s; [`nav::Navigator::capture_due`]), capture trigger and clone (eq. 41); a capture not completed within [`stereo::CAPTURE_TIMEOUT_FRAMES`] is timed out |
//! | RG2B | 20 Hz, half a period after RG2 | `zupt`: the zero-velocity update of a stop the `odometry` task saw, while the command is still zero ([`nav::Navigator::zero_velocity_cycle`]); `telemetry`: status and navigation records |
//! | RG4 | 0.2 Hz | `sun`: sun read and heading update (RB sec. 5.1); `power`: power-subsystem read and checks, the battery energy used handed to the navigator (V99 sec. 3) |
//! | background | every frame | stereo polling, rectification of raw pairs, visual odometry work items, VO gate and fusion at the capture clones |
//!
//! Every device reading is checked ([`devices`]: error, device-flagged invalid, non-finite,
//! out of range, time stamp not advancing, going backwards or leaping) and counted in
//! [`DeviceHealth`]; only checked readings are kept and handed to the [`nav::Navigator`].
//!
//! | file | content |
//! |---|---|
//! | `schedule.rs` | the rate groups and tasks as enums that index the executive's tables |
//! | `devices.rs` | the checked reads of the timestamped devices, plausibility limits, time bases |
//! | `stereo.rs` | capture trigger, polling, rectification and the background slices |
//! | `health.rs` | device health counters and the frame status record |
//! | `nav/` | the navigator and its components |

mod devices;
mod health;
pub mod nav;
mod schedule;
mod stereo;

pub use devices::{Plausibility, TimeBase};
pub use health::{DeviceHealth, FrameStatus};
pub use schedule::{Group, Task, GROUP_COUNT, SCHEDULE_GROUPS, SCHEDULE_TASKS, TASK_COUNT};
pub use stereo::CAPTURE_TIMEOUT_FRAMES;

use crate::exec::{ExecConfig, ExecError, Executive, FrameReport, TaskSet};
use crate::guidance::Point2;
use crate::rectify::{Rectifier, RectifyConfig, RectifyMemory};
use crate::telemetry::{self, RecordKind, MAX_RECORD_BYTES};
use nav::{NavConfig, NavError, Navigator};
use rover_hal::{
    Clock, Imu, ImuSample, JointState, Mobility, Power, PowerReading, StereoCamera, SunReading,
    SunSensor, Telemetry,
};
use stereo::RectStage;

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

impl FswConfig {
    /// Defaults for Rocky 8 starting at `position` (m, `N`) heading `yaw_rad` (from north): the
    /// default executive with 60 cost units of background work per minor frame (at most
    /// 0.6 M instructions plus one item; the largest frame measured with its slice takes 80 %
    /// of the 5 ms period at CPI 2.0, where 100 units took 133 %; a VO update with the
    /// rectification of its pair about 14,000 units, 1.1 s; `docs/results/timing.md`).
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
pub(crate) struct Fresh {
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

pub(crate) struct DevicesNoClock<P: Platform> {
    imu: P::Imu,
    mobility: P::Mobility,
    camera: P::Camera,
    sun: P::Sun,
    power: P::Power,
    telemetry: P::Telemetry,
    image_memory: P::ImageMemory,
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

pub(crate) struct Work<'a, P: Platform> {
    limits: &'a Plausibility,
    devices: &'a mut DevicesNoClock<P>,
    state: &'a mut FlightState,
    nav: &'a mut Navigator,
    fresh: &'a mut Fresh,
    rect: &'a mut RectStage,
}

impl<P: Platform> Work<'_, P> {
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
        let nav = self.nav.status(tick);
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
}

// The tasks and the background are `#[inline(never)]` (here, in `Work` and in the navigator's
// task entry points): inlined into `Fsw::tick` their locals would share one frame on the stack
// under every task (`cargo xtask stack`); apart, the frame of the one task running is. No
// effect on the numerics (no FP contraction in Rust).
impl<P: Platform> TaskSet for Work<'_, P> {
    #[inline(never)]
    fn run_task(&mut self, task: usize, tick: u64) {
        let Some(task) = Task::from_index(task) else {
            return;
        };
        match task {
            Task::Imu => self.read_imu(tick),
            Task::Propagate => self.nav.propagate(self.fresh.imu.take().as_ref()),
            Task::Joints => self.read_joints(tick),
            Task::Odometry => self.nav.kinematic_cycle(self.fresh.joints.take().as_ref()),
            Task::Guidance => self.command_motors(),
            Task::Stereo => self.trigger_stereo(tick),
            Task::Sun => self.read_sun(tick),
            Task::Power => self.read_power(tick),
            Task::Zupt => self.nav.zero_velocity_cycle(),
            Task::Telemetry => self.send_status(tick),
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
