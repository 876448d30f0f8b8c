//! Goal-directed driving with hazard avoidance (V99 sec. 4): hazard maps from the hazcam pair
//! ([`crate::perception`]) feed the RoverBug planner ([`crate::planning`]), whose paths replace
//! the guidance path; guidance keeps its slip compensation (H05).
//!
//! - **When a map is made**: on the frame of a stereo capture that VO has just finished with
//!   (or at once when VO is off), when [`NavConfig::map_interval_m`] of EKF travel has passed
//!   since the last map, when the rover holds at the end of a planned path, after a gaze turn,
//!   and before the first drive. The map runs in background work items like VO (the frame
//!   stays held), with the camera pose of the capture clone.
//! - **Planning**: each finished map is one RoverBug step at the current EKF pose: `Driving`
//!   sets a new guidance path (the planner's, from the rover's position), `Gaze` turns the
//!   rover in place towards the requested heading and maps again, `Reached` ends the drive
//!   through the arrival check of fault protection, `Unreachable` and `Blocked` stop the rover
//!   ([`FaultResponse::GoalUnreachable`], [`FaultResponse::PlannerBlocked`]).
//! - **Holding**: before the first plan and at the end of a planned path short of the goal the
//!   rover stands and waits for the next map (counted); a map that fails (blank images, too
//!   few points) is counted and retried at the next capture.

use super::drive::{Drive, MAX_WAYPOINTS};
use super::filter::NavFilter;
use super::goal::{GoalCtx, GoalNav, ModeRequest};
use super::protection::FaultResponse;
use super::{yaw_of, StereoStage};
use crate::guidance::Point2;
use crate::guidance::{Guidance, Path};
use crate::kinematics::{wheel_contact_points, RoverGeometry, SuspensionState, VehicleCommand};
use crate::perception::{CameraPose, HazardMap, HazardMapper, MapProgress};
use crate::planning::{ConvexPolygon, PlanStatus, Planner, PlannerOutput, Wedge};
use crate::types::{Quat, Vec3};
use rover_hal::{StereoCalibration, StereoFrame};

/// Counters of the hazard navigation (telemetry and the simulator's summary).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct HazardCounters {
    /// Hazard maps started.
    pub maps_started: u32,
    /// Hazard maps finished with a map.
    pub maps: u32,
    /// Hazard maps that failed (perception error: blank or textureless images, too few
    /// points, bad pose) or could not start.
    pub map_errors: u32,
    /// Obstacles of the last map.
    pub last_obstacles: u32,
    /// Obstacle polygons of a map the planner refused (degenerate after conversion).
    pub polygons_refused: u32,
    /// Planner steps.
    pub plans: u32,
    /// Planner steps refused (non-finite pose, invalid wedge).
    pub plan_errors: u32,
    /// Paths handed to guidance.
    pub paths: u32,
    /// Gaze turns.
    pub gazes: u32,
    /// RG2 cycles the rover held still waiting for a map.
    pub holds: u32,
    /// Gaze turns given up because a remembered obstacle was inside the circle the rover's
    /// corners sweep when it turns in place; the rover maps where it stands instead.
    pub gazes_skipped: u32,
    /// Gaze requests answered first by a short forward drive along the rover's heading to gain
    /// room for the turn ([`room_move`]); the rover maps and plans again at its end.
    pub room_moves: u32,
}

/// The planner's verdict as the ground sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum PlannerVerdict {
    /// Driving (or waiting for a map).
    #[default]
    Driving,
    /// Goal reached (planner's tolerance).
    Reached,
    /// The goal cannot be reached (RoverBug completed a loop round the blocking obstacle).
    Unreachable,
    /// The planner stopped without a verdict.
    Blocked,
}

/// State of the goal-directed drive.
pub struct HazardNav {
    /// Goal-directed driving (the planner's paths replace the guidance path). False: the
    /// mapper serves terrain-map localization on a path drive alone ([`super::loc_nav`]).
    planning: bool,
    pub(super) mapper: HazardMapper,
    planner: Planner,
    /// EKF position `[x, y]` (`N`, m) where the last map was started.
    last_map_xy: Option<[f64; 2]>,
    /// A map is wanted at the next capture (start, end of a planned path, after a gaze).
    map_wanted: bool,
    /// Heading to turn to in place (`Gaze`), rad from north.
    gaze_rad: Option<f64>,
    /// At least one path came from the planner.
    planned: bool,
    verdict: PlannerVerdict,
    last_output: Option<PlannerOutput>,
    counters: HazardCounters,
}

impl HazardNav {
    /// Placeholder (mapper and planner placeholders, nothing planned): the compile-time value
    /// of a statically allocated navigator's hazard navigation before
    /// [`Navigator::start_vo`] builds it in place.
    pub(super) const EMPTY: Self = Self {
        planning: false,
        mapper: HazardMapper::EMPTY,
        planner: Planner::EMPTY,
        last_map_xy: None,
        map_wanted: false,
        gaze_rad: None,
        planned: false,
        verdict: PlannerVerdict::Driving,
        last_output: None,
        counters: HazardCounters {
            maps_started: 0,
            maps: 0,
            map_errors: 0,
            last_obstacles: 0,
            polygons_refused: 0,
            plans: 0,
            plan_errors: 0,
            paths: 0,
            gazes: 0,
            holds: 0,
            gazes_skipped: 0,
            room_moves: 0,
        },
    };
}

