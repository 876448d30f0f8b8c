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
//! The replay can also run in slices ([`Recorder::start_late`], then [`Recorder::replay_step`]
//! until it is done), so that no single call costs a whole second of propagation: the late
//! measurement is applied to the snapshot, the recorded operations are replayed on the snapshot
//! a few at a time while the live filter goes on (its new operations are recorded and replayed
//! too), and once the snapshot has caught up it is copied into the live filter. The result is
//! the same, bit for bit, as [`Recorder::apply_late`] at that moment.
//!
//! Capacity: [`REPLAY_IMU`] IMU samples (1.07 s at 200 Hz), [`REPLAY_POSES`] relative poses
//! (1.2 s of kinematic intervals at 20 Hz) and [`REPLAY_MEASUREMENTS`] other operations (the
//! clone and release of each interval, sun and zero-velocity updates: 40 to 60 per second).
//! The relative poses (368 B each) have their own list so that the small operations do not take
//! their room: one list of 64 for both held the same 1.07 s in 15 KB more RAM. Longer
//! recordings (1.28 and 1.6 s), to keep the VO results that rectifying the wide-angle pair makes
//! late, were tried and made the filter diverge on `cul-de-sac` seed 2 when those
//! results were replayed (`docs/estimation.md`); results later than 1.07 s are dropped
//! ([`ReplayProgress::Abandoned`], counted by the navigator). When a capacity is exceeded
//! the recording is abandoned ([`Recorder::overflowed`])
//! and the caller applies the measurement at the clones instead (first-order exact).

use super::{Ekf, EstError, GateDecision};
use crate::types::RelativePose;
use rover_hal::{ImuSample, SunReading};

/// IMU samples a recording holds.
pub const REPLAY_IMU: usize = 214;
/// Relative poses a recording holds.
pub const REPLAY_POSES: usize = 24;
/// Zero-velocity and sun updates, clones, releases and inflations a recording holds.
pub const REPLAY_MEASUREMENTS: usize = 48;
/// Operations (of all kinds) a recording holds.
const REPLAY_OPS: usize = REPLAY_IMU + REPLAY_POSES + REPLAY_MEASUREMENTS;

/// One recorded operation other than propagation and relative poses.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Measurement {
    /// `update_zero_velocity(t_us)`.
    ZeroVelocity { t_us: u64 },
    /// `update_sun(reading)`.
    Sun { reading: SunReading },
    /// `clone_at(t_us)`.
    Clone { t_us: u64 },
    /// `release(handle)` of the clone at `t_us`.
    Release { t_us: u64 },
    /// `inflate_velocity(velocity, accel_bias)`.
    Inflate { velocity: f64, accel_bias: f64 },
    /// `inflate_heading(sigma)`.
    InflateHeading { sigma: f64 },
    /// `inflate_position(delta)`.
    InflatePosition { delta: f64 },
}

/// Which list the next operation comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Op {
    Imu,
    Pose,
    Measurement,
}

/// A recording of filter operations since a snapshot (see the module doc). About 34 KB.
#[derive(Debug, Clone)]
pub struct Recorder {
    snapshot: Option<Ekf>,
    imu: [ImuSample; REPLAY_IMU],
    imu_count: usize,
    poses: [Option<(RelativePose, bool)>; REPLAY_POSES],
    pose_count: usize,
    measurements: [Option<Measurement>; REPLAY_MEASUREMENTS],
    measurement_count: usize,
    ops: [Op; REPLAY_OPS],
    op_count: usize,
    overflowed: bool,
    /// Replay in progress on the snapshot: next operation, IMU sample, relative pose and
    /// measurement.
    cursor: Option<(usize, usize, usize, usize)>,
}

/// State of a sliced replay ([`Recorder::replay_step`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplayProgress {
    /// No replay in progress.
    Idle,
    /// Operations remain; call again.
    Working,
    /// The snapshot caught up and is now the live filter; the recording has ended.
    Done,
    /// The recording overflowed before the replay caught up: the late measurement is lost and
    /// the live filter is unchanged (the recording has ended).
    Abandoned,
}

impl Default for Recorder {
    fn default() -> Self {
        Self::new()
    }
}

