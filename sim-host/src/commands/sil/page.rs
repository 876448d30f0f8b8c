//! The results page `docs/results/sil-results.md`, made from the rows of a tier
//! ([`super::seeds::SeedRow`]): its text is the template `page.md` (next to this file);
//! [`markdown`] fills in the header figures, the table of checks at their statistics with the
//! worst seed of each, and the component metrics of each case over its seeds.

use super::seeds::{judge_case, SeedRow};
use super::{Compare, Stat, CASES};

/// The template of the page.
const PAGE: &str = include_str!("page.md");

/// Nearest-rank percentile `p` of the finite values.
fn pct(mut v: Vec<f64>, p: f64) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * v.len() as f64).ceil().max(1.0) as usize;
    v.get(rank.min(v.len()) - 1).copied()
}

fn f(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".to_string(), |x| format!("{x:.digits$}"))
}

/// The cases that have rows (every case for the release tier, one for `sil --case`).
fn present<'a>(rows: &'a [SeedRow]) -> impl Iterator<Item = &'static super::Case> + 'a {
    CASES
        .iter()
        .filter(move |c| rows.iter().any(|r| r.case == c.id))
}

/// Requirements, open ones (of the cases with rows), and the runs' summed wall time (s).
fn counts(rows: &[SeedRow]) -> (usize, usize, f64) {
    let checks: usize = present(rows).map(|c| c.checks.len()).sum();
    let open = present(rows)
        .map(|c| (0..c.checks.len()).filter(|&k| c.is_open(k)).count())
        .sum();
    let wall = rows.iter().map(|r| r.metrics.wall_time_s).sum();
    (checks, open, wall)
}

/// One line for the terminal.
pub fn digest(rows: &[SeedRow]) -> String {
    let (checks, _, wall) = counts(rows);
    let failing: usize = present(rows)
        .map(|c| judge_case(c, rows).iter().filter(|j| !j.pass).count())
        .sum();
    format!(
        "{} runs: {failing} of {checks} requirements fail at their statistic; runs' wall time \
         summed {:.1} min",
        rows.len(),
        wall / 60.0
    )
}

/// The results as a Markdown page; `commit` is the commit the rows were made from.
pub fn markdown(rows: &[SeedRow], commit: &str) -> String {
    let (checks, open, wall) = counts(rows);
    let mut seeds: Vec<u64> = rows.iter().map(|r| r.seed).collect();
    seeds.sort_unstable();
    seeds.dedup();
    let per_case = present(rows)
        .map(|c| rows.iter().filter(|r| r.case == c.id).count())
        .min()
        .unwrap_or(0);
    let template = PAGE.strip_suffix('\n').unwrap_or(PAGE);
    let mut page = String::with_capacity(2 * template.len());
    let mut rest = template;
    for (key, value) in [
        ("{commit}", commit.to_string()),
        ("{runs}", rows.len().to_string()),
        ("{per_case}", per_case.to_string()),
        (
            "{seed_range}",
            match (seeds.first(), seeds.last()) {
                (Some(a), Some(b)) => format!("{a}-{b}"),
                _ => "-".to_string(),
            },
        ),
        ("{wall_min}", format!("{:.0}", wall / 60.0)),
        ("{checks}", checks.to_string()),
        ("{open}", open.to_string()),
        ("{check_rows}", check_rows(rows)),
        ("{metric_rows}", metric_rows(rows)),
    ] {
        let (before, after) = rest.split_once(key).unwrap_or((rest, ""));
        page += before;
        page += &value;
        rest = after;
    }
    page += rest;
    page
}

