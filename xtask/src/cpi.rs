//! Cycles per instruction of the flight kernels on the Cortex-M7 pipeline.
//!
//! QEMU counts instructions, not cycles. This module derives a CPI for the image's own code from
//! the Cortex-M7 pipeline description that LLVM carries (`ARMScheduleM7.td`: dual issue, two
//! ALU pipes, one load/store pipe pair, the FP pipeline latencies, 64-bit operations taking the
//! FP pipe twice), through `llvm-mca -mcpu=cortex-m7`:
//!
//! - the image is disassembled (`llvm-objdump -d`), split into functions by their symbols;
//! - every innermost loop of every function of a kernel group (a backward branch to an address
//!   in the same function whose span contains no other backward branch) is a micro-benchmark:
//!   its body, in address order, is handed to `llvm-mca`, which simulates 100 iterations
//!   back to back and reports the steady-state cycles per iteration;
//! - a group's static CPI is the sum of its loops' cycles per iteration over the sum of their
//!   instructions (each loop weighted by its size, one iteration each), with the smallest and
//!   largest loop CPI beside it;
//! - with the block counts of a run (QEMU plugin `xtask/qemu/block_count.c`: every translated
//!   block, straight-line code up to a branch, with its execution count), the group's model CPI
//!   is its executed blocks' simulated cycles weighted by their counts, the hottest blocks
//!   simulated until they cover [`COVERAGE`] of the group's executed instructions.
//!
//! What the model assumes: code and data in zero-wait memory (ITCM/DTCM or cache hits), no
//! branch mispredictions (the loop branch is predicted), calls inside a loop as one instruction
//! (the callee's own loops are measured where the callee is). Data-cache misses on the stereo
//! images in external RAM are not modelled: they add to the figure (see `docs/results/timing.md`).

use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// Simulated iterations of each loop body.
pub const ITERATIONS: u32 = 100;
/// Loop bodies longer than this are left out (a branch back over a whole function body is a
/// retry path, not a kernel loop).
const MAX_LOOP_INSNS: usize = 400;

/// A group of functions by demangled name prefix, with the tasks it carries.
pub struct Group {
    /// Row label.
    pub label: &'static str,
    /// Demangled function name prefixes of the group.
    pub prefixes: &'static [&'static str],
}

/// The kernel groups of the flight software measured.
pub const GROUPS: &[Group] = &[
    Group {
        label: "visual odometry and stereo (`fsw::vo`: NCC scans, Forstner, tracking, refinement, motion)",
        prefixes: &["fsw::vo::"],
    },
    Group {
        label: "rectification (`fsw::rectify`)",
        prefixes: &["fsw::rectify::"],
    },
    Group {
        label: "hazard mapper (`fsw::perception`)",
        prefixes: &["fsw::perception::"],
    },
    Group {
        label: "terrain-map localization (`fsw::localization`)",
        prefixes: &["fsw::localization::"],
    },
    Group {
        label: "EKF (`fsw::estimation`, f64)",
        prefixes: &["fsw::estimation::"],
    },
    Group {
        label: "kinematics (`fsw::kinematics`, f64)",
        prefixes: &["fsw::kinematics::"],
    },
    Group {
        label: "executive, navigator, guidance, planning, sequencer",
        prefixes: &[
            "fsw::flight::",
            "fsw::exec::",
            "fsw::guidance::",
            "fsw::planning::",
            "fsw::sequencer::",
        ],
    },
    Group {
        label: "libm (f64 sin, cos, atan2, sqrt)",
        prefixes: &["libm::"],
    },
    Group {
        label: "runtime (`memcpy`, `memset`, conversions, division: compiler builtins)",
        prefixes: &["compiler_builtins::", "__aeabi", "__", "memcpy", "memset", "memmove"],
    },
];

/// One innermost loop and its simulated cost.
#[derive(Debug, Clone)]
pub struct LoopCost {
    /// The function the loop is in (demangled).
    pub function: String,
    /// Instructions of one iteration.
    pub insns: usize,
    /// Steady-state cycles of one iteration.
    pub cycles: f64,
}

/// The measured loops of one group.
#[derive(Debug, Clone, Default)]
pub struct GroupCost {
    /// Functions of the group in the image.
    pub functions: usize,
    /// Loops simulated.
    pub loops: Vec<LoopCost>,
    /// Loops `llvm-mca` could not read (an instruction its assembler refuses).
    pub skipped: usize,
    /// The group's executed code on the tape, when QEMU's block counts are given.
    pub profile: Option<Profile>,
}