/// The zero IMU sample (`ImuSample::default()`, usable in a `const`).
const NO_SAMPLE: ImuSample = ImuSample {
    t_us: 0,
    gyro_rad_s: [0.0; 3],
    accel_m_s2: [0.0; 3],
    valid: false,
};

impl Recorder {
    /// An idle recorder (a compile-time value: the initialiser of a statically allocated
    /// navigator).
    pub const EMPTY: Self = Self {
        snapshot: None,
        imu: [NO_SAMPLE; REPLAY_IMU],
        imu_count: 0,
        poses: [None; REPLAY_POSES],
        pose_count: 0,
        measurements: [None; REPLAY_MEASUREMENTS],
        measurement_count: 0,
        ops: [Op::Imu; REPLAY_OPS],
        op_count: 0,
        overflowed: false,
        cursor: None,
    };

    /// An idle recorder.
    pub fn new() -> Self {
        Self::EMPTY
    }

    /// Make this recorder idle in place, as [`Self::new`] returns it (the 34 KB of lists are
    /// cleared in loops, not built as a temporary); a held snapshot is dropped.
    pub fn reset(&mut self) {
        self.snapshot = None;
        for s in self.imu.iter_mut() {
            *s = NO_SAMPLE;
        }
        self.imu_count = 0;
        for p in self.poses.iter_mut() {
            *p = None;
        }
        self.pose_count = 0;
        for m in self.measurements.iter_mut() {
            *m = None;
        }
        self.measurement_count = 0;
        for o in self.ops.iter_mut() {
            *o = Op::Imu;
        }
        self.op_count = 0;
        self.overflowed = false;
        self.cursor = None;
    }

    /// Start recording at the filter's current state (call right after cloning the capture).
    /// A recording in progress is abandoned.
    pub fn begin(&mut self, ekf: &Ekf) {
        match self.snapshot.as_mut() {
            Some(s) => s.copy_from(ekf),
            None => self.snapshot = Some(ekf.clone()),
        }
        self.imu_count = 0;
        self.pose_count = 0;
        self.measurement_count = 0;
        self.op_count = 0;
        self.overflowed = false;
        self.cursor = None;
    }

    /// True while a recording is in progress (and has not overflowed).
    pub fn active(&self) -> bool {
        self.snapshot.is_some() && !self.overflowed
    }

    /// The filter as it was at the start of the recording (the capture time), while a recording
    /// is in progress and no replay has started: a late measurement can be tested there (e.g.
    /// [`Ekf::gate_relative_pose`]) exactly as [`Self::start_late`] would apply it.
    pub fn snapshot(&self) -> Option<&Ekf> {
        self.snapshot
            .as_ref()
            .filter(|_| !self.overflowed && self.cursor.is_none())
    }

    /// True when the recording ran out of capacity (the late measurement cannot be replayed).
    pub fn overflowed(&self) -> bool {
        self.overflowed
    }

    /// Stop recording without replaying.
    pub fn end(&mut self) {
        self.snapshot = None;
        self.overflowed = false;
        self.cursor = None;
    }

