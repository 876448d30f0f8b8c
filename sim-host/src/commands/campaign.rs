//! The `campaign` subcommand of `sim-host`: `plan`, `run`, `gather`, `local`, `slurm`.

use crate::campaign::{exec, html, plan, slurm, stats};
use clap::{Args, Subcommand, ValueEnum};
use std::path::{Path, PathBuf};

/// `sim-host campaign ...`.
#[derive(Debug, Args)]
pub struct CampaignArgs {
    /// What to do.
    #[command(subcommand)]
    pub command: CampaignCommand,
}

/// The campaign commands.
#[derive(Debug, Subcommand)]
pub enum CampaignCommand {
    /// Expand a spec into DIR/manifest.json (every run's index, seeds and drawn parameters).
    Plan {
        /// Campaign spec (TOML), e.g. campaigns/slope-10-cross.toml.
        spec: PathBuf,
        /// Campaign folder.
        #[arg(long)]
        out: PathBuf,
        /// Number of runs (default: the spec's); run i is the same run whatever the count.
        #[arg(long)]
        runs: Option<u64>,
    },
    /// Run one index (or a shard of the indices) of a planned campaign: DIR/runs/I/summary.json.
    Run {
        /// Campaign folder (holds manifest.json).
        dir: PathBuf,
        /// Run index.
        #[arg(long, conflicts_with = "shard", required_unless_present = "shard")]
        index: Option<u64>,
        /// Shard K/N: the indices K, K + N, K + 2N, ... one after the other.
        #[arg(long)]
        shard: Option<String>,
        /// Also write every output of `sim-host run` (trajectories, report) for the index here.
        #[arg(long, requires = "index")]
        outputs: Option<PathBuf>,
    },
    /// Statistics, criteria and report of the runs of DIR: stats.json, report.html.
    Gather {
        /// Campaign folder.
        dir: PathBuf,
    },
    /// Plan, run (in parallel, with a progress bar) and gather on this machine.
    Local {
        /// Campaign spec (TOML).
        spec: PathBuf,
        /// Campaign folder.
        #[arg(long)]
        out: PathBuf,
        /// Number of runs (default: the spec's).
        #[arg(long)]
        runs: Option<u64>,
        /// Runs at once (default: one per core).
        #[arg(long)]
        jobs: Option<usize>,
        /// Run again the indices that already have a summary in DIR.
        #[arg(long)]
        rerun: bool,
    },
    /// Plan and write the Slurm scripts (job array and dependent gather); --submit submits them.
    Slurm(SlurmArgs),
}

/// `sim-host campaign slurm SPEC --out DIR [OPTIONS]`.
#[derive(Debug, Args)]
pub struct SlurmArgs {
    /// Campaign spec (TOML).
    pub spec: PathBuf,
    /// Campaign folder (on a filesystem every node sees).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of runs (default: the spec's).
    #[arg(long)]
    pub runs: Option<u64>,
    /// The job array, the job after it, and their submission.
    #[command(flatten)]
    pub batch: BatchArgs,
}

/// Options of a Slurm job array and of the job that runs after it (the campaign's gather, the
/// SIL's merge); shared by `campaign slurm` and `sil --slurm`.
#[derive(Debug, Clone, Args)]
pub struct BatchArgs {
    /// Array tasks running at once (the `%` of --array); 0: no limit.
    #[arg(long, default_value_t = 0)]
    pub throttle: u64,
    /// Array tasks at most (Slurm's MaxArraySize is 1001 by default); more runs are split
    /// into this many shards.
    #[arg(long, default_value_t = 1000)]
    pub tasks: u64,
    /// Partition.
    #[arg(long)]
    pub partition: Option<String>,
    /// Account.
    #[arg(long)]
    pub account: Option<String>,
    /// Quality of service.
    #[arg(long)]
    pub qos: Option<String>,
    /// Time limit of each array task.
    #[arg(long, default_value = "00:30:00")]
    pub time: String,
    /// Time limit of the job after the array (gather, merge).
    #[arg(long, default_value = "00:30:00")]
    pub gather_time: String,
    /// CPUs per array task (the renderer's threads).
    #[arg(long, default_value_t = 1)]
    pub cpus_per_task: u32,
    /// Memory per task.
    #[arg(long, default_value = "1G")]
    pub mem: String,
    /// Start the job after the array when every task succeeded (ok) or ended (any).
    #[arg(long, value_enum, default_value_t = After::Ok)]
    pub gather_after: After,
    /// More #SBATCH options for both scripts (repeatable), e.g. --sbatch=--constraint=x86.
    #[arg(long = "sbatch", allow_hyphen_values = true)]
    pub extra: Vec<String>,
    /// sim-host binary the jobs run (default: this one).
    #[arg(long)]
    pub bin: Option<PathBuf>,
    /// Submit with sbatch and print the job ids.
    #[arg(long)]
    pub submit: bool,
    /// With --submit: wait until the job after the array ends (fails if it fails or cannot
    /// start).
    #[arg(long, requires = "submit")]
    pub wait: bool,
    /// With --wait: give up after this many seconds.
    #[arg(long, default_value_t = 7200.0)]
    pub timeout: f64,
}

