//! `summary.json`: the figures of a run. Estimate errors are horizontal (north, east) position
//! errors at the last record where the estimate exists; `null` when it never existed (VO with
//! `--no-render`, for example). Attitude errors are the largest rotation angle between the
//! estimate and the truth over the run.

use super::tum::Trajectory;
use crate::closed_loop::RunResult;
use serde::Serialize;

/// Five flight estimates.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct PerEstimate {
    /// EKF.
    pub ekf: Option<f64>,
    /// Visual odometry.
    pub vo: Option<f64>,
    /// 3D kinematic odometry.
    pub kin3d: Option<f64>,
    /// Planar kinematic odometry.
    pub kin2d: Option<f64>,
    /// Dead reckoning (wheel odometry with gyro attitude, RB sec. 6).
    pub dr: Option<f64>,
}

/// Attitude errors of the estimates that carry attitude.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct AttitudeErrors {
    /// EKF.
    pub ekf: Option<f64>,
    /// Visual odometry.
    pub vo: Option<f64>,
}

/// Error of the distance travelled (path length of the estimate against the true horizontal
/// path length), % of the true distance (V99 sec. 6).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct DistanceErrors {
    /// Flight 3D kinematic odometry (with contact-angle estimation).
    pub kin3d: Option<f64>,
    /// Averaged wheel odometry, pitch-compensated (simulator-side baseline).
    pub wheel_average: f64,
}

/// Effective wheel-radius scales the flight software learnt (effective over nominal radius, at
/// the end of the run).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct RadiusScales {
    /// Applied to the EKF's kinematic measurement (eq. 15), learnt from the EKF's travel.
    pub ekf: f64,
    /// Applied to the 3D kinematic dead reckoning (`kin3d`), learnt from VO over clean capture
    /// intervals (`fsw::flight::nav::CaptureScale`, KIN-14).
    pub kin3d: f64,
    /// 1 m windows the `kin3d` scale was learnt from (0: nominal).
    pub kin3d_windows: u32,
}

/// Cross-track error of the true path, m.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CrossTrack {
    /// Root mean square.
    pub rms: f64,
    /// Largest.
    pub max: f64,
}

/// How far the true suspension moved (H04 Fig. 17's "rocker and bogies exercised to their
/// full extent"), rad, with the truth vehicle's mechanical stops for comparison.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct SuspensionSummary {
    /// Largest `|beta|` of the rocker differential over the run.
    pub rocker_max_abs_rad: f64,
    /// Largest `|rho|` of the right and the left bogie over the run.
    pub bogie_max_abs_rad: [f64; 2],
    /// Largest peak-to-peak travel of the rocker, of the right and of the left bogie.
    pub travel_rad: [f64; 3],
    /// The truth vehicle's stops `[rocker, bogie]` (`vehicle::placement::JointLimits`).
    pub stops_rad: [f64; 2],
}

/// Slip figures.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct SlipSummary {
    /// Fraction of kinematic intervals the flight slip gate rejected (`null`: none tested).
    pub gate_reject_fraction: Option<f64>,
    /// Mean true longitudinal slip ratio while driving.
    pub mean_slip_ratio: f64,
    /// Mean true lateral slip angle while driving, deg.
    pub mean_slip_angle_deg: f64,
}

/// Visual-odometry figures of the flight software (means `null` when VO never delivered).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct VoSummary {
    /// Relative poses delivered.
    pub updates: Option<u64>,
    /// Failed attempts.
    pub failures: Option<u64>,
    /// Mean features per frame.
    pub mean_features: Option<f64>,
    /// Mean inliers per frame.
    pub mean_inliers: Option<f64>,
    /// VO yaw boresight learnt by the flight software (`docs/estimation.md`, "VO boresight
    /// learnt as a gyro bias"), mrad, at the end of the run.
    pub boresight_mrad: f64,
    /// Samples the boresight was learnt from.
    pub boresight_samples: u32,
    /// The last VO failure's reason (`fsw::vo::VoError`), if VO failed.
    pub last_error: Option<String>,
}

