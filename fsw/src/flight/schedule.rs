//! # The flight schedule: rate groups and tasks as enums
//!
//! [`Group`] and [`Task`] name the rate groups and tasks; their discriminants are the indices
//! of [`SCHEDULE_GROUPS`] and [`SCHEDULE_TASKS`] (the executive's tables) and of the dispatch
//! ([`Task::from_index`]), so the table, the dispatch and the names cannot drift apart.

use crate::exec::{GroupConfig, TaskConfig};

/// Number of rate groups in the flight schedule.
pub const GROUP_COUNT: usize = 5;
/// Number of tasks in the flight schedule.
pub const TASK_COUNT: usize = 10;

/// The rate groups (ARCHITECTURE.md sec. 4), in the executive's order. Divisors are relative to
/// the 200 Hz minor frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(usize)]
pub enum Group {
    /// 200 Hz: IMU read and EKF propagation.
    Rg1 = 0,
    /// 20 Hz: joints, kinematic aiding, guidance and the motor command.
    Rg2 = 1,
    /// 5 Hz: checks the distance-based capture policy often enough that a capture starts
    /// within 0.2 s (1 cm at the nominal 5 cm/s) of being due.
    Rg3 = 2,
    /// 0.2 Hz: sun sensor and power subsystem.
    Rg4 = 3,
    /// RG2's rate half a period later (offset 1 + 5): the zero-velocity update of a stop, apart
    /// from the kinematic update of the same stop, and the status telemetry (the RG2 release
    /// budget of 100,000 instructions, `docs/results/timing.md`). Frames of phase 6 run no
    /// other group but RG1 (RG3's and RG4's phases are 2 and 3 modulo 10).
    Rg2b = 4,
}

impl Group {
    /// Every group in table order.
    pub const ALL: [Group; GROUP_COUNT] =
        [Group::Rg1, Group::Rg2, Group::Rg3, Group::Rg4, Group::Rg2b];

    /// The group's executive settings: name, divisor, offset.
    pub const fn config(self) -> GroupConfig {
        let (name, divisor, offset) = match self {
            Group::Rg1 => ("RG1", 1, 0),
            Group::Rg2 => ("RG2", 10, 1),
            Group::Rg3 => ("RG3", 40, 2),
            Group::Rg4 => ("RG4", 1000, 3),
            Group::Rg2b => ("RG2B", 10, 6),
        };
        GroupConfig {
            name,
            divisor,
            offset,
            enabled: true,
        }
    }
}

/// The flight tasks in call order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(usize)]
pub enum Task {
    /// RG1: IMU read and checks.
    Imu = 0,
    /// RG1: EKF propagation (eq. 26-27; the alignment at the start).
    Propagate = 1,
    /// RG2: joint read and checks.
    Joints = 2,
    /// RG2: kinematic interval, gate (eq. 46), EKF update or slip vector.
    Odometry = 3,
    /// RG2: guidance (eq. 47-49), inverse kinematics, motor command.
    Guidance = 4,
    /// RG3: capture policy, trigger and clone (eq. 41).
    Stereo = 5,
    /// RG4: sun read and heading update (RB sec. 5.1).
    Sun = 6,
    /// RG4: power-subsystem read and checks (V99 sec. 3).
    Power = 7,
    /// RG2B: the zero-velocity update of a stop.
    Zupt = 8,
    /// RG2B: status and navigation telemetry records.
    Telemetry = 9,
}

impl Task {
    /// Every task in call order.
    pub const ALL: [Task; TASK_COUNT] = [
        Task::Imu,
        Task::Propagate,
        Task::Joints,
        Task::Odometry,
        Task::Guidance,
        Task::Stereo,
        Task::Sun,
        Task::Power,
        Task::Zupt,
        Task::Telemetry,
    ];

    /// The task of table index `index`, if any.
    pub fn from_index(index: usize) -> Option<Task> {
        Task::ALL.get(index).copied()
    }

    /// The task's executive settings: name, group, budget in microseconds of the rover CPU
    /// (300 MHz class; `docs/results/timing.md` measures them).
    pub const fn config(self) -> TaskConfig {
        let (name, group, budget_us) = match self {
            Task::Imu => ("imu", Group::Rg1, 100),
            Task::Propagate => ("propagate", Group::Rg1, 400),
            Task::Joints => ("joints", Group::Rg2, 100),
            Task::Odometry => ("odometry", Group::Rg2, 1_500),
            Task::Guidance => ("guidance", Group::Rg2, 500),
            Task::Stereo => ("stereo", Group::Rg3, 200),
            Task::Sun => ("sun", Group::Rg4, 300),
            Task::Power => ("power", Group::Rg4, 100),
            Task::Zupt => ("zupt", Group::Rg2b, 300),
            Task::Telemetry => ("telemetry", Group::Rg2b, 200),
        };
        TaskConfig {
            name,
            group: group as usize,
            budget_us,
        }
    }
}

/// Rate-group table, indexed by [`Group`].
pub const SCHEDULE_GROUPS: [GroupConfig; GROUP_COUNT] = {
    let mut t = [Group::Rg1.config(); GROUP_COUNT];
    let mut i = 0;
    while i < GROUP_COUNT {
        t[i] = Group::ALL[i].config();
        i += 1;
    }
    t
};

/// Task table in call order, indexed by [`Task`].
pub const SCHEDULE_TASKS: [TaskConfig; TASK_COUNT] = {
    let mut t = [Task::Imu.config(); TASK_COUNT];
    let mut i = 0;
    while i < TASK_COUNT {
        t[i] = Task::ALL[i].config();
        i += 1;
    }
    t
};

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    /// EXEC-8: the enums index the tables and the dispatch: every discriminant is its index,
    /// and the tables hold the schedule of ARCHITECTURE.md sec. 4 in call order.
    #[test]
    fn exec_8_task_and_group_enums_index_the_tables() {
        for (i, t) in Task::ALL.iter().enumerate() {
            assert_eq!(*t as usize, i);
            assert_eq!(Task::from_index(i), Some(*t));
            assert_eq!(SCHEDULE_TASKS[i], t.config());
        }
        assert_eq!(Task::from_index(TASK_COUNT), None);
        for (i, g) in Group::ALL.iter().enumerate() {
            assert_eq!(*g as usize, i);
            assert_eq!(SCHEDULE_GROUPS[i], g.config());
        }
        let names: Vec<&str> = SCHEDULE_TASKS.iter().map(|t| t.name).collect();
        assert_eq!(
            names,
            [
                "imu",
                "propagate",
                "joints",
                "odometry",
                "guidance",
                "stereo",
                "sun",
                "power",
                "zupt",
                "telemetry"
            ]
        );
        let groups: Vec<usize> = SCHEDULE_TASKS.iter().map(|t| t.group).collect();
        assert_eq!(groups, [0, 0, 1, 1, 1, 2, 3, 3, 4, 4]);
        let g: Vec<(u32, u32)> = SCHEDULE_GROUPS
            .iter()
            .map(|g| (g.divisor, g.offset))
            .collect();
        assert_eq!(g, [(1, 0), (10, 1), (40, 2), (1000, 3), (10, 6)]);
    }
}
