//! The still run: SysTick starts each 5 ms minor frame, the flight executive runs the schedule
//! for 10 s on a rover standing still, and the per-group counts and timing go out through
//! semihosting; it passes when the counts match the schedule.

use super::devices::{
    self, take_image_buffers, ExtramStereo, SystickClock, TargetCamera, TargetClock, TargetImu,
    TargetMobility, TargetPlatform, TargetPower, TargetSun, TargetTelemetry,
};
use super::{report, CORE_CLOCK_HZ, SYSTICKS};
use core::sync::atomic::Ordering;
use cortex_m::peripheral::syst::SystClkSource;
use fsw::exec::ExecConfig;
use fsw::flight::{Devices, SCHEDULE_GROUPS};
use fsw_image::flight_replay::FlightSetup;

/// Minor frames to run: 10 s at 200 Hz.
const FRAMES: u32 = 2_000;
/// Stereo captures of the 10 s still run.
const STILL_STEREO_FRAMES: u32 = 1;

/// Run; true when the schedule's counts matched and no device fault was counted.
pub fn run(mut core: cortex_m::Peripherals) -> bool {
    let config = ExecConfig::default();
    let reload = CORE_CLOCK_HZ / 1_000_000 * config.frame_period_us;
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(reload - 1);
    core.SYST.clear_current();

    let Some([left, right, ..]) = take_image_buffers() else {
        report(format_args!("fsw-image: image buffers already taken\n"));
        return false;
    };
    let devices = Devices::<TargetPlatform> {
        clock: TargetClock::Systick(SystickClock::new(reload, &SYSTICKS)),
        imu: TargetImu::Still(devices::StillImu::new(&SYSTICKS)),
        mobility: TargetMobility::Still(devices::StillMobility::new(&SYSTICKS)),
        camera: TargetCamera::Still(ExtramStereo::new([left, right], &SYSTICKS)),
        sun: TargetSun::Still(devices::FixedSun::new(&SYSTICKS)),
        power: TargetPower::Still(devices::ConstantPower::new(&SYSTICKS)),
        telemetry: TargetTelemetry::Counting(devices::CountingTelemetry::default()),
        // The still camera delivers a rectified test pattern: no rectification memory.
        image_memory: fsw::rectify::ImageMemory {
            map: &mut [],
            left: &mut [],
            right: &mut [],
        },
    };
    let Some(fsw) = super::install_new_fsw(devices, &FlightSetup::still()) else {
        return false;
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
    // Captures follow the capture policy (docs/vo.md): the first right after the 2 s alignment.
    // The target's still camera holds a test pattern, so VO keeps that frame as its keyframe;
    // a rover standing still then needs no capture before the 10 s time fallback (the host's
    // still run, SIL-EXEC-1, has uniform grey frames and retries every second instead).
    ok &= faults == 0 && state.stereo_frames == STILL_STEREO_FRAMES;
    report(format_args!(
        "frames {} late {} cycle_slips {} stereo_frames {} device_faults {} frame_max_us {}\n",
        FRAMES,
        late_frames,
        exec.cycle_slips(),
        state.stereo_frames,
        faults,
        exec.frame_timing().max_us
    ));
    ok
}