/// Battery energy of a run: the simulator's truth energy model (`sim_host::energy`) and the
/// flight software's last accepted power reading.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct EnergySummary {
    /// Truth energy used over the run, J.
    pub used_j: f64,
    /// Truth mean electrical power over the run, W.
    pub mean_power_w: f64,
    /// Energy used of the last power reading the flight software accepted, J (null: none
    /// accepted).
    pub fsw_used_j: Option<f64>,
}

/// Timing of one rate group.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct GroupTimingJson {
    /// Largest execution time, us.
    pub max_us: u64,
    /// Mean execution time, us.
    pub mean_us: u64,
    /// Task overruns.
    pub overruns: u64,
}

/// The summary.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Summary {
    /// Scenario name.
    pub scenario: String,
    /// Seed.
    pub seed: u64,
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// True distance travelled, m.
    pub distance_m: f64,
    /// Final position error per estimate, m.
    pub final_error_m: PerEstimate,
    /// Final position error / distance x 100.
    pub error_pct: PerEstimate,
    /// Distance-travelled error of the kinematic estimates, %.
    pub distance_error_pct: DistanceErrors,
    /// Wheel-radius scales the flight software learnt.
    pub radius_scale: RadiusScales,
    /// Largest attitude error, deg.
    pub max_attitude_error_deg: AttitudeErrors,
    /// Cross-track error of the truth against the path.
    pub cross_track_m: CrossTrack,
    /// Goal reached within the scenario's tolerance.
    pub goal_reached: bool,
    /// Final distance to the goal, m.
    pub goal_miss_m: f64,
    /// True suspension excursions.
    pub suspension: SuspensionSummary,
    /// Truth steps that fell back from the quasi-static force model to the kinematic solve
    /// (an implausible twist after a placement that did not converge; 0 is expected).
    pub truth_force_fallbacks: u64,
    /// Truth steps whose velocity change was limited to what gravity and friction can do
    /// (the quasi-static balance had no static solution; `docs/simulator.md`).
    pub truth_inertia_limits: u64,
    /// Truth steps whose twist was scaled down to the quasi-static bounds.
    pub truth_twist_caps: u64,
    /// Truth-side scrub: how far the contact points of the wheels on the ground slid along
    /// their rolling tangents against the ground speed the wheels drove, % of that ground
    /// travel (`World::scrub_m`): wheel rates that do not fit the terrain show here, and no
    /// odometry can see this motion.
    pub truth_scrub_pct: f64,
    /// The same with sign: ground travel driven less the travel made, % of the ground travel
    /// (positive: the wheels turned more than the rover moved, so odometry runs long).
    pub truth_scrub_net_pct: f64,
    /// Truth-side hazard contacts: new overlaps of the rover footprint with a hazard
    /// footprint (`sim_host::hazards`).
    pub collisions: u32,
    /// The truth-side hazard check in detail.
    pub hazards: HazardSummary,
    /// The goal-directed drive (hazard maps and RoverBug; null for a path drive).
    pub planner: Option<PlannerSummary>,
    /// Terrain-map localization (V99 sec. 5; null when the run did not ask for it).
    pub localization: Option<LocalizationSummary>,
    /// The day's targets and the sequencer (V99 sec. 3; null without targets).
    pub targets: Option<TargetsSummary>,
    /// Slip.
    pub slip: SlipSummary,
    /// VO.
    pub vo: VoSummary,
    /// Per rate group (name -> figures), in schedule order.
    pub timing: serde_json::Map<String, serde_json::Value>,
    /// Device faults counted by the flight software.
    pub device_faults: u32,
    /// Per-device health counters of the flight software.
    pub device_health: serde_json::Map<String, serde_json::Value>,
    /// Stereo frames completed by the flight software.
    pub stereo_frames: u32,
    /// Battery energy.
    pub energy: EnergySummary,
    /// Who drove (`flight` or `reference`).
    pub driver: String,
    /// Slip compensation on.
    pub slip_compensation: bool,
    /// Final navigation mode of the flight software.
    pub nav_mode: String,
    /// Fault protection of the flight software.
    pub fault_protection: FaultProtectionSummary,
    /// Navigation counters of the flight software.
    pub nav: fsw::flight::nav::NavCounters,
    /// H04 eq. 15 kinematics alone, integrated with its own attitude
    /// ([`crate::output::components`]).
    pub kin_eq15: crate::output::components::Eq15Summary,
    /// The VO pipeline's relative poses chained raw.
    pub vo_raw: crate::output::components::VoRawSummary,
    /// Distance errors with their sign.
    pub signed_distance_error_pct: crate::output::components::SignedDistanceErrors,
    /// Slip estimation against the simulator's truth.
    pub slip_vs_truth: crate::output::components::SlipTruthSummary,
    /// The EKF's consistency in closed loop.
    pub nees: crate::output::components::NeesSummary,
    /// Wall-clock time of the run, s (the only field that differs between identical runs when
    /// the counter is simulated time).
    pub wall_time_s: f64,
}

