//! `campaign gather`: read every run's `summary.json` in index order, compute the statistics
//! of the metrics, check the criteria, list the worst runs, and write `DIR/stats.json`.
//!
//! `stats.json` is a pure function of the manifest and the summaries: runs are read in index
//! order, sums are taken in that order, ties are broken by the run index, maps are sorted by
//! key, every field has a fixed place, and numbers are written by `serde_json` (shortest
//! decimal that reads back to the same `f64`). Wall-clock times are left out (they go to
//! `runtime.json`). So a campaign run locally and one run on Slurm give the same bytes.
//!
//! **Percentiles** are nearest-rank: of the `n` values sorted ascending (ties by run index),
//! `P_p` is the value of rank `ceil(p n / 100)` (1-based, at least 1). It is always the value
//! of an actual run (named in the statistics), and `P_p <= t` holds exactly when at least
//! `p` % of the runs have a value `<= t`. The standard deviation is the sample one
//! (`n - 1`); a true/false metric counts 1 for true, so its mean is the fraction of runs.

use super::plan::Manifest;
use super::spec::{Criterion, Op, Stat};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// A metric of `summary.json`.
#[derive(Debug, Clone, Copy)]
pub struct MetricDef {
    /// Dotted path into `summary.json`.
    pub name: &'static str,
    /// Unit.
    pub unit: &'static str,
    /// What it is.
    pub doc: &'static str,
    /// In every campaign's statistics.
    pub default: bool,
}

const fn m(name: &'static str, unit: &'static str, doc: &'static str, default: bool) -> MetricDef {
    MetricDef {
        name,
        unit,
        doc,
        default,
    }
}

