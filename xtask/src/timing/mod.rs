//! `cargo xtask timing`: timing analysis on the rover CPU model (QEMU `mps2-an500`, `-icount`),
//! bit-identical host/target replay, stack and memory budgets; writes `docs/results/timing.md`.

use crate::cpi;
use crate::elf::{self, ElfReport};
use crate::stack;
use crate::{build_image, cargo, qemu_args, run, step, TARGET};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

mod page;
use page::document;

/// Scenario and length of the recorded segment.
const SCENARIO: &str = "scenarios/slope-10-cross.toml";
const SECONDS: &str = "10";
/// Where the tape goes.
const TAPE: &str = "target/timing/slope-10-cross.tape";
/// The generated document.
const DOC: &str = "docs/results/timing.md";

/// Stated clock of the rover CPU, Hz.
const CLOCK_HZ: f64 = 300e6;
/// Stated range of cycles per instruction.
const CPI: [f64; 2] = [1.0, 2.0];
/// CPU design margin: total utilisation must stay at or below this.
const DESIGN_MARGIN: f64 = 0.5;

/// Goals (reported, not enforced).
const GOAL_PROPAGATE: u64 = 15_000;
/// Inverse kinematics per RG2 cycle.
const GOAL_IK: u64 = 10_000;
const GOAL_RG2_FRAME: u64 = 100_000;
/// The minor frame, s.
const FRAME_S: f64 = 0.005;
const GOAL_VO: u64 = 60_000_000;
const GOAL_STACK: u64 = 32 * 1024;
/// Least stack-region headroom every measured phase must leave (enforced): a peak that reaches
/// the bottom of the painted region may have overflowed into the statics unseen.
const MIN_STACK_HEADROOM: u64 = 4 * 1024;

/// Most stack the flight phase may use, bytes (the flight stack budget of 32 KiB):
/// the painted high-water mark of "flight software, 2000 replayed frames", which includes the
/// image's `main`, the measuring closure and the replay harness under `Fsw::tick`. Enforced:
/// `cargo xtask timing` fails above it (the margin is in `docs/results/timing.md`, Goals and Stack).
const MAX_FLIGHT_STACK: u64 = 32 * 1024;

/// True when the painted flight phase is within [`MAX_FLIGHT_STACK`].
fn flight_stack_ok(m: &Measured) -> bool {
    m.stack
        .get("flight")
        .is_some_and(|&v| v <= MAX_FLIGHT_STACK)
}

/// The deepest measured stack phase (initialisation, flight, navigation tasks), bytes.
fn stack_peak(m: &Measured) -> u64 {
    ["init", "flight", "bench"]
        .iter()
        .filter_map(|k| m.stack.get(*k).copied())
        .max()
        .unwrap_or(0)
}

/// True when the deepest phase leaves at least [`MIN_STACK_HEADROOM`] of the stack region.
fn stack_headroom_ok(m: &Measured) -> bool {
    let region = m.stack.get("region").copied().unwrap_or(0);
    stack_peak(m) + MIN_STACK_HEADROOM <= region
}
const GOAL_STATIC_RAM: u64 = 256 * 1024;

/// Statistics of one measured item, instructions.
#[derive(Debug, Clone, Copy, Default)]
struct Stat {
    n: u64,
    min: u64,
    max: u64,
    mean: u64,
    errors: u64,
}

/// Everything the image printed.
#[derive(Debug, Default)]
struct Measured {
    calib: BTreeMap<String, u64>,
    tape: (String, u64, u64),
    frames: BTreeMap<String, Stat>,
    tasks: Vec<(String, Stat)>,
    exec: Vec<(String, u64, u64, u64)>,
    exec_tasks: Vec<(String, u64, u64, u64)>,
    vo: BTreeMap<String, u64>,
    vo_items: Vec<(String, Stat)>,
    vo_cost: BTreeMap<String, u64>,
    background_quantum: u64,
    stack: BTreeMap<String, u64>,
    replay_insns: u64,
    replay_end: String,
}

fn pairs(words: &[&str]) -> BTreeMap<String, u64> {
    words
        .chunks(2)
        .filter_map(|kv| match kv {
            [k, v] => v.parse().ok().map(|v| (k.to_string(), v)),
            _ => None,
        })
        .collect()
}

fn stat(words: &[&str]) -> Stat {
    let p = pairs(words);
    let g = |k: &str| p.get(k).copied().unwrap_or(0);
    Stat {
        n: g("n"),
        min: g("min"),
        max: g("max"),
        mean: g("mean"),
        errors: g("errors"),
    }
}

