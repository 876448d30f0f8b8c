//! `sim-host sil`: the release tier (every case on the acceptance seeds, in parallel with a
//! progress bar and an estimate of the time left; or one shard of it for a Slurm job array),
//! the results page from the rows, and the replay of one case on one seed.

use super::seeds::{self, SeedRow};
use super::{run_case, CASES};
use std::path::PathBuf;

/// `sim-host sil [OPTIONS]`.
#[derive(Debug, Clone, clap::Args)]
pub struct SilArgs {
    /// Seeds per case, from the first acceptance seed (1001). The release tier is at least 50.
    #[arg(long, default_value_t = seeds::RELEASE_SEEDS)]
    pub seeds: u64,
    /// Skip the first K of the seeds (run seeds K..N): more seeds for rows made before, to
    /// `--merge` with them.
    #[arg(long, default_value_t = 0)]
    pub skip_seeds: u64,
    /// Only this case (with `--seed`: replay it on that seed).
    #[arg(long)]
    pub case: Option<String>,
    /// With `--case`: run that seed only, print its checks and write every output of the run
    /// into `--outputs` (default `out/sil/<case>-<seed>`).
    #[arg(long, requires = "case")]
    pub seed: Option<u64>,
    /// Output directory of a replay.
    #[arg(long, requires = "seed")]
    pub outputs: Option<PathBuf>,
    /// Run shard K/N of the (case, seed) runs only and write their rows to `--rows` (no page):
    /// one task of a Slurm job array (`docs/sil.md`).
    #[arg(long)]
    pub shard: Option<String>,
    /// Make the page from these row files (the shards' rows) instead of running.
    #[arg(long, num_args = 1.., conflicts_with_all = ["shard", "seed"])]
    pub merge: Vec<PathBuf>,
    /// With `--merge`: the commit the merged rows were made from (default: this checkout's).
    #[arg(long, requires = "merge")]
    pub made_from: Option<String>,
    /// Rows to write (JSON lines).
    #[arg(long, default_value = seeds::RELEASE_ROWS)]
    pub rows: PathBuf,
    /// Results page to write.
    #[arg(long, default_value = "docs/results/sil-results.md")]
    pub out: PathBuf,
    /// Directory of the scenario files.
    #[arg(long, default_value = "scenarios")]
    pub scenarios: PathBuf,
    /// Runs at once (default: one per core).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Also write each run's `summary.json` into this directory, as `<case id>-<seed>.json`
    /// (for comparing the runs of two builds, `tools/behaviour.sh`).
    #[arg(long)]
    pub summaries: Option<PathBuf>,
    /// Fail unless every row (run or merged) equals the row of the same case and seed in
    /// this file (values, final mode and metrics; the wall time aside), e.g. the release rows.
    #[arg(long)]
    pub expect: Option<PathBuf>,
    /// Write the tier as a Slurm job array into this folder (on a filesystem every node sees):
    /// `sil.sbatch` runs the shards, `merge.sbatch` makes the rows (`--rows`) and the page
    /// (`--out`) after it (`docs/sil.md`).
    #[arg(long, conflicts_with_all = ["shard", "merge", "seed"])]
    pub slurm: Option<PathBuf>,
    /// With `--slurm`: the job array and its submission.
    #[command(flatten)]
    pub batch: crate::commands::campaign::BatchArgs,
}

/// Run `sim-host sil`.
pub fn main(args: SilArgs) -> anyhow::Result<()> {
    if let (Some(id), Some(seed)) = (&args.case, args.seed) {
        return replay(&args, id, seed);
    }
    // The commit of the code that runs (read before the runs, which take a while).
    let commit = args.made_from.clone().unwrap_or_else(commit);
    if let Some(dir) = &args.slurm {
        return super::batch::write_and_submit(&args, dir, &commit);
    }
    if args.shard.is_some() || args.skip_seeds > 0 {
        let rows = run_tier(&args)?;
        return expect(&args, &rows);
    }
    let rows = if args.merge.is_empty() {
        run_tier(&args)?
    } else {
        let mut rows = Vec::new();
        for f in &args.merge {
            rows.extend(seeds::read_rows(f)?);
        }
        rows
    };
    expect(&args, &rows)?;
    let (rows_path, out) = output_paths(&args);
    write(&rows_path, &seeds::rows_text(&rows)?)?;
    write(&out, &super::page::markdown(&rows, &commit))?;
    println!("{}", super::page::digest(&rows));
    println!("rows in {}, page in {}", rows_path.display(), out.display());
    Ok(())
}

/// The rows and the page a tier writes: `--rows` and `--out`, or for one case (`--case`) files
/// beside them, not over the release tier's.
pub(super) fn output_paths(args: &SilArgs) -> (PathBuf, PathBuf) {
    match &args.case {
        Some(id) => (
            args.rows.with_file_name(format!("sil-seeds-{id}.jsonl")),
            args.out.with_file_name(format!("sil-results-{id}.md")),
        ),
        None => (args.rows.clone(), args.out.clone()),
    }
}

/// With `--expect FILE`: every row must equal its row in `FILE` (`seeds::differences`).
fn expect(args: &SilArgs, rows: &[SeedRow]) -> anyhow::Result<()> {
    let Some(path) = &args.expect else {
        return Ok(());
    };
    let reference = seeds::read_rows(path)?;
    let diff = seeds::differences(rows, &reference);
    anyhow::ensure!(
        diff.is_empty(),
        "{} of {} rows differ from {}:\n{}",
        diff.len(),
        rows.len(),
        path.display(),
        diff.join("\n")
    );
    println!("{} rows equal to {}", rows.len(), path.display());
    Ok(())
}

fn write(path: &std::path::Path, text: &str) -> anyhow::Result<()> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    std::fs::write(path, text)?;
    Ok(())
}

