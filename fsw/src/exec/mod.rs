//! # Rate-group cyclic executive (design card, ARCHITECTURE.md sec. 4)
//!
//! A minor frame (default 5 ms, 200 Hz) is started by a tick: SysTick on the rover CPU, the
//! simulator's clock on the host. In every frame the executive
//!
//! 1. applies pending group enable/disable requests (only at frame boundaries),
//! 2. runs every enabled group whose `tick % divisor == offset`, in group order (group 0 first),
//!    and inside a group its tasks in their configured order,
//! 3. gives the background slot one fixed work quantum (long work such as visual odometry),
//! 4. records execution times from the [`Clock`] counter and counts overruns.
//!
//! ## Overrun policy
//!
//! Timing feeds telemetry, never decisions: the logical schedule (which task runs in which
//! frame, how much background work is done) is a function of the tick count alone, so the same
//! inputs give bit-identical outputs on the host and on the target. An overrun is therefore
//! *reported*, not acted on by the executive:
//!
//! - a task whose execution time exceeds its budget increments that task's overrun counter;
//! - a frame whose total execution time exceeds the minor-frame period is a *cycle slip*: the
//!   frame counter [`Executive::cycle_slips`] increments, the next tick is simply late (no
//!   logical frame is dropped), and after [`ExecConfig::slip_fault_threshold`] consecutive slips
//!   the latched [`Executive::timing_fault`] flag is raised for fault management and telemetry.
//! - a failing clock read leaves that sample out of the statistics and counts a timing fault;
//!   the tasks still run.
//!
//! Capacities are const generics: `G` rate groups, `T` tasks. Nothing allocates.

mod sliced;
mod stats;

use rover_hal::Clock;
pub use sliced::{step_frame_job, FrameJob, FrameKey, Progress};
pub use stats::TimingStats;

/// Background work in a quantum (ARCHITECTURE sec. 4: long work is a resumable pipeline
/// advanced by a fixed work quantum per frame): calls `item` until the costs it reports reach
/// `quantum` units (at least one call; the last item may go past the quantum by its own cost)
/// or an item returns a result, which is returned. `item` gives the cost of the work item it
/// runs (units of about 10 000 rover-CPU instructions; 0 counts as 1, so at most `quantum`
/// items run) and the pipeline's result when that item finished it. Used by the visual
/// odometry, the hazard mapper and the rectification ([`step_frame_job`]).
pub fn spend_quantum<R>(quantum: u32, mut item: impl FnMut() -> (u16, Option<R>)) -> Option<R> {
    let mut spent = 0u32;
    while spent < quantum.max(1) {
        let (cost, done) = item();
        spent = spent.saturating_add(u32::from(cost.max(1)));
        if done.is_some() {
            return done;
        }
    }
    None
}

/// One rate group: it fires in every minor frame whose tick satisfies
/// `tick % divisor == offset` (F Prime `RateGroupDriver` style).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GroupConfig {
    /// Name for reports and telemetry.
    pub name: &'static str,
    /// Rate divisor relative to the minor-frame rate (1 = every frame). Must be at least 1.
    pub divisor: u32,
    /// Phase in minor frames, `0 <= offset < divisor`.
    pub offset: u32,
    /// Whether the group runs from the first frame.
    pub enabled: bool,
}

/// One task: a unit of work inside a rate group with its own execution-time budget.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskConfig {
    /// Name for reports and telemetry.
    pub name: &'static str,
    /// Index of the group the task belongs to.
    pub group: usize,
    /// Execution-time budget, microseconds.
    pub budget_us: u32,
}

/// Executive-wide settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExecConfig {
    /// Minor-frame period, microseconds (default 5000, i.e. 200 Hz).
    pub frame_period_us: u32,
    /// Work quantum handed to the background slot in every frame (units defined by the
    /// background work, e.g. pipeline steps of visual odometry).
    pub background_quantum: u32,
    /// Consecutive cycle slips after which [`Executive::timing_fault`] latches.
    pub slip_fault_threshold: u32,
}

impl Default for ExecConfig {
    fn default() -> Self {
        Self {
            frame_period_us: 5_000,
            background_quantum: 1,
            slip_fault_threshold: 3,
        }
    }
}

/// A configuration the executive refuses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExecError {
    /// Group `0` has a zero divisor or an offset not below its divisor.
    BadGroup(usize),
    /// Task `0` names a group that does not exist.
    BadTask(usize),
    /// Tasks must be listed group by group, in group order (so that the call order is the
    /// table order).
    TasksNotInGroupOrder(usize),
    /// The frame period is zero.
    BadFramePeriod,
    /// A group index out of range was given to [`Executive::request_group_enabled`].
    NoSuchGroup(usize),
}

