//! Target side: entry point, SysTick time base, devices in HAL glue, semihosting report.

mod devices;

use core::fmt::Write as _;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::{debug, hio};
use devices::{ExtramStereo, SystickClock, TargetPlatform};
use fsw::flight::{Devices, Fsw, FswConfig, SCHEDULE_GROUPS};

/// Core clock of the mps2-an500 model, Hz.
pub const CORE_CLOCK_HZ: u32 = 25_000_000;
/// Minor frames to run: 10 s at 200 Hz.
const FRAMES: u32 = 2_000;

/// SysTick interrupts since start (one per minor frame).
static SYSTICKS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    SYSTICKS.fetch_add(1, Ordering::Relaxed);
}

fn report(args: core::fmt::Arguments<'_>) {
    if let Ok(mut out) = hio::hstdout() {
        let _ = out.write_fmt(args);
    }
}

#[entry]
fn main() -> ! {
    // A still rover at the origin of N with a 1 m path north: guidance commands, the still
    // devices do not move.
    let fsw_config = FswConfig::rocky8([0.0; 3], 0.0);
    let config = fsw_config.exec;
    let reload = CORE_CLOCK_HZ / 1_000_000 * config.frame_period_us;
    let Some(mut core) = cortex_m::Peripherals::take() else {
        report(format_args!("fsw-image: core peripherals unavailable\n"));
        exit(debug::EXIT_FAILURE)
    };
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(reload - 1);
    core.SYST.clear_current();

    let devices = Devices::<TargetPlatform> {
        clock: SystickClock::new(reload, &SYSTICKS),
        imu: devices::StillImu::new(&SYSTICKS),
        mobility: devices::StillMobility::new(&SYSTICKS),
        camera: ExtramStereo::take(&SYSTICKS),
        sun: devices::FixedSun::new(&SYSTICKS),
        telemetry: devices::CountingTelemetry::default(),
    };
    let mut fsw = match Fsw::new(devices, &fsw_config, &[[0.0, 0.0], [1.0, 0.0]]) {
        Ok(f) => f,
        Err(e) => {
            report(format_args!(
                "fsw-image: flight software refused its configuration: {e:?}\n"
            ));
            exit(debug::EXIT_FAILURE)
        }
    };
    report(format_args!(
        "fsw-image: Cortex-M7, {} frames of {} us, SysTick reload {}\n",
        FRAMES, config.frame_period_us, reload
    ));
    core.SYST.enable_interrupt();
    core.SYST.enable_counter();

    let mut late_frames = 0u32;
    for frame in 0..FRAMES {
        // Wait for the tick that starts this frame.
        while SYSTICKS.load(Ordering::Relaxed) <= frame {
            cortex_m::asm::wfi();
        }
        if SYSTICKS.load(Ordering::Relaxed) > frame + 1 {
            late_frames += 1;
        }
        fsw.tick();
    }
    core.SYST.disable_counter();

    let exec = fsw.executive();
    let mut ok = exec.cycle_slips() == 0;
    report(format_args!(
        "{:<6} {:>8} {:>8} {:>10} {:>10} {:>9}\n",
        "group", "runs", "expect", "max_us", "mean_us", "overruns"
    ));
    for (g, state) in exec.groups().iter().enumerate() {
        let config = SCHEDULE_GROUPS[g];
        let expected = (0..FRAMES)
            .filter(|f| f % config.divisor == config.offset)
            .count() as u64;
        let overruns: u64 = exec
            .tasks()
            .iter()
            .filter(|t| t.config.group == g)
            .map(|t| t.timing.overruns)
            .sum();
        ok &= state.runs == expected;
        report(format_args!(
            "{:<6} {:>8} {:>8} {:>10} {:>10} {:>9}\n",
            state.config.name,
            state.runs,
            expected,
            state.timing.max_us,
            state.timing.mean_us(),
            overruns
        ));
    }
    for task in exec.tasks() {
        report(format_args!(
            "task {:<10} min_us {:>6} max_us {:>6} mean_us {:>6} budget_us {:>6}\n",
            task.config.name,
            task.timing.min_or_zero(),
            task.timing.max_us,
            task.timing.mean_us(),
            task.config.budget_us
        ));
    }
    let state = fsw.state();
    let faults: u32 = state.health.iter().map(|h| h.faults()).sum();
    ok &= faults == 0 && state.stereo_frames == FRAMES / SCHEDULE_GROUPS[2].divisor;
    report(format_args!(
        "frames {} late {} cycle_slips {} stereo_frames {} device_faults {} frame_max_us {}\n",
        FRAMES,
        late_frames,
        exec.cycle_slips(),
        state.stereo_frames,
        faults,
        exec.frame_timing().max_us
    ));
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