/// The truth-side hazard check of a run (`sim_host::hazards`).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct HazardSummary {
    /// Hazards in the terrain: rocks and placed obstacles at least `height_m` high.
    pub count: usize,
    /// Hazard height of the scenario, m.
    pub height_m: f64,
    /// Closest approach of the rover footprint to a hazard footprint, m (null without
    /// hazards; 0 after a collision).
    pub min_distance_m: Option<f64>,
    /// Each collision: simulated time, s, and the hazard's centre (north, east), m.
    pub contacts: Vec<HazardContact>,
}

/// The goal-directed drive of a run (hazard maps and RoverBug, V99 sec. 4).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct PlannerSummary {
    /// `reached`, `unreachable`, `blocked` or `driving` (the planner's verdict at the end).
    pub status: String,
    /// The planner's last step's status with its reason (e.g. `Blocked(GazeLimit)`).
    pub last_status: Option<String>,
    /// Planner replans (changes of route).
    pub replans: u32,
    /// Planner steps (one per hazard map).
    pub steps: u32,
    /// Boundary-following episodes.
    pub boundary_following: u32,
    /// True path length of the rover, m.
    pub path_length_m: f64,
    /// Straight line from start to goal, m.
    pub straight_line_m: f64,
    /// Hazard maps made, and failed.
    pub maps: u32,
    /// Hazard maps that failed (perception errors).
    pub map_errors: u32,
    /// Gaze turns.
    pub gazes: u32,
    /// Gaze turns given up: a remembered obstacle inside the turning sweep.
    pub gazes_skipped: u32,
    /// Short forward drives made to gain room for a gaze turn next to a remembered obstacle
    /// (`HazardCounters::room_moves`, docs/hazard-navigation.md).
    pub room_moves: u32,
    /// RG2 cycles held still waiting for a map.
    pub hold_cycles: u32,
}

/// Terrain-map localization of a run (V99 sec. 5).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct LocalizationSummary {
    /// Fixes fused into the EKF.
    pub updates: u32,
    /// Fixes the EKF's gate refused.
    pub rejected: u32,
    /// Searches that ended without a fix (detected failures: ambiguous, too few inliers, peak
    /// on the window's edge, budget).
    pub failed: u32,
    /// Searches that could not start (mostly too few points in the local map).
    pub not_started: u32,
    /// Fixes whose capture state was gone.
    pub stale: u32,
    /// Searches started.
    pub searches: u32,
    /// Hazard maps added to local maps.
    pub maps: u32,
    /// Mean NEES of the fixes against the truth at their capture (3 dof: 3 when the
    /// covariance is consistent); null without a fix.
    pub nees_mean: Option<f64>,
    /// Fixes checked against the truth.
    pub fixes_checked: usize,
    /// Root-mean-square position error of the fixes, m; null without a fix.
    pub fix_error_rms_m: Option<f64>,
    /// Largest position error of a fused fix, m; null without one.
    pub fused_error_max_m: Option<f64>,
    /// Points of the uplinked global map, and rocks the descent image mapped.
    pub map_points: usize,
    /// Rocks and blocks the descent image mapped.
    pub map_features: usize,
    /// Why the last search failed, if one did.
    pub last_error: Option<String>,
}

