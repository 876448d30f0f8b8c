//! What the rover-CPU image's ELF file says: section sizes, the largest statics, allocator
//! symbols and the call sites of panic functions (a Thumb-2 branch decoder over `.text`).

use anyhow::{Context, Result};
use object::{Object, ObjectSection, ObjectSymbol, SymbolKind};
use std::collections::BTreeMap;
use std::path::Path;

/// One allocated section.
#[derive(Debug, Clone)]
pub struct Section {
    pub name: String,
    pub addr: u64,
    pub size: u64,
}

/// One symbol with a size.
#[derive(Debug, Clone)]
pub struct Sized {
    pub name: String,
    pub addr: u64,
    pub size: u64,
}

/// The analysis of the image.
#[derive(Debug, Clone)]
pub struct ElfReport {
    pub sections: Vec<Section>,
    /// Largest objects in `.data`/`.bss`/`.extram`, largest first.
    pub statics: Vec<Sized>,
    /// Symbols that would belong to an allocator (must be empty).
    pub allocator_symbols: Vec<String>,
    /// Call or branch sites of panic functions from outside them, per panic function.
    pub panic_sites: BTreeMap<String, usize>,
    /// The same per calling crate (first path segment of the enclosing function).
    pub panic_sites_by_crate: BTreeMap<String, usize>,
    /// The same per enclosing function, most sites first.
    pub panic_sites_by_function: Vec<(String, usize)>,
    /// Instructions decoded (sanity figure).
    pub decoded_instructions: usize,
    /// `_stack_start` and `_stack_end`.
    pub stack_region: (u64, u64),
}

impl ElfReport {
    pub fn section(&self, name: &str) -> u64 {
        self.sections
            .iter()
            .filter(|s| s.name == name)
            .map(|s| s.size)
            .sum()
    }
    pub fn panic_total(&self) -> usize {
        self.panic_sites.values().sum()
    }

    /// Panic sites outside the image's number formatting (`core::fmt`, `core::num::flt2dec`,
    /// `core::num::bignum`: the semihosting reports and the panic handler's message), per
    /// enclosing function: the flight code's own, inlined into whatever function it ended up
    /// in. Must be empty (the flight code has no panic path); `cargo xtask timing`
    /// fails otherwise.
    pub fn flight_panic_sites(&self) -> Vec<(String, usize)> {
        self.panic_sites_by_function
            .iter()
            .filter(|(name, _)| !is_formatting_function(name))
            .cloned()
            .collect()
    }
}

/// The image's float and integer formatting machinery (reports over semihosting).
fn is_formatting_function(name: &str) -> bool {
    let name = name.trim_start_matches('<');
    ["core::fmt::", "core::num::flt2dec::", "core::num::bignum::"]
        .iter()
        .any(|p| name.starts_with(p))
}

/// The identifiers of a v0-mangled Rust symbol (`_R...`) joined with `::`, skipping crate
/// disambiguators, back-references and generic arguments' markers (good enough to match
/// paths such as `core::panicking::panic_fmt`; not a full demangler).
fn demangle_v0(rest: &str) -> String {
    let b = rest.as_bytes();
    let mut parts = Vec::new();
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            // Back-reference `B<base62>_`, or a disambiguator `s<base62>_` (after C, M, X, Y
            // or a namespace tag; identifiers always start with their length).
            b'B' | b's' => {
                i = rest[i..].find('_').map_or(b.len(), |k| i + k + 1);
            }
            b'0'..=b'9' => {
                let digits = rest[i..].bytes().take_while(u8::is_ascii_digit).count();
                let n: usize = rest[i..i + digits].parse().unwrap_or(0);
                i += digits;
                if b.get(i) == Some(&b'_') {
                    i += 1;
                }
                if let Some(ident) = rest.get(i..i + n) {
                    parts.push(ident.to_string());
                }
                i += n;
            }
            _ => i += 1,
        }
    }
    parts.join("::")
}

