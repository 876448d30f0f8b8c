//! `report.html`: one self-contained page of a run with figures drawn by `plotters`
//! ([`crate::figure`]): the top view at equal scale (path, truth, EKF, VO, kinematics, rocks),
//! the cross-track error, the EKF position and heading errors with the filter's own 3-sigma
//! bounds, the slip (flight estimate against truth), the slip gate (decisions over time, NIS
//! against the chi-square threshold), the flight slip vector, the VO relative-pose errors,
//! attitude and suspension, and the execution time per rate group. The page is a pure function
//! of the run, so it is byte-identical for identical runs.
//!
//! [`compare_figure`] draws the main command's figure in the style of H05 Fig. 9: the runs with
//! and without slip compensation on one equal-scale top view with the path.

use crate::closed_loop::{Estimates, Record, RunResult};
use crate::figure::{render, Figure, Layer, Mark, Stroke, YLabels, FIG_W};
use crate::output::summary::Summary;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::fmt::Write as _;

/// Height of the plotting area of the time-series figures, px.
const PLOT_H: u32 = 200;
/// Window of the flight slip estimate, records (20 Hz: 1 s).
const SLIP_WINDOW: usize = 20;
/// Smallest kinematic travel along the heading over [`SLIP_WINDOW`] for a slip estimate, m.
const SLIP_MIN_TRAVEL_M: f64 = 0.05;
/// Smallest NIS drawn on the log axis (a zero would have no logarithm).
const NIS_FLOOR: f64 = 1e-3;

const GREY: RGBColor = RGBColor(90, 90, 90);
const C_TRUTH: RGBColor = RGBColor(214, 39, 40);
const C_EKF: RGBColor = RGBColor(31, 119, 180);
const C_VO: RGBColor = RGBColor(44, 160, 44);
const C_KIN3D: RGBColor = RGBColor(255, 127, 14);
const C_KIN2D: RGBColor = RGBColor(148, 103, 189);
const C_ROCK: RGBColor = RGBColor(160, 130, 90);
const C_ACCEPT: RGBColor = RGBColor(120, 180, 120);
const C_REJECT: RGBColor = RGBColor(214, 39, 40);

/// Yaw of a quaternion `[x, y, z, w]` (`R` to `W`), rad.
fn yaw(q: [f64; 4]) -> f64 {
    let [qx, qy, qz, qw] = q;
    (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz))
}

/// A top view of points given as `(north, east)`: north to the right (east increasing down the
/// page) when the data extend mainly north-south, otherwise north up.
struct TopView {
    north_right: bool,
}

impl TopView {
    /// The orientation that puts the longer extent of `ne` along the wide page.
    fn for_points(ne: &[(f64, f64)]) -> Self {
        let span = |f: &dyn Fn(&(f64, f64)) -> f64| {
            let (lo, hi) = ne
                .iter()
                .map(f)
                .fold((f64::INFINITY, f64::NEG_INFINITY), |a, v| {
                    (a.0.min(v), a.1.max(v))
                });
            if hi >= lo {
                hi - lo
            } else {
                0.0
            }
        };
        Self {
            north_right: span(&|p| p.0) > 1.2 * span(&|p| p.1),
        }
    }

    fn xy(&self, (n, e): (f64, f64)) -> (f64, f64) {
        if self.north_right {
            (n, -e)
        } else {
            (e, n)
        }
    }

    fn line(&self, name: &str, c: RGBColor, stroke: Stroke, ne: &[(f64, f64)]) -> Layer {
        Layer::line(name, c, stroke, ne.iter().map(|&p| self.xy(p)).collect())
    }

