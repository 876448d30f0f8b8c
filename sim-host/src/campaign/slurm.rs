//! `campaign slurm`: the batch scripts of a planned campaign. `DIR/campaign.sbatch` is a job
//! array over the run indices (one index per array task, or shards `K/N` of the indices when
//! the campaign has more runs than array tasks), with an optional `%` throttle;
//! `DIR/gather.sbatch` runs `campaign gather DIR` after the array (`--dependency=afterok:<array
//! job>`, or `afterany` to gather whatever finished). `DIR` must be on a filesystem every node
//! sees; the scripts name it and the `sim-host` binary by absolute path. `docs/campaigns.md`
//! explains the options for a real cluster.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Options of the scripts.
#[derive(Debug, Clone, PartialEq)]
pub struct SlurmOptions {
    /// `sim-host` executable the jobs run (absolute; must exist on the compute nodes).
    pub bin: PathBuf,
    /// Array tasks at most; more runs than this are split into this many shards.
    pub tasks: u64,
    /// Array tasks running at once (`%` of `--array`); 0: no limit.
    pub throttle: u64,
    /// `--partition`.
    pub partition: Option<String>,
    /// `--account`.
    pub account: Option<String>,
    /// `--qos`.
    pub qos: Option<String>,
    /// `--time` of each array task (`HH:MM:SS` or minutes).
    pub time: String,
    /// `--time` of the gather job.
    pub gather_time: String,
    /// `--cpus-per-task` (the renderer's threads).
    pub cpus_per_task: u32,
    /// `--mem` per task (e.g. `2G`).
    pub mem: String,
    /// The gather waits for `ok` (every task succeeded: `afterok`) or `any` (`afterany`).
    pub gather_after: GatherAfter,
    /// More `#SBATCH` lines (without the prefix), e.g. `--constraint=x86`.
    pub extra: Vec<String>,
}

/// When the gather job starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GatherAfter {
    /// Every array task succeeded (`afterok`): a failed run leaves the gather pending with
    /// `DependencyNeverSatisfied`.
    Ok,
    /// Every array task ended, successfully or not (`afterany`): the gather reports the
    /// failed runs.
    Any,
}

impl GatherAfter {
    /// The `--dependency` type.
    pub fn dependency(self) -> &'static str {
        match self {
            GatherAfter::Ok => "afterok",
            GatherAfter::Any => "afterany",
        }
    }
}

/// Absolute form of `p` (from the current folder), without requiring it to exist.
pub fn absolute(p: &Path) -> anyhow::Result<PathBuf> {
    let abs = if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir()?.join(p)
    };
    Ok(abs.canonicalize().unwrap_or(abs))
}

