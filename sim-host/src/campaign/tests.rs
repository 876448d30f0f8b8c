//! Tests of the campaign steps: seeds, draws, parameters, statistics, figures, and a small
//! campaign end to end (plan, runs in parallel and one by one, gather, missing and failed
//! runs).

use super::plan::{self, Manifest};
use super::spec::{Criterion, Op, Spec};
use super::stats::{self, RunValue};
use super::{exec, html, params, svg_labels};
use crate::scenario::Scenario;
use std::path::{Path, PathBuf};

fn scenario_text(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scenarios")
        .join(format!("{name}.toml"));
    std::fs::read_to_string(path).unwrap()
}

fn scenario(name: &str) -> Scenario {
    Scenario::from_toml(&scenario_text(name)).unwrap()
}

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sim-host-campaign-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn campaign_seeds_are_splitmix64() {
    // The first outputs of SplitMix64 started at 0 (Vigna's splitmix64.c).
    assert_eq!(super::run_seed(0, 0), 0xE220_A839_7B1D_CDAF);
    assert_eq!(super::run_seed(0, 1), 0x6E78_9E6A_A1B9_65F4);
    assert_eq!(super::run_seed(0, 2), 0x06C4_5D18_8009_454F);
    // Distinct over many indices and base seeds.
    let mut all: Vec<u64> = (0..3)
        .flat_map(|b| (0..1000).map(move |i| super::run_seed(b, i)))
        .collect();
    all.sort_unstable();
    all.dedup();
    assert_eq!(all.len(), 3000);
    assert_eq!(super::fnv1a64(""), 0xcbf2_9ce4_8422_2325);
    assert_eq!(super::fnv1a64("a"), 0xaf63_dc4c_8601_ec8c);
}

const SPEC: &str = r#"
name = "unit"
scenario = "slope-10-cross.toml"
runs = 40
base_seed = 7

[[dispersion]]
name = "phi"
params = ["soil.friction_angle_deg"]
apply = "offset"
dist = { kind = "normal", mean = 0.0, sigma = 2.0, min = -3.0, max = 3.0 }

[[dispersion]]
name = "slope"
params = ["terrain.slope_deg"]
dist = { kind = "uniform", min = 8.0, max = 12.0 }

[[dispersion]]
name = "imu"
params = ["sensors.imu.gyro_noise_rad_s", "sensors.imu.accel_noise_m_s2"]
apply = "scale"
dist = { kind = "uniform", min = 0.5, max = 2.0 }
"#;

fn plan_of(spec_text: &str, runs: Option<u64>) -> Manifest {
    let spec = Spec::from_toml(spec_text).unwrap();
    plan::plan(
        &spec,
        spec_text,
        "spec.toml",
        &scenario_text("slope-10-cross"),
        runs,
    )
    .unwrap()
}

