//! Target side: entry point, SysTick time base, devices in HAL glue, semihosting report.
//!
//! Two runs, chosen by the semihosting command line (`-semihosting-config arg=...`):
//! - no argument: [`still`], the flight software on a rover standing still for 10 s, driven by
//!   SysTick, checking the schedule's counts (`cargo xtask qemu`);
//! - `timing <tape>`: [`timing`], the timing analysis: instruction-count calibration, replay of
//!   a recorded call tape with per-frame digests and instruction counts, the navigation tasks
//!   measured on the tape's inputs, and the stack high-water marks (`cargo xtask timing`).

mod bench;
mod devices;
mod loc_bench;
mod measure;
mod semihost;
mod still;
mod timing;

use core::fmt::Write as _;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::{debug, hio};
use devices::TargetPlatform;
use fsw::flight::Fsw;

/// Core clock of the mps2-an500 model, Hz.
pub const CORE_CLOCK_HZ: u32 = 25_000_000;

/// SysTick interrupts since start (one per minor frame).
static SYSTICKS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    SYSTICKS.fetch_add(1, Ordering::Relaxed);
}

/// Print to the host's standard output (semihosting).
fn report(args: core::fmt::Arguments<'_>) {
    if let Ok(mut out) = hio::hstdout() {
        let _ = out.write_fmt(args);
    }
}

/// The flight software: one static instance, initialised at compile time with the placeholder
/// [`Fsw::EMPTY`] (no code runs to build it, and it never passes through the stack); its RAM
/// shows in `.data`/`.bss`, not on the stack. [`install_new_fsw`] builds it in place.
static mut FSW: Fsw<TargetPlatform> = Fsw::EMPTY;
static FSW_TAKEN: AtomicBool = AtomicBool::new(false);

/// The flight software's static (once; `None` afterwards).
fn take_fsw() -> Option<&'static mut Fsw<TargetPlatform>> {
    if FSW_TAKEN.swap(true, Ordering::AcqRel) {
        return None;
    }
    // SAFETY: the flag above makes this the only reference ever made to FSW.
    Some(unsafe { &mut *core::ptr::addr_of_mut!(FSW) })
}

/// Build the flight software for `setup` around `devices` in its static, then its VO and
/// hazard navigation state: everything in place ([`Fsw::init`], [`Fsw::start_vo`]), so that
/// the initialisation runs on a shallow stack (no constructor returns the large state by
/// value).
#[inline(never)]
fn install_new_fsw(
    devices: fsw::flight::Devices<TargetPlatform>,
    setup: &fsw_image::flight_replay::FlightSetup,
) -> Option<&'static mut Fsw<TargetPlatform>> {
    let Some(fsw) = take_fsw() else {
        report(format_args!(
            "fsw-image: flight software already installed\n"
        ));
        return None;
    };
    if let Err(e) = fsw_image::flight_replay::init_fsw(fsw, devices, setup) {
        report(format_args!(
            "fsw-image: flight software refused its configuration: {e:?}\n"
        ));
        return None;
    }
    // Terrain-map localization's storage (about 82 KB): in external RAM, like the
    // image buffers (the replayed configuration leaves localization off; the storage is
    // there for a drive that enables it).
    if let Some(store) = take_static!(
        extram,
        fsw::flight::nav::LocNav,
        fsw::flight::nav::LocNav::EMPTY
    ) {
        fsw.provide_localization_memory(store);
    }
    fsw.start_vo();
    Some(fsw)
}

/// A `&'static mut` to a new static of type `$t` holding `$value` (evaluated once; `None` on a
/// second call). Like `cortex_m::singleton!`, with the static in `.bss` (`MaybeUninit`), or in
/// the external RAM `.extram` with `take_static!(extram, T, value)` (measurement harness state
/// that is not part of the flight software's RAM budget, and the flight software's large data
/// buffers: the localization storage).
macro_rules! take_static {
    (extram, $t:ty, $value:expr) => {{
        static TAKEN: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);
        #[link_section = ".extram"]
        static mut SLOT: core::mem::MaybeUninit<$t> = core::mem::MaybeUninit::uninit();
        if TAKEN.swap(true, core::sync::atomic::Ordering::AcqRel) {
            None
        } else {
            // SAFETY: the flag above makes this the only reference ever made to SLOT.
            Some(unsafe { (*core::ptr::addr_of_mut!(SLOT)).write($value) })
        }
    }};
    ($t:ty, $value:expr) => {{
        static TAKEN: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);
        static mut SLOT: core::mem::MaybeUninit<$t> = core::mem::MaybeUninit::uninit();
        if TAKEN.swap(true, core::sync::atomic::Ordering::AcqRel) {
            None
        } else {
            // SAFETY: the flag above makes this the only reference ever made to SLOT.
            Some(unsafe { (*core::ptr::addr_of_mut!(SLOT)).write($value) })
        }
    }};
}
pub(crate) use take_static;

#[entry]
fn main() -> ! {
    let mut buf = [0u8; 256];
    let cmdline = semihost::command_line(&mut buf);
    let mut words = cmdline.split_ascii_whitespace();
    let timing = words.by_ref().any(|w| w == "timing");
    let tape = words.next();
    let Some(core) = cortex_m::Peripherals::take() else {
        report(format_args!("fsw-image: core peripherals unavailable\n"));
        exit(debug::EXIT_FAILURE)
    };
    let ok = if timing {
        timing::run(core, tape)
    } else {
        still::run(core)
    };
    report(format_args!(
        "fsw-image: {}\n",
        if ok { "PASS" } else { "FAIL" }
    ));
    exit(if ok {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    })
}

/// Leave QEMU with `code` through semihosting; on hardware without a debugger, sleep forever.
fn exit(code: debug::ExitStatus) -> ! {
    debug::exit(code);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    report(format_args!("fsw-image: PANIC {info}\n"));
    exit(debug::EXIT_FAILURE)
}
