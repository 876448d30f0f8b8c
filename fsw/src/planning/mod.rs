//! RoverBug path planning (V99 sec. 4; S. Laubach and J. Burdick, ICRA 1999): a sensor-based
//! planner for a rover whose cameras see a limited wedge, over convex obstacle polygons.
//!
//! - [`geometry`]: convex polygons (hull, outer reduction, miter inflation), segment and point
//!   tests, tangents (angular intervals) from a point, polygon intersection.
//! - [`wedge`]: the visible wedge (apex, heading, half-angle, near and far range) and clipping.
//! - [`memory`]: the remembered obstacles at fixed capacity, merged by overlap, with connected
//!   components.
//! - [`ltg`]: the local tangent graph and its shortest paths (Dijkstra, no heap).
//! - [`planner`]: the persistent [`Planner`] and its step [`Planner::plan`]: motion-to-goal,
//!   boundary following with virtual sliding, gaze requests, loop detection.
//!
//! Frame: the navigation frame `N` on the ground plane, `[x, y]` = (north, east), m; yaw from
//! north, positive east (to the rover's right). Output paths are [`crate::guidance::Path`]s of
//! waypoints in the same frame. Design, V99 mapping, capacities and measured figures:
//! `docs/planning.md`.

pub mod geometry;
pub mod ltg;
pub mod memory;
pub mod planner;
pub mod wedge;

pub use geometry::{ConvexPolygon, GeometryError, PointLocation, MAX_VERTICES};
pub use memory::{InsertOutcome, ObstacleMemory, MEMORY_CAPACITY};
pub use planner::{
    BlockedReason, FollowState, Mode, PlanError, PlanStatus, Planner, PlannerConfig,
    PlannerCounters, PlannerOutput, Side, UnreachableReason, PATH_CAPACITY,
};
pub use wedge::Wedge;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_world;
