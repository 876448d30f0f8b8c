//! Instruction counts from SysTick, and the stack high-water mark by stack painting.
//!
//! QEMU runs with `-icount shift=0,align=off,sleep=off`: virtual time advances exactly 1 ns per
//! instruction executed, independent of the host. SysTick counts the 25 MHz core clock of the
//! `mps2-an500` model in that virtual time, so one SysTick count is 40 instructions
//! ([`INSNS_PER_COUNT`]); `timing::calibrate` checks this with loops of known length.

use super::devices::SystickClock;
use core::sync::atomic::{compiler_fence, Ordering};
use rover_hal::Clock;

/// Instructions per SysTick count: 1e9 instructions per virtual second (`-icount shift=0`)
/// over the 25 MHz SysTick clock.
pub const INSNS_PER_COUNT: u64 = 1_000_000_000 / super::CORE_CLOCK_HZ as u64;

/// Statistics of one measured task, in instructions.
#[derive(Clone, Copy, Debug)]
pub struct Stats {
    /// Samples.
    pub n: u32,
    /// Smallest.
    pub min: u64,
    /// Largest.
    pub max: u64,
    /// Sum, for the mean.
    pub sum: u64,
    /// Calls that returned an error (still measured).
    pub errors: u32,
}

impl Stats {
    /// No samples.
    pub const fn new() -> Self {
        Self {
            n: 0,
            min: u64::MAX,
            max: 0,
            sum: 0,
            errors: 0,
        }
    }

    /// Add a sample; `ok == false` counts an error.
    pub fn add(&mut self, insns: u64, ok: bool) {
        self.n = self.n.saturating_add(1);
        self.min = self.min.min(insns);
        self.max = self.max.max(insns);
        self.sum = self.sum.saturating_add(insns);
        if !ok {
            self.errors = self.errors.saturating_add(1);
        }
    }

    /// Mean (0 without samples).
    pub fn mean(&self) -> u64 {
        if self.n == 0 {
            0
        } else {
            self.sum / u64::from(self.n)
        }
    }

    /// Smallest (0 without samples).
    pub fn min_or_zero(&self) -> u64 {
        if self.n == 0 {
            0
        } else {
            self.min
        }
    }
}

/// Instruction counter over SysTick.
pub struct Meter {
    clock: SystickClock,
    /// Instructions of an empty measurement (subtracted from every measurement).
    pub overhead: u64,
}

impl Meter {
    /// A meter over `clock` (SysTick must be running).
    pub fn new(clock: SystickClock) -> Self {
        let mut meter = Self { clock, overhead: 0 };
        // The empty measurement is constant; take the smallest of a few.
        let overhead = (0..8).map(|_| meter.measure(|| ()).1).min().unwrap_or(0);
        meter.overhead = overhead;
        meter
    }

    /// Instructions since SysTick started (resolution [`INSNS_PER_COUNT`]).
    pub fn now(&mut self) -> u64 {
        self.clock.counter().unwrap_or(0) * INSNS_PER_COUNT
    }

    /// Run `f` and return its result and the instructions it took (minus the overhead).
    #[inline(never)]
    pub fn measure<R>(&mut self, f: impl FnOnce() -> R) -> (R, u64) {
        compiler_fence(Ordering::SeqCst);
        let start = self.now();
        compiler_fence(Ordering::SeqCst);
        let r = core::hint::black_box(f());
        compiler_fence(Ordering::SeqCst);
        let end = self.now();
        compiler_fence(Ordering::SeqCst);
        (r, end.saturating_sub(start).saturating_sub(self.overhead))
    }
}

/// The value cortex-m-rt's `paint-stack` writes over the whole stack region at reset.
pub const STACK_PAINT: u32 = 0xCCCC_CCCC;

extern "C" {
    /// Top of the stack (initial SP), from cortex-m-rt's `link.x`.
    static _stack_start: u32;
    /// Bottom of the stack region (end of .bss and .uninit), from cortex-m-rt's `link.x`.
    static _stack_end: u32;
}

/// `(bottom, top)` addresses of the stack region.
pub fn stack_region() -> (usize, usize) {
    // Only the addresses of the linker symbols are taken.
    (
        core::ptr::addr_of!(_stack_end) as usize,
        core::ptr::addr_of!(_stack_start) as usize,
    )
}

/// Bytes of stack used since the last painting: scan up from the bottom of the region for the
/// first word that is not [`STACK_PAINT`].
pub fn stack_high_water() -> usize {
    let (bottom, top) = stack_region();
    let mut addr = bottom;
    while addr < top {
        // SAFETY: `addr` is a word-aligned address inside the RAM of the stack region.
        let word = unsafe { core::ptr::read_volatile(addr as *const u32) };
        if word != STACK_PAINT {
            break;
        }
        addr += 4;
    }
    top - addr
}

/// Paint the unused stack again (from the bottom to 256 bytes below the current stack
/// pointer), so the next [`stack_high_water`] measures the next phase alone.
#[inline(never)]
pub fn repaint_stack() {
    let (bottom, _) = stack_region();
    let sp = cortex_m::register::msp::read() as usize;
    let mut addr = bottom;
    while addr + 256 < sp {
        // SAFETY: the words below the current stack pointer (with a margin) are not in use;
        // an interrupt that uses them in between has returned before the next write.
        unsafe { core::ptr::write_volatile(addr as *mut u32, STACK_PAINT) };
        addr += 4;
    }
}
