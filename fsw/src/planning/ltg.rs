//! Local tangent graph (LTG, V99 sec. 4) and its shortest paths.
//!
//! V99: "The tangent graph consists of all line segments in freespace connecting the initial
//! position, the goal, and all obstacle vertices, such that the segments are tangent to any
//! obstacles they encounter. A line l is tangent to an obstacle O at a vertex x iff in a
//! neighborhood of x, the interior of O lies entirely on one side of l. The local tangent graph
//! (LTG) is the tangent graph restricted to the visible region."
//!
//! Nodes: the start (the rover) and every vertex of the local polygons (those near the rover)
//! that is not inside another polygon. Edges: segments that do not pass through any remembered
//! polygon's interior and are tangent to the polygon at each vertex end. Shortest paths from the start: Dijkstra with a
//! linear scan for the next node (no heap, at most [`MAX_NODES`] settles of at most
//! [`MAX_NODES`] relaxations each). The goal enters through [`LocalTangentGraph::candidates`]:
//! every settled node `n` inside the visible disc whose straight ray towards the goal is free up
//! to the goal or to the disc's edge is a way on, scored by TangentBug's heuristic
//! `d(start, n) + d(n, T)` with `d(start, n)` measured along the graph.

use super::geometry::{
    add_scaled, cross, dist, dot, norm, sub, ConvexPolygon, PointLocation, EPS_M, MAX_VERTICES,
};
use crate::guidance::Point2;

/// Most polygons in one LTG (the nearest to the rover).
pub const LOCAL_CAPACITY: usize = 16;

/// Most LTG nodes: the start and every vertex of every local polygon.
pub const MAX_NODES: usize = 1 + LOCAL_CAPACITY * MAX_VERTICES;

/// A node within this distance of the sticky point is the sticky node, m.
pub const STICKY_MATCH_M: f64 = 1e-3;

/// Marks the start node in [`LocalTangentGraph`]'s owner table.
const START_OWNER: u8 = u8::MAX;

/// Work counts of one LTG solution (bounded by `MAX_NODES^2`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LtgStats {
    /// Valid nodes.
    pub nodes: u32,
    /// Node pairs examined.
    pub pairs: u32,
    /// Pairs that passed the tangency and cost tests and had their segment checked against
    /// every local polygon.
    pub segment_checks: u32,
}

/// A way on towards the goal found in the LTG.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// LTG node the ray to the goal leaves from.
    pub node: usize,
    /// Where the free ray ends: the goal when it is inside the visible disc, else the point
    /// where the ray leaves the disc, m in `N`.
    pub exit: Point2,
    /// TangentBug heuristic `d(start, node) + d(node, T)`, m.
    pub cost_m: f64,
    /// `d(exit, T)`, m: how close to the goal this way reaches inside the visible disc.
    pub reach_m: f64,
}

/// What [`LocalTangentGraph::candidates`] looks for (m, in `N`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CandidateQuery {
    /// Centre of the visible disc (the rover).
    pub center: Point2,
    /// Radius of the visible disc (the sensor range R).
    pub radius_m: f64,
    /// The goal `T`.
    pub goal: Point2,
    /// Progress threshold: `d_min` (motion-to-goal) or `d_followed` (boundary following).
    pub threshold_m: f64,
    /// Margin below the threshold that counts as progress.
    pub epsilon_m: f64,
    /// The way-on node chosen at the last step, if binding.
    pub sticky: Option<Point2>,
}

/// The ways on of one LTG.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CandidateSummary {
    /// The cheapest candidate (by `cost_m`) among those with `reach_m < d_min - epsilon` or
    /// that reach the goal itself, i.e. that make progress (V99: "monotonic progress toward
    /// the goal").
    pub best: Option<Candidate>,
    /// `d_reach`: the smallest `reach_m` over every candidate, m (infinite when none).
    pub d_reach_m: f64,
    /// Number of candidates (free rays), progressing or not.
    pub count: u32,
    /// The progressing candidate at the `sticky` node, if any (the way on chosen at the last
    /// step; it stays eligible when it has drifted out of the disc).
    pub sticky: Option<Candidate>,
}