/// The day's targets and the on-board sequencer of a run (V99 sec. 3): the flight
/// software's counters (`total`, `visited`, `dropped`, `unreachable`, `replans`, `reorders`,
/// the triggers, `goal_switches`, the power calibration, `energy_used_j` since the uplink at
/// its last replan; `fsw::flight::nav::MissionCounters`) and the outcome per target.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TargetsSummary {
    /// The flight software's counters, flattened into this object.
    #[serde(flatten)]
    pub counters: fsw::flight::nav::MissionCounters,
    /// Order of the visits (target indices).
    pub order: Vec<usize>,
    /// Outcome per target (scenario order).
    pub outcomes: Vec<String>,
    /// Truth miss at the start of each visited target's dwell, m (scenario order; null when
    /// not visited).
    pub miss_m: Vec<Option<f64>>,
    /// The ground's energy budget, J.
    pub energy_budget_j: f64,
    /// Final phase of the mission.
    pub phase: String,
}

/// One truth-side collision.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct HazardContact {
    /// Simulated time, s.
    pub t_s: f64,
    /// Centre of the hazard (north, east), m.
    pub at_m: [f64; 2],
}

/// What fault protection did in a run.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct FaultProtectionSummary {
    /// Fault-protection stops (0 or 1: a stop is latched).
    pub responses: u32,
    /// The stop's reason (`None` when the drive was not stopped).
    pub last_response: String,
    /// The flight EKF's last error, if it returned any (the cause of `nav.ekf_errors`' last
    /// count and, for a fault, of the `Safed` mode).
    pub last_ekf_error: Option<String>,
    /// The rover ended stopped by fault protection (it reported why instead of driving on or
    /// claiming an arrival it cannot support).
    pub stopped_safe: bool,
    /// The EKF's horizontal position 1-sigma at the end, m.
    pub final_position_sigma_m: Option<f64>,
}

/// A pose: position m, quaternion `[x, y, z, w]`.
type Pose = ([f64; 3], [f64; 4]);

/// The VO-only poses at their capture times with the truth there.
fn vo_pairs(run: &RunResult) -> impl Iterator<Item = (Pose, Pose)> + '_ {
    run.vo_checks
        .iter()
        .filter_map(|c| c.vo_pose.map(|v| (v, c.truth_pose)))
}

/// Final horizontal error of `which`, m.
fn final_error(run: &RunResult, which: Trajectory) -> Option<f64> {
    if which == Trajectory::Vo {
        return vo_pairs(run)
            .last()
            .map(|((p, _), (t, _))| (p[0] - t[0]).hypot(p[1] - t[1]));
    }
    let start_z = run.records.first().map_or(0.0, |r| r.pos_m[2]);
    run.records.iter().rev().find_map(|r| {
        which
            .pose(r, start_z)
            .map(|(p, _)| (p[0] - r.pos_m[0]).hypot(p[1] - r.pos_m[1]))
    })
}