#[test]
fn campaign_plan_draws_are_deterministic_and_per_index() {
    let a = plan_of(SPEC, None);
    let b = plan_of(SPEC, None);
    assert_eq!(
        plan::manifest_text(&a).unwrap(),
        plan::manifest_text(&b).unwrap()
    );
    // The manifest reads back exactly (every f64 bit), as each run on a cluster reads it.
    let text = plan::manifest_text(&a).unwrap();
    let back: Manifest = serde_json::from_str(&text).unwrap();
    assert_eq!(back, a);
    // The first 10 runs of the 40-run campaign are the 10-run campaign.
    let short = plan_of(SPEC, Some(10));
    assert_eq!(short.entries[..], a.entries[..10]);
    // Bounds, apply modes and the recorded parameters.
    let base = scenario("slope-10-cross");
    let phi0 = crate::soil::terramechanics::Soil::ishigami_regolith_simulant()
        .phi_rad
        .to_degrees();
    let gyro0 = base.sensors.imu.gyro_noise_rad_s;
    for e in &a.entries {
        let d = e.draws["phi"];
        assert!((-3.0..=3.0).contains(&d));
        assert!((e.params["soil.friction_angle_deg"] - (phi0 + d)).abs() < 1e-12);
        let s = e.draws["slope"];
        assert!((8.0..12.0).contains(&s));
        assert_eq!(e.params["terrain.slope_deg"], s);
        let k = e.draws["imu"];
        assert_eq!(e.params["sensors.imu.gyro_noise_rad_s"], gyro0 * k);
        assert_eq!(e.seed, super::run_seed(7, e.index));
        assert_eq!((e.terrain_seed, e.calibration_seed), (e.seed, e.seed));
        // The run's scenario carries the values.
        let sc = a.scenario(e.index).unwrap();
        assert_eq!(sc.seed, e.seed);
        assert_eq!(sc.terrain_seed, None);
        let mut sc2 = sc.clone();
        assert_eq!(params::get(&mut sc2, "terrain.slope_deg").unwrap(), s);
    }
    // The draws spread: a normal of sigma 2 truncated at +-3 over 40 runs.
    let phis: Vec<f64> = a.entries.iter().map(|e| e.draws["phi"]).collect();
    let mean = phis.iter().sum::<f64>() / 40.0;
    let sd = (phis.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 39.0).sqrt();
    assert!(mean.abs() < 0.7 && (1.0..2.2).contains(&sd), "{mean} {sd}");
    // Removing a dispersion does not change the others' draws (one stream per name).
    let without_phi = SPEC.replace("name = \"phi\"", "name = \"phi2\"");
    let c = plan_of(&without_phi, Some(10));
    for (x, y) in c.entries.iter().zip(&a.entries) {
        assert_eq!(x.draws["slope"], y.draws["slope"]);
        assert_eq!(x.draws["imu"], y.draws["imu"]);
        assert_ne!(x.draws["phi2"], y.draws["phi"]);
    }
    // Fixed terrain and calibration seeds.
    let fixed = format!("{SPEC}\n[seeds]\nterrain = 5\ncalibration = 6\n");
    let f = plan_of(&fixed, Some(3));
    assert!(f
        .entries
        .iter()
        .all(|e| e.terrain_seed == 5 && e.calibration_seed == 6));
    let sc = f.scenario(2).unwrap();
    assert_eq!((sc.terrain_seed, sc.calibration_seed), (Some(5), Some(6)));
}

#[test]
fn campaign_plan_refuses_bad_specs() {
    // A plane parameter on dunes.
    let dunes = SPEC.replace("slope-10-cross.toml", "dunes-long.toml");
    let spec = Spec::from_toml(&dunes).unwrap();
    assert!(plan::plan(&spec, &dunes, "x", &scenario_text("dunes-long"), Some(2)).is_err());
    // A lumped soil parameter on the terramechanics scenario.
    let lumped = SPEC.replace("soil.friction_angle_deg", "soil_lumped.friction_angle_deg");
    let spec = Spec::from_toml(&lumped).unwrap();
    assert!(plan::plan(
        &spec,
        &lumped,
        "x",
        &scenario_text("slope-10-cross"),
        Some(2)
    )
    .is_err());
    // A drawn scenario the simulator refuses (speed above 0.3 m/s).
    let fast = format!(
        "{SPEC}\n[[dispersion]]\nparams = ['speed_m_s']\ndist = {{ kind = 'uniform', min = 0.5, max = 0.6 }}\n"
    );
    let spec = Spec::from_toml(&fast).unwrap();
    let e = plan::plan(&spec, &fast, "x", &scenario_text("slope-10-cross"), Some(2))
        .unwrap_err()
        .to_string();
    assert!(e.contains("speed_m_s"), "{e}");
    // An override key that is not a scenario key.
    let typo = format!("{SPEC}\n[scenario_overrides]\nduration = 5.0\n");
    let spec = Spec::from_toml(&typo).unwrap();
    assert!(plan::plan(&spec, &typo, "x", &scenario_text("slope-10-cross"), Some(2)).is_err());
}