impl BatchArgs {
    /// The scripts' options (the binary made absolute).
    pub fn options(&self) -> anyhow::Result<slurm::SlurmOptions> {
        Ok(slurm::SlurmOptions {
            bin: match &self.bin {
                Some(b) => slurm::absolute(b)?,
                None => std::env::current_exe()?,
            },
            tasks: self.tasks,
            throttle: self.throttle,
            partition: self.partition.clone(),
            account: self.account.clone(),
            qos: self.qos.clone(),
            time: self.time.clone(),
            gather_time: self.gather_time.clone(),
            cpus_per_task: self.cpus_per_task,
            mem: self.mem.clone(),
            gather_after: self.gather_after.into(),
            extra: self.extra.clone(),
        })
    }
}

impl From<After> for slurm::GatherAfter {
    fn from(a: After) -> Self {
        match a {
            After::Ok => slurm::GatherAfter::Ok,
            After::Any => slurm::GatherAfter::Any,
        }
    }
}

/// `--gather-after`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum After {
    /// afterok.
    Ok,
    /// afterany.
    Any,
}

/// Exit status of `gather` and `local` when the verdict is not `pass` (after writing
/// everything).
pub const EXIT_NOT_PASSED: i32 = 2;

/// Run a campaign command. `Ok(false)`: finished, but the verdict is not `pass`.
pub fn main(args: CampaignArgs) -> anyhow::Result<bool> {
    match args.command {
        CampaignCommand::Plan { spec, out, runs } => {
            let m = plan::plan_to_dir(&spec, &out, runs)?;
            println!(
                "campaign {}: {} runs planned in {}",
                m.campaign,
                m.runs,
                out.join("manifest.json").display()
            );
            Ok(true)
        }
        CampaignCommand::Run {
            dir,
            index,
            shard,
            outputs,
        } => run(&dir, index, shard, outputs.as_deref()),
        CampaignCommand::Gather { dir } => gather(&dir),
        CampaignCommand::Local {
            spec,
            out,
            runs,
            jobs,
            rerun,
        } => local(&spec, &out, runs, jobs, rerun),
        CampaignCommand::Slurm(args) => submit_slurm(args),
    }
}

/// `campaign run`: one index (every output with `outputs`) or a shard, one after the other.
fn run(
    dir: &Path,
    index: Option<u64>,
    shard: Option<String>,
    outputs: Option<&Path>,
) -> anyhow::Result<bool> {
    let manifest = plan::Manifest::load(dir)?;
    let indices = match (index, shard) {
        (Some(i), _) => {
            manifest.entry(i)?;
            vec![i]
        }
        (None, Some(s)) => {
            let (k, n) = exec::parse_shard(&s)?;
            exec::shard_indices(manifest.runs, k, n)
        }
        (None, None) => anyhow::bail!("give --index I or --shard K/N"),
    };
    if let (Some(out), [i]) = (outputs, indices.as_slice()) {
        let s = exec::run_index(dir, &manifest, *i, Some(out))?;
        println!(
            "run {i}: goal {} cross-track max {:.3} m; every output in {}",
            if s.goal_reached { "reached" } else { "missed" },
            s.cross_track_m.max,
            out.display()
        );
        return Ok(true);
    }
    let failed = exec::run_sequential(dir, &manifest, &indices);
    anyhow::ensure!(failed == 0, "{failed} of {} runs failed", indices.len());
    Ok(true)
}