/// Margin over the rover half-width by which the visible wedge is eroded for the planner, m.
pub const WEDGE_EROSION_MARGIN_M: f64 = 0.1;

/// Largest heading error of a gaze turn before the rover maps again, rad.
pub(super) const GAZE_TOLERANCE_RAD: f64 = 0.05;
/// Yaw rate of a gaze turn, rad/s.
pub(super) const GAZE_RATE_RAD_S: f64 = 0.1;
/// Clearance kept between the circle the rover's footprint sweeps turning in place and a
/// remembered obstacle's hazard outline, m: the outline is the hull of 0.1 m hazard cells above
/// the step limit, smaller than the rock's base, and the position is the EKF's. From the
/// collision it prevents (`unreachable` seed 1 with the lens model: a ring rock 0.95 m from the
/// rover's centre hit during a gaze, with the hull about 0.2 m in radius and a 0.61 m sweep)
/// the margin must exceed 0.15 m.
pub const GAZE_TURN_MARGIN_M: f64 = 0.2;

/// Distance beyond the turn's room (the sweep plus [`GAZE_TURN_MARGIN_M`] from a remembered
/// outline) that a forward room move aims for, m; a gaze asked for with less spare room than
/// this starts with the room move. Without it a turn begun at the limit is given up part way
/// (the EKF's reference point shifts by millimetres while the rover turns): `multi-target`
/// with 54 kJ, riding the wall 0.804 m from its outline against the 0.805 m needed, turned a
/// few degrees per map at best and hit the planner's gaze limit twice (T0 and T1 dropped).
pub const ROOM_MOVE_EXTRA_M: f64 = 0.05;
/// Longest forward room move, m (the ground ahead within the hazcam wedge's near range).
pub const ROOM_MOVE_MAX_M: f64 = 0.4;
/// Step of the room move's search along the heading and of its clearance samples, m (a grown
/// outline is at least twice the growth, 1.3 m, across: none fits between two samples).
const ROOM_MOVE_STEP_M: f64 = 0.05;

/// A forward move giving a gaze turn its room: the nearest point `position + s u(heading_rad)`
/// (`N`, m; `s` a multiple of [`ROOM_MOVE_STEP_M`], at most [`ROOM_MOVE_MAX_M`]) from which
/// the point `stop_short_m` short of it (where guidance may call the path done) is at least
/// `need_m` from every polygon of `grown` (the planner's remembered outlines, grown, `N`, m).
/// Every sample of the way keeps at least `clearance_m` from them (the planner's rule for its
/// paths), or, when the rover already stands closer, no less than where it stands. `None` when
/// the heading does not give the room within the limit (towards or along the obstacle), when
/// an obstacle is in the way, or for non-finite input. The caller checks that the heading is
/// inside the hazcam wedge just mapped.
pub fn room_move(
    position: Point2,
    heading_rad: f64,
    grown: &[ConvexPolygon],
    need_m: f64,
    clearance_m: f64,
    stop_short_m: f64,
) -> Option<Point2> {
    let finite = position.iter().all(|v| v.is_finite())
        && heading_rad.is_finite()
        && need_m.is_finite()
        && clearance_m.is_finite()
        && stop_short_m.is_finite();
    if !finite {
        return None;
    }
    let nearest = |p: Point2| {
        grown
            .iter()
            .map(|g| g.distance(p))
            .fold(f64::INFINITY, f64::min)
    };
    let floor = nearest(position).min(clearance_m);
    let (sh, ch) = libm::sincos(heading_rad);
    let at = |s: f64| [position[0] + s * ch, position[1] + s * sh];
    // Bounded: ROOM_MOVE_MAX_M / ROOM_MOVE_STEP_M = 8 steps.
    let steps = (ROOM_MOVE_MAX_M / ROOM_MOVE_STEP_M) as u32;
    for k in 1..=steps {
        let s = f64::from(k) * ROOM_MOVE_STEP_M;
        if nearest(at(s)) < floor {
            return None;
        }
        // At least twice guidance's tolerance, so that the rover does move.
        if s >= 2.0 * stop_short_m && nearest(at((s - stop_short_m).max(0.0))) >= need_m {
            return Some(at(s));
        }
    }
    None
}

/// Radius (m) of the circle the rover's footprint sweeps turning in place about its reference
/// point: the farthest wheel contact plus the wheel radius fore and aft, the half-width (with
/// its margin, [`crate::perception::ROVER_HALF_WIDTH_M`]) across.
pub fn turn_sweep_radius(geometry: &RoverGeometry) -> f64 {
    sweep_radius_of(
        wheel_contact_points(geometry, &SuspensionState::default()).ok(),
        geometry,
    )
}

