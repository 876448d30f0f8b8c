//! The per-run report, the main command's H05 Fig. 9 figure and the TUM outputs of a real
//! closed-loop run of `slope-10-cross` (rendered stereo, so VO delivers), with and without slip
//! compensation: the figures' geometry (equal scale of the top views, no overlapping labels,
//! no text on the plotting areas), the page's determinism, and that every stamp of every
//! estimate TUM file is a stamp of `truth.tum` (what `evo_ape tum truth.tum X.tum` needs).

use sim_host::closed_loop::{run, RunOptions, RunResult};
use sim_host::devices::renderer::{StereoRenderer, TexturedRenderer};
use sim_host::devices::world::CounterMode;
use sim_host::figure::{overlapping_texts, plot_geometry, svg_elements, svg_texts, tick_scales};
use sim_host::scenario::Scenario;
use std::path::Path;
use std::sync::OnceLock;

/// The two runs (with, without slip compensation), run once for all tests of this file.
fn runs() -> &'static (RunResult, RunResult) {
    static RUNS: OnceLock<(RunResult, RunResult)> = OnceLock::new();
    RUNS.get_or_init(|| {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/slope-10-cross.toml");
        let scenario = Scenario::load(&path).unwrap();
        let one = |no_slip_comp: bool| {
            let sun = scenario.site.sun_w(0.0);
            let renderer: Box<dyn StereoRenderer> = Box::new(TexturedRenderer::new(
                sim_host::devices::hazcam_calibration(),
                scenario.seed,
                [sun.x, sun.y, sun.z],
            ));
            run(
                &scenario,
                RunOptions {
                    no_slip_comp,
                    counter: CounterMode::SimTime,
                    renderer: Some(renderer),
                    ..RunOptions::default()
                },
            )
            .unwrap()
        };
        (one(false), one(true))
    })
}

/// Geometry checks common to every figure: no two labels overlap, no text on the plotting area
/// (legends sit in their own strip), and for top views (`equal`) the same metres per pixel in
/// x and y, from the declared ranges and from the tick labels as drawn (1 %).
fn check_figure(svg: &str, what: &str, equal: bool) {
    let overlaps = overlapping_texts(svg);
    assert!(
        overlaps.is_empty(),
        "{what}: overlapping labels: {:?}",
        overlaps
            .iter()
            .map(|(a, b)| (&a.text, a.bbox, &b.text, b.bbox))
            .collect::<Vec<_>>()
    );
    let Some(g) = plot_geometry(svg) else {
        assert!(!equal, "{what}: no plot geometry");
        return;
    };
    let [x0, x1, y0, y1] = g.plot_px;
    for t in svg_texts(svg) {
        let b = t.bbox;
        let inside = b[2] > x0 + 0.5 && b[0] < x1 - 0.5 && b[3] > y0 + 0.5 && b[1] < y1 - 0.5;
        assert!(
            !inside,
            "{what}: text {:?} {:?} on the plotting area {:?}",
            t.text, b, g.plot_px
        );
    }
    if equal {
        let (ux, uy) = g.units_per_px();
        assert!((ux / uy - 1.0).abs() < 0.01, "{what}: m/px x {ux} y {uy}");
        let (sx, sy) = tick_scales(svg).expect("tick labels on both axes");
        assert!(
            (sx / sy - 1.0).abs() < 0.01,
            "{what}: px/m from ticks x {sx} y {sy}"
        );
        assert!(
            ((1.0 / sx) / ux - 1.0).abs() < 0.01,
            "{what}: ticks {sx} px/m, range {ux} m/px"
        );
    }
}

#[test]
fn report_page_figures_equal_scale_no_overlaps_deterministic() {
    let (comp, _) = runs();
    let summary = sim_host::output::summary::summarise(comp);
    let html = sim_host::output::report::report_html(comp, &summary).unwrap();
    assert_eq!(
        html,
        sim_host::output::report::report_html(comp, &summary).unwrap()
    );
    let svgs = svg_elements(&html);
    assert!(svgs.len() >= 12, "{} figures", svgs.len());
    for (k, svg) in svgs.iter().enumerate() {
        check_figure(svg, &format!("figure {k}"), k == 0);
    }
    // The top view is the first figure: equal scale, and the 4.5 m path spans most of its
    // width (north to the right) instead of a sliver.
    let top = plot_geometry(svgs[0]).unwrap();
    let (ux, _) = top.units_per_px();
    let path_px = 4.5 / ux;
    let width_px = top.plot_px[1] - top.plot_px[0];
    assert!(path_px > 0.8 * width_px, "path {path_px} px of {width_px}");
    let titles: Vec<String> = svgs
        .iter()
        .filter_map(|s| svg_texts(s).into_iter().next().map(|t| t.text))
        .collect();
    for want in [
        "3σ",
        "Slip angle",
        "NIS",
        "decisions",
        "attitude",
        "rate group",
    ] {
        assert!(
            titles.iter().any(|t| t.contains(want)),
            "no figure titled {want}: {titles:?}"
        );
    }
}

