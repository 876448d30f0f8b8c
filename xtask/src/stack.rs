//! Static worst-case stack analysis of the rover-CPU image (the flight stack budget of 32 KiB,
//! `docs/results/timing.md`), next to the painted
//! high-water marks of `cargo xtask timing`.
//!
//! The image's `.text` is decoded here (Thumb-2, no external disassembler; the `$d` mapping
//! symbols mark the literal pools, which are skipped):
//!
//! - **frame of a function**: the sum of every stack-pointer decrement in its body: `push`
//!   (16-bit and `push.w`/`stmdb sp!`, 4 B per register), `str rN, [sp, #-4]!`, `sub sp, #imm`
//!   (16-bit, `sub.w` with a modified immediate, `subw`), `sub.w sp, sp, rN` after a
//!   `movw`/`movt` of rN, and `vpush`/`vstmdb sp!` (4 B per single-precision register). Summing
//!   every decrement (not only the entry block's) over-counts a function whose prologue was
//!   duplicated, never under-counts one whose prologue was shrink-wrapped;
//! - **call graph**: `bl` is a call (the callee runs below the caller's whole frame); a `b`,
//!   `b.w` or `b<cond>(.w)` whose target lies outside the function is a tail call (the callee
//!   runs at the caller's entry stack pointer, after its epilogue);
//! - **indirect transfers** (`blx rN`, `bx rN` other than `bx lr`, `mov pc, rN`, `ldr pc, [rN]`
//!   other than a return through `[sp]`) cannot be followed: they are counted per function and
//!   reported along every path, never silently dropped;
//! - **cycles** (recursion through the call graph) are found as strongly connected components;
//!   the depth search cuts the edge that closes a cycle (one trip around it is counted) and the
//!   report lists every cycle.
//!
//! Worst case of a function `f`: `max(frame(f) + max over calls c of depth(c), max over tail
//! calls t of depth(t))`. Exception entry (the hardware-stacked 32 B, 104 B with the FPU
//! context) comes on top and is not part of the figure.

use crate::elf::{branch16, branch32, demangle};
use anyhow::{Context, Result};
use object::{Object, ObjectSection, ObjectSymbol, SymbolKind};
use std::collections::BTreeMap;
use std::path::Path;

/// One function of the image as the analysis sees it.
#[derive(Debug, Clone, Default)]
pub struct Func {
    /// Demangled name (legacy hashes dropped: instances of a generic share a name).
    pub name: String,
    /// First and one-past-last address (Thumb bit cleared).
    pub start: u64,
    pub end: u64,
    /// Bytes of stack the function's own instructions reserve.
    pub frame: u64,
    /// Functions it calls with `bl` (indices into [`StackReport::funcs`]).
    pub calls: Vec<usize>,
    /// Functions it branches to as a tail call.
    pub tails: Vec<usize>,
    /// Indirect calls and jumps out of the function (`blx rN`, `bx rN`, ...).
    pub indirect: usize,
    /// Direct branches to an address inside no known function.
    pub unresolved: usize,
}

/// A call-graph edge: callee index and whether it is a tail call.
type Edge = (usize, bool);

/// One step of a deepest path: the function and the stack in use when it runs.
#[derive(Debug, Clone)]
pub struct Step {
    pub func: usize,
    /// Stack in use below the root's entry stack pointer when the function is entered, bytes.
    pub depth_at_entry: u64,
    /// How it was reached from the previous step.
    pub tail: bool,
}

/// The deepest path from one root.
#[derive(Debug, Clone)]
pub struct DeepPath {
    /// Worst-case stack of the root, bytes (exception entry not included).
    pub total: u64,
    pub steps: Vec<Step>,
    /// Indirect calls and jumps in functions reachable from the root.
    pub reachable_indirect: usize,
    /// Functions reachable from the root.
    pub reachable: usize,
}

/// The analysis of one image.
#[derive(Debug, Clone, Default)]
pub struct StackReport {
    pub funcs: Vec<Func>,
    /// Cycles of the call graph (strongly connected components of more than one function, or
    /// a function that calls itself), as function indices.
    pub cycles: Vec<Vec<usize>>,
    /// Call-graph edges cut to make the depth search finite (one per closing edge found).
    pub cut_edges: usize,
    /// The ELF entry point (cortex-m-rt's `Reset`).
    pub entry: Option<u64>,
}

