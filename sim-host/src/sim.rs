//! One closed-loop run of a scenario: the world, the flight software on the simulated devices,
//! and the command source (the reference driver until the flight software drives).

use crate::camera::{FlatGreyRenderer, StereoRenderer};
use crate::devices::CountingTelemetry;
use crate::driver::{closest_arc, CommandSource, ReferenceDriver};
use crate::hal_devices::{
    CounterMode, SharedWorld, WorldClock, WorldImu, WorldMobility, WorldStereo, WorldSun,
};
use crate::scenario::{DriverMode, Scenario};
use crate::world::{World, FRAME_US};
use fsw::exec::ExecConfig;
use fsw::flight::{Devices, Fsw, Platform};
use std::cell::RefCell;
use std::rc::Rc;

/// The simulated platform's device types.
pub struct WorldPlatform;

impl Platform for WorldPlatform {
    type Clock = WorldClock;
    type Imu = WorldImu;
    type Mobility = WorldMobility;
    type Camera = WorldStereo;
    type Sun = WorldSun;
    type Telemetry = CountingTelemetry;
}

/// Options of a run.
pub struct RunOptions {
    /// Seed (overrides the scenario's).
    pub seed: Option<u64>,
    /// Force the reference driver to open loop (no slip compensation).
    pub no_slip_comp: bool,
    /// Execution counter of the flight clock.
    pub counter: CounterMode,
    /// Stereo renderer (default: [`FlatGreyRenderer`]).
    pub renderer: Option<Box<dyn StereoRenderer>>,
    /// Called every simulated second with the fraction done.
    pub progress: Option<Box<dyn FnMut(f64)>>,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            seed: None,
            no_slip_comp: false,
            counter: CounterMode::Host,
            renderer: None,
            progress: None,
        }
    }
}

/// Truth and slip at one record time (20 Hz).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Record {
    /// Time, s.
    pub t_s: f64,
    /// Position in `W` (north, east, down), m.
    pub pos_m: [f64; 3],
    /// Attitude `R` to `W` as a quaternion `[x, y, z, w]`.
    pub quat_xyzw: [f64; 4],
    /// Roll, pitch, yaw, rad.
    pub rpy_rad: [f64; 3],
    /// Rocker, right bogie, left bogie, rad.
    pub suspension_rad: [f64; 3],
    /// Longitudinal slip ratio.
    pub slip_ratio: f64,
    /// Lateral slip angle, rad.
    pub slip_angle_rad: f64,
    /// Distance to the path, m.
    pub cross_track_m: f64,
    /// Distance travelled, m.
    pub distance_m: f64,
}

/// Per-rate-group timing of the flight executive.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupTiming {
    /// Group name.
    pub name: String,
    /// Runs.
    pub runs: u64,
    /// Largest execution time, us.
    pub max_us: u64,
    /// Mean execution time, us.
    pub mean_us: u64,
    /// Task overruns in the group.
    pub overruns: u64,
}

/// Everything a run produces (before formatting).
#[derive(Debug, Clone)]
pub struct RunResult {
    /// Scenario name.
    pub scenario: String,
    /// Seed used.
    pub seed: u64,
    /// Waypoints.
    pub waypoints: Vec<[f64; 2]>,
    /// Records at 20 Hz.
    pub records: Vec<Record>,
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Distance travelled, m.
    pub distance_m: f64,
    /// Goal reached within the tolerance.
    pub goal_reached: bool,
    /// Final distance to the last waypoint, m.
    pub goal_miss_m: f64,
    /// Flight executive timing per group.
    pub timing: Vec<GroupTiming>,
    /// Device faults the flight software counted.
    pub device_faults: u32,
    /// Stereo frames the flight software completed.
    pub stereo_frames: u32,
    /// Rocks of the terrain `[north, east, radius]` for the top view.
    pub rocks: Vec<[f64; 3]>,
    /// Wall-clock seconds of the run.
    pub wall_time_s: f64,
}

/// Hooks into a run (used by `record`): wrap the simulated devices before the flight software
/// is built, and look at the flight software after every frame.
pub trait RunHooks {
    /// Device types after wrapping.
    type Platform: Platform;
    /// Wrap the simulated devices.
    fn wrap(&mut self, devices: Devices<WorldPlatform>) -> Devices<Self::Platform>;
    /// Called after every `Fsw::tick`.
    fn after_tick(&mut self, fsw: &Fsw<Self::Platform>);
}

/// No hooks: the simulated devices as they are.
pub struct NoHooks;

impl RunHooks for NoHooks {
    type Platform = WorldPlatform;
    fn wrap(&mut self, devices: Devices<WorldPlatform>) -> Devices<WorldPlatform> {
        devices
    }
    fn after_tick(&mut self, _fsw: &Fsw<WorldPlatform>) {}
}

/// Run `scenario` with `options`.
pub fn run(scenario: &Scenario, options: RunOptions) -> anyhow::Result<RunResult> {
    run_with(scenario, options, &mut NoHooks)
}