    fn figure(&self, title: &str, layers: Vec<Layer>, rocks: &[[f64; 3]]) -> Figure {
        let mut f = Figure::new(title, "", "", 0);
        f.equal_scale = true;
        if self.north_right {
            f.x_desc = "north (m)".into();
            f.y_desc = "east (m), downwards".into();
            f.y_labels = YLabels::Negated;
        } else {
            f.x_desc = "east (m)".into();
            f.y_desc = "north (m)".into();
        }
        if !rocks.is_empty() {
            f.layers.push(Layer {
                name: Some("rocks".into()),
                color: C_ROCK,
                mark: Mark::Discs(
                    rocks
                        .iter()
                        .map(|r| {
                            let (x, y) = self.xy((r[0], r[1]));
                            (x, y, r[2])
                        })
                        .collect(),
                ),
            });
        }
        f.layers.extend(layers);
        f
    }
}

/// Estimate pairs `(record, estimates)` of the aligned part of the run.
fn estimates(r: &[Record]) -> impl Iterator<Item = (&Record, &Estimates)> {
    r.iter().filter_map(|x| x.est.as_ref().map(|e| (x, e)))
}

fn top_view_figure(run: &RunResult) -> anyhow::Result<String> {
    let r = &run.records;
    let path: Vec<(f64, f64)> = run.waypoints.iter().map(|w| (w[0], w[1])).collect();
    let truth: Vec<(f64, f64)> = r.iter().map(|x| (x.pos_m[0], x.pos_m[1])).collect();
    let est = |f: &dyn Fn(&Estimates) -> (f64, f64)| -> Vec<(f64, f64)> {
        estimates(r).map(|(_, e)| f(e)).collect()
    };
    let vo: Vec<(f64, f64)> = run
        .vo_checks
        .iter()
        .filter_map(|c| c.vo_pose.map(|(p, _)| (p[0], p[1])))
        .collect();
    let all: Vec<(f64, f64)> = path.iter().chain(&truth).copied().collect();
    let view = TopView::for_points(&all);
    let layers = vec![
        view.line("path", GREY, Stroke::Dashed, &path),
        view.line("truth", C_TRUTH, Stroke::Solid, &truth),
        view.line(
            "EKF",
            C_EKF,
            Stroke::Solid,
            &est(&|e| (e.ekf_pos_m[0], e.ekf_pos_m[1])),
        ),
        view.line("VO (chained)", C_VO, Stroke::Solid, &vo),
        view.line(
            "kin3d (3D kinematics)",
            C_KIN3D,
            Stroke::Dashed,
            &est(&|e| (e.kin3d.0[0], e.kin3d.0[1])),
        ),
        view.line(
            "kin2d (wheel odometry)",
            C_KIN2D,
            Stroke::Dotted,
            &est(&|e| (e.kin2d[0], e.kin2d[1])),
        ),
    ];
    render(&view.figure(
        "Top view at equal scale: path, truth and flight estimates",
        layers,
        &run.rocks,
    ))
}

/// An error plot with the filter's +-3 sigma band: `f` gives `(error, sigma)` per record.
fn error_figure(
    run: &RunResult,
    title: &str,
    unit: &str,
    f: &dyn Fn(&Record, &Estimates) -> (f64, f64),
) -> anyhow::Result<String> {
    let pts: Vec<(f64, f64, f64)> = estimates(&run.records)
        .map(|(x, e)| {
            let (err, sigma) = f(x, e);
            (x.t_s, err, 3.0 * sigma)
        })
        .collect();
    let mut fig = Figure::new(title, "time (s)", unit, PLOT_H);
    fig.y_include = vec![0.0];
    fig.layers = vec![
        Layer {
            name: Some("EKF ±3σ".into()),
            color: C_EKF,
            mark: Mark::Band {
                x: pts.iter().map(|p| p.0).collect(),
                lo: pts.iter().map(|p| -p.2).collect(),
                hi: pts.iter().map(|p| p.2).collect(),
            },
        },
        Layer::line(
            "EKF error",
            C_EKF,
            Stroke::Solid,
            pts.iter().map(|p| (p.0, p.1)).collect(),
        ),
    ];
    render(&fig)
}

