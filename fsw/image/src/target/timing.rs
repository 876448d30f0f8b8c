//! The timing run (`cargo xtask timing`): calibration of the instruction count, replay of a
//! recorded call tape through the flight software with per-frame digests and instruction
//! counts, the navigation tasks measured on the tape's inputs ([`super::bench`]), and the stack
//! high-water mark of each phase. Every result is one `timing ...` or `replay ...` line on the
//! host's standard output, parsed by xtask.

use super::bench::Bench;
use super::devices::{
    player, take_image_buffers, take_rectify_maps, SystickClock, TargetCamera, TargetClock,
    TargetImu, TargetMobility, TargetPlatform, TargetPower, TargetSun, TargetTelemetry,
};
use super::measure::{
    repaint_stack, stack_high_water, stack_region, Meter, Stats, INSNS_PER_COUNT,
};
use super::semihost::HostFile;
use super::{report, SYSTICKS};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_semihosting::hio;
use fsw::flight::{Devices, GROUP_COUNT};
use fsw_image::flight_replay::{FlightSetup, Replay};
use rover_replay::devices::{
    ReplayClock, ReplayImu, ReplayMobility, ReplayPower, ReplayStereo, ReplaySun, ReplayTelemetry,
};
use rover_replay::tape::TapeReader;

/// Iterations of the calibration loops.
const CALIBRATION_LOOPS: u32 = 1_000_000;

/// Two instructions per iteration (`subs`, `bne`).
#[inline(never)]
fn spin2(n: u32) {
    // SAFETY: register-only loop.
    unsafe {
        core::arch::asm!("2:", "subs {0}, {0}, #1", "bne 2b", inout(reg) n => _, options(nomem, nostack));
    }
}

/// Four instructions per iteration (`nop`, `nop`, `subs`, `bne`).
#[inline(never)]
fn spin4(n: u32) {
    // SAFETY: register-only loop.
    unsafe {
        core::arch::asm!("2:", "nop", "nop", "subs {0}, {0}, #1", "bne 2b", inout(reg) n => _, options(nomem, nostack));
    }
}

/// Measure loops of known length; true when both read 2,000,000 instructions within two
/// SysTick counts (plus the few instructions of the call).
fn calibrate(meter: &mut Meter) -> bool {
    let (_, two) = meter.measure(|| spin2(CALIBRATION_LOOPS));
    let (_, four) = meter.measure(|| spin4(CALIBRATION_LOOPS / 2));
    let expect = 2 * u64::from(CALIBRATION_LOOPS);
    report(format_args!(
        "timing calib insns_per_count {} overhead {} loop2 {} loop4 {} expect {}\n",
        INSNS_PER_COUNT, meter.overhead, two, four, expect
    ));
    let tolerance = 2 * INSNS_PER_COUNT + 16;
    two.abs_diff(expect) <= tolerance && four.abs_diff(expect) <= tolerance
}

fn print_stats(kind: &str, name: &str, s: &Stats) {
    report(format_args!(
        "timing {kind} {name} n {} min {} max {} mean {} errors {}\n",
        s.n,
        s.min_or_zero(),
        s.max,
        s.mean(),
        s.errors
    ));
}

/// SysTick reload of the timing run, counts (the register holds `reload - 1`, 24 bits).
const TIMING_RELOAD: u32 = 1 << 24;