/// Run `scenario` with `options` and `hooks`.
pub fn run_with<H: RunHooks>(
    scenario: &Scenario,
    mut options: RunOptions,
    hooks: &mut H,
) -> anyhow::Result<RunResult> {
    let start = std::time::Instant::now();
    let seed = options.seed.unwrap_or(scenario.seed);
    let world: SharedWorld = Rc::new(RefCell::new(World::new(scenario, seed)?));
    let renderer = options
        .renderer
        .take()
        .unwrap_or_else(|| Box::new(FlatGreyRenderer));
    let devices = Devices::<WorldPlatform> {
        clock: WorldClock::new(world.clone(), options.counter),
        imu: WorldImu::new(world.clone()),
        mobility: WorldMobility::new(world.clone()),
        camera: WorldStereo::new(
            world.clone(),
            renderer,
            scenario.sensors.camera_latency_polls,
            seed,
        ),
        sun: WorldSun::new(world.clone()),
        telemetry: CountingTelemetry::default(),
    };
    let mut fsw = Fsw::new(hooks.wrap(devices), ExecConfig::default())
        .map_err(|e| anyhow::anyhow!("flight schedule refused: {e:?}"))?;
    let mode = if options.no_slip_comp {
        DriverMode::OpenLoop
    } else {
        scenario.driver
    };
    let mut source = CommandSource::Reference(ReferenceDriver::new(scenario, mode));
    let max_steps = (scenario.duration_s * 1e6 / FRAME_US as f64).ceil() as u64;
    let mut records = Vec::new();
    let mut stop_countdown: Option<u32> = None;
    let mut steps = 0;
    while steps < max_steps {
        {
            let mut w = world.borrow_mut();
            let command = match &mut source {
                CommandSource::Reference(driver) => {
                    let c = driver.command(&w);
                    if driver.done() && stop_countdown.is_none() {
                        stop_countdown = Some(200);
                    }
                    c
                }
                CommandSource::Flight => w.flight_command.unwrap_or_default(),
            };
            w.command = command;
            w.step();
            if w.steps % 10 == 0 {
                records.push(record(&w, &scenario.waypoints));
            }
        }
        fsw.tick();
        hooks.after_tick(&fsw);
        steps += 1;
        if steps % 200 == 0 {
            if let Some(p) = options.progress.as_mut() {
                p(steps as f64 / max_steps as f64);
            }
        }
        if let Some(n) = stop_countdown.as_mut() {
            *n = n.saturating_sub(1);
            if *n == 0 {
                break;
            }
        }
    }
    let w = world.borrow();
    let end = scenario.waypoints[scenario.waypoints.len() - 1];
    let p = w.truth.pose.pos_m;
    let goal_miss_m = ((p[0] - end[0]).powi(2) + (p[1] - end[1]).powi(2)).sqrt();
    let exec = fsw.executive();
    let timing = exec
        .groups()
        .iter()
        .enumerate()
        .map(|(g, state)| GroupTiming {
            name: state.config.name.to_string(),
            runs: state.runs,
            max_us: state.timing.max_us,
            mean_us: state.timing.mean_us(),
            overruns: exec
                .tasks()
                .iter()
                .filter(|t| t.config.group == g)
                .map(|t| t.timing.overruns)
                .sum(),
        })
        .collect();
    let state = fsw.state();
    Ok(RunResult {
        scenario: scenario.name.clone(),
        seed,
        waypoints: scenario.waypoints.clone(),
        records,
        sim_time_s: w.truth.t_us as f64 * 1e-6,
        distance_m: w.truth.distance_m,
        goal_reached: goal_miss_m <= scenario.goal_tolerance_m,
        goal_miss_m,
        timing,
        device_faults: state.health.iter().map(|h| h.faults()).sum(),
        stereo_frames: state.stereo_frames,
        rocks: w
            .terrain
            .rocks()
            .iter()
            .map(|r| [r.x_m, r.y_m, r.radius_m])
            .collect(),
        wall_time_s: start.elapsed().as_secs_f64(),
    })
}

fn record(w: &World, path: &[[f64; 2]]) -> Record {
    let t = &w.truth;
    let q = nalgebra::UnitQuaternion::from_rotation_matrix(&t.pose.rot_w_from_r());
    let (_, cross) = closest_arc(path, [t.pose.pos_m[0], t.pose.pos_m[1]]);
    Record {
        t_s: t.t_us as f64 * 1e-6,
        pos_m: t.pose.pos_m,
        quat_xyzw: [q.i, q.j, q.k, q.w],
        rpy_rad: [t.pose.roll_rad, t.pose.pitch_rad, t.pose.yaw_rad],
        suspension_rad: [
            t.suspension.rocker_rad,
            t.suspension.bogie_rad[0],
            t.suspension.bogie_rad[1],
        ],
        slip_ratio: t.slip.slip_ratio,
        slip_angle_rad: t.slip.slip_angle_rad,
        cross_track_m: cross,
        distance_m: t.distance_m,
    }
}