/// The executed code of one group: QEMU's translated blocks with their execution counts
/// (`xtask/qemu/block_count.c`), the hottest simulated by `llvm-mca`.
#[derive(Debug, Clone, Default)]
pub struct Profile {
    /// Instructions executed in the group's functions.
    pub executed: u64,
    /// Distinct blocks executed.
    pub blocks: usize,
    /// Blocks simulated (the hottest, until [`COVERAGE`] of `executed` or [`MAX_BLOCKS`]).
    pub simulated_blocks: usize,
    /// Executed instructions in the simulated blocks.
    pub simulated: u64,
    /// Their modelled cycles: each block's steady-state cycles per pass times its count.
    pub cycles: f64,
}

impl Profile {
    /// Cycles per executed instruction over the simulated blocks.
    pub fn cpi(&self) -> Option<f64> {
        (self.simulated > 0).then(|| self.cycles / self.simulated as f64)
    }

    /// Share of the group's executed instructions that was simulated.
    pub fn coverage(&self) -> f64 {
        if self.executed == 0 {
            0.0
        } else {
            self.simulated as f64 / self.executed as f64
        }
    }
}

/// Blocks are simulated, hottest first, until they cover this share of a group's executed
/// instructions...
pub const COVERAGE: f64 = 0.995;
/// ... or this many blocks per group.
pub const MAX_BLOCKS: usize = 1500;

impl GroupCost {
    /// The group's CPI: weighted by execution counts when a profile is given, else by loop
    /// size ([`GroupCost::loop_cpi`]).
    pub fn cpi(&self) -> Option<f64> {
        self.profile
            .as_ref()
            .and_then(Profile::cpi)
            .or_else(|| self.loop_cpi())
    }

    /// Size-weighted CPI over the loops, `None` without loops.
    pub fn loop_cpi(&self) -> Option<f64> {
        let insns: usize = self.loops.iter().map(|l| l.insns).sum();
        let cycles: f64 = self.loops.iter().map(|l| l.cycles).sum();
        (insns > 0).then(|| cycles / insns as f64)
    }

    /// Smallest and largest loop CPI.
    pub fn range(&self) -> Option<(f64, f64)> {
        let cpis = self
            .loops
            .iter()
            .filter(|l| l.insns > 0)
            .map(|l| l.cycles / l.insns as f64);
        cpis.fold(None, |acc, c| match acc {
            None => Some((c, c)),
            Some((lo, hi)) => Some((f64::min(lo, c), f64::max(hi, c))),
        })
    }

    /// Instructions in all loops (one iteration each).
    pub fn insns(&self) -> usize {
        self.loops.iter().map(|l| l.insns).sum()
    }
}

/// One disassembled instruction.
struct Insn {
    addr: u64,
    text: String,
    /// Target of a direct branch (not a call), if any.
    branch: Option<u64>,
}

/// A function of the disassembly.
struct Function {
    name: String,
    insns: Vec<Insn>,
}

/// The QEMU plugin that counts block executions, its source in the repository.
const PLUGIN_SRC: &str = "xtask/qemu/block_count.c";
/// Where `cargo xtask timing` builds the plugin.
pub const PLUGIN: &str = "target/timing/libblock_count.so";
/// Where the timing run's block counts are written (read by `cargo xtask cpi` when present).
pub const BLOCKS: &str = "target/timing/blocks.txt";

/// Build the block-count plugin with the host C compiler (`cc`, present wherever Rust links).
pub fn build_plugin() -> Result<std::path::PathBuf> {
    let out = std::path::PathBuf::from(PLUGIN);
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let status = Command::new("cc")
        .args(["-O2", "-shared", "-fPIC", "-Wall", "-Werror", "-o"])
        .arg(&out)
        .arg(PLUGIN_SRC)
        .status()
        .context("cannot run the C compiler `cc` for the QEMU plugin")?;
    if !status.success() {
        bail!("building the QEMU plugin {PLUGIN_SRC} failed");
    }
    Ok(out)
}

/// The version line of `llvm-mca`, or an error when it is missing.
pub fn tool_version() -> Result<String> {
    let out = Command::new("llvm-mca")
        .arg("--version")
        .output()
        .context("llvm-mca not found (Debian package llvm-14)")?;
    let text = String::from_utf8_lossy(&out.stdout);
    Ok(text
        .lines()
        .find(|l| l.contains("LLVM version"))
        .map(|l| l.trim().to_string())
        .unwrap_or_else(|| "llvm-mca".into()))
}

