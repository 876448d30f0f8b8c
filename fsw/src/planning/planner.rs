//! The RoverBug planner (V99 sec. 4; Laubach & Burdick 1999): persistent state and the step
//! function [`Planner::plan`].
//!
//! Each call: remember the new obstacles, build the local tangent graph (LTG) over the
//! remembered obstacles near the rover, and
//! - in *motion-to-goal*, drive along the LTG to the way on with the least heuristic distance
//!   `d(x, n) + d(n, T)` among those that reach closer to the goal than `d_min` (the closest the
//!   rover has been); when there is none the rover "cannot make forward progress" (V99) and
//!   switches to boundary following;
//! - in *boundary-following*, slide virtually along the blocking obstacle (a connected set of
//!   remembered polygons): drive to the obstacle's tangent vertex on the chosen side as seen
//!   from the rover, i.e. as far round the border as is visible; return to motion-to-goal as
//!   soon as a way on reaches closer than `d_min` (`d_reach < d_min`); halt `Unreachable` when
//!   the rover has wound once round the obstacle without that.
//!
//! The path is cut to the current visible wedge; when its first leg leaves the wedge the
//! planner asks to turn the cameras there first (gaze control).

use super::geometry::{dist, point_ok, ConvexPolygon, GeometryError, PointLocation, EPS_M};
use super::ltg::{
    segment_clear, Candidate, CandidateQuery, CandidateSummary, LocalTangentGraph, LOCAL_CAPACITY,
};
use super::memory::{ObstacleMemory, MEMORY_CAPACITY};
use super::wedge::Wedge;
use crate::guidance::{Path, Point2};
use core::f64::consts::PI;
use heapless::Vec;

mod follow;
mod route;

use follow::VertexRef;

/// Most waypoints of the path handed to guidance (the rover first).
pub const PATH_CAPACITY: usize = 8;

/// Most points of an untruncated route (start, LTG nodes, way-on point).
const ROUTE_CAPACITY: usize = 16;

/// Tuning of the planner (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlannerConfig {
    /// Goal reached within this distance, m.
    pub goal_tolerance_m: f64,
    /// Clearance added round every remembered (already grown) polygon, m: the paths keep at
    /// least this far from the grown polygons (margin for path-following error).
    pub clearance_m: f64,
    /// A way on must reach at least this much closer than `d_min` to count as progress, m.
    pub progress_epsilon_m: f64,
    /// The path's first leg must lie this far inside the wedge's half-angle to be driven,
    /// else the planner asks for a gaze turn, rad.
    pub gaze_margin_rad: f64,
    /// Driving direction is taken over at least this distance; shorter visible paths trigger a
    /// gaze, m.
    pub min_drive_m: f64,
    /// A cut path is handed to guidance only when its end is at least this far from the rover
    /// in a straight line, else the planner asks for a gaze towards the cut leg, m. Must exceed
    /// guidance's stopping tolerance: guidance arrives at once at a path ending within it.
    pub min_reach_m: f64,
    /// Gaze requests without motion before the planner halts `Blocked(GazeLimit)`.
    pub max_consecutive_gazes: u32,
    /// A new way on replaces the one chosen at the last step only when its heuristic distance
    /// is shorter by more than this, m (hysteresis); the old one stops binding once the rover
    /// is within this distance of its node.
    pub switch_margin_m: f64,
    /// Distance driven in one boundary-following episode before it halts
    /// `Unreachable(FollowLimit)`, m (safety net, see `docs/planning.md`).
    pub max_follow_m: f64,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl PlannerConfig {
    /// The defaults: 0.1 m goal tolerance, 5 cm clearance and progress margin, 5 deg gaze
    /// margin, 5 cm minimum drive and reach, 8 gazes, 0.5 m switch margin, 500 m follow limit.
    pub const DEFAULT: Self = Self {
        goal_tolerance_m: 0.1,
        clearance_m: 0.05,
        progress_epsilon_m: 0.05,
        gaze_margin_rad: 5.0 * PI / 180.0,
        min_drive_m: 0.05,
        min_reach_m: 0.05,
        max_consecutive_gazes: 8,
        switch_margin_m: 0.5,
        max_follow_m: 500.0,
    };

    const fn valid(&self) -> bool {
        const fn pos(v: f64) -> bool {
            v.is_finite() && v > 0.0
        }
        pos(self.goal_tolerance_m)
            && self.clearance_m.is_finite()
            && self.clearance_m >= 0.0
            && pos(self.progress_epsilon_m)
            && self.gaze_margin_rad.is_finite()
            && self.gaze_margin_rad >= 0.0
            && pos(self.min_drive_m)
            && pos(self.min_reach_m)
            && self.max_consecutive_gazes > 0
            && self.switch_margin_m.is_finite()
            && self.switch_margin_m >= 0.0
            && pos(self.max_follow_m)
    }
}

