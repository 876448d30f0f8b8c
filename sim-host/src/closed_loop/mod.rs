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
use std::collections::VecDeque;
use std::rc::Rc;

mod flight_config;
pub mod isolated;
mod result;

pub use flight_config::{flight_config, DriveOptions, Mission};
use result::{
    group_timing, loc_check, localization_run, mission_run, planner_run, quat_xyzw, record,
    vo_check,
};
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
    /// the simulator makes from its own rocks as a MARDI descent image from 50 m shows them
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

/// The global map the ground uplinks: the rocks a MARDI frame from 50 m shows
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
    let devices = world_devices(&world, renderer, scenario, seed, options.counter);
    let mut fsw = start_flight(scenario, &options, hooks.wrap(devices))?;
    let uplinked = if options.localization {
        Some(uplink_localization(
            &mut fsw,
            &world,
            scenario,
            seed,
            options.map_offset_m,
        )?)
    } else {
        None
    };
    if let Some(m) = &scenario.mission {
        uplink_mission(&mut fsw, m, scenario.duration_s)?;
    }
    let mut source = command_source(scenario, &options);
    let max_steps = (scenario.duration_s * 1e6 / FRAME_US as f64).ceil() as u64;
    let mut log = RunLog::new(&world, scenario);
    let mut stop_countdown: Option<u32> = None;
    let mut steps = 0;
    while steps < max_steps {
        step_world(&world, &mut source, &mut stop_countdown, &mut log.history);
        fsw.tick();
        hooks.after_tick(&fsw);
        log.observe_joints(&world);
        log.observe_gate(fsw.nav(), &world);
        log.observe(fsw.nav(), &world, scenario);
        if matches!(source, CommandSource::Flight)
            && matches!(
                fsw.nav().mode(),
                NavMode::Arrived | NavMode::Safed | NavMode::Stopped
            )
            && stop_countdown.is_none()
        {
            stop_countdown = Some(200);
        }
        log.record(&world, scenario, &fsw);
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
    let run = RunEnd {
        scenario,
        seed,
        world: &w,
        source: &source,
        slip_compensation: !options.no_slip_comp,
        start,
    };
    Ok(run.result(&fsw, log, uplinked))
}

/// The simulated devices of the world, for the flight software.
fn world_devices(
    world: &SharedWorld,
    renderer: Box<dyn StereoRenderer>,
    scenario: &Scenario,
    seed: u64,
    counter: CounterMode,
) -> Devices<WorldPlatform> {
    Devices::<WorldPlatform> {
        clock: WorldClock::new(world.clone(), counter),
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
    }
}

/// The flight software on `devices`, configured by [`flight_config`] (and the experiment
/// hook), with its localization memory when the run asks for localization, VO started.
fn start_flight<P: Platform>(
    scenario: &Scenario,
    options: &RunOptions,
    devices: Devices<P>,
) -> anyhow::Result<Fsw<P>> {
    let mut config = flight_config(
        scenario,
        DriveOptions {
            slip_compensation: !options.no_slip_comp,
            vo_enabled: !options.no_vo,
        },
    );
    config.nav.goal.localization.enabled = options.localization;
    if let Some(configure) = options.configure {
        configure(&mut config);
    }
    let mut fsw = Fsw::new(devices, &config, &scenario.waypoints)
        .map_err(|e| anyhow::anyhow!("flight software refused its configuration: {e:?}"))?;
    if options.localization {
        // The flight software keeps a `&'static mut` to its localization storage (external
        // RAM on the rover CPU): one leaked 82 KB block per run that asks for localization.
        fsw.provide_localization_memory(Box::leak(Box::new(fsw::flight::nav::LocNav::EMPTY)));
    }
    fsw.start_vo();
    Ok(fsw)
}

/// Uplink the global map of terrain-map localization ([`uplink_map`], every point moved by
/// the map-tie fault `map_offset_m`); returns the map and the points the flight software
/// inserted.
fn uplink_localization<P: Platform>(
    fsw: &mut Fsw<P>,
    world: &SharedWorld,
    scenario: &Scenario,
    seed: u64,
    map_offset_m: [f64; 2],
) -> anyhow::Result<(crate::descent_map::DescentMap, usize)> {
    let mut map = {
        let w = world.borrow();
        uplink_map(&w.terrain, &scenario.waypoints, seed)
    };
    for p in &mut map.1.points {
        p[0] += map_offset_m[0];
        p[1] += map_offset_m[1];
    }
    let inserted = fsw
        .uplink_global_map(map.0, &map.1.points)
        .ok_or_else(|| anyhow::anyhow!("the flight software refused the global map"))?;
    Ok((map.1, inserted))
}

