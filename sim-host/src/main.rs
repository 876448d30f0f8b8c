//! `sim-host`: the product's main command. Runs the flight software on the simulated rover and
//! prints a summary. With no arguments it runs `slope-10-cross` with and without slip
//! compensation and prints the comparison.

use clap::{Parser, Subcommand};
use sim_host::closed_loop::{run, RunOptions};
use sim_host::devices::world::CounterMode;
use sim_host::output::summary::Summary;
use sim_host::scenario::Scenario;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    version,
    about = "Host simulator of a Rocky 8 class rover running the flight software"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scenario (default: slope-10-cross) with and without slip compensation and compare.
    Compare {
        /// Scenario file (TOML).
        #[arg(default_value_os_t = default_scenario())]
        scenario: PathBuf,
        /// Seed (default: the scenario's).
        #[arg(long)]
        seed: Option<u64>,
        /// Output directory; the two runs go to `<out>/comp` and `<out>/no-comp`
        /// (default: out/compare-<scenario>-<seed>).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Run the flight executive on a rover standing still for N minor frames (200 Hz).
    Still {
        /// Number of 5 ms minor frames.
        #[arg(long, default_value_t = 2000)]
        frames: u64,
    },
    /// Run the SIL acceptance cases (in parallel) and write the results page.
    Sil {
        /// Results page to write.
        #[arg(long, default_value = "docs/sil-results.md")]
        out: PathBuf,
        /// Directory of the scenario files.
        #[arg(long, default_value = "scenarios")]
        scenarios: PathBuf,
        /// Also write each case's `summary.json` into this directory, as `<case id>.json`.
        #[arg(long)]
        summaries: Option<PathBuf>,
    },
    /// Measure the slip gate's detection probability against the true slip magnitude (slope
    /// sweeps of slope-10-cross, two seeds, in parallel) and the slip-hold policy; write the
    /// results page and its figure.
    Detection {
        /// Results page to write.
        #[arg(long, default_value = "docs/slip-detection.md")]
        out: PathBuf,
        /// Figure to write (SVG).
        #[arg(long, default_value = "docs/figures/slip-detection.svg")]
        figure: PathBuf,
        /// Directory of the scenario files.
        #[arg(long, default_value = "scenarios")]
        scenarios: PathBuf,
    },
    /// Run a scenario file in closed loop and write the outputs.
    Run {
        /// Scenario file (TOML), e.g. scenarios/slope-10-cross.toml.
        scenario: PathBuf,
        /// Seed (default: the scenario's).
        #[arg(long)]
        seed: Option<u64>,
        /// Output directory (default: out/<scenario>-<seed>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Drive without slip compensation: the flight software navigates on wheel and IMU
        /// odometry only (with --reference-driver: the reference driver holds heading open loop).
        #[arg(long)]
        no_slip_comp: bool,
        /// Let the simulator's reference driver (which sees the truth) command the motors
        /// instead of the flight software.
        #[arg(long)]
        reference_driver: bool,
        /// Print summary.json to stdout instead of the table.
        #[arg(long)]
        json: bool,
        /// Use simulated time as the execution counter: timing figures read 0 and every output
        /// file is byte-identical for the same scenario and seed (except wall_time_s).
        #[arg(long)]
        sim_counter: bool,
        /// Skip rendering the stereo images (uniform grey frames): faster, but visual odometry
        /// has nothing to track.
        #[arg(long)]
        no_render: bool,
        /// The terrain produces no slip (every axle moves at its wheel's rim speed).
        #[arg(long)]
        no_slip: bool,
        /// Visual odometry off in the flight software: the EKF gets IMU, sun sensor and
        /// kinematics (the cameras still capture).
        #[arg(long)]
        no_vo: bool,
        /// The truth vehicle gets the published dimensions exactly (no per-seed dimension or
        /// wheel-radius errors), as the SIL kinematic cases run it.
        #[arg(long)]
        exact_dimensions: bool,
        /// Slip model of the truth (overrides the scenario's): `terramechanics` (per wheel,
        /// docs/terramechanics.md; the default) or `lumped`.
        #[arg(long)]
        slip_model: Option<String>,
        /// Ideal lenses: the cameras deliver the rectified pinhole pair (no wide-angle lens
        /// model, no rectification in the flight software), for comparison.
        #[arg(long)]
        ideal_lens: bool,
        /// Terrain-map localization on (V99 sec. 5): the simulator uplinks a global map of its
        /// rocks as a MARDI descent image from 150 m shows them; the flight software matches
        /// its hazard maps against it (docs/localization.md).
        #[arg(long)]
        localization: bool,
    },
    /// Record the HAL call tape of a scenario segment (with rendered stereo images) for replay
    /// on the host or the rover CPU (docs/timing.md).
    Record {
        /// Scenario file (TOML).
        scenario: PathBuf,
        /// Simulated seconds to record.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Seed (default: the scenario's).
        #[arg(long)]
        seed: Option<u64>,
        /// Tape file to write.
        #[arg(long)]
        out: PathBuf,
        /// Uniform grey images instead of rendered ones.
        #[arg(long)]
        no_render: bool,
    },
    /// Monte Carlo campaigns: plan, run, gather, local, slurm (docs/campaigns.md).
    Campaign(sim_host::commands::campaign::CampaignArgs),
    /// Replay a call tape through the flight software and print per-frame digest lines;
    /// fails unless every frame matches the recording.
    Replay {
        /// Tape file written by `record`.
        tape: PathBuf,
        /// Also write the digest of every frame, one hex value per line, to this file.
        #[arg(long)]
        digests: Option<PathBuf>,
    },
}