/// Slip ratio and slip angle (rad) from the flight estimates over [`SLIP_WINDOW`] records:
/// the EKF's travel against the 3D kinematics' travel, along and across the EKF heading at the
/// window's end (`1 - along_ekf / along_kin`; the angle between the two travel directions,
/// positive to the right). Windows with less kinematic travel than [`SLIP_MIN_TRAVEL_M`] are
/// left out (standing still).
pub fn estimated_slip(records: &[Record]) -> Vec<(f64, f64, f64)> {
    let est: Vec<(&Record, &Estimates)> = estimates(records).collect();
    est.windows(SLIP_WINDOW + 1)
        .filter_map(|w| {
            let (a, b) = (w[0].1, w[SLIP_WINDOW].1);
            let psi = yaw(b.ekf_quat_xyzw);
            let (s, c) = psi.sin_cos();
            let along_across = |d: [f64; 2]| (c * d[0] + s * d[1], -s * d[0] + c * d[1]);
            let (el, ea) = along_across([
                b.ekf_pos_m[0] - a.ekf_pos_m[0],
                b.ekf_pos_m[1] - a.ekf_pos_m[1],
            ]);
            let (kl, ka) = along_across([b.kin3d.0[0] - a.kin3d.0[0], b.kin3d.0[1] - a.kin3d.0[1]]);
            (kl.abs() >= SLIP_MIN_TRAVEL_M).then(|| {
                let angle = crate::world::wrap_pi(ea.atan2(el) - ka.atan2(kl));
                (w[SLIP_WINDOW].0.t_s, 1.0 - el / kl, angle)
            })
        })
        .collect()
}

/// The true slip averaged over the same windows as [`estimated_slip`]:
/// `(t, slip ratio, slip angle rad)`.
pub(crate) fn true_slip(records: &[Record]) -> Vec<(f64, f64, f64)> {
    records
        .windows(SLIP_WINDOW + 1)
        .map(|w| {
            let n = w.len() as f64;
            (
                w[SLIP_WINDOW].t_s,
                w.iter().map(|x| x.slip_ratio).sum::<f64>() / n,
                w.iter().map(|x| x.slip_angle_rad).sum::<f64>() / n,
            )
        })
        .collect()
}

fn slip_figures(run: &RunResult) -> anyhow::Result<[String; 2]> {
    let est = estimated_slip(&run.records);
    let truth = true_slip(&run.records);
    let fig = |title: &str, unit: &str, k: usize, scale: f64| {
        let pick = |v: &(f64, f64, f64)| (v.0, if k == 1 { v.1 } else { v.2 } * scale);
        let mut f = Figure::new(title, "time (s)", unit, PLOT_H);
        f.y_include = vec![0.0];
        f.layers = vec![
            Layer::line(
                "truth (1 s mean)",
                C_TRUTH,
                Stroke::Solid,
                truth.iter().map(pick).collect(),
            ),
            Layer::line(
                "flight: EKF vs kin3d (1 s)",
                C_EKF,
                Stroke::Solid,
                est.iter().map(pick).collect(),
            ),
        ];
        render(&f)
    };
    Ok([
        fig(
            "Longitudinal slip ratio: flight estimate and truth",
            "slip ratio",
            1,
            1.0,
        )?,
        fig(
            "Slip angle: flight estimate and truth (positive: drift to the right)",
            "slip angle (deg)",
            2,
            1.0f64.to_degrees(),
        )?,
    ])
}

/// One decision of the slip gate: `(t, d2, dof, accepted)` for every record whose
/// `kin_tested` count grew (the last decision of that 50 ms record).
fn gate_decisions(records: &[Record]) -> Vec<(f64, f64, u8, bool)> {
    let mut last = 0;
    let mut out = Vec::new();
    for (x, e) in estimates(records) {
        if e.kin_tested > last {
            last = e.kin_tested;
            out.push((x.t_s, e.gate_d2, e.gate_dof, e.gate_accepted));
        }
    }
    out
}