/// Largest attitude error of `which` over the run, deg.
fn max_attitude_error(run: &RunResult, which: Trajectory) -> Option<f64> {
    let q = |v: [f64; 4]| {
        nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(v[3], v[0], v[1], v[2]))
    };
    if which == Trajectory::Vo {
        return vo_pairs(run)
            .map(|((_, e), (_, t))| q(e).angle_to(&q(t)).to_degrees())
            .reduce(f64::max);
    }
    run.records
        .iter()
        .filter_map(|r| {
            which
                .pose(r, 0.0)
                .map(|(_, e)| q(e).angle_to(&q(r.quat_xyzw)).to_degrees())
        })
        .reduce(f64::max)
}

fn per_estimate(f: impl Fn(Trajectory) -> Option<f64>) -> PerEstimate {
    PerEstimate {
        ekf: f(Trajectory::Ekf),
        vo: f(Trajectory::Vo),
        kin3d: f(Trajectory::Kin3d),
        kin2d: f(Trajectory::Kin2d),
        dr: f(Trajectory::Dr),
    }
}

/// Distance errors of the 3D kinematic odometry and of the averaged wheel odometry.
fn distance_errors(run: &RunResult) -> DistanceErrors {
    let truth = run.distance_m.max(1e-9);
    let points: Vec<[f64; 3]> = run
        .records
        .iter()
        .filter_map(|r| r.est.map(|e| e.kin3d.0))
        .collect();
    let kin3d = (points.len() > 1).then(|| {
        let length: f64 = points
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .sum();
        100.0 * (length - truth).abs() / truth
    });
    let wheel = run.records.last().map_or(0.0, |r| r.wheel_average_m);
    DistanceErrors {
        kin3d,
        wheel_average: 100.0 * (wheel - truth).abs() / truth,
    }
}

/// The true suspension's excursions over the run.
fn suspension(run: &RunResult) -> SuspensionSummary {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for r in &run.records {
        for k in 0..3 {
            lo[k] = lo[k].min(r.suspension_rad[k]);
            hi[k] = hi[k].max(r.suspension_rad[k]);
        }
    }
    let travel = std::array::from_fn(|k| if hi[k] >= lo[k] { hi[k] - lo[k] } else { 0.0 });
    let max_abs = |k: usize| {
        if hi[k] >= lo[k] {
            hi[k].abs().max(lo[k].abs())
        } else {
            0.0
        }
    };
    let stops = crate::vehicle::placement::JointLimits::rocky8();
    SuspensionSummary {
        rocker_max_abs_rad: max_abs(0),
        bogie_max_abs_rad: [max_abs(1), max_abs(2)],
        travel_rad: travel,
        stops_rad: [stops.rocker_rad, stops.bogie_rad],
    }
}

/// The targets of the mission sequencer, if the run had any.
fn targets_summary(run: &RunResult) -> Option<TargetsSummary> {
    run.mission.as_ref().map(|m| TargetsSummary {
        counters: m.counters,
        order: m.order.clone(),
        outcomes: m.outcomes.iter().map(|o| format!("{o:?}")).collect(),
        miss_m: (0..m.outcomes.len())
            .map(|i| m.visits.iter().find(|v| v.target == i).map(|v| v.miss_m))
            .collect(),
        energy_budget_j: m.energy_budget_j,
        phase: format!("{:?}", m.phase),
    })
}

/// What terrain-map localization did, if the run asked for it.
fn localization_summary(run: &RunResult) -> Option<LocalizationSummary> {
    run.localization.as_ref().map(|l| {
        let n = l.checks.len();
        let mean = |f: &dyn Fn(&crate::closed_loop::LocCheck) -> f64| {
            (n > 0).then(|| l.checks.iter().map(f).sum::<f64>() / n as f64)
        };
        LocalizationSummary {
            updates: l.counters.updates,
            rejected: l.counters.rejected,
            failed: l.counters.failed,
            not_started: l.counters.not_started,
            stale: l.counters.stale,
            searches: l.counters.searches,
            maps: l.counters.maps,
            nees_mean: mean(&|c| c.nees),
            fixes_checked: n,
            fix_error_rms_m: mean(&|c| c.error[0].powi(2) + c.error[1].powi(2)).map(f64::sqrt),
            fused_error_max_m: l
                .checks
                .iter()
                .filter(|c| c.applied)
                .map(|c| c.error[0].hypot(c.error[1]))
                .reduce(f64::max),
            map_points: l.map_points,
            map_features: l.map_features,
            last_error: l.last_error.clone(),
        }
    })
}

