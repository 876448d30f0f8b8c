//! The step's output: the route cut to the visible region, gaze requests, latched verdicts.

use super::{
    BlockedReason, Mode, PlanError, PlanStatus, Planner, PlannerOutput, PATH_CAPACITY,
    ROUTE_CAPACITY,
};
use crate::guidance::{wrap_pi, Path, Point2};
use crate::planning::geometry::{
    add_scaled, dist, sub, unit, yaw, ConvexPolygon, EPS_M, MAX_VERTICES,
};
use crate::planning::ltg::{disc_exit, CandidateSummary};
use crate::planning::wedge::Wedge;
use core::f64::consts::PI;
use heapless::Vec;

/// Waypoints closer than this are merged, m (guidance refuses segments under 1 mm).
const MERGE_WAYPOINT_M: f64 = 2e-3;

/// Points of the circle of radius `min_drive_m` about the rover added to the visible region.
const NEAR_POINTS: usize = 8;

impl Planner {
    /// Nothing near to follow: straight towards the goal.
    pub(super) fn plan_direct(
        &mut self,
        position: Point2,
        start: Point2,
        target: Point2,
        radius: f64,
        wedge: &Wedge,
    ) -> Result<PlannerOutput, PlanError> {
        self.mode = Mode::MotionToGoal;
        let exit = if dist(start, target) <= radius {
            target
        } else {
            disc_exit(start, radius, start, target)
        };
        let mut route: Vec<Point2, ROUTE_CAPACITY> = Vec::new();
        let _ = route.push(start);
        let _ = route.push(exit);
        let summary = CandidateSummary {
            best: None,
            d_reach_m: dist(exit, target),
            count: 1,
            sticky: None,
        };
        Ok(self.finish(position, start, &route, wedge, &summary))
    }

    pub(super) fn halt(&mut self, status: PlanStatus) -> PlannerOutput {
        self.halted = Some(status);
        self.output(status, None, None, None, None)
    }

    pub(super) fn output(
        &self,
        status: PlanStatus,
        path: Option<Path<PATH_CAPACITY>>,
        subgoal: Option<Point2>,
        gaze: Option<f64>,
        summary: Option<&CandidateSummary>,
    ) -> PlannerOutput {
        let stats = self.memory.stats();
        PlannerOutput {
            status,
            mode: self.mode,
            path,
            subgoal,
            gaze_heading_rad: gaze,
            heuristic_m: summary
                .and_then(|s| s.best)
                .map_or(f64::INFINITY, |b| b.cost_m),
            d_reach_m: summary.map_or(f64::INFINITY, |s| s.d_reach_m),
            d_min_m: self.d_min_m,
            follow: self.follow,
            replans: self.counters.replans,
            memory_overflows: stats.evicted.saturating_add(stats.dropped),
            escaped: false,
        }
    }