/// Quote `s` for the shell (single quotes).
pub fn shell_quote(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+=:,%".contains(c))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

fn header(lines: &mut Vec<String>, job: &str, o: &SlurmOptions, time: &str, log: &Path, cpus: u32) {
    lines.push("#!/bin/bash".into());
    lines.push(format!("#SBATCH --job-name={job}"));
    lines.push(format!("#SBATCH --output={}", log.display()));
    lines.push(format!("#SBATCH --time={time}"));
    lines.push("#SBATCH --ntasks=1".into());
    lines.push(format!("#SBATCH --cpus-per-task={cpus}"));
    lines.push(format!("#SBATCH --mem={}", o.mem));
    if let Some(p) = &o.partition {
        lines.push(format!("#SBATCH --partition={p}"));
    }
    if let Some(a) = &o.account {
        lines.push(format!("#SBATCH --account={a}"));
    }
    if let Some(q) = &o.qos {
        lines.push(format!("#SBATCH --qos={q}"));
    }
    for e in &o.extra {
        lines.push(format!("#SBATCH {e}"));
    }
}

/// A job array and the job that runs after it: what [`array_scripts`] writes.
#[derive(Debug, Clone, PartialEq)]
pub struct ArrayJob {
    /// Job name prefix of the array (`<name>-runs`).
    pub name: String,
    /// Job name of the job after it.
    pub after_name: String,
    /// Array tasks (`0..tasks`).
    pub tasks: u64,
    /// Comment lines of the array script (without `# `).
    pub about: Vec<String>,
    /// The line each array task runs (it names its task by `$SLURM_ARRAY_TASK_ID`).
    pub task_command: String,
    /// Comment line of the second script (without `# `).
    pub after_about: String,
    /// The line the second script runs.
    pub after_command: String,
}

/// The two scripts `(array, after)` of `job` with the logs in the absolute folder `dir/logs`.
pub fn array_scripts(job: &ArrayJob, dir: &Path, o: &SlurmOptions) -> (String, String) {
    let mut array = format!("0-{}", job.tasks.max(1) - 1);
    if o.throttle > 0 {
        array += &format!("%{}", o.throttle);
    }
    let mut a = Vec::new();
    header(
        &mut a,
        &format!("{}-runs", job.name),
        o,
        &o.time,
        &dir.join("logs").join("run-%a.out"),
        o.cpus_per_task,
    );
    a.push(format!("#SBATCH --array={array}"));
    a.push(String::new());
    a.extend(job.about.iter().map(|l| format!("# {l}")));
    a.push("set -euo pipefail".into());
    a.push("# The renderer's threads: the CPUs Slurm gave the task.".into());
    a.push("export RAYON_NUM_THREADS=\"${SLURM_CPUS_PER_TASK:-1}\"".into());
    a.push(job.task_command.clone());
    let mut g = Vec::new();
    header(
        &mut g,
        &job.after_name,
        o,
        &o.gather_time,
        &dir.join("logs").join("gather.out"),
        1,
    );
    g.push(String::new());
    g.push(format!("# {}", job.after_about));
    g.push("set -euo pipefail".into());
    g.push(job.after_command.clone());
    (a.join("\n") + "\n", g.join("\n") + "\n")
}

/// The two scripts `(campaign.sbatch, gather.sbatch)` for the campaign `name` of `runs` runs
/// in the absolute folder `dir`.
pub fn scripts(name: &str, runs: u64, dir: &Path, o: &SlurmOptions) -> (String, String) {
    let tasks = o.tasks.clamp(1, runs.max(1));
    let sharded = tasks < runs;
    let bin = shell_quote(&o.bin.display().to_string());
    let d = shell_quote(&dir.display().to_string());
    let job = ArrayJob {
        name: name.to_string(),
        after_name: format!("{name}-gather"),
        tasks,
        about: vec![
            format!(
                "Campaign {name}: {runs} runs{}. Written by `sim-host campaign slurm`; submit with",
                if sharded {
                    format!(" in {tasks} shards (task K runs the indices K, K + {tasks}, ...)")
                } else {
                    ", one per array task".to_string()
                }
            ),
            format!(
                "  jid=$(sbatch --parsable {d}/campaign.sbatch) && sbatch --dependency={}:$jid {d}/gather.sbatch",
                o.gather_after.dependency()
            ),
        ],
        task_command: if sharded {
            format!("exec {bin} campaign run {d} --shard \"$SLURM_ARRAY_TASK_ID/{tasks}\"")
        } else {
            format!("exec {bin} campaign run {d} --index \"$SLURM_ARRAY_TASK_ID\"")
        },
        after_about: format!(
            "Gather of campaign {name}: statistics, criteria, report. Submitted with \
             --dependency={}:<array job>.",
            o.gather_after.dependency()
        ),
        after_command: format!("exec {bin} campaign gather {d}"),
    };
    array_scripts(&job, dir, o)
}

/// Write the scripts into `dir` (and `dir/logs`, which Slurm does not create).
pub fn write_scripts(name: &str, runs: u64, dir: &Path, o: &SlurmOptions) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir.join("logs"))?;
    let (a, g) = scripts(name, runs, dir, o);
    std::fs::write(dir.join("campaign.sbatch"), a)?;
    std::fs::write(dir.join("gather.sbatch"), g)?;
    Ok(())
}

fn sbatch(args: &[&str]) -> anyhow::Result<String> {
    let out = Command::new("sbatch")
        .arg("--parsable")
        .args(args)
        .output()
        .map_err(|e| anyhow::anyhow!("cannot run sbatch: {e} (is Slurm installed?)"))?;
    anyhow::ensure!(
        out.status.success(),
        "sbatch {} failed: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr).trim()
    );
    // `--parsable` prints `jobid` or `jobid;cluster`.
    let text = String::from_utf8_lossy(&out.stdout);
    let id = text.trim().split(';').next().unwrap_or("").to_string();
    anyhow::ensure!(
        !id.is_empty() && id.chars().all(|c| c.is_ascii_digit()),
        "sbatch printed no job id: {text:?}"
    );
    Ok(id)
}

