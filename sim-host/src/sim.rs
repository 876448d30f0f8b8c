//! One closed-loop run of a scenario: the world, the flight software on the simulated devices,
//! and the command source (the flight software; the simulator's reference driver on request).
//!
//! The flight software is configured as the ground would configure it: the start pose (from
//! the world's truth at the start, as a localisation before the drive would give it), the
//! path, the IMU noise densities from the IMU data sheet (the scenario's sensor parameters) and
//! the sun direction from the ephemeris (the scenario's sun). It sees the world only through
//! the HAL devices.

use crate::camera::{FlatGreyRenderer, StereoRenderer};
use crate::devices::CountingTelemetry;
use crate::driver::{closest_arc, CommandSource, ReferenceDriver};
use crate::hal_devices::{
    CounterMode, SharedWorld, WorldClock, WorldImu, WorldMobility, WorldPower, WorldStereo,
    WorldSun,
};
use crate::scenario::{DriverMode, Scenario};
use crate::vehicle::placement::BodyPose;
use crate::world::{World, FRAME_US};
use fsw::flight::nav::{NavCounters, NavMode};
use fsw::flight::{Devices, Fsw, FswConfig, Platform};
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
    /// Averaged wheel odometry distance, m (diagnostic baseline of V99 sec. 6: the mean drive
    /// encoder increment times the nominal wheel radius, times the cosine of the true pitch).
    pub wheel_average_m: f64,
    /// Flight estimates at this time (`None` before the flight software is aligned).
    pub est: Option<Estimates>,
}

/// The flight software's estimates at one record time, `N` (= the simulator's `W`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimates {
    /// EKF position, m.
    pub ekf_pos_m: [f64; 3],
    /// EKF attitude `[x, y, z, w]`.
    pub ekf_quat_xyzw: [f64; 4],
    /// EKF 1-sigma position, m, per axis.
    pub ekf_pos_sigma_m: [f64; 3],
    /// EKF 1-sigma heading, rad.
    pub ekf_heading_sigma_rad: f64,
    /// VO-only pose (position, attitude), once VO has delivered.
    pub vo: Option<([f64; 3], [f64; 4])>,
    /// 3D kinematic dead reckoning (position, attitude).
    pub kin3d: ([f64; 3], [f64; 4]),
    /// Planar wheel odometry `[north, east, yaw]`.
    pub kin2d: [f64; 3],
    /// Dead reckoning: wheel odometry with gyro attitude (position, attitude).
    pub dr: ([f64; 3], [f64; 4]),
    /// Slip vector of the last RG2 cycle `[x m, y m, yaw rad]` (EKF minus kinematics).
    pub slip: [f64; 3],
    /// The gate accepted the last kinematic interval.
    pub gate_accepted: bool,
    /// Kinematic intervals tested by the gate so far ([`NavCounters::kin_tested`]): a record
    /// whose count is larger than the previous record's carries a new gate decision.
    pub kin_tested: u32,
    /// Mahalanobis squared distance (NIS) of the last kinematic interval, H04 eq. 46
    /// (flight telemetry [`fsw::flight::nav::GateStatus::d2`]).
    pub gate_d2: f64,
    /// Degrees of freedom of that test; its threshold is
    /// [`fsw::estimation::gate::chi2_95`] of it (0 before the first test).
    pub gate_dof: u8,
}

