//! Cycles per instruction of the flight kernels on the Cortex-M7 pipeline (issue 18).
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
//! - a group's CPI is the sum of its loops' cycles per iteration over the sum of their
//!   instructions (each loop weighted by its size, one iteration each: the tape's execution
//!   counts are not known per loop), with the smallest and largest loop CPI beside it.
//!
//! What the model assumes: code and data in zero-wait memory (ITCM/DTCM or cache hits), no
//! branch mispredictions (the loop branch is predicted), calls inside a loop as one instruction
//! (the callee's own loops are measured where the callee is). Data-cache misses on the stereo
//! images in external RAM are not modelled: they add to the figure (see `docs/timing.md`).

use anyhow::{bail, Context, Result};
use std::path::Path;
use std::process::Command;

/// Simulated iterations of each loop body.
const ITERATIONS: u32 = 100;
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
}

impl GroupCost {
    /// Size-weighted CPI over the loops, `None` without loops.
    pub fn cpi(&self) -> Option<f64> {
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

/// Disassemble `image` and simulate the innermost loops of every group.
pub fn analyse(image: &Path) -> Result<Vec<GroupCost>> {
    let out = Command::new("llvm-objdump")
        .args(["-d", "-C", "--no-show-raw-insn"])
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
    let _ = std::fs::remove_dir_all(&dir);
    Ok(result)
}

fn parse_disassembly(text: &str) -> Vec<Function> {
    let mut functions: Vec<Function> = Vec::new();
    for line in text.lines() {
        if let Some(name) = line
            .split_once(" <")
            .filter(|(a, _)| !a.is_empty() && a.chars().all(|c| c.is_ascii_hexdigit()))
            .and_then(|(_, rest)| rest.strip_suffix(">:"))
        {
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
        if code.is_empty() || code.starts_with('.') || code.starts_with("<unknown>") {
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

/// A loop body as `llvm-mca` reads it. Its assembler refuses three things the disassembly has,
/// none of which changes the issue timing of the instructions: absolute branch targets (every
/// branch goes to the body's own label, in the 32-bit encoding that reaches it), and `IT`
/// blocks (`llvm-mca` does not model `IT`: it is dropped and the instructions it predicates
/// are simulated unconditionally, as the core issues them whatever the condition).
fn mca_body(body: &[String]) -> Vec<String> {
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
        if is_branch(&mnemonic) && operands.trim().starts_with("0x") {
            let base = mnemonic.trim_end_matches(".w").trim_end_matches(".n");
            out.push(format!("{base}.w .Lloop"));
            continue;
        }
        out.push(format!("{mnemonic} {operands}").trim().to_string());
    }
    out
}

/// `llvm-mca` on one loop body: steady-state cycles per iteration, `None` when the body does
/// not assemble.
fn simulate(dir: &Path, body: &[String]) -> Result<Option<LoopCost>> {
    let file = dir.join("loop.s");
    let mut text = String::from(".syntax unified\n.thumb\n.Lloop:\n");
    for l in mca_body(body) {
        text.push_str(&l);
        text.push('\n');
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
    let field = |name: &str| -> Option<f64> {
        report
            .lines()
            .find_map(|l| l.trim().strip_prefix(name))
            .and_then(|v| v.trim().parse::<f64>().ok())
    };
    let (Some(insns), Some(cycles)) = (field("Instructions:"), field("Total Cycles:")) else {
        return Ok(None);
    };
    let per_iter = f64::from(ITERATIONS);
    Ok(Some(LoopCost {
        function: String::new(),
        insns: (insns / per_iter).round() as usize,
        cycles: cycles / per_iter,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

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
            mca_body(&body),
            vec![
                "mov r4, r8",
                "add.w r0, r1, #1",
                "vmovgt.f64 d0, d1",
                "bne.w .Lloop"
            ]
        );
    }
}