/// The work the executive dispatches: implemented by the flight software's top level.
pub trait TaskSet {
    /// Run task `task` (its index in the task table) for minor frame `tick`.
    fn run_task(&mut self, task: usize, tick: u64);

    /// Advance background work by at most `quantum` units. Returns the number of units used; it
    /// must depend only on the work's inputs, never on time.
    fn background(&mut self, quantum: u32, tick: u64) -> u32;
}

/// What happened in one minor frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameReport {
    /// The frame's tick number (0 for the first frame).
    pub tick: u64,
    /// Bit `g` set when group `g` ran in this frame.
    pub groups_run: u32,
    /// Number of tasks that ran.
    pub tasks_run: u32,
    /// Background units used.
    pub background_used: u32,
    /// Total execution time of the frame, microseconds (0 when the clock failed).
    pub elapsed_us: u64,
    /// True when the frame took longer than the minor-frame period.
    pub slipped: bool,
}

/// Per-group state and statistics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GroupState {
    /// Configuration.
    pub config: GroupConfig,
    /// Enabled in the current frame.
    pub enabled: bool,
    /// Times the group ran.
    pub runs: u64,
    /// Execution time of the group (all its tasks), counter-derived microseconds.
    pub timing: TimingStats,
}

/// Per-task state and statistics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskState {
    /// Configuration.
    pub config: TaskConfig,
    /// Execution time and overruns against `config.budget_us`.
    pub timing: TimingStats,
}

/// The rate-group executive with `G` groups and `T` tasks (fixed capacities).
#[derive(Debug, Clone)]
pub struct Executive<const G: usize, const T: usize> {
    config: ExecConfig,
    groups: [GroupState; G],
    tasks: [TaskState; T],
    pending_enable: [Option<bool>; G],
    tick: u64,
    frame: TimingStats,
    background_units: u64,
    cycle_slips: u64,
    consecutive_slips: u32,
    timing_fault: bool,
    clock_faults: u64,
}

impl<const G: usize, const T: usize> Executive<G, T> {
    /// An executive with no schedule (every group disabled, no task budget): the placeholder a
    /// statically allocated flight software starts from before [`Self::new`]'s value replaces
    /// it (`crate::flight::Fsw::init`).
    pub const EMPTY: Self = Self {
        config: ExecConfig {
            frame_period_us: 5_000,
            background_quantum: 0,
            slip_fault_threshold: 0,
        },
        groups: [GroupState {
            config: GroupConfig {
                name: "",
                divisor: 1,
                offset: 0,
                enabled: false,
            },
            enabled: false,
            runs: 0,
            timing: TimingStats::new(0),
        }; G],
        tasks: [TaskState {
            config: TaskConfig {
                name: "",
                group: 0,
                budget_us: 0,
            },
            timing: TimingStats::new(0),
        }; T],
        pending_enable: [None; G],
        tick: 0,
        frame: TimingStats::new(0),
        background_units: 0,
        cycle_slips: 0,
        consecutive_slips: 0,
        timing_fault: false,
        clock_faults: 0,
    };

    /// Build an executive from its group and task tables. Rejects zero divisors, offsets not
    /// below their divisor, tasks naming unknown groups, and tasks out of group order.
    pub fn new(
        config: ExecConfig,
        groups: [GroupConfig; G],
        tasks: [TaskConfig; T],
    ) -> Result<Self, ExecError> {
        if config.frame_period_us == 0 {
            return Err(ExecError::BadFramePeriod);
        }
        if G > 32 {
            return Err(ExecError::BadGroup(32));
        }
        for (i, g) in groups.iter().enumerate() {
            if g.divisor == 0 || g.offset >= g.divisor {
                return Err(ExecError::BadGroup(i));
            }
        }
        let mut previous_group = 0;
        for (i, t) in tasks.iter().enumerate() {
            if t.group >= G {
                return Err(ExecError::BadTask(i));
            }
            if t.group < previous_group {
                return Err(ExecError::TasksNotInGroupOrder(i));
            }
            previous_group = t.group;
        }
        Ok(Self {
            config,
            groups: groups.map(|g| GroupState {
                config: g,
                enabled: g.enabled,
                runs: 0,
                timing: TimingStats::new(0),
            }),
            tasks: tasks.map(|t| TaskState {
                config: t,
                timing: TimingStats::new(t.budget_us),
            }),
            pending_enable: [None; G],
            tick: 0,
            frame: TimingStats::new(config.frame_period_us),
            background_units: 0,
            cycle_slips: 0,
            consecutive_slips: 0,
            timing_fault: false,
            clock_faults: 0,
        })
    }

    /// Ask for group `group` to be enabled or disabled; applied at the start of the next frame.
    pub fn request_group_enabled(&mut self, group: usize, enabled: bool) -> Result<(), ExecError> {
        match self.pending_enable.get_mut(group) {
            Some(slot) => {
                *slot = Some(enabled);
                Ok(())
            }
            None => Err(ExecError::NoSuchGroup(group)),
        }
    }

