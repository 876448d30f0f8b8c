//! Executive unit tests with a fake clock (requirements EXEC-1 .. EXEC-6, docs/requirements.md).

use super::*;

/// A fake clock whose counter advances by a scripted amount on every read (1 MHz counter, so
/// one count is one microsecond).
struct FakeClock {
    counter: u64,
    step: u64,
    fail_every: u64,
    reads: u64,
}

impl FakeClock {
    fn new(step: u64) -> Self {
        Self {
            counter: 0,
            step,
            fail_every: 0,
            reads: 0,
        }
    }
}

#[derive(Debug)]
struct ClockError;
impl rover_hal::Error for ClockError {
    fn kind(&self) -> rover_hal::ErrorKind {
        rover_hal::ErrorKind::Hardware
    }
}

impl Clock for FakeClock {
    type Error = ClockError;
    fn now_us(&mut self) -> Result<u64, ClockError> {
        Ok(self.counter)
    }
    fn counter(&mut self) -> Result<u64, ClockError> {
        self.reads += 1;
        if self.fail_every > 0 && self.reads % self.fail_every == 0 {
            return Err(ClockError);
        }
        self.counter += self.step;
        Ok(self.counter)
    }
    fn counter_hz(&self) -> u64 {
        1_000_000
    }
}

/// Records the call sequence (task, tick) in a fixed array.
struct Recorder {
    calls: [(usize, u64); 256],
    len: usize,
    background_calls: u64,
}

impl Recorder {
    fn new() -> Self {
        Self {
            calls: [(0, 0); 256],
            len: 0,
            background_calls: 0,
        }
    }
    fn calls(&self) -> &[(usize, u64)] {
        &self.calls[..self.len]
    }
}

impl TaskSet for Recorder {
    fn run_task(&mut self, task: usize, tick: u64) {
        if self.len < self.calls.len() {
            self.calls[self.len] = (task, tick);
            self.len += 1;
        }
    }
    fn background(&mut self, quantum: u32, _tick: u64) -> u32 {
        self.background_calls += 1;
        quantum
    }
}

fn groups() -> [GroupConfig; 3] {
    [
        GroupConfig {
            name: "RG1",
            divisor: 1,
            offset: 0,
            enabled: true,
        },
        GroupConfig {
            name: "RG2",
            divisor: 10,
            offset: 1,
            enabled: true,
        },
        GroupConfig {
            name: "RG3",
            divisor: 200,
            offset: 3,
            enabled: true,
        },
    ]
}

fn tasks() -> [TaskConfig; 4] {
    [
        TaskConfig {
            name: "imu",
            group: 0,
            budget_us: 100,
        },
        TaskConfig {
            name: "joints",
            group: 1,
            budget_us: 100,
        },
        TaskConfig {
            name: "guidance",
            group: 1,
            budget_us: 100,
        },
        TaskConfig {
            name: "stereo",
            group: 2,
            budget_us: 100,
        },
    ]
}

fn executive() -> Executive<3, 4> {
    match Executive::new(ExecConfig::default(), groups(), tasks()) {
        Ok(e) => e,
        Err(e) => panic!("valid configuration refused: {e:?}"),
    }
}

/// EXEC-1: groups fire on `tick % divisor == offset`, in group order, tasks in table order.
#[test]
fn exec_1_divisors_offsets_and_order() {
    let mut exec = executive();
    let mut clock = FakeClock::new(1);
    let mut rec = Recorder::new();
    for _ in 0..25 {
        exec.run_frame(&mut clock, &mut rec);
    }
    let mut expected = [(0usize, 0u64); 256];
    let mut n = 0;
    for tick in 0..25u64 {
        expected[n] = (0, tick);
        n += 1;
        if tick % 10 == 1 {
            expected[n] = (1, tick);
            expected[n + 1] = (2, tick);
            n += 2;
        }
        if tick % 200 == 3 {
            expected[n] = (3, tick);
            n += 1;
        }
    }
    assert_eq!(rec.calls(), &expected[..n]);
    assert_eq!(exec.groups()[0].runs, 25);
    assert_eq!(exec.groups()[1].runs, 3); // ticks 1, 11, 21
    assert_eq!(exec.groups()[2].runs, 1); // tick 3
    assert_eq!(rec.background_calls, 25);
    assert_eq!(exec.background_units(), 25);
}

/// EXEC-2: bad tables are refused with an error value.
#[test]
fn exec_2_bad_configuration_is_refused() {
    let mut g = groups();
    g[1].divisor = 0;
    assert_eq!(
        Executive::new(ExecConfig::default(), g, tasks()).err(),
        Some(ExecError::BadGroup(1))
    );
    let mut g = groups();
    g[2].offset = 200;
    assert_eq!(
        Executive::new(ExecConfig::default(), g, tasks()).err(),
        Some(ExecError::BadGroup(2))
    );
    let mut t = tasks();
    t[3].group = 7;
    assert_eq!(
        Executive::new(ExecConfig::default(), groups(), t).err(),
        Some(ExecError::BadTask(3))
    );
    let mut t = tasks();
    t[0].group = 2;
    assert_eq!(
        Executive::new(ExecConfig::default(), groups(), t).err(),
        Some(ExecError::TasksNotInGroupOrder(1))
    );
    let config = ExecConfig {
        frame_period_us: 0,
        ..ExecConfig::default()
    };
    assert_eq!(
        Executive::new(config, groups(), tasks()).err(),
        Some(ExecError::BadFramePeriod)
    );
}