fn record(
    path: PathBuf,
    seconds: f64,
    seed: Option<u64>,
    out: PathBuf,
    no_render: bool,
) -> anyhow::Result<()> {
    let scenario = Scenario::load(&path)?;
    let start = std::time::Instant::now();
    let recording = sim_host::commands::record::record(
        &scenario,
        sim_host::commands::record::RecordOptions {
            seconds,
            seed,
            render: !no_render,
        },
    )?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&out, &recording.tape)?;
    println!(
        "sim-host record {}: {} frames, {} stereo pairs, {} bytes in {} ({:.1} s)",
        scenario.name,
        recording.digests.len(),
        recording.image_pairs,
        recording.tape.len(),
        out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn replay(path: PathBuf, digests: Option<PathBuf>) -> anyhow::Result<()> {
    let tape = std::fs::read(&path)?;
    let outcome = sim_host::commands::replay::replay(&tape)?;
    print!("{}", outcome.text);
    if let Some(file) = digests {
        let lines: String = outcome
            .digests
            .iter()
            .map(|d| format!("{d:016x}\n"))
            .collect();
        std::fs::write(file, lines)?;
    }
    if !outcome.passed() {
        anyhow::bail!("the replay does not reproduce the recording");
    }
    Ok(())
}

fn still(frames: u64) -> anyhow::Result<()> {
    let summary = sim_host::commands::still::run_still(frames)?;
    println!(
        "sim-host: {} frames, {:.2} s simulated, {} stereo frames, {} cycle slips, {} device faults",
        summary.frames,
        summary.sim_time_s,
        summary.stereo_frames,
        summary.cycle_slips,
        summary.device_faults
    );
    println!(
        "{:<6} {:>8} {:>10} {:>10} {:>9}",
        "group", "runs", "max_us", "mean_us", "overruns"
    );
    for g in &summary.groups {
        println!(
            "{:<6} {:>8} {:>10} {:>10} {:>9}",
            g.name, g.runs, g.max_us, g.mean_us, g.overruns
        );
    }
    Ok(())
}

/// `scenarios/slope-10-cross.toml` of the working directory, or of the source tree.
fn default_scenario() -> PathBuf {
    let local = PathBuf::from("scenarios/slope-10-cross.toml");
    if local.exists() {
        return local;
    }
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenarios/slope-10-cross.toml")
}

/// What `run_scenario` needs.
struct RunRequest {
    path: PathBuf,
    seed: Option<u64>,
    out: Option<PathBuf>,
    no_slip_comp: bool,
    reference_driver: bool,
    json: bool,
    sim_counter: bool,
    no_render: bool,
    no_slip: bool,
    no_vo: bool,
    exact_dimensions: bool,
    slip_model: Option<String>,
    ideal_lens: bool,
    localization: bool,
    quiet: bool,
}

fn fmt_opt(v: Option<f64>, unit: &str, digits: usize) -> String {
    match v {
        Some(x) => format!("{x:.digits$}{unit}"),
        None => "-".to_string(),
    }
}

fn compare(path: PathBuf, seed: Option<u64>, out: Option<PathBuf>) -> anyhow::Result<()> {
    let scenario = Scenario::load(&path)?;
    let seed_used = seed.unwrap_or(scenario.seed);
    let out =
        out.unwrap_or_else(|| PathBuf::from(format!("out/compare-{}-{seed_used}", scenario.name)));
    println!(
        "sim-host: {} (seed {seed_used}) with and without slip compensation; the flight software \
         drives in both runs",
        scenario.name
    );
    let mut results = Vec::new();
    for (label, no_comp) in [("with compensation", false), ("without compensation", true)] {
        let dir = out.join(if no_comp { "no-comp" } else { "comp" });
        let (summary, result) = run_scenario(RunRequest {
            path: path.clone(),
            seed,
            out: Some(dir.clone()),
            no_slip_comp: no_comp,
            reference_driver: false,
            json: false,
            sim_counter: false,
            no_render: false,
            no_slip: false,
            no_vo: false,
            exact_dimensions: false,
            slip_model: None,
            ideal_lens: false,
            localization: false,
            quiet: true,
        })?;
        results.push((label, dir, summary, result));
    }
    println!();
    println!("  {:<30} {:>20} {:>22}", "", results[0].0, results[1].0);
    type Row = (&'static str, fn(&Summary) -> String);
    let rows: [Row; 9] = [
        ("goal", |s| {
            format!(
                "{} ({:.3} m)",
                if s.goal_reached { "reached" } else { "missed" },
                s.goal_miss_m
            )
        }),
        ("cross-track max (truth)", |s| {
            format!("{:.3} m", s.cross_track_m.max)
        }),
        ("cross-track rms (truth)", |s| {
            format!("{:.3} m", s.cross_track_m.rms)
        }),
        ("distance driven", |s| format!("{:.2} m", s.distance_m)),
        ("EKF final error", |s| fmt_opt(s.final_error_m.ekf, " m", 3)),
        ("VO final error", |s| fmt_opt(s.final_error_m.vo, " m", 3)),
        ("kinematic 3D final error", |s| {
            fmt_opt(s.final_error_m.kin3d, " m", 3)
        }),
        ("gate rejections (slip)", |s| {
            fmt_opt(s.slip.gate_reject_fraction.map(|f| 100.0 * f), " %", 1)
        }),
        ("VO updates / failures", |s| {
            format!(
                "{} / {}",
                s.vo.updates.unwrap_or(0),
                s.vo.failures.unwrap_or(0)
            )
        }),
    ];
    for (name, f) in rows {
        println!(
            "  {:<30} {:>20} {:>22}",
            name,
            f(&results[0].2),
            f(&results[1].2)
        );
    }
    println!();
    for (label, dir, _, _) in &results {
        println!("  {label}: outputs and report.html in {}", dir.display());
    }
    let figure = out.join("fig9-top-view.svg");
    std::fs::write(
        &figure,
        sim_host::output::report::compare_figure(&results[0].3, &results[1].3)?,
    )?;
    println!(
        "  H05 Fig. 9 figure (both runs on one equal-scale top view): {}",
        figure.display()
    );
    Ok(())
}

/// Run one scenario, write its outputs; returns the summary and the run.
fn run_scenario(req: RunRequest) -> anyhow::Result<(Summary, sim_host::closed_loop::RunResult)> {
    let RunRequest {
        path,
        seed,
        out,
        no_slip_comp,
        reference_driver,
        json,
        sim_counter,
        no_render,
        no_slip,
        no_vo,
        exact_dimensions,
        slip_model,
        ideal_lens,
        localization,
        quiet,
    } = req;
    let mut scenario = Scenario::load(&path)?;
    if ideal_lens {
        scenario.sensors.ideal_lens = true;
    }
    if no_slip {
        scenario.slip = false;
    }
    if exact_dimensions {
        scenario.sensors.dimension_error_m = 0.0;
        scenario.sensors.wheel_radius_error_m = 0.0;
    }
    match slip_model.as_deref() {
        None => {}
        Some("lumped") => scenario.slip_model = sim_host::scenario::SlipModelKind::Lumped,
        Some("terramechanics") => {
            scenario.slip_model = sim_host::scenario::SlipModelKind::Terramechanics;
        }
        Some(other) => anyhow::bail!("unknown slip model {other:?} (lumped, terramechanics)"),
    }
    let seed_used = seed.unwrap_or(scenario.seed);
    let renderer: Option<Box<dyn sim_host::devices::renderer::StereoRenderer>> =
        (!no_render).then(|| {
            let sun = scenario.site.sun_w(0.0);
            Box::new(sim_host::devices::renderer::TexturedRenderer::new(
                sim_host::devices::hazcam_calibration(),
                seed_used,
                [sun.x, sun.y, sun.z],
            )) as Box<dyn sim_host::devices::renderer::StereoRenderer>
        });
    let out = out.unwrap_or_else(|| PathBuf::from(format!("out/{}-{seed_used}", scenario.name)));
    let bar = (!json && scenario.duration_s > 30.0).then(|| {
        let bar = indicatif::ProgressBar::new(1000);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {percent}% {elapsed}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_message(format!(
            "{}{}",
            scenario.name,
            if no_slip_comp { " (no slip comp)" } else { "" }
        ));
        bar
    });
    let progress: Option<Box<dyn FnMut(f64)>> = bar.clone().map(|b| {
        Box::new(move |f: f64| b.set_position((f * 1000.0) as u64)) as Box<dyn FnMut(f64)>
    });
    let result = run(
        &scenario,
        RunOptions {
            seed,
            no_slip_comp,
            reference_driver,
            no_vo,
            localization,
            map_offset_m: [0.0; 2],
            counter: if sim_counter {
                CounterMode::SimTime
            } else {
                CounterMode::Host
            },
            renderer,
            progress,
            configure: None,
        },
    )?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let summary = sim_host::output::write_all(&out, &result)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok((summary, result));
    }
    if quiet {
        return Ok((summary, result));
    }
    let speedup = result.sim_time_s / result.wall_time_s.max(1e-9);
    println!(
        "sim-host run {} (seed {}): outputs in {}",
        result.scenario,
        result.seed,
        out.display()
    );
    let rows = [
        ("simulated time", format!("{:.1} s", result.sim_time_s)),
        (
            "wall time",
            format!("{:.2} s ({speedup:.0}x real time)", result.wall_time_s),
        ),
        ("distance", format!("{:.2} m", result.distance_m)),
        (
            "goal",
            format!(
                "{} (miss {:.3} m)",
                if result.goal_reached {
                    "reached"
                } else {
                    "not reached"
                },
                result.goal_miss_m
            ),
        ),
        (
            "cross-track",
            format!(
                "rms {:.3} m, max {:.3} m",
                summary.cross_track_m.rms, summary.cross_track_m.max
            ),
        ),
        (
            "true slip",
            format!(
                "mean ratio {:.3}, mean angle {:.2} deg",
                summary.slip.mean_slip_ratio, summary.slip.mean_slip_angle_deg
            ),
        ),
        (
            "true scrub",
            format!(
                "{:.2} % of the wheels' ground travel ({:+.2} % net): contacts sliding",
                summary.truth_scrub_pct, summary.truth_scrub_net_pct
            ),
        ),
        (
            "driver",
            format!(
                "{}, slip compensation {}, final mode {}",
                summary.driver,
                if summary.slip_compensation {
                    "on"
                } else {
                    "off"
                },
                summary.nav_mode
            ),
        ),
        (
            "final error",
            format!(
                "EKF {} VO {} kin3d {} kin2d {}",
                fmt_opt(summary.error_pct.ekf, " %", 2),
                fmt_opt(summary.error_pct.vo, " %", 2),
                fmt_opt(summary.error_pct.kin3d, " %", 2),
                fmt_opt(summary.error_pct.kin2d, " %", 2)
            ),
        ),
        (
            "attitude error max",
            format!(
                "EKF {} VO {}",
                fmt_opt(summary.max_attitude_error_deg.ekf, " deg", 2),
                fmt_opt(summary.max_attitude_error_deg.vo, " deg", 2)
            ),
        ),
        (
            "slip gate",
            format!(
                "{} of {} kinematic intervals rejected",
                summary.nav.kin_rejected, summary.nav.kin_tested
            ),
        ),
        (
            "radius scale",
            format!(
                "kin3d {:.4} (from VO, {} windows), EKF {:.4}",
                summary.radius_scale.kin3d,
                summary.radius_scale.kin3d_windows,
                summary.radius_scale.ekf
            ),
        ),
        (
            "kin3d track memory",
            format!(
                "heave corrected on {} of {} kinematic steps",
                summary.nav.track_matched,
                summary
                    .nav
                    .track_matched
                    .saturating_add(summary.nav.track_unmatched)
            ),
        ),
        (
            "VO",
            format!(
                "{} updates, {} failures, {} fused, {} rejected ({} rotation, {} forced), mean inliers {}",
                summary.nav.vo_updates,
                summary.nav.vo_failures,
                summary.nav.vo_fused,
                summary.nav.vo_rejected,
                summary.nav.vo_rejected_rotation,
                summary.nav.vo_forced,
                fmt_opt(summary.vo.mean_inliers, "", 1)
            ),
        ),
        (
            "device faults",
            format!("{} counted by the flight software", result.device_faults),
        ),
    ];
    for (k, v) in rows {
        println!("  {k:<18} {v}");
    }
    println!(
        "  {:<6} {:>8} {:>10} {:>10} {:>9}",
        "group", "runs", "max_us", "mean_us", "overruns"
    );
    for g in &result.timing {
        println!(
            "  {:<6} {:>8} {:>10} {:>10} {:>9}",
            g.name, g.runs, g.max_us, g.mean_us, g.overruns
        );
    }
    Ok((summary, result))
}

fn sil(out: PathBuf, scenarios: PathBuf, summaries: Option<PathBuf>) -> anyhow::Result<()> {
    use rayon::prelude::*;
    println!(
        "sim-host sil: {} cases with rendered stereo, in parallel",
        sim_host::commands::sil::CASES.len()
    );
    let results: Vec<_> = sim_host::commands::sil::CASES
        .par_iter()
        .map(|c| sim_host::commands::sil::run_case(*c, &scenarios))
        .collect::<anyhow::Result<_>>()?;
    if let Some(dir) = &summaries {
        std::fs::create_dir_all(dir)?;
        for r in &results {
            let json = serde_json::to_string_pretty(&r.summary)?;
            std::fs::write(dir.join(format!("{}.json", r.case.id)), json + "\n")?;
        }
    }
    let page = sim_host::commands::sil::markdown(&results);
    std::fs::write(&out, &page)?;
    print!("{page}");
    println!("written to {}", out.display());
    if results.iter().all(|r| r.passed()) {
        Ok(())
    } else {
        anyhow::bail!("a SIL requirement failed")
    }
}

fn detection(out: PathBuf, figure: PathBuf, scenarios: PathBuf) -> anyhow::Result<()> {
    use sim_host::commands::detection;
    let n = detection::jobs().len();
    println!("sim-host detection: {n} runs with rendered stereo, 2 at a time");
    let study = detection::run_study(&scenarios)?;
    let page = detection::markdown(&study, detection::READING);
    let svg = detection::svg(&study)?;
    for path in [&out, &figure] {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
    }
    std::fs::write(&out, &page)?;
    std::fs::write(&figure, &svg)?;
    print!("{page}");
    println!(
        "written to {} and {} ({:.0} s wall time)",
        out.display(),
        figure.display(),
        study.wall_time_s
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Still { frames }) => still(frames),
        None => compare(default_scenario(), None, None),
        Some(Command::Compare {
            scenario,
            seed,
            out,
        }) => compare(scenario, seed, out),
        Some(Command::Sil {
            out,
            scenarios,
            summaries,
        }) => sil(out, scenarios, summaries),
        Some(Command::Detection {
            out,
            figure,
            scenarios,
        }) => detection(out, figure, scenarios),
        Some(Command::Run {
            scenario,
            seed,
            out,
            no_slip_comp,
            reference_driver,
            json,
            sim_counter,
            no_render,
            no_slip,
            no_vo,
            exact_dimensions,
            slip_model,
            ideal_lens,
            localization,
        }) => run_scenario(RunRequest {
            path: scenario,
            seed,
            out,
            no_slip_comp,
            reference_driver,
            json,
            sim_counter,
            no_render,
            no_slip,
            no_vo,
            exact_dimensions,
            slip_model,
            ideal_lens,
            localization,
            quiet: false,
        })
        .map(|_| ()),
        Some(Command::Record {
            scenario,
            seconds,
            seed,
            out,
            no_render,
        }) => record(scenario, seconds, seed, out, no_render),
        Some(Command::Replay { tape, digests }) => replay(tape, digests),
        Some(Command::Campaign(args)) => {
            if !sim_host::commands::campaign::main(args)? {
                std::process::exit(sim_host::commands::campaign::EXIT_NOT_PASSED);
            }
            Ok(())
        }
    }
}
