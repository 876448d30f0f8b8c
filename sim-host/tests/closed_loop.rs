//! Closed-loop runs of the simulator with the flight software (SIM-11 to SIM-15).

use sim_host::closed_loop::{run, RunOptions, RunResult};
use sim_host::devices::world::CounterMode;
use sim_host::scenario::{DriverMode, Scenario};
use sim_host::soil::rigid_wheel::{slip_angle_for_side_force, slip_for_drawbar_pull};
use sim_host::soil::terramechanics::{Soil, Wheel, MARS_GRAVITY, ROCKY8_MASS_KG};
use sim_host::world::{World, MARS_GRAVITY_M_S2};
use std::path::{Path, PathBuf};

fn scenario(name: &str) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scenarios")
        .join(format!("{name}.toml"));
    Scenario::load(&path).unwrap()
}

fn deterministic(seed: Option<u64>, no_slip_comp: bool) -> RunOptions {
    RunOptions {
        seed,
        no_slip_comp,
        counter: CounterMode::SimTime,
        ..RunOptions::default()
    }
}

/// The simulator's own reference driver (truth-based, or open loop with `no_slip_comp`): for
/// tests of the simulator's models rather than of the flight software.
fn reference(seed: Option<u64>, no_slip_comp: bool) -> RunOptions {
    RunOptions {
        reference_driver: true,
        ..deterministic(seed, no_slip_comp)
    }
}

fn out_dir(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("sim-host-test-{}-{tag}", std::process::id()))
}

fn final_east(r: &RunResult) -> f64 {
    r.records.last().unwrap().pos_m[1]
}

