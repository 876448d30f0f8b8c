//! `report.html`: one self-contained page with hand-written SVG plots (top view of the path and
//! the trajectories, cross-track error, slip, attitude and suspension, timing per rate group).
//! The page is a pure function of the run, so it is byte-identical for identical runs.

use crate::output::summary::Summary;
use crate::sim::{Estimates, Record, RunResult};
use std::fmt::Write as _;

const W: f64 = 640.0;
const H: f64 = 300.0;
const MARGIN: f64 = 50.0;

/// One line of a plot.
struct Series<'a> {
    name: &'a str,
    color: &'a str,
    dashed: bool,
    points: Vec<(f64, f64)>,
}

fn bounds(series: &[Series], extra: &[(f64, f64)]) -> (f64, f64, f64, f64) {
    let mut b = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in series.iter().flat_map(|s| s.points.iter()).chain(extra) {
        b = (b.0.min(x), b.1.max(x), b.2.min(y), b.3.max(y));
    }
    if !b.0.is_finite() {
        return (0.0, 1.0, 0.0, 1.0);
    }
    if b.1 - b.0 < 1e-9 {
        b.1 = b.0 + 1.0;
    }
    if b.3 - b.2 < 1e-9 {
        b = (b.0, b.1, b.2 - 0.5, b.3 + 0.5);
    }
    b
}

/// An SVG line plot; `equal` keeps the x and y scales equal (top view); `circles` are
/// `(x, y, radius)` in data units.
fn plot(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    equal: bool,
    circles: &[(f64, f64, f64)],
) -> String {
    let (mut x0, mut x1, mut y0, mut y1) = bounds(series, &[]);
    let pad_x = 0.05 * (x1 - x0);
    let pad_y = 0.08 * (y1 - y0);
    (x0, x1, y0, y1) = (x0 - pad_x, x1 + pad_x, y0 - pad_y, y1 + pad_y);
    let (pw, ph) = (W - 2.0 * MARGIN, H - 2.0 * MARGIN);
    let (mut sx, mut sy) = (pw / (x1 - x0), ph / (y1 - y0));
    if equal {
        let s = sx.min(sy);
        (sx, sy) = (s, s);
    }
    let px = |x: f64| MARGIN + (x - x0) * sx;
    let py = |y: f64| H - MARGIN - (y - y0) * sy;
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="11">"#
    );
    let _ = write!(
        s,
        r##"<rect x="{MARGIN}" y="{MARGIN}" width="{pw}" height="{ph}" fill="#fafafa" stroke="#999"/>"##
    );
    let _ = write!(
        s,
        r#"<text x="{}" y="20" text-anchor="middle" font-size="14">{title}</text>"#,
        W / 2.0
    );
    let _ = write!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">{x_label}</text>"#,
        W / 2.0,
        H - 12.0
    );
    let _ = write!(
        s,
        r#"<text x="14" y="{}" text-anchor="middle" transform="rotate(-90 14 {})">{y_label}</text>"#,
        H / 2.0,
        H / 2.0
    );
    for k in 0..=4 {
        let fx = x0 + (x1 - x0) * k as f64 / 4.0;
        let fy = y0 + (y1 - y0) * k as f64 / 4.0;
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{:.2}</text>"#,
            px(fx),
            H - MARGIN + 14.0,
            fx
        );
        if py(fy) >= MARGIN - 1.0 {
            let _ = write!(
                s,
                r#"<text x="{:.1}" y="{:.1}" text-anchor="end">{:.3}</text>"#,
                MARGIN - 4.0,
                py(fy) + 4.0,
                fy
            );
        }
    }
    for &(cx, cy, r) in circles {
        let (x, y) = (px(cx), py(cy));
        if (MARGIN..=W - MARGIN).contains(&x) && (MARGIN..=H - MARGIN).contains(&y) {
            let _ = write!(
                s,
                r##"<circle cx="{x:.1}" cy="{y:.1}" r="{:.1}" fill="#c8b49a" stroke="none"/>"##,
                (r * sx).max(0.5)
            );
        }
    }
    for (k, ser) in series.iter().enumerate() {
        // Decimate to at most ~1500 points per line.
        let step = (ser.points.len() / 1500).max(1);
        let mut d = String::new();
        for (j, &(x, y)) in ser.points.iter().step_by(step).enumerate() {
            let _ = write!(
                d,
                "{}{:.1},{:.1} ",
                if j == 0 { "M" } else { "L" },
                px(x),
                py(y)
            );
        }
        let dash = if ser.dashed {
            r#" stroke-dasharray="6,4""#
        } else {
            ""
        };
        let _ = write!(
            s,
            r#"<path d="{}" fill="none" stroke="{}" stroke-width="1.5"{dash}/>"#,
            d.trim_end(),
            ser.color
        );
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}" fill="{}">{}</text>"#,
            W - MARGIN - 110.0,
            MARGIN + 14.0 + 13.0 * k as f64,
            ser.color,
            ser.name
        );
    }
    s.push_str("</svg>");
    s
}