fn parse(text: &str) -> Result<Measured> {
    let mut m = Measured::default();
    for line in text.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["timing", "calib", rest @ ..] => m.calib = pairs(rest),
            ["timing", "tape", name, "frames", f, "bytes", b] => {
                m.tape = (name.to_string(), f.parse()?, b.parse()?)
            }
            ["timing", "frame", name, rest @ ..] => {
                m.frames.insert(name.to_string(), stat(rest));
            }
            ["timing", "task", name, rest @ ..] => m.tasks.push((name.to_string(), stat(rest))),
            ["timing", "exec", name, "runs", r, "max_us", x, "mean_us", a] => {
                m.exec
                    .push((name.to_string(), r.parse()?, x.parse()?, a.parse()?))
            }
            ["timing", "exec_task", name, "max_us", x, "mean_us", a, "budget_us", b] => m
                .exec_tasks
                .push((name.to_string(), x.parse()?, a.parse()?, b.parse()?)),
            ["timing", "vo", rest @ ..] => m.vo = pairs(rest),
            ["timing", "vo_item", name, rest @ ..] => {
                m.vo_items.push((name.to_string(), stat(rest)))
            }
            ["timing", "vo_cost", name, c] => {
                m.vo_cost.insert(name.to_string(), c.parse()?);
            }
            ["timing", "background", "quantum", q] => m.background_quantum = q.parse()?,
            ["timing", "stack", rest @ ..] => m.stack = pairs(rest),
            ["timing", "replay", "frames", _, "insns", i] => m.replay_insns = i.parse()?,
            ["replay", "end", ..] => m.replay_end = line.to_string(),
            _ => {}
        }
    }
    if m.tasks.is_empty() || m.frames.is_empty() || m.stack.is_empty() {
        bail!("the image's timing output is incomplete");
    }
    Ok(m)
}

impl Measured {
    fn task(&self, name: &str) -> Stat {
        self.tasks
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, s)| *s)
            .unwrap_or_default()
    }
    fn frame(&self, name: &str) -> Stat {
        self.frames.get(name).copied().unwrap_or_default()
    }
}

fn lines_with<'a>(text: &'a str, prefix: &str) -> Vec<&'a str> {
    text.lines().filter(|l| l.starts_with(prefix)).collect()
}

/// One timing run of the image; with `plugin` (a QEMU plugin and its arguments) loaded.
fn run_qemu(image: &Path, plugin: Option<&str>) -> Result<String> {
    let mut args = qemu_args(image);
    if let Some(p) = plugin {
        args.insert(0, p.to_string());
        args.insert(0, "-plugin".into());
    }
    let semihosting = args
        .iter()
        .position(|a| a == "enable=on,target=native")
        .context("qemu arguments changed")?;
    args[semihosting] = format!("enable=on,target=native,arg=fsw-image,arg=timing,arg={TAPE}");
    let output = Command::new("timeout")
        .arg("900")
        .arg("qemu-system-arm")
        .args(&args)
        .stderr(Stdio::inherit())
        .output()
        .context("cannot start qemu-system-arm")?;
    let text = String::from_utf8_lossy(&output.stdout).into_owned();
    if !output.status.success() || !text.contains("fsw-image: PASS") {
        print!("{text}");
        bail!("the timing run in QEMU failed ({})", output.status);
    }
    Ok(text)
}

/// Seconds at the stated clock for `insns` instructions at `cpi`.
fn secs(insns: u64, cpi: f64) -> f64 {
    insns as f64 * cpi / CLOCK_HZ
}

fn fmt_time(s: f64) -> String {
    if s >= 1.0 {
        format!("{s:.2} s")
    } else if s >= 1e-3 {
        format!("{:.2} ms", s * 1e3)
    } else {
        format!("{:.1} us", s * 1e6)
    }
}

fn thousands(v: u64) -> String {
    let s = v.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

fn pass(ok: bool) -> &'static str {
    if ok {
        "PASS"
    } else {
        "FAIL"
    }
}

/// One schedulable entity of the response-time analysis.
struct Group {
    name: &'static str,
    period_s: f64,
    /// Worst-case instructions per release.
    insns: u64,
    /// What the figure is made of.
    content: String,
}

/// Joseph-Pandya response time of entity `i` (entities in priority order), seconds; `None`
/// when the iteration passes the period (deadline = period) or the demand never converges.
fn response_time(groups: &[Group], i: usize, cpi: f64) -> Option<f64> {
    let c = |g: &Group| secs(g.insns, cpi);
    let me = groups.get(i)?;
    let mut r: f64 = groups[..=i].iter().map(c).sum();
    for _ in 0..10_000 {
        if r > me.period_s {
            return None;
        }
        let next = c(me)
            + groups[..i]
                .iter()
                .map(|h| (r / h.period_s).ceil() * c(h))
                .sum::<f64>();
        if (next - r).abs() <= 1e-15 {
            return Some(r);
        }
        r = next;
    }
    None
}