fn gate_figures(run: &RunResult) -> anyhow::Result<[String; 2]> {
    let d = gate_decisions(&run.records);
    let t_end = run.records.last().map_or(1.0, |r| r.t_s).max(1.0);
    let bin = [1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0]
        .into_iter()
        .find(|b| t_end / b <= 60.0)
        .unwrap_or(200.0);
    let nbins = (t_end / bin).ceil() as usize;
    let mut counts = vec![(0u32, 0u32); nbins.max(1)];
    for &(t, _, _, ok) in &d {
        let k = ((t / bin) as usize).min(counts.len() - 1);
        if ok {
            counts[k].0 += 1;
        } else {
            counts[k].1 += 1;
        }
    }
    let gap = 0.1 * bin;
    let bars = |rejected: bool| -> Vec<[f64; 4]> {
        counts
            .iter()
            .enumerate()
            .filter(|(_, c)| if rejected { c.1 > 0 } else { c.0 > 0 })
            .map(|(k, c)| {
                let x0 = k as f64 * bin + gap;
                let (acc, rej) = (f64::from(c.0), f64::from(c.1));
                if rejected {
                    [x0, x0 + bin - 2.0 * gap, acc, acc + rej]
                } else {
                    [x0, x0 + bin - 2.0 * gap, 0.0, acc]
                }
            })
            .collect()
    };
    let (acc, rej) = d.iter().fold(
        (0, 0),
        |a, x| if x.3 { (a.0 + 1, a.1) } else { (a.0, a.1 + 1) },
    );
    let mut per_bin = Figure::new(
        &format!("Slip gate decisions per {bin:.0} s: {acc} accepted, {rej} rejected (H04 eq. 46)"),
        "time (s)",
        "kinematic intervals",
        PLOT_H,
    );
    per_bin.y_include = vec![0.0];
    per_bin.layers = vec![
        Layer {
            name: Some("accepted".into()),
            color: C_ACCEPT,
            mark: Mark::Bars(bars(false)),
        },
        Layer {
            name: Some("rejected (slip)".into()),
            color: C_REJECT,
            mark: Mark::Bars(bars(true)),
        },
    ];
    let log = |v: f64| v.max(NIS_FLOOR).log10();
    let pts = |ok: bool| -> Vec<(f64, f64)> {
        d.iter()
            .filter(|x| x.3 == ok)
            .map(|x| (x.0, log(x.1)))
            .collect()
    };
    let threshold: Vec<(f64, f64)> = d
        .iter()
        .filter_map(|x| fsw::estimation::gate::chi2_95(usize::from(x.2)).map(|c| (x.0, log(c))))
        .collect();
    let mut nis = Figure::new(
        "Slip gate NIS (Mahalanobis d², log scale) against the 95 % chi-square threshold",
        "time (s)",
        "d² (log scale)",
        PLOT_H + 40,
    );
    nis.y_labels = YLabels::Pow10;
    nis.layers = vec![
        Layer::points("accepted", C_ACCEPT, 2, pts(true)),
        Layer::points("rejected (slip)", C_REJECT, 2, pts(false)),
        Layer::line(
            "χ²(95 %, dof) threshold",
            RGBColor(0, 0, 0),
            Stroke::Dashed,
            threshold,
        ),
    ];
    Ok([render(&per_bin)?, render(&nis)?])
}

fn line_of<'a>(
    r: &'a [Record],
    name: &str,
    c: RGBColor,
    f: &dyn Fn(&Record) -> (f64, f64),
) -> Layer {
    Layer::line(name, c, Stroke::Solid, r.iter().map(f).collect())
}