/// RoverBug's two operational modes (V99 sec. 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Monotonic progress towards the goal along the LTG.
    MotionToGoal,
    /// Skirting the blocking obstacle with virtual sliding.
    BoundaryFollowing,
}

/// Side of the rover on which the followed obstacle stays (yaw is positive to the right).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// Obstacle on the left: the rover heads for the tangent at the larger yaw.
    Left,
    /// Obstacle on the right: the rover heads for the tangent at the smaller yaw.
    Right,
}

/// Why the goal was declared unreachable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UnreachableReason {
    /// Boundary following wound once round the obstacle without a way on (V99: "completes a
    /// loop, in which case T is unreachable and the algorithm halts").
    LoopCompleted,
    /// The goal lies inside a remembered (grown) obstacle.
    GoalInObstacle,
    /// The followed obstacle surrounds the rover in every direction.
    Enclosed,
    /// One boundary-following episode exceeded `max_follow_m`.
    FollowLimit,
}

/// Why the planner stopped without a verdict on the goal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockedReason {
    /// The rover is inside obstacles and no nearby free point was found.
    NoEscape,
    /// `max_consecutive_gazes` gaze requests without motion.
    GazeLimit,
    /// The boundary-following target is not reachable in the LTG.
    BoundaryTargetUnreachable,
    /// No path of at least two distinct waypoints could be formed.
    NoPath,
}

/// Outcome of one planning step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanStatus {
    /// Drive the path.
    Driving,
    /// Turn the cameras (or the rover in place) to `gaze_heading_rad`, image, and call again.
    Gaze,
    /// Within `goal_tolerance_m` of the goal (latched).
    Reached,
    /// The goal cannot be reached (latched).
    Unreachable(UnreachableReason),
    /// Stopped without a verdict (latched).
    Blocked(BlockedReason),
}

/// Bookkeeping of one boundary-following episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FollowState {
    /// Where following started, m in `N`.
    pub start: Point2,
    /// A point inside the followed obstacle (centre of the polygon that blocked), m in `N`:
    /// the loop test counts the rover's winding round it.
    pub reference: Point2,
    /// Side the obstacle is kept on.
    pub side: Side,
    /// Signed angle the rover has swept round `reference` since `start`, rad.
    pub winding_rad: f64,
    last_angle_rad: f64,
    /// Distance driven while following, m.
    pub followed_m: f64,
    /// `d_min` when following started, m.
    pub d_min_at_start_m: f64,
}

/// Event and work counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PlannerCounters {
    /// Calls of [`Planner::plan`] with valid input.
    pub calls: u32,
    /// Paths produced (`Driving` outputs).
    pub replans: u32,
    /// Gaze requests.
    pub gazes: u32,
    /// Boundary-following episodes started.
    pub follow_entries: u32,
    /// Episodes resumed (re-blocked on the same obstacle without progress since).
    pub follow_resumes: u32,
    /// Returns from boundary following to motion-to-goal.
    pub follow_exits: u32,
    /// Followed obstacle lost from memory (episode restarted).
    pub follow_restarts: u32,
    /// Starts moved out of an inflated polygon.
    pub escapes: u32,
    /// Calls with more polygons in range than [`LOCAL_CAPACITY`] (the farthest left out).
    pub local_overflows: u32,
    /// LTG solutions.
    pub ltg_solves: u32,
    /// Largest number of segment checks in one LTG solution.
    pub max_segment_checks: u32,
    /// Largest number of node pairs examined in one LTG solution.
    pub max_ltg_pairs: u32,
}

