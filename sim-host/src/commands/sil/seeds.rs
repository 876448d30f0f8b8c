//! The seed sets of the SIL acceptance and the statistics over them.
//!
//! Every run of a case on a seed is its own terrain, slip, sensor noise and rover unit (the
//! per-seed dimension, wheel-radius, camera and IMU calibration errors): the scenario's seed is
//! replaced by the acceptance seed, with no separate terrain or calibration seed.
//!
//! - **Calibration set**: seeds 1 to 3 (the scenario files' seeds and the seeds the design
//!   notes measured on), on which the flight software's parameters and the scenarios were set.
//!   The acceptance never uses them.
//! - **Acceptance set**: seeds [`ACCEPTANCE_FIRST_SEED`], +1, ... The CI tier runs the first
//!   [`CI_SEEDS`] of them per case; the release tier at least [`RELEASE_SEEDS`].
//!
//! One [`SeedRow`] per case and seed holds the check values and the component metrics; the
//! release tier's rows are `docs/results/sil-seeds.jsonl`, from which the results page is
//! made, and which the CI tier reproduces value for value.

use super::{Case, CaseRun, Check, Compare, Stat, CASES};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The first seed of the acceptance set.
pub const ACCEPTANCE_FIRST_SEED: u64 = 1001;
/// Seeds per case of the CI tier (the test command).
pub const CI_SEEDS: u64 = 2;
/// Seeds per case of the release tier (at least).
pub const RELEASE_SEEDS: u64 = 50;
/// The release tier's rows, relative to the repository root.
pub const RELEASE_ROWS: &str = "docs/results/sil-seeds.jsonl";

/// The seeds `0..n` of the acceptance set.
pub fn acceptance_seeds(n: u64) -> impl Iterator<Item = u64> {
    (0..n).map(|k| ACCEPTANCE_FIRST_SEED + k)
}

/// The component metrics of one run, for the results page (`summary.json` has them all).
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct RunMetrics {
    /// Distance driven, m.
    pub distance_m: f64,
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// EKF, VO (flight VO-only pose), raw VO, flight 3D kinematics, H04 eq. 15 alone: final
    /// horizontal error / distance, %.
    pub ekf_pct: Option<f64>,
    /// VO.
    pub vo_pct: Option<f64>,
    /// Raw VO.
    pub vo_raw_pct: Option<f64>,
    /// Flight 3D kinematics.
    pub kin3d_pct: Option<f64>,
    /// Eq. 15 alone.
    pub kin_eq15_pct: Option<f64>,
    /// Signed distance error of the flight 3D kinematics and of eq. 15 alone, %.
    pub kin3d_dist_signed_pct: Option<f64>,
    /// Eq. 15 alone.
    pub kin_eq15_dist_signed_pct: Option<f64>,
    /// Position and heading NEES means and the fraction of time within the 95 % bounds.
    pub nees_pos_mean: Option<f64>,
    /// Heading NEES mean.
    pub nees_heading_mean: Option<f64>,
    /// Position NEES within its 95 % bound.
    pub nees_pos_within_95: Option<f64>,
    /// Heading NEES within its 95 % bound.
    pub nees_heading_within_95: Option<f64>,
    /// Slip vector minus true slip per interval, rms over x and y, mm.
    pub slip_rms_mm: Option<f64>,
    /// The gate's detection probability and false-alarm rate against the true slip.
    pub slip_detection: Option<f64>,
    /// False-alarm rate.
    pub slip_false_alarm: Option<f64>,
    /// VO updates and failures.
    pub vo_updates: u64,
    /// VO failures.
    pub vo_failures: u64,
    /// Wall time of the case's runs, s (not compared).
    pub wall_time_s: f64,
}