/// One flight VO relative pose checked against the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoCheck {
    /// Capture time of the second frame, s.
    pub t_s: f64,
    /// True translation between the captures, m.
    pub step_m: f64,
    /// Translation error, m (rover frame at the first capture).
    pub trans_err_m: [f64; 3],
    /// Rotation error (rotation vector of `rot_meas * rot_true'`), rad.
    pub rot_err_rad: [f64; 3],
    /// Reported 1-sigma of the translation, m.
    pub trans_sigma_m: [f64; 3],
    /// Reported 1-sigma of the rotation, rad.
    pub rot_sigma_rad: [f64; 3],
    /// The VO-only pose after this update (position m, quaternion `[x, y, z, w]`), `W`.
    pub vo_pose: Option<([f64; 3], [f64; 4])>,
    /// The true pose at the capture time `t_s`.
    pub truth_pose: ([f64; 3], [f64; 4]),
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
    /// Truth steps whose quasi-static twist was implausible and fell back to the kinematic
    /// solve ([`crate::world::World::force_fallbacks`]; 0 on every shipped scenario).
    pub truth_force_fallbacks: u64,
    /// Truth steps whose twist changed faster than gravity and friction can accelerate the body
    /// and was limited ([`crate::world::World::inertia_limits`]).
    pub truth_inertia_limits: u64,
    /// Truth steps whose twist exceeded the quasi-static bounds and was scaled down
    /// ([`crate::world::World::twist_caps`]).
    pub truth_twist_caps: u64,
    /// Scrub of the wheels on the ground over the run, % of the ground travel they drove
    /// ([`crate::world::World::scrub_m`]).
    pub truth_scrub_pct: f64,
    /// The same with sign ([`crate::world::World::scrub_net_m`]), %.
    pub truth_scrub_net_pct: f64,
    /// Per-device health counters of the flight software: IMU, joints, camera, sun, power.
    pub device_health: [fsw::flight::DeviceHealth; fsw::flight::DEVICE_COUNT],
    /// Battery energy used over the run by the truth energy model, J ([`crate::energy`]).
    pub energy_used_j: f64,
    /// Mean electrical power of the truth energy model over the run, W.
    pub mean_power_w: f64,
    /// The energy used of the last power reading the flight software accepted, J (`None`:
    /// it accepted none).
    pub fsw_energy_used_j: Option<f64>,
    /// Stereo frames the flight software completed.
    pub stereo_frames: u32,
    /// Navigation counters of the flight software at the end.
    pub nav: NavCounters,
    /// Final navigation mode.
    pub nav_mode: NavMode,
    /// Why fault protection stopped the drive, if it did.
    pub fault_response: fsw::flight::nav::protection::FaultResponse,
    /// The flight EKF's last error (`Debug` text), if it returned any.
    pub last_ekf_error: Option<String>,
    /// Who drove: `"flight"` or `"reference"`.
    pub driver: String,
    /// Slip compensation on.
    pub slip_compensation: bool,
    /// Mean features and inliers of the VO updates that delivered a pose.
    pub vo_mean_features: Option<f64>,
    /// Mean inliers of the VO updates that delivered a pose.
    pub vo_mean_inliers: Option<f64>,
    /// VO yaw boresight learnt by the flight software at the end (rad, positive: VO's
    /// translation turned towards `+y` of `R`) and the samples it learnt from.
    pub vo_boresight: (f64, u32),
    /// Effective wheel-radius scales learnt by the flight software at the end: the EKF's
    /// kinematic measurement's (eq. 15) and the 3D dead reckoning's with its windows
    /// (`fsw::flight::nav::CaptureScale`).
    pub radius_scales: (f64, f64, u32),
    /// The error of the flight software's last failed VO update, if any.
    pub vo_last_error: Option<String>,
    /// Every VO relative pose checked against the truth.
    pub vo_checks: Vec<VoCheck>,
    /// Rocks of the terrain `[north, east, radius]` for the top view.
    pub rocks: Vec<[f64; 3]>,
    /// Truth-side hazard contacts ([`crate::hazards`]), in time order.
    pub collisions: Vec<crate::hazards::Collision>,
    /// Hazards in the terrain (features at least the scenario's hazard height).
    pub hazards: usize,
    /// Hazard height of the scenario, m.
    pub hazard_height_m: f64,
    /// Closest approach of the rover footprint to a hazard footprint, m (`None` without
    /// hazards).
    pub hazard_min_distance_m: Option<f64>,
    /// The goal-directed drive (hazard maps and RoverBug), when the scenario asked for it.
    pub planner: Option<PlannerRun>,
    /// Terrain-map localization, when the run asked for it.
    pub localization: Option<LocalizationRun>,
    /// The day's targets and the sequencer, when the scenario has them.
    pub mission: Option<MissionRun>,
    /// Wall-clock seconds of the run.
    pub wall_time_s: f64,
}