/// The metrics a campaign can use (any counter of the navigator, `nav.<field>`, as well).
pub const METRICS: &[MetricDef] = &[
    m(
        "goal_reached",
        "-",
        "goal reached within the scenario's tolerance (1 true, 0 false)",
        true,
    ),
    m("goal_miss_m", "m", "final distance to the goal", true),
    m(
        "cross_track_m.max",
        "m",
        "largest cross-track error of the truth",
        true,
    ),
    m(
        "cross_track_m.rms",
        "m",
        "rms cross-track error of the truth",
        true,
    ),
    m(
        "error_pct.ekf",
        "%",
        "EKF final horizontal error / distance",
        true,
    ),
    m(
        "error_pct.vo",
        "%",
        "VO final horizontal error / distance",
        true,
    ),
    m(
        "error_pct.kin3d",
        "%",
        "3D kinematic odometry final error / distance",
        true,
    ),
    m(
        "error_pct.kin2d",
        "%",
        "planar wheel odometry final error / distance",
        false,
    ),
    m(
        "error_pct.dr",
        "%",
        "dead reckoning final error / distance",
        false,
    ),
    m("final_error_m.ekf", "m", "EKF final horizontal error", true),
    m("final_error_m.vo", "m", "VO final horizontal error", false),
    m(
        "final_error_m.kin3d",
        "m",
        "3D kinematic final error",
        false,
    ),
    m(
        "final_error_m.kin2d",
        "m",
        "planar wheel odometry final error",
        false,
    ),
    m("final_error_m.dr", "m", "dead reckoning final error", false),
    m(
        "max_attitude_error_deg.ekf",
        "deg",
        "largest EKF attitude error",
        true,
    ),
    m(
        "max_attitude_error_deg.vo",
        "deg",
        "largest VO attitude error",
        false,
    ),
    m(
        "distance_error_pct.kin3d",
        "%",
        "3D odometry distance-travelled error",
        false,
    ),
    m(
        "distance_error_pct.wheel_average",
        "%",
        "averaged wheel odometry distance error",
        false,
    ),
    m(
        "kin_eq15.error_pct",
        "%",
        "H04 eq. 15 kinematics alone (own attitude, no IMU/VO/sun/learnt scale): final error / distance",
        true,
    ),
    m(
        "vo_raw.error_pct",
        "%",
        "VO relative poses chained raw (no boresight, no anchor): final error / distance",
        true,
    ),
    m(
        "signed_distance_error_pct.kin3d",
        "%",
        "3D odometry path length against the true one, signed",
        false,
    ),
    m(
        "signed_distance_error_pct.kin_eq15",
        "%",
        "eq. 15 path length against the true one, signed",
        false,
    ),
    m(
        "nees.position_mean",
        "-",
        "mean horizontal-position NEES of the EKF (2 when consistent)",
        true,
    ),
    m(
        "nees.position_within_95",
        "-",
        "fraction of time the position NEES is within its 95 % bound",
        true,
    ),
    m(
        "nees.heading_within_95",
        "-",
        "fraction of time the heading NEES is within its 95 % bound",
        false,
    ),
    m(
        "slip_vs_truth.detection",
        "-",
        "gate rejections over the intervals that truly slip",
        false,
    ),
    m(
        "slip_vs_truth.false_alarm",
        "-",
        "gate rejections over the intervals that truly do not slip",
        false,
    ),
    m(
        "slip.gate_reject_fraction",
        "-",
        "fraction of kinematic intervals the gate rejected",
        true,
    ),
    m(
        "slip.mean_slip_ratio",
        "-",
        "mean true slip ratio while driving",
        true,
    ),
    m(
        "slip.mean_slip_angle_deg",
        "deg",
        "mean true slip angle while driving",
        true,
    ),
    m("vo.updates", "-", "VO relative poses delivered", true),
    m("vo.failures", "-", "VO failed attempts", true),
    m("vo.mean_features", "-", "mean VO features per frame", false),
    m("vo.mean_inliers", "-", "mean VO inliers per frame", false),
    m(
        "fault_protection.responses",
        "-",
        "fault-protection stops",
        true,
    ),
    m(
        "fault_protection.stopped_safe",
        "-",
        "ended stopped by fault protection",
        false,
    ),
    m(
        "fault_protection.final_position_sigma_m",
        "m",
        "EKF horizontal 1-sigma at the end",
        true,
    ),
    m("distance_m", "m", "true distance travelled", true),
    m("sim_time_s", "s", "simulated time", true),
    m(
        "device_faults",
        "-",
        "device faults counted by the flight software",
        false,
    ),
    m("stereo_frames", "-", "stereo frames completed", false),
    m(
        "truth_force_fallbacks",
        "-",
        "truth steps that fell back to the kinematic solve",
        true,
    ),
    m(
        "suspension.rocker_max_abs_rad",
        "rad",
        "largest rocker angle",
        false,
    ),
    m(
        "energy.used_j",
        "J",
        "battery energy used (truth energy model)",
        false,
    ),
    m(
        "energy.mean_power_w",
        "W",
        "mean electrical power (truth energy model)",
        false,
    ),
];

/// Check that `name` is a metric ([`METRICS`] or `nav.<counter>`).
pub fn check_metric(name: &str) -> anyhow::Result<()> {
    if METRICS.iter().any(|m| m.name == name) {
        return Ok(());
    }
    if let Some(field) = name.strip_prefix("nav.") {
        if !field.is_empty() && field.chars().all(|c| c.is_ascii_lowercase() || c == '_') {
            return Ok(());
        }
    }
    let names: Vec<&str> = METRICS.iter().map(|m| m.name).collect();
    anyhow::bail!(
        "unknown metric {name:?}; known: {}, nav.<counter>",
        names.join(", ")
    )
}

/// The unit of a metric.
pub fn unit(name: &str) -> &'static str {
    METRICS
        .iter()
        .find(|m| m.name == name)
        .map_or("-", |m| m.unit)
}