/// The commit the page is made from (`git describe`, `-dirty` with uncommitted changes).
fn commit() -> String {
    std::process::Command::new("git")
        .args(["describe", "--always", "--dirty", "--abbrev=12"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map_or("unknown".to_string(), |o| {
            String::from_utf8_lossy(&o.stdout).trim().to_string()
        })
}

/// The cases of the tier (`--case`: that one).
pub(super) fn tier_cases(args: &SilArgs) -> anyhow::Result<Vec<super::Case>> {
    let cases: Vec<_> = CASES
        .iter()
        .filter(|c| args.case.as_deref().is_none_or(|id| c.id == id))
        .copied()
        .collect();
    anyhow::ensure!(!cases.is_empty(), "no SIL case {:?}", args.case);
    Ok(cases)
}

/// The (case, seed) runs of the tier, in the order the shards split (`--skip-seeds` applied).
pub(super) fn tier_runs(
    args: &SilArgs,
    cases: &[super::Case],
) -> anyhow::Result<Vec<(super::Case, u64)>> {
    Ok(seeds::acceptance_seeds(args.seeds)
        .skip(usize::try_from(args.skip_seeds)?)
        .flat_map(|s| cases.iter().map(move |c| (*c, s)))
        .collect())
}

/// Every (case, seed) run of the tier (or of the shard), in parallel, with a progress bar.
fn run_tier(args: &SilArgs) -> anyhow::Result<Vec<SeedRow>> {
    use indicatif::{ProgressBar, ProgressStyle};
    use rayon::prelude::*;
    let cases = tier_cases(args)?;
    let mut todo = tier_runs(args, &cases)?;
    if let Some(shard) = &args.shard {
        let (k, n) = crate::campaign::exec::parse_shard(shard)?;
        todo = todo
            .into_iter()
            .enumerate()
            .filter(|(i, _)| (*i as u64) % n == k)
            .map(|(_, x)| x)
            .collect();
    }
    let jobs = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
    });
    let pool = rayon::ThreadPoolBuilder::new().num_threads(jobs).build()?;
    println!(
        "sim-host sil: {} cases x {} seeds from {} ({} runs with rendered stereo, {jobs} at once)",
        cases.len(),
        args.seeds,
        seeds::ACCEPTANCE_FIRST_SEED,
        todo.len()
    );
    let bar = ProgressBar::new(todo.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} runs, about {eta} left {msg}",
        )?
        .progress_chars("=> "),
    );
    let start = std::time::Instant::now();
    // Without a terminal the bar is hidden: a line per 5 % of the runs instead.
    let lines = !std::io::IsTerminal::is_terminal(&std::io::stderr());
    let done = std::sync::atomic::AtomicUsize::new(0);
    let total = todo.len();
    let rows: Vec<SeedRow> = pool.install(|| {
        todo.par_iter()
            .map(|(c, s)| {
                let r = run_case(*c, &args.scenarios, *s, None)
                    .map_err(|e| anyhow::anyhow!("{} seed {s}: {e:#}", c.id));
                bar.inc(1);
                if let (Ok(r), Some(dir)) = (&r, &args.summaries) {
                    write_summary(dir, r)?;
                }
                let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                if lines && (20 * n / total.max(1)) > (20 * (n - 1) / total.max(1)) {
                    let min = start.elapsed().as_secs_f64() / 60.0;
                    eprintln!(
                        "{n}/{total} runs in {min:.1} min, about {:.1} min left",
                        min * (total - n) as f64 / n as f64
                    );
                }
                r.map(|r| SeedRow::of(&r))
            })
            .collect::<anyhow::Result<_>>()
    })?;
    bar.finish();
    println!(
        "{} runs in {:.1} min wall time ({jobs} at once)",
        rows.len(),
        start.elapsed().as_secs_f64() / 60.0
    );
    if args.shard.is_some() || args.skip_seeds > 0 {
        write(&args.rows, &seeds::rows_text(&rows)?)?;
        println!("rows of these runs in {}", args.rows.display());
    }
    Ok(rows)
}

/// `summary.json` of `run` into `dir` as `<case id>-<seed>.json` (and the paired run's as
/// `<case id>-<seed>-no-comp.json`).
fn write_summary(dir: &std::path::Path, run: &super::CaseRun) -> anyhow::Result<()> {
    let name = format!("{}-{}", run.case.id, run.seed);
    let json = serde_json::to_string_pretty(&run.runs.main)?;
    write(&dir.join(format!("{name}.json")), &(json + "\n"))?;
    if let Some(n) = &run.runs.no_comp {
        let json = serde_json::to_string_pretty(n)?;
        write(&dir.join(format!("{name}-no-comp.json")), &(json + "\n"))?;
    }
    Ok(())
}

/// `sim-host sil --case ID --seed S`: the case on one seed, every output written, the checks
/// printed.
fn replay(args: &SilArgs, id: &str, seed: u64) -> anyhow::Result<()> {
    let case = super::case(id).ok_or_else(|| anyhow::anyhow!("no SIL case {id}"))?;
    let out = args
        .outputs
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("out/sil/{id}-{seed}")));
    let r = run_case(case, &args.scenarios, seed, Some(&out))?;
    println!("{id} on seed {seed}: {}", case.title);
    for (c, v) in case.checks.iter().zip(&r.values) {
        println!(
            "  {:<4} {}: {} (per seed: {} {} {})",
            if c.passes(*v) { "pass" } else { "FAIL" },
            c.what,
            v.map_or("-".to_string(), |x| format!("{x:.4}")),
            match c.compare {
                super::Compare::AtMost => "<=",
                super::Compare::AtLeast => ">=",
            },
            c.threshold,
            c.unit
        );
    }
    println!("every output in {}", out.display());
    Ok(())
}