/// What the planner hands to the flight loop.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannerOutput {
    /// Outcome.
    pub status: PlanStatus,
    /// Mode after this step.
    pub mode: Mode,
    /// For `Driving`: the path from the rover's position (first waypoint) to the visible part
    /// of the route, in `N`, m (for [`crate::guidance`]).
    pub path: Option<Path<PATH_CAPACITY>>,
    /// The untruncated route's end (way-on point or boundary target), m.
    pub subgoal: Option<Point2>,
    /// Yaw to point the cameras at, rad: the driving direction (`Driving`) or where to look
    /// before driving (`Gaze`).
    pub gaze_heading_rad: Option<f64>,
    /// Heuristic distance of the chosen way on, `d(x, n) + d(n, T)`, m (infinite when none).
    pub heuristic_m: f64,
    /// `d_reach`, m (infinite when no way on).
    pub d_reach_m: f64,
    /// `d_min`: the closest the rover has been to the goal, m.
    pub d_min_m: f64,
    /// Boundary-following bookkeeping (the last episode, also after it ended).
    pub follow: Option<FollowState>,
    /// Paths produced so far.
    pub replans: u32,
    /// Polygons evicted or dropped by the memory so far (overflow; the completeness argument
    /// no longer holds when nonzero).
    pub memory_overflows: u32,
    /// The rover's position was inside an inflated polygon (the path starts with an escape).
    pub escaped: bool,
}

/// Input the planner refuses (its state is unchanged).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanError {
    /// [`Planner::plan`] before [`Planner::set_goal`].
    NoGoal,
    /// Position or heading NaN or infinite.
    NonFinitePose,
    /// Position or goal beyond the coordinate limit, or a non-finite goal.
    OutOfRange,
    /// The wedge is invalid.
    BadWedge(GeometryError),
    /// The configuration is invalid.
    BadConfig,
}

/// The RoverBug planner: memory of obstacles, goal, mode and boundary-following bookkeeping.
/// Fixed size ([`core::mem::size_of`] reported in `docs/planning.md`); no allocation.
#[derive(Debug, Clone)]
pub struct Planner {
    config: PlannerConfig,
    goal: Option<Point2>,
    memory: ObstacleMemory,
    ltg: LocalTangentGraph,
    local: Vec<u8, LOCAL_CAPACITY>,
    mode: Mode,
    halted: Option<PlanStatus>,
    d_min_m: f64,
    follow: Option<FollowState>,
    last_position: Option<Point2>,
    /// LTG nodes (after the start) of the way on chosen at the last step; the last is the
    /// committed candidate node.
    committed: Vec<Point2, ROUTE_CAPACITY>,
    consecutive_gazes: u32,
    counters: PlannerCounters,
}

/// Moves `p` out of every polygon it is inside (to the nearest boundary point, at most four
/// times); `None` when still inside.
fn push_out(p: Point2, polygons: &[ConvexPolygon]) -> Option<Point2> {
    let mut q = p;
    for _ in 0..4 {
        match polygons
            .iter()
            .find(|poly| poly.locate(q) == PointLocation::Inside)
        {
            Some(poly) => q = poly.closest_boundary_point(q),
            None => return Some(q),
        }
    }
    None
}

fn local_refs<'a>(
    memory: &'a ObstacleMemory,
    local: &[u8],
) -> Vec<&'a ConvexPolygon, LOCAL_CAPACITY> {
    let mut out = Vec::new();
    for &i in local {
        if let Some(p) = memory.inflated().get(i as usize) {
            let _ = out.push(p);
        }
    }
    out
}

impl Planner {
    /// A planner with an empty memory and no goal. Refuses an invalid configuration. `const`, so
    /// that the flight image can place the 33 KiB state in a static without passing it through
    /// the stack.
    pub const fn new(config: PlannerConfig) -> Result<Self, PlanError> {
        if !config.valid() {
            return Err(PlanError::BadConfig);
        }
        Ok(Self::empty(config))
    }