impl RunMetrics {
    /// The metrics of `run`.
    pub fn of(run: &CaseRun) -> Self {
        let s = &run.runs.main;
        let rms2 = s
            .slip_vs_truth
            .rms_m
            .map(|[x, y]| 1000.0 * (0.5 * (x * x + y * y)).sqrt());
        Self {
            distance_m: s.distance_m,
            sim_time_s: s.sim_time_s,
            ekf_pct: s.error_pct.ekf,
            vo_pct: s.error_pct.vo,
            vo_raw_pct: s.vo_raw.error_pct,
            kin3d_pct: s.error_pct.kin3d,
            kin_eq15_pct: s.kin_eq15.error_pct,
            kin3d_dist_signed_pct: s.signed_distance_error_pct.kin3d,
            kin_eq15_dist_signed_pct: s.signed_distance_error_pct.kin_eq15,
            nees_pos_mean: s.nees.position_mean,
            nees_heading_mean: s.nees.heading_mean,
            nees_pos_within_95: s.nees.position_within_95,
            nees_heading_within_95: s.nees.heading_within_95,
            slip_rms_mm: rms2,
            slip_detection: s.slip_vs_truth.detection,
            slip_false_alarm: s.slip_vs_truth.false_alarm,
            vo_updates: s.vo.updates.unwrap_or(0),
            vo_failures: s.vo.failures.unwrap_or(0),
            wall_time_s: s.wall_time_s + run.runs.no_comp.as_ref().map_or(0.0, |n| n.wall_time_s),
        }
    }
}

/// One case on one seed: what the results page and the CI tier need.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct SeedRow {
    /// Case id.
    pub case: String,
    /// Seed.
    pub seed: u64,
    /// Check values in the case's order (`None`: the estimate does not exist).
    pub values: Vec<Option<f64>>,
    /// The case's final navigation mode.
    pub nav_mode: String,
    /// Component metrics.
    pub metrics: RunMetrics,
}

impl SeedRow {
    /// The row of `run`.
    pub fn of(run: &CaseRun) -> Self {
        Self {
            case: run.case.id.to_string(),
            seed: run.seed,
            values: run.values.clone(),
            nav_mode: run.runs.main.nav_mode.clone(),
            metrics: RunMetrics::of(run),
        }
    }
}

/// Read rows (JSON lines).
pub fn read_rows(path: &Path) -> anyhow::Result<Vec<SeedRow>> {
    let text =
        std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| Ok(serde_json::from_str(l)?))
        .collect()
}

/// The rows of `rows` that differ from the row of the same case and seed in `reference`, or
/// have none there: one line each. Rows compare as their JSON lines with the wall time set
/// to 0 (a run's figures are deterministic, its wall time is not; a non-finite value is
/// `null` in both).
pub fn differences(rows: &[SeedRow], reference: &[SeedRow]) -> Vec<String> {
    let line = |r: &SeedRow| {
        let mut r = r.clone();
        r.metrics.wall_time_s = 0.0;
        serde_json::to_string(&r).unwrap_or_default()
    };
    rows.iter()
        .filter_map(|r| {
            let Some(want) = reference
                .iter()
                .find(|x| x.case == r.case && x.seed == r.seed)
            else {
                return Some(format!("{} seed {}: not in the reference", r.case, r.seed));
            };
            let (got, want) = (line(r), line(want));
            (got != want).then(|| format!("{} seed {}: {got}\n  expected {want}", r.case, r.seed))
        })
        .collect()
}

/// Rows as JSON lines, sorted by case (table order) and seed.
pub fn rows_text(rows: &[SeedRow]) -> anyhow::Result<String> {
    let mut sorted: Vec<&SeedRow> = rows.iter().collect();
    let order = |id: &str| CASES.iter().position(|c| c.id == id).unwrap_or(usize::MAX);
    sorted.sort_by_key(|r| (order(&r.case), r.seed));
    let mut s = String::new();
    for r in sorted {
        s += &serde_json::to_string(r)?;
        s.push('\n');
    }
    Ok(s)
}

/// A check's values over the seeds, judged at its statistic.
#[derive(Debug, Clone, PartialEq)]
pub struct Judged {
    /// Seeds with a row.
    pub seeds: usize,
    /// The statistic's value: the percentile, the fraction of seeds passing, or the worst
    /// value (`None`: a seed has no value, or there are no seeds).
    pub statistic: Option<f64>,
    /// The check holds at its statistic.
    pub pass: bool,
    /// The worst seed and its value.
    pub worst: Option<(u64, Option<f64>)>,
    /// Seeds failing the per-seed check.
    pub failing_seeds: usize,
}

/// Nearest-rank percentile `p` (0-100) of sorted `v`.
fn nearest_rank(v: &[f64], p: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let rank = ((p / 100.0) * v.len() as f64).ceil().max(1.0) as usize;
    v.get(rank.min(v.len()) - 1).copied()
}