/// EXEC-3: per-task overruns and frame cycle slips are counted; the fault latches after the
/// configured number of consecutive slips.
#[test]
fn exec_3_overruns_and_cycle_slips() {
    let mut exec = executive();
    // Every counter read advances 150 us: each task measures 150 us (> 100 us budget).
    let mut clock = FakeClock::new(150);
    let mut rec = Recorder::new();
    exec.run_frame(&mut clock, &mut rec); // tick 0: only RG1
    assert_eq!(exec.tasks()[0].timing.overruns, 1);
    assert_eq!(exec.tasks()[0].timing.last_us, 150);
    assert_eq!(exec.cycle_slips(), 0); // 5 reads * 150 = 750 us < 5000 us
                                       // Slow clock: every read 2 ms, so frames exceed 5 ms.
    clock.step = 2_000;
    for _ in 0..2 {
        let r = exec.run_frame(&mut clock, &mut rec);
        assert!(r.slipped);
    }
    assert_eq!(exec.cycle_slips(), 2);
    assert!(!exec.timing_fault());
    exec.run_frame(&mut clock, &mut rec);
    assert!(exec.timing_fault());
    // Back to fast: slips stop, the fault stays latched for fault management to clear.
    clock.step = 1;
    let r = exec.run_frame(&mut clock, &mut rec);
    assert!(!r.slipped);
    assert!(exec.timing_fault());
    assert_eq!(exec.frame_timing().overruns, 3);
}

/// EXEC-4: group enable/disable takes effect at the next frame boundary.
#[test]
fn exec_4_enable_disable_at_frame_boundary() {
    let mut exec = executive();
    let mut clock = FakeClock::new(1);
    let mut rec = Recorder::new();
    assert!(exec.request_group_enabled(0, false).is_ok());
    assert_eq!(
        exec.request_group_enabled(9, true),
        Err(ExecError::NoSuchGroup(9))
    );
    assert!(exec.groups()[0].enabled, "not applied before the frame");
    let r = exec.run_frame(&mut clock, &mut rec);
    assert_eq!(r.groups_run & 1, 0);
    assert!(exec.request_group_enabled(0, true).is_ok());
    let r = exec.run_frame(&mut clock, &mut rec);
    assert_eq!(r.groups_run & 1, 1);
    assert_eq!(rec.calls(), &[(0, 1), (1, 1), (2, 1)]);
}

/// EXEC-5: the logical schedule does not depend on timing: two clocks with very different
/// speeds, and one that fails, give the same call sequence.
#[test]
fn exec_5_schedule_independent_of_timing() {
    let mut fast = executive();
    let mut slow = executive();
    let mut clock_fast = FakeClock::new(1);
    let mut clock_slow = FakeClock::new(3_000);
    clock_slow.fail_every = 7;
    let mut rec_fast = Recorder::new();
    let mut rec_slow = Recorder::new();
    for _ in 0..120 {
        let a = fast.run_frame(&mut clock_fast, &mut rec_fast);
        let b = slow.run_frame(&mut clock_slow, &mut rec_slow);
        assert_eq!(a.groups_run, b.groups_run);
        assert_eq!(a.tasks_run, b.tasks_run);
        assert_eq!(a.background_used, b.background_used);
    }
    assert_eq!(rec_fast.calls(), rec_slow.calls());
    assert!(slow.clock_faults() > 0);
    assert_eq!(fast.clock_faults(), 0);
}

/// EXEC-6: last/min/max/mean statistics.
#[test]
fn exec_6_statistics() {
    let mut s = TimingStats::new(10);
    assert_eq!(s.mean_us(), 0);
    assert_eq!(s.min_or_zero(), 0);
    for us in [4, 8, 12, 0] {
        s.record(Some(us));
    }
    s.record(None);
    assert_eq!(s.samples, 4);
    assert_eq!((s.last_us, s.min_us, s.max_us, s.mean_us()), (0, 0, 12, 6));
    assert_eq!(s.overruns, 1);
    assert_eq!(elapsed_us(Some(10), Some(5), 1_000_000), None);
    assert_eq!(
        elapsed_us(Some(0), Some(25_000_000), 25_000_000),
        Some(1_000_000)
    );
    assert_eq!(elapsed_us(Some(0), Some(1), 0), None);
}

/// EXEC-7: `spend_quantum` runs items until their costs reach the quantum (at least one item,
/// zero costs count as one, so at most `quantum` items) and stops at the first result.
#[test]
fn exec_7_spend_quantum_bounds_and_results() {
    let mut calls = 0u32;
    let r: Option<()> = super::spend_quantum(10, || {
        calls += 1;
        (3, None)
    });
    assert_eq!(
        (r, calls),
        (None, 4),
        "3 + 3 + 3 < 10, the fourth reaches 12"
    );
    calls = 0;
    let r: Option<()> = super::spend_quantum(0, || {
        calls += 1;
        (5, None)
    });
    assert_eq!((r, calls), (None, 1), "at least one item");
    calls = 0;
    let r: Option<()> = super::spend_quantum(7, || {
        calls += 1;
        (0, None)
    });
    assert_eq!((r, calls), (None, 7), "zero costs count as one");
    calls = 0;
    let r = super::spend_quantum(100, || {
        calls += 1;
        (1, (calls == 3).then_some(42))
    });
    assert_eq!((r, calls), (Some(42), 3), "stops at the first result");
}