fn timing_figure(run: &RunResult) -> anyhow::Result<String> {
    let rows = run.timing.len().max(1) as u32;
    let height = 44 + 30 * rows;
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, (FIG_W, height)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let body = root
            .titled(
                "Flight executive: execution time per rate group, max (orange) and mean (blue)",
                TextStyle::from(("sans-serif", 15.0 * 1.24).into_font()),
            )
            .map_err(plot_err)?;
        let max = run
            .timing
            .iter()
            .map(|g| g.max_us)
            .max()
            .unwrap_or(1)
            .max(1) as f64;
        let font = TextStyle::from(("sans-serif", 12.0 * 1.24).into_font());
        for (k, g) in run.timing.iter().enumerate() {
            let y = 8 + 30 * k as i32;
            let wmax = (400.0 * g.max_us as f64 / max).round() as i32;
            let wmean = (400.0 * g.mean_us as f64 / max).round() as i32;
            body.draw(&Text::new(
                g.name.clone(),
                (70, y + 8),
                font.pos(Pos::new(HPos::Right, VPos::Center)),
            ))
            .map_err(plot_err)?;
            body.draw(&Rectangle::new(
                [(80, y), (80 + wmax.max(1), y + 8)],
                RGBColor(224, 138, 90).filled(),
            ))
            .map_err(plot_err)?;
            body.draw(&Rectangle::new(
                [(80, y + 8), (80 + wmean.max(1), y + 16)],
                C_EKF.filled(),
            ))
            .map_err(plot_err)?;
            body.draw(&Text::new(
                format!(
                    "max {} us, mean {} us, {} runs, {} overruns",
                    g.max_us, g.mean_us, g.runs, g.overruns
                ),
                (90 + wmax.max(wmean), y + 8),
                font.pos(Pos::new(HPos::Left, VPos::Center)),
            ))
            .map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    Ok(text)
}

fn plot_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow::anyhow!("plot: {e:?}")
}

/// The figures of the page in order, with the section heading each starts (if any).
/// The figures of the report, each with the heading of the section it opens.
fn figures(run: &RunResult) -> anyhow::Result<Vec<(Option<&'static str>, String)>> {
    let mut out = vec![(Some("Trajectory"), top_view_figure(run)?)];
    out.push((None, cross_track_figure(run)?));
    out.push((
        Some("Flight estimates against the truth, with the EKF's 3σ bounds"),
        error_figure(run, "EKF north error and 3σ bound", "m", &|x, e| {
            (e.ekf_pos_m[0] - x.pos_m[0], e.ekf_pos_sigma_m[0])
        })?,
    ));
    out.push((
        None,
        error_figure(run, "EKF east error and 3σ bound", "m", &|x, e| {
            (e.ekf_pos_m[1] - x.pos_m[1], e.ekf_pos_sigma_m[1])
        })?,
    ));
    out.push((
        None,
        error_figure(run, "EKF heading error and 3σ bound", "deg", &|x, e| {
            let d = crate::world::wrap_pi(yaw(e.ekf_quat_xyzw) - yaw(x.quat_xyzw));
            (d.to_degrees(), e.ekf_heading_sigma_rad.to_degrees())
        })?,
    ));
    out.push((None, vo_error_figure(run)?));
    let [ratio, angle] = slip_figures(run)?;
    out.push((Some("Slip"), ratio));
    out.push((None, angle));
    out.push((None, flight_slip_figure(run)?));
    let [per_bin, nis] = gate_figures(run)?;
    out.push((Some("Slip gate"), per_bin));
    out.push((None, nis));
    out.push((Some("Vehicle"), attitude_figure(run)?));
    out.push((Some("Timing"), timing_figure(run)?));
    Ok(out)
}

/// The cross-track error of the true path.
fn cross_track_figure(run: &RunResult) -> anyhow::Result<String> {
    let r = &run.records;
    let mut cross = Figure::new(
        "Cross-track error of the true path",
        "time (s)",
        "m",
        PLOT_H,
    );
    cross.y_include = vec![0.0];
    cross.layers = vec![line_of(r, "truth", C_TRUTH, &|x| (x.t_s, x.cross_track_m))];
    render(&cross)
}