    /// A planner with the default configuration, an empty memory and no goal (the
    /// compile-time value of a statically allocated navigator before [`Self::init`]).
    pub const EMPTY: Self = Self::empty(PlannerConfig::DEFAULT);

    /// [`Self::new`] in place: this planner becomes the one `new(config)` returns (the memory
    /// and the tangent graph are cleared in loops: no 33 KiB temporary on the stack). Refuses
    /// an invalid configuration (nothing changed then).
    pub fn init(&mut self, config: PlannerConfig) -> Result<(), PlanError> {
        if !config.valid() {
            return Err(PlanError::BadConfig);
        }
        self.config = config;
        self.goal = None;
        self.memory.reset(config.clearance_m);
        self.ltg.reset();
        self.local.clear();
        self.mode = Mode::MotionToGoal;
        self.halted = None;
        self.d_min_m = f64::INFINITY;
        self.follow = None;
        self.last_position = None;
        self.committed.clear();
        self.consecutive_gazes = 0;
        self.counters = Self::EMPTY_COUNTERS;
        Ok(())
    }

    /// Zero counters.
    const EMPTY_COUNTERS: PlannerCounters = PlannerCounters {
        calls: 0,
        replans: 0,
        gazes: 0,
        follow_entries: 0,
        follow_resumes: 0,
        follow_exits: 0,
        follow_restarts: 0,
        escapes: 0,
        local_overflows: 0,
        ltg_solves: 0,
        max_segment_checks: 0,
        max_ltg_pairs: 0,
    };

    /// The planner `new(config)` returns, without the configuration check.
    const fn empty(config: PlannerConfig) -> Self {
        Self {
            config,
            goal: None,
            memory: ObstacleMemory::new(config.clearance_m),
            ltg: LocalTangentGraph::new(),
            local: Vec::new(),
            mode: Mode::MotionToGoal,
            halted: None,
            d_min_m: f64::INFINITY,
            follow: None,
            last_position: None,
            committed: Vec::new(),
            consecutive_gazes: 0,
            counters: Self::EMPTY_COUNTERS,
        }
    }

    /// Sets the goal `T` (m in `N`) and starts a new traverse in motion-to-goal: clears the
    /// latched status, `d_min` and the boundary-following bookkeeping; keeps the obstacles.
    pub fn set_goal(&mut self, goal: Point2) -> Result<(), PlanError> {
        if !point_ok(goal) {
            return Err(PlanError::OutOfRange);
        }
        self.goal = Some(goal);
        self.mode = Mode::MotionToGoal;
        self.halted = None;
        self.d_min_m = f64::INFINITY;
        self.follow = None;
        self.committed.clear();
        self.consecutive_gazes = 0;
        Ok(())
    }

    /// The goal, if set.
    pub fn goal(&self) -> Option<Point2> {
        self.goal
    }

    /// Current mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The configuration.
    pub fn config(&self) -> PlannerConfig {
        self.config
    }

    /// The obstacle memory.
    pub fn memory(&self) -> &ObstacleMemory {
        &self.memory
    }

    /// Forgets every remembered obstacle.
    pub fn clear_memory(&mut self) {
        self.memory.clear();
    }

    /// Event and work counts.
    pub fn counters(&self) -> PlannerCounters {
        self.counters
    }

    /// The last boundary-following episode.
    pub fn follow_state(&self) -> Option<FollowState> {
        self.follow
    }

    /// One RoverBug step (V99 sec. 4). `position` and `heading_rad`: rover pose in `N` (m,
    /// rad, yaw from north positive east). `wedge`: what the cameras just imaged.
    /// `new_obstacles`: the obstacles seen in it, convex and grown by the rover half-width (m in
    /// `N`). Returns the next path for guidance, a gaze request, or a latched verdict; refuses
    /// non-finite input and an invalid wedge without changing state.
    pub fn plan(
        &mut self,
        position: Point2,
        heading_rad: f64,
        wedge: &Wedge,
        new_obstacles: &[ConvexPolygon],
    ) -> Result<PlannerOutput, PlanError> {
        self.plan_each(position, heading_rad, wedge, new_obstacles)
    }

