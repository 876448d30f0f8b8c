//! The results page `docs/results/sil-results.md`: its text is the template `page.md` (next to this
//! file); [`markdown`] fills in the table of checks, the count of force-model fallbacks and the
//! table of runs.

use super::{CaseResult, Compare};

/// The template of the page.
const PAGE: &str = include_str!("page.md");

/// The results as a Markdown page.
pub fn markdown(results: &[CaseResult]) -> String {
    let fallbacks: u64 = results
        .iter()
        .map(|r| r.summary.truth_force_fallbacks)
        .sum();
    let template = PAGE.strip_suffix('\n').unwrap_or(PAGE);
    let mut page = String::with_capacity(2 * template.len());
    let mut rest = template;
    for (key, value) in [
        ("{check_rows}", check_rows(results)),
        ("{fallbacks}", fallbacks.to_string()),
        ("{run_rows}", run_rows(results)),
    ] {
        let (before, after) = rest.split_once(key).unwrap_or((rest, ""));
        page += before;
        page += &value;
        rest = after;
    }
    page += rest;
    page
}

/// One row per check of every case.
fn check_rows(results: &[CaseResult]) -> String {
    let mut s = String::new();
    for r in results {
        let mut notes = r.case.variant.label();
        if r.case.no_slip_comp {
            notes = if notes.is_empty() {
                "no slip comp".to_string()
            } else {
                format!("no slip comp, {notes}")
            };
        }
        let scenario = if notes.is_empty() {
            r.case.scenario.to_string()
        } else {
            format!("{} ({notes})", r.case.scenario)
        };
        for c in &r.checks {
            let op = match c.check.compare {
                Compare::AtMost => "<=",
                Compare::AtLeast => ">=",
            };
            let value = c
                .value
                .map_or("-".to_string(), |v| format!("{v:.3} {}", c.check.unit));
            s += &format!(
                "| {} | {} | {} | {} | {op} {} {} | {} | {} |\n",
                r.case.id,
                scenario,
                c.check.what,
                if c.check.required {
                    "requirement"
                } else if c.check.open {
                    "requirement (open)"
                } else {
                    "goal"
                },
                c.check.threshold,
                c.check.unit,
                value.trim(),
                if c.pass { "pass" } else { "FAIL" }
            );
        }
    }
    s
}

/// One row per run: distances, errors, scrub, gate, VO and path.
fn run_rows(results: &[CaseResult]) -> String {
    let mut s = String::new();
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.2}"));
    for r in results {
        let m = &r.summary;
        s += &format!(
            "| {} | {:.2} | {:.1} | {} | {} | {} | {} | {} | {:.2} | {:.1}/{:+.1} | {} | {}/{} | {:.3}/{:.3} | {:.3} |\n",
            r.case.id,
            m.distance_m,
            m.sim_time_s,
            f(m.error_pct.ekf),
            f(m.error_pct.vo),
            f(m.error_pct.kin3d),
            f(m.error_pct.kin2d),
            f(m.distance_error_pct.kin3d),
            m.distance_error_pct.wheel_average,
            m.truth_scrub_pct,
            m.truth_scrub_net_pct,
            m.slip
                .gate_reject_fraction
                .map_or("-".to_string(), |x| format!("{:.0} %", 100.0 * x)),
            m.vo.updates.unwrap_or(0),
            m.vo.failures.unwrap_or(0),
            m.cross_track_m.rms,
            m.cross_track_m.max,
            m.goal_miss_m
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
        let at = |k: &str| {
            assert_eq!(PAGE.matches(k).count(), 1, "{k}");
            PAGE.find(k).unwrap_or(0)
        };
        assert!(at("{check_rows}") < at("{fallbacks}"));
        assert!(at("{fallbacks}") < at("{run_rows}"));
        assert!(PAGE.ends_with("{run_rows}\n"));
    }
}