/// True when the segment `a`-`b` passes through the interior of none of `polygons`.
pub fn segment_clear(polygons: &[ConvexPolygon], a: Point2, b: Point2) -> bool {
    !polygons.iter().any(|p| p.segment_hits_interior(a, b))
}

/// True when the line through vertex `i` of `polygon` and the point `q` is tangent to the
/// polygon at that vertex: both neighbouring vertices lie on one side of it (or on it).
pub fn tangent_at_vertex(polygon: &ConvexPolygon, i: usize, q: Point2) -> bool {
    let n = polygon.len();
    let p = polygon.vertex(i);
    let d = sub(q, p);
    let l = norm(d);
    if l <= EPS_M {
        return true;
    }
    let a = sub(polygon.vertex(i + n - 1), p);
    let b = sub(polygon.vertex(i + 1), p);
    let (ca, cb) = (cross(d, a), cross(d, b));
    let (ta, tb) = (1e-9 * l * norm(a), 1e-9 * l * norm(b));
    (ca >= -ta && cb >= -tb) || (ca <= ta && cb <= tb)
}

/// Scratch and result of one LTG shortest-path solution (fixed size, no allocation).
#[derive(Debug, Clone)]
pub struct LocalTangentGraph {
    points: [Point2; MAX_NODES],
    owner: [u8; MAX_NODES],
    vertex: [u8; MAX_NODES],
    valid: [bool; MAX_NODES],
    settled: [bool; MAX_NODES],
    cost: [f64; MAX_NODES],
    prev: [u16; MAX_NODES],
    len: usize,
    stats: LtgStats,
}

impl Default for LocalTangentGraph {
    fn default() -> Self {
        Self::new()
    }
}

impl LocalTangentGraph {
    /// Make this graph [`Self::new`] in place (arrays refilled, not rebuilt as a temporary).
    pub fn reset(&mut self) {
        self.points.fill([0.0; 2]);
        self.owner.fill(START_OWNER);
        self.vertex.fill(0);
        self.valid.fill(false);
        self.settled.fill(false);
        self.cost.fill(f64::INFINITY);
        self.prev.fill(0);
        self.len = 0;
        self.stats = LtgStats {
            nodes: 0,
            pairs: 0,
            segment_checks: 0,
        };
    }

    /// An empty graph.
    pub const fn new() -> Self {
        Self {
            points: [[0.0; 2]; MAX_NODES],
            owner: [START_OWNER; MAX_NODES],
            vertex: [0; MAX_NODES],
            valid: [false; MAX_NODES],
            settled: [false; MAX_NODES],
            cost: [f64::INFINITY; MAX_NODES],
            prev: [0; MAX_NODES],
            len: 0,
            stats: LtgStats {
                nodes: 0,
                pairs: 0,
                segment_checks: 0,
            },
        }
    }

