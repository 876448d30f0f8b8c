//! `DIR/report.html` of a campaign: self-contained (inline CSS and SVG, nothing fetched), a
//! pure function of the manifest and the statistics (no wall-clock figures), so local and
//! Slurm execution give the same page. Figures are drawn with `plotters` (SVG backend): per
//! criterion the empirical CDF of its metric with the threshold and the checked percentile
//! marked (a bar chart of the fraction of runs for a true/false metric).

use super::plan::Manifest;
use super::stats::{op_of, CriterionResult, Gathered, RunValue, Stats};
use plotters::coord::ranged1d::SegmentValue;
use plotters::prelude::*;
use std::fmt::Write as _;

/// Size of a criterion figure, pixels.
pub const FIGURE_SIZE: (u32, u32) = (640, 380);

fn esc(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A number for a table: 4 significant digits, exponent form outside 1e-3..1e4.
pub fn fmt_num(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-3..1e4).contains(&a) {
        return format!("{v:.3e}");
    }
    let digits = (3 - a.log10().floor() as i32).clamp(0, 6) as usize;
    format!("{v:.digits$}")
}

/// A unit for display (`-`, dimensionless, shows as nothing).
fn unit_text(unit: &str) -> String {
    if unit == "-" {
        String::new()
    } else {
        esc(unit)
    }
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or_else(|| "-".into(), fmt_num)
}

fn plot_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow::anyhow!("plot: {e:?}")
}

/// Decimals of tick labels for an axis spanning `range` with about 5 ticks.
fn tick_digits(range: f64) -> usize {
    if range <= 0.0 || !range.is_finite() {
        return 3;
    }
    (-(range / 5.0).log10()).ceil().clamp(0.0, 6.0) as usize
}

/// Whether every value is 0 or 1 (a true/false metric).
fn is_boolean(values: &[RunValue]) -> bool {
    values
        .iter()
        .filter_map(|r| r.value)
        .all(|v| v == 0.0 || v == 1.0)
}

/// The figure of one criterion (SVG text).
pub fn criterion_figure(c: &CriterionResult, values: &[RunValue]) -> anyhow::Result<String> {
    if c.stat == "mean" && is_boolean(values) {
        fraction_figure(c, values)
    } else {
        cdf_figure(c, values)
    }
}

fn cdf_figure(c: &CriterionResult, values: &[RunValue]) -> anyhow::Result<String> {
    let mut xs: Vec<f64> = values.iter().filter_map(|r| r.value).collect();
    xs.sort_by(f64::total_cmp);
    let lo = xs.first().copied().unwrap_or(c.threshold).min(c.threshold);
    let hi = xs.last().copied().unwrap_or(c.threshold).max(c.threshold);
    let pad = if hi > lo {
        0.06 * (hi - lo)
    } else {
        0.1 * hi.abs().max(1e-3)
    };
    let (x0, x1) = (lo - pad, hi + pad);
    let digits = tick_digits(x1 - x0);
    let n = xs.len().max(1) as f64;
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, FIGURE_SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{}: {} {} {}", c.name, c.stat, c.op, fmt_num(c.threshold)),
                ("sans-serif", 18),
            )
            .margin(12)
            .margin_right(30)
            .x_label_area_size(56)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, 0.0..1.0)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_labels(6)
            .y_labels(6)
            .x_label_formatter(&|v| format!("{v:.digits$}"))
            .y_label_formatter(&|v| format!("{v:.1}"))
            .x_desc(if c.unit == "-" {
                c.metric.clone()
            } else {
                format!("{} ({})", c.metric, c.unit)
            })
            .y_desc("fraction of runs <= x")
            .light_line_style(WHITE)
            .draw()
            .map_err(plot_err)?;
        // The empirical CDF as a staircase.
        let mut steps = vec![(x0, 0.0)];
        for (k, x) in xs.iter().enumerate() {
            steps.push((*x, k as f64 / n));
            steps.push((*x, (k + 1) as f64 / n));
        }
        steps.push((x1, if xs.is_empty() { 0.0 } else { 1.0 }));
        chart
            .draw_series(LineSeries::new(steps, BLUE.stroke_width(2)))
            .map_err(plot_err)?;
        let threshold_colour = RGBColor(200, 30, 30);
        chart
            .draw_series(DashedLineSeries::new(
                [(c.threshold, 0.0), (c.threshold, 1.0)],
                8,
                5,
                threshold_colour.stroke_width(2),
            ))
            .map_err(plot_err)?;
        if let Some(v) = c.value {
            let level = c
                .stat
                .strip_prefix('P')
                .and_then(|p| p.parse::<f64>().ok())
                .map(|p| p / 100.0);
            let marker = RGBColor(20, 120, 20);
            match level {
                Some(p) => {
                    chart
                        .draw_series(DashedLineSeries::new(
                            [(x0, p), (v, p)],
                            3,
                            3,
                            marker.stroke_width(1),
                        ))
                        .map_err(plot_err)?;
                    chart
                        .draw_series(std::iter::once(Circle::new((v, p), 5, marker.filled())))
                        .map_err(plot_err)?;
                }
                None => {
                    chart
                        .draw_series(DashedLineSeries::new(
                            [(v, 0.0), (v, 1.0)],
                            3,
                            3,
                            marker.stroke_width(2),
                        ))
                        .map_err(plot_err)?;
                }
            }
        }
        root.present().map_err(plot_err)?;
    }
    Ok(text)
}