/// What the hazard maps and the planner did, on a goal-directed drive.
fn planner_summary(run: &RunResult) -> Option<PlannerSummary> {
    run.planner.as_ref().map(|p| PlannerSummary {
        status: match p.verdict {
            fsw::flight::nav::hazard_nav::PlannerVerdict::Driving => "driving",
            fsw::flight::nav::hazard_nav::PlannerVerdict::Reached => "reached",
            fsw::flight::nav::hazard_nav::PlannerVerdict::Unreachable => "unreachable",
            fsw::flight::nav::hazard_nav::PlannerVerdict::Blocked => "blocked",
        }
        .to_string(),
        last_status: p.last_status.clone(),
        replans: p.planner.map_or(0, |c| c.replans),
        steps: p.planner.map_or(0, |c| c.calls),
        boundary_following: p.planner.map_or(0, |c| c.follow_entries),
        path_length_m: run.distance_m,
        straight_line_m: p.straight_line_m,
        maps: p.hazard.maps,
        map_errors: p.hazard.map_errors,
        gazes: p.hazard.gazes,
        gazes_skipped: p.hazard.gazes_skipped,
        room_moves: p.hazard.room_moves,
        hold_cycles: p.hazard.holds,
    })
}

/// The truth-side hazard check.
fn hazard_summary(run: &RunResult) -> HazardSummary {
    HazardSummary {
        count: run.hazards,
        height_m: run.hazard_height_m,
        min_distance_m: run.hazard_min_distance_m,
        contacts: run
            .collisions
            .iter()
            .map(|c| HazardContact {
                t_s: c.t_s,
                at_m: c.at_m,
            })
            .collect(),
    }
}

/// Fault protection at the end of the run.
fn fault_protection_summary(run: &RunResult) -> FaultProtectionSummary {
    FaultProtectionSummary {
        responses: run.nav.fault_stops,
        last_response: format!("{:?}", run.fault_response),
        last_ekf_error: run.last_ekf_error.clone(),
        stopped_safe: run.nav_mode == fsw::flight::nav::NavMode::Stopped,
        final_position_sigma_m: run
            .records
            .iter()
            .rev()
            .find_map(|r| r.est)
            .map(|e| e.ekf_pos_sigma_m[0].hypot(e.ekf_pos_sigma_m[1])),
    }
}

/// The true slip over the records where the rover moved, and the gate's rejections.
fn slip_summary(run: &RunResult) -> SlipSummary {
    let moving: Vec<_> = run
        .records
        .windows(2)
        .filter(|w| w[1].distance_m > w[0].distance_m + 1e-5)
        .map(|w| w[1])
        .collect();
    let m = moving.len().max(1) as f64;
    SlipSummary {
        gate_reject_fraction: (run.nav.kin_tested > 0)
            .then(|| f64::from(run.nav.kin_rejected) / f64::from(run.nav.kin_tested)),
        mean_slip_ratio: moving.iter().map(|r| r.slip_ratio).sum::<f64>() / m,
        mean_slip_angle_deg: moving
            .iter()
            .map(|r| r.slip_angle_rad.to_degrees())
            .sum::<f64>()
            / m,
    }
}

/// Visual odometry in the flight software.
fn vo_summary(run: &RunResult) -> VoSummary {
    VoSummary {
        updates: Some(u64::from(run.nav.vo_updates)),
        failures: Some(u64::from(run.nav.vo_failures)),
        mean_features: run.vo_mean_features,
        mean_inliers: run.vo_mean_inliers,
        boresight_mrad: run.vo_boresight.0 * 1e3,
        boresight_samples: run.vo_boresight.1,
        last_error: run.vo_last_error.clone(),
    }
}