    /// Builds the graph with the vertices of `polygons` (the local ones, at most
    /// [`LOCAL_CAPACITY`]; more are ignored) as nodes and solves the shortest paths from
    /// `start` (m, in `N`). Edges and node validity are checked against every polygon of
    /// `obstacles` (all remembered ones: an edge may reach beyond the local disc). `start`
    /// should be outside every polygon or on a boundary (the planner moves it out first).
    pub fn solve(
        &mut self,
        start: Point2,
        polygons: &[&ConvexPolygon],
        obstacles: &[ConvexPolygon],
    ) {
        let polygons = polygons
            .get(..polygons.len().min(LOCAL_CAPACITY))
            .unwrap_or(&[]);
        self.stats = LtgStats::default();
        self.len = 0;
        self.push_node(start, START_OWNER, 0, true);
        for (k, poly) in polygons.iter().enumerate() {
            for (i, v) in poly.vertices().iter().enumerate() {
                let inside_other = obstacles
                    .iter()
                    .any(|other| other.locate(*v) == PointLocation::Inside);
                self.push_node(*v, k as u8, i as u8, !inside_other);
            }
        }
        self.stats.nodes = self.valid.iter().take(self.len).filter(|v| **v).count() as u32;
        for c in self.cost.iter_mut() {
            *c = f64::INFINITY;
        }
        for s in self.settled.iter_mut() {
            *s = false;
        }
        if let Some(c) = self.cost.first_mut() {
            *c = 0.0;
        }
        for _ in 0..self.len {
            // Next node: the unsettled valid node of least cost (ties: lowest index).
            let mut u: Option<usize> = None;
            for i in 0..self.len {
                let open = self.valid.get(i).copied().unwrap_or(false)
                    && !self.settled.get(i).copied().unwrap_or(true);
                let c = self.cost.get(i).copied().unwrap_or(f64::INFINITY);
                if open && c.is_finite() && u.is_none_or(|b| c < self.cost_of(b)) {
                    u = Some(i);
                }
            }
            let Some(u) = u else { break };
            if let Some(s) = self.settled.get_mut(u) {
                *s = true;
            }
            let pu = self.point(u);
            let cu = self.cost_of(u);
            for v in 0..self.len {
                if !self.valid.get(v).copied().unwrap_or(false)
                    || self.settled.get(v).copied().unwrap_or(true)
                {
                    continue;
                }
                self.stats.pairs = self.stats.pairs.saturating_add(1);
                let pv = self.point(v);
                let w = cu + dist(pu, pv);
                if w >= self.cost_of(v) {
                    continue;
                }
                if !self.tangent_end(polygons, u, pv) || !self.tangent_end(polygons, v, pu) {
                    continue;
                }
                self.stats.segment_checks = self.stats.segment_checks.saturating_add(1);
                if !segment_clear(obstacles, pu, pv) {
                    continue;
                }
                if let (Some(c), Some(p)) = (self.cost.get_mut(v), self.prev.get_mut(v)) {
                    *c = w;
                    *p = u as u16;
                }
            }
        }
    }

    fn push_node(&mut self, p: Point2, owner: u8, vertex: u8, valid: bool) {
        let i = self.len;
        if i >= MAX_NODES {
            return;
        }
        if let (Some(pt), Some(o), Some(vx), Some(va)) = (
            self.points.get_mut(i),
            self.owner.get_mut(i),
            self.vertex.get_mut(i),
            self.valid.get_mut(i),
        ) {
            *pt = p;
            *o = owner;
            *vx = vertex;
            *va = valid;
            self.len += 1;
        }
    }

    /// Tangency at node `i` (true for the start) for the segment towards `q`.
    fn tangent_end(&self, polygons: &[&ConvexPolygon], i: usize, q: Point2) -> bool {
        let owner = self.owner.get(i).copied().unwrap_or(START_OWNER);
        if owner == START_OWNER {
            return true;
        }
        match polygons.get(owner as usize) {
            Some(poly) => {
                tangent_at_vertex(poly, self.vertex.get(i).copied().unwrap_or(0) as usize, q)
            }
            None => true,
        }
    }

    fn cost_of(&self, i: usize) -> f64 {
        self.cost.get(i).copied().unwrap_or(f64::INFINITY)
    }

    /// Number of nodes (start included).
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when the graph has no node (before the first [`Self::solve`]).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Work counts of the last solution.
    pub fn stats(&self) -> LtgStats {
        self.stats
    }

    /// Position of node `i`, m (the start when out of range).
    pub fn point(&self, i: usize) -> Point2 {
        self.points
            .get(i)
            .or(self.points.first())
            .copied()
            .unwrap_or([0.0; 2])
    }

    /// Length of the shortest LTG path from the start to node `i`, m (infinite when
    /// unreachable or out of range).
    pub fn cost(&self, i: usize) -> f64 {
        self.cost_of(i)
    }

    /// The node of vertex `vertex` of local polygon `polygon`, if any.
    pub fn node_of(&self, polygon: usize, vertex: usize) -> Option<usize> {
        (1..self.len).find(|&i| {
            self.owner.get(i).copied() == Some(polygon as u8)
                && self.vertex.get(i).copied() == Some(vertex as u8)
        })
    }