#[test]
fn campaign_params_every_accessor_works() {
    let mut tried = 0;
    for p in params::PARAMS {
        let base = if p.name.starts_with("soil_lumped.") {
            "flat-firm"
        } else if p.name.starts_with("terrain.rocks.") {
            "marsyard-25m"
        } else {
            "slope-10-cross"
        };
        let mut s = scenario(base);
        let v = params::get(&mut s, p.name).unwrap_or_else(|e| panic!("{}: {e}", p.name));
        assert!(v.is_finite(), "{}", p.name);
        params::set(&mut s, p.name, v + 0.25).unwrap();
        assert_eq!(params::get(&mut s, p.name).unwrap(), v + 0.25, "{}", p.name);
        tried += 1;
    }
    assert_eq!(tried, params::PARAMS.len());
    // Making the preset explicit keeps the simulator's soil.
    let mut s = scenario("slope-10-cross");
    let before = s.soil.bekker().unwrap();
    params::get(&mut s, "soil.n").unwrap();
    let after = s.soil.bekker().unwrap();
    assert!((after.phi_rad - before.phi_rad).abs() < 1e-15);
    assert_eq!(
        (
            after.k_phi,
            after.shear_k_y_m,
            after.theta_m_a0,
            after.exit_sinkage_ratio
        ),
        (
            before.k_phi,
            before.shear_k_y_m,
            before.theta_m_a0,
            before.exit_sinkage_ratio
        )
    );
    assert!(params::find("soil.nope").is_err());
}

#[test]
fn campaign_world_start_offset_and_seeds() {
    let base = scenario("marsyard-25m");
    let world = |s: &Scenario, seed: u64| crate::world::World::new(s, seed).unwrap();
    let w0 = world(&base, 3);
    let mut off = base.clone();
    off.start_offset.north_m = 0.05;
    off.start_offset.east_m = -0.1;
    off.start_offset.yaw_deg = 2.0;
    let w1 = world(&off, 3);
    let (p0, p1) = (w0.truth.pose, w1.truth.pose);
    assert!((p1.pos_m[0] - p0.pos_m[0] - 0.05).abs() < 1e-9);
    assert!((p1.pos_m[1] - p0.pos_m[1] + 0.1).abs() < 1e-9);
    assert!((p1.yaw_rad - p0.yaw_rad - 2f64.to_radians()).abs() < 1e-3);
    // The flight software is given the planned start, not the offset one.
    assert_eq!(
        crate::closed_loop::Mission::plan(&base),
        crate::closed_loop::Mission::plan(&off)
    );
    // A fixed terrain seed keeps the rocks; a fixed calibration seed keeps the rover unit.
    let rocks = |w: &crate::world::World| w.terrain.rocks().to_vec();
    assert_ne!(rocks(&world(&base, 3)), rocks(&world(&base, 4)));
    let mut fixed = base.clone();
    fixed.terrain_seed = Some(11);
    fixed.calibration_seed = Some(12);
    let (a, b) = (world(&fixed, 3), world(&fixed, 4));
    assert_eq!(rocks(&a), rocks(&b));
    assert_eq!(a.geometry.wheel_radius_m, b.geometry.wheel_radius_m);
    assert_ne!(
        world(&base, 3).geometry.wheel_radius_m,
        world(&base, 4).geometry.wheel_radius_m
    );
    // Without the new fields a world is what it was: seed 3 of the scenario.
    let mut same = base.clone();
    same.terrain_seed = Some(3);
    same.calibration_seed = Some(3);
    assert_eq!(rocks(&world(&same, 3)), rocks(&w0));
    assert_eq!(
        world(&same, 3).geometry.wheel_radius_m,
        w0.geometry.wheel_radius_m
    );
}

fn rv(index: u64, value: Option<f64>) -> RunValue {
    RunValue {
        index,
        seed: 100 + index,
        value,
    }
}

fn criterion(metric: &str, stat: &str, op: Op, threshold: f64) -> Criterion {
    Criterion {
        name: "c".into(),
        metric: metric.into(),
        stat: stat.into(),
        op,
        threshold,
        source: String::new(),
    }
}