fn timing_bars(run: &RunResult) -> String {
    let max = run
        .timing
        .iter()
        .map(|g| g.max_us)
        .max()
        .unwrap_or(1)
        .max(1) as f64;
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{}" font-family="sans-serif" font-size="11">"#,
        40 + 30 * run.timing.len()
    );
    let _ = write!(
        s,
        r#"<text x="{}" y="18" text-anchor="middle" font-size="14">Flight executive: execution time per rate group (max, mean)</text>"#,
        W / 2.0
    );
    for (k, g) in run.timing.iter().enumerate() {
        let y = 30.0 + 30.0 * k as f64;
        let wmax = 400.0 * g.max_us as f64 / max;
        let wmean = 400.0 * g.mean_us as f64 / max;
        let _ = write!(
            s,
            r##"<text x="60" y="{:.1}" text-anchor="end">{}</text><rect x="70" y="{y:.1}" width="{wmax:.1}" height="10" fill="#e08a5a"/><rect x="70" y="{:.1}" width="{wmean:.1}" height="10" fill="#4a7fb0"/><text x="{:.1}" y="{:.1}">max {} us, mean {} us, {} runs, {} overruns</text>"##,
            y + 14.0,
            g.name,
            y + 11.0,
            75.0 + wmax.max(wmean),
            y + 14.0,
            g.max_us,
            g.mean_us,
            g.runs,
            g.overruns
        );
    }
    s.push_str("</svg>");
    s
}