impl StackReport {
    /// Index of the function whose demangled name satisfies `pred` (the largest frame first
    /// when several do).
    pub fn find(&self, pred: impl Fn(&str) -> bool) -> Option<usize> {
        self.funcs
            .iter()
            .enumerate()
            .filter(|(_, f)| pred(&f.name))
            .max_by_key(|(_, f)| f.frame)
            .map(|(i, _)| i)
    }

    /// The function that contains `addr`.
    pub fn at(&self, addr: u64) -> Option<usize> {
        let addr = addr & !1;
        let i = self
            .funcs
            .partition_point(|f| f.start <= addr)
            .checked_sub(1)?;
        (addr < self.funcs.get(i)?.end).then_some(i)
    }

    /// Total indirect transfers in the image.
    pub fn indirect_total(&self) -> usize {
        self.funcs.iter().map(|f| f.indirect).sum()
    }

    /// Worst-case depth of every function (cycle-closing edges cut), and for each the callee
    /// that realises it (`(index, tail)`).
    fn depths(&self) -> (Vec<u64>, Vec<Option<Edge>>, usize) {
        let n = self.funcs.len();
        let mut depth = vec![0u64; n];
        let mut best: Vec<Option<Edge>> = vec![None; n];
        // 0: unvisited, 1: on the search stack, 2: done.
        let mut state = vec![0u8; n];
        let mut cut = 0usize;
        for root in 0..n {
            if state[root] != 0 {
                continue;
            }
            // Iterative post-order search (the graph is deep: no recursion here either).
            let mut stack: Vec<(usize, usize)> = vec![(root, 0)];
            state[root] = 1;
            while let Some(&mut (f, ref mut next)) = stack.last_mut() {
                let edges = self.edges(f);
                if let Some(&(c, _)) = edges.get(*next) {
                    *next += 1;
                    match state[c] {
                        0 => {
                            state[c] = 1;
                            stack.push((c, 0));
                        }
                        1 => cut += 1,
                        _ => {}
                    }
                    continue;
                }
                let frame = self.funcs[f].frame;
                let mut d = frame;
                let mut b = None;
                for (c, tail) in edges {
                    if state[c] != 2 {
                        continue; // cycle-closing edge
                    }
                    let via = if tail { depth[c] } else { frame + depth[c] };
                    if via > d {
                        d = via;
                        b = Some((c, tail));
                    }
                }
                depth[f] = d;
                best[f] = b;
                state[f] = 2;
                stack.pop();
            }
        }
        (depth, best, cut)
    }

    /// Outgoing edges of `f`: `(callee, is_tail_call)`.
    fn edges(&self, f: usize) -> Vec<(usize, bool)> {
        let func = &self.funcs[f];
        func.calls
            .iter()
            .map(|&c| (c, false))
            .chain(func.tails.iter().map(|&t| (t, true)))
            .collect()
    }

    /// Functions reachable from `root` (itself included).
    fn reachable(&self, root: usize) -> Vec<usize> {
        let mut seen = vec![false; self.funcs.len()];
        let mut todo = vec![root];
        let mut out = Vec::new();
        while let Some(f) = todo.pop() {
            if std::mem::replace(&mut seen[f], true) {
                continue;
            }
            out.push(f);
            todo.extend(self.edges(f).into_iter().map(|(c, _)| c));
        }
        out
    }

    /// The deepest path from `root`.
    pub fn deepest(&self, root: usize) -> DeepPath {
        let (depth, best, _) = self.depths();
        let mut steps = Vec::new();
        let mut at = 0u64;
        let mut f = root;
        let mut tail = false;
        for _ in 0..self.funcs.len() {
            steps.push(Step {
                func: f,
                depth_at_entry: at,
                tail,
            });
            let Some((c, t)) = best[f] else { break };
            if !t {
                at += self.funcs[f].frame;
            }
            f = c;
            tail = t;
        }
        let reach = self.reachable(root);
        DeepPath {
            total: depth[root],
            steps,
            reachable_indirect: reach.iter().map(|&i| self.funcs[i].indirect).sum(),
            reachable: reach.len(),
        }
    }