/// Uplink the day's targets of `mission` with its budget (the run's duration when the mission
/// has no end time).
fn uplink_mission<P: Platform>(
    fsw: &mut Fsw<P>,
    m: &crate::scenario::MissionSpec,
    duration_s: f64,
) -> anyhow::Result<()> {
    let budget = fsw::flight::nav::MissionBudget {
        energy_j: m.energy_budget_j,
        end_s: m.end_s.unwrap_or(duration_s),
    };
    // The flight software's own a-priori resource model (not the simulator's energy
    // model: the flight software learns the difference from the power telemetry).
    fsw.uplink_targets(
        &m.targets(),
        fsw::sequencer::ResourceModel::rocky8(),
        budget,
    )
    .map_err(|e| anyhow::anyhow!("the flight software refused the targets: {e:?}"))
}

/// Who commands the motors: the flight software, or the reference driver (open loop without
/// slip compensation).
fn command_source(scenario: &Scenario, options: &RunOptions) -> CommandSource {
    if options.reference_driver {
        let mode = if options.no_slip_comp {
            DriverMode::OpenLoop
        } else {
            scenario.driver
        };
        CommandSource::Reference(ReferenceDriver::new(scenario, mode))
    } else {
        CommandSource::Flight
    }
}

/// One step of the world under the command of `source` (the reference driver starts the stop
/// countdown when it is done), and the truth pose into `history`.
fn step_world(
    world: &SharedWorld,
    source: &mut CommandSource,
    stop_countdown: &mut Option<u32>,
    history: &mut VecDeque<(u64, BodyPose)>,
) {
    let mut w = world.borrow_mut();
    let command = match source {
        CommandSource::Reference(driver) => {
            let c = driver.command(&w);
            if driver.done() && stop_countdown.is_none() {
                *stop_countdown = Some(200);
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

/// What a run collects while it goes.
struct RunLog {
    /// Truth poses of the last 10 s, to check VO relative poses and localization fixes
    /// against.
    history: VecDeque<(u64, BodyPose)>,
    /// The 20 Hz records.
    records: Vec<Record>,
    /// VO updates seen, and the sums of their features and inliers.
    vo_seen: u32,
    vo_features: f64,
    vo_inliers: f64,
    /// The VO relative poses checked against the truth.
    vo_checks: Vec<VoCheck>,
    /// The mission phase of the last frame, and the dwells' starts against the truth.
    mission_phase: fsw::flight::nav::MissionPhase,
    mission_visits: Vec<TargetVisit>,
    /// The last localization search seen, and the fixes checked against the truth.
    loc_seen: u32,
    loc_checks: Vec<LocCheck>,
    /// The truth-side hazard check.
    hazard_monitor: crate::hazards::HazardMonitor,
    /// H04 eq. 15 odometry on the encoder readings, and the time of the last reading it saw.
    eq15: isolated::Eq15Odometry,
    eq15_t_us: Option<u64>,
    /// The VO pipeline's relative poses chained raw.
    vo_raw: isolated::VoRawChain,
    /// The slip gate's intervals against the truth, the gate decisions seen and where the
    /// current interval started.
    slip_intervals: Vec<isolated::SlipInterval>,
    kin_tested_seen: u32,
    slip_mark: Option<isolated::SlipMark>,
}

impl RunLog {
    fn new(world: &SharedWorld, scenario: &Scenario) -> Self {
        let hazard_monitor = {
            let w = world.borrow();
            crate::hazards::HazardMonitor::new(&w.terrain, scenario.hazard_height_m)
        };
        Self {
            history: VecDeque::new(),
            records: Vec::new(),
            vo_seen: 0,
            vo_features: 0.0,
            vo_inliers: 0.0,
            vo_checks: Vec::new(),
            mission_phase: fsw::flight::nav::MissionPhase::None,
            mission_visits: Vec::new(),
            loc_seen: 0,
            loc_checks: Vec::new(),
            hazard_monitor,
            eq15: isolated::Eq15Odometry::new(),
            eq15_t_us: None,
            vo_raw: isolated::VoRawChain::default(),
            slip_intervals: Vec::new(),
            kin_tested_seen: 0,
            slip_mark: None,
        }
    }

    /// After a frame: a new gate decision closes a slip interval against the truth.
    fn observe_gate(&mut self, nav: &fsw::flight::nav::Navigator, world: &SharedWorld) {
        let Some(eq15) = self.eq15.pose() else {
            return;
        };
        let w = world.borrow();
        let mark = isolated::SlipMark::new(isolated::Pose::of_body(&w.truth.pose), eq15);
        let tested = nav.counters().kin_tested;
        if tested == self.kin_tested_seen {
            if self.slip_mark.is_none() {
                self.slip_mark = Some(mark);
            }
            return;
        }
        self.kin_tested_seen = tested;
        if let Some(start) = self.slip_mark {
            let s = nav.slip();
            self.slip_intervals.push(start.interval(
                &mark,
                w.truth.t_us as f64 * 1e-6,
                [s.x_m, s.y_m, s.phi_rad],
                nav.gate().accepted,
            ));
        }
        self.slip_mark = Some(mark);
    }

    /// After a frame: a new encoder reading into the eq. 15 odometry.
    fn observe_joints(&mut self, world: &SharedWorld) {
        let w = world.borrow();
        if self.eq15_t_us != Some(w.joints.t_us) {
            self.eq15_t_us = Some(w.joints.t_us);
            self.eq15.update(&w.joints, &w.truth.pose);
        }
    }

    /// After a frame: a new VO update, a new mission phase (the truth at a dwell's start), a
    /// new localization fix.
    fn observe(
        &mut self,
        nav: &fsw::flight::nav::Navigator,
        world: &SharedWorld,
        scenario: &Scenario,
    ) {
        if nav.counters().vo_updates > self.vo_seen {
            self.vo_seen = nav.counters().vo_updates;
            if let Some(out) = nav.vo().output() {
                self.vo_features += f64::from(out.quality.features);
                self.vo_inliers += f64::from(out.quality.inliers);
                if let Some(mut check) =
                    out.pose.as_ref().and_then(|rp| vo_check(rp, &self.history))
                {
                    check.vo_pose = nav
                        .vo_pose()
                        .map(|v| ([v.p_n.x, v.p_n.y, v.p_n.z], quat_xyzw(&v.q_nr)));
                    if let Some(rp) = out.pose.as_ref() {
                        let history = &self.history;
                        let truth_at = |t: u64| {
                            history
                                .iter()
                                .find(|(ht, _)| *ht == t)
                                .map(|(_, p)| isolated::Pose::of_body(p))
                        };
                        check.raw_pose = self
                            .vo_raw
                            .push(rp.t0_us, rp.t1_us, &rp.trans_0_1_m, &rp.rot_0_1, truth_at)
                            .map(|p| p.arrays());
                    }
                    self.vo_checks.push(check);
                }
            }
        }
        if nav.goal().mission_phase() != self.mission_phase {
            self.mission_phase = nav.goal().mission_phase();
            if let (fsw::flight::nav::MissionPhase::Dwelling { target }, Some(m)) =
                (self.mission_phase, &scenario.mission)
            {
                // The truth at the start of the dwell: is the rover really at the target?
                let w = world.borrow();
                let p = w.truth.pose.pos_m;
                let t = m.targets.get(usize::from(target));
                self.mission_visits.push(TargetVisit {
                    target: usize::from(target),
                    t_s: w.truth.t_us as f64 * 1e-6,
                    miss_m: t.map_or(f64::NAN, |t| (p[0] - t.x_m).hypot(p[1] - t.y_m)),
                    distance_m: w.truth.distance_m,
                });
            }
        }
        if let Some(fix) = nav.goal().last_localization() {
            if fix.search != self.loc_seen {
                self.loc_seen = fix.search;
                if let Some(check) = loc_check(&fix, &self.history) {
                    self.loc_checks.push(check);
                }
            }
        }
    }

    /// Every 10th world step (20 Hz): the record of truth and estimates, and the hazard check.
    fn record<P: Platform>(&mut self, world: &SharedWorld, scenario: &Scenario, fsw: &Fsw<P>) {
        let w = world.borrow();
        if w.steps % 10 == 0 {
            let mut r = record(&w, &scenario.waypoints, fsw);
            r.kin_eq15 = self.eq15.pose().map(|p| p.arrays());
            self.records.push(r);
            self.hazard_monitor
                .check(w.truth.t_us as f64 * 1e-6, &w.truth.pose, &w.geometry);
        }
    }
}

/// A run at its end: what it ran and the world's final state.
struct RunEnd<'a> {
    scenario: &'a Scenario,
    seed: u64,
    world: &'a World,
    source: &'a CommandSource,
    slip_compensation: bool,
    /// Wall-clock start of the run.
    start: std::time::Instant,
}

impl RunEnd<'_> {
    /// The result of the run from the world and the flight software at its end and what the
    /// run collected.
    fn result<P: Platform>(
        &self,
        fsw: &Fsw<P>,
        log: RunLog,
        uplinked: Option<(crate::descent_map::DescentMap, usize)>,
    ) -> RunResult {
        let (scenario, seed, w, source) = (self.scenario, self.seed, self.world, self.source);
        let end = scenario.waypoints[scenario.waypoints.len() - 1];
        let p = w.truth.pose.pos_m;
        let mission = scenario
            .mission
            .as_ref()
            .map(|m| mission_run(m, fsw.nav(), &log.mission_visits, p));
        // With targets the goal is every target: reached when each was visited within the
        // tolerance; the miss is the largest truth miss (at the dwell, or at the end for a target
        // not visited).
        let goal_miss_m = match &mission {
            Some(m) => m.worst_miss_m,
            None => ((p[0] - end[0]).powi(2) + (p[1] - end[1]).powi(2)).sqrt(),
        };
        let state = fsw.state();
        let nav = fsw.nav();
        let monitor = &log.hazard_monitor;
        let vo_seen = log.vo_seen;
        RunResult {
            scenario: scenario.name.clone(),
            seed,
            waypoints: scenario.waypoints.clone(),
            records: log.records,
            sim_time_s: w.truth.t_us as f64 * 1e-6,
            distance_m: w.truth.distance_m,
            goal_reached: goal_miss_m <= scenario.goal_tolerance_m,
            goal_miss_m,
            timing: group_timing(fsw.executive()),
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
            nav: nav.counters(),
            nav_mode: nav.mode(),
            fault_response: nav.fault_response(),
            last_ekf_error: nav.filter().last_error().map(|e| format!("{e:?}")),
            driver: match source {
                CommandSource::Flight => "flight".to_string(),
                CommandSource::Reference(_) => "reference".to_string(),
            },
            slip_compensation: self.slip_compensation,
            vo_mean_features: (vo_seen > 0).then(|| log.vo_features / f64::from(vo_seen)),
            vo_mean_inliers: (vo_seen > 0).then(|| log.vo_inliers / f64::from(vo_seen)),
            vo_boresight: nav.calibration().boresight(),
            radius_scales: {
                let (k, n) = nav.calibration().dr_scale();
                (nav.kin().radius_scale(), k, n)
            },
            vo_last_error: nav.vo().last_error().map(|e| format!("{e:?}")),
            vo_checks: log.vo_checks,
            vo_raw_gaps: log.vo_raw.gaps,
            eq15_refused: log.eq15.refused,
            slip_intervals: log.slip_intervals,
            rocks: w
                .terrain
                .rocks()
                .iter()
                .map(|r| [r.x_m, r.y_m, r.radius_m])
                .collect(),
            collisions: monitor.collisions.clone(),
            hazards: monitor.hazards().len(),
            hazard_height_m: monitor.hazard_height_m,
            hazard_min_distance_m: monitor
                .min_distance_m
                .is_finite()
                .then_some(monitor.min_distance_m),
            mission,
            localization: uplinked
                .map(|(map, inserted)| localization_run(nav, &map, inserted, log.loc_checks)),
            planner: (scenario.navigation == crate::scenario::NavigationKind::Roverbug)
                .then(|| planner_run(nav, scenario.waypoints[0], end)),
            wall_time_s: self.start.elapsed().as_secs_f64(),
        }
    }
}