fn fraction_figure(c: &CriterionResult, values: &[RunValue]) -> anyhow::Result<String> {
    let n = values.iter().filter(|r| r.value.is_some()).count().max(1) as f64;
    let ones = values.iter().filter(|r| r.value == Some(1.0)).count() as f64;
    let fractions = [(n - ones) / n, ones / n];
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, FIGURE_SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{}: fraction {} {}", c.name, c.op, fmt_num(c.threshold)),
                ("sans-serif", 18),
            )
            .margin(12)
            .margin_right(30)
            .x_label_area_size(56)
            .y_label_area_size(70)
            .build_cartesian_2d((0u32..1u32).into_segmented(), 0.0..1.0)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .y_labels(6)
            .y_label_formatter(&|v| format!("{v:.1}"))
            .x_label_formatter(&|v| match v {
                SegmentValue::CenterOf(0) => "false (0)".to_string(),
                SegmentValue::CenterOf(1) => "true (1)".to_string(),
                _ => String::new(),
            })
            .x_desc(c.metric.clone())
            .y_desc("fraction of runs")
            .light_line_style(WHITE)
            .draw()
            .map_err(plot_err)?;
        chart
            .draw_series(fractions.iter().enumerate().map(|(k, f)| {
                let k = k as u32;
                let colour = if k == 1 {
                    RGBColor(70, 130, 200)
                } else {
                    RGBColor(200, 140, 60)
                };
                let mut bar = Rectangle::new(
                    [
                        (SegmentValue::Exact(k), 0.0),
                        (SegmentValue::Exact(k + 1), *f),
                    ],
                    colour.filled(),
                );
                bar.set_margin(0, 0, 30, 30);
                bar
            }))
            .map_err(plot_err)?;
        chart
            .draw_series(DashedLineSeries::new(
                [
                    (SegmentValue::Exact(0), c.threshold),
                    (SegmentValue::Last, c.threshold),
                ],
                8,
                5,
                RGBColor(200, 30, 30).stroke_width(2),
            ))
            .map_err(plot_err)?;
        root.present().map_err(plot_err)?;
    }
    Ok(text)
}

/// The command that replays run `index` with every output, from the campaign folder.
pub fn replay_command(index: u64) -> String {
    format!("sim-host campaign run . --index {index} --outputs replay/{index}")
}

