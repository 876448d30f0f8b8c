//! `sim-host`: the product's main command. Runs the flight software on the simulated rover and
//! prints a summary.

use clap::{Parser, Subcommand};

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
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let frames = match cli.command {
        Some(Command::Still { frames }) => frames,
        None => 2000,
    };
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