/// [`turn_sweep_radius`] from the nominal contact points `points` (m, `R`, zero suspension
/// state) already evaluated (the navigator keeps them: `Trajectories::nominal_points`), so the
/// navigator computes the sweep once at its initialisation, not in the RG2 guidance cycle; 0.5 m
/// of reach without them.
pub(super) fn sweep_radius_of(
    points: Option<[crate::types::Vec3; rover_hal::WHEEL_COUNT]>,
    geometry: &RoverGeometry,
) -> f64 {
    let reach = match points {
        Some(p) => p.iter().fold(0.0_f64, |m, c| m.max(libm::fabs(c.x))),
        None => 0.5,
    } + geometry.wheel_radius_m;
    let w = crate::perception::ROVER_HALF_WIDTH_M;
    crate::linalg::sqrt(reach * reach + w * w)
}

/// The wedge the planner gets for a map of visible wedge `w` (`N`): the planner keeps its path
/// inside the wedge it is given, and the rover's body sweeps half its width to each side of
/// the path, where a narrow hazcam wedge has not looked (a rock approached at 45 deg off the
/// axis was never in view and was hit: SIL-HAZ-3). So the wedge is eroded by the half-width
/// plus [`WEDGE_EROSION_MARGIN_M`]: the sector whose points are at least `d` inside both edges
/// (apex moved forward by `d / sin(alpha)`) and `d` short of the far range.
fn eroded_wedge(w: &crate::perception::Wedge) -> Wedge {
    let d = crate::perception::ROVER_HALF_WIDTH_M + WEDGE_EROSION_MARGIN_M;
    let s = libm::sin(w.half_angle_rad);
    let shift = if s > 1e-3 { d / s } else { f64::INFINITY };
    let (sh, ch) = libm::sincos(w.heading_rad);
    Wedge {
        apex: [w.apex_m[0] + shift * ch, w.apex_m[1] + shift * sh],
        heading_rad: w.heading_rad,
        half_angle_rad: w.half_angle_rad,
        min_range_m: (w.min_range_m - shift).max(0.0),
        max_range_m: w.max_range_m - shift - d,
    }
}

/// The planner's estimate of the leg left to `goal` (`N`, m) from `position` when it drives a
/// path (`status` [`PlanStatus::Driving`]) on `waypoints`: from the rover to the path, along
/// it, then the straight line from the path's end (the sequencer's leg trigger), m.
fn leg_left(
    status: PlanStatus,
    waypoints: Option<&[Point2]>,
    goal: Option<[f64; 2]>,
    position: Point2,
) -> Option<f64> {
    match (status, waypoints, goal) {
        (PlanStatus::Driving, Some(w), Some(goal)) => {
            let along = w
                .windows(2)
                .map(|s| match s {
                    [a, b] => libm::hypot(b[0] - a[0], b[1] - a[1]),
                    _ => 0.0,
                })
                .sum::<f64>();
            let first = w
                .first()
                .map_or(0.0, |a| libm::hypot(a[0] - position[0], a[1] - position[1]));
            let last = w
                .last()
                .map_or(0.0, |b| libm::hypot(goal[0] - b[0], goal[1] - b[1]));
            Some(first + along + last)
        }
        _ => None,
    }
}

impl HazardNav {
    /// A new traverse to `goal` (`N`, m; the sequencer's next target): the planner's goal
    /// (its obstacle memory kept), the verdict back to `Driving`. With `face_rad` (the bearing
    /// of the goal, rad from north) the rover first turns in place to face it, as a gaze (the
    /// planner's own gazes, a wedge's width at a time, would hit its gaze limit on a target
    /// behind the rover), then maps; without, it maps where it stands.
    pub(super) fn restart(
        &mut self,
        goal: [f64; 2],
        face_rad: Option<f64>,
    ) -> Result<(), crate::planning::PlanError> {
        self.planner.set_goal(goal)?;
        self.verdict = PlannerVerdict::Driving;
        self.last_output = None;
        self.gaze_rad = face_rad.filter(|h| h.is_finite());
        // Holding for a map at once, or after the turn (`hazard_command` asks for it).
        self.map_wanted = self.gaze_rad.is_none();
        self.planned = self.gaze_rad.is_some();
        Ok(())
    }
}

impl GoalNav {
    /// Build the hazard mapper and the planner in place (about 68 KB) when
    /// [`NavConfig::hazard_avoidance`] is on, or the mapper alone for terrain-map localization
    /// on a path drive ([`LocalizationSettings::enabled`]); the goal is the last waypoint of
    /// the plan. A configuration the mapper refuses leaves the drive held (counted in
    /// [`NavCounters::command_errors`]) rather than driving blind.
    pub(super) fn start_hazard_nav(
        &mut self,
        goal: Option<[f64; 2]>,
        calibration: &StereoCalibration,
    ) {
        let planning = self.config.hazard_avoidance;
        if !(planning || self.loc_on()) || self.hazard.is_some() {
            return;
        }
        let Some(goal) = goal else {
            return;
        };
        // Built in its storage (no 68 KB value through the stack).
        let h = &mut self.hazard.value;
        let planner = h
            .planner
            .init(self.config.planner)
            .and_then(|()| h.planner.set_goal(goal));
        let mapper = h.mapper.init(self.config.perception, calibration);
        match (mapper, planner) {
            (Ok(()), Ok(())) => {
                h.planning = planning;
                h.last_map_xy = None;
                // A path drive does not wait for maps: they come every
                // `LocalizationSettings::map_interval_m` of travel.
                h.map_wanted = planning;
                h.gaze_rad = None;
                h.planned = !planning;
                h.verdict = PlannerVerdict::Driving;
                h.last_output = None;
                h.counters = HazardCounters::default();
                self.hazard.built = true;
            }
            // The drive holds without a hazard navigation (`guidance_cycle`).
            _ => self.build_errors = self.build_errors.saturating_add(1),
        }
    }

