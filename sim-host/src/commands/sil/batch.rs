//! `sim-host sil --slurm DIR`: the tier as a Slurm job array. `DIR/sil.sbatch` is an array
//! whose task K runs shard K/T of the (case, seed) runs (`sil --shard K/T`) into
//! `DIR/rows/K.jsonl`; `DIR/merge.sbatch`, submitted after it (`--dependency`), merges every
//! shard's rows into the rows and the page (`sil --merge`), stating the commit the scripts were
//! written from. The scripts come from the campaigns' Slurm machinery
//! (`crate::campaign::slurm`), so the options are those of `campaign slurm`.

use super::command::{output_paths, tier_cases, tier_runs, SilArgs};
use super::seeds::ACCEPTANCE_FIRST_SEED;
use crate::campaign::slurm::{self, absolute, shell_quote, AfterJob, ArrayJob};
use std::path::Path;

/// The command line of one `sim-host sil` invocation, quoted for the shell.
fn line(bin: &Path, words: &[String]) -> String {
    let mut s = format!("exec {} sil", shell_quote(&bin.display().to_string()));
    for w in words {
        s.push(' ');
        // `$SLURM_...` words are double-quoted so the shell expands them.
        if w.contains("$SLURM") || w.contains("${SLURM") {
            s += &format!("\"{w}\"");
        } else {
            s += &shell_quote(w);
        }
    }
    s
}

fn path_word(p: &Path) -> anyhow::Result<String> {
    Ok(absolute(p)?.display().to_string())
}

/// Write `DIR/sil.sbatch` and `DIR/merge.sbatch` for the tier `args` describes; with
/// `--submit` submit them, with `--wait` wait for the merge and print its digest.
pub fn write_and_submit(args: &SilArgs, dir: &Path, commit: &str) -> anyhow::Result<()> {
    let cases = tier_cases(args)?;
    let runs = tier_runs(args, &cases)?.len() as u64;
    anyhow::ensure!(
        runs > 0,
        "no runs: --seeds {} --skip-seeds {}",
        args.seeds,
        args.skip_seeds
    );
    let dir = absolute(dir)?;
    let o = args.batch.options()?;
    let tasks = o.tasks.clamp(1, runs);
    let rows_dir = dir.join("rows");
    std::fs::create_dir_all(&rows_dir)?;
    std::fs::create_dir_all(dir.join("logs"))?;
    // What selects the runs, the same in every task.
    let mut tier = vec!["--seeds".to_string(), args.seeds.to_string()];
    if args.skip_seeds > 0 {
        tier.extend(["--skip-seeds".to_string(), args.skip_seeds.to_string()]);
    }
    if let Some(id) = &args.case {
        tier.extend(["--case".to_string(), id.clone()]);
    }
    tier.extend(["--scenarios".to_string(), path_word(&args.scenarios)?]);
    let rows_of = |k: &str| rows_dir.join(format!("{k}.jsonl")).display().to_string();
    let mut task = tier.clone();
    task.extend([
        "--jobs".to_string(),
        "${SLURM_CPUS_PER_TASK:-1}".to_string(),
        "--shard".to_string(),
        format!("$SLURM_ARRAY_TASK_ID/{tasks}"),
        "--rows".to_string(),
        rows_of("$SLURM_ARRAY_TASK_ID"),
    ]);
    // Every shard's rows by name: a missing shard fails the merge instead of thinning the tier.
    let mut merge = vec!["--merge".to_string()];
    merge.extend((0..tasks).map(|k| rows_of(&k.to_string())));
    if let Some(id) = &args.case {
        merge.extend(["--case".to_string(), id.clone()]);
    }
    let (rows, out) = (path_word(&args.rows)?, path_word(&args.out)?);
    merge.extend([
        "--made-from".to_string(),
        commit.to_string(),
        "--rows".to_string(),
        rows.clone(),
        "--out".to_string(),
        out.clone(),
    ]);
    if let Some(e) = &args.expect {
        merge.extend(["--expect".to_string(), path_word(e)?]);
    }
    let after = o.gather_after;
    let job = ArrayJob {
        name: "sil".to_string(),
        after_name: "sil-merge".to_string(),
        tasks,
        about: vec![
            format!(
                "SIL tier: {} cases x seeds {}-{} ({runs} runs) in {tasks} shards (task K runs \
                 the runs K, K + {tasks}, ...); made from {commit}.",
                cases.len(),
                ACCEPTANCE_FIRST_SEED + args.skip_seeds,
                ACCEPTANCE_FIRST_SEED + args.seeds.saturating_sub(1)
            ),
            format!(
                "Written by `sim-host sil --slurm`; submit with: jid=$(sbatch --parsable {d}/sil.sbatch) \
                 && sbatch --dependency={}:$jid {d}/merge.sbatch",
                after.dependency(),
                d = dir.display()
            ),
        ],
        task_command: line(&o.bin, &task),
        after_about: format!(
            "Merge of the SIL shards into the rows and the page. Submitted with \
             --dependency={}:<array job>.",
            after.dependency()
        ),
        after_command: line(&o.bin, &merge),
    };
    let (a, m) = slurm::array_scripts(&job, &dir, &o);
    let (array_path, merge_path) = (dir.join("sil.sbatch"), dir.join("merge.sbatch"));
    std::fs::write(&array_path, a)?;
    std::fs::write(&merge_path, m)?;
    println!(
        "sil: {runs} runs in {tasks} array tasks; wrote {} and {}",
        array_path.display(),
        merge_path.display()
    );
    if !args.batch.submit {
        println!(
            "submit: jid=$(sbatch --parsable {}) && sbatch --dependency={}:$jid {}",
            array_path.display(),
            after.dependency(),
            merge_path.display()
        );
        return Ok(());
    }
    let (array, merge_id) =
        slurm::submit_files(&array_path, &merge_path, &dir.join("slurm-jobs.txt"), after)?;
    println!("submitted: array job {array}, merge job {merge_id}");
    if args.batch.wait {
        let (rows, out) = output_paths(args);
        let out = absolute(&out)?;
        slurm::wait_for(
            &AfterJob {
                id: &merge_id,
                logs: &dir.join("logs"),
                result: &out,
                retry: format!(
                    "merge the shards that finished with `sim-host sil --merge {}/*.jsonl`",
                    rows_dir.display()
                ),
            },
            args.batch.timeout,
        )?;
        println!(
            "merged: rows in {}, page in {}",
            absolute(&rows)?.display(),
            out.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::line;
    use std::path::Path;

    /// Slurm's variables stay expandable, every other word is quoted when it must be.
    #[test]
    fn command_lines_quote_all_but_slurm_variables() {
        let l = line(
            Path::new("/opt/rover/sim-host"),
            &[
                "--shard".into(),
                "$SLURM_ARRAY_TASK_ID/16".into(),
                "--rows".into(),
                "/shared/a b/$SLURM_ARRAY_TASK_ID.jsonl".into(),
                "--case".into(),
                "SIL-NAV-1".into(),
                "--jobs".into(),
                "${SLURM_CPUS_PER_TASK:-1}".into(),
            ],
        );
        assert_eq!(
            l,
            "exec /opt/rover/sim-host sil --shard \"$SLURM_ARRAY_TASK_ID/16\" --rows \
             \"/shared/a b/$SLURM_ARRAY_TASK_ID.jsonl\" --case SIL-NAV-1 --jobs \
             \"${SLURM_CPUS_PER_TASK:-1}\""
        );
    }
}