/// The executive's timing per rate group, by group name.
fn timing_summary(run: &RunResult) -> serde_json::Map<String, serde_json::Value> {
    let mut timing = serde_json::Map::new();
    for g in &run.timing {
        let value = serde_json::to_value(GroupTimingJson {
            max_us: g.max_us,
            mean_us: g.mean_us,
            overruns: g.overruns,
        })
        .unwrap_or(serde_json::Value::Null);
        timing.insert(g.name.clone(), value);
    }
    timing
}

/// The flight software's health of each device, by device name.
fn device_health_summary(run: &RunResult) -> serde_json::Map<String, serde_json::Value> {
    ["imu", "joints", "camera", "sun", "power"]
        .iter()
        .zip(run.device_health.iter())
        .map(|(k, h)| {
            (
                k.to_string(),
                serde_json::to_value(h).unwrap_or(serde_json::Value::Null),
            )
        })
        .collect()
}

/// Build the summary of `run`.
pub fn summarise(run: &RunResult) -> Summary {
    let n = run.records.len().max(1) as f64;
    let rms = (run
        .records
        .iter()
        .map(|r| r.cross_track_m.powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let max = run
        .records
        .iter()
        .map(|r| r.cross_track_m)
        .fold(0.0, f64::max);
    Summary {
        scenario: run.scenario.clone(),
        seed: run.seed,
        sim_time_s: run.sim_time_s,
        distance_m: run.distance_m,
        final_error_m: per_estimate(|w| final_error(run, w)),
        error_pct: per_estimate(|w| {
            final_error(run, w).map(|e| 100.0 * e / run.distance_m.max(1e-9))
        }),
        distance_error_pct: distance_errors(run),
        radius_scale: RadiusScales {
            ekf: run.radius_scales.0,
            kin3d: run.radius_scales.1,
            kin3d_windows: run.radius_scales.2,
        },
        max_attitude_error_deg: AttitudeErrors {
            ekf: max_attitude_error(run, Trajectory::Ekf),
            vo: max_attitude_error(run, Trajectory::Vo),
        },
        cross_track_m: CrossTrack { rms, max },
        goal_reached: run.goal_reached,
        goal_miss_m: run.goal_miss_m,
        suspension: suspension(run),
        truth_force_fallbacks: run.truth_force_fallbacks,
        truth_inertia_limits: run.truth_inertia_limits,
        truth_twist_caps: run.truth_twist_caps,
        truth_scrub_pct: run.truth_scrub_pct,
        truth_scrub_net_pct: run.truth_scrub_net_pct,
        collisions: u32::try_from(run.collisions.len()).unwrap_or(u32::MAX),
        hazards: hazard_summary(run),
        targets: targets_summary(run),
        localization: localization_summary(run),
        planner: planner_summary(run),
        slip: slip_summary(run),
        vo: vo_summary(run),
        timing: timing_summary(run),
        device_faults: run.device_faults,
        device_health: device_health_summary(run),
        stereo_frames: run.stereo_frames,
        energy: EnergySummary {
            used_j: run.energy_used_j,
            mean_power_w: run.mean_power_w,
            fsw_used_j: run.fsw_energy_used_j,
        },
        driver: run.driver.clone(),
        slip_compensation: run.slip_compensation,
        nav_mode: format!("{:?}", run.nav_mode),
        fault_protection: fault_protection_summary(run),
        nav: run.nav,
        kin_eq15: crate::output::components::eq15(run),
        vo_raw: crate::output::components::vo_raw(run),
        signed_distance_error_pct: crate::output::components::signed_distance(run),
        slip_vs_truth: crate::output::components::slip_truth(run),
        nees: crate::output::components::nees(run),
        wall_time_s: run.wall_time_s,
    }
}