    /// Counters of the hazard navigation (zero when it is off).
    pub fn hazard_counters(&self) -> HazardCounters {
        self.hazard.as_ref().map(|h| h.counters).unwrap_or_default()
    }

    /// The planner's verdict (`Driving` when hazard avoidance is off).
    pub fn planner_verdict(&self) -> PlannerVerdict {
        self.hazard.as_ref().map(|h| h.verdict).unwrap_or_default()
    }

    /// The planner's counters (replans, gazes, boundary following), if hazard avoidance is on.
    pub fn planner_counters(&self) -> Option<crate::planning::PlannerCounters> {
        self.hazard
            .as_ref()
            .filter(|h| h.planning)
            .map(|h| h.planner.counters())
    }

    /// The last planner output, if any.
    pub fn planner_output(&self) -> Option<&PlannerOutput> {
        self.hazard.as_ref().and_then(|h| h.last_output.as_ref())
    }

    /// The last finished hazard map, if any.
    pub fn hazard_map(&self) -> Option<&HazardMap> {
        self.hazard.as_ref().and_then(|h| h.mapper.map())
    }

    /// True when hazard avoidance is on (the mapper and planner were built).
    pub(super) fn hazard_on(&self) -> bool {
        self.hazard.is_some()
    }

    /// A hazard map is wanted from the next capture (a localization stop's view).
    pub(super) fn request_map(&mut self) {
        if let Some(h) = self.hazard.as_mut() {
            h.map_wanted = true;
        }
    }

    /// True when a hazard map should be made from the next frame.
    pub(super) fn map_due(&self, filter: &NavFilter) -> bool {
        let Some(h) = self.hazard.as_ref() else {
            return false;
        };
        if !filter.is_running() || h.verdict != PlannerVerdict::Driving {
            return false;
        }
        if h.map_wanted || !h.planned {
            return true;
        }
        let p = filter.state().p_n;
        match h.last_map_xy {
            None => true,
            Some(q) => {
                let d =
                    crate::linalg::sqrt((p.x - q[0]) * (p.x - q[0]) + (p.y - q[1]) * (p.y - q[1]));
                let interval = if h.planning {
                    self.config.map_interval_m
                } else {
                    self.config.localization.map_interval_m
                };
                // A non-finite distance (a diverged estimate) asks for a map too.
                d >= interval || !d.is_finite()
            }
        }
    }

    /// True when the rover stands waiting for a map: a capture is due at once.
    pub(super) fn map_wanted_now(&self) -> bool {
        self.hazard.as_ref().is_some_and(|h| {
            h.verdict == PlannerVerdict::Driving
                && (h.map_wanted || !h.planned)
                && h.gaze_rad.is_none()
        })
    }

    /// Background: start a hazard map on `frame`, taken with the rover at `pose` (rotation
    /// `R -> N`, position in `N`, from the capture clone). Returns true when the map runs (the
    /// frame stays held); false when no map is due or it could not start (counted).
    pub(super) fn start_map(
        &mut self,
        frame: &StereoFrame,
        pose: Option<(Quat, Vec3)>,
        ctx: &mut GoalCtx<'_>,
    ) -> bool {
        if !self.map_due(ctx.filter) {
            return false;
        }
        let xy = {
            let p = ctx.filter.state().p_n;
            [p.x, p.y]
        };
        let calibration = *ctx.calibration;
        let Some(h) = self.hazard.as_mut() else {
            return false;
        };
        let started = pose
            .and_then(|(q, p)| {
                let rot = q.to_rotation_matrix().into_inner();
                CameraPose::from_rover(&rot, &p, &calibration).ok()
            })
            .is_some_and(|camera| h.mapper.start(frame, &camera).is_ok());
        if started {
            h.counters.maps_started = h.counters.maps_started.saturating_add(1);
            h.last_map_xy = Some(xy);
            h.map_wanted = false;
            *ctx.stage = StereoStage::Mapping { items: 0 };
        } else {
            h.counters.map_errors = h.counters.map_errors.saturating_add(1);
        }
        started
    }

    /// Background: advance the hazard map on `frame` by at most `quantum` cost units. Returns
    /// the units used and whether the map (and the planning step after it) finished.
    pub(super) fn map_step(
        &mut self,
        frame: &StereoFrame,
        items: u32,
        quantum: u32,
        ctx: &mut GoalCtx<'_>,
    ) -> (u32, bool) {
        let Some(h) = self.hazard.as_mut() else {
            *ctx.stage = StereoStage::Idle;
            return (0, true);
        };
        match h.mapper.step(frame, quantum) {
            MapProgress::Working { items: total } => {
                *ctx.stage = StereoStage::Mapping { items: total };
                (total.saturating_sub(items).max(1), false)
            }
            MapProgress::Finished(result) => {
                *ctx.stage = StereoStage::Idle;
                match result {
                    Ok(()) => {
                        h.counters.maps = h.counters.maps.saturating_add(1);
                        if h.planning {
                            self.plan_step(ctx);
                        }
                        // Terrain-map localization on the same map: its search keeps the
                        // pipeline busy.
                        if self.loc_after_map(ctx) {
                            return (quantum.max(1), false);
                        }
                    }
                    Err(_) => {
                        h.counters.map_errors = h.counters.map_errors.saturating_add(1);
                        h.map_wanted = true;
                    }
                }
                (quantum.max(1), true)
            }
        }
    }