/// The HTML report of `run`.
pub fn report_html(run: &RunResult, summary: &Summary) -> String {
    let r = &run.records;
    let series = |name, color, f: &dyn Fn(&crate::sim::Record) -> (f64, f64)| Series {
        name,
        color,
        dashed: false,
        points: r.iter().map(f).collect(),
    };
    let path = Series {
        name: "path",
        color: "#666",
        dashed: true,
        points: run.waypoints.iter().map(|w| (w[1], w[0])).collect(),
    };
    let truth = series("truth", "#d62728", &|x| (x.pos_m[1], x.pos_m[0]));
    let rocks: Vec<_> = run.rocks.iter().map(|k| (k[1], k[0], k[2])).collect();
    let est = |name, color, f: &dyn Fn(&Estimates) -> (f64, f64)| Series {
        name,
        color,
        dashed: false,
        points: r.iter().filter_map(|x| x.est.as_ref().map(f)).collect(),
    };
    let vo_top = Series {
        name: "VO",
        color: "#2ca02c",
        dashed: false,
        points: run
            .vo_checks
            .iter()
            .filter_map(|c| c.vo_pose.map(|(p, _)| (p[1], p[0])))
            .collect(),
    };
    let top = plot(
        "Top view: truth and flight estimates",
        "east (m)",
        "north (m)",
        &[
            path,
            truth,
            est("EKF", "#1f77b4", &|e| (e.ekf_pos_m[1], e.ekf_pos_m[0])),
            vo_top,
            est("kin3d", "#ff7f0e", &|e| (e.kin3d.0[1], e.kin3d.0[0])),
            est("kin2d", "#9467bd", &|e| (e.kin2d[1], e.kin2d[0])),
        ],
        true,
        &rocks,
    );
    // EKF errors against the truth with the filter's own 3-sigma bounds.
    let err_plot = |title: &str, unit: &str, f: &dyn Fn(&Record, &Estimates) -> (f64, f64)| {
        let pts: Vec<(f64, f64, f64)> = r
            .iter()
            .filter_map(|x| {
                x.est.as_ref().map(|e| {
                    let (err, sigma) = f(x, e);
                    (x.t_s, err, 3.0 * sigma)
                })
            })
            .collect();
        let line = |name, color, dashed, g: &dyn Fn(&(f64, f64, f64)) -> f64| Series {
            name,
            color,
            dashed,
            points: pts.iter().map(|p| (p.0, g(p))).collect(),
        };
        plot(
            title,
            "time (s)",
            unit,
            &[
                line("error", "#1f77b4", false, &|p| p.1),
                line("+3 sigma", "#999", true, &|p| p.2),
                line("-3 sigma", "#999", true, &|p| -p.2),
            ],
            false,
            &[],
        )
    };
    let ekf_north = err_plot("EKF north error and 3-sigma", "m", &|x, e| {
        (e.ekf_pos_m[0] - x.pos_m[0], e.ekf_pos_sigma_m[0])
    });
    let ekf_east = err_plot("EKF east error and 3-sigma", "m", &|x, e| {
        (e.ekf_pos_m[1] - x.pos_m[1], e.ekf_pos_sigma_m[1])
    });
    let ekf_heading = err_plot("EKF heading error and 3-sigma", "deg", &|x, e| {
        let yaw = |q: [f64; 4]| {
            let [qx, qy, qz, qw] = q;
            (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz))
        };
        let d = crate::world::wrap_pi(yaw(e.ekf_quat_xyzw) - yaw(x.quat_xyzw));
        (d.to_degrees(), e.ekf_heading_sigma_rad.to_degrees())
    });
    let flight_slip = plot(
        "Flight slip vector (EKF minus kinematics, per 50 ms cycle; 0 when the gate accepts)",
        "time (s)",
        "mm / mrad",
        &[
            est("x slip (mm)", "#1f77b4", &|e| (0.0, e.slip[0] * 1e3)),
            est("y slip (mm)", "#d62728", &|e| (0.0, e.slip[1] * 1e3)),
            est("yaw slip (mrad)", "#2ca02c", &|e| (0.0, e.slip[2] * 1e3)),
        ]
        .map(|mut s| {
            let times = r.iter().filter(|x| x.est.is_some()).map(|x| x.t_s);
            for (p, t) in s.points.iter_mut().zip(times) {
                p.0 = t;
            }
            s
        }),
        false,
        &[],
    );
    let vo_line = |name, color, dashed, g: &dyn Fn(&crate::sim::VoCheck) -> f64| Series {
        name,
        color,
        dashed,
        points: run.vo_checks.iter().map(|c| (c.t_s, g(c) * 1e3)).collect(),
    };
    let vo_errors = plot(
        "Flight VO relative-pose translation error per update and 3-sigma",
        "time (s)",
        "mm",
        &[
            vo_line("x error", "#1f77b4", false, &|c| c.trans_err_m[0]),
            vo_line("y error", "#d62728", false, &|c| c.trans_err_m[1]),
            vo_line("+3 sigma x", "#999", true, &|c| 3.0 * c.trans_sigma_m[0]),
            vo_line("-3 sigma x", "#999", true, &|c| -3.0 * c.trans_sigma_m[0]),
        ],
        false,
        &[],
    );
    let cross = plot(
        "Cross-track error of the true path",
        "time (s)",
        "m",
        &[series("truth", "#d62728", &|x| (x.t_s, x.cross_track_m))],
        false,
        &[],
    );
    let slip = plot(
        "True slip",
        "time (s)",
        "ratio / deg",
        &[
            series("slip ratio", "#1f77b4", &|x| (x.t_s, x.slip_ratio)),
            series("slip angle (deg/10)", "#2ca02c", &|x| {
                (x.t_s, x.slip_angle_rad.to_degrees() / 10.0)
            }),
        ],
        false,
        &[],
    );
    let attitude = plot(
        "True attitude and suspension",
        "time (s)",
        "deg",
        &[
            series("roll", "#1f77b4", &|x| (x.t_s, x.rpy_rad[0].to_degrees())),
            series("pitch", "#ff7f0e", &|x| (x.t_s, x.rpy_rad[1].to_degrees())),
            series("rocker", "#2ca02c", &|x| {
                (x.t_s, x.suspension_rad[0].to_degrees())
            }),
            series("bogie R", "#9467bd", &|x| {
                (x.t_s, x.suspension_rad[1].to_degrees())
            }),
            series("bogie L", "#8c564b", &|x| {
                (x.t_s, x.suspension_rad[2].to_degrees())
            }),
        ],
        false,
        &[],
    );
    // The embedded summary leaves out the wall-clock time so the page is reproducible.
    let mut value = serde_json::to_value(summary).unwrap_or_default();
    if let Some(map) = value.as_object_mut() {
        map.remove("wall_time_s");
    }
    let json = serde_json::to_string_pretty(&value).unwrap_or_default();
    let json = json.replace('&', "&amp;").replace('<', "&lt;");
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>sim-host: {name} seed {seed}</title>\
<style>body{{font-family:sans-serif;max-width:700px;margin:auto}} pre{{background:#f4f4f4;padding:8px}}</style></head><body>\n\
<h1>{name} (seed {seed})</h1>\n<p>{dist:.2} m travelled in {t:.1} s; goal {goal} (miss {miss:.3} m); \
cross-track rms {rms:.3} m, max {max:.3} m.</p>\n",
        name = run.scenario,
        seed = run.seed,
        dist = run.distance_m,
        t = run.sim_time_s,
        goal = if run.goal_reached { "reached" } else { "NOT reached" },
        miss = run.goal_miss_m,
        rms = summary.cross_track_m.rms,
        max = summary.cross_track_m.max,
    );
    for svg in [&top, &cross, &slip, &attitude] {
        html.push_str(svg);
        html.push('\n');
    }
    html.push_str("<h2>Flight estimates and 3-sigma bounds</h2>\n");
    for svg in [
        &ekf_north,
        &ekf_east,
        &ekf_heading,
        &flight_slip,
        &vo_errors,
    ] {
        html.push_str(svg);
        html.push('\n');
    }
    html.push_str(&timing_bars(run));
    let _ = write!(
        html,
        "\n<h2>summary.json</h2>\n<pre>{json}</pre>\n</body></html>\n"
    );
    html
}