#[test]
fn campaign_stats_nearest_rank_percentiles() {
    assert_eq!(stats::nearest_rank(200, 99.0), 197); // rank 198
    assert_eq!(stats::nearest_rank(200, 95.0), 189); // rank 190
    assert_eq!(stats::nearest_rank(200, 100.0), 199);
    assert_eq!(stats::nearest_rank(1000, 99.9), 998); // rank 999 exactly
    assert_eq!(stats::nearest_rank(5, 50.0), 2); // rank 3 of 5: the median
    assert_eq!(stats::nearest_rank(4, 50.0), 1); // rank 2 of 4
    assert_eq!(stats::nearest_rank(3, 1.0), 0);
    // 1..=100 shuffled: P_p is p.
    let values: Vec<RunValue> = (0..100u64)
        .map(|i| rv(i, Some(((i * 37) % 100 + 1) as f64)))
        .collect();
    let m = stats::metric_stats("cross_track_m.max", &values);
    let p = |q: f64| m.percentiles.iter().find(|x| x.p == q).unwrap().value;
    assert_eq!(
        (p(50.0), p(90.0), p(95.0), p(99.0)),
        (50.0, 90.0, 95.0, 99.0)
    );
    assert_eq!(m.mean, Some(50.5));
    let sd = m.std.unwrap();
    assert!((sd - (100.0f64 * 101.0 / 12.0).sqrt()).abs() < 1e-9, "{sd}");
    assert_eq!(m.max.as_ref().unwrap().value, 100.0);
    // The run that holds the maximum: i * 37 % 100 = 99, i = 27.
    assert_eq!(m.max.as_ref().unwrap().run, 27);
}

#[test]
fn campaign_stats_criteria_nulls_and_worst_runs() {
    let values = vec![
        rv(0, Some(0.10)),
        rv(1, Some(0.30)),
        rv(2, None),
        rv(3, Some(0.30)),
        rv(4, Some(0.05)),
    ];
    // P50 of 4 values = rank 2 = 0.10; but run 2 has no value: the criterion fails.
    let r = stats::evaluate(
        &criterion("cross_track_m.max", "p50", Op::Le, 0.2),
        &values,
        3,
    )
    .unwrap();
    assert_eq!((r.value, r.value_run), (Some(0.10), Some(0)));
    assert!(!r.pass);
    assert_eq!(r.null_runs, vec![2]);
    assert_eq!(r.runs_beyond_threshold, 2);
    // Worst: the null run, then the largest values, ties by index.
    let worst: Vec<u64> = r.worst.iter().map(|w| w.index).collect();
    assert_eq!(worst, vec![2, 1, 3]);
    // Without the null run it passes; P99 = 0.30 fails a 0.2 threshold.
    let full: Vec<RunValue> = values
        .iter()
        .copied()
        .filter(|v| v.value.is_some())
        .collect();
    let r = stats::evaluate(
        &criterion("cross_track_m.max", "p50", Op::Le, 0.2),
        &full,
        3,
    )
    .unwrap();
    assert!(r.pass);
    let r = stats::evaluate(
        &criterion("cross_track_m.max", "p99", Op::Le, 0.2),
        &full,
        3,
    )
    .unwrap();
    assert!(!r.pass && r.value == Some(0.30));
    // Lower-tail criterion: worst are the smallest.
    let r = stats::evaluate(
        &criterion("slip.gate_reject_fraction", "p5", Op::Ge, 0.06),
        &full,
        2,
    )
    .unwrap();
    assert_eq!(r.value, Some(0.05));
    assert!(!r.pass);
    assert_eq!(r.worst[0].index, 4);
    // A fraction.
    let flags: Vec<RunValue> = (0..10)
        .map(|i| rv(i, Some(if i == 3 { 0.0 } else { 1.0 })))
        .collect();
    let r = stats::evaluate(
        &criterion("goal_reached", "fraction", Op::Ge, 0.9),
        &flags,
        1,
    )
    .unwrap();
    assert_eq!(r.value, Some(0.9));
    assert!(r.pass);
    assert_eq!(r.worst[0].index, 3);
    let r = stats::evaluate(
        &criterion("goal_reached", "fraction", Op::Ge, 0.95),
        &flags,
        1,
    )
    .unwrap();
    assert!(!r.pass);
}

#[test]
fn campaign_stats_value_paths() {
    let v: serde_json::Value = serde_json::json!({
        "a": { "b": 1.5, "n": null, "t": true, "s": "x" }, "arr": [1, 2]
    });
    assert_eq!(stats::value_at(&v, "a.b"), Ok(Some(1.5)));
    assert_eq!(stats::value_at(&v, "a.n"), Ok(None));
    assert_eq!(stats::value_at(&v, "a.t"), Ok(Some(1.0)));
    assert_eq!(stats::value_at(&v, "arr.1"), Ok(Some(2.0)));
    assert!(stats::value_at(&v, "a.s").is_err());
    assert!(stats::value_at(&v, "a.zz").is_err());
    assert!(stats::check_metric("nav.kin_rejected").is_ok());
    assert!(stats::check_metric("cross_track_m.max").is_ok());
    assert!(stats::check_metric("cross_track.max").is_err());
    let r = stats::pearson(&[(1.0, 2.0), (2.0, 4.1), (3.0, 5.9), (4.0, 8.0)]).unwrap();
    assert!(r > 0.99);
    assert_eq!(stats::pearson(&[(1.0, 2.0), (1.0, 3.0), (1.0, 4.0)]), None);
}