/// The flight VO relative-pose translation errors with their reported 3σ.
fn vo_error_figure(run: &RunResult) -> anyhow::Result<String> {
    let mut vo = Figure::new(
        "Flight VO relative-pose translation error per update and 3σ bound",
        "time (s)",
        "mm",
        PLOT_H,
    );
    vo.y_include = vec![0.0];
    let c = &run.vo_checks;
    vo.layers = vec![
        Layer {
            name: Some("±3σ x (reported)".into()),
            color: C_EKF,
            mark: Mark::Band {
                x: c.iter().map(|c| c.t_s).collect(),
                lo: c.iter().map(|c| -3e3 * c.trans_sigma_m[0]).collect(),
                hi: c.iter().map(|c| 3e3 * c.trans_sigma_m[0]).collect(),
            },
        },
        Layer::line(
            "x error",
            C_EKF,
            Stroke::Solid,
            c.iter().map(|c| (c.t_s, 1e3 * c.trans_err_m[0])).collect(),
        ),
        Layer::line(
            "y error",
            C_TRUTH,
            Stroke::Solid,
            c.iter().map(|c| (c.t_s, 1e3 * c.trans_err_m[1])).collect(),
        ),
    ];
    render(&vo)
}

/// The flight software's slip vector.
fn flight_slip_figure(run: &RunResult) -> anyhow::Result<String> {
    let r = &run.records;
    let mut flight_slip = Figure::new(
        "Flight slip vector (EKF minus kinematics per 50 ms cycle; 0 when the gate accepts)",
        "time (s)",
        "mm / mrad",
        PLOT_H,
    );
    flight_slip.y_include = vec![0.0];
    let sv = |k: usize| -> Vec<(f64, f64)> {
        estimates(r)
            .map(|(x, e)| (x.t_s, e.slip[k] * 1e3))
            .collect()
    };
    flight_slip.layers = vec![
        Layer::line("x slip (mm)", C_EKF, Stroke::Solid, sv(0)),
        Layer::line("y slip (mm)", C_TRUTH, Stroke::Solid, sv(1)),
        Layer::line("yaw slip (mrad)", C_VO, Stroke::Solid, sv(2)),
    ];
    render(&flight_slip)
}

/// The true attitude and suspension angles.
fn attitude_figure(run: &RunResult) -> anyhow::Result<String> {
    let r = &run.records;
    let mut attitude = Figure::new(
        "True attitude and suspension",
        "time (s)",
        "deg",
        PLOT_H + 40,
    );
    let deg = |f: fn(&Record) -> f64| move |x: &Record| (x.t_s, f(x).to_degrees());
    attitude.layers = vec![
        line_of(r, "roll", C_EKF, &deg(|x| x.rpy_rad[0])),
        line_of(r, "pitch", C_KIN3D, &deg(|x| x.rpy_rad[1])),
        line_of(r, "rocker", C_VO, &deg(|x| x.suspension_rad[0])),
        line_of(r, "bogie right", C_KIN2D, &deg(|x| x.suspension_rad[1])),
        line_of(
            r,
            "bogie left",
            RGBColor(140, 86, 75),
            &deg(|x| x.suspension_rad[2]),
        ),
    ];
    render(&attitude)
}