    /// True while a sliced replay is in progress ([`Self::start_late`] was called and
    /// [`Self::replay_step`] has not finished it).
    pub fn replaying(&self) -> bool {
        self.snapshot.is_some() && self.cursor.is_some()
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
        if !self.active() {
            return;
        }
        if self.pose_count < REPLAY_POSES && self.push_op(Op::Pose) {
            if let Some(slot) = self.poses.get_mut(self.pose_count) {
                *slot = Some((*m, gated));
            }
            self.pose_count += 1;
        } else {
            self.overflowed = true;
        }
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

    /// Record `inflate_position(delta_m)`.
    pub fn inflate_position(&mut self, delta_m: f64) {
        self.measurement(Measurement::InflatePosition { delta: delta_m });
    }

    /// Record `inflate_heading(sigma_rad)`.
    pub fn inflate_heading(&mut self, sigma_rad: f64) {
        self.measurement(Measurement::InflateHeading { sigma: sigma_rad });
    }

    /// Record `inflate_velocity(velocity_sigma_m_s, accel_bias_sigma_m_s2)`.
    pub fn inflate_velocity(&mut self, velocity_sigma_m_s: f64, accel_bias_sigma_m_s2: f64) {
        self.measurement(Measurement::Inflate {
            velocity: velocity_sigma_m_s,
            accel_bias: accel_bias_sigma_m_s2,
        });
    }

    /// Restore the snapshot into `ekf`, apply the late measurement `m` there (gated or not),
    /// replay the recorded operations and end the recording. Returns the decision of `m`.
    /// Errors: no recording or an overflowed one ([`EstError::NoStateAtTime`]; `ekf` is then
    /// unchanged), or the filter's own errors on `m` (the replay still runs, so `ekf` is the
    /// recorded filter again). Operations that fail during the replay fail as they did live.
    /// The same as [`Self::start_late`] followed by [`Self::replay_step`] without a limit.
    pub fn apply_late(
        &mut self,
        ekf: &mut Ekf,
        m: &RelativePose,
        gated: bool,
    ) -> Result<GateDecision, EstError> {
        let decision = self.start_late(m, gated);
        if self.cursor.is_some() {
            let _ = self.replay_step(ekf, usize::MAX);
        }
        decision
    }

    /// First part of a sliced late update: applies `m` (gated or not) to the snapshot, at capture
    /// time, and starts the replay; the recording goes on. Returns the decision of `m`.
    /// Errors: no recording, an overflowed one or a replay already started
    /// ([`EstError::NoStateAtTime`]; the recording is then ended), or the filter's own errors
    /// on `m` (the replay still runs, as in [`Self::apply_late`]).
    pub fn start_late(&mut self, m: &RelativePose, gated: bool) -> Result<GateDecision, EstError> {
        let ready = !self.overflowed && self.cursor.is_none();
        let Some(snapshot) = self.snapshot.as_mut().filter(|_| ready) else {
            self.end();
            return Err(EstError::NoStateAtTime { t_us: m.t1_us });
        };
        let decision = snapshot.update_relative_pose(m, gated);
        self.cursor = Some((0, 0, 0, 0));
        decision
    }

    /// Replays at most `max_ops` recorded operations on the snapshot (at least one). When the
    /// snapshot has caught up with the recording it is copied into `ekf` (the live filter) and
    /// the recording ends ([`ReplayProgress::Done`]).
    pub fn replay_step(&mut self, ekf: &mut Ekf, max_ops: usize) -> ReplayProgress {
        let Some((mut op, mut i, mut p, mut k)) = self.cursor else {
            return ReplayProgress::Idle;
        };
        if self.overflowed {
            self.end();
            return ReplayProgress::Abandoned;
        }
        let Some(snapshot) = self.snapshot.as_mut() else {
            self.end();
            return ReplayProgress::Idle;
        };
        let stop = op.saturating_add(max_ops.max(1)).min(self.op_count);
        for kind in self.ops.get(op..stop).unwrap_or(&[]) {
            match kind {
                Op::Imu => {
                    if let Some(s) = self.imu.get(i) {
                        let _ = snapshot.propagate(s);
                    }
                    i += 1;
                }
                Op::Pose => {
                    if let Some(Some((m, gated))) = self.poses.get(p) {
                        let _ = snapshot.update_relative_pose(m, *gated);
                    }
                    p += 1;
                }
                Op::Measurement => {
                    if let Some(Some(meas)) = self.measurements.get(k) {
                        replay_one(snapshot, meas);
                    }
                    k += 1;
                }
            }
            op += 1;
        }
        if op >= self.op_count {
            ekf.copy_from(snapshot);
            self.end();
            ReplayProgress::Done
        } else {
            self.cursor = Some((op, i, p, k));
            ReplayProgress::Working
        }
    }
}

fn replay_one(ekf: &mut Ekf, m: &Measurement) {
    match m {
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
        Measurement::Inflate {
            velocity,
            accel_bias,
        } => {
            let _ = ekf.inflate_velocity(*velocity, *accel_bias);
        }
        Measurement::InflateHeading { sigma } => {
            let _ = ekf.inflate_heading(*sigma);
        }
        Measurement::InflatePosition { delta } => {
            let _ = ekf.inflate_position(*delta);
        }
    }
}