/// The value at the dotted `path` of a summary: `Ok(None)` for `null`, an error when the path
/// does not exist or is not a number or a boolean.
pub fn value_at(summary: &serde_json::Value, path: &str) -> Result<Option<f64>, String> {
    let mut v = summary;
    for part in path.split('.') {
        v = match v {
            serde_json::Value::Object(map) => map.get(part),
            serde_json::Value::Array(a) => part.parse::<usize>().ok().and_then(|i| a.get(i)),
            _ => None,
        }
        .ok_or_else(|| format!("no {path:?} in summary.json"))?;
    }
    match v {
        serde_json::Value::Null => Ok(None),
        serde_json::Value::Bool(b) => Ok(Some(if *b { 1.0 } else { 0.0 })),
        serde_json::Value::Number(n) => n
            .as_f64()
            .map(Some)
            .ok_or_else(|| format!("{path:?} is not a number")),
        _ => Err(format!("{path:?} is not a number or a boolean")),
    }
}

/// The value of one run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RunValue {
    /// Run index.
    pub index: u64,
    /// Run seed.
    pub seed: u64,
    /// Value (`null`: the run has none, e.g. an estimate that never existed).
    pub value: Option<f64>,
}

/// A percentile with the run that has it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Percentile {
    /// Percent, e.g. 99.
    pub p: f64,
    /// Value.
    pub value: f64,
    /// Run index with that value.
    pub run: u64,
}

/// Statistics of one metric over the runs that have a value.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MetricStats {
    /// Metric.
    pub metric: String,
    /// Unit.
    pub unit: String,
    /// Runs with a value.
    pub n: u64,
    /// Runs whose value is `null`.
    pub null_runs: Vec<u64>,
    /// Mean (`null` when `n` = 0).
    pub mean: Option<f64>,
    /// Sample standard deviation (`null` when `n` < 2).
    pub std: Option<f64>,
    /// Smallest value and its run.
    pub min: Option<Percentile>,
    /// Largest value and its run.
    pub max: Option<Percentile>,
    /// P50, P90, P95, P99 (nearest rank).
    pub percentiles: Vec<Percentile>,
}

/// The result of one criterion.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CriterionResult {
    /// Name.
    pub name: String,
    /// Metric.
    pub metric: String,
    /// Unit.
    pub unit: String,
    /// Statistic (`P99`, `mean`, ...).
    pub stat: String,
    /// Comparison.
    pub op: String,
    /// Threshold.
    pub threshold: f64,
    /// Where the threshold comes from.
    pub source: String,
    /// Runs with a value.
    pub n: u64,
    /// Runs without a value (each counts as a failure of the criterion).
    pub null_runs: Vec<u64>,
    /// The statistic's value (`null` when no run has a value).
    pub value: Option<f64>,
    /// The run that has the value (percentiles, min, max).
    pub value_run: Option<u64>,
    /// Whether the criterion holds: a value, no run without a value, `value op threshold`.
    pub pass: bool,
    /// Runs on the wrong side of the threshold.
    pub runs_beyond_threshold: u64,
    /// The worst runs (runs without a value first, then by value, ties by index).
    pub worst: Vec<RunValue>,
}

/// A run that did not finish.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FailedRun {
    /// Index.
    pub index: u64,
    /// Seed.
    pub seed: u64,
    /// The error (`runs/<index>/error.txt`).
    pub error: String,
}

/// Pearson correlation of a metric with one dispersion's draws.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Sensitivity {
    /// Metric.
    pub metric: String,
    /// Dispersion.
    pub dispersion: String,
    /// Pearson `r` over the runs with a value (`null`: fewer than 3 runs or no spread).
    pub r: Option<f64>,
}

/// Range of one dispersion's draws.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DrawRange {
    /// Dispersion.
    pub dispersion: String,
    /// Smallest draw.
    pub min: f64,
    /// Mean draw.
    pub mean: f64,
    /// Largest draw.
    pub max: f64,
}