/// Submit the scripts of `dir`: returns `(array job id, gather job id)`.
pub fn submit(dir: &Path, after: GatherAfter) -> anyhow::Result<(String, String)> {
    submit_files(
        &dir.join("campaign.sbatch"),
        &dir.join("gather.sbatch"),
        &dir.join("slurm-jobs.txt"),
        after,
    )
}

/// Submit the array script `array`, then `gather` depending on it (`after`); the job ids go
/// into `record`. Returns `(array job id, gather job id)`.
pub fn submit_files(
    array: &Path,
    gather: &Path,
    record: &Path,
    after: GatherAfter,
) -> anyhow::Result<(String, String)> {
    let array = sbatch(&[&array.display().to_string()])?;
    let gather = sbatch(&[
        &format!("--dependency={}:{array}", after.dependency()),
        &gather.display().to_string(),
    ])?;
    std::fs::write(record, format!("array {array}\ngather {gather}\n"))?;
    Ok((array, gather))
}

/// `JobState` and `Reason` of a job from `scontrol show job -o` (`None`: the job is unknown,
/// e.g. already purged).
pub fn job_state(id: &str) -> Option<(String, String)> {
    let out = Command::new("scontrol")
        .args(["show", "job", "-o", id])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let field = |k: &str| {
        text.split_whitespace()
            .find_map(|w| w.strip_prefix(&format!("{k}=")))
            .map(str::to_string)
    };
    Some((field("JobState")?, field("Reason").unwrap_or_default()))
}

/// Wait (at most `timeout_s`) until the gather job `gather` of the campaign in `dir` ends.
/// Fails when it cannot run (a run failed under `afterok`) or ends other than `COMPLETED`.
pub fn wait(dir: &Path, gather: &str, timeout_s: f64) -> anyhow::Result<()> {
    wait_for(
        &AfterJob {
            id: gather,
            logs: &dir.join("logs"),
            result: &dir.join("stats.json"),
            retry: format!(
                "gather what finished with `sim-host campaign gather {}`",
                dir.display()
            ),
        },
        timeout_s,
    )
}

/// The job that runs after an array, for [`wait_for`].
#[derive(Debug)]
pub struct AfterJob<'a> {
    /// Its job id.
    pub id: &'a str,
    /// The folder of the logs.
    pub logs: &'a Path,
    /// The file it writes (when the job is gone from `scontrol`, it ended if this exists).
    pub result: &'a Path,
    /// What to do when it will never start (a task failed under `afterok`).
    pub retry: String,
}

/// Wait (at most `timeout_s`) until `job` ends. Fails when it cannot run (a task of the array
/// failed under `afterok`) or ends other than `COMPLETED`.
pub fn wait_for(job: &AfterJob, timeout_s: f64) -> anyhow::Result<()> {
    let start = std::time::Instant::now();
    let mut last = String::new();
    let id = job.id;
    loop {
        match job_state(id) {
            Some((state, reason)) => {
                let now = format!("{state} {reason}");
                if now != last {
                    println!(
                        "job {id}: {state} ({reason}) after {:.0} s",
                        start.elapsed().as_secs_f64()
                    );
                    last = now;
                }
                match state.as_str() {
                    "COMPLETED" => return Ok(()),
                    "PENDING" if reason == "DependencyNeverSatisfied" => anyhow::bail!(
                        "a task of the array failed, so job {id} will never start (cancel it \
                         with `scancel {id}`); logs in {}; {}",
                        job.logs.display(),
                        job.retry
                    ),
                    "PENDING" | "RUNNING" | "CONFIGURING" | "COMPLETING" | "SUSPENDED"
                    | "REQUEUED" | "RESIZING" => {}
                    other => anyhow::bail!(
                        "job {id} ended {other}: see the logs in {}",
                        job.logs.display()
                    ),
                }
            }
            None => {
                anyhow::ensure!(
                    job.result.exists(),
                    "job {id} is gone and there is no {}",
                    job.result.display()
                );
                return Ok(());
            }
        }
        anyhow::ensure!(
            start.elapsed().as_secs_f64() < timeout_s,
            "timed out after {timeout_s} s waiting for job {id}"
        );
        std::thread::sleep(std::time::Duration::from_secs(2));
    }
}
