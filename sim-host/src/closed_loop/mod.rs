//! One closed-loop run of a scenario: the world, the flight software on the simulated devices,
//! and the command source (the flight software; the simulator's reference driver on request).
//!
//! The flight software is configured as the ground would configure it: the start pose (from
//! the world's truth at the start, as a localisation before the drive would give it), the
//! path, the IMU noise densities from the IMU data sheet (the scenario's sensor parameters) and
//! the sun direction from the ephemeris (the scenario's sun). It sees the world only through
//! the HAL devices.

use crate::devices::renderer::{FlatGreyRenderer, StereoRenderer};
use crate::devices::world::{
    CounterMode, SharedWorld, WorldClock, WorldImu, WorldMobility, WorldPower, WorldStereo,
    WorldSun,
};
use crate::devices::CountingTelemetry;
use crate::driver::{CommandSource, ReferenceDriver};
use crate::scenario::{DriverMode, Scenario};
use crate::vehicle::placement::BodyPose;
use crate::world::{World, FRAME_US};
use fsw::flight::nav::NavMode;
use fsw::flight::{Devices, Fsw, FswConfig, Platform};
use std::cell::RefCell;
use std::rc::Rc;

mod flight_config;
mod result;

pub use flight_config::{flight_config, DriveOptions, Mission};
use result::{loc_check, mission_run, quat_xyzw, record, vo_check};
pub use result::{
    Estimates, GroupTiming, LocCheck, LocalizationRun, MissionRun, PlannerRun, Record, RunResult,
    TargetVisit, VoCheck,
};

/// The simulated platform's device types.
pub struct WorldPlatform;

impl Platform for WorldPlatform {
    type Clock = WorldClock;
    type Imu = WorldImu;
    type Mobility = WorldMobility;
    type Camera = WorldStereo;
    type Sun = WorldSun;
    type Power = WorldPower;
    type Telemetry = CountingTelemetry;
    type ImageMemory = crate::devices::HostImageMemory;
}

/// Options of a run.
pub struct RunOptions {
    /// Seed (overrides the scenario's).
    pub seed: Option<u64>,
    /// Run without slip compensation: the flight software navigates on wheel and IMU odometry
    /// (or, with `reference_driver`, the reference driver runs open loop).
    pub no_slip_comp: bool,
    /// Let the simulator's reference driver command the motors instead of the flight software.
    pub reference_driver: bool,
    /// Visual odometry off in the flight software (the cameras still capture).
    pub no_vo: bool,
    /// Terrain-map localization on in the flight software (V99 sec. 5), against a global map
    /// the simulator makes from its own rocks as a MARDI descent image from 150 m shows them
    /// ([`crate::descent_map`]) and uplinks before the drive.
    pub localization: bool,
    /// Map-tie fault of the uplinked map: every point moved by this, m (north, east), on top of
    /// the descent image's own errors (a wrong registration of the image to the rover's frame).
    pub map_offset_m: [f64; 2],
    /// Execution counter of the flight clock.
    pub counter: CounterMode,
    /// Stereo renderer (default: [`FlatGreyRenderer`]).
    pub renderer: Option<Box<dyn StereoRenderer>>,
    /// Called every simulated second with the fraction done.
    pub progress: Option<Box<dyn FnMut(f64)>>,
    /// Experiment hook: changes the flight configuration after [`flight_config`] has built it
    /// from the scenario and the drive options (for example `nav.slip_hold_cycles`, measured by
    /// `sim-host detection`). Never set by the `run`, `compare` and `sil` commands: the flight
    /// configuration of a normal run comes from the nominal profile and the mission plan only.
    pub configure: Option<fn(&mut FswConfig)>,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            seed: None,
            no_slip_comp: false,
            reference_driver: false,
            no_vo: false,
            localization: false,
            map_offset_m: [0.0; 2],
            counter: CounterMode::Host,
            renderer: None,
            progress: None,
            configure: None,
        }
    }
}

