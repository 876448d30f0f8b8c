//! `campaign run` and the run step of `campaign local`: run one index of a planned campaign
//! and write `DIR/runs/<index>/summary.json` (or `DIR/runs/<index>/error.txt` when the run
//! fails). A campaign run writes only the summary (no trajectories, no per-run report); the
//! flight clock counts simulated time, so the summary is byte-identical wherever the run
//! executes, except `wall_time_s`. `--outputs OUT` replays a run with every output of
//! `sim-host run` in `OUT`.

use super::plan::Manifest;
use crate::closed_loop::{run, RunOptions};
use crate::devices::world::CounterMode;
use crate::output::summary::Summary;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// The folder of run `index`.
pub fn run_dir(dir: &Path, index: u64) -> PathBuf {
    dir.join("runs").join(index.to_string())
}

/// Write `text` to `path` through a temporary file and a rename, so a reader (the gather
/// step, possibly on another node) never sees half a file.
pub fn write_atomic(path: &Path, text: &str) -> anyhow::Result<()> {
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    std::fs::write(&tmp, text)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .map_err(|e| anyhow::anyhow!("cannot rename {} to {}: {e}", tmp.display(), path.display()))
}

/// Run `index` of the campaign in `dir` (whose manifest is `manifest`) and return its summary.
/// Writes `runs/<index>/summary.json`; on failure `runs/<index>/error.txt` (and returns the
/// error). With `outputs`, also every output of `sim-host run` (trajectories, report) there.
pub fn run_index(
    dir: &Path,
    manifest: &Manifest,
    index: u64,
    outputs: Option<&Path>,
) -> anyhow::Result<Summary> {
    let folder = run_dir(dir, index);
    std::fs::create_dir_all(&folder)?;
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        simulate(manifest, index, outputs)
    }))
    .unwrap_or_else(|panic| {
        let msg = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".to_string());
        Err(anyhow::anyhow!("the simulation panicked: {msg}"))
    });
    let error_file = folder.join("error.txt");
    match outcome {
        Ok(summary) => {
            let text = serde_json::to_string_pretty(&summary)? + "\n";
            write_atomic(&folder.join("summary.json"), &text)?;
            if error_file.exists() {
                std::fs::remove_file(&error_file)?;
            }
            Ok(summary)
        }
        Err(e) => {
            let _ = std::fs::remove_file(folder.join("summary.json"));
            write_atomic(&error_file, &format!("{e:#}\n"))?;
            Err(e.context(format!("campaign run {index}")))
        }
    }
}

fn simulate(manifest: &Manifest, index: u64, outputs: Option<&Path>) -> anyhow::Result<Summary> {
    let entry = manifest.entry(index)?;
    let scenario = manifest.scenario(index)?;
    let renderer: Option<Box<dyn crate::devices::renderer::StereoRenderer>> =
        manifest.run.render.then(|| {
            let sun = scenario.site.sun_w(0.0);
            // The ground texture belongs to the terrain: its seed is the terrain seed.
            Box::new(crate::devices::renderer::TexturedRenderer::new(
                crate::devices::hazcam_calibration(),
                entry.terrain_seed,
                [sun.x, sun.y, sun.z],
            )) as Box<dyn crate::devices::renderer::StereoRenderer>
        });
    let result = run(
        &scenario,
        RunOptions {
            seed: Some(entry.seed),
            no_slip_comp: !manifest.run.slip_compensation,
            reference_driver: false,
            no_vo: !manifest.run.vo,
            localization: false,
            map_offset_m: [0.0; 2],
            counter: CounterMode::SimTime,
            renderer,
            progress: None,
            configure: None,
        },
    )?;
    match outputs {
        Some(out) => crate::output::write_all(out, &result),
        None => Ok(crate::output::summary::summarise(&result)),
    }
}

/// Parse a shard `K/N` (0 <= K < N).
pub fn parse_shard(text: &str) -> anyhow::Result<(u64, u64)> {
    let (k, n) = text
        .split_once('/')
        .ok_or_else(|| anyhow::anyhow!("shard {text:?}: expected K/N, e.g. 3/16"))?;
    let (k, n): (u64, u64) = (k.trim().parse()?, n.trim().parse()?);
    anyhow::ensure!(n >= 1 && k < n, "shard {text:?}: need 0 <= K < N");
    Ok((k, n))
}

/// The indices of shard `k` of `n` among `runs`: `k, k + n, k + 2n, ...`.
pub fn shard_indices(runs: u64, k: u64, n: u64) -> Vec<u64> {
    (k..runs).step_by(n as usize).collect()
}

/// Whether run `index` has its summary.
pub fn is_done(dir: &Path, index: u64) -> bool {
    run_dir(dir, index).join("summary.json").exists()
}

/// Run `indices` one after the other (a shard); returns how many failed (each failure is in
/// its `error.txt` and printed).
pub fn run_sequential(dir: &Path, manifest: &Manifest, indices: &[u64]) -> u64 {
    let mut failed = 0;
    for &i in indices {
        match run_index(dir, manifest, i, None) {
            Ok(s) => println!(
                "run {i}: seed {} goal {} cross-track max {:.3} m ({:.1} s)",
                manifest.entries[i as usize].seed,
                if s.goal_reached { "reached" } else { "missed" },
                s.cross_track_m.max,
                s.wall_time_s
            ),
            Err(e) => {
                failed += 1;
                eprintln!("run {i}: FAILED: {e:#}");
            }
        }
    }
    failed
}

/// Run `indices` in parallel on `jobs` threads (default: one per core) with a progress bar;
/// returns the failed indices with their errors, in index order.
pub fn run_parallel(
    dir: &Path,
    manifest: &Manifest,
    indices: &[u64],
    jobs: Option<usize>,
) -> anyhow::Result<Vec<(u64, String)>> {
    let bar = indicatif::ProgressBar::new(indices.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} runs, {elapsed} elapsed, eta {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message(manifest.campaign.clone());
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(j) = jobs {
        builder = builder.num_threads(j.max(1));
    }
    let pool = builder.build()?;
    let mut failed: Vec<(u64, String)> = pool.install(|| {
        indices
            .par_iter()
            .filter_map(|&i| {
                let r = run_index(dir, manifest, i, None);
                bar.inc(1);
                r.err().map(|e| (i, format!("{e:#}")))
            })
            .collect()
    });
    bar.finish_and_clear();
    failed.sort_by_key(|f| f.0);
    Ok(failed)
}
