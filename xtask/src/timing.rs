//! `cargo xtask timing`: timing analysis on the rover CPU model (QEMU `mps2-an500`, `-icount`),
//! bit-identical host/target replay, stack and memory budgets; writes `docs/timing.md`.

use crate::cpi::{self, GroupCost};
use crate::elf::{self, ElfReport};
use crate::stack::{self, StackReport, Summary as StackSummary};
use crate::{build_image, cargo, qemu_args, run, step, TARGET};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

/// Scenario and length of the recorded segment.
const SCENARIO: &str = "scenarios/slope-10-cross.toml";
const SECONDS: &str = "10";
/// Where the tape goes.
const TAPE: &str = "target/timing/slope-10-cross.tape";
/// The generated document.
const DOC: &str = "docs/timing.md";

/// Stated clock of the rover CPU, Hz.
const CLOCK_HZ: f64 = 300e6;
/// Stated range of cycles per instruction.
const CPI: [f64; 2] = [1.0, 2.0];
/// CPU design margin: total utilisation must stay at or below this.
const DESIGN_MARGIN: f64 = 0.5;

/// Goals (reported, not enforced).
const GOAL_PROPAGATE: u64 = 15_000;
/// Inverse kinematics per RG2 cycle (issue 18).
const GOAL_IK: u64 = 10_000;
const GOAL_RG2_FRAME: u64 = 100_000;
/// The minor frame, s.
const FRAME_S: f64 = 0.005;
const GOAL_VO: u64 = 60_000_000;
const GOAL_STACK: u64 = 32 * 1024;
/// Least stack-region headroom every measured phase must leave (enforced): a peak that reaches
/// the bottom of the painted region may have overflowed into the statics unseen.
const MIN_STACK_HEADROOM: u64 = 4 * 1024;

/// Most stack the flight phase may use, bytes (issue 18: the flight stack at most 32 KiB):
/// the painted high-water mark of "flight software, 2000 replayed frames", which includes the
/// image's `main`, the measuring closure and the replay harness under `Fsw::tick`. Enforced:
/// `cargo xtask timing` fails above it (the margin is in `docs/timing.md`, Goals and Stack).
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