/// The HTML report of `run`.
pub fn report_html(run: &RunResult, summary: &Summary) -> anyhow::Result<String> {
    // The embedded summary leaves out the wall-clock time so the page is reproducible.
    let mut value = serde_json::to_value(summary)?;
    if let Some(map) = value.as_object_mut() {
        map.remove("wall_time_s");
    }
    let json = serde_json::to_string_pretty(&value)?;
    let json = json.replace('&', "&amp;").replace('<', "&lt;");
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>sim-host: {name} seed {seed}</title>\
<style>body{{font-family:sans-serif;max-width:{w}px;margin:auto;padding:0 8px}} \
svg{{display:block;margin:6px 0 14px 0}} pre{{background:#f4f4f4;padding:8px;overflow-x:auto}}</style></head><body>\n\
<h1>{name} (seed {seed})</h1>\n<p>{dist:.2} m travelled in {t:.1} s; goal {goal} (miss {miss:.3} m); \
cross-track rms {rms:.3} m, max {max:.3} m; driver {driver}, slip compensation {comp}.</p>\n",
        w = FIG_W + 20,
        name = run.scenario,
        seed = run.seed,
        dist = run.distance_m,
        t = run.sim_time_s,
        goal = if run.goal_reached { "reached" } else { "NOT reached" },
        miss = run.goal_miss_m,
        rms = summary.cross_track_m.rms,
        max = summary.cross_track_m.max,
        driver = run.driver,
        comp = if run.slip_compensation { "on" } else { "off" },
    );
    let o = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |x| format!("{x:.d$}"));
    let _ = writeln!(
        html,
        "<p>Components (error / distance, %): EKF {}, VO {}, VO raw {}, 3D kinematics {}, \
         H04 eq. 15 alone {}; EKF NEES mean position {} (2 when consistent), heading {} (1), \
         time within the 95 % bounds {} / {}; slip vector against the true slip rms {} m, \
         gate detection {} and false alarm {} (<code>docs/sil.md</code>).</p>",
        o(summary.error_pct.ekf, 2),
        o(summary.error_pct.vo, 2),
        o(summary.vo_raw.error_pct, 2),
        o(summary.error_pct.kin3d, 2),
        o(summary.kin_eq15.error_pct, 2),
        o(summary.nees.position_mean, 2),
        o(summary.nees.heading_mean, 2),
        o(summary.nees.position_within_95, 2),
        o(summary.nees.heading_within_95, 2),
        o(
            summary
                .slip_vs_truth
                .rms_m
                .map(|[x, y]| (0.5 * (x * x + y * y)).sqrt()),
            4
        ),
        o(summary.slip_vs_truth.detection, 2),
        o(summary.slip_vs_truth.false_alarm, 2),
    );
    for (heading, svg) in figures(run)? {
        if let Some(h) = heading {
            let _ = writeln!(html, "<h2>{h}</h2>");
        }
        html.push_str(&svg);
        html.push('\n');
    }
    let _ = write!(
        html,
        "<h2>summary.json</h2>\n<pre>{json}</pre>\n</body></html>\n"
    );
    Ok(html)
}