/// Disassemble `image` and simulate the innermost loops of every group; with `blocks` (the
/// block counts of a run of the image, `xtask/qemu/block_count.c`), also the executed blocks
/// weighted by their counts.
pub fn analyse(image: &Path, blocks: Option<&Path>) -> Result<Vec<GroupCost>> {
    let out = Command::new("llvm-objdump")
        .args(["-d", "-C", "--no-show-raw-insn", "--mcpu=cortex-m7"])
        .arg(image)
        .output()
        .context("llvm-objdump not found")?;
    if !out.status.success() {
        bail!("llvm-objdump failed on {}", image.display());
    }
    let functions = parse_disassembly(&String::from_utf8_lossy(&out.stdout));
    let dir = std::env::temp_dir().join(format!("xtask-cpi-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let mut result = Vec::new();
    for group in GROUPS {
        let mut cost = GroupCost::default();
        for f in functions
            .iter()
            .filter(|f| group.prefixes.iter().any(|p| f.name.starts_with(p)))
        {
            cost.functions += 1;
            for body in innermost_loops(f) {
                match simulate(&dir, &body)? {
                    Some(mut l) => {
                        l.function = f.name.clone();
                        cost.loops.push(l);
                    }
                    None => cost.skipped += 1,
                }
            }
        }
        result.push(cost);
    }
    if let Some(path) = blocks {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the block counts {}", path.display()))?;
        let counts = parse_blocks(&text)?;
        for (group, cost) in GROUPS.iter().zip(result.iter_mut()) {
            cost.profile = Some(profile(&dir, &functions, group, &counts)?);
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(result)
}

/// Block counts `<address hex> <instructions> <executions>`, summed over the translations of
/// each (address, length).
fn parse_blocks(text: &str) -> Result<BTreeMap<(u64, usize), u64>> {
    let mut counts = BTreeMap::new();
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let mut f = line.split_whitespace();
        let (Some(a), Some(n), Some(c)) = (f.next(), f.next(), f.next()) else {
            bail!("bad block-count line {line:?}");
        };
        let key = (u64::from_str_radix(a, 16)?, n.parse::<usize>()?);
        *counts.entry(key).or_insert(0) += c.parse::<u64>()?;
    }
    Ok(counts)
}

/// The executed blocks of `group`'s functions, the hottest simulated.
fn profile(
    dir: &Path,
    functions: &[Function],
    group: &Group,
    counts: &BTreeMap<(u64, usize), u64>,
) -> Result<Profile> {
    // (executed instructions, count, body) of every block that starts at an instruction of
    // the group's functions.
    let mut blocks: Vec<(u64, u64, Vec<String>)> = Vec::new();
    for f in functions
        .iter()
        .filter(|f| group.prefixes.iter().any(|p| f.name.starts_with(p)))
    {
        let (Some(first), Some(last)) = (f.insns.first(), f.insns.last()) else {
            continue;
        };
        for (&(addr, n), &count) in counts.range((first.addr, 0)..=(last.addr, usize::MAX)) {
            let Some(start) = f.insns.iter().position(|i| i.addr == addr) else {
                continue;
            };
            let body: Vec<String> = f
                .insns
                .iter()
                .skip(start)
                .take(n)
                .map(|i| i.text.clone())
                .collect();
            blocks.push((n as u64 * count, count, body));
        }
    }
    blocks.sort_by_key(|b| std::cmp::Reverse(b.0));
    let executed: u64 = blocks.iter().map(|b| b.0).sum();
    let mut p = Profile {
        executed,
        blocks: blocks.len(),
        ..Profile::default()
    };
    let mut chosen = 0u64;
    let take = blocks
        .iter()
        .take_while(|b| {
            let more = (chosen as f64) < COVERAGE * executed as f64;
            chosen += b.0;
            more
        })
        .take(MAX_BLOCKS)
        .count();
    let bodies: Vec<&[String]> = blocks.iter().take(take).map(|b| b.2.as_slice()).collect();
    let costs = simulate_all(dir, &bodies)?;
    for (b, cost) in blocks.iter().zip(costs) {
        if let Some((_, cycles)) = cost {
            p.simulated_blocks += 1;
            p.simulated += b.0;
            p.cycles += cycles * b.1 as f64;
        }
    }
    Ok(p)
}

fn parse_disassembly(text: &str) -> Vec<Function> {
    let mut functions: Vec<Function> = Vec::new();
    for line in text.lines() {
        if let Some(name) = line
            .split_once(" <")
            .filter(|(a, _)| !a.is_empty() && a.chars().all(|c| c.is_ascii_hexdigit()))
            .and_then(|(_, rest)| rest.strip_suffix(">:"))
        {
            // `$t` and `$d` are mapping symbols (code and data inside a function, after a
            // literal pool), not functions.
            if name.starts_with('$') {
                continue;
            }
            functions.push(Function {
                name: name.to_string(),
                insns: Vec::new(),
            });
            continue;
        }
        let Some((addr, rest)) = line.trim_start().split_once(':') else {
            continue;
        };
        let Ok(addr) = u64::from_str_radix(addr.trim(), 16) else {
            continue;
        };
        // Drop the comment and the symbolic target; data in literal pools is not code.
        let code = rest.split('@').next().unwrap_or("").trim();
        let code = match code.find(" <") {
            Some(i) => code[..i].trim(),
            None => code,
        };
        // Literal-pool data keeps its raw bytes even with `--no-show-raw-insn`
        // (`00 00 f0 7f  .word 0x7ff00000`).
        let data = code
            .split_whitespace()
            .any(|t| matches!(t, ".word" | ".short" | ".byte" | ".long"));
        if code.is_empty() || data || code.starts_with('.') || code.starts_with("<unknown>") {
            continue;
        }
        let mnemonic = code.split_whitespace().next().unwrap_or("");
        let branch = is_branch(mnemonic)
            .then(|| code.split_whitespace().last())
            .flatten()
            .and_then(|t| t.strip_prefix("0x"))
            .and_then(|t| u64::from_str_radix(t, 16).ok());
        if let Some(f) = functions.last_mut() {
            f.insns.push(Insn {
                addr,
                text: code.split_whitespace().collect::<Vec<_>>().join(" "),
                branch,
            });
        }
    }
    functions
}

/// A direct branch that is not a call: `b`, `b<cond>`, with an optional `.w`/`.n`.
fn is_branch(mnemonic: &str) -> bool {
    let m = mnemonic.trim_end_matches(".w").trim_end_matches(".n");
    const CONDS: [&str; 15] = [
        "", "eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt",
    ];
    const MORE: [&str; 3] = ["gt", "le", "al"];
    m.strip_prefix('b')
        .is_some_and(|c| CONDS.contains(&c) || MORE.contains(&c))
}

/// The bodies of the innermost loops of `f`, as instruction texts in address order.
fn innermost_loops(f: &Function) -> Vec<Vec<String>> {
    let (Some(first), Some(last)) = (f.insns.first(), f.insns.last()) else {
        return Vec::new();
    };
    let (lo, hi) = (first.addr, last.addr);
    // (target, branch address) of every backward branch inside the function.
    let loops: Vec<(u64, u64)> = f
        .insns
        .iter()
        .filter_map(|i| i.branch.map(|t| (t, i.addr)))
        .filter(|&(t, at)| t <= at && t >= lo && t <= hi)
        .collect();
    loops
        .iter()
        .filter(|&&(t, at)| {
            !loops
                .iter()
                .any(|&(t2, at2)| (t2, at2) != (t, at) && t2 >= t && at2 <= at)
        })
        .map(|&(t, at)| {
            f.insns
                .iter()
                .filter(|i| i.addr >= t && i.addr <= at)
                .map(|i| i.text.clone())
                .collect::<Vec<_>>()
        })
        .filter(|body| !body.is_empty() && body.len() <= MAX_LOOP_INSNS)
        .collect()
}

/// The condition codes of the Thumb-2 instruction set.
const CONDS: [&str; 16] = [
    "eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt", "le",
];

/// A code sequence as `llvm-mca` reads it, labelled `begin` at its start and `end` after it.
/// Its assembler refuses, and its model mistimes, a few things the disassembly has; none of the
/// replacements changes the issue timing of the instructions:
/// - absolute branch targets: every `b`/`b<cond>` goes to `begin`, in the 32-bit encoding that
///   reaches it, and `cbz`/`cbnz` to `end` (they only branch forward);
/// - calls: `llvm-mca` gives a call 100 cycles of latency ("call instructions are not correctly
///   modeled"); on the core `bl` is a predicted branch, so `bl` is simulated as `b.w` and
///   `blx rN` as `bx rN` (the callee's own code is measured where it is);
/// - `IT` blocks (`llvm-mca` does not model `IT`): dropped, and the instructions they predicate
///   are simulated unconditionally, as the core issues them whatever the condition.
fn mca_body(body: &[String], begin: &str, end: &str) -> Vec<String> {
    let mut out = Vec::with_capacity(body.len());
    let mut predicated = 0usize;
    for line in body {
        let (mnemonic, operands) = line.split_once(' ').unwrap_or((line.as_str(), ""));
        if let Some(mask) = mnemonic.strip_prefix("it").filter(|m| m.len() <= 3) {
            if mask.chars().all(|c| c == 't' || c == 'e') {
                predicated = 1 + mask.len();
                continue;
            }
        }
        let mut mnemonic = mnemonic.to_string();
        if predicated > 0 {
            predicated -= 1;
            // Strip the condition: `moveq` -> `mov`, `addne.w` -> `add.w`, `vmovgt.f64` ->
            // `vmov.f64`.
            let (base, suffix) = match mnemonic.find('.') {
                Some(i) => (mnemonic[..i].to_string(), mnemonic[i..].to_string()),
                None => (mnemonic.clone(), String::new()),
            };
            if let Some(stripped) = CONDS.iter().find_map(|c| base.strip_suffix(c)) {
                if !stripped.is_empty() {
                    mnemonic = format!("{stripped}{suffix}");
                }
            }
        }
        let base = mnemonic.trim_end_matches(".w").trim_end_matches(".n");
        let operands = operands.trim();
        if is_branch(&mnemonic) && operands.starts_with("0x") {
            out.push(format!("{base}.w {begin}"));
            continue;
        }
        if base == "bl" {
            out.push(format!("b.w {end}"));
            continue;
        }
        if base == "blx" {
            out.push(format!("bx {operands}"));
            continue;
        }
        if base == "cbz" || base == "cbnz" {
            if let Some((reg, _)) = operands.split_once(',') {
                out.push(format!("{base} {reg}, {end}"));
                continue;
            }
        }
        out.push(format!("{mnemonic} {operands}").trim().to_string());
    }
    out
}

/// The cost `llvm-mca` gives one code region: instructions and cycles per iteration.
fn region_cost(report: &str) -> Option<(f64, f64)> {
    let field = |name: &str| -> Option<f64> {
        report
            .lines()
            .find_map(|l| l.trim().strip_prefix(name))
            .and_then(|v| v.trim().parse::<f64>().ok())
    };
    let per_iter = f64::from(ITERATIONS);
    Some((
        field("Instructions:")? / per_iter,
        field("Total Cycles:")? / per_iter,
    ))
}

/// `llvm-mca` on code regions: the steady-state instructions and cycles per iteration of each
/// (`ITERATIONS` back to back), `None` for the whole set when it does not assemble.
fn simulate_regions(dir: &Path, bodies: &[&[String]]) -> Result<Option<Vec<(f64, f64)>>> {
    let file = dir.join("regions.s");
    let mut text = String::from(".syntax unified\n.thumb\n");
    for (i, body) in bodies.iter().enumerate() {
        let (begin, end) = (format!(".Lb{i}"), format!(".Le{i}"));
        text.push_str(&format!("# LLVM-MCA-BEGIN r{i}\n{begin}:\n"));
        for l in mca_body(body, &begin, &end) {
            text.push_str(&l);
            text.push('\n');
        }
        text.push_str(&format!("{end}:\n# LLVM-MCA-END\n"));
    }
    std::fs::write(&file, text)?;
    let out = Command::new("llvm-mca")
        .args([
            "-mtriple=thumbv7em-none-eabihf",
            "-mcpu=cortex-m7",
            &format!("-iterations={ITERATIONS}"),
            "-summary-view",
            "-instruction-info=0",
            "-resource-pressure=0",
        ])
        .arg(&file)
        .output()
        .context("llvm-mca not found")?;
    if !out.status.success() {
        return Ok(None);
    }
    let report = String::from_utf8_lossy(&out.stdout);
    // With one region `llvm-mca` prints no region header.
    let parts: Vec<&str> = if bodies.len() == 1 {
        vec![&report]
    } else {
        report.split("Code Region - ").skip(1).collect()
    };
    if parts.len() != bodies.len() {
        return Ok(None);
    }
    Ok(parts.iter().map(|p| region_cost(p)).collect())
}

/// Costs of many regions: in batches, a batch that does not assemble region by region (a
/// region that does not assemble alone gets `None`).
fn simulate_all(dir: &Path, bodies: &[&[String]]) -> Result<Vec<Option<(f64, f64)>>> {
    const BATCH: usize = 200;
    let mut out = Vec::with_capacity(bodies.len());
    for batch in bodies.chunks(BATCH) {
        match simulate_regions(dir, batch)? {
            Some(costs) => out.extend(costs.into_iter().map(Some)),
            None => {
                for body in batch {
                    out.push(simulate_regions(dir, &[body])?.and_then(|c| c.first().copied()));
                }
            }
        }
    }
    Ok(out)
}

/// `llvm-mca` on one loop body: steady-state cycles per iteration, `None` when the body does
/// not assemble.
fn simulate(dir: &Path, body: &[String]) -> Result<Option<LoopCost>> {
    let cost = simulate_regions(dir, &[body])?.and_then(|c| c.first().copied());
    Ok(cost.map(|(insns, cycles)| LoopCost {
        function: String::new(),
        insns: insns.round() as usize,
        cycles,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mapping_symbols_stay_in_their_function_and_block_counts_sum() {
        let text = "00002000 <fsw::estimation::f::h1>:\n\
                        2000:      \tvldr\td0, [r0]\n\
                        2004:      \tb\t0x2010 <$t+0x4> @ imm = #8\n\
                    \n\
                    00002008 <$d>:\n\
                        2008:\t00 00 00 00\t.word\t0x00000000\n\
                    \n\
                    0000200c <$t>:\n\
                        200c:      \tvmla.f64\td0, d1, d2\n\
                        2010:      \tbx\tlr\n";
        let f = parse_disassembly(text);
        assert_eq!(f.len(), 1, "`$d` and `$t` are not functions");
        assert_eq!(f[0].insns.len(), 4);
        let counts = parse_blocks("2000 2 5\n200c 2 7\n2000 2 3\n").unwrap();
        assert_eq!(
            counts.get(&(0x2000, 2)),
            Some(&8),
            "retranslations are summed"
        );
        assert_eq!(counts.get(&(0x200c, 2)), Some(&7));
        assert!(parse_blocks("2000 x 1\n").is_err());
    }

    #[test]
    fn finds_innermost_loops_and_branches() {
        let text = "00001000 <fsw::vo::k::h1>:\n\
                        1000:      \tmov\tr0, r1\n\
                        1002:      \tadds\tr0, #1\n\
                        1004:      \tldr\tr2, [r1]\n\
                        1006:      \tbne\t0x1002 <fsw::vo::k::h1+0x2> @ imm = #-8\n\
                        1008:      \tsubs\tr3, #1\n\
                        100a:      \tbne.w\t0x1000 <fsw::vo::k::h1> @ imm = #-14\n\
                        100e:      \tbl\t0x1000 <fsw::vo::k::h1> @ imm = #-18\n\
                        1012:      \t.word\t0x12345678\n";
        let f = parse_disassembly(text);
        assert_eq!(f.len(), 1);
        assert_eq!(f[0].name, "fsw::vo::k::h1");
        assert_eq!(f[0].insns.len(), 7);
        assert_eq!(f[0].insns[3].branch, Some(0x1002));
        assert_eq!(f[0].insns[6].branch, None, "a call is not a loop branch");
        let loops = innermost_loops(&f[0]);
        assert_eq!(loops.len(), 1, "the outer loop contains the inner one");
        assert_eq!(loops[0], vec!["adds r0, #1", "ldr r2, [r1]", "bne 0x1002"]);
        assert!(is_branch("bhs.w") && is_branch("b") && !is_branch("bl") && !is_branch("bic"));
        let body: Vec<String> = [
            "ite eq",
            "moveq r4, r8",
            "addne.w r0, r1, #1",
            "vmovgt.f64 d0, d1",
            "bne 0x1002",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        assert_eq!(
            mca_body(&body, ".Lb", ".Le"),
            vec![
                "mov r4, r8",
                "add.w r0, r1, #1",
                "vmovgt.f64 d0, d1",
                "bne.w .Lb"
            ]
        );
        let calls: Vec<String> = ["bl 0x2000", "blx r3", "cbnz r2, 0x1010"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(
            mca_body(&calls, ".Lb", ".Le"),
            vec!["b.w .Le", "bx r3", "cbnz r2, .Le"]
        );
    }
}