/// The global map the ground uplinks: the rocks a MARDI frame from 150 m shows
/// ([`crate::descent_map::DescentImage::mardi`]) in the flight map's 38.4 m square centred on
/// the middle of the waypoints' bounding box.
fn uplink_map(
    terrain: &crate::terrain::Terrain,
    waypoints: &[[f64; 2]],
    seed: u64,
) -> ([f64; 2], crate::descent_map::DescentMap) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for w in waypoints {
        for k in 0..2 {
            lo[k] = lo[k].min(w[k]);
            hi[k] = hi[k].max(w[k]);
        }
    }
    let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
    let side = fsw::localization::MAP_SIDE as f64 * fsw::localization::MAP_CELL_M;
    let image = crate::descent_map::DescentImage::mardi(50.0);
    (
        centre,
        crate::descent_map::descent_map(terrain, &image, centre, side, seed),
    )
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
        power: WorldPower::new(world.clone()),
        telemetry: CountingTelemetry::with_refusal(crate::devices::world::telemetry_faults(
            world.clone(),
        )),
        image_memory: crate::devices::host_image_memory(),
    };
    let mut config = flight_config(
        scenario,
        DriveOptions {
            slip_compensation: !options.no_slip_comp,
            vo_enabled: !options.no_vo,
        },
    );
    config.nav.localization.enabled = options.localization;
    if let Some(configure) = options.configure {
        configure(&mut config);
    }
    let mut fsw = Fsw::new(hooks.wrap(devices), &config, &scenario.waypoints)
        .map_err(|e| anyhow::anyhow!("flight software refused its configuration: {e:?}"))?;
    if options.localization {
        // The flight software keeps a `&'static mut` to its localization storage (external
        // RAM on the rover CPU): one leaked 82 KB block per run that asks for localization.
        fsw.provide_localization_memory(Box::leak(Box::new(fsw::flight::nav::LocNav::EMPTY)));
    }
    fsw.start_vo();
    let uplinked = if options.localization {
        let mut map = {
            let w = world.borrow();
            uplink_map(&w.terrain, &scenario.waypoints, seed)
        };
        for p in &mut map.1.points {
            p[0] += options.map_offset_m[0];
            p[1] += options.map_offset_m[1];
        }
        let inserted = fsw
            .uplink_global_map(map.0, &map.1.points)
            .ok_or_else(|| anyhow::anyhow!("the flight software refused the global map"))?;
        Some((map.1, inserted))
    } else {
        None
    };
    if let Some(m) = &scenario.mission {
        let budget = fsw::flight::nav::MissionBudget {
            energy_j: m.energy_budget_j,
            end_s: m.end_s.unwrap_or(scenario.duration_s),
        };
        // The flight software's own a-priori resource model (not the simulator's energy
        // model: the flight software learns the difference from the power telemetry).
        fsw.uplink_targets(
            &m.targets(),
            fsw::sequencer::ResourceModel::rocky8(),
            budget,
        )
        .map_err(|e| anyhow::anyhow!("the flight software refused the targets: {e:?}"))?;
    }
    let mut mission_visits: Vec<TargetVisit> = Vec::new();
    let mut mission_phase = fsw::flight::nav::MissionPhase::None;
    let mut loc_seen = 0u32;
    let mut loc_checks: Vec<LocCheck> = Vec::new();
    let mut source = if options.reference_driver {
        let mode = if options.no_slip_comp {
            DriverMode::OpenLoop
        } else {
            scenario.driver
        };
        CommandSource::Reference(ReferenceDriver::new(scenario, mode))
    } else {
        CommandSource::Flight
    };
    let max_steps = (scenario.duration_s * 1e6 / FRAME_US as f64).ceil() as u64;
    let mut records = Vec::new();
    let mut stop_countdown: Option<u32> = None;
    let mut steps = 0;
    let mut vo_seen = 0u32;
    let (mut vo_features, mut vo_inliers) = (0.0, 0.0);
    let mut vo_checks = Vec::new();
    // Truth poses of the last 10 s, to check VO relative poses against.
    let mut history: std::collections::VecDeque<(u64, BodyPose)> = Default::default();
    let mut hazard_monitor = {
        let w = world.borrow();
        crate::hazards::HazardMonitor::new(&w.terrain, scenario.hazard_height_m)
    };
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
            history.push_back((w.truth.t_us, w.truth.pose));
            if history.len() > 2000 {
                history.pop_front();
            }
        }
        fsw.tick();
        hooks.after_tick(&fsw);
        let nav = fsw.nav();
        if nav.counters().vo_updates > vo_seen {
            vo_seen = nav.counters().vo_updates;
            if let Some(out) = nav.vo_output() {
                vo_features += f64::from(out.quality.features);
                vo_inliers += f64::from(out.quality.inliers);
                if let Some(mut check) = out.pose.as_ref().and_then(|rp| vo_check(rp, &history)) {
                    check.vo_pose = nav
                        .vo_pose()
                        .map(|v| ([v.p_n.x, v.p_n.y, v.p_n.z], quat_xyzw(&v.q_nr)));
                    vo_checks.push(check);
                }
            }
        }
        if nav.mission_phase() != mission_phase {
            mission_phase = nav.mission_phase();
            if let (fsw::flight::nav::MissionPhase::Dwelling { target }, Some(m)) =
                (mission_phase, &scenario.mission)
            {
                // The truth at the start of the dwell: is the rover really at the target?
                let w = world.borrow();
                let p = w.truth.pose.pos_m;
                let t = m.targets.get(usize::from(target));
                mission_visits.push(TargetVisit {
                    target: usize::from(target),
                    t_s: w.truth.t_us as f64 * 1e-6,
                    miss_m: t.map_or(f64::NAN, |t| (p[0] - t.x_m).hypot(p[1] - t.y_m)),
                    distance_m: w.truth.distance_m,
                });
            }
        }
        if let Some(fix) = nav.last_localization() {
            if fix.search != loc_seen {
                loc_seen = fix.search;
                if let Some(check) = loc_check(&fix, &history) {
                    loc_checks.push(check);
                }
            }
        }
        if matches!(source, CommandSource::Flight)
            && matches!(
                nav.mode(),
                NavMode::Arrived | NavMode::Safed | NavMode::Stopped
            )
            && stop_countdown.is_none()
        {
            stop_countdown = Some(200);
        }
        {
            let w = world.borrow();
            if w.steps % 10 == 0 {
                records.push(record(&w, &scenario.waypoints, &fsw));
                hazard_monitor.check(w.truth.t_us as f64 * 1e-6, &w.truth.pose, &w.geometry);
            }
        }
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
    let mission = scenario
        .mission
        .as_ref()
        .map(|m| mission_run(m, fsw.nav(), &mission_visits, p));
    // With targets the goal is every target: reached when each was visited within the
    // tolerance; the miss is the largest truth miss (at the dwell, or at the end for a target
    // not visited).
    let goal_miss_m = match &mission {
        Some(m) => m.worst_miss_m,
        None => ((p[0] - end[0]).powi(2) + (p[1] - end[1]).powi(2)).sqrt(),
    };
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
        truth_force_fallbacks: w.force_fallbacks,
        truth_inertia_limits: w.inertia_limits,
        truth_twist_caps: w.twist_caps,
        truth_scrub_pct: 100.0 * w.scrub_m / w.driven_m.max(1e-9),
        truth_scrub_net_pct: 100.0 * w.scrub_net_m / w.driven_m.max(1e-9),
        device_health: state.health,
        energy_used_j: w.energy.energy_j(),
        mean_power_w: w.energy.mean_power_w(),
        fsw_energy_used_j: state.power.map(|p| p.energy_used_j),
        stereo_frames: state.stereo_frames,
        nav: *fsw.nav().counters(),
        nav_mode: fsw.nav().mode(),
        fault_response: fsw.nav().fault_response(),
        last_ekf_error: fsw.nav().last_ekf_error().map(|e| format!("{e:?}")),
        driver: match source {
            CommandSource::Flight => "flight".to_string(),
            CommandSource::Reference(_) => "reference".to_string(),
        },
        slip_compensation: !options.no_slip_comp,
        vo_mean_features: (vo_seen > 0).then(|| vo_features / f64::from(vo_seen)),
        vo_mean_inliers: (vo_seen > 0).then(|| vo_inliers / f64::from(vo_seen)),
        vo_boresight: fsw.nav().vo_boresight(),
        radius_scales: {
            let (k, n) = fsw.nav().kin3d_radius_scale();
            (fsw.nav().radius_scale(), k, n)
        },
        vo_last_error: fsw.nav().last_vo_error().map(|e| format!("{e:?}")),
        vo_checks,
        rocks: w
            .terrain
            .rocks()
            .iter()
            .map(|r| [r.x_m, r.y_m, r.radius_m])
            .collect(),
        collisions: hazard_monitor.collisions.clone(),
        hazards: hazard_monitor.hazards().len(),
        hazard_height_m: hazard_monitor.hazard_height_m,
        hazard_min_distance_m: hazard_monitor
            .min_distance_m
            .is_finite()
            .then_some(hazard_monitor.min_distance_m),
        mission,
        localization: uplinked.map(|(map, inserted)| LocalizationRun {
            counters: fsw.nav().localization_counters(),
            map_points: inserted,
            map_features: map.features_mapped,
            checks: loc_checks,
            last_error: fsw
                .nav()
                .last_localization_error()
                .map(|e| format!("{e:?}")),
        }),
        planner: (scenario.navigation == crate::scenario::NavigationKind::Roverbug).then(|| {
            let (a, b) = (scenario.waypoints[0], end);
            PlannerRun {
                verdict: fsw.nav().planner_verdict(),
                hazard: fsw.nav().hazard_counters(),
                planner: fsw.nav().planner_counters(),
                straight_line_m: (b[0] - a[0]).hypot(b[1] - a[1]),
                last_status: fsw
                    .nav()
                    .planner_output()
                    .map(|o| format!("{:?}", o.status)),
            }
        }),
        wall_time_s: start.elapsed().as_secs_f64(),
    })
}