    /// [`Self::plan`] with the new obstacles taken one at a time from an iterator (at most one
    /// polygon on the caller's stack instead of a whole map's: the flight stack budget).
    /// The iterator is not advanced when the input is refused (non-finite pose, bad wedge, no
    /// goal); it is otherwise drained in order before anything else is planned.
    pub fn plan_each<I>(
        &mut self,
        position: Point2,
        heading_rad: f64,
        wedge: &Wedge,
        new_obstacles: I,
    ) -> Result<PlannerOutput, PlanError>
    where
        I: IntoIterator,
        I::Item: core::borrow::Borrow<ConvexPolygon>,
    {
        if !(position[0].is_finite() && position[1].is_finite() && heading_rad.is_finite()) {
            return Err(PlanError::NonFinitePose);
        }
        if !point_ok(position) {
            return Err(PlanError::OutOfRange);
        }
        wedge.validate().map_err(PlanError::BadWedge)?;
        let goal = self.goal.ok_or(PlanError::NoGoal)?;
        self.counters.calls = self.counters.calls.saturating_add(1);
        self.take_obstacles(position, new_obstacles);

        if let Some(status) = self.halted {
            return Ok(self.output(status, None, None, None, None));
        }
        let d_goal = dist(position, goal);
        self.d_min_m = self.d_min_m.min(d_goal);
        if d_goal <= self.config.goal_tolerance_m {
            return Ok(self.halt(PlanStatus::Reached));
        }
        if self.memory.grown_containing(goal).is_some() {
            return Ok(self.halt(PlanStatus::Unreachable(UnreachableReason::GoalInObstacle)));
        }
        // A goal inside the clearance band only: aim at the nearest point outside it.
        let target = push_out(goal, self.memory.inflated()).unwrap_or(goal);
        if dist(position, target) <= self.config.goal_tolerance_m {
            return Ok(self.halt(PlanStatus::Reached));
        }
        let Some(start) = push_out(position, self.memory.inflated()) else {
            return Ok(self.halt(PlanStatus::Blocked(BlockedReason::NoEscape)));
        };
        if dist(start, position) > EPS_M {
            self.counters.escapes = self.counters.escapes.saturating_add(1);
        }
        let radius = wedge.max_range_m;

        self.solve(start, radius, None);
        let summary = self.ways_on(start, radius, target);
        // Commitment: keep last step's way on unless another is better by the margin (the
        // best way on can jump between near-equal alternatives as the disc moves with the rover).
        let choice = match (summary.best, summary.sticky) {
            (Some(b), Some(s)) if s.cost_m <= b.cost_m + self.config.switch_margin_m => Some(s),
            (None, Some(s)) => Some(s),
            (b, _) => b,
        };
        self.committed.clear();
        if let Some(best) = choice {
            let route = self.way_on_route(&best);
            return Ok(self.finish(position, start, &route, wedge, &summary));
        }

        // No progress: boundary following (enter, resume or continue).
        if self.mode == Mode::BoundaryFollowing && self.followed_label().is_none() {
            // The followed obstacle left the memory (overflow): start again on what blocks now.
            self.counters.follow_restarts = self.counters.follow_restarts.saturating_add(1);
            self.follow = None;
            self.mode = Mode::MotionToGoal;
        }
        if self.mode == Mode::MotionToGoal {
            match self.begin_follow(start, target, radius, heading_rad) {
                Ok(true) => {}
                Ok(false) => {
                    // Nothing to follow near the rover: forget d_min and head for the goal.
                    self.d_min_m = d_goal;
                    return self.plan_direct(position, start, target, radius, wedge);
                }
                Err(status) => return Ok(self.halt(status)),
            }
        }
        match self.boundary_route(start, radius) {
            Ok(route) => Ok(self.finish(position, start, &route, wedge, &summary)),
            Err(status) => Ok(self.halt(status)),
        }
    }