/// Judge `check` (the `k`-th of its case) over `values` (seed, value).
pub fn judge(check: &Check, values: &[(u64, Option<f64>)]) -> Judged {
    let worse = |a: f64, b: f64| match check.compare {
        Compare::AtMost => a > b,
        Compare::AtLeast => a < b,
    };
    // The worst seed: a missing value first, then the worst value.
    let mut worst: Option<(u64, Option<f64>)> = None;
    for &(seed, v) in values {
        worst = match (worst, v) {
            (None, _) => Some((seed, v)),
            (Some((_, None)), _) => worst,
            (Some(_), None) => Some((seed, None)),
            (Some((_, Some(w))), Some(x)) if worse(x, w) => Some((seed, v)),
            (w, _) => w,
        };
    }
    let failing_seeds = values.iter().filter(|(_, v)| !check.passes(*v)).count();
    let n = values.len();
    let (statistic, pass) = match check.stat {
        Stat::Percentile => {
            // A missing value counts as the worst.
            let bad = match check.compare {
                Compare::AtMost => f64::INFINITY,
                Compare::AtLeast => f64::NEG_INFINITY,
            };
            let mut v: Vec<f64> = values.iter().map(|(_, x)| x.unwrap_or(bad)).collect();
            v.sort_by(f64::total_cmp);
            let p = match check.compare {
                Compare::AtMost => nearest_rank(&v, 95.0),
                Compare::AtLeast => nearest_rank(&v, 5.0),
            };
            let p = p.filter(|x| x.is_finite());
            (p, check.passes(p))
        }
        Stat::Fraction(f) => {
            let frac = (n > 0).then(|| (n - failing_seeds) as f64 / n as f64);
            (frac, frac.is_some_and(|x| x >= f))
        }
        Stat::Every => (worst.and_then(|w| w.1), n > 0 && failing_seeds == 0),
    };
    Judged {
        seeds: n,
        statistic,
        pass,
        worst,
        failing_seeds,
    }
}

/// Every check of `case` judged over the rows of that case.
pub fn judge_case(case: &Case, rows: &[SeedRow]) -> Vec<Judged> {
    let mine: Vec<&SeedRow> = rows.iter().filter(|r| r.case == case.id).collect();
    case.checks
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let values: Vec<(u64, Option<f64>)> = mine
                .iter()
                .map(|r| (r.seed, r.values.get(k).copied().flatten()))
                .collect();
            judge(c, &values)
        })
        .collect()
}

/// What contradicts the table in `rows`: a case without rows, a row whose values do not
/// match its case's checks, a requirement that fails at its statistic without being `open`,
/// or an `open` one that holds (and should be closed).
pub fn consistency(rows: &[SeedRow]) -> Vec<String> {
    let mut problems = Vec::new();
    for case in &CASES {
        let mine = rows.iter().filter(|r| r.case == case.id).count();
        if mine == 0 {
            problems.push(format!("{}: no rows", case.id));
            continue;
        }
        for r in rows.iter().filter(|r| r.case == case.id) {
            if r.values.len() != case.checks.len() {
                problems.push(format!(
                    "{} seed {}: {} values for {} checks",
                    case.id,
                    r.seed,
                    r.values.len(),
                    case.checks.len()
                ));
            }
        }
        for (k, (c, j)) in case.checks.iter().zip(judge_case(case, rows)).enumerate() {
            let open = case.is_open(k);
            if !j.pass && !open {
                problems.push(format!(
                    "{} '{}': fails at its statistic over {} seeds and is not marked open",
                    case.id, c.what, j.seeds
                ));
            }
            if j.pass && open {
                problems.push(format!(
                    "{} '{}': holds at its statistic over {} seeds but is marked open",
                    case.id, c.what, j.seeds
                ));
            }
        }
    }
    for r in rows {
        if !CASES.iter().any(|c| c.id == r.case) {
            problems.push(format!("row of an unknown case {}", r.case));
        }
    }
    problems
}

#[cfg(test)]
mod tests {
    use super::*;

    const P95: Check = Check {
        what: "x",
        value: |_| None,
        compare: Compare::AtMost,
        threshold: 1.0,
        unit: "",
        stat: Stat::Percentile,
    };

    fn seeds(v: &[Option<f64>]) -> Vec<(u64, Option<f64>)> {
        v.iter().enumerate().map(|(k, x)| (k as u64, *x)).collect()
    }