const STYLE: &str = "body{font-family:sans-serif;margin:24px;max-width:1400px;color:#222}\
table{border-collapse:collapse;margin:8px 0 20px}\
td,th{border:1px solid #bbb;padding:3px 8px;text-align:right;font-size:14px}\
th{background:#eee}td.l,th.l{text-align:left}\
.pass{background:#d8f0d8}.fail{background:#f6d0d0}.incomplete{background:#f6e8c0}\
.verdict{font-size:22px;padding:8px 14px;display:inline-block;border:1px solid #888}\
.figs{display:flex;flex-wrap:wrap;gap:16px}.fig{border:1px solid #ddd;padding:6px;width:640px}\
.fig p{max-width:640px;font-size:13px;margin:4px}code{font-size:13px}";

/// The report page.
pub fn report_html(manifest: &Manifest, gathered: &Gathered) -> anyhow::Result<String> {
    let s: &Stats = &gathered.stats;
    let spec = manifest.spec()?;
    let keys: Vec<String> = spec.dispersions.iter().map(|d| d.key()).collect();
    let mut h = String::new();
    header(&mut h, manifest, s)?;
    unfinished_runs(&mut h, manifest, s)?;
    criteria_table(&mut h, s)?;
    criteria_figures(&mut h, gathered)?;
    worst_runs(&mut h, manifest, s, &keys)?;
    metrics_table(&mut h, s)?;
    outcomes_table(&mut h, s)?;
    dispersions_table(&mut h, &spec, s)?;
    sensitivity_table(&mut h, s, &keys)?;
    let _ = writeln!(
        h,
        "<h2>Reproduce</h2>\n<p><code>sim-host campaign local {spec} --out DIR --runs {n}</code> \
         or on Slurm <code>sim-host campaign slurm {spec} --out DIR --runs {n} --submit</code>; \
         any single run: <code>sim-host campaign run DIR --index I</code>. \
         <code>stats.json</code> holds every figure of this page.</p>\n</body></html>",
        spec = esc(&manifest.spec_file),
        n = manifest.runs
    );
    Ok(h)
}

/// The title, the verdict and what the campaign ran.
fn header(h: &mut String, manifest: &Manifest, s: &Stats) -> anyhow::Result<()> {
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>campaign {name}</title>\
         <style>{STYLE}</style></head><body>\n<h1>Campaign {name}</h1>\n<p>{desc}</p>\n",
        name = esc(&s.campaign),
        desc = esc(&manifest.description)
    );
    let _ = writeln!(
        h,
        "<p class=\"verdict {v}\">verdict: <b>{V}</b></p>",
        v = esc(&s.verdict),
        V = esc(&s.verdict.to_uppercase())
    );
    let _ = writeln!(
        h,
        "<table><tr><th class=\"l\">base scenario</th><td class=\"l\">{} ({})</td></tr>\
         <tr><th class=\"l\">runs</th><td class=\"l\">{} planned, {} with a summary, {} failed, \
         {} missing</td></tr>\
         <tr><th class=\"l\">base seed</th><td class=\"l\">{}</td></tr>\
         <tr><th class=\"l\">execution</th><td class=\"l\">rendered stereo {}, slip compensation \
         {}, VO {}; flight clock counting simulated time</td></tr>\
         <tr><th class=\"l\">seeds</th><td class=\"l\">{}</td></tr>\
         <tr><th class=\"l\">percentiles</th><td class=\"l\">{}</td></tr></table>",
        esc(&s.scenario),
        esc(&manifest.scenario_file),
        s.runs_planned,
        s.runs_ok,
        s.failed_runs.len(),
        s.missing_runs.len(),
        s.base_seed,
        on_off(manifest.run.render),
        on_off(manifest.run.slip_compensation),
        on_off(manifest.run.vo),
        esc(&format!(
            "terrain {}, rover unit (calibration) {}; {}",
            seed_choice(&manifest.seeds.terrain),
            seed_choice(&manifest.seeds.calibration),
            manifest.seed_rule
        )),
        esc(&s.percentile_definition)
    );
    Ok(())
}

