//! `cargo xtask`: the project's commands.
//!
//! - `cargo xtask test`: everything CI checks, after its own setup (target, QEMU): format check,
//!   clippy with warnings denied, host tests (unit, SIL), the cross build of the flight crates
//!   and the rover-CPU image, and the image's run in QEMU.
//! - `cargo xtask setup`: only the setup (adds `thumbv7em-none-eabihf`, installs
//!   `qemu-system-arm` when missing).
//! - `cargo xtask qemu`: build the rover-CPU image and run it in QEMU `mps2-an500`.
//! - `cargo xtask fuzz --frames N [--seed S] [--no-vo]`: the seeded adversarial-HAL fuzzer of
//!   the flight software (crate `fuzz-hal`, `docs/fault-protection.md` "Fuzzing"); a short run
//!   ([`FUZZ_TEST_FRAMES`] frames) is a step of `test`.
//! - `cargo xtask report`: the per-run output checks ([`report::report_checks`]): a real run of
//!   `slope-10-cross`, `evo_ape`/`evo_rpe` with default options on every TUM output, and
//!   headless-Chromium screenshots of its `report.html` and of the main command's H05 Fig. 9
//!   figure (installs `chromium` and evo when missing). Also a step of `test`.
//! - `cargo xtask campaign`: the CI smoke campaign (`campaigns/ci-smoke.toml`) through `sbatch`
//!   on a single-node Slurm cluster started on this machine and locally; the two `stats.json`
//!   must be identical (installs `slurm-wlm` and `munge` when missing). A step of `test`.
//! - `cargo xtask timing`: timing analysis on the rover CPU model (instruction counts per task,
//!   utilisation, response times, stack, memory, panic sites) and the bit-identical host/target
//!   replay check; writes `docs/results/timing.md`. Also the last step of `test`.
//! - `cargo xtask cpi`: build the rover-CPU image and print the CPI of its kernel loops on
//!   LLVM's Cortex-M7 pipeline model ([`cpi`]; also a section of `docs/results/timing.md`).
//! - `cargo xtask stack`: build the rover-CPU image and print its static worst-case stack paths
//!   ([`stack`]; `STACK_CALLEES=<name part>` lists a function's callees, `STACK_INDIRECT=1` the
//!   functions with indirect calls).

mod campaign;
mod cpi;
mod elf;
mod report;
mod stack;
mod timing;

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

/// The rover CPU's target triple (Cortex-M7 with double-precision FPU).
const TARGET: &str = "thumbv7em-none-eabihf";
/// Cargo profile of the rover-CPU image (fat LTO, one codegen unit; see Cargo.toml).
const FLIGHT_PROFILE: &str = "flight";
/// QEMU machine modelling the rover CPU.
const QEMU_MACHINE: &str = "mps2-an500";
/// Frames of the fuzzer's short run in `cargo xtask test` (about 1-2 s of fuzzing).
const FUZZ_TEST_FRAMES: u64 = 200_000;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let root = workspace_root()?;
    std::env::set_current_dir(&root)?;
    match args.first().map(String::as_str) {
        Some("test") => test(),
        Some("setup") => setup(),
        Some("qemu") => {
            setup()?;
            qemu_run().map(|_| ())
        }
        Some("fuzz") => fuzz(&args[1..]),
        Some("report") => report::report_checks(),
        Some("campaign") => campaign::slurm_smoke(),
        Some("stack") => stack_command(),
        Some("cpi") => cpi_command(),
        Some("timing") => {
            setup()?;
            timing::timing()
        }
        _ => {
            eprintln!("usage: cargo xtask <test|setup|qemu|fuzz|report|campaign|timing>");
            eprintln!("  test   everything CI checks (does its own setup first)");
            eprintln!("  setup  add the {TARGET} target and install qemu-system-arm if missing");
            eprintln!("  qemu   build the rover-CPU image and run it in QEMU {QEMU_MACHINE}");
            eprintln!(
                "  fuzz   --frames N [--seed S] [--no-vo]: adversarial-HAL fuzzer of the flight software"
            );
            eprintln!(
                "  report evo on every TUM output of a run, headless-Chromium screenshots of the reports"
            );
            eprintln!(
                "  campaign  the smoke campaign through a single-node Slurm cluster and locally"
            );
            eprintln!(
                "  stack  build the rover-CPU image and print its static worst-case stack paths"
            );
            eprintln!(
                "  timing timing analysis on the rover CPU model, writes docs/results/timing.md"
            );
            bail!("unknown or missing command")
        }
    }
}