/// The timing run over the tape at `path`; true when the calibration held and the replay
/// matched the recording frame for frame.
pub fn run(mut core: cortex_m::Peripherals, path: Option<&str>) -> bool {
    // The timing run replays frames back to back: SysTick is only its time base, so it runs
    // with the longest period the 24-bit reload register holds (2^24 counts, 671 M
    // instructions). The clock's reads near a reload are the ambiguous ones (QEMU raises the
    // pending bit after the counter has reloaded, `SystickClock::counter`): at the 5 ms period
    // of the still run one reload in about 4,000 reads left a measurement one period off.
    let reload = TIMING_RELOAD;
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(reload - 1);
    core.SYST.clear_current();
    core.SYST.enable_interrupt();
    core.SYST.enable_counter();
    let clock = SystickClock::new(reload, &SYSTICKS);
    let mut meter = Meter::new(clock);
    let calibrated = calibrate(&mut meter);

    let Some(path) = path else {
        report(format_args!("fsw-image: timing needs a tape path\n"));
        return false;
    };
    let files = (
        HostFile::open(path),
        HostFile::open(path),
        HostFile::open(path),
        HostFile::open(path),
    );
    let (Some(stream), Some(payload), Some(bench_stream), Some(bench_payload)) = files else {
        report(format_args!("fsw-image: cannot open {path}\n"));
        return false;
    };
    let tape_bytes = payload.len().unwrap_or(0);
    let mut replay = match Replay::open(stream) {
        Ok(r) => r,
        Err(e) => {
            report(format_args!("fsw-image: bad tape {path}: {e:?}\n"));
            return false;
        }
    };
    let header = *replay.header();
    report(format_args!(
        "timing tape {} frames {} bytes {}\n",
        header.scenario_name(),
        header.frames,
        tape_bytes
    ));

    let Some([b0, b1, b2, b3, b4, b5, b6, b7, b8, b9]) = take_image_buffers() else {
        report(format_args!("fsw-image: image buffers already taken\n"));
        return false;
    };
    let Some([map_fsw, map_bench]) = take_rectify_maps() else {
        report(format_args!(
            "fsw-image: rectification maps already taken\n"
        ));
        return false;
    };
    let Some(tape) = player() else {
        report(format_args!("fsw-image: replay player already taken\n"));
        return false;
    };
    let slots = [[&mut b0[..], &mut b1[..]], [&mut b2[..], &mut b3[..]]];
    let devices = Devices::<TargetPlatform> {
        clock: TargetClock::Replay(ReplayClock::new(tape, clock)),
        imu: TargetImu::Replay(ReplayImu::new(tape)),
        mobility: TargetMobility::Replay(ReplayMobility::new(tape)),
        camera: TargetCamera::Replay(
            ReplayStereo::new(tape, payload, slots, header.calibration).with_lens(header.lens),
        ),
        sun: TargetSun::Replay(ReplaySun::new(tape)),
        power: TargetPower::Replay(ReplayPower::new(tape, header.has_power())),
        telemetry: TargetTelemetry::Replay(ReplayTelemetry::new(tape)),
        image_memory: fsw::rectify::ImageMemory {
            map: &mut map_fsw[..],
            left: &mut b6[..],
            right: &mut b7[..],
        },
    };
    let Some(fsw) = super::install_new_fsw(devices, &FlightSetup::from_header(&header)) else {
        return false;
    };
    let Some(bench) = Bench::install(&header, [b4, b5], [b8, b9], &mut map_bench[..]) else {
        report(format_args!(
            "fsw-image: navigation tasks refused their setup\n"
        ));
        return false;
    };
    let init_stack = stack_high_water();
    repaint_stack();

    // Phase 1: the flight software on the tape, frame by frame.
    let Ok(mut out) = hio::hstdout() else {
        return false;
    };
    let mut frames = [Stats::new(); 1 << GROUP_COUNT];
    let mut replay_insns = 0u64;
    loop {
        match replay.load(&tape) {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => {
                report(format_args!("fsw-image: bad tape: {e:?}\n"));
                return false;
            }
        }
        let (frame, insns) = meter.measure(|| fsw.tick());
        if let Some(s) = frames.get_mut(frame.groups_run as usize) {
            s.add(insns, true);
        }
        replay_insns = replay_insns.saturating_add(insns);
        if replay.finish(&tape, fsw, &mut out).is_err() {
            break;
        }
    }
    replay.summary(&mut out);
    let flight_stack = stack_high_water();
    repaint_stack();
    for (mask, s) in frames.iter().enumerate() {
        if s.n > 0 {
            let name = FrameName(mask);
            report(format_args!(
                "timing frame {name} n {} min {} max {} mean {} errors {}\n",
                s.n,
                s.min_or_zero(),
                s.max,
                s.mean(),
                s.errors
            ));
        }
    }
    report(format_args!(
        "timing replay frames {} insns {}\n",
        replay.frames(),
        replay_insns
    ));
    let exec = fsw.executive();
    for g in exec.groups() {
        report(format_args!(
            "timing exec {} runs {} max_us {} mean_us {}\n",
            g.config.name,
            g.runs,
            g.timing.max_us,
            g.timing.mean_us()
        ));
    }
    for t in exec.tasks() {
        report(format_args!(
            "timing exec_task {} max_us {} mean_us {} budget_us {}\n",
            t.config.name,
            t.timing.max_us,
            t.timing.mean_us(),
            t.config.budget_us
        ));
    }

    // Phase 2: the navigation tasks on the tape's inputs.
    let mut reader = match TapeReader::open(bench_stream) {
        Ok(r) => r,
        Err(e) => {
            report(format_args!("fsw-image: bad tape: {e:?}\n"));
            return false;
        }
    };
    let bench_result = bench.run(&mut meter, &mut reader, bench_payload);
    let bench_stack = stack_high_water();
    for (name, s) in bench.tasks() {
        print_stats("task", name, s);
    }
    print_stats("task", "rectify_row", bench.rectify_rows());
    for (name, s) in bench.vo_items() {
        print_stats("vo_item", name, s);
    }
    let flight = fsw::flight::FswConfig::rocky8([0.0; 3], 0.0);
    for (kind, cost) in fsw::vo::WorkKind::ALL
        .iter()
        .zip(flight.nav.vo.pipeline.work_cost)
    {
        report(format_args!("timing vo_cost {} {}\n", kind.name(), cost));
    }
    report(format_args!(
        "timing background quantum {}\n",
        flight.exec.background_quantum
    ));
    bench.report_vo();
    if let Err(e) = bench_result {
        report(format_args!("fsw-image: bench stopped: {e:?}\n"));
    }
    let (bottom, top) = stack_region();
    report(format_args!(
        "timing stack init {} flight {} bench {} region {}\n",
        init_stack,
        flight_stack,
        bench_stack,
        top - bottom
    ));
    calibrated && replay.passed() && bench_result.is_ok()
}

/// The groups that ran in a frame, as `RG1+RG2`.
struct FrameName(usize);

impl core::fmt::Display for FrameName {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let mut first = true;
        for g in 0..GROUP_COUNT {
            if self.0 & (1 << g) != 0 {
                if !first {
                    f.write_str("+")?;
                }
                let name = fsw::flight::SCHEDULE_GROUPS.get(g).map_or("?", |c| c.name);
                f.write_str(name)?;
                first = false;
            }
        }
        if first {
            f.write_str("none")?;
        }
        Ok(())
    }
}