/// Every figure kind over awkward value ranges: no two labels overlap, none leaves the canvas.
#[test]
fn campaign_figures_labels_do_not_overlap() {
    let (w, h) = (
        f64::from(html::FIGURE_SIZE.0),
        f64::from(html::FIGURE_SIZE.1),
    );
    let cases: Vec<(&str, &str, Op, f64, Vec<f64>)> = vec![
        (
            "cross_track_m.max",
            "p99",
            Op::Le,
            0.15,
            vec![0.031, 0.032, 0.035, 0.04, 0.12, 0.2],
        ),
        (
            "goal_miss_m",
            "p95",
            Op::Le,
            0.1,
            vec![1.2e-4, 3.3e-4, 2.2e-4, 9.9e-5],
        ),
        (
            "error_pct.ekf",
            "p95",
            Op::Le,
            1.0,
            (0..200).map(|i| 0.3 + 0.004 * i as f64).collect(),
        ),
        (
            "sim_time_s",
            "max",
            Op::Le,
            12_000.0,
            vec![10_234.5, 11_876.25, 9_999.0],
        ),
        (
            "slip.mean_slip_ratio",
            "p5",
            Op::Ge,
            -0.05,
            vec![-0.0213, 0.0085, -0.0064, 0.0011],
        ),
        (
            "slip.gate_reject_fraction",
            "mean",
            Op::Ge,
            0.5,
            vec![0.55, 0.75, 0.61],
        ),
        ("distance_m", "p50", Op::Ge, 4.4, vec![4.46, 4.46, 4.46]),
        (
            "goal_reached",
            "fraction",
            Op::Ge,
            0.99,
            vec![1.0, 1.0, 0.0, 1.0],
        ),
    ];
    for (metric, stat, op, threshold, xs) in cases {
        let values: Vec<RunValue> = xs
            .iter()
            .enumerate()
            .map(|(i, x)| rv(i as u64, Some(*x)))
            .collect();
        let c = stats::evaluate(&criterion(metric, stat, op, threshold), &values, 3).unwrap();
        let svg = html::criterion_figure(&c, &values).unwrap();
        let labels = svg_labels::labels(&svg).unwrap();
        assert!(labels.len() >= 8, "{metric}: {} labels", labels.len());
        let pairs = svg_labels::overlapping(&svg).unwrap();
        assert!(pairs.is_empty(), "{metric}: overlapping labels {pairs:?}");
        let out = svg_labels::outside(&svg, w, h).unwrap();
        assert!(
            out.is_empty(),
            "{metric}: labels outside the canvas {out:?}"
        );
    }
}

