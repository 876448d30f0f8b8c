//! Obstacle memory of the planner: the convex polygons seen so far, at fixed capacity.
//!
//! V99 sec. 4 renews RoverBug's local model at every step ("no information is passed between
//! steps" other than recorded points). This planner keeps what the cameras saw instead, because
//! its wedge (80 deg) is narrower than the directions it must check while it slides along an
//! obstacle; see `docs/planning.md` for the consequences.

use super::geometry::{dist, ConvexPolygon, MAX_INPUT_POINTS, MAX_VERTICES};
use crate::guidance::Point2;
use heapless::Vec;

/// Removes element `i` of `v`, keeping the order of the others (`heapless::Vec::remove`
/// without its panic: an index out of range removes nothing and returns false).
fn remove_at<T, const N: usize>(v: &mut Vec<T, N>, i: usize) -> bool {
    let n = v.len();
    if i >= n {
        return false;
    }
    let s = v.as_mut_slice();
    // Bounded: at most N - 1 swaps move element i to the end.
    for k in i..n - 1 {
        if let Some(pair) = s.get_mut(k..k + 2) {
            if let Ok([a, b]) = <&mut [T; 2]>::try_from(pair) {
                core::mem::swap(a, b);
            }
        }
    }
    v.pop().is_some()
}

/// Most remembered polygons.
pub const MEMORY_CAPACITY: usize = 32;

/// A new polygon overlapping a remembered one by at least this fraction of the smaller area
/// is the same obstacle seen again: the two are replaced by the convex hull of both.
pub const MERGE_OVERLAP_FRACTION: f64 = 0.5;

/// A merge may not make the hull larger than the union of the two polygons by more than this
/// fraction of the smaller polygon's area.
pub const MERGE_FILL_FRACTION: f64 = 0.1;

/// What [`ObstacleMemory::insert`] did with a polygon.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InsertOutcome {
    /// Stored in a free slot (index).
    Added(usize),
    /// Merged with the remembered polygon at this index (hull of both).
    Merged(usize),
    /// Memory full: replaced the polygon farthest from the rover (index).
    Evicted(usize),
    /// Memory full and the new polygon is the farthest: not stored.
    Dropped,
    /// The inflated polygon could not be formed (vertex sharper than 0.1 deg).
    Rejected,
}

/// Counts of [`InsertOutcome`]s since the memory was created or cleared.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MemoryStats {
    /// Polygons stored in a free slot.
    pub added: u32,
    /// Polygons merged with a remembered one.
    pub merged: u32,
    /// Remembered polygons replaced because the memory was full (overflow).
    pub evicted: u32,
    /// New polygons not stored because the memory was full (overflow).
    pub dropped: u32,
    /// Polygons refused.
    pub rejected: u32,
}

/// The remembered obstacles: each as seen (grown by the rover half-width by perception) and
/// inflated by the planner's clearance (what the planner keeps out of), with a connected-
/// component label over the inflated polygons (touching or overlapping polygons form one
/// obstacle, the "obstacle O" that boundary following goes round).
#[derive(Debug, Clone)]
pub struct ObstacleMemory {
    grown: Vec<ConvexPolygon, MEMORY_CAPACITY>,
    inflated: Vec<ConvexPolygon, MEMORY_CAPACITY>,
    component: [u8; MEMORY_CAPACITY],
    clearance_m: f64,
    components_stale: bool,
    stats: MemoryStats,
}

impl ObstacleMemory {
    /// Make this memory `new(clearance_m)` in place (the polygon lists are emptied, not rebuilt
    /// as a temporary).
    pub fn reset(&mut self, clearance_m: f64) {
        self.grown.clear();
        self.inflated.clear();
        self.component.fill(0);
        self.clearance_m = Self::valid_clearance(clearance_m);
        self.components_stale = false;
        self.stats = MemoryStats {
            added: 0,
            merged: 0,
            evicted: 0,
            dropped: 0,
            rejected: 0,
        };
    }

    /// `clearance_m` when finite and at least 0, else 0.
    const fn valid_clearance(clearance_m: f64) -> f64 {
        if clearance_m.is_finite() && clearance_m >= 0.0 {
            clearance_m
        } else {
            0.0
        }
    }

    /// An empty memory whose polygons are inflated by `clearance_m` (m, finite, at least 0;
    /// other values are taken as 0).
    pub const fn new(clearance_m: f64) -> Self {
        let clearance_m = Self::valid_clearance(clearance_m);
        Self {
            grown: Vec::new(),
            inflated: Vec::new(),
            component: [0; MEMORY_CAPACITY],
            clearance_m,
            components_stale: false,
            stats: MemoryStats {
                added: 0,
                merged: 0,
                evicted: 0,
                dropped: 0,
                rejected: 0,
            },
        }
    }