    /// One RoverBug step on the map just finished, at the current EKF pose.
    fn plan_step(&mut self, ctx: &mut GoalCtx<'_>) {
        let x = *ctx.filter.state();
        let position = [x.p_n.x, x.p_n.y];
        let heading = yaw_of(&x.q_nr);
        let Some(h) = self.hazard.as_mut() else {
            return;
        };
        let Some(map) = h.mapper.map() else {
            return;
        };
        h.counters.last_obstacles = u32::try_from(map.obstacles.len()).unwrap_or(u32::MAX);
        let view = (map.wedge.heading_rad, map.wedge.half_angle_rad);
        let wedge = eroded_wedge(&map.wedge);
        h.counters.plans = h.counters.plans.saturating_add(1);
        // The obstacles' polygons are built one at a time as the planner takes them (a whole
        // map's, 16 x 440 B, would sit on the stack otherwise). Polygons the planner did not take
        // (input refused) are still built to count the refused ones.
        let mut refused = 0u32;
        let mut polygons =
            map.obstacles
                .iter()
                .filter_map(|o| match ConvexPolygon::from_points(&o.vertices) {
                    Ok(p) => Some(p),
                    Err(_) => {
                        refused = refused.saturating_add(1);
                        None
                    }
                });
        let result = h
            .planner
            .plan_each(position, heading, &wedge, polygons.by_ref());
        polygons.for_each(drop);
        h.counters.polygons_refused = h.counters.polygons_refused.saturating_add(refused);
        let out = match result {
            Ok(o) => o,
            Err(_) => {
                h.counters.plan_errors = h.counters.plan_errors.saturating_add(1);
                h.map_wanted = true;
                return;
            }
        };
        let status = out.status;
        let gaze = out.gaze_heading_rad;
        let path = out.path;
        let leg = leg_left(
            status,
            path.as_ref().map(|p| p.waypoints()),
            h.planner.goal(),
            position,
        );
        h.last_output = Some(out);
        h.gaze_rad = None;
        let waypoints = path.as_ref().map(|p| p.waypoints());
        self.follow_plan(status, gaze, waypoints, (position, heading), view, ctx);
        if let Some(remaining) = leg {
            self.mission_leg(position, remaining);
        }
    }

    /// The consequence of one RoverBug step with `status` (module doc): a new guidance path on
    /// the planner's `waypoints`, a gaze towards `gaze` (rad from north) from the rover's
    /// `pose` (`N` position m, heading rad) after a map of wedge `view` (axis heading,
    /// half-angle, rad), the arrival on the line to the goal, or the verdict's stop.
    fn follow_plan(
        &mut self,
        status: PlanStatus,
        gaze: Option<f64>,
        waypoints: Option<&[Point2]>,
        pose: (Point2, f64),
        view: (f64, f64),
        ctx: &mut GoalCtx<'_>,
    ) {
        let (position, heading) = pose;
        let Some(h) = self.hazard.as_mut() else {
            return;
        };
        match status {
            PlanStatus::Driving => {
                let guidance = waypoints
                    .and_then(|w| Path::<MAX_WAYPOINTS>::new(w).ok())
                    .and_then(|p| Guidance::new(p, ctx.drive.config().guidance).ok());
                match guidance {
                    Some(g) => {
                        h.counters.paths = h.counters.paths.saturating_add(1);
                        h.planned = true;
                        ctx.drive.set_guidance(g);
                    }
                    None => {
                        // A path guidance refuses (too short): look again.
                        h.counters.plan_errors = h.counters.plan_errors.saturating_add(1);
                        h.map_wanted = true;
                    }
                }
            }
            PlanStatus::Gaze => {
                h.counters.gazes = h.counters.gazes.saturating_add(1);
                self.begin_gaze(gaze, position, heading, view, ctx.drive);
            }
            PlanStatus::Reached => {
                h.verdict = PlannerVerdict::Reached;
                // Guidance finishes on the straight line to the goal and fault protection
                // checks the arrival as for a path.
                let goal = h.planner.goal().unwrap_or(position);
                let line = Path::<MAX_WAYPOINTS>::new(&[position, goal])
                    .ok()
                    .and_then(|p| Guidance::new(p, ctx.drive.config().guidance).ok());
                match line {
                    Some(g) => ctx.drive.set_guidance(g),
                    None => {
                        if !self.mission_arrived(ctx.filter) {
                            ctx.mode = Some(ModeRequest::Arrived);
                        }
                    }
                }
            }
            PlanStatus::Unreachable(_) => {
                h.verdict = PlannerVerdict::Unreachable;
                // With targets the sequencer drops it and the rover goes on to the next.
                if !self.mission_unreachable() {
                    ctx.mode = Some(ModeRequest::Stop(FaultResponse::GoalUnreachable));
                }
            }
            PlanStatus::Blocked(_) => {
                h.verdict = PlannerVerdict::Blocked;
                if !self.mission_unreachable() {
                    ctx.mode = Some(ModeRequest::Stop(FaultResponse::PlannerBlocked));
                }
            }
        }
    }