/// The runs that failed or left no summary (nothing when every run finished).
fn unfinished_runs(h: &mut String, manifest: &Manifest, s: &Stats) -> anyhow::Result<()> {
    if !s.failed_runs.is_empty() || !s.missing_runs.is_empty() {
        *h += "<h2>Runs that did not finish</h2>\n<table><tr><th>run</th><th>seed</th>\
              <th class=\"l\">state</th></tr>\n";
        for f in &s.failed_runs {
            let _ = writeln!(
                h,
                "<tr class=\"fail\"><td>{}</td><td>{}</td><td class=\"l\">failed: {}</td></tr>",
                f.index,
                f.seed,
                esc(&f.error)
            );
        }
        for i in &s.missing_runs {
            let seed = manifest.entries.get(*i as usize).map_or(0, |e| e.seed);
            let _ = writeln!(
                h,
                "<tr class=\"incomplete\"><td>{i}</td><td>{seed}</td><td class=\"l\">missing (no \
                 summary.json, no error.txt)</td></tr>"
            );
        }
        *h += "</table>\n";
    }
    Ok(())
}

/// The acceptance criteria and their results.
fn criteria_table(h: &mut String, s: &Stats) -> anyhow::Result<()> {
    *h += "<h2>Acceptance criteria</h2>\n<table><tr><th class=\"l\">criterion</th>\
          <th class=\"l\">metric</th><th>statistic</th><th>required</th><th>measured</th>\
          <th>at run</th><th>runs beyond</th><th>runs without value</th><th>result</th>\
          <th class=\"l\">source of the threshold</th></tr>\n";
    for c in &s.criteria {
        let _ = writeln!(
            h,
            "<tr class=\"{cls}\"><td class=\"l\">{}</td><td class=\"l\"><code>{}</code></td>\
             <td>{}</td><td>{} {} {}</td><td>{} {}</td><td>{}</td><td>{} of {}</td><td>{}</td>\
             <td><b>{}</b></td><td class=\"l\">{}</td></tr>",
            esc(&c.name),
            esc(&c.metric),
            esc(&c.stat),
            esc(&c.op),
            fmt_num(c.threshold),
            unit_text(&c.unit),
            fmt_opt(c.value),
            unit_text(&c.unit),
            c.value_run.map_or("-".into(), |r| r.to_string()),
            c.runs_beyond_threshold,
            c.n,
            c.null_runs.len(),
            if c.pass { "PASS" } else { "FAIL" },
            esc(&c.source),
            cls = if c.pass { "pass" } else { "fail" },
        );
    }
    *h += "</table>\n";
    Ok(())
}

/// One figure per criterion with its explanation.
fn criteria_figures(h: &mut String, gathered: &Gathered) -> anyhow::Result<()> {
    *h += "<div class=\"figs\">\n";
    let s: &Stats = &gathered.stats;
    for c in &s.criteria {
        let values = gathered
            .values
            .get(&c.metric)
            .map(Vec::as_slice)
            .unwrap_or(&[]);
        let svg = criterion_figure(c, values)?;
        let explain = if c.stat == "mean" && is_boolean(values) {
            format!(
                "Bars: fraction of runs with {m} false and true; red dashed: the required \
                 fraction {op} {t}.",
                m = esc(&c.metric),
                op = esc(&c.op),
                t = fmt_num(c.threshold)
            )
        } else if c.stat.starts_with('P') {
            format!(
                "Blue: empirical CDF of {m} over {n} runs; red dashed: threshold {t} {u}; \
                 green dot: {st} = {v} {u}.",
                m = esc(&c.metric),
                n = c.n,
                t = fmt_num(c.threshold),
                u = esc(&c.unit),
                st = esc(&c.stat),
                v = fmt_opt(c.value)
            )
        } else {
            format!(
                "Blue: empirical CDF of {m} over {n} runs; red dashed: threshold {t} {u}; green \
                 dashed: {st} = {v} {u}.",
                m = esc(&c.metric),
                n = c.n,
                t = fmt_num(c.threshold),
                u = esc(&c.unit),
                st = esc(&c.stat),
                v = fmt_opt(c.value)
            )
        };
        let _ = writeln!(h, "<div class=\"fig\">{svg}<p>{explain}</p></div>");
    }
    *h += "</div>\n";
    Ok(())
}

