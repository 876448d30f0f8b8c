//! Boundary following (V99 sec. 4): the followed obstacle, its arc of directions seen from the
//! rover, the tangent vertex on the following side (virtual sliding), and the winding count
//! of the loop test.

use super::{BlockedReason, FollowState, Mode, PlanStatus, Planner, Side, UnreachableReason};
use crate::guidance::{wrap_pi, Point2};
use crate::planning::geometry::{dist, yaw, PointLocation};
use crate::planning::ltg::disc_exit;
use crate::planning::memory::{ObstacleMemory, MEMORY_CAPACITY};
use core::f64::consts::PI;

/// Angular tolerance of the obstacle arc union, rad.
const ARC_TOL_RAD: f64 = 1e-6;

/// A tangent vertex of the followed obstacle: (memory index, vertex index).
pub(super) type VertexRef = (usize, usize);

pub(super) enum Arc {
    Span {
        lo: VertexRef,
        hi: VertexRef,
        lo_rad: f64,
        hi_rad: f64,
    },
    Enclosed,
    Empty,
}

/// The directions under which the connected obstacle `label` is seen from `p`: union of its
/// polygons' angular intervals (a connected set is seen under a connected arc).
pub(super) fn component_arc(memory: &ObstacleMemory, label: u8, p: Point2) -> Arc {
    let inflated = memory.inflated();
    let mut iv = [(0.0f64, 0.0f64, 0usize, 0usize); MEMORY_CAPACITY];
    let mut member = [false; MEMORY_CAPACITY];
    let mut seed: Option<(usize, f64)> = None;
    for (i, poly) in inflated.iter().enumerate() {
        if memory.component(i) != label {
            continue;
        }
        let Some(a) = poly.angular_interval(p) else {
            continue;
        };
        if let (Some(slot), Some(m)) = (iv.get_mut(i), member.get_mut(i)) {
            *slot = (a.lo_rad, a.hi_rad, a.lo_vertex, a.hi_vertex);
            *m = true;
        }
        let d = poly.distance(p);
        if seed.is_none_or(|(_, best)| d < best) {
            seed = Some((i, d));
        }
    }
    let Some((s, _)) = seed else {
        return Arc::Empty;
    };
    let vdist = |r: VertexRef| {
        inflated
            .get(r.0)
            .map_or(0.0, |poly| dist(poly.vertex(r.1), p))
    };
    let (s_lo, s_hi, s_lv, s_hv) = iv.get(s).copied().unwrap_or((0.0, 0.0, 0, 0));
    let (mut lo, mut hi) = (s_lo, s_hi);
    let (mut lo_v, mut hi_v) = ((s, s_lv), (s, s_hv));
    let mut merged = [false; MEMORY_CAPACITY];
    if let Some(m) = merged.get_mut(s) {
        *m = true;
    }
    for _pass in 0..MEMORY_CAPACITY {
        let mut changed = false;
        for j in 0..inflated.len() {
            if !member.get(j).copied().unwrap_or(false) || merged.get(j).copied().unwrap_or(true) {
                continue;
            }
            let (a, b, lv, hv) = iv.get(j).copied().unwrap_or((0.0, 0.0, 0, 0));
            let k = libm::round((0.5 * (lo + hi) - 0.5 * (a + b)) / (2.0 * PI));
            let shifts = [k, k - 1.0, k + 1.0];
            let Some(shift) = shifts
                .iter()
                .map(|k| 2.0 * PI * k)
                .find(|sh| a + sh <= hi + ARC_TOL_RAD && b + sh >= lo - ARC_TOL_RAD)
            else {
                continue;
            };
            let (a, b) = (a + shift, b + shift);
            if a < lo - 1e-12 || (a <= lo + 1e-12 && vdist((j, lv)) > vdist(lo_v)) {
                lo = a;
                lo_v = (j, lv);
            }
            if b > hi + 1e-12 || (b >= hi - 1e-12 && vdist((j, hv)) > vdist(hi_v)) {
                hi = b;
                hi_v = (j, hv);
            }
            if let Some(m) = merged.get_mut(j) {
                *m = true;
            }
            changed = true;
        }
        if !changed {
            break;
        }
    }
    if hi - lo >= 2.0 * PI - ARC_TOL_RAD {
        return Arc::Enclosed;
    }
    Arc::Span {
        lo: lo_v,
        hi: hi_v,
        lo_rad: lo,
        hi_rad: hi,
    }
}

impl Planner {
    pub(super) fn vertex_point(&self, v: VertexRef) -> Point2 {
        self.memory
            .inflated()
            .get(v.0)
            .map_or([0.0; 2], |p| p.vertex(v.1))
    }