/// What terrain-map localization did in a run.
#[derive(Debug, Clone, PartialEq)]
pub struct LocalizationRun {
    /// The flight software's counters.
    pub counters: fsw::flight::nav::LocCounters,
    /// Points of the uplinked global map the flight software inserted.
    pub map_points: usize,
    /// Rocks and blocks the descent image mapped.
    pub map_features: usize,
    /// Every fix offered to the EKF, checked against the truth.
    pub checks: Vec<LocCheck>,
    /// Why the last search failed, if one did.
    pub last_error: Option<String>,
}

/// One localization fix against the truth at its capture time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocCheck {
    /// Capture time, s.
    pub t_s: f64,
    /// Fix minus truth: north, east (m), heading (rad, wrapped).
    pub error: [f64; 3],
    /// Normalised estimation error squared of the fix (3 dof: chi-square mean 3).
    pub nees: f64,
    /// The EKF's estimate before the fix minus truth: north, east (m).
    pub prior_error_m: [f64; 2],
    /// The EKF's gate distance of the fix.
    pub d2: f64,
    /// Fused.
    pub applied: bool,
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

fn loc_check(
    fix: &fsw::flight::nav::LocFixReport,
    history: &std::collections::VecDeque<(u64, BodyPose)>,
) -> Option<LocCheck> {
    let truth = history
        .iter()
        .find(|(t, _)| *t == fix.t_us)
        .map(|(_, p)| *p)?;
    let r = truth.rot_w_from_r();
    let yaw = r[(1, 0)].atan2(r[(0, 0)]);
    let wrap = |a: f64| {
        (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
    };
    let e = nalgebra::Vector3::new(
        fix.pose[0] - truth.pos_m[0],
        fix.pose[1] - truth.pos_m[1],
        wrap(fix.pose[2] - yaw),
    );
    let c = nalgebra::Matrix3::from_fn(|i, j| fix.covariance[i][j]);
    let nees = c.try_inverse().map(|ci| (e.transpose() * ci * e)[(0, 0)])?;
    Some(LocCheck {
        t_s: fix.t_us as f64 * 1e-6,
        error: [e.x, e.y, e.z],
        nees,
        prior_error_m: [fix.prior[0] - truth.pos_m[0], fix.prior[1] - truth.pos_m[1]],
        d2: fix.d2,
        applied: fix.applied,
    })
}

/// What the sequencer did with the day's targets (issue 17, V99 sec. 3).
#[derive(Debug, Clone, PartialEq)]
pub struct MissionRun {
    /// The flight software's counters.
    pub counters: fsw::flight::nav::MissionCounters,
    /// Outcome of each target, in the scenario's order.
    pub outcomes: Vec<fsw::flight::nav::TargetOutcome>,
    /// Target indices in the order visited.
    pub order: Vec<usize>,
    /// Each dwell's start against the truth.
    pub visits: Vec<TargetVisit>,
    /// Largest truth miss: at the dwell for a visited target, at the end of the run for one
    /// not visited, m.
    pub worst_miss_m: f64,
    /// The ground's energy budget, J.
    pub energy_budget_j: f64,
    /// Final mission phase.
    pub phase: fsw::flight::nav::MissionPhase,
}

/// The truth at the start of a dwell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetVisit {
    /// Target index.
    pub target: usize,
    /// Simulated time, s.
    pub t_s: f64,
    /// Truth distance to the target, m.
    pub miss_m: f64,
    /// True distance travelled so far, m.
    pub distance_m: f64,
}

