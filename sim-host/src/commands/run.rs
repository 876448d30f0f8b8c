//! `sim-host run`: one scenario in closed loop, its output files and its summary table.
//!
//! [`RunFlags`] are the options of a run that change what is simulated or how it is measured
//! (seed, execution counter, rendering, slip, VO, dimensions, slip model, lenses,
//! localization); `run` and `compare` ([`super::compare`]) both take them. The options of
//! `run` alone ([`RunArgs`]): the output directory, the drive without slip compensation, the
//! reference driver and the JSON summary.

use crate::closed_loop::{run, RunOptions, RunResult};
use crate::devices::renderer::{StereoRenderer, TexturedRenderer};
use crate::devices::world::CounterMode;
use crate::output::summary::Summary;
use crate::scenario::{Scenario, SlipModelKind};
use std::path::{Path, PathBuf};

/// The options of a run shared by `run` and `compare` (`compare` applies them to both of its
/// runs).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RunFlags {
    /// Seed (default: the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Use simulated time as the execution counter: timing figures read 0 and every output
    /// file is byte-identical for the same scenario and seed (except wall_time_s).
    #[arg(long)]
    pub sim_counter: bool,
    /// Skip rendering the stereo images (uniform grey frames): faster, but visual odometry
    /// has nothing to track.
    #[arg(long)]
    pub no_render: bool,
    /// The terrain produces no slip (every axle moves at its wheel's rim speed).
    #[arg(long)]
    pub no_slip: bool,
    /// Visual odometry off in the flight software: the EKF gets IMU, sun sensor and
    /// kinematics (the cameras still capture).
    #[arg(long)]
    pub no_vo: bool,
    /// The truth vehicle gets the published dimensions exactly (no per-seed dimension or
    /// wheel-radius errors), as the SIL kinematic cases run it.
    #[arg(long)]
    pub exact_dimensions: bool,
    /// Slip model of the truth (overrides the scenario's): `terramechanics` (per wheel,
    /// docs/terramechanics.md; the default) or `lumped`.
    #[arg(long)]
    pub slip_model: Option<String>,
    /// Ideal lenses: the cameras deliver the rectified pinhole pair (no wide-angle lens
    /// model, no rectification in the flight software), for comparison.
    #[arg(long)]
    pub ideal_lens: bool,
    /// Terrain-map localization on (V99 sec. 5): the simulator uplinks a global map of its
    /// rocks as a MARDI descent image from 50 m shows them; the flight software matches
    /// its hazard maps against it (docs/localization.md).
    #[arg(long)]
    pub localization: bool,
}

impl RunFlags {
    /// The scenario at `path` with the flags' overrides applied (lenses, slip, dimensions,
    /// slip model).
    pub fn scenario(&self, path: &Path) -> anyhow::Result<Scenario> {
        let mut scenario = Scenario::load(path)?;
        if self.ideal_lens {
            scenario.sensors.ideal_lens = true;
        }
        if self.no_slip {
            scenario.slip = false;
        }
        if self.exact_dimensions {
            scenario.sensors.dimension_error_m = 0.0;
            scenario.sensors.wheel_radius_error_m = 0.0;
        }
        match self.slip_model.as_deref() {
            None => {}
            Some("lumped") => scenario.slip_model = SlipModelKind::Lumped,
            Some("terramechanics") => scenario.slip_model = SlipModelKind::Terramechanics,
            Some(other) => anyhow::bail!("unknown slip model {other:?} (lumped, terramechanics)"),
        }
        Ok(scenario)
    }

    /// The stereo renderer of a run of `scenario` with seed `seed` (`None` with
    /// `--no-render`: uniform grey frames).
    fn renderer(&self, scenario: &Scenario, seed: u64) -> Option<Box<dyn StereoRenderer>> {
        (!self.no_render).then(|| {
            let sun = scenario.site.sun_w(0.0);
            Box::new(TexturedRenderer::new(
                crate::devices::hazcam_calibration(),
                seed,
                [sun.x, sun.y, sun.z],
            )) as Box<dyn StereoRenderer>
        })
    }

    /// The execution counter of the flight clock.
    fn counter(&self) -> CounterMode {
        if self.sim_counter {
            CounterMode::SimTime
        } else {
            CounterMode::Host
        }
    }
}

/// Who commands the motors, and whether the drive compensates slip.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Drive {
    /// Drive without slip compensation.
    pub no_slip_comp: bool,
    /// The simulator's reference driver commands the motors instead of the flight software.
    pub reference_driver: bool,
}