    /// Forgets every polygon (the counts are kept).
    pub fn clear(&mut self) {
        self.grown.clear();
        self.inflated.clear();
        self.components_stale = false;
    }

    /// Number of remembered polygons.
    pub fn len(&self) -> usize {
        self.grown.len()
    }

    /// True when nothing is remembered.
    pub fn is_empty(&self) -> bool {
        self.grown.is_empty()
    }

    /// The polygons as delivered (after merging), m in `N`.
    pub fn grown(&self) -> &[ConvexPolygon] {
        &self.grown
    }

    /// The polygons inflated by the clearance, m in `N` (what paths keep out of).
    pub fn inflated(&self) -> &[ConvexPolygon] {
        &self.inflated
    }

    /// Component label of polygon `i` (the smallest index in its component; 255 when out of
    /// range). Labels are valid after [`Self::refresh_components`].
    pub fn component(&self, i: usize) -> u8 {
        self.component.get(i).copied().unwrap_or(u8::MAX)
    }

    /// Insertion counts.
    pub fn stats(&self) -> MemoryStats {
        self.stats
    }

    /// Index of the first remembered grown polygon with `p` inside (deeper than the boundary
    /// tolerance), if any (used for "goal inside an obstacle").
    pub fn grown_containing(&self, p: Point2) -> Option<usize> {
        self.grown
            .iter()
            .position(|g| g.locate(p) == super::geometry::PointLocation::Inside)
    }

    /// Stores `polygon` (grown obstacle in `N`, m), merging it with a remembered polygon it
    /// overlaps by at least [`MERGE_OVERLAP_FRACTION`] of the smaller area. When the memory is
    /// full, the polygon farthest from `rover` is replaced (or the new one dropped if it is the
    /// farthest); both are counted (defined overflow response). Polygons of the component
    /// holding `protected` (the followed obstacle's reference point) are replaced last.
    pub fn insert(
        &mut self,
        polygon: &ConvexPolygon,
        rover: Point2,
        protected: Option<Point2>,
    ) -> InsertOutcome {
        let outcome = self.insert_inner(polygon, rover, protected);
        match outcome {
            InsertOutcome::Added(_) => self.stats.added = self.stats.added.saturating_add(1),
            InsertOutcome::Merged(_) => self.stats.merged = self.stats.merged.saturating_add(1),
            InsertOutcome::Evicted(_) => self.stats.evicted = self.stats.evicted.saturating_add(1),
            InsertOutcome::Dropped => self.stats.dropped = self.stats.dropped.saturating_add(1),
            InsertOutcome::Rejected => self.stats.rejected = self.stats.rejected.saturating_add(1),
        }
        if !matches!(outcome, InsertOutcome::Dropped | InsertOutcome::Rejected) {
            self.components_stale = true;
        }
        outcome
    }