    /// The deepest path from `root` that passes through `via`, if `via` is reachable.
    pub fn deepest_through(&self, root: usize, via: usize) -> Option<DeepPath> {
        let (depth, _, _) = self.depths();
        // Longest prefix root -> via over the acyclic graph (edges into the search stack cut):
        // best[f] = stack in use when `via` is entered on the deepest path from f.
        let n = self.funcs.len();
        let mut reach: Vec<Option<(u64, Option<Edge>)>> = vec![None; n];
        let mut state = vec![0u8; n];
        let mut stack: Vec<(usize, usize)> = vec![(root, 0)];
        state[root] = 1;
        while let Some(&mut (f, ref mut next)) = stack.last_mut() {
            let edges = self.edges(f);
            if f != via {
                if let Some(&(c, _)) = edges.get(*next) {
                    *next += 1;
                    if state[c] == 0 {
                        state[c] = 1;
                        stack.push((c, 0));
                    }
                    continue;
                }
            }
            let r = if f == via {
                Some((0, None))
            } else {
                edges
                    .iter()
                    .filter(|(c, _)| state[*c] == 2)
                    .filter_map(|&(c, tail)| {
                        let (d, _) = reach[c]?;
                        let extra = if tail { 0 } else { self.funcs[f].frame };
                        Some((d + extra, Some((c, tail))))
                    })
                    .max_by_key(|(d, _)| *d)
            };
            reach[f] = r;
            state[f] = 2;
            stack.pop();
        }
        let mut steps = Vec::new();
        let mut f = root;
        let mut at = 0u64;
        let mut tail = false;
        for _ in 0..n {
            steps.push(Step {
                func: f,
                depth_at_entry: at,
                tail,
            });
            if f == via {
                break;
            }
            let (_, Some((c, t))) = reach[f]? else {
                return None;
            };
            if !t {
                at += self.funcs[f].frame;
            }
            f = c;
            tail = t;
        }
        let below = self.deepest(via);
        for s in below.steps.iter().skip(1) {
            steps.push(Step {
                func: s.func,
                depth_at_entry: at + s.depth_at_entry,
                tail: s.tail,
            });
        }
        let reach_all = self.reachable(root);
        Some(DeepPath {
            total: at + depth[via],
            steps,
            reachable_indirect: below.reachable_indirect,
            reachable: reach_all.len(),
        })
    }
}

/// The roots the report follows: the image's entry, the flight software's frame function, and
/// the entry's deepest path through the frame function (the static counterpart of the painted
/// flight-phase peak).
#[derive(Debug, Clone)]
pub struct Summary {
    pub entry: Option<DeepPath>,
    pub tick: Option<DeepPath>,
    pub flight: Option<DeepPath>,
}

/// True for the flight software's frame function `fsw::flight::Fsw<P>::tick`.
pub fn is_tick(name: &str) -> bool {
    name.starts_with("fsw::flight::Fsw<") && name.ends_with(">::tick")
}

/// Follow the roots of [`Summary`].
pub fn summarise(r: &StackReport) -> Summary {
    let entry = r.entry.and_then(|a| r.at(a));
    let tick = r.find(is_tick);
    Summary {
        entry: entry.map(|e| r.deepest(e)),
        tick: tick.map(|t| r.deepest(t)),
        flight: entry.zip(tick).and_then(|(e, t)| r.deepest_through(e, t)),
    }
}

/// Function names shortened for a table: generic arguments and hash dropped, at most 70
/// characters.
pub fn short(name: &str) -> String {
    let mut out = String::new();
    let mut depth = 0usize;
    let mut angle_start = 0usize;
    for (i, c) in name.char_indices() {
        match c {
            '<' => {
                if depth == 0 {
                    angle_start = i;
                }
                depth += 1;
                if depth == 1 {
                    out.push('<');
                }
            }
            '>' if depth > 0 => {
                depth -= 1;
                if depth == 0 {
                    // Keep `<impl X>`-style paths readable: only the first segment.
                    let inner = &name[angle_start + 1..i];
                    if inner.contains(" as ") || inner.starts_with("impl ") {
                        out.push_str(inner.split(" as ").next().unwrap_or(inner));
                    } else if inner.chars().all(|c| c.is_alphanumeric() || c == '_') {
                        out.push_str(inner);
                    } else {
                        out.push_str("..");
                    }
                    out.push('>');
                }
            }
            _ if depth == 0 => out.push(c),
            _ => {}
        }
    }
    if out.chars().count() > 70 {
        let tail: String = out
            .chars()
            .rev()
            .take(67)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        format!("...{tail}")
    } else {
        out
    }
}