    /// Run one minor frame: due groups in order, then the background quantum.
    pub fn run_frame<C: Clock, S: TaskSet>(&mut self, clock: &mut C, work: &mut S) -> FrameReport {
        let tick = self.tick;
        let hz = clock.counter_hz();
        for (state, pending) in self.groups.iter_mut().zip(self.pending_enable.iter_mut()) {
            if let Some(enabled) = pending.take() {
                state.enabled = enabled;
            }
        }
        let mut report = FrameReport {
            tick,
            ..FrameReport::default()
        };
        let frame_start = self.read_counter(clock);
        let mut task_index = 0usize;
        for (g, group) in self.groups.iter_mut().enumerate() {
            let due = group.enabled
                && tick.checked_rem(u64::from(group.config.divisor))
                    == Some(u64::from(group.config.offset));
            let group_start = if due {
                read(clock, &mut self.clock_faults)
            } else {
                None
            };
            // Tasks are stored group by group, so this group's tasks follow the previous ones.
            while let Some(task) = self.tasks.get_mut(task_index) {
                if task.config.group != g {
                    break;
                }
                if due {
                    let start = read(clock, &mut self.clock_faults);
                    work.run_task(task_index, tick);
                    let end = read(clock, &mut self.clock_faults);
                    task.timing.record(elapsed_us(start, end, hz));
                    report.tasks_run = report.tasks_run.saturating_add(1);
                }
                task_index += 1;
            }
            if due {
                let end = read(clock, &mut self.clock_faults);
                group.timing.record(elapsed_us(group_start, end, hz));
                group.runs = group.runs.saturating_add(1);
                report.groups_run |= 1u32 << g;
            }
        }
        let used = work.background(self.config.background_quantum, tick);
        report.background_used = used;
        self.background_units = self.background_units.saturating_add(u64::from(used));
        let frame_end = self.read_counter(clock);
        let frame_us = elapsed_us(frame_start, frame_end, hz);
        self.frame.record(frame_us);
        report.elapsed_us = frame_us.unwrap_or(0);
        report.slipped = frame_us.is_some_and(|us| us > u64::from(self.config.frame_period_us));
        if report.slipped {
            self.cycle_slips = self.cycle_slips.saturating_add(1);
            self.consecutive_slips = self.consecutive_slips.saturating_add(1);
            if self.consecutive_slips >= self.config.slip_fault_threshold {
                self.timing_fault = true;
            }
        } else {
            self.consecutive_slips = 0;
        }
        self.tick = self.tick.wrapping_add(1);
        report
    }

    fn read_counter<C: Clock>(&mut self, clock: &mut C) -> Option<u64> {
        read(clock, &mut self.clock_faults)
    }

    /// The tick number of the next frame (frames run so far).
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// Group states and statistics, in group order.
    pub fn groups(&self) -> &[GroupState; G] {
        &self.groups
    }

    /// Task states and statistics, in table order.
    pub fn tasks(&self) -> &[TaskState; T] {
        &self.tasks
    }

    /// Whole-frame execution time; its overruns are the cycle slips.
    pub fn frame_timing(&self) -> &TimingStats {
        &self.frame
    }

    /// Frames whose execution time exceeded the minor-frame period.
    pub fn cycle_slips(&self) -> u64 {
        self.cycle_slips
    }

    /// Latched when `slip_fault_threshold` consecutive frames slipped.
    pub fn timing_fault(&self) -> bool {
        self.timing_fault
    }

    /// Clock reads that failed (timing samples left out).
    pub fn clock_faults(&self) -> u64 {
        self.clock_faults
    }

    /// Background work units used since boot.
    pub fn background_units(&self) -> u64 {
        self.background_units
    }

    /// The executive's configuration.
    pub fn config(&self) -> &ExecConfig {
        &self.config
    }
}

fn read<C: Clock>(clock: &mut C, faults: &mut u64) -> Option<u64> {
    match clock.counter() {
        Ok(c) => Some(c),
        Err(_) => {
            *faults = faults.saturating_add(1);
            None
        }
    }
}

/// Counter difference converted to microseconds; `None` when a read failed or the counter went
/// backwards (a clock fault, not a negative duration).
fn elapsed_us(start: Option<u64>, end: Option<u64>, counter_hz: u64) -> Option<u64> {
    let (start, end) = (start?, end?);
    let ticks = end.checked_sub(start)?;
    if counter_hz == 0 {
        return None;
    }
    let us = u128::from(ticks) * 1_000_000 / u128::from(counter_hz);
    Some(u64::try_from(us).unwrap_or(u64::MAX))
}

#[cfg(test)]
mod tests;