/// Demangle a Rust symbol: legacy (`_ZN...E`, hash dropped) fully, v0 (`_R...`) to its path
/// identifiers; other names are returned as they are.
pub fn demangle(name: &str) -> String {
    if let Some(rest) = name.strip_prefix("_R") {
        return demangle_v0(rest);
    }
    let Some(mut rest) = name.strip_prefix("_ZN") else {
        return name.to_string();
    };
    let mut parts = Vec::new();
    while let Some(first) = rest.chars().next() {
        if first == 'E' {
            break;
        }
        let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        let Ok(len) = digits.parse::<usize>() else {
            return name.to_string();
        };
        let start = digits.len();
        let Some(part) = rest.get(start..start + len) else {
            return name.to_string();
        };
        parts.push(
            part.strip_prefix('_')
                .filter(|p| p.starts_with('$'))
                .unwrap_or(part)
                .to_string(),
        );
        rest = &rest[start + len..];
    }
    if parts
        .last()
        .is_some_and(|p| p.len() == 17 && p.starts_with('h'))
    {
        parts.pop();
    }
    let joined = parts.join("::");
    joined
        .replace("$LT$", "<")
        .replace("$GT$", ">")
        .replace("$RF$", "&")
        .replace("$BP$", "*")
        .replace("$C$", ",")
        .replace("$u20$", " ")
        .replace("$u27$", "'")
        .replace("$u5b$", "[")
        .replace("$u5d$", "]")
        .replace("$u7b$", "{")
        .replace("$u7d$", "}")
        .replace("$u3b$", ";")
        .replace("$u2b$", "+")
        .replace("$u22$", "\"")
        .replace("..", "::")
}

/// True for the functions a panic goes through (the targets counted as panic sites).
fn is_panic_function(name: &str) -> bool {
    const PATTERNS: [&str; 9] = [
        "core::panicking::",
        "core::option::unwrap_failed",
        "core::option::expect_failed",
        "core::result::unwrap_failed",
        "core::slice::index::",
        "len_mismatch_fail",
        "core::cell::panic_already",
        "rust_begin_unwind",
        "core::str::slice_error_fail",
    ];
    PATTERNS.iter().any(|p| name.contains(p))
}

/// Allocator entry points: any of these in the image would mean a heap.
const ALLOCATOR_SYMBOLS: [&str; 8] = [
    "__rust_alloc",
    "__rust_dealloc",
    "__rust_realloc",
    "__rust_alloc_zeroed",
    "__rg_alloc",
    "__rdl_alloc",
    "__rust_alloc_error_handler",
    "alloc::alloc::",
];

struct Function {
    name: String,
    start: u64,
    end: u64,
}

/// Everything the analysis reads from the image's symbol table.
struct Symbols {
    /// Functions by start address (one per address).
    functions: Vec<Function>,
    /// Addresses of the `$d` (data) and `$t` (Thumb code) mapping symbols, sorted.
    data_marks: Vec<u64>,
    code_marks: Vec<u64>,
    /// The largest statics in RAM and external RAM.
    statics: Vec<Sized>,
    allocator_symbols: Vec<String>,
    /// `_stack_start`, `_stack_end`.
    stack_region: (u64, u64),
}

/// The panic sites the decoder found.
struct PanicSites {
    by_target: BTreeMap<String, usize>,
    by_crate: BTreeMap<String, usize>,
    by_function: BTreeMap<String, usize>,
    /// Instructions decoded.
    decoded: usize,
}

pub fn analyse(path: &Path) -> Result<ElfReport> {
    let data = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let file = object::File::parse(&*data).context("not an ELF file")?;
    let sections = sections(&file);
    let symbols = symbols(&file);
    let sites = panic_sites(&file, &symbols)?;
    let mut panic_sites_by_function: Vec<(String, usize)> = sites.by_function.into_iter().collect();
    panic_sites_by_function.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    Ok(ElfReport {
        panic_sites_by_function,
        sections,
        statics: symbols.statics,
        allocator_symbols: symbols.allocator_symbols,
        panic_sites: sites.by_target,
        panic_sites_by_crate: sites.by_crate,
        decoded_instructions: sites.decoded,
        stack_region: symbols.stack_region,
    })
}

/// The image's allocated sections (and `.text`, `.vector_table`, `.data`, `.bss`, `.rodata`
/// even when empty).
fn sections(file: &object::File) -> Vec<Section> {
    let mut sections = Vec::new();
    for s in file.sections() {
        let name = s.name().unwrap_or("").to_string();
        if s.address() == 0 && name != ".vector_table" && name != ".text" {
            continue; // debug and comment sections
        }
        if s.size() > 0 || matches!(name.as_str(), ".data" | ".bss" | ".text" | ".rodata") {
            sections.push(Section {
                name,
                addr: s.address(),
                size: s.size(),
            });
        }
    }

    sections
}