/// Plain-text report of one path (for the console).
pub fn path_text(r: &StackReport, title: &str, p: &DeepPath, rows: usize) -> String {
    let mut s = format!(
        "{title}: worst case {} B over {} reachable functions ({} indirect calls/jumps not \
         followed)\n",
        p.total, p.reachable, p.reachable_indirect
    );
    for st in p.steps.iter().take(rows) {
        let f = &r.funcs[st.func];
        s.push_str(&format!(
            "  {:>7} B {:>7} B {}{}{}\n",
            st.depth_at_entry,
            f.frame,
            if st.tail { "(tail) " } else { "" },
            short(&f.name),
            if f.indirect > 0 {
                format!(" [{} indirect]", f.indirect)
            } else {
                String::new()
            }
        ));
    }
    if p.steps.len() > rows {
        s.push_str(&format!("  ... {} more\n", p.steps.len() - rows));
    }
    s
}

/// Decoded meaning of one instruction for the analysis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Insn {
    /// Reserves this many bytes of stack.
    Reserve(u64),
    /// `sub.w sp, sp, rN`: reserves the value last moved into rN.
    ReserveReg(usize),
    /// `movw rN, #imm16` (true) or `movt rN, #imm16` (false).
    Mov(usize, u32, bool),
    /// `bl` to this address.
    Call(u64),
    /// A direct branch to this address (a tail call when outside the function).
    Branch(u64),
    /// An indirect call or jump.
    Indirect,
    Other,
}

/// `ThumbExpandImm` of a 12-bit `i:imm3:imm8` modified immediate.
fn thumb_expand_imm(imm12: u32) -> u32 {
    let imm8 = imm12 & 0xFF;
    if imm12 >> 10 == 0 {
        match (imm12 >> 8) & 3 {
            0 => imm8,
            1 => imm8 << 16 | imm8,
            2 => imm8 << 24 | imm8 << 8,
            _ => imm8 * 0x0101_0101,
        }
    } else {
        (0x80 | (imm12 & 0x7F)).rotate_right(imm12 >> 7)
    }
}

/// Decode a 16-bit Thumb instruction at `pc`.
fn decode16(pc: u64, hw: u16) -> Insn {
    if hw & 0xFE00 == 0xB400 {
        // PUSH T1: registers r0-r7 plus lr (M bit).
        let regs = (hw & 0xFF).count_ones() + u32::from((hw >> 8) & 1);
        return Insn::Reserve(4 * u64::from(regs));
    }
    if hw & 0xFF80 == 0xB080 {
        // SUB SP, SP, #imm7*4 (T1).
        return Insn::Reserve(4 * u64::from(hw & 0x7F));
    }
    if hw & 0xFF80 == 0x4780 {
        return Insn::Indirect; // BLX rm
    }
    if hw & 0xFF87 == 0x4700 {
        // BX rm: a return through lr, else an indirect jump.
        return if (hw >> 3) & 0xF == 14 {
            Insn::Other
        } else {
            Insn::Indirect
        };
    }
    if hw & 0xFF87 == 0x4687 {
        return Insn::Indirect; // MOV pc, rm
    }
    match branch16(pc, hw) {
        Some(t) => Insn::Branch(t),
        None => Insn::Other,
    }
}

