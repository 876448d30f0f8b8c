//! `sim-host`: the product's main command. Runs the flight software on the simulated rover and
//! prints a summary.

use clap::{Parser, Subcommand};
use sim_host::hal_devices::CounterMode;
use sim_host::scenario::Scenario;
use sim_host::sim::{run, RunOptions};
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
    /// Run the flight executive on a rover standing still for N minor frames (200 Hz).
    Still {
        /// Number of 5 ms minor frames.
        #[arg(long, default_value_t = 2000)]
        frames: u64,
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
        /// Drive without slip compensation (the reference driver holds heading open loop).
        #[arg(long)]
        no_slip_comp: bool,
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
    let recording = sim_host::record::record(
        &scenario,
        sim_host::record::RecordOptions {
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
    let outcome = sim_host::replay::replay(&tape)?;
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
    let summary = sim_host::run::run_still(frames)?;
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

fn run_scenario(
    path: PathBuf,
    seed: Option<u64>,
    out: Option<PathBuf>,
    no_slip_comp: bool,
    json: bool,
    sim_counter: bool,
    no_render: bool,
) -> anyhow::Result<()> {
    let scenario = Scenario::load(&path)?;
    let seed_used = seed.unwrap_or(scenario.seed);
    let renderer: Option<Box<dyn sim_host::camera::StereoRenderer>> = (!no_render).then(|| {
        let sun = &scenario.sensors.sun;
        Box::new(sim_host::camera::TexturedRenderer::new(
            sim_host::devices::hazcam_calibration(),
            seed_used,
            sun.azimuth_deg,
            sun.elevation_deg,
        )) as Box<dyn sim_host::camera::StereoRenderer>
    });
    let out = out.unwrap_or_else(|| PathBuf::from(format!("out/{}-{seed_used}", scenario.name)));
    let bar = (!json && scenario.duration_s > 30.0).then(|| {
        let bar = indicatif::ProgressBar::new(1000);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {percent}% {elapsed}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_message(scenario.name.clone());
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
            counter: if sim_counter {
                CounterMode::SimTime
            } else {
                CounterMode::Host
            },
            renderer,
            progress,
        },
    )?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let summary = sim_host::output::write_all(&out, &result)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(());
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
            "flight estimates",
            "EKF, VO, kin3d, kin2d: none yet (null)".to_string(),
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
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Still { frames }) => still(frames),
        None => still(2000),
        Some(Command::Run {
            scenario,
            seed,
            out,
            no_slip_comp,
            json,
            sim_counter,
            no_render,
        }) => run_scenario(
            scenario,
            seed,
            out,
            no_slip_comp,
            json,
            sim_counter,
            no_render,
        ),
        Some(Command::Record {
            scenario,
            seconds,
            seed,
            out,
            no_render,
        }) => record(scenario, seconds, seed, out, no_render),
        Some(Command::Replay { tape, digests }) => replay(tape, digests),
    }
}