/// One row per check of every case, at its statistic, with the worst seed.
fn check_rows(rows: &[SeedRow]) -> String {
    let mut s = String::new();
    for case in present(rows) {
        let mut notes = case.variant.label();
        if case.no_slip_comp {
            notes = if notes.is_empty() {
                "no slip comp".to_string()
            } else {
                format!("no slip comp, {notes}")
            };
        }
        let scenario = if notes.is_empty() {
            case.scenario.to_string()
        } else {
            format!("{} ({notes})", case.scenario)
        };
        for (k, (c, j)) in case.checks.iter().zip(judge_case(case, rows)).enumerate() {
            let op = match c.compare {
                Compare::AtMost => "<=",
                Compare::AtLeast => ">=",
            };
            let (stat, measured) = match c.stat {
                Stat::Percentile => (
                    match c.compare {
                        Compare::AtMost => "P95",
                        Compare::AtLeast => "P5",
                    }
                    .to_string(),
                    format!("{} {}", f(j.statistic, 3), c.unit),
                ),
                Stat::Fraction(x) => (
                    format!("seeds passing >= {:.0} %", 100.0 * x),
                    j.statistic
                        .map_or("-".to_string(), |v| format!("{:.0} % passing", 100.0 * v)),
                ),
                Stat::Every => (
                    "every seed".to_string(),
                    format!("worst {} {}", f(j.statistic, 3), c.unit),
                ),
            };
            let worst = j.worst.map_or("-".to_string(), |(seed, v)| {
                format!(
                    "{seed}: {} (`sil --case {} --seed {seed}`)",
                    f(v, 3),
                    case.id
                )
            });
            s += &format!(
                "| {} | {} | {} | {} | {op} {} {} | {} | {}/{} | {} | {} |\n",
                case.id,
                scenario,
                c.what,
                stat,
                c.threshold,
                c.unit,
                measured.trim(),
                j.failing_seeds,
                j.seeds,
                worst,
                match (j.pass, case.is_open(k)) {
                    (true, _) => "pass",
                    (false, true) => "FAIL (open)",
                    (false, false) => "FAIL",
                }
            );
        }
    }
    s
}

/// One row per case: the component metrics over its seeds (P50 / P95).
fn metric_rows(rows: &[SeedRow]) -> String {
    let mut s = String::new();
    for case in &CASES {
        let mine: Vec<&SeedRow> = rows.iter().filter(|r| r.case == case.id).collect();
        if mine.is_empty() {
            continue;
        }
        let col = |g: &dyn Fn(&SeedRow) -> Option<f64>| -> Vec<f64> {
            mine.iter().filter_map(|r| g(r)).collect()
        };
        let both = |g: &dyn Fn(&SeedRow) -> Option<f64>, d: usize| {
            let v = col(g);
            format!("{}/{}", f(pct(v.clone(), 50.0), d), f(pct(v, 95.0), d))
        };
        let median = |g: &dyn Fn(&SeedRow) -> Option<f64>, d: usize| f(pct(col(g), 50.0), d);
        let (upd, fail) = mine.iter().fold((0, 0), |(u, k), r| {
            (u + r.metrics.vo_updates, k + r.metrics.vo_failures)
        });
        let slip = format!(
            "{}/{}",
            median(&|r| r.metrics.slip_detection, 2),
            median(&|r| r.metrics.slip_false_alarm, 2)
        );
        s += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {}/{} |\n",
            case.id,
            mine.len(),
            both(&|r| r.metrics.ekf_pct, 2),
            both(&|r| r.metrics.vo_pct, 2),
            both(&|r| r.metrics.vo_raw_pct, 2),
            both(&|r| r.metrics.kin3d_pct, 2),
            both(&|r| r.metrics.kin_eq15_pct, 2),
            median(&|r| r.metrics.kin3d_dist_signed_pct, 2),
            median(&|r| r.metrics.kin_eq15_dist_signed_pct, 2),
            both(&|r| r.metrics.nees_pos_mean, 2),
            median(&|r| r.metrics.nees_pos_within_95, 2),
            median(&|r| r.metrics.nees_heading_within_95, 2),
            both(&|r| r.metrics.slip_rms_mm, 2),
            slip,
            upd,
            fail
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::PAGE;

    /// The page template has each placeholder once, in the order `markdown` fills them.
    #[test]
    fn template_placeholders_once_in_order() {
        let keys = [
            "{commit}",
            "{runs}",
            "{per_case}",
            "{seed_range}",
            "{wall_min}",
            "{checks}",
            "{open}",
            "{check_rows}",
            "{metric_rows}",
        ];
        let mut last = 0;
        for k in keys {
            assert_eq!(PAGE.matches(k).count(), 1, "{k}");
            let at = PAGE.find(k).unwrap_or(0);
            assert!(at >= last, "{k} out of order");
            last = at;
        }
    }
}