/// Run the timing analysis and write `docs/results/timing.md`.
pub fn timing() -> Result<()> {
    let total = Instant::now();
    let host_output = record_and_replay()?;
    let host_replay = lines_with(&host_output, "replay ");
    let t = step(
        "timing: rover-CPU image, two runs in QEMU (-icount shift=0), the second counting \
         block executions",
    );
    let image = build_image()?;
    let plugin = cpi::build_plugin()?;
    let _ = std::fs::remove_file(cpi::BLOCKS);
    let first = run_qemu(&image, None)?;
    let qemu_s = t.elapsed().as_secs_f64();
    // The plugin adds host code only: the determinism check below also shows that it leaves
    // the guest's instruction counts unchanged.
    let second = run_qemu(
        &image,
        Some(&format!("{},out={}", plugin.display(), cpi::BLOCKS)),
    )?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());
    check_determinism(&first, &second)?;
    let target_replay = lines_with(&first, "replay ");
    check_replay(&host_replay, &target_replay)?;
    let m = parse(&first)?;
    check_calibration(&m)?;
    let report = elf::analyse(&image)?;
    write_document(&m, &report, &image, &target_replay)?;
    println!("{}", summary(&m, &report));
    check_budgets(&m, &report)?;
    println!(
        "timing: done in {:.1} s (one QEMU run {:.1} s)",
        total.elapsed().as_secs_f64(),
        qemu_s
    );
    Ok(())
}

/// Record the call tape with `sim-host record` and replay it on the host; returns the
/// replay's output.
fn record_and_replay() -> Result<String> {
    let t = step("timing: record the call tape (sim-host, 10 s of slope-10-cross, rendered)");
    run(cargo().args(["build", "--release", "-p", "sim-host"]))?;
    let sim = Path::new("target").join("release").join("sim-host");
    run(Command::new(&sim).args(["record", SCENARIO, "--seconds", SECONDS, "--out", TAPE]))?;
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

    let t = step("timing: host replay of the tape");
    let out = Command::new(&sim)
        .args(["replay", TAPE])
        .output()
        .context("cannot run sim-host replay")?;
    let host = String::from_utf8_lossy(&out.stdout).into_owned();
    if !out.status.success() {
        print!("{host}");
        bail!("the host replay does not reproduce the recording");
    }
    println!(
        "{}",
        lines_with(&host, "replay ")
            .last()
            .copied()
            .unwrap_or("no replay output")
    );
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());
    Ok(host)
}

/// Determinism: every figure of the two QEMU runs is identical.
fn check_determinism(first: &str, second: &str) -> Result<()> {
    let (a, b) = (lines_with(first, "timing "), lines_with(second, "timing "));
    if a != b {
        for (x, y) in a.iter().zip(b.iter()).filter(|(x, y)| x != y) {
            println!("run 1: {x}\nrun 2: {y}");
        }
        bail!("two QEMU runs gave different instruction counts");
    }
    println!(
        "determinism: {} timing lines identical in two runs",
        a.len()
    );
    Ok(())
}

/// Bit-identical replay: the image's digest lines are the host's.
fn check_replay(host_replay: &[&str], target_replay: &[&str]) -> Result<()> {
    if target_replay != host_replay {
        for (x, y) in host_replay
            .iter()
            .zip(target_replay.iter())
            .filter(|(x, y)| x != y)
        {
            println!("host:   {x}\ntarget: {y}");
        }
        bail!("the rover CPU's replay digests differ from the host's");
    }
    println!(
        "replay: {} digest lines identical on host and rover CPU",
        target_replay.len()
    );
    Ok(())
}

/// The instruction-count calibration loops measured within two counts of their length.
fn check_calibration(m: &Measured) -> Result<()> {
    let expect = m.calib.get("expect").copied().unwrap_or(0);
    let tol = 2 * m.calib.get("insns_per_count").copied().unwrap_or(40) + 16;
    let ok = ["loop2", "loop4"]
        .iter()
        .all(|k| m.calib.get(*k).is_some_and(|v| v.abs_diff(expect) <= tol));
    if !ok {
        bail!("instruction-count calibration failed: {:?}", m.calib);
    }
    Ok(())
}