/// The main command's figure in the style of H05 Fig. 9 (tilt table, 4.5 m on a 10 deg slope):
/// the run with slip compensation and the run without it on one equal-scale top view with the
/// path; for each run the truth, the chained VO poses and the 3D kinematic odometry (their
/// constant offset is the slip).
pub fn compare_figure(comp: &RunResult, no_comp: &RunResult) -> anyhow::Result<String> {
    type Track = Vec<(f64, f64)>;
    let ne = |r: &RunResult| -> (Track, Track, Track) {
        (
            r.records.iter().map(|x| (x.pos_m[0], x.pos_m[1])).collect(),
            r.vo_checks
                .iter()
                .filter_map(|c| c.vo_pose.map(|(p, _)| (p[0], p[1])))
                .collect(),
            estimates(&r.records)
                .map(|(_, e)| (e.kin3d.0[0], e.kin3d.0[1]))
                .collect(),
        )
    };
    let path: Vec<(f64, f64)> = comp.waypoints.iter().map(|w| (w[0], w[1])).collect();
    let (ct, cv, ck) = ne(comp);
    let (nt, nv, nk) = ne(no_comp);
    let all: Vec<(f64, f64)> = path.iter().chain(&ct).chain(&nt).copied().collect();
    let view = TopView::for_points(&all);
    let layers = vec![
        view.line("path", GREY, Stroke::Dashed, &path),
        view.line(
            "compensated: truth",
            RGBColor(31, 119, 180),
            Stroke::Solid,
            &ct,
        ),
        view.line(
            "compensated: VO",
            RGBColor(23, 190, 207),
            Stroke::Dashed,
            &cv,
        ),
        view.line(
            "compensated: kinematics",
            RGBColor(44, 160, 44),
            Stroke::Dotted,
            &ck,
        ),
        view.line(
            "uncompensated: truth",
            RGBColor(214, 39, 40),
            Stroke::Solid,
            &nt,
        ),
        view.line(
            "uncompensated: VO",
            RGBColor(255, 127, 14),
            Stroke::Dashed,
            &nv,
        ),
        view.line(
            "uncompensated: kinematics",
            RGBColor(148, 103, 189),
            Stroke::Dotted,
            &nk,
        ),
    ];
    render(&view.figure(
        &format!(
            "H05 Fig. 9 style: {} seed {}, with and without slip compensation (equal scale)",
            comp.scenario, comp.seed
        ),
        layers,
        &[],
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records of a rover heading `psi` whose wheels (kin3d) travel 0.1 m/s straight ahead
    /// while the EKF sees `1 - s` of that along the heading and `tan(alpha)` times that to the
    /// right (slip ratio `s` of the longitudinal speed, slip angle `alpha`).
    fn drive(psi: f64, s: f64, alpha: f64) -> Vec<Record> {
        let (sp, cp) = psi.sin_cos();
        let q = [0.0, 0.0, (0.5 * psi).sin(), (0.5 * psi).cos()];
        (0..60)
            .map(|k| {
                let d = 0.005 * k as f64;
                let g = (1.0 - s) * d / alpha.cos();
                let (sg, cg) = (psi + alpha).sin_cos();
                Record {
                    t_s: 0.05 * k as f64,
                    pos_m: [g * cg, g * sg, 0.0],
                    quat_xyzw: q,
                    rpy_rad: [0.0, 0.0, psi],
                    suspension_rad: [0.0; 3],
                    slip_ratio: s,
                    slip_angle_rad: alpha,
                    cross_track_m: 0.0,
                    distance_m: g,
                    wheel_average_m: d,
                    est: Some(Estimates {
                        ekf_pos_m: [g * cg, g * sg, 0.0],
                        ekf_quat_xyzw: q,
                        ekf_pos_sigma_m: [0.01; 3],
                        ekf_heading_sigma_rad: 0.01,
                        ekf_pos_cov_ne: [1e-4, 0.0, 1e-4],
                        vo: None,
                        kin3d: ([d * cp, d * sp, 0.0], q),
                        kin2d: [d * cp, d * sp, psi],
                        dr: ([d * cp, d * sp, 0.0], q),
                        slip: [0.0; 3],
                        gate_accepted: true,
                        kin_tested: k,
                        gate_d2: 1.0,
                        gate_dof: 5,
                    }),
                    kin_eq15: None,
                }
            })
            .collect()
    }

    #[test]
    fn report_estimated_slip_recovers_ratio_and_angle() {
        for psi in [0.0, 1.0, -2.5] {
            let r = drive(psi, 0.2, 4f64.to_radians());
            let est = estimated_slip(&r);
            assert_eq!(est.len(), r.len() - SLIP_WINDOW);
            for (_, ratio, angle) in est {
                assert!((ratio - 0.2).abs() < 1e-9, "{ratio}");
                assert!(
                    (angle.to_degrees() - 4.0).abs() < 1e-9,
                    "{}",
                    angle.to_degrees()
                );
            }
        }
        // Standing still: no estimate.
        let mut r = drive(0.0, 0.0, 0.0);
        for x in &mut r {
            if let Some(e) = x.est.as_mut() {
                e.kin3d.0 = [0.0; 3];
            }
        }
        assert!(estimated_slip(&r).is_empty());
    }

    #[test]
    fn report_gate_decisions_one_per_new_test() {
        let mut r = drive(0.0, 0.0, 0.0);
        for (k, x) in r.iter_mut().enumerate() {
            let e = x.est.as_mut().unwrap();
            e.kin_tested = (k / 2) as u32; // a new decision every other record
            e.gate_accepted = k % 4 != 0;
        }
        let d = gate_decisions(&r);
        assert_eq!(d.len(), 29);
        assert!(d
            .iter()
            .all(|x| x.3 == ((x.0 / 0.05).round() as usize % 4 != 0)));
    }
}
