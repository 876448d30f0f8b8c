//! `sim-host`: the product's main command. Runs the flight software on the simulated rover and
//! prints a summary. With no arguments it runs `slope-10-cross` with and without slip
//! compensation and prints the comparison. Each subcommand lives in [`sim_host::commands`].

use clap::{Parser, Subcommand};
use sim_host::commands;

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
    #[command(after_help = "The options of `run` apply to both runs, apart from \
                            `--no-slip-comp` (the comparison is the two settings), \
                            `--reference-driver` (the flight software drives both runs) and \
                            `--json` (the comparison is a table), which only `run` takes.")]
    Compare(commands::compare::CompareArgs),
    /// Run the flight executive on a rover standing still for N minor frames (200 Hz).
    Still(commands::still::StillArgs),
    /// Run the SIL acceptance cases (in parallel) and write the results page.
    Sil(Box<commands::sil::SilArgs>),
    /// Measure the slip gate's detection probability against the true slip magnitude (slope
    /// sweeps of slope-10-cross, two seeds, in parallel) and the slip-hold policy; write the
    /// results page and its figure.
    Detection(commands::detection::DetectionArgs),
    /// Run a scenario file in closed loop and write the outputs.
    Run(commands::run::RunArgs),
    /// Record the HAL call tape of a scenario segment (with rendered stereo images) for replay
    /// on the host or the rover CPU (docs/results/timing.md).
    Record(commands::record::RecordArgs),
    /// Monte Carlo campaigns: plan, run, gather, local, slurm (docs/campaigns.md).
    Campaign(commands::campaign::CampaignArgs),
    /// Replay a call tape through the flight software and print per-frame digest lines;
    /// fails unless every frame matches the recording.
    Replay(commands::replay::ReplayArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        None => commands::compare::main(commands::compare::CompareArgs::default_run()),
        Some(Command::Compare(args)) => commands::compare::main(args),
        Some(Command::Still(args)) => commands::still::main(args),
        Some(Command::Sil(args)) => commands::sil::main(*args),
        Some(Command::Detection(args)) => commands::detection::main(args),
        Some(Command::Run(args)) => commands::run::main(args),
        Some(Command::Record(args)) => commands::record::main(args),
        Some(Command::Replay(args)) => commands::replay::main(args),
        Some(Command::Campaign(args)) => {
            if !commands::campaign::main(args)? {
                std::process::exit(commands::campaign::EXIT_NOT_PASSED);
            }
            Ok(())
        }
    }
}