/// The worst runs of each criterion with their draws and replay commands.
fn worst_runs(
    h: &mut String,
    manifest: &Manifest,
    s: &Stats,
    keys: &[String],
) -> anyhow::Result<()> {
    *h += "<h2>Worst runs per criterion</h2>\n<p>Replay a run with every output (trajectories, \
          per-run report) from the campaign folder with the command shown; \
          <code>sim-host campaign run . --index I</code> alone rewrites its summary.</p>\n";
    for c in &s.criteria {
        let _ = write!(
            h,
            "<h3>{}</h3>\n<table><tr><th>run</th><th>seed</th><th>{}</th>",
            esc(&c.name),
            esc(&c.metric)
        );
        for k in keys {
            let _ = write!(h, "<th>{}</th>", esc(k));
        }
        *h += "<th class=\"l\">replay</th></tr>\n";
        let op = op_of(c);
        for w in &c.worst {
            let bad = w.value.is_none_or(|v| !op.holds(v, c.threshold));
            let _ = write!(
                h,
                "<tr{}><td>{}</td><td>{}</td><td>{}</td>",
                if bad { " class=\"fail\"" } else { "" },
                w.index,
                w.seed,
                w.value.map_or("null".into(), fmt_num)
            );
            let entry = manifest.entries.get(w.index as usize);
            for k in keys {
                let d = entry.and_then(|e| e.draws.get(k)).copied();
                let _ = write!(h, "<td>{}</td>", fmt_opt(d));
            }
            let _ = writeln!(
                h,
                "<td class=\"l\"><code>{}</code></td></tr>",
                esc(&replay_command(w.index))
            );
        }
        *h += "</table>\n";
    }
    Ok(())
}

/// The statistics of every metric.
fn metrics_table(h: &mut String, s: &Stats) -> anyhow::Result<()> {
    *h += "<h2>Statistics of the metrics</h2>\n<table><tr><th class=\"l\">metric</th><th>unit</th>\
          <th>n</th><th>null</th><th>mean</th><th>std</th><th>min</th><th>P50</th><th>P90</th>\
          <th>P95</th><th>P99</th><th>max</th><th>max at run</th></tr>\n";
    for m in &s.metrics {
        let p = |q: f64| {
            m.percentiles
                .iter()
                .find(|x| x.p == q)
                .map_or("-".into(), |x| fmt_num(x.value))
        };
        let _ = writeln!(
            h,
            "<tr><td class=\"l\"><code>{}</code></td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td></tr>",
            esc(&m.metric),
            esc(&m.unit),
            m.n,
            m.null_runs.len(),
            fmt_opt(m.mean),
            fmt_opt(m.std),
            m.min.as_ref().map_or("-".into(), |x| fmt_num(x.value)),
            p(50.0),
            p(90.0),
            p(95.0),
            p(99.0),
            m.max.as_ref().map_or("-".into(), |x| fmt_num(x.value)),
            m.max.as_ref().map_or("-".into(), |x| x.run.to_string()),
        );
    }
    *h += "</table>\n";
    Ok(())
}

/// The counts of each outcome field's values.
fn outcomes_table(h: &mut String, s: &Stats) -> anyhow::Result<()> {
    *h += "<h2>Outcomes</h2>\n<table><tr><th class=\"l\">field</th>\
          <th class=\"l\">value</th><th>runs</th></tr>\n";
    for (field, counts) in &s.outcomes {
        for (value, n) in counts {
            let _ = writeln!(
                h,
                "<tr><td class=\"l\"><code>{}</code></td><td class=\"l\">{}</td><td>{n}</td></tr>",
                esc(field),
                esc(value)
            );
        }
    }
    *h += "</table>\n";
    Ok(())
}