/// Decode a 32-bit Thumb-2 instruction at `pc`.
fn decode32(pc: u64, hw1: u16, hw2: u16) -> Insn {
    let (h1, h2) = (u32::from(hw1), u32::from(hw2));
    let rd = ((h2 >> 8) & 0xF) as usize;
    let imm12 = ((h1 >> 10) & 1) << 11 | ((h2 >> 12) & 7) << 8 | (h2 & 0xFF);
    // PUSH.W / STMDB SP!, {list} (T2).
    if h1 == 0xE92D {
        return Insn::Reserve(4 * u64::from((h2 & 0x5FFF).count_ones()));
    }
    // STR rt, [sp, #-4]! (PUSH T3).
    if h1 == 0xF84D && h2 & 0x0FFF == 0x0D04 {
        return Insn::Reserve(4);
    }
    // SUB.W SP, SP, #const (T2, S = 0).
    if h1 & 0xFBFF == 0xF1AD && h2 & 0x8F00 == 0x0D00 {
        return Insn::Reserve(u64::from(thumb_expand_imm(imm12)));
    }
    // SUBW SP, SP, #imm12 (T3).
    if h1 & 0xFBFF == 0xF2AD && h2 & 0x8F00 == 0x0D00 {
        return Insn::Reserve(u64::from(imm12));
    }
    // SUB.W SP, SP, rm (T1, no shift).
    if h1 == 0xEBAD && h2 & 0xFFF0 == 0x0D00 {
        return Insn::ReserveReg((h2 & 0xF) as usize);
    }
    // VPUSH / VSTMDB SP!, {d or s list}: imm8 words.
    if h1 & 0xFFBF == 0xED2D && h2 & 0x0E00 == 0x0A00 {
        return Insn::Reserve(4 * u64::from(h2 & 0xFF));
    }
    // MOVW / MOVT rd, #imm16 (T3).
    if h1 & 0xFB70 == 0xF240 && h2 & 0x8000 == 0 {
        let imm16 = (h1 & 0xF) << 12 | imm12;
        return Insn::Mov(rd, imm16, h1 & 0x0080 == 0);
    }
    // LDR.W pc, [rn, ...]: a return when rn is sp, else an indirect jump.
    if (h1 & 0xFFF0 == 0xF8D0 || h1 & 0xFFF0 == 0xF850) && h2 >> 12 == 0xF {
        return if h1 & 0xF == 13 {
            Insn::Other
        } else {
            Insn::Indirect
        };
    }
    if h1 & 0xF800 == 0xF000 && h2 & 0xD000 == 0xD000 {
        if let Some(t) = branch32(pc, hw1, hw2) {
            return Insn::Call(t);
        }
    }
    match branch32(pc, hw1, hw2) {
        Some(t) => Insn::Branch(t),
        None => Insn::Other,
    }
}

/// Analyse the image at `path`.
pub fn analyse(path: &Path) -> Result<StackReport> {
    let data = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let file = object::File::parse(&*data).context("not an ELF file")?;
    let mut funcs = Vec::new();
    let mut data_marks = Vec::new();
    let mut code_marks = Vec::new();
    for sym in file.symbols() {
        let raw = sym.name().unwrap_or("");
        if raw == "$d" || raw.starts_with("$d.") {
            data_marks.push(sym.address());
        } else if raw == "$t" || raw.starts_with("$t.") {
            code_marks.push(sym.address());
        }
        if sym.kind() == SymbolKind::Text && sym.size() > 0 {
            let start = sym.address() & !1;
            funcs.push(Func {
                name: demangle(raw),
                start,
                end: start + sym.size(),
                ..Func::default()
            });
        }
    }
    funcs.sort_by_key(|f| f.start);
    funcs.dedup_by_key(|f| f.start);
    data_marks.sort_unstable();
    code_marks.sort_unstable();
    let in_data = |addr: u64| -> bool {
        let d = data_marks.partition_point(|&a| a <= addr);
        let t = code_marks.partition_point(|&a| a <= addr);
        match (d.checked_sub(1), t.checked_sub(1)) {
            (Some(d), Some(t)) => data_marks[d] > code_marks[t],
            (Some(_), None) => true,
            _ => false,
        }
    };
    let mut report = StackReport {
        funcs,
        entry: Some(file.entry()),
        ..StackReport::default()
    };
    let mut bodies = Vec::new();
    for f in &report.funcs {
        let sec = file
            .sections()
            .find(|s| s.address() <= f.start && f.end <= s.address() + s.size());
        let words = match sec.and_then(|s| Some((s.address(), s.data().ok()?))) {
            Some((base, bytes)) => decode_body(f.start, f.end, base, bytes, &in_data),
            None => Vec::new(),
        };
        bodies.push(words);
    }
    for (i, body) in bodies.into_iter().enumerate() {
        let (start, end) = (report.funcs[i].start, report.funcs[i].end);
        let mut regs: BTreeMap<usize, u32> = BTreeMap::new();
        let mut f = Func::default();
        for insn in body {
            match insn {
                Insn::Reserve(n) => f.frame += n,
                Insn::ReserveReg(r) => match regs.get(&r) {
                    Some(&v) => f.frame += u64::from(v),
                    None => f.indirect += 1, // a frame of unknown size is reported like a jump
                },
                Insn::Mov(r, v, low) => {
                    let old = regs.get(&r).copied().unwrap_or(0);
                    let new = if low { v } else { (old & 0xFFFF) | v << 16 };
                    regs.insert(r, new);
                }
                Insn::Call(t) => match report.at(t) {
                    Some(c) => f.calls.push(c),
                    None => f.unresolved += 1,
                },
                Insn::Branch(t) if !(start..end).contains(&t) => match report.at(t) {
                    Some(c) => f.tails.push(c),
                    None => f.unresolved += 1,
                },
                Insn::Indirect => f.indirect += 1,
                Insn::Branch(_) | Insn::Other => {}
            }
        }
        f.calls.sort_unstable();
        f.calls.dedup();
        f.tails.sort_unstable();
        f.tails.dedup();
        let dst = &mut report.funcs[i];
        dst.frame = f.frame;
        dst.calls = f.calls;
        dst.tails = f.tails;
        dst.indirect = f.indirect;
        dst.unresolved = f.unresolved;
    }
    report.cycles = cycles(&report);
    report.cut_edges = report.depths().2;
    Ok(report)
}