fn mission_run(
    spec: &crate::scenario::MissionSpec,
    nav: &fsw::flight::nav::Navigator,
    visits: &[TargetVisit],
    end: [f64; 3],
) -> MissionRun {
    let outcomes: Vec<_> = (0..spec.targets.len())
        .map(|i| {
            nav.goal()
                .target_outcome(i)
                .unwrap_or(fsw::flight::nav::TargetOutcome::Pending)
        })
        .collect();
    let worst_miss_m = spec
        .targets
        .iter()
        .enumerate()
        .map(|(i, t)| match visits.iter().find(|v| v.target == i) {
            Some(v) => v.miss_m,
            None => (end[0] - t.x_m).hypot(end[1] - t.y_m),
        })
        .fold(0.0, f64::max);
    MissionRun {
        counters: nav.goal().mission_counters(),
        outcomes,
        order: nav
            .goal()
            .visit_order()
            .iter()
            .map(|&i| usize::from(i))
            .collect(),
        visits: visits.to_vec(),
        worst_miss_m,
        energy_budget_j: spec.energy_budget_j,
        phase: nav.goal().mission_phase(),
    }
}

/// What the flight software's hazard maps and RoverBug planner did in a run.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannerRun {
    /// The planner's verdict at the end.
    pub verdict: fsw::flight::nav::hazard_nav::PlannerVerdict,
    /// Hazard-navigation counters (maps, paths, gazes, holds).
    pub hazard: fsw::flight::nav::hazard_nav::HazardCounters,
    /// Planner counters (replans, boundary following).
    pub planner: Option<fsw::planning::PlannerCounters>,
    /// Straight-line distance from the start to the goal, m.
    pub straight_line_m: f64,
    /// The planner's last step's status with its reason (e.g. `Blocked(GazeLimit)`).
    pub last_status: Option<String>,
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
        telemetry: CountingTelemetry::with_refusal(crate::hal_devices::telemetry_faults(
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
    config.nav.goal.localization.enabled = options.localization;
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
            if let Some(out) = nav.vo().output() {
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
        if nav.goal().mission_phase() != mission_phase {
            mission_phase = nav.goal().mission_phase();
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
        if let Some(fix) = nav.goal().last_localization() {
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
        nav: fsw.nav().counters(),
        nav_mode: fsw.nav().mode(),
        fault_response: fsw.nav().fault_response(),
        last_ekf_error: fsw.nav().filter().last_error().map(|e| format!("{e:?}")),
        driver: match source {
            CommandSource::Flight => "flight".to_string(),
            CommandSource::Reference(_) => "reference".to_string(),
        },
        slip_compensation: !options.no_slip_comp,
        vo_mean_features: (vo_seen > 0).then(|| vo_features / f64::from(vo_seen)),
        vo_mean_inliers: (vo_seen > 0).then(|| vo_inliers / f64::from(vo_seen)),
        vo_boresight: fsw.nav().calibration().boresight(),
        radius_scales: {
            let (k, n) = fsw.nav().calibration().dr_scale();
            (fsw.nav().kin().radius_scale(), k, n)
        },
        vo_last_error: fsw.nav().vo().last_error().map(|e| format!("{e:?}")),
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
            counters: fsw.nav().goal().localization_counters(),
            map_points: inserted,
            map_features: map.features_mapped,
            checks: loc_checks,
            last_error: fsw
                .nav()
                .goal()
                .last_localization_error()
                .map(|e| format!("{e:?}")),
        }),
        planner: (scenario.navigation == crate::scenario::NavigationKind::Roverbug).then(|| {
            let (a, b) = (scenario.waypoints[0], end);
            PlannerRun {
                verdict: fsw.nav().goal().planner_verdict(),
                hazard: fsw.nav().goal().hazard_counters(),
                planner: fsw.nav().goal().planner_counters(),
                straight_line_m: (b[0] - a[0]).hypot(b[1] - a[1]),
                last_status: fsw
                    .nav()
                    .goal()
                    .planner_output()
                    .map(|o| format!("{:?}", o.status)),
            }
        }),
        wall_time_s: start.elapsed().as_secs_f64(),
    })
}

/// What the ground chooses for a drive besides the scenario: slip compensation and VO.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriveOptions {
    /// Slip compensation on (H05) or off (wheel and IMU odometry only).
    pub slip_compensation: bool,
    /// Visual odometry on; off: the EKF gets IMU, sun and kinematics only.
    pub vo_enabled: bool,
}