    /// Writes the shortest path from the start to node `i` (start first) into `out` and
    /// returns the number of points written (0 when unreachable; the first `out.len()` points
    /// when longer).
    pub fn path_to(&self, i: usize, out: &mut [Point2]) -> usize {
        if !self.cost_of(i).is_finite() {
            return 0;
        }
        let mut chain = [0u16; MAX_NODES];
        let mut n = 0usize;
        let mut node = i;
        for _ in 0..MAX_NODES {
            if let Some(slot) = chain.get_mut(n) {
                *slot = node as u16;
                n += 1;
            }
            if node == 0 {
                break;
            }
            node = self.prev.get(node).copied().unwrap_or(0) as usize;
        }
        let mut written = 0;
        for (slot, node) in out.iter_mut().zip(chain.iter().take(n).rev()) {
            *slot = self.point(*node as usize);
            written += 1;
        }
        written
    }

    /// The ways on towards the goal (V99's motion-to-goal nodes): for every reached node within
    /// the visible disc, the straight ray towards the goal when no polygon of `obstacles` (all
    /// remembered ones) blocks it, up to the goal or the disc's edge (the exit point). `best`
    /// is the cheapest by `d(start, n) + d(n, T)` among the rays reaching closer than
    /// `threshold_m - epsilon_m` to the goal (or reaching the goal). The node at `sticky` (the
    /// last step's choice) is also evaluated when outside the disc (its exit is then the node
    /// itself) and reported as `sticky`.
    pub fn candidates(
        &self,
        obstacles: &[ConvexPolygon],
        query: &CandidateQuery,
    ) -> CandidateSummary {
        let CandidateQuery {
            center,
            radius_m,
            goal,
            threshold_m: d_min_m,
            epsilon_m,
            sticky,
        } = *query;
        let mut summary = CandidateSummary {
            best: None,
            d_reach_m: f64::INFINITY,
            count: 0,
            sticky: None,
        };
        let goal_inside = dist(center, goal) <= radius_m;
        for node in 0..self.len {
            let g = self.cost_of(node);
            if !g.is_finite() {
                continue;
            }
            let p = self.point(node);
            let is_sticky = sticky.is_some_and(|s| dist(s, p) <= STICKY_MATCH_M);
            let in_disc = dist(center, p) <= radius_m + EPS_M;
            if !in_disc && !is_sticky {
                continue;
            }
            let exit = if goal_inside {
                goal
            } else if in_disc {
                disc_exit(center, radius_m, p, goal)
            } else {
                p
            };
            // The whole ray to the goal must be free of remembered obstacles: beyond the disc
            // too (else the disc's edge in front of a known wall would look like progress, an
            // illusion that comes and goes as the rover moves).
            if !segment_clear(obstacles, p, goal) {
                continue;
            }
            summary.count = summary.count.saturating_add(1);
            let reach = dist(exit, goal);
            summary.d_reach_m = summary.d_reach_m.min(reach);
            // Reaching the goal itself is always progress (even when the goal sits on an
            // obstacle's clearance band, where d_followed can be 0).
            if reach < d_min_m - epsilon_m || (goal_inside && exit == goal) {
                let candidate = Candidate {
                    node,
                    exit,
                    cost_m: g + dist(p, goal),
                    reach_m: reach,
                };
                if is_sticky {
                    summary.sticky = Some(candidate);
                }
                if in_disc && summary.best.is_none_or(|b| candidate.cost_m < b.cost_m) {
                    summary.best = Some(candidate);
                }
            }
        }
        summary
    }
}

/// Where the segment from `p` (inside the disc) to `q` (outside) crosses the circle of radius
/// `r` about `c` (the larger root; `p` when the segment is degenerate).
pub fn disc_exit(c: Point2, r: f64, p: Point2, q: Point2) -> Point2 {
    let f = sub(p, c);
    let d = sub(q, p);
    let a = dot(d, d);
    if a <= 0.0 {
        return p;
    }
    let b = 2.0 * dot(f, d);
    let cc = dot(f, f) - r * r;
    let disc = (b * b - 4.0 * a * cc).max(0.0);
    let t = ((-b + crate::linalg::sqrt(disc)) / (2.0 * a)).clamp(0.0, 1.0);
    add_scaled(p, d, t)
}
