//! Exact late measurements by replay (H04 sec. 4: a VO result that arrives frames after its
//! capture).
//!
//! Applied at the capture clones (eq. 41-45), a late relative pose gives the clone states of an
//! update at capture time exactly, but the current state only to first order (it receives the
//! correction through the cross-covariance, linearised along the uncorrected trajectory). A
//! [`Recorder`] makes it exact: at the capture it keeps a copy of the filter (about 9 KB),
//! then records every operation applied to the filter until the result arrives (IMU samples,
//! relative poses with their gating, zero-velocity and sun updates, clones and releases, in
//! order, fixed capacities). [`Recorder::apply_late`] restores the copy, applies the late
//! measurement there (at capture time) and replays the operations: the filter is then the one
//! that would have applied the measurement at capture time, bit for bit. Gated relative poses are
//! gated again by the corrected filter, as they would have been.
//!
//! Capacity: [`REPLAY_IMU`] IMU samples (1.28 s at 200 Hz) and [`REPLAY_MEASUREMENTS`] other
//! operations. When a capacity is exceeded the recording is abandoned ([`Recorder::overflowed`])
//! and the caller applies the measurement at the clones instead (first-order exact).

use super::{Ekf, EstError, GateDecision};
use crate::types::RelativePose;
use rover_hal::{ImuSample, SunReading};

/// IMU samples a recording holds.
pub const REPLAY_IMU: usize = 256;
/// Relative poses, zero-velocity and sun updates, clones and releases a recording holds.
pub const REPLAY_MEASUREMENTS: usize = 64;
/// Operations (of both kinds) a recording holds.
const REPLAY_OPS: usize = REPLAY_IMU + REPLAY_MEASUREMENTS;

/// One recorded operation other than propagation.
// Stored in a fixed array: there is no heap to box the large variant into.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
enum Measurement {
    /// `update_relative_pose(m, gated)`.
    RelativePose { m: RelativePose, gated: bool },
    /// `update_zero_velocity(t_us)`.
    ZeroVelocity { t_us: u64 },
    /// `update_sun(reading)`.
    Sun { reading: SunReading },
    /// `clone_at(t_us)`.
    Clone { t_us: u64 },
    /// `release(handle)` of the clone at `t_us`.
    Release { t_us: u64 },
}

/// Which list the next operation comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Op {
    Imu,
    Measurement,
}

/// A recording of filter operations since a snapshot (see the module doc). About 30 KB.
#[derive(Debug, Clone)]
pub struct Recorder {
    snapshot: Option<Ekf>,
    imu: [ImuSample; REPLAY_IMU],
    imu_count: usize,
    measurements: [Option<Measurement>; REPLAY_MEASUREMENTS],
    measurement_count: usize,
    ops: [Op; REPLAY_OPS],
    op_count: usize,
    overflowed: bool,
}

impl Default for Recorder {
    fn default() -> Self {
        Self::new()
    }
}

impl Recorder {
    /// An idle recorder.
    pub fn new() -> Self {
        Self {
            snapshot: None,
            imu: [ImuSample::default(); REPLAY_IMU],
            imu_count: 0,
            measurements: [None; REPLAY_MEASUREMENTS],
            measurement_count: 0,
            ops: [Op::Imu; REPLAY_OPS],
            op_count: 0,
            overflowed: false,
        }
    }

    /// Start recording at the filter's current state (call right after cloning the capture).
    /// A recording in progress is abandoned.
    pub fn begin(&mut self, ekf: &Ekf) {
        match self.snapshot.as_mut() {
            Some(s) => s.copy_from(ekf),
            None => self.snapshot = Some(ekf.clone()),
        }
        self.imu_count = 0;
        self.measurement_count = 0;
        self.op_count = 0;
        self.overflowed = false;
    }

    /// True while a recording is in progress (and has not overflowed).
    pub fn active(&self) -> bool {
        self.snapshot.is_some() && !self.overflowed
    }

    /// True when the recording ran out of capacity (the late measurement cannot be replayed).
    pub fn overflowed(&self) -> bool {
        self.overflowed
    }

    /// Stop recording without replaying.
    pub fn end(&mut self) {
        self.snapshot = None;
        self.overflowed = false;
    }