impl Default for DriveOptions {
    fn default() -> Self {
        Self {
            slip_compensation: true,
            vo_enabled: true,
        }
    }
}

/// The mission inputs of a drive as the ground plans it from the scenario, never from the
/// simulator's truth or seed: the start pose of the plan (first waypoint, heading towards the
/// second, height from the smooth terrain model plus the nominal height of the rover
/// reference point), the site and time for the sun ephemeris, the cruise speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mission {
    /// Planned start position, m, `N` (north, east, down).
    pub start_n_m: [f64; 3],
    /// Planned start heading, rad.
    pub start_yaw_rad: f64,
    /// Sun ephemeris of the site and time.
    pub sun: fsw::estimation::ephemeris::SunEphemeris,
    /// Cruise speed, m/s.
    pub cruise_speed_m_s: f64,
    /// Distance from the goal that counts as arriving, m (the arrival must be supported by the
    /// estimate to this tolerance, `ProtectionConfig::arrival_tolerance_m`).
    pub goal_tolerance_m: f64,
    /// Slip limit of the drive (fault protection), fraction.
    pub slip_limit: f64,
    /// Largest horizontal position sigma the ground accepts for the drive (fault protection), m.
    pub max_position_sigma_m: f64,
    /// "Go to the last waypoint, avoiding hazards" (RoverBug, V99 sec. 4) instead of "follow
    /// the waypoints".
    pub goal_directed: bool,
}

impl Mission {
    /// The plan of `scenario`.
    pub fn plan(scenario: &Scenario) -> Self {
        let [start, next] = [scenario.waypoints[0], scenario.waypoints[1]];
        // The ground's terrain model: the base shape without roughness, rocks or obstacles.
        let mut smooth = scenario.terrain.clone();
        smooth.roughness_m = 0.0;
        smooth.rocks = None;
        smooth.obstacles.clear();
        let ground = crate::surface::TerrainSurface::height_m(
            &crate::terrain::Terrain::new(smooth, 0, &scenario.waypoints),
            start[0],
            start[1],
        );
        // Nominal height of the reference point above the wheel contacts (flight geometry).
        let reference_height = fsw::kinematics::wheel_contact_points(
            &fsw::kinematics::ROCKY8,
            &fsw::kinematics::SuspensionState::default(),
        )
        .map(|c| c.iter().map(|p| p.z).sum::<f64>() / c.len() as f64)
        .unwrap_or(0.0);
        let site = &scenario.site;
        Self {
            start_n_m: [start[0], start[1], -(ground + reference_height)],
            start_yaw_rad: (next[1] - start[1]).atan2(next[0] - start[0]),
            sun: fsw::estimation::ephemeris::SunEphemeris::from_site(
                site.latitude_deg,
                site.solar_longitude_deg,
                site.local_solar_time_h,
            ),
            cruise_speed_m_s: scenario.speed_m_s,
            goal_tolerance_m: scenario.goal_tolerance_m,
            slip_limit: scenario.slip_limit,
            max_position_sigma_m: scenario.max_position_sigma_m,
            goal_directed: scenario.navigation == crate::scenario::NavigationKind::Roverbug,
        }
    }
}

/// The flight software's configuration for `scenario`: the nominal flight profile
/// ([`FswConfig::rocky8`]: datasheet-class IMU densities, nominal geometry and calibration,
/// calibrated odometry noise) with the mission inputs of [`Mission::plan`] and the drive
/// options. Nothing comes from the simulator's truth, parameters or seed
/// (`sim-host/tests/flight_profile.rs` checks it for every scenario and several seeds).
pub fn flight_config(scenario: &Scenario, options: DriveOptions) -> FswConfig {
    let mission = Mission::plan(scenario);
    let mut config = FswConfig::rocky8(mission.start_n_m, mission.start_yaw_rad);
    let nav = &mut config.nav;
    nav.filter.ekf.sun = Some(mission.sun);
    nav.drive.guidance.cruise_speed_m_s = mission
        .cruise_speed_m_s
        .min(nav.drive.guidance.max_wheel_speed_m_s);
    nav.drive.slip_compensation = options.slip_compensation;
    nav.vo.enabled = options.vo_enabled;
    nav.drive.protection.arrival_tolerance_m = mission.goal_tolerance_m;
    nav.drive.protection.slip_limit = mission.slip_limit;
    nav.drive.protection.max_position_sigma_m = mission.max_position_sigma_m;
    nav.goal.hazard_avoidance = mission.goal_directed;
    config
}