    /// Turns a route (start first) into the output: prepends the rover position, asks for a
    /// gaze when the driving direction is outside the wedge, else cuts the path to the visible
    /// region (the wedge polygon plus the rover position).
    pub(super) fn finish(
        &mut self,
        position: Point2,
        start: Point2,
        route: &[Point2],
        wedge: &Wedge,
        summary: &CandidateSummary,
    ) -> PlannerOutput {
        let subgoal = route.last().copied();
        let mut pts: Vec<Point2, ROUTE_CAPACITY> = Vec::new();
        let _ = pts.push(position);
        for p in core::iter::once(&start).chain(route.iter().skip(1)) {
            if pts
                .last()
                .is_some_and(|last| dist(*last, *p) > MERGE_WAYPOINT_M)
            {
                let _ = pts.push(*p);
            }
        }
        let escaped = dist(start, position) > EPS_M;
        if pts.len() < 2 {
            let mut out = self.halt(PlanStatus::Blocked(BlockedReason::NoPath));
            out.escaped = escaped;
            return out;
        }
        // Driving direction: towards the first waypoint at least min_drive away.
        let aim = pts
            .iter()
            .skip(1)
            .find(|p| dist(position, **p) >= self.config.min_drive_m)
            .or(pts.last())
            .copied()
            .unwrap_or(position);
        let drive_yaw = yaw(position, aim);
        let limit = wedge.half_angle_rad - self.config.gaze_margin_rad;
        if !escaped && libm::fabs(wrap_pi(drive_yaw - wedge.heading_rad)) > limit {
            return self.gaze(drive_yaw, subgoal, summary);
        }
        // Cut to the visible region: the wedge and the ground within min_drive of the rover
        // (under and beside it, crossed on the way there), as one convex polygon.
        let region = wedge.polygon().ok().and_then(|w| {
            let mut v = [[0.0; 2]; MAX_VERTICES + NEAR_POINTS];
            let mut n = 0;
            let near = (0..NEAR_POINTS).map(|k| {
                let a = 2.0 * PI * k as f64 / NEAR_POINTS as f64;
                add_scaled(position, unit(a), self.config.min_drive_m)
            });
            for (slot, p) in v.iter_mut().zip(w.vertices().iter().copied().chain(near)) {
                *slot = p;
                n += 1;
            }
            ConvexPolygon::from_points(v.get(..n).unwrap_or(&[])).ok()
        });
        let mut path_pts: Vec<Point2, PATH_CAPACITY> = Vec::new();
        let _ = path_pts.push(position);
        let mut cut_yaw: Option<f64> = None;
        let mut length = 0.0;
        for (a, b) in pts.iter().zip(pts.iter().skip(1)) {
            if path_pts.is_full() {
                break;
            }
            let (t0, t1) = match &region {
                // The escape leg is driven even though it may leave the region.
                Some(r) if !(escaped && *a == position) => {
                    r.clip_segment(*a, *b).unwrap_or((1.0, 0.0))
                }
                _ => (0.0, 1.0),
            };
            if t0 > 1e-9 || t1 <= t0 {
                cut_yaw = Some(yaw(*a, *b));
                break;
            }
            let d = sub(*b, *a);
            let end = [a[0] + t1 * d[0], a[1] + t1 * d[1]];
            if dist(*a, end) > MERGE_WAYPOINT_M {
                let _ = path_pts.push(end);
                length += dist(*a, end);
            }
            if t1 < 1.0 {
                if dist(end, *b) > MERGE_WAYPOINT_M {
                    cut_yaw = Some(yaw(*a, *b));
                }
                break;
            }
        }
        // A cut path must take the rover at least `min_reach` away, measured straight to its
        // end: guidance stops within its tolerance of a path's end, so a path whose end is that
        // close is no drive at all, however long its polyline (without the rule, a
        // boundary-following route cut by the wedge right after a bend on `rockfield-goal` goes
        // 6.7 cm to an end 5 cm away, and the rover holds, maps and gets the same path back
        // until fault protection stops it).
        let reach = path_pts.last().map_or(0.0, |end| dist(position, *end));
        if length < self.config.min_drive_m || reach < self.config.min_reach_m {
            if let Some(y) = cut_yaw {
                return self.gaze(y, subgoal, summary);
            }
        }
        match Path::new(&path_pts) {
            Ok(path) => {
                self.counters.replans = self.counters.replans.saturating_add(1);
                let mut out = self.output(
                    PlanStatus::Driving,
                    Some(path),
                    subgoal,
                    Some(drive_yaw),
                    Some(summary),
                );
                out.escaped = escaped;
                out
            }
            Err(_) => {
                let mut out = self.halt(PlanStatus::Blocked(BlockedReason::NoPath));
                out.escaped = escaped;
                out
            }
        }
    }

    pub(super) fn gaze(
        &mut self,
        yaw_rad: f64,
        subgoal: Option<Point2>,
        summary: &CandidateSummary,
    ) -> PlannerOutput {
        self.consecutive_gazes = self.consecutive_gazes.saturating_add(1);
        self.counters.gazes = self.counters.gazes.saturating_add(1);
        if self.consecutive_gazes > self.config.max_consecutive_gazes {
            return self.halt(PlanStatus::Blocked(BlockedReason::GazeLimit));
        }
        self.output(
            PlanStatus::Gaze,
            None,
            subgoal,
            Some(yaw_rad),
            Some(summary),
        )
    }
}