/// The functions, mapping symbols, statics, allocator symbols and stack region of the
/// symbol table.
fn symbols(file: &object::File) -> Symbols {
    let mut functions = Vec::new();
    let mut data_marks = Vec::new();
    let mut code_marks = Vec::new();
    let mut statics = Vec::new();
    let mut allocator_symbols = Vec::new();
    let mut stack_start = 0;
    let mut stack_end = 0;
    for sym in file.symbols() {
        let raw = sym.name().unwrap_or("");
        let name = demangle(raw);
        match raw {
            "_stack_start" => stack_start = sym.address(),
            "_stack_end" => stack_end = sym.address(),
            _ => {}
        }
        if raw == "$d" || raw.starts_with("$d.") {
            data_marks.push(sym.address());
        } else if raw == "$t" || raw.starts_with("$t.") {
            code_marks.push(sym.address());
        }
        if ALLOCATOR_SYMBOLS
            .iter()
            .any(|a| name.contains(a) || raw.contains(a))
        {
            allocator_symbols.push(name.clone());
        }
        match sym.kind() {
            SymbolKind::Text if sym.size() > 0 => {
                let start = sym.address() & !1;
                functions.push(Function {
                    name,
                    start,
                    end: start + sym.size(),
                });
            }
            SymbolKind::Data if sym.size() > 0 => {
                let in_ram = (0x2000_0000..0x2010_0000).contains(&sym.address())
                    || (0x6000_0000..0x6100_0000).contains(&sym.address());
                if in_ram {
                    statics.push(Sized {
                        name,
                        addr: sym.address(),
                        size: sym.size(),
                    });
                }
            }
            _ => {}
        }
    }
    statics.sort_by_key(|s| std::cmp::Reverse(s.size));
    statics.truncate(12);
    functions.sort_by_key(|f| f.start);
    functions.dedup_by_key(|f| f.start);
    data_marks.sort_unstable();
    code_marks.sort_unstable();

    Symbols {
        functions,
        data_marks,
        code_marks,
        statics,
        allocator_symbols,
        stack_region: (stack_start, stack_end),
    }
}

/// Decode every function of `.text` (skipping literal pools) and count the branches to a
/// panic function.
fn panic_sites(file: &object::File, symbols: &Symbols) -> Result<PanicSites> {
    let Symbols {
        functions,
        data_marks,
        code_marks,
        ..
    } = symbols;
    let text = file.section_by_name(".text").context("no .text section")?;
    let text_addr = text.address();
    let text_data = text.data()?;
    let read16 = |addr: u64| -> Option<u16> {
        let off = usize::try_from(addr.checked_sub(text_addr)?).ok()?;
        let b = text_data.get(off..off + 2)?;
        Some(u16::from_le_bytes([b[0], b[1]]))
    };
    let panic_targets: Vec<(u64, u64, &str)> = functions
        .iter()
        .filter(|f| is_panic_function(&f.name))
        .map(|f| (f.start, f.end, f.name.as_str()))
        .collect();
    let target_of = |addr: u64| -> Option<&str> {
        panic_targets
            .iter()
            .find(|(s, e, _)| (*s..*e).contains(&addr))
            .map(|(_, _, n)| *n)
    };
    // Is `addr` inside a data ($d) run: the last mapping symbol at or before it is $d?
    let in_data = |addr: u64| -> bool {
        let d = data_marks.partition_point(|&a| a <= addr);
        let t = code_marks.partition_point(|&a| a <= addr);
        let last_d = d.checked_sub(1).map(|i| data_marks[i]);
        let last_t = t.checked_sub(1).map(|i| code_marks[i]);
        match (last_d, last_t) {
            (Some(d), Some(t)) => d > t,
            (Some(_), None) => true,
            _ => false,
        }
    };

    let mut panic_sites = BTreeMap::new();
    let mut panic_sites_by_crate = BTreeMap::new();
    let mut by_function: BTreeMap<String, usize> = BTreeMap::new();
    let mut decoded = 0usize;
    for f in functions {
        if is_panic_function(&f.name) {
            continue;
        }
        let mut pc = f.start;
        while pc + 2 <= f.end {
            if in_data(pc) {
                pc += 2;
                continue;
            }
            let Some(hw1) = read16(pc) else { break };
            decoded += 1;
            let wide = matches!(hw1 >> 11, 0b11101..=0b11111);
            let target = if wide {
                let Some(hw2) = read16(pc + 2) else { break };
                branch32(pc, hw1, hw2)
            } else {
                branch16(pc, hw1)
            };
            if let Some(name) = target.and_then(target_of) {
                *panic_sites.entry(name.to_string()).or_insert(0) += 1;
                let krate = f
                    .name
                    .split("::")
                    .next()
                    .unwrap_or("?")
                    .trim_start_matches('<');
                *panic_sites_by_crate.entry(krate.to_string()).or_insert(0) += 1;
                *by_function.entry(f.name.clone()).or_insert(0) += 1;
            }
            pc += if wide { 4 } else { 2 };
        }
    }
    Ok(PanicSites {
        by_target: panic_sites,
        by_crate: panic_sites_by_crate,
        by_function,
        decoded,
    })
}