fn vo_check(
    rp: &fsw::types::RelativePose,
    history: &std::collections::VecDeque<(u64, BodyPose)>,
) -> Option<VoCheck> {
    let find = |t: u64| history.iter().find(|(ht, _)| *ht == t).map(|(_, p)| *p);
    let (p0, p1) = (find(rp.t0_us)?, find(rp.t1_us)?);
    let (r0, r1) = (p0.rot_w_from_r(), p1.rot_w_from_r());
    let d = nalgebra::Vector3::from(p1.pos_m) - nalgebra::Vector3::from(p0.pos_m);
    let trans_true = r0.inverse() * d;
    let rot_true = r0.inverse() * r1;
    let rot_meas = rp.rot_0_1.to_rotation_matrix();
    let rot_err = (rot_meas * rot_true.inverse()).scaled_axis();
    let e = rp.trans_0_1_m - trans_true;
    let sigma = |k: usize| rp.covariance[(k, k)].max(0.0).sqrt();
    let q1 = nalgebra::UnitQuaternion::from_rotation_matrix(&r1);
    Some(VoCheck {
        vo_pose: None,
        truth_pose: (p1.pos_m, [q1.i, q1.j, q1.k, q1.w]),
        t_s: rp.t1_us as f64 * 1e-6,
        step_m: trans_true.norm(),
        trans_err_m: [e.x, e.y, e.z],
        rot_err_rad: [rot_err.x, rot_err.y, rot_err.z],
        trans_sigma_m: [sigma(3), sigma(4), sigma(5)],
        rot_sigma_rad: [sigma(0), sigma(1), sigma(2)],
    })
}

fn quat_xyzw(q: &fsw::types::Quat) -> [f64; 4] {
    [q.i, q.j, q.k, q.w]
}

fn estimates<P: Platform>(fsw: &Fsw<P>) -> Option<Estimates> {
    let nav = fsw.nav();
    let ekf = nav.ekf()?;
    let x = ekf.state();
    let p = ekf.covariance();
    let i = fsw::estimation::state::I_P;
    let sigma = |k: usize| p[(i + k, i + k)].max(0.0).sqrt();
    let kin3d = nav.kin3d();
    let slip = nav.slip();
    Some(Estimates {
        ekf_pos_m: [x.p_n.x, x.p_n.y, x.p_n.z],
        ekf_quat_xyzw: quat_xyzw(&x.q_nr),
        ekf_pos_sigma_m: [sigma(0), sigma(1), sigma(2)],
        ekf_heading_sigma_rad: ekf.heading_sigma_rad(),
        vo: nav
            .vo_pose()
            .map(|v| ([v.p_n.x, v.p_n.y, v.p_n.z], quat_xyzw(&v.q_nr))),
        kin3d: (
            [kin3d.p_n.x, kin3d.p_n.y, kin3d.p_n.z],
            quat_xyzw(&kin3d.q_nr),
        ),
        kin2d: nav.kin2d(),
        dr: {
            let d = nav.dead_reckoning();
            ([d.p_n.x, d.p_n.y, d.p_n.z], quat_xyzw(&d.q_nr))
        },
        slip: [slip.x_m, slip.y_m, slip.phi_rad],
        gate_accepted: nav.gate().accepted,
        kin_tested: nav.counters().kin_tested,
        gate_d2: nav.gate().d2,
        gate_dof: nav.gate().dof,
    })
}

fn record<P: Platform>(w: &World, path: &[[f64; 2]], fsw: &Fsw<P>) -> Record {
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
        wheel_average_m: w.wheel_average_m,
        est: estimates(fsw),
    }
}