/// A small campaign end to end: plan into two folders, run one in parallel and the other run
/// by run, gather both: identical `stats.json` and `report.html`; then a missing and a failed
/// run are reported, never dropped.
#[test]
fn campaign_end_to_end_local_equals_one_by_one() {
    let spec_text = r#"
name = "e2e"
scenario = "slope-10-cross.toml"
runs = 3
base_seed = 5
[run]
render = false
vo = false
[scenario_overrides]
waypoints = [[0.0, 0.0], [0.6, 0.0]]
duration_s = 15.0
[[dispersion]]
name = "slope"
params = ["terrain.slope_deg"]
dist = { kind = "uniform", min = 8.0, max = 12.0 }
[[dispersion]]
name = "start"
params = ["start.east_m"]
dist = { kind = "normal", mean = 0.0, sigma = 0.02 }
[[criterion]]
name = "cross-track"
metric = "cross_track_m.max"
stat = "p99"
op = "<="
threshold = 0.15
[[criterion]]
name = "reached"
metric = "goal_reached"
stat = "fraction"
op = ">="
threshold = 1.0
"#;
    let root = temp_dir("e2e");
    std::fs::create_dir_all(&root).unwrap();
    let spec_path = root.join("e2e.toml");
    std::fs::write(&spec_path, spec_text).unwrap();
    std::fs::write(
        root.join("slope-10-cross.toml"),
        scenario_text("slope-10-cross"),
    )
    .unwrap();
    let (a, b) = (root.join("a"), root.join("b"));
    let ma = plan::plan_to_dir(&spec_path, &a, None).unwrap();
    let mb = plan::plan_to_dir(&spec_path, &b, None).unwrap();
    assert_eq!(ma, mb);
    // Planning again into the same folder keeps it; another run count is refused.
    plan::plan_to_dir(&spec_path, &a, None).unwrap();
    assert!(plan::plan_to_dir(&spec_path, &a, Some(4)).is_err());
    let failed = exec::run_parallel(&a, &ma, &[0, 1, 2], Some(2)).unwrap();
    assert!(failed.is_empty(), "{failed:?}");
    for i in [2, 0, 1] {
        exec::run_index(&b, &mb, i, None).unwrap();
    }
    let ga = stats::gather(&a, &Manifest::load(&a).unwrap()).unwrap();
    let gb = stats::gather(&b, &Manifest::load(&b).unwrap()).unwrap();
    let (sa, sb) = (
        stats::stats_text(&ga.stats).unwrap(),
        stats::stats_text(&gb.stats).unwrap(),
    );
    assert_eq!(sa, sb);
    let (ra, rb) = (
        html::report_html(&ma, &ga).unwrap(),
        html::report_html(&mb, &gb).unwrap(),
    );
    assert_eq!(ra, rb);
    assert_eq!(ga.stats.runs_ok, 3);
    assert_eq!(ga.stats.criteria.len(), 2);
    assert!(ga.stats.verdict == "pass" || ga.stats.verdict == "fail");
    // The statistics are those of the summaries.
    let max_ct = (0..3)
        .map(|i| {
            let text = std::fs::read_to_string(exec::run_dir(&a, i).join("summary.json")).unwrap();
            let v: serde_json::Value = serde_json::from_str(&text).unwrap();
            v["cross_track_m"]["max"].as_f64().unwrap()
        })
        .fold(f64::MIN, f64::max);
    assert_eq!(ga.stats.criteria[0].value, Some(max_ct)); // P99 of 3 runs is the largest
                                                          // Every figure of the report: no overlapping labels.
    let figures: Vec<&str> = ra.split("<svg").skip(1).collect();
    assert_eq!(figures.len(), 2);
    for f in figures {
        let svg = format!("<svg{}", &f[..f.find("</svg>").unwrap() + 6]);
        assert!(svg_labels::overlapping(&svg).unwrap().is_empty());
    }
    // A replay with every output reproduces the summary (but for the wall time).
    let replay = root.join("replay");
    let s = exec::run_index(&a, &ma, 1, Some(&replay)).unwrap();
    assert!(replay.join("truth.tum").exists() && replay.join("summary.json").exists());
    let again = stats::gather(&a, &ma).unwrap();
    assert_eq!(stats::stats_text(&again.stats).unwrap(), sa);
    assert!(s.distance_m > 0.3);
    // A missing run and a failed run.
    std::fs::remove_file(exec::run_dir(&a, 1).join("summary.json")).unwrap();
    std::fs::remove_file(exec::run_dir(&a, 2).join("summary.json")).unwrap();
    std::fs::write(exec::run_dir(&a, 2).join("error.txt"), "boom\n").unwrap();
    let g = stats::gather(&a, &ma).unwrap();
    assert_eq!(g.stats.verdict, "incomplete");
    assert_eq!(g.stats.missing_runs, vec![1]);
    assert_eq!(g.stats.failed_runs.len(), 1);
    assert_eq!(
        (
            g.stats.failed_runs[0].index,
            g.stats.failed_runs[0].error.as_str()
        ),
        (2, "boom")
    );
    assert_eq!(g.stats.runs_ok, 1);
    let page = html::report_html(&ma, &g).unwrap();
    assert!(page.contains("failed: boom") && page.contains("missing"));
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn campaign_slurm_scripts() {
    use super::slurm::{scripts, GatherAfter, SlurmOptions};
    let mut o = SlurmOptions {
        bin: PathBuf::from("/opt/rover/sim-host"),
        tasks: 1000,
        throttle: 8,
        partition: Some("batch".into()),
        account: Some("nav".into()),
        qos: None,
        time: "00:20:00".into(),
        gather_time: "00:10:00".into(),
        cpus_per_task: 2,
        mem: "2G".into(),
        gather_after: GatherAfter::Ok,
        extra: vec!["--constraint=x86".into()],
    };
    let dir = Path::new("/shared/camp");
    let (a, g) = scripts("slope", 200, dir, &o);
    assert!(a.starts_with("#!/bin/bash\n"));
    for line in [
        "#SBATCH --array=0-199%8",
        "#SBATCH --partition=batch",
        "#SBATCH --account=nav",
        "#SBATCH --time=00:20:00",
        "#SBATCH --cpus-per-task=2",
        "#SBATCH --constraint=x86",
        "#SBATCH --output=/shared/camp/logs/run-%a.out",
        "exec /opt/rover/sim-host campaign run /shared/camp --index \"$SLURM_ARRAY_TASK_ID\"",
    ] {
        assert!(a.contains(line), "{line} missing in\n{a}");
    }
    assert!(g.contains("exec /opt/rover/sim-host campaign gather /shared/camp"));
    assert!(g.contains("#SBATCH --time=00:10:00") && !g.contains("--array"));
    // More runs than tasks: shards.
    o.tasks = 16;
    o.throttle = 0;
    let (a, _) = scripts("big", 10_000, dir, &o);
    assert!(a.contains("#SBATCH --array=0-15\n"));
    assert!(a.contains("--shard \"$SLURM_ARRAY_TASK_ID/16\""));
    assert_eq!(exec::shard_indices(10, 3, 4), vec![3, 7]);
    assert_eq!(exec::parse_shard("3/16").unwrap(), (3, 16));
    assert!(exec::parse_shard("16/16").is_err());
    // Every index is in exactly one shard.
    let mut all: Vec<u64> = (0..16)
        .flat_map(|k| exec::shard_indices(100, k, 16))
        .collect();
    all.sort_unstable();
    assert_eq!(all, (0..100).collect::<Vec<_>>());
}

/// The example specs in `campaigns/` parse, plan, and name scenarios that exist.
#[test]
fn campaign_example_specs_plan() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../campaigns");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let out = temp_dir(&format!(
                "spec-{}",
                path.file_stem().unwrap().to_string_lossy()
            ));
            let m = plan::plan_to_dir(&path, &out, None)
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(!m.spec().unwrap().criteria.is_empty());
            names.push(m.campaign.clone());
            let _ = std::fs::remove_dir_all(&out);
        }
    }
    names.sort();
    assert!(names.contains(&"slope-10-cross".to_string()), "{names:?}");
    assert!(names.contains(&"ci-smoke".to_string()), "{names:?}");
}