#[test]
fn report_compare_figure_both_runs_equal_scale() {
    let (comp, no_comp) = runs();
    let svg = sim_host::output::report::compare_figure(comp, no_comp).unwrap();
    check_figure(&svg, "compare figure", true);
    let g = plot_geometry(&svg).unwrap();
    let legend: Vec<String> = svg_texts(&svg).into_iter().map(|t| t.text).collect();
    for want in [
        "compensated: truth",
        "uncompensated: truth",
        "uncompensated: VO",
        "path",
    ] {
        assert!(
            legend.iter().any(|t| t == want),
            "{want} missing: {legend:?}"
        );
    }
    // The uncompensated run drifts downhill (east) by more than the compensated one, and the
    // figure's east range holds both ends.
    let east_end = |r: &RunResult| r.records.last().unwrap().pos_m[1];
    assert!(east_end(no_comp) > east_end(comp) + 0.1);
    // North to the right: y = -east.
    assert!(g.y_range[0] < -east_end(no_comp));
}

#[test]
fn report_tum_every_estimate_stamp_is_a_truth_stamp() {
    let (comp, _) = runs();
    let dir = std::env::temp_dir().join(format!("sim-host-report-tum-{}", std::process::id()));
    sim_host::output::write_all(&dir, comp).unwrap();
    let stamps = |name: &str| -> Vec<String> {
        std::fs::read_to_string(dir.join(name))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .map(|l| {
                let f: Vec<&str> = l.split_whitespace().collect();
                assert_eq!(f.len(), 8, "{name}: {l}");
                f[0].to_string()
            })
            .collect()
    };
    let truth = stamps("truth.tum");
    let truth_t: Vec<f64> = truth.iter().map(|s| s.parse().unwrap()).collect();
    assert!(
        truth_t.windows(2).all(|w| w[1] > w[0]),
        "truth stamps not increasing"
    );
    let set: std::collections::BTreeSet<&String> = truth.iter().collect();
    for name in ["ekf.tum", "vo.tum", "kin3d.tum", "kin2d.tum", "dr.tum"] {
        let s = stamps(name);
        assert!(s.len() > 20, "{name}: {} poses", s.len());
        for t in &s {
            assert!(set.contains(t), "{name}: stamp {t} not in truth.tum");
            // evo's default association tolerance.
            let v: f64 = t.parse().unwrap();
            let near = truth_t
                .iter()
                .map(|u| (u - v).abs())
                .fold(f64::INFINITY, f64::min);
            assert!(near <= 0.01, "{name}: {t} is {near} s from truth");
        }
    }
    // VO captures are off the 20 Hz record times, so the truth has more stamps than records.
    assert!(truth.len() > comp.records.len());
    let _ = std::fs::remove_dir_all(&dir);
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The slip figures' flight estimate (EKF travel against the 3D kinematics over 1 s) follows
/// the true slip angle of the cross-slope drive: medians within 1 deg over the drive (the true
/// slip angle is about 3.5 deg with compensation). The slip ratio estimate carries the
/// kinematics' calibration error (wheel radius), so only its sign is checked.
#[test]
fn report_slip_estimate_follows_true_slip_angle() {
    let (comp, _) = runs();
    let est = sim_host::output::report::estimated_slip(&comp.records);
    assert!(est.len() > 500, "{} windows", est.len());
    let t0 = est[0].0 + 5.0;
    let t1 = est.last().unwrap().0 - 5.0;
    let est_angle = median(
        est.iter()
            .filter(|e| e.0 > t0 && e.0 < t1)
            .map(|e| e.2.to_degrees())
            .collect(),
    );
    let true_angle = median(
        comp.records
            .iter()
            .filter(|r| r.t_s > t0 && r.t_s < t1)
            .map(|r| r.slip_angle_rad.to_degrees())
            .collect(),
    );
    let est_ratio = median(
        est.iter()
            .filter(|e| e.0 > t0 && e.0 < t1)
            .map(|e| e.1)
            .collect(),
    );
    let true_ratio = median(
        comp.records
            .iter()
            .filter(|r| r.t_s > t0 && r.t_s < t1)
            .map(|r| r.slip_ratio)
            .collect(),
    );
    eprintln!(
        "slip angle median: flight {est_angle:.2} deg, truth {true_angle:.2} deg; \
         slip ratio median: flight {est_ratio:.3}, truth {true_ratio:.3}"
    );
    assert!(true_angle > 2.0, "{true_angle}");
    assert!((est_angle - true_angle).abs() < 1.0);
    assert!(est_ratio > 0.0 && true_ratio > 0.0);
}