/// The static analyses of `image` (CPI, stack), then the document, written to [`DOC`].
fn write_document(
    m: &Measured,
    report: &ElfReport,
    image: &Path,
    target_replay: &[&str],
) -> Result<()> {
    let mca = cpi::tool_version()?;
    let loops = cpi::analyse(image, Some(Path::new(cpi::BLOCKS)))?;
    let stack_sizes = stack_sizes_note();
    let static_stack = stack::analyse(image)?;
    let static_summary = stack::summarise(&static_stack);
    let qemu = Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.lines().next().map(str::to_string))
        .unwrap_or_else(|| "qemu-system-arm".into());
    let doc = document(
        m,
        report,
        target_replay,
        &stack_sizes,
        (&static_stack, &static_summary),
        &qemu,
        (&mca, &loops),
    )?;
    let old = std::fs::read_to_string(DOC).unwrap_or_default();
    std::fs::write(DOC, &doc).with_context(|| format!("cannot write {DOC}"))?;
    println!(
        "{DOC}: {}",
        if old == doc {
            "unchanged"
        } else {
            "written (changed: commit it)"
        }
    );
    Ok(())
}

/// The enforced budgets: no panic path in the flight code, the flight stack, the stack
/// headroom.
fn check_budgets(m: &Measured, report: &ElfReport) -> Result<()> {
    let flight_panics = report.flight_panic_sites();
    if !flight_panics.is_empty() {
        bail!(
            "the image has panic sites outside its number formatting (the flight code has no \
             panic path); enclosing functions: {flight_panics:?}"
        );
    }
    if !flight_stack_ok(m) {
        bail!(
            "the flight phase's painted stack peak ({} B) exceeds {} B (the flight stack \
             budget, docs/results/timing.md, Stack; `cargo xtask stack` shows the deepest static path)",
            m.stack.get("flight").copied().unwrap_or(0),
            MAX_FLIGHT_STACK
        );
    }
    if !stack_headroom_ok(m) {
        bail!(
            "the deepest stack phase ({} B) leaves less than {} B of the {} B stack region: the \
             stack may have overflowed into the statics (docs/results/timing.md, Stack)",
            stack_peak(m),
            MIN_STACK_HEADROOM,
            m.stack.get("region").copied().unwrap_or(0)
        );
    }
    Ok(())
}

/// Whether `-Z emit-stack-sizes` can cross-check the painted stack here.
fn stack_sizes_note() -> String {
    let nightly_target = Command::new("rustup")
        .args(["+nightly", "target", "list", "--installed"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).contains(TARGET));
    match nightly_target {
        None => "not done: no nightly toolchain is installed (`-Z emit-stack-sizes` is \
                 nightly-only, and stable ignores `-C llvm-args=-stack-size-section`)"
            .into(),
        Some(false) => format!(
            "not done: the nightly toolchain here has no `{TARGET}` standard library and no \
             `rust-src` for `-Z build-std`, and neither can be installed offline \
             (`-Z emit-stack-sizes` is nightly-only; stable ignores \
             `-C llvm-args=-stack-size-section`)"
        ),
        Some(true) => format!(
            "available (nightly with `{TARGET}`) but not automated yet: build with \
             `RUSTFLAGS=\"-Z emit-stack-sizes\" cargo +nightly build --profile flight --target \
             {TARGET} -p fsw-image` and read `.stack_sizes`"
        ),
    }
}

/// The executive's largest time for group `name` in instructions: its per-group timing reads
/// SysTick in whole microseconds of virtual time (1 us = 1000 instructions), rounded up here.
fn exec_group_insns(m: &Measured, name: &str) -> u64 {
    m.exec
        .iter()
        .find(|e| e.0 == name)
        .map_or(0, |e| (e.2 + 1) * 1000)
}

/// Largest background slice of a frame (VO work items): the largest RG1-only frame less the
/// RG1 group's own worst case.
fn background_slice_insns(m: &Measured) -> u64 {
    m.frame("RG1")
        .max
        .saturating_sub(exec_group_insns(m, "RG1").min(m.frame("RG1").min))
}