    /// The 95th percentile of 20 values is the 19th smallest: one bad seed in 20 passes, two
    /// fail.
    #[test]
    fn percentile_allows_one_seed_in_twenty() {
        let mut v: Vec<Option<f64>> = (0..20).map(|k| Some(0.01 * k as f64)).collect();
        v[3] = Some(5.0);
        let j = judge(&P95, &seeds(&v));
        assert!(j.pass, "{j:?}");
        assert_eq!(j.worst, Some((3, Some(5.0))));
        v[4] = Some(4.0);
        let j = judge(&P95, &seeds(&v));
        assert!(!j.pass, "{j:?}");
        assert_eq!(j.statistic, Some(4.0));
        assert_eq!(j.failing_seeds, 2);
    }

    /// A missing value is the worst seed, and at the percentile it fails like an infinite
    /// error.
    #[test]
    fn missing_value_is_worst() {
        let j = judge(&P95, &seeds(&[Some(0.1), None]));
        assert!(!j.pass);
        assert_eq!(j.worst, Some((1, None)));
    }

    /// A fraction and the every-seed statistic on the same values.
    #[test]
    fn fraction_and_every() {
        let v = seeds(
            &[Some(1.0); 19]
                .iter()
                .copied()
                .chain([Some(0.0)])
                .collect::<Vec<_>>(),
        );
        let verdict = Check {
            compare: Compare::AtLeast,
            stat: Stat::Fraction(0.95),
            ..P95
        };
        let j = judge(&verdict, &v);
        assert!(j.pass);
        assert_eq!(j.statistic, Some(0.95));
        let every = Check {
            stat: Stat::Every,
            ..verdict
        };
        let j = judge(&every, &v);
        assert!(!j.pass);
        assert_eq!(j.worst, Some((19, Some(0.0))));
    }

    /// The release rows in the repository agree with the table: every requirement that fails
    /// at its statistic is marked open, every open one fails, every case has the same seeds
    /// and they include the CI tier's.
    #[test]
    fn release_rows_agree_with_the_table() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("..")
            .join(RELEASE_ROWS);
        let rows = match read_rows(&path) {
            Ok(r) => r,
            Err(e) => panic!("{e:#}: run `sim-host sil` (the release tier)"),
        };
        let problems = consistency(&rows);
        assert!(problems.is_empty(), "{}", problems.join("\n"));
        let seeds_of = |id: &str| {
            let mut v: Vec<u64> = rows
                .iter()
                .filter(|r| r.case == id)
                .map(|r| r.seed)
                .collect();
            v.sort_unstable();
            v
        };
        let first = seeds_of(CASES[0].id);
        let ci: Vec<u64> = acceptance_seeds(CI_SEEDS).collect();
        assert!(first.starts_with(&ci), "{first:?}");
        for case in &CASES {
            assert_eq!(seeds_of(case.id), first, "{}", case.id);
        }
    }

    /// Shards merged in any order give the rows of one run: sorted by case (table order) and
    /// seed.
    /// A row equal to its reference but for the wall time is no difference; a changed value
    /// or a row the reference lacks is.
    #[test]
    fn differences_ignore_the_wall_time_only() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("..")
            .join(RELEASE_ROWS);
        let rows = read_rows(&path).expect("release rows");
        let mut same = rows[0].clone();
        same.metrics.wall_time_s += 3.0;
        assert!(differences(&[same.clone()], &rows).is_empty());
        let mut changed = same.clone();
        changed.values[0] = Some(changed.values[0].unwrap_or(0.0) + 1e-12);
        assert_eq!(differences(&[changed], &rows).len(), 1);
        let mut absent = same;
        absent.seed = 1;
        assert_eq!(differences(&[absent], &rows).len(), 1);
    }

    #[test]
    fn merged_rows_are_in_table_order() {
        let row = |case: &str, seed| SeedRow {
            case: case.to_string(),
            seed,
            values: vec![Some(1.0), None],
            nav_mode: "Arrived".to_string(),
            metrics: RunMetrics::default(),
        };
        let (a, b) = (CASES[0].id, CASES[1].id);
        let shard1 = [row(b, 1002), row(a, 1001)];
        let shard2 = [row(a, 1002), row(b, 1001)];
        let merged: Vec<SeedRow> = shard2.iter().chain(&shard1).cloned().collect();
        let text = rows_text(&merged).unwrap();
        let order: Vec<(String, u64)> = text
            .lines()
            .map(|l| serde_json::from_str::<SeedRow>(l).unwrap())
            .map(|r| (r.case, r.seed))
            .collect();
        let want = [(a, 1001), (a, 1002), (b, 1001), (b, 1002)];
        assert_eq!(order, want.map(|(c, s)| (c.to_string(), s)).to_vec());
    }
}