/// `stats.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Stats {
    /// Campaign name.
    pub campaign: String,
    /// Base scenario name.
    pub scenario: String,
    /// Base seed.
    pub base_seed: u64,
    /// Runs planned.
    pub runs_planned: u64,
    /// Runs with a summary.
    pub runs_ok: u64,
    /// Runs that failed (an `error.txt`).
    pub failed_runs: Vec<FailedRun>,
    /// Runs with neither a summary nor an error (not run, or still running).
    pub missing_runs: Vec<u64>,
    /// `pass` (every run present, every criterion holds), `fail` (every run present, a
    /// criterion fails) or `incomplete` (a run failed or is missing).
    pub verdict: String,
    /// How percentiles are defined.
    pub percentile_definition: String,
    /// Criteria.
    pub criteria: Vec<CriterionResult>,
    /// Metrics.
    pub metrics: Vec<MetricStats>,
    /// Counts of the final navigation mode and of the fault-protection response.
    pub outcomes: BTreeMap<String, BTreeMap<String, u64>>,
    /// Ranges of the draws.
    pub draws: Vec<DrawRange>,
    /// Correlation of each criterion's metric with each dispersion.
    pub sensitivity: Vec<Sensitivity>,
}

/// The percentile definition written into `stats.json`.
pub const PERCENTILE_DEFINITION: &str = "nearest rank: of the n values sorted ascending (ties by \
     run index), P_p is the value of rank ceil(p n / 100) (1-based, at least 1); runs without a \
     value (null) are left out of the statistics, listed, and fail any criterion on the metric";

/// Everything `gather` read and computed.
#[derive(Debug, Clone)]
pub struct Gathered {
    /// The statistics.
    pub stats: Stats,
    /// Per metric, the value of every run with a summary, in index order.
    pub values: BTreeMap<String, Vec<RunValue>>,
    /// Wall-clock seconds and simulated seconds of every run with a summary.
    pub times: Vec<(u64, f64, f64)>,
}

/// Nearest-rank percentile `p` of `sorted` (ascending): the value and its position.
pub fn nearest_rank(sorted_len: usize, p: f64) -> usize {
    let n = sorted_len as f64;
    // A small tolerance so that p n / 100 that is an integer in exact arithmetic is not pushed
    // up by one by rounding (99.9 * 1000 / 100 = 999.0000000000001).
    let rank = (p * n / 100.0 - 1e-9).ceil().max(1.0) as usize;
    rank.min(sorted_len) - 1
}

fn sorted_values(values: &[RunValue]) -> Vec<(f64, u64)> {
    let mut v: Vec<(f64, u64)> = values
        .iter()
        .filter_map(|r| r.value.map(|x| (x, r.index)))
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    v
}