/// `cargo xtask cpi`: the Cortex-M7 pipeline model's CPI of the image's kernel loops
/// ([`cpi`]), printed per group (the same figures as `docs/results/timing.md`); `CPI_LOOPS=1` lists
/// every loop with its function.
fn cpi_command() -> Result<()> {
    let image = build_image()?;
    println!("{}", cpi::tool_version()?);
    let blocks = Path::new(cpi::BLOCKS);
    let blocks = blocks.exists().then_some(blocks);
    match blocks {
        Some(b) => println!(
            "block counts: {} (from the last `cargo xtask timing`; stale if the image changed)",
            b.display()
        ),
        None => println!(
            "no block counts ({}): run `cargo xtask timing`",
            cpi::BLOCKS
        ),
    }
    for (g, c) in cpi::GROUPS.iter().zip(cpi::analyse(&image, blocks)?) {
        if let Some(p) = &c.profile {
            println!(
                "{:.2} CPI over {} executed instructions ({} of {} blocks simulated, {:.1} % of \
                 the instructions)",
                p.cpi().unwrap_or(f64::NAN),
                p.executed,
                p.simulated_blocks,
                p.blocks,
                100.0 * p.coverage()
            );
        }
        let (lo, hi) = c.range().unwrap_or((0.0, 0.0));
        println!(
            "{:.2} CPI ({:.2}-{:.2}) over {} loops, {} instructions, {} functions, {} skipped: {}",
            c.loop_cpi().unwrap_or(f64::NAN),
            lo,
            hi,
            c.loops.len(),
            c.insns(),
            c.functions,
            c.skipped,
            g.label
        );
        if std::env::var_os("CPI_LOOPS").is_some() {
            for l in &c.loops {
                println!(
                    "    {:6.2} CPI  {:4} insns  {}",
                    l.cycles / l.insns.max(1) as f64,
                    l.insns,
                    l.function
                );
            }
        }
    }
    Ok(())
}