    /// The bookkeeping of a step's pose and the new obstacles: the gaze count restarts once
    /// the rover has moved half a minimum drive, the distance followed grows by the motion
    /// while following, and the obstacles (m in `N`) go into the memory in order (the followed
    /// obstacle's reference polygon protected) before its components are refreshed.
    fn take_obstacles<I>(&mut self, position: Point2, new_obstacles: I)
    where
        I: IntoIterator,
        I::Item: core::borrow::Borrow<ConvexPolygon>,
    {
        use core::borrow::Borrow;
        let moved = self.last_position.map_or(0.0, |p| dist(p, position));
        if moved > 0.5 * self.config.min_drive_m {
            self.consecutive_gazes = 0;
        }
        self.last_position = Some(position);
        if self.mode == Mode::BoundaryFollowing {
            if let Some(f) = self.follow.as_mut() {
                f.followed_m += moved;
            }
        }
        let protected = self.follow.map(|f| f.reference);
        for o in new_obstacles {
            self.memory.insert(o.borrow(), position, protected);
        }
        self.memory.refresh_components();
    }

    /// The ways on of the LTG just solved from `start` (disc of `radius`, m) towards `target`,
    /// against the progress threshold: `d_min` in motion-to-goal; while following, TangentBug's
    /// `d_followed`, which also counts the remembered boundary of the followed obstacle (a way
    /// on must beat every point of that boundary, else it is the disc's edge in front of the
    /// same obstacle).
    fn ways_on(&self, start: Point2, radius: f64, target: Point2) -> CandidateSummary {
        let threshold = match (self.mode, self.followed_label()) {
            (Mode::BoundaryFollowing, Some(label)) => {
                let mut d = self.d_min_m;
                for (i, poly) in self.memory.inflated().iter().enumerate() {
                    if self.memory.component(i) == label {
                        d = d.min(poly.distance(target));
                    }
                }
                d
            }
            _ => self.d_min_m,
        };
        let query = CandidateQuery {
            center: start,
            radius_m: radius,
            goal: target,
            threshold_m: threshold,
            epsilon_m: self.config.progress_epsilon_m,
            // A way on the rover has (nearly) reached is no longer binding.
            sticky: self
                .committed
                .last()
                .copied()
                .filter(|c| dist(*c, start) > self.config.switch_margin_m),
        };
        self.ltg.candidates(self.memory.inflated(), &query)
    }

    /// Motion-to-goal along the way on `best` (it makes progress; a boundary-following episode
    /// ends): the route along the LTG to its node, then its exit point; the route's nodes
    /// become the committed ones.
    fn way_on_route(&mut self, best: &Candidate) -> Vec<Point2, ROUTE_CAPACITY> {
        let mut route: Vec<Point2, ROUTE_CAPACITY> = Vec::new();
        if self.mode == Mode::BoundaryFollowing {
            self.counters.follow_exits = self.counters.follow_exits.saturating_add(1);
            self.mode = Mode::MotionToGoal;
        }
        let mut buf = [[0.0; 2]; ROUTE_CAPACITY];
        let n = self.ltg.path_to(best.node, &mut buf[..ROUTE_CAPACITY - 1]);
        for p in buf.iter().take(n) {
            let _ = route.push(*p);
        }
        // Commit to the route's nodes (their polygons stay in the next LTG even when they
        // are out of range, so that the route does not vanish as the rover moves).
        for p in buf.iter().take(n).skip(1) {
            let _ = self.committed.push(*p);
        }
        if n <= 1 {
            let _ = self.committed.push(self.ltg.point(best.node));
        }
        let _ = route.push(best.exit);
        route
    }