/// SIM-11: the same scenario and seed give byte-identical output files (apart from
/// `wall_time_s`); another seed gives another truth.
#[test]
fn sim_11_same_seed_byte_identical_outputs() {
    let s = scenario("slope-10-cross");
    let dirs = [out_dir("a"), out_dir("b")];
    for d in &dirs {
        let r = run(&s, deterministic(Some(7), false)).unwrap();
        sim_host::output::write_all(d, &r).unwrap();
    }
    for name in [
        "truth.tum",
        "ekf.tum",
        "vo.tum",
        "kin3d.tum",
        "kin2d.tum",
        "report.html",
        "summary.json",
    ] {
        let read = |d: &PathBuf| {
            std::fs::read_to_string(d.join(name))
                .unwrap()
                .lines()
                .filter(|l| !l.contains("wall_time_s"))
                .collect::<Vec<_>>()
                .join("\n")
        };
        assert_eq!(read(&dirs[0]), read(&dirs[1]), "{name} differs");
    }
    let summary = std::fs::read_to_string(dirs[0].join("summary.json")).unwrap();
    for key in [
        "\"scenario\"",
        "\"seed\"",
        "\"sim_time_s\"",
        "\"distance_m\"",
        "\"final_error_m\"",
        "\"error_pct\"",
        "\"max_attitude_error_deg\"",
        "\"cross_track_m\"",
        "\"goal_reached\"",
        "\"goal_miss_m\"",
        "\"gate_reject_fraction\"",
        "\"mean_slip_ratio\"",
        "\"vo\"",
        "\"mean_inliers\"",
        "\"timing\"",
        "\"RG1\"",
        "\"overruns\"",
        "\"wall_time_s\"",
    ] {
        assert!(summary.contains(key), "summary.json lacks {key}");
    }
    let other = run(&s, deterministic(Some(8), false)).unwrap();
    let first = run(&s, deterministic(Some(7), false)).unwrap();
    assert_ne!(other.records, first.records);
    for d in &dirs {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// Single-wheel prediction of the rigid-wheel law for a sixth of the weight on a plane of
/// `slope_deg` across the wheel: (slip ratio at zero drawbar pull, slip-angle magnitude), two
/// passes as in `sim_host::soil::per_wheel_slip`.
fn single_wheel(soil: &Soil, slope_deg: f64) -> (f64, f64) {
    let wheel = Wheel::rocky8();
    let w = ROCKY8_MASS_KG * MARS_GRAVITY / 6.0;
    let t = slope_deg.to_radians();
    let (n, side) = (w * t.cos(), w * t.sin());
    let s = slip_for_drawbar_pull(soil, &wheel, n, 0.0, 0.0).slip_ratio;
    let (a, _) = slip_angle_for_side_force(soil, &wheel, n, s, side);
    let s = slip_for_drawbar_pull(soil, &wheel, n, a, 0.0).slip_ratio;
    let (a, _) = slip_angle_for_side_force(soil, &wheel, n, s, side);
    (s, a.abs())
}

/// SIM-12: on the 10 deg sand cross slope without slip compensation the rover drifts downhill,
/// by the path length times the tangent of the single-wheel slip angle of the rigid-wheel law
/// (within a factor 1.5: load transfer, per-seed soil, start-up), and at least 0.1 m; with the
/// (truth) compensating driver it stays within 0.1 m of the path and reaches the goal. Both
/// with the simulator's reference driver (the flight software's version is SIL-GNC-1/2).
/// H05 Fig. 9 reports more drift than this model gives (about half of H05's; see
/// `docs/simulator.md`, section Slip); SIL-GNC-2 keeps H05's 0.5 m.
#[test]
fn sim_12_cross_slope_drift_without_compensation() {
    let s = scenario("slope-10-cross");
    let (_, alpha) = single_wheel(&Soil::ishigami_regolith_simulant(), 10.0);
    for seed in [1, 2, 3] {
        let open = run(&s, reference(Some(seed), true)).unwrap();
        let drift = final_east(&open);
        let predicted = open.distance_m * alpha.tan();
        assert!(
            drift >= 0.1 && drift > predicted / 1.5 && drift < predicted * 1.5,
            "seed {seed}: drift {drift:.3} m, single-wheel prediction {predicted:.3} m"
        );
        let comp = run(&s, reference(Some(seed), false)).unwrap();
        let max_cross = comp
            .records
            .iter()
            .map(|r| r.cross_track_m)
            .fold(0.0, f64::max);
        assert!(
            max_cross < 0.1 && comp.goal_reached,
            "seed {seed}: {max_cross}"
        );
    }
}

/// SIM-13: on flat firm soil the rover does not drift sideways (less than 2 cm over the open-loop
/// drive) and its mean slip ratio is the single-wheel free-rolling slip of the rigid-wheel law
/// on `firm_soil` within 0.06 (about 0.17: Wong's loam resists a 0.2 m wheel; the lumped
/// model's "below 2 %" does not hold for it, see `docs/simulator.md`, section Slip).
#[test]
fn sim_13_flat_firm_soil_small_slip() {
    let mut s = scenario("slope-10-cross");
    s.terrain.base = sim_host::terrain::BaseShape::Flat;
    s.soil = sim_host::scenario::SoilSpec::Preset("firm_soil".into());
    s.driver = DriverMode::OpenLoop;
    let r = run(&s, reference(Some(3), false)).unwrap();
    let summary = sim_host::output::summary::summarise(&r);
    let (free, _) = single_wheel(&Soil::sandy_loam(), 0.0);
    assert!(
        (summary.slip.mean_slip_ratio - free).abs() < 0.06,
        "{} vs {free}: {summary:?}",
        summary.slip.mean_slip_ratio
    );
    assert!(final_east(&r).abs() < 0.02, "{}", final_east(&r));
    assert!(r.distance_m > 1.0);
}

/// SIM-14: the IMU of a rover at rest on level ground reads minus gravity in `R` —
/// `[0, 0, -3.711]` m/s^2 turned by the body's small tilt from the per-seed dimension errors —
/// and zero rate, within its noise; on a 10 deg cross slope gravity appears on `+y_R` (right
/// side downhill).
#[test]
fn sim_14_imu_at_rest() {
    let mut s = scenario("slope-10-cross");
    s.terrain.base = sim_host::terrain::BaseShape::Flat;
    let mut w = World::new(&s, 4).unwrap();
    let n = 2000;
    let (mut a, mut g) = ([0.0; 3], [0.0; 3]);
    for _ in 0..n {
        w.step();
        for k in 0..3 {
            a[k] += w.imu_sample.accel_m_s2[k] / n as f64;
            g[k] += w.imu_sample.gyro_rad_s[k] / n as f64;
        }
    }
    let rot = w.truth.pose.rot_w_from_r();
    let f = rot.inverse() * nalgebra::Vector3::new(0.0, 0.0, -MARS_GRAVITY_M_S2);
    assert!(w.truth.pose.pitch_rad.abs() < 0.02 && w.truth.pose.roll_rad.abs() < 0.02);
    for k in 0..3 {
        // Bias 5e-3 (1-sigma) plus averaged noise.
        assert!((a[k] - f[k]).abs() < 0.02, "{a:?} vs {f:?}");
    }
    assert!(g.iter().all(|v| v.abs() < 1e-3), "{g:?}");
    let slope = scenario("slope-10-cross");
    let mut w = World::new(&slope, 4).unwrap();
    w.step();
    w.step();
    let ay = w.imu_sample.accel_m_s2[1];
    let expected = -MARS_GRAVITY_M_S2 * 10f64.to_radians().sin();
    // Specific force is minus gravity: gravity pulls to +y_R, the accelerometer reads -y.
    assert!((ay - expected).abs() < 0.03, "{ay} vs {expected}");
}

/// SIM-15: injected faults reach the flight software through the HAL and are counted there;
/// a clean run counts none; the stereo camera completes one capture per second.
#[test]
fn sim_15_faults_reach_the_flight_software() {
    let mut s = scenario("slope-10-cross");
    let clean = run(&s, deterministic(None, false)).unwrap();
    assert_eq!(clean.device_faults, 0);
    let seconds = clean.sim_time_s.floor() as u32;
    assert!(clean.stereo_frames + 1 >= seconds && clean.stereo_frames <= seconds + 1);
    s.faults = toml::from_str::<toml::Table>(
        r#"
        [[f]]
        device = "imu"
        kind = "nan"
        start_s = 5.0
        duration_s = 0.1
        [[f]]
        device = "joints"
        kind = "dropout"
        start_s = 6.0
        duration_s = 1.0
        "#,
    )
    .unwrap()["f"]
        .clone()
        .try_into()
        .unwrap();
    let faulty = run(&s, deterministic(None, false)).unwrap();
    // 20 NaN IMU samples and 2 joint reads in the dropout window (RG2 at 20 Hz).
    assert!(faulty.device_faults >= 20 + 2, "{}", faulty.device_faults);
}