fn mean_std(values: &[RunValue]) -> (Option<f64>, Option<f64>) {
    let xs: Vec<f64> = values.iter().filter_map(|r| r.value).collect();
    if xs.is_empty() {
        return (None, None);
    }
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let std = (xs.len() >= 2)
        .then(|| (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt());
    (Some(mean), std)
}

/// Statistics of one metric.
pub fn metric_stats(metric: &str, values: &[RunValue]) -> MetricStats {
    let sorted = sorted_values(values);
    let (mean, std) = mean_std(values);
    let at = |k: usize, p: f64| Percentile {
        p,
        value: sorted[k].0,
        run: sorted[k].1,
    };
    let has = !sorted.is_empty();
    MetricStats {
        metric: metric.to_string(),
        unit: unit(metric).to_string(),
        n: sorted.len() as u64,
        null_runs: values
            .iter()
            .filter(|r| r.value.is_none())
            .map(|r| r.index)
            .collect(),
        mean,
        std,
        min: has.then(|| at(0, 0.0)),
        max: has.then(|| at(sorted.len() - 1, 100.0)),
        percentiles: if has {
            [50.0, 90.0, 95.0, 99.0]
                .iter()
                .map(|&p| at(nearest_rank(sorted.len(), p), p))
                .collect()
        } else {
            Vec::new()
        },
    }
}

/// Evaluate `criterion` on `values`, listing `worst` worst runs.
pub fn evaluate(
    criterion: &Criterion,
    values: &[RunValue],
    worst: usize,
) -> anyhow::Result<CriterionResult> {
    let stat = criterion.stat()?;
    let sorted = sorted_values(values);
    let (value, value_run) = if sorted.is_empty() {
        (None, None)
    } else {
        match stat {
            Stat::Percentile(p) => {
                let k = nearest_rank(sorted.len(), p);
                (Some(sorted[k].0), Some(sorted[k].1))
            }
            Stat::Mean => (mean_std(values).0, None),
            Stat::Min => (Some(sorted[0].0), Some(sorted[0].1)),
            Stat::Max => {
                let last = sorted[sorted.len() - 1];
                (Some(last.0), Some(last.1))
            }
        }
    };
    let null_runs: Vec<u64> = values
        .iter()
        .filter(|r| r.value.is_none())
        .map(|r| r.index)
        .collect();
    let op = criterion.op;
    let pass = null_runs.is_empty() && value.is_some_and(|v| op.holds(v, criterion.threshold));
    let beyond = sorted
        .iter()
        .filter(|(v, _)| !op.holds(*v, criterion.threshold))
        .count() as u64;
    // Worst first: runs without a value, then by value in the bad direction, ties by index.
    let mut order: Vec<RunValue> = values.to_vec();
    order.sort_by(|a, b| match (a.value, b.value) {
        (None, None) => a.index.cmp(&b.index),
        (None, Some(_)) => std::cmp::Ordering::Less,
        (Some(_), None) => std::cmp::Ordering::Greater,
        (Some(x), Some(y)) => {
            let by_value = if op.large_is_bad() {
                y.total_cmp(&x)
            } else {
                x.total_cmp(&y)
            };
            by_value.then(a.index.cmp(&b.index))
        }
    });
    order.truncate(worst);
    Ok(CriterionResult {
        name: criterion.name.clone(),
        metric: criterion.metric.clone(),
        unit: unit(&criterion.metric).to_string(),
        stat: stat.label(),
        op: op.symbol().to_string(),
        threshold: criterion.threshold,
        source: criterion.source.clone(),
        n: sorted.len() as u64,
        null_runs,
        value,
        value_run,
        pass,
        runs_beyond_threshold: beyond,
        worst: order,
    })
}

/// Pearson correlation of `(x, y)` pairs (`None`: fewer than 3 pairs or no spread).
pub fn pearson(pairs: &[(f64, f64)]) -> Option<f64> {
    if pairs.len() < 3 {
        return None;
    }
    let n = pairs.len() as f64;
    let mx = pairs.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pairs.iter().map(|p| p.1).sum::<f64>() / n;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (x, y) in pairs {
        sxy += (x - mx) * (y - my);
        sxx += (x - mx).powi(2);
        syy += (y - my).powi(2);
    }
    (sxx > 0.0 && syy > 0.0).then(|| sxy / (sxx * syy).sqrt())
}

/// The metrics of a campaign: the criteria's, the default list, the spec's extra ones, each
/// once, in that order.
pub fn metric_list(spec: &super::spec::Spec) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    let candidates = spec
        .criteria
        .iter()
        .map(|c| c.metric.clone())
        .chain(
            METRICS
                .iter()
                .filter(|m| m.default)
                .map(|m| m.name.to_string()),
        )
        .chain(spec.metrics.iter().cloned());
    for n in candidates {
        if !names.contains(&n) {
            names.push(n);
        }
    }
    names
}

/// What the runs of a campaign folder hold.
struct RunsRead {
    /// Each metric's value per run with a summary, in index order.
    values: BTreeMap<String, Vec<RunValue>>,
    failed: Vec<FailedRun>,
    missing: Vec<u64>,
    /// Counts of each outcome field's values.
    outcomes: BTreeMap<String, BTreeMap<String, u64>>,
    /// `(index, wall time, simulated time)` per run with a summary.
    times: Vec<(u64, f64, f64)>,
    /// Runs with a summary.
    ok: u64,
}