fn sign_extend(value: u32, bits: u32) -> i64 {
    let shift = 32 - bits;
    i64::from(((value << shift) as i32) >> shift)
}

/// Target of a 32-bit Thumb-2 branch: BL (T1), B.W (T4) or B<cond>.W (T3).
pub(crate) fn branch32(pc: u64, hw1: u16, hw2: u16) -> Option<u64> {
    if hw1 & 0xF800 != 0xF000 {
        return None;
    }
    let (hw1, hw2) = (u32::from(hw1), u32::from(hw2));
    let s = (hw1 >> 10) & 1;
    let j1 = (hw2 >> 13) & 1;
    let j2 = (hw2 >> 11) & 1;
    let imm11 = hw2 & 0x7FF;
    let offset = match hw2 & 0xD000 {
        // BL and B.W (T4): S:I1:I2:imm10:imm11:0, I = NOT(J xor S).
        0xD000 | 0x9000 => {
            let i1 = 1 ^ (j1 ^ s);
            let i2 = 1 ^ (j2 ^ s);
            let imm10 = hw1 & 0x3FF;
            let v = (s << 24) | (i1 << 23) | (i2 << 22) | (imm10 << 12) | (imm11 << 1);
            sign_extend(v, 25)
        }
        // B<cond>.W (T3): S:J2:J1:imm6:imm11:0 (cond 111x is not a branch).
        0x8000 => {
            let cond = (hw1 >> 6) & 0xF;
            if cond >= 0xE {
                return None;
            }
            let imm6 = hw1 & 0x3F;
            let v = (s << 20) | (j2 << 19) | (j1 << 18) | (imm6 << 12) | (imm11 << 1);
            sign_extend(v, 21)
        }
        _ => return None,
    };
    Some((pc as i64 + 4 + offset) as u64)
}

/// Target of a 16-bit Thumb branch: B (T2) or B<cond> (T1).
pub(crate) fn branch16(pc: u64, hw1: u16) -> Option<u64> {
    let hw1 = u32::from(hw1);
    let offset = if hw1 & 0xF800 == 0xE000 {
        sign_extend((hw1 & 0x7FF) << 1, 12)
    } else if hw1 & 0xF000 == 0xD000 && ((hw1 >> 8) & 0xF) < 0xE {
        sign_extend((hw1 & 0xFF) << 1, 9)
    } else {
        return None;
    };
    Some((pc as i64 + 4 + offset) as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demangles_legacy_names() {
        assert_eq!(
            demangle("_ZN4core9panicking18panic_bounds_check17h0123456789abcdefE"),
            "core::panicking::panic_bounds_check"
        );
        assert_eq!(
            demangle("_ZN59_$LT$core..fmt..Arguments$u20$as$u20$core..fmt..Display$GT$3fmt17h0123456789abcdefE"),
            "<core::fmt::Arguments as core::fmt::Display>::fmt"
        );
        assert_eq!(demangle("main"), "main");
        assert_eq!(
            demangle("_RNvNtCs7ldSeZOOJos_4core9panicking18panic_bounds_check"),
            "core::panicking::panic_bounds_check"
        );
        assert_eq!(
            demangle("_RNvMsa_NtCs7ldSeZOOJos_4core3fmtNtB5_9Formatter3pad"),
            "core::fmt::Formatter::pad"
        );
        assert_eq!(
            demangle("_RNvXs_NtNtCs7ldSeZOOJos_4core5panic10panic_infoNtB4_9PanicInfoNtNtB8_3fmt7Display3fmt"),
            "core::panic::panic_info::PanicInfo::fmt::Display::fmt"
        );
    }

    #[test]
    fn decodes_thumb2_branches() {
        // bl with offset +0x100: f000 f87e at pc 0x1000 -> 0x1000 + 4 + 0xFC.
        assert_eq!(branch32(0x1000, 0xF000, 0xF87E), Some(0x1100));
        // bl backwards by 4: f7ff fffe -> pc + 4 - 4.
        assert_eq!(branch32(0x2000, 0xF7FF, 0xFFFE), Some(0x2000));
        // b.w (T4) forward 8: f000 b804.
        assert_eq!(branch32(0x3000, 0xF000, 0xB804), Some(0x300C));
        // bne.w (T3) forward 8: f040 8004.
        assert_eq!(branch32(0x3000, 0xF040, 0x8004), Some(0x300C));
        // b (T2) backwards: e7fe is a branch to itself.
        assert_eq!(branch16(0x400, 0xE7FE), Some(0x400));
        // beq (T1) forward 4: d002.
        assert_eq!(branch16(0x400, 0xD002), Some(0x408));
        // svc (cond 1111) is not a branch.
        assert_eq!(branch16(0x400, 0xDF00), None);
    }
}