/// The rate groups as the executive measured them on the replay (the navigation tasks run in
/// them), and visual odometry as the background entity.
fn groups(m: &Measured) -> Vec<Group> {
    vec![
        Group {
            name: "RG1",
            period_s: 0.005,
            insns: exec_group_insns(m, "RG1"),
            content: "IMU read and checks, EKF propagation (alignment at start)".into(),
        },
        Group {
            name: "RG2",
            period_s: 0.05,
            insns: exec_group_insns(m, "RG2"),
            content: "joints; kinematic odometry, gate, EKF update or slip vector, clone and \
                      release; guidance, inverse kinematics, motor command"
                .into(),
        },
        Group {
            name: "RG2B",
            period_s: 0.05,
            insns: exec_group_insns(m, "RG2B"),
            content: "half an RG2 period later: the zero-velocity update of a stop (apart from \
                      the stop's kinematic update); status and navigation telemetry"
                .into(),
        },
        Group {
            name: "RG3",
            period_s: 0.2,
            insns: exec_group_insns(m, "RG3"),
            content: "capture decision (distance, heading, time), stereo trigger, capture \
                      clone and recorder snapshot"
                .into(),
        },
        Group {
            name: "RG4",
            period_s: 5.0,
            insns: exec_group_insns(m, "RG4"),
            content: "sun sensor read and heading update; power subsystem read and checks".into(),
        },
        Group {
            name: "VO",
            period_s: 1.0,
            insns: m.task("vo_update").max + m.task("rectify_pair").max,
            content: "one rectification of the raw pair and one visual-odometry update per \
                      stereo pair (largest measured; a capture every 0.1 m, 1 s at 0.1 m/s), run \
                      in the background slices of the frames"
                .into(),
        },
        Group {
            name: "HAZ",
            period_s: 5.0,
            insns: m.task("hazard_map").max + m.task("roverbug_plan").max,
            content: "goal-directed drives only: one hazard map and one RoverBug step (largest \
                      measured); a map every 1 m of travel (10 s at 0.1 m/s) and at path ends: \
                      the SIL-HAZ runs made one every 7-10 s, 5 s is taken as the bound"
                .into(),
        },
        Group {
            name: "LOC",
            period_s: 5.0,
            insns: m.task("localize").max,
            content: "terrain-map localization (`fsw::flight::nav::loc_nav`): a search \
                      in background work items after the hazard map that completes a local \
                      map (four maps, one every 0.5 m of travel) or a stop's view: at most one \
                      per hazard map, the HAZ bound"
                .into(),
        },
        Group {
            name: "SEQ",
            period_s: 5.0,
            insns: m.task("sequencer_replan").max,
            content: "on-board sequencer (`fsw::flight::nav::mission`): one replan in \
                      a background slice per trigger (a dwell done, every 2 m of travel, a leg \
                      grown at a RoverBug step, the energy check at a 0.2 Hz power reading): \
                      at most one per power reading, 5 s, taken as the bound (SIL-SEQ-1 made \
                      18 in 563 s)"
                .into(),
        },
    ]
}

fn summary(m: &Measured, r: &ElfReport) -> String {
    let g = groups(m);
    let u = |cpi: f64| -> f64 {
        g.iter()
            .map(|x| secs(x.insns, cpi) / x.period_s)
            .sum::<f64>()
    };
    format!(
        "timing summary: propagate max {} insns, VO max {} insns, total utilisation at 300 MHz \
         {:.1}-{:.1} % (CPI 1-2), stack flight {} B (margin {} B to {} B) / nav tasks {} B, \
         static RAM {} B, panic sites {}",
        thousands(m.task("ekf_propagate").max),
        thousands(m.task("vo_update").max),
        100.0 * u(CPI[0]),
        100.0 * u(CPI[1]),
        m.stack.get("flight").copied().unwrap_or(0),
        margin(
            MAX_FLIGHT_STACK,
            m.stack.get("flight").copied().unwrap_or(0)
        ),
        MAX_FLIGHT_STACK,
        m.stack.get("bench").copied().unwrap_or(0),
        r.section(".data") + r.section(".bss") + r.section(".uninit"),
        r.panic_total()
    )
}

/// `limit - used` with its sign, thousands separated.
fn margin(limit: u64, used: u64) -> String {
    if used <= limit {
        thousands(limit - used)
    } else {
        format!("-{}", thousands(used - limit))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flight_stack_limit_is_enforced_at_32_kib() {
        let with = |flight: u64| Measured {
            stack: pairs(&[
                "init",
                "1000",
                "flight",
                &flight.to_string(),
                "region",
                "281188",
            ]),
            ..Measured::default()
        };
        assert!(flight_stack_ok(&with(25_544)));
        assert!(flight_stack_ok(&with(32_768)));
        assert!(!flight_stack_ok(&with(32_769)));
        // A missing figure is a failure, not a pass.
        assert!(!flight_stack_ok(&Measured::default()));
        assert_eq!(margin(MAX_FLIGHT_STACK, 25_544), "7,224");
        assert_eq!(margin(MAX_FLIGHT_STACK, 40_816), "-8,048");
    }
}