/// Decode the instructions of `[start, end)` (literal pools skipped).
fn decode_body(
    start: u64,
    end: u64,
    base: u64,
    bytes: &[u8],
    in_data: &impl Fn(u64) -> bool,
) -> Vec<Insn> {
    let read16 = |addr: u64| -> Option<u16> {
        let off = usize::try_from(addr.checked_sub(base)?).ok()?;
        let b = bytes.get(off..off + 2)?;
        Some(u16::from_le_bytes([b[0], b[1]]))
    };
    let mut out = Vec::new();
    let mut pc = start;
    while pc + 2 <= end {
        if in_data(pc) {
            pc += 2;
            continue;
        }
        let Some(hw1) = read16(pc) else { break };
        if matches!(hw1 >> 11, 0b11101..=0b11111) {
            let Some(hw2) = read16(pc + 2) else { break };
            out.push(decode32(pc, hw1, hw2));
            pc += 4;
        } else {
            out.push(decode16(pc, hw1));
            pc += 2;
        }
    }
    out
}

/// Strongly connected components with a cycle (Tarjan, iterative).
fn cycles(r: &StackReport) -> Vec<Vec<usize>> {
    let n = r.funcs.len();
    let mut index = vec![usize::MAX; n];
    let mut low = vec![0usize; n];
    let mut on = vec![false; n];
    let mut stack = Vec::new();
    let mut next_index = 0usize;
    let mut out = Vec::new();
    for root in 0..n {
        if index[root] != usize::MAX {
            continue;
        }
        let mut work: Vec<(usize, usize)> = vec![(root, 0)];
        index[root] = next_index;
        low[root] = next_index;
        next_index += 1;
        stack.push(root);
        on[root] = true;
        while let Some(&mut (v, ref mut k)) = work.last_mut() {
            let edges = r.edges(v);
            if let Some(&(w, _)) = edges.get(*k) {
                *k += 1;
                if index[w] == usize::MAX {
                    index[w] = next_index;
                    low[w] = next_index;
                    next_index += 1;
                    stack.push(w);
                    on[w] = true;
                    work.push((w, 0));
                } else if on[w] {
                    low[v] = low[v].min(index[w]);
                }
                continue;
            }
            work.pop();
            if let Some(&(u, _)) = work.last() {
                low[u] = low[u].min(low[v]);
            }
            if low[v] == index[v] {
                let mut comp = Vec::new();
                while let Some(w) = stack.pop() {
                    on[w] = false;
                    comp.push(w);
                    if w == v {
                        break;
                    }
                }
                let self_loop = edges.iter().any(|&(w, _)| w == v);
                if comp.len() > 1 || self_loop {
                    comp.sort_unstable();
                    out.push(comp);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_prologues() {
        // push {r4, r5, r6, r7, lr}
        assert_eq!(decode16(0, 0xB5F0), Insn::Reserve(20));
        // sub sp, #4
        assert_eq!(decode16(0, 0xB081), Insn::Reserve(4));
        // push.w {r8, r9, r10, r11}
        assert_eq!(decode32(0, 0xE92D, 0x0F00), Insn::Reserve(16));
        // vpush {d8-d14}: 14 words
        assert_eq!(decode32(0, 0xED2D, 0x8B0E), Insn::Reserve(56));
        // sub.w sp, sp, #544 (modified immediate 0x708 -> 0x220)
        assert_eq!(decode32(0, 0xF5AD, 0x7D08), Insn::Reserve(544));
        // subw sp, sp, #2248
        assert_eq!(decode32(0, 0xF6AD, 0x0DC8), Insn::Reserve(2248));
        // str r11, [sp, #-4]!
        assert_eq!(decode32(0, 0xF84D, 0xBD04), Insn::Reserve(4));
        // subw r2, r2, #1023 is not a stack reservation
        assert_eq!(decode32(0, 0xF2A2, 0x32FF), Insn::Other);
        // blx r3, bx r3 are indirect; bx lr is a return
        assert_eq!(decode16(0, 0x4798), Insn::Indirect);
        assert_eq!(decode16(0, 0x4718), Insn::Indirect);
        assert_eq!(decode16(0, 0x4770), Insn::Other);
        // bl +0x100 is a call, b.w is a branch
        assert_eq!(decode32(0x1000, 0xF000, 0xF87E), Insn::Call(0x1100));
        assert_eq!(decode32(0x3000, 0xF000, 0xB804), Insn::Branch(0x300C));
        // movw r4, #0x1234; movt r4, #1
        assert_eq!(decode32(0, 0xF241, 0x2434), Insn::Mov(4, 0x1234, true));
        assert_eq!(decode32(0, 0xF2C0, 0x0401), Insn::Mov(4, 1, false));
        assert_eq!(decode32(0, 0xEBAD, 0x0D04), Insn::ReserveReg(4));
        // ldr pc, [sp], #4 is a return; ldr.w pc, [r0, r1, lsl #2] a jump
        assert_eq!(decode32(0, 0xF85D, 0xFB04), Insn::Other);
        assert_eq!(decode32(0, 0xF850, 0xF021), Insn::Indirect);
    }

    #[test]
    fn expands_modified_immediates() {
        assert_eq!(thumb_expand_imm(0x0FF), 0xFF);
        assert_eq!(thumb_expand_imm(0x1AB), 0x00AB_00AB);
        // i:imm3:imm8 = 1:111:00001000 (sub.w sp, sp, #544): 0x88 rotated right by 30.
        assert_eq!(thumb_expand_imm(0xF08), 544);
        // 129536 = 0xFD << 9: rotation 23 of 0xFD.
        assert_eq!(thumb_expand_imm((23 << 7) | 0x7D), 129_536);
    }

    fn func(name: &str, frame: u64, calls: &[usize], tails: &[usize]) -> Func {
        Func {
            name: name.into(),
            frame,
            calls: calls.to_vec(),
            tails: tails.to_vec(),
            ..Func::default()
        }
    }

    #[test]
    fn deepest_path_counts_calls_tail_calls_and_cuts_cycles() {
        // 0 calls 1 and 2; 1 tail-calls 3 (runs at 1's entry); 2 calls 4; 4 calls 2 (cycle).
        let r = StackReport {
            funcs: vec![
                func("root", 100, &[1, 2], &[]),
                func("small_then_tail", 10, &[], &[3]),
                func("mid", 40, &[4], &[]),
                func("big", 500, &[], &[]),
                func("loop", 30, &[2], &[]),
            ],
            ..StackReport::default()
        };
        let p = r.deepest(0);
        // root 100 + big 500 (tail call from a 10 B frame) > root + mid + loop = 170.
        assert_eq!(p.total, 600);
        let names: Vec<&str> = p
            .steps
            .iter()
            .map(|s| r.funcs[s.func].name.as_str())
            .collect();
        assert_eq!(names, ["root", "small_then_tail", "big"]);
        assert_eq!(p.steps[2].depth_at_entry, 100);
        assert!(p.steps[2].tail);
        assert_eq!(cycles(&r), vec![vec![2, 4]]);
        let t = r.deepest_through(0, 4).map(|p| p.total);
        assert_eq!(t, Some(170));
    }
}
