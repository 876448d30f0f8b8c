//! The campaign step of `cargo xtask test`: the CI smoke campaign (`campaigns/ci-smoke.toml`)
//! through `sbatch` on a single-node Slurm cluster started on this machine
//! (`tools/slurm-single-node.sh`), and locally; the two `stats.json` (and `report.html`) must
//! be identical byte for byte. Installs Debian's `slurm-wlm` and `munge` when missing (as
//! `setup` installs QEMU) and stops the daemons it started at the end, also on failure.

use super::{cargo, have, run, step};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The campaign the step runs.
const SPEC: &str = "campaigns/ci-smoke.toml";
/// The cluster script.
const CLUSTER: &str = "tools/slurm-single-node.sh";

/// Install `slurm-wlm` and `munge` with apt-get when `sbatch`, `slurmctld` or `munged` is
/// missing; say exactly what to do when that fails.
pub fn ensure_slurm() -> Result<()> {
    // `sbatch --version` needs a configuration; the daemons print their version without one.
    let present = || {
        have("slurmctld", "-V")
            && have("slurmd", "-V")
            && have("munged", "--version")
            && on_path("sbatch")
    };
    if present() {
        println!("slurm-wlm and munge: present");
        return Ok(());
    }
    println!("slurm-wlm or munge missing: installing them with apt-get");
    let apt = run(Command::new("apt-get").args(["update", "-qq"])).and_then(|_| {
        run(Command::new("apt-get")
            .args(["install", "-y", "-qq", "slurm-wlm", "munge"])
            .env("DEBIAN_FRONTEND", "noninteractive"))
    });
    if apt.is_err() || !present() {
        bail!(
            "slurm-wlm and munge are required for the campaign step and could not be installed \
             automatically: install them with `sudo apt-get install -y slurm-wlm munge` \
             (Debian/Ubuntu), then run again"
        );
    }
    Ok(())
}

/// Whether `program` is an executable file in a folder of `PATH`.
fn on_path(program: &str) -> bool {
    std::env::var_os("PATH")
        .is_some_and(|paths| std::env::split_paths(&paths).any(|d| d.join(program).is_file()))
}

/// Stops the cluster when dropped.
struct Cluster {
    state: PathBuf,
}

impl Cluster {
    fn start(state: &Path) -> Result<Self> {
        let cluster = Cluster {
            state: state.to_path_buf(),
        };
        run(Command::new("bash")
            .arg(CLUSTER)
            .arg("start")
            .env("ROVER_SLURM_DIR", state))
        .context("the single-node Slurm cluster did not start")?;
        Ok(cluster)
    }

    fn conf(&self) -> PathBuf {
        self.state.join("slurm.conf")
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = run(Command::new("bash")
            .arg(CLUSTER)
            .arg("stop")
            .env("ROVER_SLURM_DIR", &self.state));
    }
}

/// The release `sim-host` of this workspace.
fn sim_host() -> Result<PathBuf> {
    run(cargo().args(["build", "--release", "-p", "sim-host"]))?;
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target"));
    let bin = std::fs::canonicalize(target.join("release").join("sim-host"))
        .context("no release sim-host after the build")?;
    Ok(bin)
}

/// The step: the smoke campaign on Slurm and locally, identical statistics.
pub fn slurm_smoke() -> Result<()> {
    ensure_slurm()?;
    let bin = sim_host()?;
    let work = std::env::temp_dir().join(format!("rover-campaign-ci-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work)?;
    let (slurm_dir, local_dir) = (work.join("slurm"), work.join("local"));
    let t = step("campaign smoke test through sbatch on a single-node Slurm cluster");
    {
        let cluster = Cluster::start(&work.join("cluster"))?;
        run(Command::new(&bin)
            .args(["campaign", "slurm", SPEC, "--out"])
            .arg(&slurm_dir)
            .args(["--throttle", "2", "--submit", "--wait", "--timeout", "900"])
            .env("SLURM_CONF", cluster.conf()))
        .context("the smoke campaign failed on Slurm")?;
        println!("ok in {:.1} s", t.elapsed().as_secs_f64());
        // The SIL tier's array and merge on the same cluster: one fast case on the CI seeds, in
        // two shards; the merged rows must equal the release rows of those runs.
        let t = step("SIL shards through sbatch (SIL-KIN-4, 2 seeds, 2 tasks) and their merge");
        let sil = work.join("sil");
        run(Command::new(&bin)
            .args(["sil", "--case", "SIL-KIN-4", "--seeds", "2", "--slurm"])
            .arg(&sil)
            .args(["--tasks", "2", "--rows"])
            .arg(sil.join("sil-seeds.jsonl"))
            .arg("--out")
            .arg(sil.join("sil-results.md"))
            .args(["--expect", "docs/results/sil-seeds.jsonl"])
            .args(["--submit", "--wait", "--timeout", "600"])
            .env("SLURM_CONF", cluster.conf()))
        .context("the SIL shards failed on Slurm")?;
        let log = std::fs::read_to_string(sil.join("logs").join("gather.out"))
            .context("the SIL merge's log")?;
        if !log.contains("2 rows equal to") {
            bail!("the SIL merge did not compare its rows with the release rows:\n{log}");
        }
        println!("ok in {:.1} s", t.elapsed().as_secs_f64());
    }
    let t = step("campaign smoke test locally");
    run(Command::new(&bin)
        .args(["campaign", "local", SPEC, "--out"])
        .arg(&local_dir))
    .context("the smoke campaign failed locally")?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());
    for file in ["stats.json", "report.html", "manifest.json"] {
        let a = std::fs::read(slurm_dir.join(file)).with_context(|| format!("slurm {file}"))?;
        let b = std::fs::read(local_dir.join(file)).with_context(|| format!("local {file}"))?;
        if a != b {
            bail!(
                "{file} differs between the Slurm and the local campaign: compare {} and {}",
                slurm_dir.join(file).display(),
                local_dir.join(file).display()
            );
        }
        println!("{file}: identical ({} bytes)", a.len());
    }
    // The campaign report renders in headless Chromium with its CDF figures drawn.
    let t = step("campaign report: headless-Chromium screenshot");
    let png = work.join("campaign-report.png");
    crate::report::screenshot(&local_dir.join("report.html"), &png, (1280, 4000))?.check(
        "campaign report.html",
        0.05,
        0.001,
    )?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());
    let _ = std::fs::remove_dir_all(&work);
    Ok(())
}
