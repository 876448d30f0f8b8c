//! What a closed-loop run produces ([`RunResult`]), and how it is read from the world's truth
//! and the flight software while the run goes: the 20 Hz records of truth and estimates, the VO
//! relative poses and localization fixes checked against the truth, and the outcomes of the
//! mission sequencer and the RoverBug planner.

use crate::driver::closest_arc;
use crate::vehicle::placement::BodyPose;
use crate::world::World;
use fsw::flight::nav::{NavCounters, NavMode};
use fsw::flight::{Fsw, Platform};

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
    /// H04 eq. 15 odometry alone on the encoder readings (host side,
    /// [`super::isolated::Eq15Odometry`]): position and attitude `[x, y, z, w]`.
    pub kin_eq15: Option<([f64; 3], [f64; 4])>,
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
    /// EKF horizontal position covariance `[nn, ne, ee]`, m^2.
    pub ekf_pos_cov_ne: [f64; 3],
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
    /// The raw VO chain after this relative pose ([`super::isolated::VoRawChain`]): the
    /// pipeline's poses before the boresight correction and without the EKF's anchor.
    pub raw_pose: Option<([f64; 3], [f64; 4])>,
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
    /// Relative poses the raw VO chain bridged with the true motion (a failed update before
    /// them).
    pub vo_raw_gaps: u32,
    /// Encoder readings the eq. 15 odometry refused.
    pub eq15_refused: u32,
    /// The slip gate's intervals against the truth.
    pub slip_intervals: Vec<super::isolated::SlipInterval>,
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

pub(super) fn loc_check(
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

/// What the sequencer did with the day's targets (V99 sec. 3).
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

pub(super) fn mission_run(
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

pub(super) fn vo_check(
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
        raw_pose: None,
        truth_pose: (p1.pos_m, [q1.i, q1.j, q1.k, q1.w]),
        t_s: rp.t1_us as f64 * 1e-6,
        step_m: trans_true.norm(),
        trans_err_m: [e.x, e.y, e.z],
        rot_err_rad: [rot_err.x, rot_err.y, rot_err.z],
        trans_sigma_m: [sigma(3), sigma(4), sigma(5)],
        rot_sigma_rad: [sigma(0), sigma(1), sigma(2)],
    })
}

pub(super) fn quat_xyzw(q: &fsw::types::Quat) -> [f64; 4] {
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
        ekf_pos_cov_ne: [p[(i, i)], p[(i, i + 1)], p[(i + 1, i + 1)]],
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

pub(super) fn record<P: Platform>(w: &World, path: &[[f64; 2]], fsw: &Fsw<P>) -> Record {
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
        kin_eq15: None,
    }
}

/// Per-rate-group timing of the flight executive at the end of a run.
pub(super) fn group_timing<const G: usize, const T: usize>(
    exec: &fsw::exec::Executive<G, T>,
) -> Vec<GroupTiming> {
    exec.groups()
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
        .collect()
}

/// What terrain-map localization did, from the navigator at the end of a run.
pub(super) fn localization_run(
    nav: &fsw::flight::nav::Navigator,
    map: &crate::descent_map::DescentMap,
    inserted: usize,
    checks: Vec<LocCheck>,
) -> LocalizationRun {
    LocalizationRun {
        counters: nav.goal().localization_counters(),
        map_points: inserted,
        map_features: map.features_mapped,
        checks,
        last_error: nav
            .goal()
            .last_localization_error()
            .map(|e| format!("{e:?}")),
    }
}

/// What the hazard maps and the planner did on a drive from `a` to the goal `b`, from the
/// navigator at the end of a run.
pub(super) fn planner_run(
    nav: &fsw::flight::nav::Navigator,
    a: [f64; 2],
    b: [f64; 2],
) -> PlannerRun {
    PlannerRun {
        verdict: nav.goal().planner_verdict(),
        hazard: nav.goal().hazard_counters(),
        planner: nav.goal().planner_counters(),
        straight_line_m: (b[0] - a[0]).hypot(b[1] - a[1]),
        last_status: nav
            .goal()
            .planner_output()
            .map(|o| format!("{:?}", o.status)),
    }
}