/// `cargo xtask stack`: build the rover-CPU image and print the static stack analysis
/// ([`stack`]) of its entry and of the flight software's frame.
fn stack_command() -> Result<()> {
    let r = stack::analyse(&build_image()?)?;
    let s = stack::summarise(&r);
    let rows = std::env::var("STACK_ROWS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(25);
    for (title, p) in [
        ("entry", &s.entry),
        ("Fsw::tick", &s.tick),
        ("entry through Fsw::tick", &s.flight),
    ] {
        match p {
            Some(p) => print!("{}", stack::path_text(&r, title, p, rows)),
            None => println!("{title}: not found in the image"),
        }
    }
    println!(
        "{} functions, {} indirect calls/jumps, {} cycles ({} edges cut)",
        r.funcs.len(),
        r.indirect_total(),
        r.cycles.len(),
        r.cut_edges
    );
    // STACK_CALLEES=<name part>: the callees of the matching functions, with their depths.
    if let Ok(part) = std::env::var("STACK_CALLEES") {
        for (i, f) in r
            .funcs
            .iter()
            .enumerate()
            .filter(|(_, f)| f.name.contains(&part))
        {
            println!(
                "{} (frame {} B, worst case {} B):",
                f.name,
                f.frame,
                r.deepest(i).total
            );
            for (c, tail) in f
                .calls
                .iter()
                .map(|&c| (c, false))
                .chain(f.tails.iter().map(|&t| (t, true)))
            {
                let g = &r.funcs[c];
                println!(
                    "  {}{} frame {} B, worst case {} B",
                    if tail { "(tail) " } else { "" },
                    stack::short(&g.name),
                    g.frame,
                    r.deepest(c).total
                );
            }
        }
    }
    if std::env::var("STACK_INDIRECT").is_ok() {
        for f in r.funcs.iter().filter(|f| f.indirect > 0) {
            println!("  indirect x{}: {}", f.indirect, f.name);
        }
    }
    for c in &r.cycles {
        let names: Vec<String> = c.iter().map(|&i| stack::short(&r.funcs[i].name)).collect();
        println!("  cycle: {}", names.join(" <-> "));
    }
    Ok(())
}

fn workspace_root() -> Result<PathBuf> {
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    Ok(manifest
        .parent()
        .context("xtask has no parent folder")?
        .to_path_buf())
}

fn step(name: &str) -> Instant {
    println!("\n==> {name}");
    Instant::now()
}

fn run(cmd: &mut Command) -> Result<()> {
    let shown = format!("{cmd:?}");
    let status = cmd
        .status()
        .with_context(|| format!("cannot start {shown}"))?;
    if !status.success() {
        bail!("failed ({status}): {shown}");
    }
    Ok(())
}

fn cargo() -> Command {
    Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
}

fn have(program: &str, arg: &str) -> bool {
    Command::new(program)
        .arg(arg)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Add the target and install QEMU and the LLVM tools when missing; say exactly what to do when
/// that fails.
fn setup() -> Result<()> {
    let t = step("setup: rust target, QEMU and LLVM tools");
    let installed = Command::new("rustup")
        .args(["target", "list", "--installed"])
        .output();
    match installed {
        Ok(out) if String::from_utf8_lossy(&out.stdout).contains(TARGET) => {
            println!("target {TARGET}: present");
        }
        Ok(_) => run(Command::new("rustup").args(["target", "add", TARGET]))
            .with_context(|| format!("run `rustup target add {TARGET}` by hand"))?,
        Err(_) => println!(
            "rustup not found: make sure the {TARGET} standard library is installed for your toolchain"
        ),
    }
    for tool in ["rustfmt", "clippy"] {
        let probe = if tool == "rustfmt" {
            "rustfmt"
        } else {
            "cargo-clippy"
        };
        if !have(probe, "--version") {
            run(Command::new("rustup").args(["component", "add", tool]))
                .with_context(|| format!("run `rustup component add {tool}` by hand"))?;
        }
    }
    // QEMU for the rover-CPU runs; LLVM's `llvm-objdump` and `llvm-mca` (Debian package `llvm`)
    // for the timing command's CPI model and panic-site count.
    for (program, package, what) in [
        (
            "qemu-system-arm",
            "qemu-system-arm",
            "QEMU's ARM system emulator",
        ),
        ("llvm-mca", "llvm", "LLVM's llvm-mca and llvm-objdump"),
        ("llvm-objdump", "llvm", "LLVM's llvm-mca and llvm-objdump"),
    ] {
        if have(program, "--version") {
            println!("{program}: present");
            continue;
        }
        println!("{program} missing: installing {package} with apt-get");
        let apt = run(Command::new("apt-get").args(["update", "-qq"])).and_then(|_| {
            run(Command::new("apt-get")
                .args(["install", "-y", "-qq", package])
                .env("DEBIAN_FRONTEND", "noninteractive"))
        });
        if apt.is_err() || !have(program, "--version") {
            bail!(
                "{program} is required and could not be installed automatically: install it \
                 with `sudo apt-get install -y {package}` (Debian/Ubuntu) or your system's \
                 package for {what}, then run again"
            );
        }
    }
    println!("setup done in {:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

fn test() -> Result<()> {
    let total = Instant::now();
    setup()?;

    let t = step("format check");
    run(cargo().args(["fmt", "--all", "--", "--check"]))?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    let t = step("clippy (host, warnings denied)");
    run(cargo().args([
        "clippy",
        "--workspace",
        "--all-targets",
        "--",
        "-D",
        "warnings",
    ]))?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    let t = step("clippy (flight crates and image for the rover CPU, warnings denied)");
    run(cargo().args([
        "clippy",
        "--release",
        "--target",
        TARGET,
        "-p",
        "rover-hal",
        "-p",
        "fsw",
        "-p",
        "fsw-image",
        "-p",
        "rover-replay",
        "--",
        "-D",
        "warnings",
    ]))?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    let t = step("host tests (unit, SIL, doc)");
    run(cargo().args(["test", "--workspace", "--release"]))?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    let t = step("per-run outputs: evo on every TUM file, headless-Chromium report screenshots");
    report::report_checks()?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    let t = step("adversarial-HAL fuzzer, short run");
    fuzz(&[
        "--frames".to_string(),
        FUZZ_TEST_FRAMES.to_string(),
        "--seed".to_string(),
        "1".to_string(),
    ])?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    // Its own steps: Slurm and munge setup, the cluster, the two campaigns, the comparison.
    campaign::slurm_smoke()?;

    let t = step("cross build of the flight crates (no_std, no alloc)");
    run(cargo().args([
        "build",
        "--release",
        "--target",
        TARGET,
        "-p",
        "fsw",
        "-p",
        "rover-hal",
        "-p",
        "rover-replay",
    ]))?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    let t = step("rover-CPU image in QEMU");
    qemu_run()?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    let t = step("timing analysis on the rover CPU model (docs/results/timing.md)");
    timing::timing()?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    println!(
        "\nxtask test: all checks passed in {:.1} s",
        total.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Run the adversarial-HAL fuzzer (release build of `fuzz-hal`) with `args`
/// (`--frames N`, `--seed S`, `--no-vo`); fails on any invariant violation.
fn fuzz(args: &[String]) -> Result<()> {
    run(cargo()
        .args(["run", "--release", "--quiet", "-p", "fuzz-hal", "--"])
        .args(args))
    .context("the adversarial-HAL fuzzer found invariant violations (see its summary above)")
}

/// Build the image and run it in QEMU; returns what it printed.
fn qemu_run() -> Result<String> {
    let image = build_image()?;
    let output = Command::new("timeout")
        .arg("600")
        .arg("qemu-system-arm")
        .args(qemu_args(&image))
        .stderr(Stdio::inherit())
        .output()
        .context("cannot start qemu-system-arm")?;
    let text = String::from_utf8_lossy(&output.stdout).into_owned();
    print!("{text}");
    if !output.status.success() {
        bail!("the rover-CPU image failed in QEMU ({})", output.status);
    }
    if !text.contains("fsw-image: PASS") {
        bail!("the rover-CPU image did not report PASS");
    }
    Ok(text)
}

/// The rover-CPU image built by `cargo build --profile flight --target thumbv7em-none-eabihf`.
/// Build the rover-CPU image (`flight` profile) and return its path.
fn build_image() -> Result<PathBuf> {
    run(cargo().args([
        "build",
        "--profile",
        FLIGHT_PROFILE,
        "--target",
        TARGET,
        "-p",
        "fsw-image",
    ]))?;
    Ok(image_path())
}

fn image_path() -> PathBuf {
    Path::new("target")
        .join(TARGET)
        .join(FLIGHT_PROFILE)
        .join("fsw-image")
}

/// QEMU arguments: the rover CPU model, semihosting for output and exit code, and `-icount`
/// so that virtual time (and so SysTick) advances with the instruction count, deterministically.
fn qemu_args(image: &Path) -> Vec<String> {
    [
        "-machine",
        QEMU_MACHINE,
        "-cpu",
        "cortex-m7",
        "-nographic",
        "-monitor",
        "none",
        "-serial",
        "none",
        "-semihosting-config",
        "enable=on,target=native",
        "-icount",
        "shift=0,align=off,sleep=off",
        "-kernel",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain(std::iter::once(image.display().to_string()))
    .collect()
}