/// `campaign local`: plan, run what is not done (or everything with `rerun`) in parallel,
/// gather.
fn local(
    spec: &Path,
    out: &Path,
    runs: Option<u64>,
    jobs: Option<usize>,
    rerun: bool,
) -> anyhow::Result<bool> {
    let manifest = plan::plan_to_dir(spec, out, runs)?;
    let todo: Vec<u64> = (0..manifest.runs)
        .filter(|&i| rerun || !exec::is_done(out, i))
        .collect();
    let done = manifest.runs - todo.len() as u64;
    println!(
        "campaign {}: {} runs of {} ({} to run{}), output in {}",
        manifest.campaign,
        manifest.runs,
        manifest.base_scenario()?.name,
        todo.len(),
        if done > 0 {
            format!(", {done} already done")
        } else {
            String::new()
        },
        out.display()
    );
    let start = std::time::Instant::now();
    let failed = exec::run_parallel(out, &manifest, &todo, jobs)?;
    println!(
        "{} runs in {:.1} s wall time, {} failed",
        todo.len(),
        start.elapsed().as_secs_f64(),
        failed.len()
    );
    for (i, e) in &failed {
        eprintln!("run {i}: FAILED: {e}");
    }
    gather(out)
}

/// `campaign slurm`: plan, write the scripts, and with `--submit` submit them (and with
/// `--wait` wait for the gather and read its verdict).
fn submit_slurm(args: SlurmArgs) -> anyhow::Result<bool> {
    let SlurmArgs {
        spec,
        out,
        runs,
        batch,
    } = args;
    let manifest = plan::plan_to_dir(&spec, &out, runs)?;
    let dir = slurm::absolute(&out)?;
    let options = batch.options()?;
    let after = options.gather_after;
    let (submit, wait, timeout) = (batch.submit, batch.wait, batch.timeout);
    slurm::write_scripts(&manifest.campaign, manifest.runs, &dir, &options)?;
    println!(
        "campaign {}: {} runs planned; wrote {} and {}",
        manifest.campaign,
        manifest.runs,
        dir.join("campaign.sbatch").display(),
        dir.join("gather.sbatch").display()
    );
    if !submit {
        println!(
            "submit: jid=$(sbatch --parsable {d}/campaign.sbatch) && sbatch \
             --dependency={dep}:$jid {d}/gather.sbatch",
            d = dir.display(),
            dep = after.dependency()
        );
        return Ok(true);
    }
    let (array, gather_id) = slurm::submit(&dir, after)?;
    println!("submitted: array job {array}, gather job {gather_id}");
    if wait {
        slurm::wait(&dir, &gather_id, timeout)?;
        let stats: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("stats.json"))?)?;
        let verdict = stats.get("verdict").and_then(|v| v.as_str()).unwrap_or("?");
        println!(
            "campaign {}: verdict {verdict}; {}",
            manifest.campaign,
            dir.join("report.html").display()
        );
        return Ok(verdict == "pass");
    }
    Ok(true)
}

/// Gather `dir`: write `stats.json`, `report.html`, `runtime.json`, print the criteria.
pub fn gather(dir: &Path) -> anyhow::Result<bool> {
    let manifest = plan::Manifest::load(dir)?;
    let g = stats::gather(dir, &manifest)?;
    exec::write_atomic(&dir.join("stats.json"), &stats::stats_text(&g.stats)?)?;
    exec::write_atomic(&dir.join("report.html"), &html::report_html(&manifest, &g)?)?;
    exec::write_atomic(&dir.join("runtime.json"), &stats::runtime_text(&g.times)?)?;
    let s = &g.stats;
    println!(
        "campaign {}: {} of {} runs with a summary, {} failed, {} missing",
        s.campaign,
        s.runs_ok,
        s.runs_planned,
        s.failed_runs.len(),
        s.missing_runs.len()
    );
    for f in &s.failed_runs {
        println!("  run {} (seed {}) failed: {}", f.index, f.seed, f.error);
    }
    if !s.missing_runs.is_empty() {
        println!("  missing runs: {:?}", s.missing_runs);
    }
    for c in &s.criteria {
        println!(
            "  {:<4} {:<34} {} {} {} {} {}: measured {}{}",
            if c.pass { "PASS" } else { "FAIL" },
            c.name,
            c.stat,
            c.metric,
            c.op,
            html::fmt_num(c.threshold),
            c.unit,
            c.value.map_or("-".into(), html::fmt_num),
            c.value_run.map_or(String::new(), |r| format!(" (run {r})"))
        );
    }
    if let Some(t) = g.times.iter().map(|t| t.1).reduce(f64::max) {
        let mean = g.times.iter().map(|t| t.1).sum::<f64>() / g.times.len() as f64;
        println!("  wall time per run: mean {mean:.2} s, max {t:.2} s (runtime.json)");
    }
    println!(
        "verdict {}: {} and {}",
        s.verdict.to_uppercase(),
        dir.join("stats.json").display(),
        dir.join("report.html").display()
    );
    Ok(s.verdict == "pass")
}