/// Read every run of the manifest in `dir`: its summary (the `metrics`, the outcomes, the
/// times), or its error, or nothing.
fn read_runs(dir: &Path, manifest: &Manifest, metrics: &[String]) -> anyhow::Result<RunsRead> {
    let mut values: BTreeMap<String, Vec<RunValue>> = BTreeMap::new();
    let mut failed = Vec::new();
    let mut missing = Vec::new();
    let mut outcomes: BTreeMap<String, BTreeMap<String, u64>> = BTreeMap::new();
    let mut times = Vec::new();
    let mut ok = 0;
    for entry in &manifest.entries {
        let folder = super::exec::run_dir(dir, entry.index);
        let summary_path = folder.join("summary.json");
        let summary: serde_json::Value = match std::fs::read_to_string(&summary_path) {
            Ok(text) => serde_json::from_str(&text)
                .map_err(|e| anyhow::anyhow!("{}: {e}", summary_path.display()))?,
            Err(_) => {
                match std::fs::read_to_string(folder.join("error.txt")) {
                    Ok(error) => failed.push(FailedRun {
                        index: entry.index,
                        seed: entry.seed,
                        error: error.trim().to_string(),
                    }),
                    Err(_) => missing.push(entry.index),
                }
                continue;
            }
        };
        ok += 1;
        for metric in metrics {
            let value = value_at(&summary, metric)
                .map_err(|e| anyhow::anyhow!("{}: {e}", summary_path.display()))?;
            values.entry(metric.clone()).or_default().push(RunValue {
                index: entry.index,
                seed: entry.seed,
                value,
            });
        }
        for key in ["nav_mode", "fault_protection.last_response"] {
            let label = key
                .split('.')
                .try_fold(&summary, |v, k| v.get(k))
                .and_then(|v| v.as_str())
                .unwrap_or("?")
                .to_string();
            *outcomes
                .entry(key.to_string())
                .or_default()
                .entry(label)
                .or_default() += 1;
        }
        let wall = summary
            .get("wall_time_s")
            .and_then(|v| v.as_f64())
            .unwrap_or(0.0);
        let sim = summary
            .get("sim_time_s")
            .and_then(|v| v.as_f64())
            .unwrap_or(0.0);
        times.push((entry.index, wall, sim));
    }
    for metric in metrics {
        values.entry(metric.clone()).or_default();
    }
    Ok(RunsRead {
        values,
        failed,
        missing,
        outcomes,
        times,
        ok,
    })
}

/// The range of each dispersion's draws over the manifest (`keys`: the dispersions).
fn draw_ranges(manifest: &Manifest, keys: &[String]) -> Vec<DrawRange> {
    keys.iter()
        .filter_map(|k| {
            let xs: Vec<f64> = manifest
                .entries
                .iter()
                .filter_map(|e| e.draws.get(k).copied())
                .collect();
            (!xs.is_empty()).then(|| DrawRange {
                dispersion: k.clone(),
                min: xs.iter().copied().fold(f64::INFINITY, f64::min),
                mean: xs.iter().sum::<f64>() / xs.len() as f64,
                max: xs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            })
        })
        .collect()
}

/// The Pearson correlation of each criterion's metric (once per metric) with each
/// dispersion's draw.
fn sensitivities(
    spec: &super::spec::Spec,
    manifest: &Manifest,
    values: &BTreeMap<String, Vec<RunValue>>,
    keys: &[String],
) -> Vec<Sensitivity> {
    let mut sensitivity = Vec::new();
    let mut seen = Vec::new();
    for c in &spec.criteria {
        if seen.contains(&c.metric) {
            continue;
        }
        seen.push(c.metric.clone());
        for k in keys {
            let pairs: Vec<(f64, f64)> = values[&c.metric]
                .iter()
                .filter_map(|r| {
                    let draw = manifest.entries.get(r.index as usize)?.draws.get(k)?;
                    Some((*draw, r.value?))
                })
                .collect();
            sensitivity.push(Sensitivity {
                metric: c.metric.clone(),
                dispersion: k.clone(),
                r: pearson(&pairs),
            });
        }
    }
    sensitivity
}