/// `sim-host run SCENARIO [OPTIONS]`.
#[derive(Debug, Clone, clap::Args)]
pub struct RunArgs {
    /// Scenario file (TOML), e.g. scenarios/slope-10-cross.toml.
    pub scenario: PathBuf,
    /// Output directory (default: out/<scenario>-<seed>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Drive without slip compensation: the flight software navigates on wheel and IMU
    /// odometry only (with --reference-driver: the reference driver holds heading open loop).
    #[arg(long)]
    pub no_slip_comp: bool,
    /// Let the simulator's reference driver (which sees the truth) command the motors
    /// instead of the flight software.
    #[arg(long)]
    pub reference_driver: bool,
    /// Print summary.json to stdout instead of the table.
    #[arg(long)]
    pub json: bool,
    /// The options shared with `compare`.
    #[command(flatten)]
    pub flags: RunFlags,
}

/// Run `sim-host run`: the scenario, its outputs, and the summary table (or `summary.json`
/// with `--json`) on stdout.
pub fn main(args: RunArgs) -> anyhow::Result<()> {
    let drive = Drive {
        no_slip_comp: args.no_slip_comp,
        reference_driver: args.reference_driver,
    };
    let scenario = args.flags.scenario(&args.scenario)?;
    let seed_used = args.flags.seed.unwrap_or(scenario.seed);
    let out = args
        .out
        .unwrap_or_else(|| PathBuf::from(format!("out/{}-{seed_used}", scenario.name)));
    let (summary, result) = run_scenario(&scenario, &args.flags, drive, &out, !args.json)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print_summary(&result, &summary, &out);
    }
    Ok(())
}

/// A progress bar for a run longer than 30 simulated seconds (`None` for shorter runs and
/// without `progress`).
fn progress_bar(
    scenario: &Scenario,
    drive: Drive,
    progress: bool,
) -> Option<indicatif::ProgressBar> {
    (progress && scenario.duration_s > 30.0).then(|| {
        let bar = indicatif::ProgressBar::new(1000);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {percent}% {elapsed}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_message(format!(
            "{}{}",
            scenario.name,
            if drive.no_slip_comp {
                " (no slip comp)"
            } else {
                ""
            }
        ));
        bar
    })
}

/// Run `scenario` (already loaded with [`RunFlags::scenario`]) with `flags` and `drive`, and
/// write its outputs into `out`; with `progress` a run over 30 simulated seconds shows a
/// progress bar. Returns the summary and the run.
pub fn run_scenario(
    scenario: &Scenario,
    flags: &RunFlags,
    drive: Drive,
    out: &Path,
    progress: bool,
) -> anyhow::Result<(Summary, RunResult)> {
    let seed_used = flags.seed.unwrap_or(scenario.seed);
    let renderer = flags.renderer(scenario, seed_used);
    let bar = progress_bar(scenario, drive, progress);
    let on_progress: Option<Box<dyn FnMut(f64)>> = bar.clone().map(|b| {
        Box::new(move |f: f64| b.set_position((f * 1000.0) as u64)) as Box<dyn FnMut(f64)>
    });
    let result = run(
        scenario,
        RunOptions {
            seed: flags.seed,
            no_slip_comp: drive.no_slip_comp,
            reference_driver: drive.reference_driver,
            no_vo: flags.no_vo,
            localization: flags.localization,
            map_offset_m: [0.0; 2],
            counter: flags.counter(),
            renderer,
            progress: on_progress,
            configure: None,
        },
    )?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let summary = crate::output::write_all(out, &result)?;
    Ok((summary, result))
}

/// `v` with `digits` decimals and `unit`, or `-`.
pub fn fmt_opt(v: Option<f64>, unit: &str, digits: usize) -> String {
    match v {
        Some(x) => format!("{x:.digits$}{unit}"),
        None => "-".to_string(),
    }
}

/// The summary table of a run (`sim-host run` without `--json`).
fn print_summary(result: &RunResult, summary: &Summary, out: &Path) {
    println!(
        "sim-host run {} (seed {}): outputs in {}",
        result.scenario,
        result.seed,
        out.display()
    );
    for (k, v) in summary_rows(result, summary) {
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
}

/// The rows of the summary table: what the run did (time, distance, goal, slip, driver).
fn summary_rows(result: &RunResult, summary: &Summary) -> Vec<(&'static str, String)> {
    let speedup = result.sim_time_s / result.wall_time_s.max(1e-9);
    let mut rows = vec![
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
    ];
    rows.extend(estimate_rows(result, summary));
    rows
}

/// The rows of the summary table about the flight estimates (errors, gate, radius scale,
/// track memory, VO, device faults).
fn estimate_rows(result: &RunResult, summary: &Summary) -> Vec<(&'static str, String)> {
    vec![
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
    ]
}