    /// Boundary following from `start` (LTG disc of `radius`, m): the winding and the followed
    /// distance checked against their limits, then the route along the LTG to the obstacle's
    /// tangent vertex and on to the next one as seen from it (keeps guidance going). The
    /// verdict to halt with otherwise.
    fn boundary_route(
        &mut self,
        start: Point2,
        radius: f64,
    ) -> Result<Vec<Point2, ROUTE_CAPACITY>, PlanStatus> {
        self.update_winding(start);
        if let Some(f) = self.follow {
            if libm::fabs(f.winding_rad) >= 2.0 * PI {
                return Err(PlanStatus::Unreachable(UnreachableReason::LoopCompleted));
            }
            if f.followed_m > self.config.max_follow_m {
                return Err(PlanStatus::Unreachable(UnreachableReason::FollowLimit));
            }
        }
        let first = self.follow_target(start)?;
        let Some(node) = self.ensure_local_node(start, radius, first) else {
            return Err(PlanStatus::Blocked(
                BlockedReason::BoundaryTargetUnreachable,
            ));
        };
        let mut buf = [[0.0; 2]; ROUTE_CAPACITY];
        let n = self.ltg.path_to(node, &mut buf[..ROUTE_CAPACITY - 1]);
        if n == 0 {
            return Err(PlanStatus::Blocked(
                BlockedReason::BoundaryTargetUnreachable,
            ));
        }
        let mut route: Vec<Point2, ROUTE_CAPACITY> = Vec::new();
        for p in buf.iter().take(n) {
            let _ = route.push(*p);
        }
        // Second leg: the next tangent vertex as seen from the first (keeps guidance going).
        let q = self.vertex_point(first);
        if let Ok(second) = self.follow_target(q) {
            let q2 = self.vertex_point(second);
            if second != first && segment_clear(self.memory.inflated(), q, q2) {
                let _ = route.push(q2);
            }
        }
        Ok(route)
    }

    /// Solves the LTG from `start` over the remembered polygons within `radius` (nearest
    /// first, at most [`LOCAL_CAPACITY`]), plus forced ones: `target` (memory index of the
    /// boundary-following target's polygon) and the polygons of the committed route's nodes.
    fn solve(&mut self, start: Point2, radius: f64, target: Option<usize>) {
        let inflated = self.memory.inflated();
        let mut d = [f64::INFINITY; MEMORY_CAPACITY];
        for (slot, poly) in d.iter_mut().zip(inflated.iter()) {
            *slot = poly.distance(start);
        }
        self.local.clear();
        let mut taken = [false; MEMORY_CAPACITY];
        let route_polygons = self.committed.iter().filter_map(|c| {
            inflated.iter().position(|p| {
                p.vertices()
                    .iter()
                    .any(|v| dist(*v, *c) <= super::ltg::STICKY_MATCH_M)
            })
        });
        for f in target.into_iter().chain(route_polygons) {
            if let Some(t) = taken.get_mut(f) {
                if !*t && self.local.push(f as u8).is_ok() {
                    *t = true;
                }
            }
        }
        let in_range = d.iter().filter(|v| **v <= radius).count();
        for _ in 0..LOCAL_CAPACITY {
            let mut best: Option<(usize, f64)> = None;
            for (i, v) in d.iter().enumerate() {
                if *v <= radius
                    && !taken.get(i).copied().unwrap_or(true)
                    && best.is_none_or(|(_, b)| *v < b)
                {
                    best = Some((i, *v));
                }
            }
            let Some((i, _)) = best else { break };
            if self.local.push(i as u8).is_err() {
                break;
            }
            if let Some(t) = taken.get_mut(i) {
                *t = true;
            }
        }
        if in_range > self.local.len() {
            self.counters.local_overflows = self.counters.local_overflows.saturating_add(1);
        }
        let polys = local_refs(&self.memory, &self.local);
        self.ltg.solve(start, &polys, self.memory.inflated());
        self.counters.ltg_solves = self.counters.ltg_solves.saturating_add(1);
        let stats = self.ltg.stats();
        self.counters.max_segment_checks =
            self.counters.max_segment_checks.max(stats.segment_checks);
        self.counters.max_ltg_pairs = self.counters.max_ltg_pairs.max(stats.pairs);
    }

    /// The LTG node of a followed-obstacle vertex, re-solving with its polygon included when
    /// it was out of range. `None` when unreachable.
    fn ensure_local_node(&mut self, start: Point2, radius: f64, v: VertexRef) -> Option<usize> {
        let position_in_local = |local: &[u8]| local.iter().position(|&i| i as usize == v.0);
        let k = match position_in_local(&self.local) {
            Some(k) => k,
            None => {
                self.solve(start, radius, Some(v.0));
                position_in_local(&self.local)?
            }
        };
        let node = self.ltg.node_of(k, v.1)?;
        self.ltg.cost(node).is_finite().then_some(node)
    }
}