/// The committed report of the 200-run campaign: every figure without overlapping labels or
/// labels outside its canvas, and a criteria table that matches its `stats.json`.
#[test]
fn campaign_committed_report_labels_do_not_overlap() {
    let dir =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/results/campaigns/slope-10-cross");
    let page = std::fs::read_to_string(dir.join("report.html")).unwrap();
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("stats.json")).unwrap()).unwrap();
    let criteria = stats["criteria"].as_array().unwrap();
    let figures: Vec<&str> = page.split("<svg").skip(1).collect();
    assert_eq!(figures.len(), criteria.len());
    let (w, h) = (
        f64::from(html::FIGURE_SIZE.0),
        f64::from(html::FIGURE_SIZE.1),
    );
    for f in figures {
        let svg = format!("<svg{}", &f[..f.find("</svg>").unwrap() + 6]);
        assert!(svg_labels::overlapping(&svg).unwrap().is_empty());
        assert!(svg_labels::outside(&svg, w, h).unwrap().is_empty());
    }
    for c in criteria {
        let verdict = if c["pass"].as_bool().unwrap() {
            "PASS"
        } else {
            "FAIL"
        };
        let name = c["name"].as_str().unwrap();
        let row = page
            .lines()
            .find(|l| l.contains(&format!("<td class=\"l\">{name}</td>")))
            .unwrap_or_else(|| panic!("no row for {name}"));
        assert!(row.contains(verdict), "{name}: {row}");
    }
}