    fn insert_inner(
        &mut self,
        polygon: &ConvexPolygon,
        rover: Point2,
        protected: Option<Point2>,
    ) -> InsertOutcome {
        let new_area = polygon.area_m2();
        for (i, stored) in self.grown.iter().enumerate() {
            if dist(stored.center(), polygon.center()) > stored.radius_m() + polygon.radius_m() {
                continue;
            }
            let overlap = polygon.intersection_area_m2(stored);
            if overlap < MERGE_OVERLAP_FRACTION * new_area.min(stored.area_m2()) {
                continue;
            }
            let mut pts = [[0.0; 2]; 2 * MAX_VERTICES];
            let mut n = 0;
            for (slot, p) in pts
                .iter_mut()
                .zip(stored.vertices().iter().chain(polygon.vertices().iter()))
            {
                *slot = *p;
                n += 1;
            }
            let Ok(merged) =
                ConvexPolygon::from_points(pts.get(..n.min(MAX_INPUT_POINTS)).unwrap_or(&[]))
            else {
                continue;
            };
            // The hull must not fill free space: it may exceed the union of the two by at most
            // MERGE_FILL_FRACTION of the smaller one (else obstacles in an L or along an arc
            // would become one convex blob, growing merge after merge, that can swallow the
            // goal; relative to the smaller, the fill of a long merged blob stops the creep).
            let union = new_area + stored.area_m2() - overlap;
            let fill = merged.area_m2() - union;
            if fill > MERGE_FILL_FRACTION * new_area.min(stored.area_m2()) {
                continue;
            }
            let Ok(inflated) = merged.inflate(self.clearance_m) else {
                return InsertOutcome::Rejected;
            };
            if let (Some(g), Some(q)) = (self.grown.get_mut(i), self.inflated.get_mut(i)) {
                *g = merged;
                *q = inflated;
            }
            return InsertOutcome::Merged(self.absorb_contained(i));
        }
        let Ok(inflated) = polygon.inflate(self.clearance_m) else {
            return InsertOutcome::Rejected;
        };
        if self.grown.len() < MEMORY_CAPACITY {
            let index = self.grown.len();
            if self.grown.push(polygon.clone()).is_err() || self.inflated.push(inflated).is_err() {
                return InsertOutcome::Dropped;
            }
            return InsertOutcome::Added(index);
        }
        // Full: the farthest remembered polygon gives way to a nearer new one; polygons of the
        // protected component (the followed obstacle) go last.
        let protected_label = protected.and_then(|p| {
            self.inflated
                .iter()
                .position(|q| q.locate(p) != super::geometry::PointLocation::Outside)
                .map(|i| self.component(i))
        });
        let mut farthest: Option<(usize, bool, f64)> = None;
        for (i, g) in self.grown.iter().enumerate() {
            let d = g.distance(rover);
            let keep = protected_label.is_some_and(|l| self.component(i) == l);
            if farthest.is_none_or(|(_, fk, f)| (!keep && fk) || (keep == fk && d > f)) {
                farthest = Some((i, keep, d));
            }
        }
        let farthest = farthest.map(|(i, _, d)| (i, d));
        match farthest {
            Some((i, d)) if polygon.distance(rover) < d => {
                if let (Some(g), Some(q)) = (self.grown.get_mut(i), self.inflated.get_mut(i)) {
                    *g = polygon.clone();
                    *q = inflated;
                }
                InsertOutcome::Evicted(i)
            }
            _ => InsertOutcome::Dropped,
        }
    }

    /// Removes remembered polygons (other than `keep`) that lie inside polygon `keep` (earlier
    /// partial views of an obstacle now seen whole). Returns the new index of `keep`.
    fn absorb_contained(&mut self, keep: usize) -> usize {
        let Some(big) = self.grown.get(keep).cloned() else {
            return keep;
        };
        let mut index = keep;
        let mut i = self.grown.len();
        while i > 0 {
            i -= 1;
            if i == keep {
                continue;
            }
            let Some(small) = self.grown.get(i) else {
                continue;
            };
            let inside = small
                .vertices()
                .iter()
                .all(|v| big.locate(*v) != super::geometry::PointLocation::Outside);
            // Both lists have the same length (they are pushed and removed together);
            // `remove_at` has no out-of-bounds panic path.
            if inside {
                remove_at(&mut self.grown, i);
                remove_at(&mut self.inflated, i);
                if i < keep {
                    index -= 1;
                }
            }
        }
        index
    }

    /// Recomputes the component labels when the memory changed: union-find over pairs of
    /// inflated polygons that overlap or touch (separating-axis test), at most
    /// `MEMORY_CAPACITY^2 / 2` pair tests.
    pub fn refresh_components(&mut self) {
        if !self.components_stale {
            return;
        }
        self.components_stale = false;
        let n = self.inflated.len();
        let mut parent = [0u8; MEMORY_CAPACITY];
        for (i, p) in parent.iter_mut().enumerate() {
            *p = i as u8;
        }
        let find = |parent: &[u8; MEMORY_CAPACITY], mut i: usize| {
            // Depth is below the capacity: every union links a root to a smaller root.
            for _ in 0..MEMORY_CAPACITY {
                let p = parent.get(i).copied().unwrap_or(0) as usize;
                if p == i {
                    break;
                }
                i = p;
            }
            i
        };
        for i in 0..n {
            for j in (i + 1)..n {
                let (Some(a), Some(b)) = (self.inflated.get(i), self.inflated.get(j)) else {
                    continue;
                };
                if a.overlaps(b, super::geometry::EPS_M) {
                    let (ri, rj) = (find(&parent, i), find(&parent, j));
                    let (lo, hi) = if ri < rj { (ri, rj) } else { (rj, ri) };
                    if let Some(slot) = parent.get_mut(hi) {
                        *slot = lo as u8;
                    }
                }
            }
        }
        for i in 0..n {
            let r = find(&parent, i);
            if let Some(slot) = self.component.get_mut(i) {
                *slot = r as u8;
            }
        }
    }
}