    /// Memory index of the polygon holding the follow reference point.
    pub(super) fn followed_label(&self) -> Option<u8> {
        let f = self.follow?;
        self.memory
            .inflated()
            .iter()
            .position(|p| p.locate(f.reference) != PointLocation::Outside)
            .map(|i| self.memory.component(i))
    }

    /// Starts (or resumes) boundary following at `start`. `Ok(false)` when no obstacle is near.
    pub(super) fn begin_follow(
        &mut self,
        start: Point2,
        target: Point2,
        radius: f64,
        heading_rad: f64,
    ) -> Result<bool, PlanStatus> {
        // The blocking polygon: the first hit on the way to the goal, else the nearest.
        let exit = if dist(start, target) <= radius {
            target
        } else {
            disc_exit(start, radius, start, target)
        };
        let mut seed: Option<(usize, f64)> = None;
        for &i in self.local.iter() {
            let Some(poly) = self.memory.inflated().get(i as usize) else {
                continue;
            };
            if let Some((t0, _)) = poly.clip_segment(start, exit) {
                if poly.segment_hits_interior(start, exit) && seed.is_none_or(|(_, b)| t0 < b) {
                    seed = Some((i as usize, t0));
                }
            }
        }
        if seed.is_none() {
            for &i in self.local.iter() {
                let Some(poly) = self.memory.inflated().get(i as usize) else {
                    continue;
                };
                let d = 1.0 + poly.distance(start);
                if seed.is_none_or(|(_, b)| d < b) {
                    seed = Some((i as usize, d));
                }
            }
        }
        let Some((seed, _)) = seed else {
            return Ok(false);
        };
        let label = self.memory.component(seed);
        self.mode = Mode::BoundaryFollowing;
        // Re-blocked by the same obstacle without progress since: resume the episode.
        if let Some(f) = self.follow {
            if self.followed_label() == Some(label)
                && self.d_min_m >= f.d_min_at_start_m - self.config.progress_epsilon_m
            {
                self.counters.follow_resumes = self.counters.follow_resumes.saturating_add(1);
                return Ok(true);
            }
        }
        let Some(poly) = self.memory.inflated().get(seed) else {
            return Ok(false);
        };
        let reference = poly.center();
        let side = match component_arc(&self.memory, label, start) {
            Arc::Enclosed => return Err(PlanStatus::Unreachable(UnreachableReason::Enclosed)),
            Arc::Empty => return Ok(false),
            Arc::Span {
                lo,
                hi,
                lo_rad,
                hi_rad,
            } => {
                let (p_lo, p_hi) = (self.vertex_point(lo), self.vertex_point(hi));
                let h_lo = dist(start, p_lo) + dist(p_lo, target);
                let h_hi = dist(start, p_hi) + dist(p_hi, target);
                if libm::fabs(h_hi - h_lo) <= 1e-6 {
                    // Tie: the side needing less turn from the current heading.
                    if libm::fabs(wrap_pi(hi_rad - heading_rad))
                        <= libm::fabs(wrap_pi(lo_rad - heading_rad))
                    {
                        Side::Left
                    } else {
                        Side::Right
                    }
                } else if h_hi < h_lo {
                    Side::Left
                } else {
                    Side::Right
                }
            }
        };
        self.follow = Some(FollowState {
            start,
            reference,
            side,
            winding_rad: 0.0,
            last_angle_rad: yaw(reference, start),
            followed_m: 0.0,
            d_min_at_start_m: self.d_min_m,
        });
        self.counters.follow_entries = self.counters.follow_entries.saturating_add(1);
        Ok(true)
    }

    pub(super) fn update_winding(&mut self, p: Point2) {
        if let Some(f) = self.follow.as_mut() {
            let a = yaw(f.reference, p);
            f.winding_rad += wrap_pi(a - f.last_angle_rad);
            f.last_angle_rad = a;
        }
    }

    /// The tangent vertex of the followed obstacle on the following side, seen from `p`
    /// (virtual sliding: as far round the border as is visible from `p`).
    pub(super) fn follow_target(&mut self, p: Point2) -> Result<VertexRef, PlanStatus> {
        let Some(f) = self.follow else {
            return Err(PlanStatus::Blocked(BlockedReason::NoPath));
        };
        let Some(label) = self.followed_label() else {
            return Err(PlanStatus::Blocked(
                BlockedReason::BoundaryTargetUnreachable,
            ));
        };
        match component_arc(&self.memory, label, p) {
            Arc::Span { lo, hi, .. } => Ok(match f.side {
                Side::Left => hi,
                Side::Right => lo,
            }),
            Arc::Enclosed => Err(PlanStatus::Unreachable(UnreachableReason::Enclosed)),
            Arc::Empty => Err(PlanStatus::Blocked(
                BlockedReason::BoundaryTargetUnreachable,
            )),
        }
    }
}