    fn push_op(&mut self, op: Op) -> bool {
        match self.ops.get_mut(self.op_count) {
            Some(slot) => {
                *slot = op;
                self.op_count += 1;
                true
            }
            None => {
                self.overflowed = true;
                false
            }
        }
    }

    /// Record a propagation with `sample` (after the filter accepted it).
    pub fn propagate(&mut self, sample: &ImuSample) {
        if !self.active() {
            return;
        }
        if self.imu_count < REPLAY_IMU && self.push_op(Op::Imu) {
            if let Some(slot) = self.imu.get_mut(self.imu_count) {
                *slot = *sample;
            }
            self.imu_count += 1;
        } else {
            self.overflowed = true;
        }
    }

    fn measurement(&mut self, m: Measurement) {
        if !self.active() {
            return;
        }
        if self.measurement_count < REPLAY_MEASUREMENTS && self.push_op(Op::Measurement) {
            if let Some(slot) = self.measurements.get_mut(self.measurement_count) {
                *slot = Some(m);
            }
            self.measurement_count += 1;
        } else {
            self.overflowed = true;
        }
    }

    /// Record `update_relative_pose(m, gated)`.
    pub fn relative_pose(&mut self, m: &RelativePose, gated: bool) {
        self.measurement(Measurement::RelativePose { m: *m, gated });
    }

    /// Record `update_zero_velocity(t_us)`.
    pub fn zero_velocity(&mut self, t_us: u64) {
        self.measurement(Measurement::ZeroVelocity { t_us });
    }

    /// Record `update_sun(reading)`.
    pub fn sun(&mut self, reading: &SunReading) {
        self.measurement(Measurement::Sun { reading: *reading });
    }

    /// Record `clone_at(t_us)`.
    pub fn clone_at(&mut self, t_us: u64) {
        self.measurement(Measurement::Clone { t_us });
    }

    /// Record the release of the clone at `t_us`.
    pub fn release(&mut self, t_us: u64) {
        self.measurement(Measurement::Release { t_us });
    }

    /// Restore the snapshot into `ekf`, apply the late measurement `m` there (gated or not),
    /// replay the recorded operations and end the recording. Returns the decision of `m`.
    /// Errors: no recording or an overflowed one ([`EstError::NoStateAtTime`]; `ekf` is then
    /// unchanged), or the filter's own errors on `m` (the replay still runs, so `ekf` is the
    /// recorded filter again). Operations that fail during the replay fail as they did live.
    pub fn apply_late(
        &mut self,
        ekf: &mut Ekf,
        m: &RelativePose,
        gated: bool,
    ) -> Result<GateDecision, EstError> {
        let Some(snapshot) = self.snapshot.as_ref().filter(|_| !self.overflowed) else {
            self.end();
            return Err(EstError::NoStateAtTime { t_us: m.t1_us });
        };
        ekf.copy_from(snapshot);
        let decision = ekf.update_relative_pose(m, gated);
        let (mut i, mut k) = (0usize, 0usize);
        for op in self.ops.get(..self.op_count).unwrap_or(&[]) {
            match op {
                Op::Imu => {
                    if let Some(s) = self.imu.get(i) {
                        let _ = ekf.propagate(s);
                    }
                    i += 1;
                }
                Op::Measurement => {
                    if let Some(Some(meas)) = self.measurements.get(k) {
                        replay_one(ekf, meas);
                    }
                    k += 1;
                }
            }
        }
        self.end();
        decision
    }
}

fn replay_one(ekf: &mut Ekf, m: &Measurement) {
    match m {
        Measurement::RelativePose { m, gated } => {
            let _ = ekf.update_relative_pose(m, *gated);
        }
        Measurement::ZeroVelocity { t_us } => {
            let _ = ekf.update_zero_velocity(*t_us);
        }
        Measurement::Sun { reading } => {
            let _ = ekf.update_sun(reading);
        }
        Measurement::Clone { t_us } => {
            let _ = ekf.clone_at(*t_us);
        }
        Measurement::Release { t_us } => {
            if let Some(h) = ekf.clone_handle(*t_us) {
                let _ = ekf.release(h);
            }
        }
    }
}