/// Run the timing analysis and write `docs/timing.md`.
pub fn timing() -> Result<()> {
    let total = Instant::now();

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
    let host_replay = lines_with(&host, "replay ");
    println!(
        "{}",
        host_replay.last().copied().unwrap_or("no replay output")
    );
    println!("ok in {:.1} s", t.elapsed().as_secs_f64());

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

    // Determinism: every figure of the two runs is identical.
    let (a, b) = (
        lines_with(&first, "timing "),
        lines_with(&second, "timing "),
    );
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
    // Bit-identical replay: the image's digest lines are the host's.
    let target_replay = lines_with(&first, "replay ");
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

    let m = parse(&first)?;
    let calib_ok = {
        let expect = m.calib.get("expect").copied().unwrap_or(0);
        let tol = 2 * m.calib.get("insns_per_count").copied().unwrap_or(40) + 16;
        ["loop2", "loop4"]
            .iter()
            .all(|k| m.calib.get(*k).is_some_and(|v| v.abs_diff(expect) <= tol))
    };
    if !calib_ok {
        bail!("instruction-count calibration failed: {:?}", m.calib);
    }
    let report = elf::analyse(&image)?;
    let mca = cpi::tool_version()?;
    let loops = cpi::analyse(&image, Some(Path::new(cpi::BLOCKS)))?;
    let stack_sizes = stack_sizes_note();
    let static_stack = stack::analyse(&image)?;
    let static_summary = stack::summarise(&static_stack);
    let qemu = Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.lines().next().map(str::to_string))
        .unwrap_or_else(|| "qemu-system-arm".into());
    let doc = document(
        &m,
        &report,
        &target_replay,
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
    println!("{}", summary(&m, &report));
    let flight_panics = report.flight_panic_sites();
    if !flight_panics.is_empty() {
        bail!(
            "the image has panic sites outside its number formatting (issue 18: the flight code \
             has no panic path); enclosing functions: {flight_panics:?}"
        );
    }
    if !flight_stack_ok(&m) {
        bail!(
            "the flight phase's painted stack peak ({} B) exceeds {} B (issue 18; \
             docs/timing.md, Stack; `cargo xtask stack` shows the deepest static path)",
            m.stack.get("flight").copied().unwrap_or(0),
            MAX_FLIGHT_STACK
        );
    }
    if !stack_headroom_ok(&m) {
        bail!(
            "the deepest stack phase ({} B) leaves less than {} B of the {} B stack region: the \
             stack may have overflowed into the statics (docs/timing.md, Stack)",
            stack_peak(&m),
            MIN_STACK_HEADROOM,
            m.stack.get("region").copied().unwrap_or(0)
        );
    }
    println!(
        "timing: done in {:.1} s (one QEMU run {:.1} s)",
        total.elapsed().as_secs_f64(),
        qemu_s
    );
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
            content: "terrain-map localization (issue 17, `fsw::flight::nav::loc_nav`): a search \
                      in background work items after the hazard map that completes a local \
                      map (four maps, one every 0.5 m of travel) or a stop's view: at most one \
                      per hazard map, the HAZ bound"
                .into(),
        },
        Group {
            name: "SEQ",
            period_s: 5.0,
            insns: m.task("sequencer_replan").max,
            content: "on-board sequencer (issue 17, `fsw::flight::nav::mission`): one replan in \
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

/// Rows of a deepest path shown in the document.
const STATIC_PATH_ROWS: usize = 14;

/// The "Static analysis" part of the Stack section ([`crate::stack`]).
/// The image's initialisation functions: the flight software's and the navigation-task
/// bench's construction.
const INIT_FUNCTIONS: [&str; 2] = [
    "fsw_image::target::install_new_fsw",
    "fsw_image::target::bench::Bench::install",
];

/// The deepest path from the image's entry through one of [`INIT_FUNCTIONS`] (the static
/// counterpart of the painted initialisation peak).
fn init_path(sr: &StackReport, ss: &StackSummary) -> Option<stack::DeepPath> {
    let entry = ss.entry.as_ref()?.steps.first()?.func;
    INIT_FUNCTIONS
        .iter()
        .filter_map(|name| sr.find(|n| n == *name))
        .filter_map(|via| sr.deepest_through(entry, via))
        .max_by_key(|p| p.total)
}

fn static_section(d: &mut String, m: &Measured, sr: &StackReport, ss: &StackSummary) -> Result<()> {
    let painted = |k: &str| m.stack.get(k).copied().unwrap_or(0);
    writeln!(d, "### Static analysis\n")?;
    writeln!(
        d,
        "`xtask/src/stack.rs` (also `cargo xtask stack`) decodes the image's Thumb-2 code itself \
         (literal pools skipped by the `$d` mapping symbols): the frame of each of the {} \
         functions is the sum of its stack-pointer decrements (`push`, `push.w`, `str [sp, \
         #-4]!`, `sub sp`, `subw sp`, `sub.w sp, sp, rN` after `movw`/`movt`, `vpush`); `bl` \
         is a call under the caller's frame, a `b`/`b.w`/`b<cond>` out of the function a tail \
         call at the caller's entry stack pointer. The worst case of a root is the deepest path \
         of frames through that call graph (exception entry, 32-104 B, not included). \
         Indirect calls and jumps cannot be followed and are counted; cycles are listed and \
         cut after one trip.\n",
        sr.funcs.len()
    )?;
    writeln!(
        d,
        "| root | static worst case | painted | functions reachable | indirect calls/jumps reachable |"
    )?;
    writeln!(d, "|---|---:|---:|---:|---:|")?;
    let init = init_path(sr, ss);
    let rows: [(&str, &Option<stack::DeepPath>, String); 4] = [
        (
            "image entry (`Reset`): every phase",
            &ss.entry,
            format!("{} B (deepest phase)", thousands(stack_peak(m))),
        ),
        (
            "image entry through the initialisation (`install_new_fsw`, `Bench::install`)",
            &init,
            format!("{} B (initialisation)", thousands(painted("init"))),
        ),
        ("`Fsw::tick` alone", &ss.tick, "-".into()),
        (
            "image entry through `Fsw::tick` (flight phase)",
            &ss.flight,
            format!("{} B (flight)", thousands(painted("flight"))),
        ),
    ];
    for (name, p, painted) in rows {
        match p {
            Some(p) => writeln!(
                d,
                "| {name} | {} B | {painted} | {} | {} |",
                thousands(p.total),
                p.reachable,
                p.reachable_indirect
            )?,
            None => writeln!(d, "| {name} | not found in the image | {painted} | - | - |")?,
        }
    }
    writeln!(d)?;
    if let Some(p) = &ss.flight {
        writeln!(
            d,
            "Deepest path from the entry through `Fsw::tick` (the flight phase's static bound; the \
             painted figure also covers the replay harness around `tick` and reads up to 256 B \
             high, see above):\n"
        )?;
        path_table(d, sr, p)?;
    }
    if let Some(p) = &init {
        writeln!(
            d,
            "Deepest path from the entry through the initialisation (everything built in place, \
             see above):\n"
        )?;
        path_table(d, sr, p)?;
    }
    if let Some(p) = &ss.entry {
        writeln!(d, "Deepest path from the entry (every phase):\n")?;
        path_table(d, sr, p)?;
    }
    let with_indirect: Vec<String> = sr
        .funcs
        .iter()
        .filter(|f| f.indirect > 0)
        .map(|f| format!("`{}` ({})", stack::short(&f.name), f.indirect))
        .collect();
    let unresolved: usize = sr.funcs.iter().map(|f| f.unresolved).sum();
    let tick_indirect = ss.tick.as_ref().map_or(0, |p| p.reachable_indirect);
    let entry_indirect = ss.entry.as_ref().map_or(0, |p| p.reachable_indirect);
    writeln!(
        d,
        "Indirect calls and jumps: {} in {} functions of the image{}{}. {} of them are reachable \
         from `Fsw::tick`{} and {} from the entry{}. Direct branches to no known function: \
         {unresolved}.\n",
        sr.indirect_total(),
        with_indirect.len(),
        if with_indirect.is_empty() { "" } else { ": " },
        with_indirect.join(", "),
        tick_indirect,
        if tick_indirect == 0 {
            " (its figure covers everything it can call)"
        } else {
            " (its figure leaves out what they call)"
        },
        entry_indirect,
        if entry_indirect == 0 {
            ""
        } else {
            " (the entry's figure leaves out what they call: when they are all in `core::fmt`, \
             the number formatting of the semihosting reports printed between the phases, \
             through trait objects)"
        },
    )?;
    if sr.cycles.is_empty() {
        writeln!(d, "Cycles (recursion) in the call graph: none.\n")?;
    } else {
        let list: Vec<String> = sr
            .cycles
            .iter()
            .map(|c| {
                let names: Vec<String> = c
                    .iter()
                    .map(|&i| format!("`{}`", stack::short(&sr.funcs[i].name)))
                    .collect();
                names.join(" / ")
            })
            .collect();
        writeln!(
            d,
            "Cycles (recursion) in the call graph: {} ({} closing edges cut): {}.\n",
            sr.cycles.len(),
            sr.cut_edges,
            list.join("; ")
        )?;
    }
    Ok(())
}

/// One deepest path as a table, [`STATIC_PATH_ROWS`] rows at most.
fn path_table(d: &mut String, sr: &StackReport, p: &stack::DeepPath) -> Result<()> {
    writeln!(d, "| stack in use at entry | frame | function |")?;
    writeln!(d, "|---:|---:|---|")?;
    for st in p.steps.iter().take(STATIC_PATH_ROWS) {
        let f = &sr.funcs[st.func];
        writeln!(
            d,
            "| {} B | {} B | {}`{}` |",
            thousands(st.depth_at_entry),
            thousands(f.frame),
            if st.tail { "(tail call) " } else { "" },
            stack::short(&f.name).replace('|', "\\|")
        )?;
    }
    if p.steps.len() > STATIC_PATH_ROWS {
        writeln!(d, "| | | ... {} more |", p.steps.len() - STATIC_PATH_ROWS)?;
    }
    writeln!(d)?;
    Ok(())
}

const TASK_DOC: [(&str, &str, &str); 17] = [
    (
        "ekf_propagate",
        "`Ekf::propagate`",
        "RG1: one IMU sample (every valid sample of the tape)",
    ),
    (
        "ekf_gate_relative_pose",
        "`Ekf::gate_relative_pose`",
        "RG2: Mahalanobis gate of the kinematic relative pose; and of each VO pose",
    ),
    (
        "ekf_update_relative_pose",
        "`Ekf::update_relative_pose`",
        "RG2: update between two clones (applied ungated, so always whole)",
    ),
    (
        "ekf_clone",
        "`Ekf::clone_at`",
        "RG2 interval start and RG3 capture",
    ),
    (
        "ekf_gate_fuse_without_vo",
        "`Ekf::gate_relative_pose_kept` then `Ekf::fuse_kept_relative_pose` (every other kinematic interval of the tape instead of the gate and the update)",
        "RG2 without VO: the interval gated at its own covariance, then fused with z observed and the slip allowances from the kept innovation (`Navigator::fuse_without_vo`; a gate and a whole update before issue 18's third pass)",
    ),
    (
        "forward_kinematics",
        "`kinematics::forward_kinematics_from_joints`",
        "not called by the flight software (the odometry integrates the joints itself); the body-rate solve of one joint reading, kept as a kinematics benchmark",
    ),
    (
        "kinematic_odometry",
        "`KinematicOdometry::update_with_gyro` (the flight configuration: eq. 15 step with its covariance, and the contact-angle estimator on the tape's gyro rotation since the last reading)",
        "RG2: odometry integration of a joint reading",
    ),
    (
        "inverse_kinematics",
        "`kinematics::inverse_kinematics_contact` (worst case: on the odometry's contact angles without the navigator's 0.1 rad deadband)",
        "RG2: steering and wheel rates of guidance's command",
    ),
    (
        "guidance_step",
        "`Guidance::step`",
        "RG2: carrot, heading and crab loops on the EKF pose",
    ),
    (
        "vo_update",
        "`VisualOdometry::<150>::start`, then `step` per work item",
        "background: one full update on a 640x480 pair in `.extram`",
    ),
    (
        "hazard_map",
        "`HazardMapper::start`, then `step` per work item",
        "background (goal-directed drives): one hazard map of the pair after VO (issue 16)",
    ),
    (
        "roverbug_plan",
        "`Planner::plan_each` with the map's polygons built as it takes them (as `hazard_nav` flies it)",
        "background, after a hazard map: one RoverBug step (the tape's scene: few obstacles)",
    ),
    (
        "rectify_pair",
        "`Rectifier::start`, then `step` per row item (`fsw::rectify`)",
        "background, before VO: rectification of the raw wide-angle pair (2 x 480 rows, \
         fixed-point map every 8 px, integer bilinear)",
    ),
    (
        "rectify_row",
        "one `Rectifier::step` item",
        "one rectified row of 640 pixels (`RectifyConfig::row_cost` should cover its largest)",
    ),
    (
        "localization_map",
        "`GlobalMap::reset_centred`, `insert_point` per point, `finish`",
        "once per uplinked map (issue 17): a 38.4 m global map of a synthetic field of 392 rocks \
         (`fsw/image/src/target/loc_bench.rs`), with its distance transform",
    ),
    (
        "localize",
        "`Localizer::localize`",
        "background, after a hazard map (issue 17): one branch-and-bound localization of a hazard grid against that map, prior 0.3 m / \
         0.03 rad, 8 synthetic trials",
    ),
    (
        "sequencer_replan",
        "`Sequencer::replan_committed`",
        "background, on a trigger of the navigator's mission (issue 17): one replan of 8 \
         targets with windows, energy, a leg penalty and the commitment to one target, 8 random \
         problems",
    ),
];

fn document(
    m: &Measured,
    r: &ElfReport,
    replay: &[&str],
    stack_sizes: &str,
    (sr, ss): (&StackReport, &StackSummary),
    qemu: &str,
    (mca, loops): (&str, &[GroupCost]),
) -> Result<String> {
    let mut d = String::new();
    let calib = |k: &str| m.calib.get(k).copied().unwrap_or(0);
    let stack = |k: &str| m.stack.get(k).copied().unwrap_or(0);
    writeln!(
        d,
        "# Timing, stack and memory on the rover CPU\n\n\
         Generated by `cargo xtask timing` (also the last step of `cargo xtask test`); do not \
         edit by hand. Every figure below comes from the flight image built with the `flight` \
         profile (fat LTO, `-C target-cpu=cortex-m7`) running in {qemu}, machine `mps2-an500` \
         (Cortex-M7), with `-icount shift=0,align=off,sleep=off`, on the inputs recorded from \
         {} s of `{SCENARIO}` ({} minor frames, {} stereo pairs rendered by the simulator's \
         textured renderer, tape of {} bytes). The command runs QEMU twice and fails unless both \
         runs print identical figures, and fails unless the image's replay digests equal the \
         host's.\n",
        SECONDS,
        m.tape.1,
        m.vo.get("updates").copied().unwrap_or(0),
        thousands(m.tape.2)
    )?;

    writeln!(d, "## Method\n")?;
    writeln!(
        d,
        "- **Time base.** With `-icount shift=0` QEMU advances virtual time by exactly 1 ns per \
         guest instruction, whatever the host does (`align=off`: no coupling to host time; \
         `sleep=off`: idle time jumps to the next timer). SysTick counts the model's 25 MHz core \
         clock in that virtual time, so one SysTick count is **{} instructions**. The image reads \
         the SysTick count and value around each measured call (`fsw/image/src/target/measure.rs`); \
         resolution is one count (40 instructions); the cost of an empty measurement ({} \
         instructions) is subtracted.\n\
         - **Calibration** (run every time, the command fails if it is off by more than two \
         counts): a loop of 1,000,000 iterations of `subs; bne` (2,000,000 instructions) \
         measured **{}** instructions, and 500,000 iterations of `nop; nop; subs; bne` \
         measured **{}**.\n\
         - **Inputs.** `sim-host record` ran the scenario with every HAL device wrapped in a \
         recording decorator and wrote the call tape (`rover-replay`): the result of every device \
         call in call order, and the pixels of each stereo pair. The image reads it from the host \
         by semihosting. Phase 1 replays it through the flight software (`Fsw::tick` per minor \
         frame, measured whole, the navigation in the loop). Phase 2 runs each navigation module \
         on its own on the tape's inputs (`fsw/image/src/target/bench.rs`): every IMU sample, \
         every joint reading, every stereo capture.\n\
         - **Instructions to time.** QEMU counts instructions, not cycles. Time = instructions x \
         CPI / clock, at the stated clock of **{:.0} MHz** and a CPI range of **{:.1} to {:.1}**. \
         The Cortex-M7 is a dual-issue, 6-stage in-order core: with code in ITCM and data in DTCM \
         (zero wait states) integer and load/store code runs near or below 1 CPI; the \
         double-precision code of the filter and the kinematics does not (FP64 multiply-accumulate \
         several cycles, divide and square root about 30). The Cortex-M7 pipeline model in \
         \"Cycles per instruction\" below gives each code group its CPI, weighted by what ran: \
         about 1 for the image code that carries the background load, about 2.9 for the FP64 \
         groups, so the utilisation is also given with each rate group at the higher of 2.0 and \
         its model CPI (memory stalls are estimated apart). A measurement on the flight board \
         would replace both.\n",
        calib("insns_per_count"),
        calib("overhead"),
        thousands(calib("loop2")),
        thousands(calib("loop4")),
        CLOCK_HZ / 1e6,
        CPI[0],
        CPI[1]
    )?;

    writeln!(d, "## Flight tasks (instructions per call)\n")?;
    writeln!(
        d,
        "| task | function | calls | min | max | mean | time of max at {:.0} MHz, CPI {:.1} / {:.1} | errors |",
        CLOCK_HZ / 1e6,
        CPI[0],
        CPI[1]
    )?;
    writeln!(d, "|---|---|---:|---:|---:|---:|---:|---:|")?;
    for (key, func, what) in TASK_DOC {
        let s = m.task(key);
        writeln!(
            d,
            "| {key} ({what}) | {func} | {} | {} | {} | {} | {} / {} | {} |",
            s.n,
            thousands(s.min),
            thousands(s.max),
            thousands(s.mean),
            fmt_time(secs(s.max, CPI[0])),
            fmt_time(secs(s.max, CPI[1])),
            s.errors
        )?;
    }
    writeln!(
        d,
        "\nErrors are calls that returned an error value (they are measured too). Visual \
         odometry: {} updates, {} poses (the first pair only builds the keyframe), {} failures, \
         {}-{} inliers, up to {} work items.\n",
        m.vo.get("updates").copied().unwrap_or(0),
        m.vo.get("poses").copied().unwrap_or(0),
        m.vo.get("failures").copied().unwrap_or(0),
        m.vo.get("inliers_min").copied().unwrap_or(0),
        m.vo.get("inliers_max").copied().unwrap_or(0),
        m.vo.get("work_items_max").copied().unwrap_or(0)
    )?;

    writeln!(d, "### VO work items\n")?;
    writeln!(
        d,
        "The same updates run one work item per call, by kind (`fsw::vo::WorkKind`). The \
         background slot runs items until their configured costs (`VoConfig::work_cost`, units \
         of 10,000 instructions) reach `background_quantum` = {} units per frame, so a slice \
         is at most the quantum plus one item; the configured cost of a kind should cover its \
         largest item.\n",
        m.background_quantum
    )?;
    writeln!(
        d,
        "| kind | items | min | max | mean | configured cost | max / cost |"
    )?;
    writeln!(d, "|---|---:|---:|---:|---:|---:|---:|")?;
    for (name, s) in &m.vo_items {
        let cost = m.vo_cost.get(name).copied().unwrap_or(0).max(1) * 10_000;
        writeln!(
            d,
            "| {name} | {} | {} | {} | {} | {} | {:.2} |",
            s.n,
            thousands(s.min),
            thousands(s.max),
            thousands(s.mean),
            thousands(cost),
            s.max as f64 / cost as f64
        )?;
    }
    writeln!(d)?;

    writeln!(d, "## Whole minor frames of the flight software (replay)\n")?;
    writeln!(
        d,
        "`Fsw::tick` (executive, device reads and checks, navigation tasks, telemetry, stereo \
         capture, and the background slot's VO work items and late-update replay), by the groups that ran in the frame. Every frame runs RG1 and the background \
         slot, so the largest frames are those where VO work items are heavy (image check, \
         feature selection, tracking).\n"
    )?;
    writeln!(
        d,
        "| frame | frames | min | max | mean | max at {:.0} MHz, CPI {:.1} / {:.1} |",
        CLOCK_HZ / 1e6,
        CPI[0],
        CPI[1]
    )?;
    writeln!(d, "|---|---:|---:|---:|---:|---:|")?;
    for (name, s) in &m.frames {
        writeln!(
            d,
            "| {name} | {} | {} | {} | {} | {} / {} |",
            s.n,
            thousands(s.min),
            thousands(s.max),
            thousands(s.mean),
            fmt_time(secs(s.max, CPI[0])),
            fmt_time(secs(s.max, CPI[1]))
        )?;
    }
    writeln!(
        d,
        "\nAll {} frames: {} instructions. Cross-check, the executive's own per-group timing \
         from `Clock::counter` (SysTick, 1 us = 1000 instructions of virtual time; whole \
         microseconds):\n",
        m.tape.1,
        thousands(m.replay_insns)
    )?;
    writeln!(d, "| group | runs | max_us | mean_us |")?;
    writeln!(d, "|---|---:|---:|---:|")?;
    for (name, runs, max, mean) in &m.exec {
        writeln!(d, "| {name} | {runs} | {max} | {mean} |")?;
    }
    writeln!(
        d,
        "\nPer task, the same timing against the task's budget in the schedule table \
         (`fsw::flight::TASKS`; an overrun is counted in telemetry, it changes nothing):\n"
    )?;
    writeln!(d, "| task | max_us | mean_us | budget_us | max / budget |")?;
    writeln!(d, "|---|---:|---:|---:|---:|")?;
    for (name, max, mean, budget) in &m.exec_tasks {
        writeln!(
            d,
            "| {name} | {max} | {mean} | {budget} | {:.2} |",
            *max as f64 / (*budget).max(1) as f64
        )?;
    }

    let groups = groups(m);
    writeln!(d, "\n## Utilisation and response times\n")?;
    writeln!(
        d,
        "Worst case per release of each rate group: the executive's own largest time for the \
         group on the replay (its tasks, with the navigation in the loop; whole microseconds of \
         virtual time, rounded up to the next 1000 instructions). Visual odometry is the \
         background entity: one update per stereo pair (1 s), the largest measured, executed \
         in slices of `background_quantum` cost units per frame (see \"VO work items\").\n"
    )?;
    writeln!(
        d,
        "| group | period | worst case (instructions) | contents | U at CPI {:.1} | U at CPI {:.1} | model CPI | U at model CPI |",
        CPI[0], CPI[1]
    )?;
    writeln!(d, "|---|---:|---:|---|---:|---:|---:|---:|")?;
    let mut u = [0.0; 2];
    let mut u_model = 0.0;
    // Issue 18's binding figure: each group at CPI 2.0 or its model CPI, whichever is higher.
    let mut u_bind = 0.0;
    for g in &groups {
        let ui = CPI.map(|c| secs(g.insns, c) / g.period_s);
        u[0] += ui[0];
        u[1] += ui[1];
        let c = model_cpi(g.name, loops);
        let um = secs(g.insns, c) / g.period_s;
        u_model += um;
        u_bind += secs(g.insns, c.max(CPI[1])) / g.period_s;
        writeln!(
            d,
            "| {} | {} | {} | {} | {:.2} % | {:.2} % | {:.2} | {:.2} % |",
            g.name,
            fmt_time(g.period_s),
            thousands(g.insns),
            g.content,
            100.0 * ui[0],
            100.0 * ui[1],
            c,
            100.0 * um
        )?;
    }
    let rt_u: [f64; 2] = CPI.map(|c| {
        groups
            .iter()
            .filter(|g| g.name != "VO" && g.name != "HAZ")
            .map(|g| secs(g.insns, c) / g.period_s)
            .sum()
    });
    writeln!(
        d,
        "| **total** | | | | **{:.2} %** | **{:.2} %** | | **{:.2} %** |\n| total without the background (VO, HAZ) | | | | {:.2} % | {:.2} % | | |\n",
        100.0 * u[0],
        100.0 * u[1],
        100.0 * u_model,
        100.0 * rt_u[0],
        100.0 * rt_u[1]
    )?;
    writeln!(
        d,
        "The model CPI of a group is the largest CPI of the code groups its tasks run (section \
         \"Cycles per instruction\" below: LLVM's Cortex-M7 pipeline model, zero-wait memory, \
         every executed block of a code group weighted by how often it ran on the tape). Issue \
         18 asks for the utilisation \"at CPI 2.0 or at the justified CPI, whichever is \
         higher\": with each group at the higher of {:.1} and its model CPI the total is \
         **{:.2} %**. The groups above {:.1} are the double-precision ones (EKF, kinematics: the \
         FP64 operations take the FP pipe twice, with 4-11 cycles of latency on dependent \
         chains); the image groups that carry the background load run near CPI 1 in the model \
         and are taken at {:.1}.\n",
        CPI[1],
        100.0 * u_bind,
        CPI[1],
        CPI[1]
    )?;
    writeln!(
        d,
        "Margin against the {:.0} % CPU design margin: {:+.1} points at CPI {:.1}, {:+.1} points \
         at CPI {:.1} (positive: below the limit).\n",
        100.0 * DESIGN_MARGIN,
        100.0 * (DESIGN_MARGIN - u[0]),
        CPI[0],
        100.0 * (DESIGN_MARGIN - u[1]),
        CPI[1]
    )?;
    writeln!(
        d,
        "Response-time analysis (rate-monotonic fixed priorities RG1 > RG2 > RG2B > RG3 > RG4 > VO > HAZ, \
         deadline = period, Joseph-Pandya iteration `R = C + sum over higher priorities of \
         ceil(R / T_j) C_j`). The cyclic executive runs the groups in order inside a 5 ms frame \
         and hands the background a quantum per frame, so this preemptive model is the \
         schedulability test of the task set; the frame check below covers the non-preemptive \
         frame.\n"
    )?;
    writeln!(
        d,
        "| group | period | R at CPI {:.1} | R / T | R at CPI {:.1} | R / T |",
        CPI[0], CPI[1]
    )?;
    writeln!(d, "|---|---:|---:|---:|---:|---:|")?;
    for (i, g) in groups.iter().enumerate() {
        let cells: Vec<String> = CPI
            .iter()
            .map(|c| match response_time(&groups, i, *c) {
                Some(rt) => format!("{} | {:.1} %", fmt_time(rt), 100.0 * rt / g.period_s),
                None => "misses its deadline | > 100 %".into(),
            })
            .collect();
        writeln!(
            d,
            "| {} | {} | {} | {} |",
            g.name,
            fmt_time(g.period_s),
            cells[0],
            cells[1]
        )?;
    }
    let worst_frame = groups[0].insns + groups[1].insns;
    let slice = background_slice_insns(m);
    writeln!(
        d,
        "\nWorst minor frame of the groups (RG1 + RG2): {} instructions, {} / {} of the 5 ms \
         frame ({:.1} % / {:.1} %). The largest background slice (work items until their \
         costs reach the quantum of {} units, the last one past it by up to its own cost; or \
         16 operations of a late VO update's replay) adds {} instructions ({} / {}): with it \
         the frame takes {:.1} % / {:.1} % of the period. The quantum is set for this check \
         (`FswConfig::rocky8`; at 100 units the frame took 133 % at CPI 2.0, session 19).\n",
        thousands(worst_frame),
        fmt_time(secs(worst_frame, CPI[0])),
        fmt_time(secs(worst_frame, CPI[1])),
        100.0 * secs(worst_frame, CPI[0]) / 0.005,
        100.0 * secs(worst_frame, CPI[1]) / 0.005,
        m.background_quantum,
        thousands(slice),
        fmt_time(secs(slice, CPI[0])),
        fmt_time(secs(slice, CPI[1])),
        100.0 * secs(worst_frame + slice, CPI[0]) / 0.005,
        100.0 * secs(worst_frame + slice, CPI[1]) / 0.005
    )?;

    cpi_section(&mut d, mca, loops)?;
    writeln!(d, "## Stack\n")?;
    writeln!(
        d,
        "cortex-m-rt's `paint-stack` fills the stack region with `0xCCCCCCCC` at reset; the \
         image scans up from the bottom of the region (`_stack_end`) for the first changed word \
         after each phase and paints the unused part again before the next (a 256-byte margin \
         below the stack pointer is left unpainted, so the later phases read up to 256 bytes \
         high).\n"
    )?;
    writeln!(d, "| phase | high-water mark |")?;
    writeln!(d, "|---|---:|")?;
    writeln!(
        d,
        "| initialisation (flight software and the bench's navigation state built in place in their statics) | {} B |",
        thousands(stack("init"))
    )?;
    writeln!(
        d,
        "| flight software, 2000 replayed frames | {} B |",
        thousands(stack("flight"))
    )?;
    writeln!(
        d,
        "| navigation tasks on the tape (EKF, kinematics, guidance, VO) | {} B |",
        thousands(stack("bench"))
    )?;
    writeln!(
        d,
        "| stack region (RAM above the statics, 0x{:08x}-0x{:08x}) | {} B |\n",
        r.stack_region.1,
        r.stack_region.0,
        thousands(stack("region"))
    )?;
    writeln!(
        d,
        "The initialisation builds the large state in place, never as a value on the stack: the \
         flight software's static is initialised at compile time with the placeholder \
         `Fsw::EMPTY` and written field by field by `Fsw::init` and `Fsw::start_vo` (the \
         navigator's EKF, recorder, VO ({} KiB), hazard mapper and planner are reset in loops by \
         their `init`/`reset` methods); the bench's statics in `.extram` are set to their type's \
         `EMPTY` and built by the same `init` methods. (Before, `VisualOdometry::<150>::new` and \
         the other constructors returned their value through several frames: 261,412 B \
         painted.) Cross-check with `-Z emit-stack-sizes`: {stack_sizes}.\n",
        r.statics
            .iter()
            .find(|s| s.name.contains("vo_static"))
            .map(|s| s.size / 1024)
            .unwrap_or(0)
    )?;
    static_section(&mut d, m, sr, ss)?;

    writeln!(d, "## Memory\n")?;
    writeln!(
        d,
        "Read from the ELF (`xtask/src/elf.rs`, `object` crate). Regions from `memory.x`: FLASH \
         4 MiB at 0x0, RAM 512 KiB at 0x2000_0000, EXTRAM 16 MiB at 0x6000_0000.\n"
    )?;
    writeln!(d, "| section | address | size |")?;
    writeln!(d, "|---|---:|---:|")?;
    for s in &r.sections {
        writeln!(
            d,
            "| {} | 0x{:08x} | {} B |",
            s.name,
            s.addr,
            thousands(s.size)
        )?;
    }
    let flash =
        r.section(".vector_table") + r.section(".text") + r.section(".rodata") + r.section(".data");
    let ram = r.section(".data") + r.section(".bss") + r.section(".uninit");
    let extram = r.section(".extram");
    writeln!(
        d,
        "\n| budget | bytes | of region |\n|---|---:|---:|\n\
         | flash (.vector_table + .text + .rodata + .data load image) | {} | {:.1} % of 4 MiB |\n\
         | static RAM (.data + .bss + .uninit) | {} | {:.1} % of 512 KiB |\n\
         | image buffers (.extram) | {} | {:.1} % of 16 MiB |\n",
        thousands(flash),
        100.0 * flash as f64 / (4.0 * 1024.0 * 1024.0),
        thousands(ram),
        100.0 * ram as f64 / (512.0 * 1024.0),
        thousands(extram),
        100.0 * extram as f64 / (16.0 * 1024.0 * 1024.0)
    )?;
    writeln!(
        d,
        "Largest statics:\n\n| symbol | address | size |\n|---|---:|---:|"
    )?;
    for s in &r.statics {
        writeln!(
            d,
            "| `{}` | 0x{:08x} | {} B |",
            s.name,
            s.addr,
            thousands(s.size)
        )?;
    }
    writeln!(
        d,
        "\n(`bench::vo_static`, `bench::ekf_static` and `bench::bench_static` hold the navigation \
         state measured in phase 2: the VO with 150 features, the EKF and the bench's own state; \
         `devices::player` is the replay's frame queue; the flight software itself is \
         `target::FSW`.)\n"
    )?;

    writeln!(d, "## No allocator, panic sites\n")?;
    if r.allocator_symbols.is_empty() {
        writeln!(
            d,
            "**No allocator**: the image's symbol table has none of `__rust_alloc`, \
             `__rust_dealloc`, `__rust_realloc`, `__rust_alloc_zeroed`, `__rg_alloc`, \
             `__rdl_alloc`, `__rust_alloc_error_handler` or any `alloc::alloc::` function (and \
             the flight crates are `no_std` without `extern crate alloc`).\n"
        )?;
    } else {
        writeln!(
            d,
            "**Allocator symbols found**: {}\n",
            r.allocator_symbols.join(", ")
        )?;
    }
    writeln!(
        d,
        "**Panic sites: {}.** Method: every function of `.text` is decoded as Thumb-2 (skipping \
         the `$d` literal pools marked by the ARM mapping symbols; {} instructions decoded), and \
         every `bl`, `b.w`, `b<cond>.w`, `b` and `b<cond>` whose target is a panic function \
         (`core::panicking::*`, `core::option::unwrap_failed` / `expect_failed`, \
         `core::result::unwrap_failed`, `core::slice::index::*` failures, `len_mismatch_fail`, \
         `core::cell::panic_already_*`, `rust_begin_unwind`) is counted, except calls between \
         panic functions. After fat LTO a site is attributed to the function it was inlined \
         into, so the crate column is where the code ended up, not necessarily where it was \
         written (the `Meter::measure` instances of the timing run contain the measured flight \
         functions inlined; `core::fmt` and `flt2dec` are the image's semihosting reports and \
         panic handler). Each site is a bounds, arithmetic or unwrap check the compiler could not prove \
         away; it is reachable only if that check fails.\n",
        r.panic_total(),
        thousands(r.decoded_instructions as u64)
    )?;
    let flight_panics: usize = r.flight_panic_sites().iter().map(|(_, n)| n).sum();
    writeln!(
        d,
        "**Panic sites outside the image's number formatting: {flight_panics}** (required 0: \
         `cargo xtask timing` fails otherwise). Every site left is in `core::fmt`, \
         `core::num::flt2dec` or `core::num::bignum`, the float formatting of the image's \
         semihosting reports and panic message, which the flight software does not call. The \
         flight code avoids the checks the optimiser cannot prove away: checked accesses \
         (`get`) where an index is computed, iterator zips instead of parallel indexing, \
         `checked_rem`, and `fsw::linalg` for the 6x6 solve of the inverse kinematics, the 3x3 \
         SVD of Schonemann's fit and a `clamp` without `f64::clamp`'s bound assertion \
         (nalgebra's LU and SVD keep shape assertions and `unwrap`s). To find a new site: \
         `llvm-objdump -d` the image, take the address of the branch to the panic function \
         and `addr2line -i -f -C -e <image> <address>` (the `flight` profile keeps line \
         tables).\n"
    )?;
    writeln!(d, "| panic function | sites |\n|---|---:|")?;
    for (name, n) in &r.panic_sites {
        writeln!(d, "| `{name}` | {n} |")?;
    }
    writeln!(d, "\n| enclosing crate | sites |\n|---|---:|")?;
    for (name, n) in &r.panic_sites_by_crate {
        writeln!(d, "| `{name}` | {n} |")?;
    }
    writeln!(
        d,
        "\n| enclosing function (most sites) | sites |\n|---|---:|"
    )?;
    for (name, n) in r.panic_sites_by_function.iter().take(15) {
        writeln!(d, "| `{name}` | {n} |")?;
    }

    writeln!(d, "\n## Bit-identical replay\n")?;
    writeln!(
        d,
        "The tape was replayed through the flight software on the host (`sim-host replay`) and \
         on the rover CPU model; both printed the same lines: a digest every 200 frames and the \
         end line. Each frame's digest (FNV-1a 64, `fsw_image::flight_replay::frame_digest`) \
         covers the frame's mobility commands, telemetry records and selected public flight \
         state, and is also compared with the digest the recording run wrote into the tape, \
         frame by frame. Timing-derived data (the executive's cycle-slip count and timing-fault \
         flag, in the flight state and in `FrameStatus` telemetry) is excluded: the execution \
         counter is not replayed and legitimately differs.\n"
    )?;
    writeln!(d, "```text")?;
    for l in replay {
        writeln!(d, "{l}")?;
    }
    writeln!(d, "```\n")?;
    let end_ok = m.replay_end.contains("mismatches 0") && m.replay_end.contains("divergence none");
    writeln!(
        d,
        "Result: **{}** ({}).\n",
        if end_ok { "bit-identical" } else { "MISMATCH" },
        m.replay_end
    )?;

    writeln!(d, "## Goals\n")?;
    writeln!(d, "| goal | measured | result |\n|---|---:|---|")?;
    let prop = m.task("ekf_propagate").max;
    writeln!(
        d,
        "| EKF propagation <= {} instructions | {} | {} |",
        thousands(GOAL_PROPAGATE),
        thousands(prop),
        pass(prop <= GOAL_PROPAGATE)
    )?;
    let ik = m.task("inverse_kinematics").max;
    writeln!(
        d,
        "| inverse kinematics <= {} instructions | {} | {} |",
        thousands(GOAL_IK),
        thousands(ik),
        pass(ik <= GOAL_IK)
    )?;
    let rg2 = groups[1].insns;
    writeln!(
        d,
        "| RG2 release <= {} instructions (issue 18: the executive's largest RG2 time on the replay) | {} | {} |",
        thousands(GOAL_RG2_FRAME),
        thousands(rg2),
        pass(rg2 <= GOAL_RG2_FRAME)
    )?;
    // The largest frame measured on the replay (any groups, with its background slice) against
    // the 5 ms minor frame at CPI 2: a frame over it is a cycle slip on a CPU at that CPI.
    let (worst_name, worst) = m
        .frames
        .iter()
        .map(|(name, s)| (name.as_str(), s.max))
        .max_by_key(|(_, v)| *v)
        .unwrap_or(("none", 0));
    let worst_pct = 100.0 * secs(worst, CPI[1]) / FRAME_S;
    writeln!(
        d,
        "| largest minor frame with its background slice (replay, {worst_name}) within the 5 ms period at CPI {:.1} | {} ({:.1} %) | {} |",
        CPI[1],
        thousands(worst),
        worst_pct,
        pass(worst_pct <= 100.0)
    )?;
    let vo = m.task("vo_update").max;
    writeln!(
        d,
        "| VO update <= {} instructions | {} | {} |",
        thousands(GOAL_VO),
        thousands(vo),
        pass(vo <= GOAL_VO)
    )?;
    for (i, cpi) in CPI.iter().enumerate() {
        writeln!(
            d,
            "| total utilisation at {:.0} MHz <= {:.0} %, CPI {cpi:.1} | {:.1} % | {} |",
            CLOCK_HZ / 1e6,
            100.0 * DESIGN_MARGIN,
            100.0 * u[i],
            pass(u[i] <= DESIGN_MARGIN)
        )?;
    }
    writeln!(
        d,
        "| total utilisation at {:.0} MHz <= {:.0} %, each group at CPI {:.1} or its model CPI, whichever is higher | {:.1} % | {} |",
        CLOCK_HZ / 1e6,
        100.0 * DESIGN_MARGIN,
        CPI[1],
        100.0 * u_bind,
        pass(u_bind <= DESIGN_MARGIN)
    )?;
    let st = stack("flight").max(stack("bench"));
    writeln!(
        d,
        "| stack <= 32 KiB (flight software and navigation tasks) | {} B | {} |",
        thousands(st),
        pass(st <= GOAL_STACK)
    )?;
    writeln!(
        d,
        "| flight-phase stack <= 32 KiB (enforced) | {} B, margin {} B | {} |",
        thousands(stack("flight")),
        margin(MAX_FLIGHT_STACK, stack("flight")),
        pass(flight_stack_ok(m))
    )?;
    writeln!(
        d,
        "| stack <= 32 KiB including initialisation | {} B | {} |",
        thousands(stack("init")),
        pass(stack("init") <= GOAL_STACK)
    )?;
    writeln!(
        d,
        "| deepest stack phase leaves >= 4 KiB of the stack region (enforced) | {} B of {} B | {} |",
        thousands(stack_peak(m)),
        thousands(stack("region")),
        pass(stack_headroom_ok(m))
    )?;
    writeln!(
        d,
        "| static RAM apart from image buffers <= 256 KiB | {} B | {} |",
        thousands(ram),
        pass(ram <= GOAL_STATIC_RAM)
    )?;
    writeln!(
        d,
        "| host and rover CPU replay bit-identical | {} frames | {} |",
        m.tape.1,
        pass(end_ok)
    )?;
    writeln!(
        d,
        "| panic sites outside the image's number formatting = 0 (enforced) | {} | {} |",
        flight_panics,
        pass(flight_panics == 0)
    )?;
    Ok(d)
}

/// The model CPI of a utilisation group: the largest of the code groups ([`cpi::GROUPS`], by
/// index) its tasks run; 2.0 when a code group has neither a profile nor loops.
fn model_cpi(group: &str, loops: &[GroupCost]) -> f64 {
    // Indices into `cpi::GROUPS`: 0 VO, 1 rectification, 2 perception, 3 localization, 4 EKF,
    // 5 kinematics, 6 executive and navigation, 7 libm, 8 runtime (every group copies).
    let parts: &[usize] = match group {
        "RG1" => &[4, 6, 8],
        "RG2" => &[4, 5, 6, 7, 8],
        "RG2B" => &[4, 6, 8],
        "RG3" | "SEQ" => &[4, 6, 8],
        "RG4" => &[4, 6, 7, 8],
        "VO" => &[0, 1, 8],
        "HAZ" => &[0, 2, 6, 8],
        "LOC" => &[3, 8],
        _ => &[0, 1, 2, 3, 4, 5, 6, 7, 8],
    };
    parts
        .iter()
        .map(|&i| loops.get(i).and_then(GroupCost::cpi).unwrap_or(CPI[1]))
        .fold(0.0, f64::max)
}

/// The section "Cycles per instruction" (issue 18): the CPI of the image's code on the
/// Cortex-M7 pipeline model ([`cpi`]), weighted by the tape's block counts.
fn cpi_section(d: &mut String, mca: &str, loops: &[GroupCost]) -> Result<()> {
    writeln!(d, "## Cycles per instruction (Cortex-M7 pipeline model)\n")?;
    writeln!(
        d,
        "QEMU counts instructions; the time of an instruction on the Cortex-M7 depends on its \
         pipeline. The basis here is the Cortex-M7 scheduling model of LLVM \
         (`ARMScheduleM7.td`: in-order, dual issue, FP operations 3 cycles of latency, 64-bit FP \
         operations taking the FP pipe twice with 4-7 cycles of latency, FP64 \
         multiply-accumulate 11 and divide / square root about 30), run by \
         `llvm-mca -mcpu=cortex-m7` ({mca}) on the image's own code (`xtask/src/cpi.rs`, also \
         `cargo xtask cpi`), disassembled with `llvm-objdump --mcpu=cortex-m7`.\n\n\
         - **Executed blocks, weighted by their counts** (the model CPI): the second QEMU run \
         loads a plugin (`xtask/qemu/block_count.c`, QEMU's TCG plugin API) that counts the \
         executions of every translated block, straight-line code ending at a branch, over the \
         whole run (the replay of the tape and every bench). The blocks of each code group are \
         simulated hottest first, each for {it} passes back to back, until they cover \
         {cov:.1} % of the group's executed instructions (at most {max} blocks); the group's CPI \
         is the simulated cycles times the counts over the executed instructions. The plugin \
         adds host code only: both runs give the same instruction counts (checked).\n\
         - **Innermost loops, weighted by size** (the static figure it replaces): every \
         innermost loop of the group's functions, one iteration each, not weighted by how often \
         it runs.\n\n\
         In both, `IT` blocks are simulated unconditionally, branch targets replaced by a label \
         of the block, and calls by a branch (`llvm-mca` gives a call 100 cycles of latency; on \
         the core `bl` is a predicted branch): none of it changes the issue timing. Assumed: \
         code and data in zero-wait memory (ITCM/DTCM or cache hits) and predicted branches; a \
         block simulated back to back overlaps with its own next pass as a loop does, which is \
         optimistic for straight-line code that a mispredicted branch follows.\n",
        it = cpi::ITERATIONS,
        cov = 100.0 * cpi::COVERAGE,
        max = cpi::MAX_BLOCKS
    )?;
    writeln!(
        d,
        "| code group | executed instructions | blocks executed / simulated | share simulated | CPI, executed blocks | CPI, loops by size | loops (not read) | loop CPI, smallest - largest |"
    )?;
    writeln!(d, "|---|---:|---:|---:|---:|---:|---:|---|")?;
    for (g, c) in cpi::GROUPS.iter().zip(loops.iter()) {
        let (lo, hi) = c.range().unwrap_or((f64::NAN, f64::NAN));
        let p = c.profile.clone().unwrap_or_default();
        let f = |v: Option<f64>| v.map(|v| format!("{v:.2}")).unwrap_or_else(|| "-".into());
        writeln!(
            d,
            "| {} | {} | {} / {} | {:.1} % | **{}** | {} | {} ({}) | {:.2} - {:.2} |",
            g.label,
            thousands(p.executed),
            p.blocks,
            p.simulated_blocks,
            100.0 * p.coverage(),
            f(p.cpi()),
            f(c.loop_cpi()),
            c.loops.len(),
            c.skipped,
            lo,
            hi,
        )?;
    }
    writeln!(
        d,
        "\nThe double-precision groups (EKF, kinematics) come out near CPI 3: their blocks are \
         chains of dependent FP64 multiply-adds, loads of doubles and the divides and square \
         roots of the Cholesky factors and normalisations, which the single FP pipe issues one \
         at a time. The image groups (NCC, Forstner, rectification, the stereo of the hazard \
         mapper) are integer and load/store code that dual-issues, near CPI 1. Until issue 18's \
         second pass the disassembler was run without the Cortex-M7's FPU (every FP64 \
         instruction decoded as unknown, the rest of its function misaligned) and calls were \
         simulated at 100 cycles: the static figures of that pass (EKF 2.02, executive 2.12) \
         are replaced by these. Not modelled: data-cache misses on the stereo images, which \
         live in external RAM (`.extram`). The image kernels stream their rows (a 640-pixel row \
         is 20 lines of 32 bytes): the Forstner operator touches at most 4 image rows per \
         640-pixel work item of about 40,000 instructions (80 line fills), the rectification at \
         most 3 raw rows and one output row per output row of about 18,000 (80 line fills); at \
         an assumed 50 cycles per line fill from SDRAM (not a published figure of a flight \
         board) that adds at most about 0.1 and 0.25 cycles per instruction, less where the rows \
         of the previous item are still cached; the NCC scans reuse an 11-row window. With that \
         allowance the image groups stay well below CPI 2.0; the utilisation table applies the \
         higher of 2.0 and each group's model CPI.\n"
    )?;
    Ok(())
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
