//! `sim-host compare` (and `sim-host` without a command): one scenario run twice by the flight
//! software, with and without slip compensation; the comparison table, both runs' outputs and
//! the H05 Fig. 9 top view of both runs.

use super::run::{fmt_opt, run_scenario, Drive, RunFlags};
use crate::output::summary::Summary;
use std::path::PathBuf;

/// `sim-host compare [SCENARIO] [OPTIONS]`.
#[derive(Debug, Clone, clap::Args)]
pub struct CompareArgs {
    /// Scenario file (TOML).
    #[arg(default_value_os_t = default_scenario())]
    pub scenario: PathBuf,
    /// Output directory; the two runs go to `<out>/comp` and `<out>/no-comp`
    /// (default: out/compare-<scenario>-<seed>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The options of `run`, applied to both runs.
    #[command(flatten)]
    pub flags: RunFlags,
}

impl CompareArgs {
    /// The main command without a command: `slope-10-cross` with the default options.
    pub fn default_run() -> Self {
        Self {
            scenario: default_scenario(),
            out: None,
            flags: RunFlags::default(),
        }
    }
}

/// `scenarios/slope-10-cross.toml` of the working directory, or of the source tree.
pub fn default_scenario() -> PathBuf {
    let local = PathBuf::from("scenarios/slope-10-cross.toml");
    if local.exists() {
        return local;
    }
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenarios/slope-10-cross.toml")
}

/// One row of the comparison table: its label and how it reads a summary.
type Row = (&'static str, fn(&Summary) -> String);

/// The rows of the comparison table.
const ROWS: [Row; 9] = [
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

/// Run `sim-host compare`: both runs, the table, the outputs and the figure.
pub fn main(args: CompareArgs) -> anyhow::Result<()> {
    let scenario = args.flags.scenario(&args.scenario)?;
    let seed_used = args.flags.seed.unwrap_or(scenario.seed);
    let out = args
        .out
        .unwrap_or_else(|| PathBuf::from(format!("out/compare-{}-{seed_used}", scenario.name)));
    println!(
        "sim-host: {} (seed {seed_used}) with and without slip compensation; the flight software \
         drives in both runs",
        scenario.name
    );
    let mut results = Vec::new();
    for (label, no_comp) in [("with compensation", false), ("without compensation", true)] {
        let dir = out.join(if no_comp { "no-comp" } else { "comp" });
        let drive = Drive {
            no_slip_comp: no_comp,
            reference_driver: false,
        };
        let (summary, result) = run_scenario(&scenario, &args.flags, drive, &dir, true)?;
        results.push((label, dir, summary, result));
    }
    println!();
    println!("  {:<30} {:>20} {:>22}", "", results[0].0, results[1].0);
    for (name, f) in ROWS {
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
        crate::output::report::compare_figure(&results[0].3, &results[1].3)?,
    )?;
    println!(
        "  H05 Fig. 9 figure (both runs on one equal-scale top view): {}",
        figure.display()
    );
    Ok(())
}
