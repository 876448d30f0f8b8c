//! Stochastic cloning (H04 sec. 4, "Augmented-state propagation", eq. 41).
//!
//! A clone is a copy of the attitude and position of the state at a time stamp (a stereo
//! capture, the start of a kinematic interval), with its covariance block duplicated from the
//! current state (`P~ = [[P, P], [P, P]]`). Propagation leaves clone blocks unchanged and carries
//! the cross-covariance `F P_kk` (eq. 41) by multiplying the clone columns by `F_k` each step.
//! Clones are reference counted: two users cloning the same time stamp share one slot, and the
//! slot is freed when the last of them releases it.

use super::state::{clone_index, CLONE_DIM, DIM, I_P, I_THETA, MAX_CLONES};
use super::{Ekf, EstError};
use crate::types::{Quat, Vec3};

/// A handle to a live clone: its slot and the serial number it was issued with (a released
/// and reused slot does not answer to an old handle).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CloneHandle {
    slot: u8,
    serial: u32,
    t_us: u64,
}

impl CloneHandle {
    /// The clone's time stamp, microseconds since boot.
    pub fn t_us(&self) -> u64 {
        self.t_us
    }
}

/// One cloned state: attitude and position at `t_us` (the rows `[dtheta_i, dp_i]` of `P`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CloneSlot {
    pub t_us: u64,
    pub q_nr: Quat,
    pub p_n: Vec3,
    pub refs: u16,
    pub serial: u32,
}

impl Ekf {
    /// Clone the state at `t_us` (a stereo capture or the start of a kinematic interval) and
    /// return its handle. `t_us` may lie after the state time (the state is then propagated to
    /// it with the last IMU sample held) but not before it ([`EstError::TimeBackwards`]). If a
    /// clone at `t_us` exists its reference count is increased and the same handle returned.
    pub fn clone_at(&mut self, t_us: u64) -> Result<CloneHandle, EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        self.touch();
        if let Some((slot, c)) = self.find_clone(t_us) {
            if let Some(Some(live)) = self.clones.get_mut(slot) {
                live.refs = live.refs.saturating_add(1);
            }
            return Ok(CloneHandle {
                slot: slot as u8,
                serial: c.serial,
                t_us,
            });
        }
        let slot = self
            .clones
            .iter()
            .position(|c| c.is_none())
            .ok_or(EstError::CloneWindowFull)?;
        self.propagate_held(t_us)?;
        let serial = self.next_serial;
        self.next_serial = self.next_serial.wrapping_add(1);
        let i = clone_index(slot);
        // Rows and columns [dtheta, dp] of the current state copied into the clone block.
        // `slot` comes from the clone array, so `i + 5 < DIM`; the accesses are checked anyway
        // (no panic path).
        for (dst, src) in [(i, I_THETA), (i + 3, I_P)] {
            for k in 0..3 {
                for j in 0..DIM {
                    if let Some(v) = self.p.get((src + k, j)).copied() {
                        if let Some(d) = self.p.get_mut((dst + k, j)) {
                            *d = v;
                        }
                    }
                }
            }
        }
        for (dst, src) in [(i, I_THETA), (i + 3, I_P)] {
            for k in 0..3 {
                for j in 0..DIM {
                    if let Some(v) = self.p.get((j, src + k)).copied() {
                        if let Some(d) = self.p.get_mut((j, dst + k)) {
                            *d = v;
                        }
                    }
                }
            }
        }
        if let Some(c) = self.clones.get_mut(slot) {
            *c = Some(CloneSlot {
                t_us,
                q_nr: self.x.q_nr,
                p_n: self.x.p_n,
                refs: 1,
                serial,
            });
        }
        Ok(CloneHandle {
            slot: slot as u8,
            serial,
            t_us,
        })
    }

    /// Release one reference to a clone; the slot and its covariance rows and columns are
    /// cleared when no reference remains. A stale handle is refused ([`EstError::UnknownClone`]).
    pub fn release(&mut self, handle: CloneHandle) -> Result<(), EstError> {
        let slot = usize::from(handle.slot);
        let free = match self.clones.get_mut(slot) {
            Some(Some(c)) if c.serial == handle.serial => {
                c.refs = c.refs.saturating_sub(1);
                c.refs == 0
            }
            _ => return Err(EstError::UnknownClone),
        };
        if free {
            self.touch();
            if let Some(c) = self.clones.get_mut(slot) {
                *c = None;
            }
            let i = clone_index(slot);
            // P is column-major: the clone's columns are one contiguous run, its rows six
            // entries of every column (plain slice fills instead of strided views).
            let p = self.p.as_mut_slice();
            if let Some(cols) = p.get_mut(i * DIM..(i + CLONE_DIM) * DIM) {
                cols.fill(0.0);
            }
            for col in p.chunks_exact_mut(DIM) {
                if let Some(rows) = col.get_mut(i..i + CLONE_DIM) {
                    rows.fill(0.0);
                }
            }
        }
        Ok(())
    }

    /// The handle of the live clone at `t_us`, if any (one more reference is not taken).
    pub fn clone_handle(&self, t_us: u64) -> Option<CloneHandle> {
        self.find_clone(t_us).map(|(slot, c)| CloneHandle {
            slot: slot as u8,
            serial: c.serial,
            t_us,
        })
    }

    /// Attitude (`q_nr`) and position (m, `N`) of a live clone.
    pub fn clone_pose(&self, handle: CloneHandle) -> Result<(Quat, Vec3), EstError> {
        match self.clones.get(usize::from(handle.slot)) {
            Some(Some(c)) if c.serial == handle.serial => Ok((c.q_nr, c.p_n)),
            _ => Err(EstError::UnknownClone),
        }
    }

    /// Number of live clones.
    pub fn clone_count(&self) -> usize {
        self.clones.iter().filter(|c| c.is_some()).count()
    }

    pub(crate) fn find_clone(&self, t_us: u64) -> Option<(usize, CloneSlot)> {
        self.clones
            .iter()
            .enumerate()
            .find_map(|(s, c)| c.filter(|c| c.t_us == t_us).map(|c| (s, c)))
    }

    pub(crate) fn live_mask(&self) -> [bool; MAX_CLONES] {
        let mut m = [false; MAX_CLONES];
        for (o, c) in m.iter_mut().zip(self.clones.iter()) {
            *o = c.is_some();
        }
        m
    }
}