    /// The planner asked to look towards `gaze` (rad from north) with the rover at `position`
    /// (`N`, m) heading `heading` (rad), just after a map whose wedge `view` (axis heading,
    /// half-angle, rad) it planned on. The turn is left to [`Self::hazard_command`], unless a
    /// remembered obstacle is within [`ROOM_MOVE_EXTRA_M`] of the room the turn needs and a
    /// short drive straight ahead, inside the wedge just mapped and clear of the remembered
    /// obstacles, gives the room ([`room_move`]): then the rover drives that first (forward,
    /// as VO expects), and maps and plans again at its end. The planner's gaze limit counts
    /// gazes without motion, so a turn given up at its start (the rover mapping where it
    /// stands) would otherwise repeat, unchanged, until the planner halts `Blocked(GazeLimit)`.
    pub(super) fn begin_gaze(
        &mut self,
        gaze: Option<f64>,
        position: Point2,
        heading: f64,
        view: (f64, f64),
        drive: &mut Drive,
    ) {
        let sweep = self.sweep_m;
        let grown = crate::perception::ROVER_HALF_WIDTH_M + self.config.perception.grow_margin_m;
        let planner = self.config.planner;
        let guidance_config = drive.config().guidance;
        let stop_short = guidance_config.goal_tolerance_m;
        let Some(h) = self.hazard.as_mut() else {
            return;
        };
        h.gaze_rad = gaze;
        let Some(target) = gaze else {
            h.map_wanted = true;
            return;
        };
        let turn = crate::guidance::carrot::wrap_pi(target - heading);
        let in_view = libm::fabs(crate::guidance::carrot::wrap_pi(heading - view.0))
            <= view.1 - planner.gaze_margin_rad;
        if !(libm::fabs(turn) > GAZE_TOLERANCE_RAD && in_view) {
            return;
        }
        let outlines = h.planner.memory().grown();
        let need = sweep + GAZE_TURN_MARGIN_M + ROOM_MOVE_EXTRA_M - grown;
        let nearest = outlines
            .iter()
            .map(|p| p.distance(position))
            .fold(f64::INFINITY, f64::min);
        if nearest >= need {
            return;
        }
        let guidance = room_move(
            position,
            heading,
            outlines,
            need,
            planner.clearance_m,
            stop_short,
        )
        .and_then(|end| Path::<MAX_WAYPOINTS>::new(&[position, end]).ok())
        .and_then(|p| Guidance::new(p, guidance_config).ok());
        if let Some(g) = guidance {
            h.gaze_rad = None;
            h.map_wanted = false;
            h.planned = true;
            h.counters.room_moves = h.counters.room_moves.saturating_add(1);
            drive.set_guidance(g);
        }
    }

    /// RG2, from [`Self::guidance_cycle`] before guidance: the hazard navigation's say in the
    /// motor command. `Some(None)`: hold still (waiting for a map); `Some(Some(c))`: turn in
    /// place with body command `c` (gaze); `None`: drive the guidance path.
    pub(super) fn hazard_command(&mut self, filter: &NavFilter) -> Option<Option<VehicleCommand>> {
        let heading = filter.is_running().then(|| yaw_of(&filter.state().q_nr));
        let position = [filter.state().p_n.x, filter.state().p_n.y];
        let sweep = self.sweep_m;
        let grown = crate::perception::ROVER_HALF_WIDTH_M + self.config.perception.grow_margin_m;
        let h = self.hazard.as_mut()?;
        if !h.planning || h.verdict != PlannerVerdict::Driving {
            return None;
        }
        if let (Some(target), Some(yaw)) = (h.gaze_rad, heading) {
            let e = crate::guidance::carrot::wrap_pi(target - yaw);
            if libm::fabs(e) <= GAZE_TOLERANCE_RAD || !e.is_finite() {
                h.gaze_rad = None;
                h.map_wanted = true;
                h.counters.holds = h.counters.holds.saturating_add(1);
                return Some(None);
            }
            // Turning in place sweeps the footprint's corners round a circle wider than the
            // half-width the obstacles are grown by; an obstacle seen earlier (now beside or
            // behind the hazcams) can be inside it (`unreachable`: a ring rock hit during a
            // gaze). Then the gaze is given up and the rover maps where it stands (backing up
            // first was tried: reverse driving broke VO on `unreachable` and `cul-de-sac`,
            // 17 failed updates and a 44 deg VO attitude error; not investigated).
            let nearest = h
                .planner
                .memory()
                .grown()
                .iter()
                .map(|p| p.distance(position))
                .fold(f64::INFINITY, f64::min);
            let room = nearest + grown >= sweep + GAZE_TURN_MARGIN_M;
            if !room {
                h.gaze_rad = None;
                h.map_wanted = true;
                h.counters.gazes_skipped = h.counters.gazes_skipped.saturating_add(1);
                return Some(None);
            }
            let rate = if e > 0.0 {
                GAZE_RATE_RAD_S
            } else {
                -GAZE_RATE_RAD_S
            };
            return Some(Some(VehicleCommand {
                x_dot_m_s: 0.0,
                y_dot_m_s: 0.0,
                yaw_rate_rad_s: rate,
            }));
        }
        if !h.planned || h.map_wanted {
            h.counters.holds = h.counters.holds.saturating_add(1);
            return Some(None);
        }
        None
    }