/// The dispersions and the range of their draws.
fn dispersions_table(h: &mut String, spec: &super::spec::Spec, s: &Stats) -> anyhow::Result<()> {
    *h +=
        "<h2>Dispersions</h2>\n<table><tr><th class=\"l\">name</th><th class=\"l\">parameters</th>\
          <th class=\"l\">applied as</th><th class=\"l\">distribution</th><th>min drawn</th>\
          <th>mean drawn</th><th>max drawn</th></tr>\n";
    for d in &spec.dispersions {
        let key = d.key();
        let range = s.draws.iter().find(|r| r.dispersion == key);
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">{}</td><td class=\"l\"><code>{}</code></td><td class=\"l\">{}\
             </td><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&key),
            esc(&d.params.join(", ")),
            match d.apply {
                super::spec::Apply::Set => "value",
                super::spec::Apply::Scale => "factor",
                super::spec::Apply::Offset => "offset",
            },
            esc(&describe(&d.dist)),
            range.map_or("-".into(), |r| fmt_num(r.min)),
            range.map_or("-".into(), |r| fmt_num(r.mean)),
            range.map_or("-".into(), |r| fmt_num(r.max)),
        );
    }
    *h += "</table>\n";
    Ok(())
}

/// The correlation of each criterion's metric with each dispersion's draw.
fn sensitivity_table(h: &mut String, s: &Stats, keys: &[String]) -> anyhow::Result<()> {
    if !s.sensitivity.is_empty() && !keys.is_empty() {
        *h += "<h2>Sensitivity</h2>\n<p>Pearson correlation of each criterion's metric with each \
              dispersion's draw (over the runs with a value; |r| near 1: that dispersion drives \
              the metric).</p>\n<table><tr><th class=\"l\">metric</th>";
        for k in keys {
            let _ = write!(h, "<th>{}</th>", esc(k));
        }
        *h += "</tr>\n";
        let mut metrics: Vec<&str> = Vec::new();
        for x in &s.sensitivity {
            if !metrics.contains(&x.metric.as_str()) {
                metrics.push(&x.metric);
            }
        }
        for m in metrics {
            let _ = write!(h, "<tr><td class=\"l\"><code>{}</code></td>", esc(m));
            for k in keys {
                let r = s
                    .sensitivity
                    .iter()
                    .find(|x| x.metric == m && &x.dispersion == k)
                    .and_then(|x| x.r);
                let _ = write!(
                    h,
                    "<td>{}</td>",
                    r.map_or("-".into(), |r| format!("{r:+.2}"))
                );
            }
            *h += "</tr>\n";
        }
        *h += "</table>\n";
    }
    Ok(())
}

fn on_off(b: bool) -> &'static str {
    if b {
        "on"
    } else {
        "off"
    }
}

fn seed_choice(c: &super::spec::SeedChoice) -> String {
    match c {
        super::spec::SeedChoice::PerRun => "per run (the run seed)".into(),
        super::spec::SeedChoice::Fixed(v) => format!("fixed {v}"),
    }
}

fn describe(d: &super::spec::Distribution) -> String {
    match *d {
        super::spec::Distribution::Uniform { min, max } => {
            format!("uniform [{}, {})", fmt_num(min), fmt_num(max))
        }
        super::spec::Distribution::Normal {
            mean,
            sigma,
            min,
            max,
        } => format!(
            "normal mean {} sigma {}, bounds [{}, {}]",
            fmt_num(mean),
            fmt_num(sigma),
            min.map_or("-inf".into(), fmt_num),
            max.map_or("+inf".into(), fmt_num)
        ),
    }
}