/// Read the runs of `dir` and compute everything (writes nothing).
pub fn gather(dir: &Path, manifest: &Manifest) -> anyhow::Result<Gathered> {
    let spec = manifest.spec()?;
    let metrics = metric_list(&spec);
    let RunsRead {
        values,
        failed,
        missing,
        outcomes,
        times,
        ok,
    } = read_runs(dir, manifest, &metrics)?;
    let criteria = spec
        .criteria
        .iter()
        .map(|c| evaluate(c, &values[&c.metric], spec.worst_runs))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let complete = failed.is_empty() && missing.is_empty();
    let verdict = if !complete {
        "incomplete"
    } else if criteria.iter().all(|c| c.pass) {
        "pass"
    } else {
        "fail"
    };
    let keys: Vec<String> = spec.dispersions.iter().map(|d| d.key()).collect();
    let draws = draw_ranges(manifest, &keys);
    let sensitivity = sensitivities(&spec, manifest, &values, &keys);
    let scenario = manifest.base_scenario()?.name;
    let stats = Stats {
        campaign: manifest.campaign.clone(),
        scenario,
        base_seed: manifest.base_seed,
        runs_planned: manifest.runs,
        runs_ok: ok,
        failed_runs: failed,
        missing_runs: missing,
        verdict: verdict.to_string(),
        percentile_definition: PERCENTILE_DEFINITION.to_string(),
        criteria,
        metrics: metrics
            .iter()
            .map(|m| metric_stats(m, &values[m]))
            .collect(),
        outcomes,
        draws,
        sensitivity,
    };
    Ok(Gathered {
        stats,
        values,
        times,
    })
}

/// `stats.json` text (pretty JSON, a final newline).
pub fn stats_text(stats: &Stats) -> anyhow::Result<String> {
    Ok(serde_json::to_string_pretty(stats)? + "\n")
}

/// `runtime.json` text: the wall-clock figures of the runs (not in `stats.json`: they differ
/// between executions).
pub fn runtime_text(times: &[(u64, f64, f64)]) -> anyhow::Result<String> {
    let mut walls: Vec<f64> = times.iter().map(|t| t.1).collect();
    walls.sort_by(f64::total_cmp);
    let total: f64 = walls.iter().sum();
    let sim: f64 = times.iter().map(|t| t.2).sum();
    let n = walls.len();
    let median = if n == 0 {
        0.0
    } else if n % 2 == 1 {
        walls[n / 2]
    } else {
        0.5 * (walls[n / 2 - 1] + walls[n / 2])
    };
    let value = serde_json::json!({
        "runs": n,
        "wall_time_s_per_run": {
            "mean": if n > 0 { total / n as f64 } else { 0.0 },
            "median": median,
            "min": walls.first().copied().unwrap_or(0.0),
            "max": walls.last().copied().unwrap_or(0.0),
        },
        "wall_time_s_total": total,
        "sim_time_s_total": sim,
        "real_time_factor": if total > 0.0 { sim / total } else { 0.0 },
        "note": "wall_time_s of each run's summary.json (the simulation loop, one run on one \
                 core plus the renderer's threads); not part of stats.json",
    });
    Ok(serde_json::to_string_pretty(&value)? + "\n")
}

/// `Op` of a criterion result, parsed back from its symbol.
pub fn op_of(result: &CriterionResult) -> Op {
    match result.op.as_str() {
        "<" => Op::Lt,
        ">=" => Op::Ge,
        ">" => Op::Gt,
        _ => Op::Le,
    }
}