    /// RG2: guidance reached the end of its path. With hazard avoidance on and the path ending
    /// short of the goal (a planner subgoal), the rover holds and maps again instead of
    /// arriving. Returns true when the end was such a subgoal.
    pub(super) fn hazard_subgoal_reached(&mut self) -> bool {
        let Some(h) = self.hazard.as_mut() else {
            return false;
        };
        if !h.planning || h.verdict != PlannerVerdict::Driving {
            return false;
        }
        h.map_wanted = true;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[allow(unused_imports)]
    use crate::estimation::NominalState;
    #[allow(unused_imports)]
    use crate::flight::nav::*;
    #[allow(unused_imports)]
    use crate::kinematics::ROCKY8;

    /// The turning sweep of Rocky 8: farthest wheel contact 0.393 m ahead plus the 0.10 m
    /// wheel radius, 0.351 m half-width: about 0.61 m, wider than the 0.351 m the obstacles
    /// are grown by across the track.
    #[test]
    fn turn_sweep_covers_the_footprint_corners() {
        let r = turn_sweep_radius(&ROCKY8);
        let expected =
            crate::linalg::sqrt(0.493 * 0.493 + crate::perception::ROVER_HALF_WIDTH_M.powi(2));
        assert!((r - expected).abs() < 0.01, "{r}");
        assert!(r > crate::perception::ROVER_HALF_WIDTH_M + 0.2);
    }

    /// The wall of `multi-target` (x 5.8-6.2 m, y -4.5-9.0 m in `N`) grown as the navigator's
    /// perception grows it (half-width + 0.3 m).
    fn grown_wall() -> ConvexPolygon {
        let g = crate::perception::ROVER_HALF_WIDTH_M
            + NavConfig::rocky8([0.0; 3], 0.0)
                .goal
                .perception
                .grow_margin_m;
        let (x0, x1, y0, y1) = (5.8 - g, 6.2 + g, -4.5 - g, 9.0 + g);
        match ConvexPolygon::from_points(&[[x0, y0], [x1, y0], [x1, y1], [x0, y1]]) {
            Ok(p) => p,
            Err(e) => panic!("wall polygon refused: {e:?}"),
        }
    }

    /// The distance from the grown outlines a gaze turn needs before it starts (sweep, margin
    /// and the room move's extra, less the growth).
    fn room_needed() -> f64 {
        let c = NavConfig::rocky8([0.0; 3], 0.0);
        turn_sweep_radius(&ROCKY8) + GAZE_TURN_MARGIN_M + ROOM_MOVE_EXTRA_M
            - crate::perception::ROVER_HALF_WIDTH_M
            - c.goal.perception.grow_margin_m
    }

    /// HAZ-ROOM-1: a forward room move is found along a heading away from the wall (the
    /// shortest that gives the room, with guidance's stopping tolerance), none towards or
    /// along it, none through an obstacle, none for non-finite input.
    #[test]
    fn room_move_gains_turning_room_forward_only() {
        let wall = [grown_wall()];
        let need = room_needed();
        // The rover 0.154 m off the grown outline (0.805 m from the wall's face), heading
        // 20 deg off the away normal (+x).
        let p = [6.851 + 0.154, 8.2];
        let away = -20.0_f64.to_radians();
        let end = room_move(p, away, &wall, need, 0.15, 0.05);
        let Some(end) = end else {
            panic!("no room move away from the wall")
        };
        let s = libm::hypot(end[0] - p[0], end[1] - p[1]);
        assert!((0.1 - 1e-9..=ROOM_MOVE_MAX_M + 1e-9).contains(&s), "{s}");
        assert!(wall[0].distance(end) >= need, "{end:?}");
        // Towards the wall and along it: no room within the limit.
        assert_eq!(
            room_move(p, 160.0_f64.to_radians(), &wall, need, 0.15, 0.05),
            None
        );
        assert_eq!(
            room_move(p, -90.0_f64.to_radians(), &wall, need, 0.15, 0.05),
            None
        );
        // A rock 0.2 m ahead (its grown outline): in the way.
        let rock =
            match ConvexPolygon::from_points(&[[7.25, 8.0], [7.6, 8.0], [7.6, 8.4], [7.25, 8.4]]) {
                Ok(r) => r,
                Err(e) => panic!("{e:?}"),
            };
        assert_eq!(
            room_move(p, 0.0, &[wall[0].clone(), rock], need, 0.15, 0.05),
            None
        );
        assert_eq!(
            room_move([f64::NAN, 0.0], 0.0, &wall, need, 0.15, 0.05),
            None
        );
    }

    /// A goal-directed navigator (goal (10, 0)) with the wall in the planner's memory and the
    /// EKF running at rest at `xy`, heading `yaw` (rad).
    fn navigator_by_the_wall(xy: [f64; 2], yaw: f64) -> Navigator {
        let mut config = NavConfig::rocky8([0.0; 3], 0.0);
        config.goal.hazard_avoidance = true;
        let mut nav = match Navigator::new(
            config,
            &[[0.0, 0.0], [10.0, 0.0]],
            &crate::flight::nav::test_hazcam_calibration(),
        ) {
            Ok(n) => n,
            Err(e) => panic!("navigator refused: {e:?}"),
        };
        nav.start_vo();
        let wedge = Wedge {
            apex: xy,
            heading_rad: yaw,
            half_angle_rad: 0.6,
            min_range_m: 0.3,
            max_range_m: 2.0,
        };
        let Some(h) = nav.goal.hazard.as_mut() else {
            panic!("hazard navigation not built")
        };
        assert!(h.planner.plan(xy, yaw, &wedge, &[grown_wall()]).is_ok());
        let mut x = crate::estimation::NominalState::at_rest(1_000_000);
        x.p_n = Vec3::new(xy[0], xy[1], 0.0);
        x.q_nr = Quat::from_euler_angles(0.0, 0.0, yaw);
        let p0 = crate::estimation::CoreCov::identity() * 1e-4;
        assert!(nav.filter.ekf_mut().reset(x, &p0).is_ok());
        nav.filter.set_running();
        nav.mode = NavMode::Driving;
        nav
    }

    /// HAZ-ROOM-2 (`multi-target` with 54 kJ, SIL-SEQ-2): riding the wall 0.804 m from its
    /// face with 0.805 m needed for the turn, the planner asks to look 58 deg to the side.
    /// The rover drives forward out of the wall's reach first (a room move, no gaze given up);
    /// at its end it maps again. Without the move the gaze was given up, the rover mapped in
    /// place and the planner asked again, until `Blocked(GazeLimit)`.
    #[test]
    fn gaze_without_turning_room_drives_forward_first() {
        let xy = [6.851 + 0.153, 8.2];
        let yaw = -20.0_f64.to_radians();
        let mut nav = navigator_by_the_wall(xy, yaw);
        nav.goal.begin_gaze(
            Some(-78.0_f64.to_radians()),
            xy,
            yaw,
            (yaw, 0.6),
            &mut nav.drive,
        );
        // Drive the guidance path (not a hold, not a turn in place).
        assert_eq!(nav.goal.hazard_command(&nav.filter), None);
        let c = nav.goal.hazard_counters();
        assert_eq!((c.room_moves, c.gazes_skipped), (1, 0));
        let Some(g) = nav.drive.guidance() else {
            panic!("no guidance path")
        };
        let w = g.path().waypoints();
        let (a, b) = match w {
            [a, b] => (*a, *b),
            _ => panic!("{w:?}"),
        };
        assert_eq!(a, xy);
        let heading = libm::atan2(b[1] - a[1], b[0] - a[0]);
        assert!((heading - yaw).abs() < 1e-9, "{heading}");
        // At the path's end the rover maps again (a subgoal).
        assert!(nav.goal.hazard_subgoal_reached());
        assert!(nav.goal.map_wanted_now());
    }

    /// HAZ-ROOM-3: with room to spare, or facing the wall, or with a gaze within tolerance,
    /// the gaze is left to the turn in place (no room move).
    #[test]
    fn gaze_with_room_or_no_forward_way_turns_in_place() {
        // 0.4 m off the grown outline: room to spare; the turn starts.
        let xy = [6.851 + 0.4, 8.2];
        let yaw = -20.0_f64.to_radians();
        let mut nav = navigator_by_the_wall(xy, yaw);
        nav.goal.begin_gaze(
            Some(-78.0_f64.to_radians()),
            xy,
            yaw,
            (yaw, 0.6),
            &mut nav.drive,
        );
        assert!(
            matches!(nav.goal.hazard_command(&nav.filter), Some(Some(c)) if c.yaw_rate_rad_s < 0.0)
        );
        assert_eq!(nav.goal.hazard_counters().room_moves, 0);
        // Facing the wall at the limit: no forward way; the gaze is given up as before.
        let xy = [6.851 + 0.15, 8.2];
        let yaw = 170.0_f64.to_radians();
        let mut nav = navigator_by_the_wall(xy, yaw);
        nav.goal.begin_gaze(
            Some(90.0_f64.to_radians()),
            xy,
            yaw,
            (yaw, 0.6),
            &mut nav.drive,
        );
        assert_eq!(nav.goal.hazard_command(&nav.filter), Some(None));
        let c = nav.goal.hazard_counters();
        assert_eq!((c.room_moves, c.gazes_skipped), (0, 1));
        // A heading outside the wedge just mapped: not driven blind.
        let yaw = -20.0_f64.to_radians();
        let mut nav = navigator_by_the_wall(xy, yaw);
        nav.goal.begin_gaze(
            Some(-78.0_f64.to_radians()),
            xy,
            yaw,
            (yaw + 1.0, 0.6),
            &mut nav.drive,
        );
        assert_eq!(nav.goal.hazard_counters().room_moves, 0);
    }
}
