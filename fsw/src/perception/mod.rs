//! # Hazard perception from the hazcam pair (V99 sec. 4)
//!
//! RoverBug (V99 sec. 4, Laubach & Burdick) plans over "a streamlined local model of convex
//! polygons enveloping detected obstacles" inside "the visible region ranged by each stereo pair
//! [...] roughly a wedge of the ground plane, with limited downrange radius R and half-angle
//! alpha". This module builds that model from one rectified hazcam pair and the camera pose at
//! capture (see `docs/perception.md`):
//!
//! 1. **Ranging** ([`mapper`]): the left image is sampled where the cells of a ground lattice
//!    project under a ground-plane prior (the rover's wheel-contact plane), every sample is
//!    matched along its row with the visual-odometry matcher ([`crate::vo::stereo`]:
//!    normalised cross-correlation, uniqueness, range-end, depth-discontinuity and left-right
//!    rules, sub-pixel refinement) over a disparity window set by the prior, and triangulated
//!    (H04 eq. 1-8) into world points.
//! 2. **Terrain grid** ([`grid`]): points are accumulated per cell of a local-level grid
//!    (count, lowest and highest point, sum of heights); each cell is classified
//!    unknown / traversable / hazard from the step, slope and roughness of its neighbourhood
//!    against the Rocky 8 geometry.
//! 3. **Obstacles** ([`obstacles`]): connected hazard cells (bounded flood fill) become convex
//!    hulls (monotone chain), grown by the rover half-width plus a margin (Minkowski sum with a
//!    regular polygon), counter-clockwise in the world `x-y` plane, plus the visible wedge.
//!
//! Frames: world `W` = navigation frame `N` (x north, y east, z down, m); camera `K` (x right,
//! y down, z optical axis; [`crate::vo`]); grid `G`: local-level, origin at the left camera's
//! nadir, `x_G` the rover's forward axis projected on the level plane (heading), `y_G` to its
//! right, `z_G = z_W` down. Heights are up-positive, relative to the camera centre. Polygons
//! and the wedge are in the `x-y` plane of `W`; "counter-clockwise" means a positive signed area
//! `sum(x_i y_(i+1) - x_(i+1) y_i) / 2` in those coordinates (seen from below, the side `z_W`
//! points to; on a north-up map with east to the right it reads clockwise).
//!
//! No allocation, no recursion, every loop bounded, every failure a [`PerceptionError`] value.

// `!(x > limit)` is used on purpose: it is true for NaN, so a non-finite value fails the check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod footprint;
pub mod grid;
pub mod mapper;
pub mod obstacles;

#[cfg(test)]
mod render;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_obstacles;

pub use footprint::Footprint;
pub use grid::{CellClass, GridFrame, TerrainGrid};
pub use mapper::{HazardMapper, MapProgress, MapWork};
pub use obstacles::ConvexPolygon;

use crate::kinematics::geometry::WHEEL_RADIUS_M;
use crate::vo::VoConfig;

/// Side of a grid cell, m. 0.1 m: half a Rocky 8 wheel diameter (0.2 m), so that a
/// wheel-sized neighbourhood (3x3 cells, 0.3 m) resolves a step under one wheel, and about the
/// spacing of the stereo samples on the ground at 3 m (`docs/perception.md`).
pub const CELL_SIZE_M: f64 = 0.1;
/// Cells along `x_G` (forward): the grid covers `x_G` in `[GRID_X_MIN_M, GRID_X_MIN_M + 4.0)`
/// m. The hazcam (0.7 m above the ground, 45 deg down, 64 deg vertical field) sees the level
/// ground from 0.16 m to 3.0 m ahead of its nadir; 4 m leaves room for a rover pitched down
/// or for terrain rising ahead.
pub const GRID_ROWS: usize = 40;
/// Cells along `y_G` (right): `y_G` in `[GRID_Y_MIN_M, -GRID_Y_MIN_M)`, m; the footprint is
/// 4.4 m wide at 3 m.
pub const GRID_COLS: usize = 48;
/// Cells of the grid.
pub const GRID_CELLS: usize = GRID_ROWS * GRID_COLS;
/// Near edge of the grid along `x_G`, m (the camera's nadir).
pub const GRID_X_MIN_M: f64 = 0.0;
/// Left edge of the grid along `y_G`, m.
pub const GRID_Y_MIN_M: f64 = -(GRID_COLS as f64) * CELL_SIZE_M / 2.0;
/// Most obstacle polygons of one map ([`HazardMap::obstacles`]).
pub const MAX_OBSTACLES: usize = 16;
/// Most vertices of one obstacle polygon.
pub const MAX_POLYGON_VERTICES: usize = 24;
/// Sides of the regular polygon the hulls are grown with (circumscribing the disc of the
/// growth radius, so the grown polygon contains the disc-grown hull).
pub const GROW_SIDES: usize = 8;
/// Capacity of the flood fill's queue, cells. The breadth-first front of an 8-connected fill
/// of the 40x48 grid holds at most about `2 * (40 + 48)` cells; a larger component front splits
/// the component ([`MapCounts::fill_overflows`]).
pub const FILL_QUEUE: usize = 256;

/// Half the width of Rocky 8 over its wheels, m: half the track between the wheel centres
/// (0.622 m, `docs/kinematics.md`, KIN-1, from H04 Table 2) plus half the wheel width (0.08 m,
/// the simulator's assumption, `sim-host` `Wheel::rocky8`; no published figure).
pub const ROVER_HALF_WIDTH_M: f64 = 0.311 + 0.04;

/// Ground clearance of the Rocky 8 body, m. **Assumption**: H04 Table 2 places the lowest
/// joints between the wheels, the bogie pivots, 0.227 m above the level contact plane (0.127 m
/// above the axles, [`crate::kinematics::geometry::ROCKY8`]); the body and the pivot housings
/// are taken to stay above 0.20 m. To be replaced by the measured value.
pub const BODY_CLEARANCE_M: f64 = 0.20;

/// Hazard thresholds of a grid cell (`docs/perception.md` gives the reasons).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HazardLimits {
    /// Largest step, m: the highest point of a cell above the lowest point of its wheel-sized
    /// neighbourhood (3x3 cells), both measured from the local ground plane. Default one wheel
    /// radius (0.10 m): half the diameter a rocker-bogie is credited with climbing, and half
    /// the body clearance [`BODY_CLEARANCE_M`].
    pub max_step_m: f64,
    /// Largest slope of the local ground plane, rad. Default 20 deg: the rover's slip
    /// compensation is designed and tested for 10-15 deg sandy slopes (H04, H05); 20 deg
    /// leaves 5 deg for the plane-fit error and stays well below the 30 deg tilt limit of flight
    /// rovers (REFERENCE.md).
    pub max_slope_rad: f64,
    /// Largest root-mean-square residual of the local ground plane, m. Default 0.05 m (half a
    /// wheel radius): bumps the suspension averages out stay below it.
    pub max_roughness_m: f64,
    /// Fewest known cells of the 5x5 neighbourhood for a plane fit (at least 3).
    pub plane_min_cells: u8,
}

impl Default for HazardLimits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl HazardLimits {
    /// The default limits (as [`Default`], usable in a `const`).
    pub const DEFAULT: Self = Self {
        max_step_m: WHEEL_RADIUS_M,
        max_slope_rad: 20.0 * core::f64::consts::PI / 180.0,
        max_roughness_m: 0.05,
        plane_min_cells: 6,
    };
}

/// Indices of the work kinds ([`MapWork`]) in [`PerceptionConfig::work_cost`].
pub const WORK_KINDS: usize = 6;

/// Tuning of the hazard mapper. [`PerceptionConfig::default`] suits the Rocky 8 hazcams.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PerceptionConfig {
    /// Stereo matching and triangulation thresholds (the visual odometry's, [`VoConfig`]); its
    /// disparity range is replaced per sample by the prior's window, its image checks apply
    /// to both images.
    pub stereo: VoConfig,
    /// Spacing of the sample lattice on the ground, in cells: one sample at the centre of one
    /// cell in `sample_spacing_cells` of each grid row, shifted by one cell per row (1: every
    /// cell; 2: a checkerboard).
    pub sample_spacing_cells: u8,
    /// Disparity window of a sample: tallest surface above the ground-plane prior (the rover's
    /// wheel-contact plane at capture) searched for, m. Must stay below the camera's height
    /// above the prior (0.7 m).
    pub max_height_above_m: f64,
    /// Disparity window: deepest ground below the prior plane searched for, m.
    pub max_depth_below_m: f64,
    /// Largest standard deviation of a point's height (from its triangulation covariance, H04
    /// eq. 8), m; less precise points are dropped.
    pub max_height_sigma_m: f64,
    /// Hazard thresholds.
    pub limits: HazardLimits,
    /// Growth of the obstacles: the rover half-width plus this margin, m (pose and ranging
    /// errors).
    pub grow_margin_m: f64,
    /// Fewest hazard cells of a component for it to become an obstacle. A wrong match that
    /// passes the stereo rules makes one high point, which flags its own cell only (the step is
    /// measured from a cell's highest point down), so 2 drops it; a hazard narrower than one
    /// cell (0.1 m) is missed with it.
    pub min_obstacle_cells: u16,
    /// Fewest points in the hazard cells of a component for it to become an obstacle.
    pub min_obstacle_points: u16,
    /// Most obstacles kept per map (at most [`MAX_OBSTACLES`]; the planner's budget). The
    /// nearest are kept ([`MapCounts::obstacles_dropped`]).
    pub max_obstacles: u8,
    /// Fewest matched points for a map ([`PerceptionError::TooFewPoints`] below).
    pub min_points: u16,
    /// Largest range of the reported wedge from its apex, m.
    pub max_wedge_range_m: f64,
    /// Cost of one work item of each [`MapWork`] kind (indexed by `kind as usize`), units of
    /// about 10 000 rover-CPU instructions (as [`VoConfig::work_cost`]); 0 counts as 1. The
    /// defaults are the largest items measured on the Cortex-M7 model (four rendered scenes,
    /// sample spacings 1-4, `docs/perception.md`), rounded up: check 262 k, wedge 18 k, sample
    /// 238 k, classify 162 k, obstacle 87 k (a 110-cell component), finish 0.1 k instructions.
    pub work_cost: [u16; WORK_KINDS],
}

impl Default for PerceptionConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl PerceptionConfig {
    /// The default settings (as [`Default`], usable in a `const`).
    pub const DEFAULT: Self = Self {
        stereo: VoConfig::DEFAULT,
        sample_spacing_cells: 2,
        max_height_above_m: 0.45,
        max_depth_below_m: 0.5,
        max_height_sigma_m: 0.05,
        limits: HazardLimits::DEFAULT,
        grow_margin_m: 0.1,
        min_obstacle_cells: 2,
        min_obstacle_points: 3,
        max_obstacles: MAX_OBSTACLES as u8,
        min_points: 30,
        max_wedge_range_m: 3.5,
        work_cost: [27, 2, 24, 17, 9, 1],
    };

    /// True when every field is finite and in range (and the stereo part is valid).
    pub fn is_valid(&self) -> bool {
        let l = &self.limits;
        let finite = [
            self.max_height_above_m,
            self.max_depth_below_m,
            self.max_height_sigma_m,
            self.grow_margin_m,
            self.max_wedge_range_m,
            l.max_step_m,
            l.max_slope_rad,
            l.max_roughness_m,
        ]
        .iter()
        .all(|v| v.is_finite());
        finite
            && self.stereo.is_valid()
            && self.sample_spacing_cells >= 1
            && usize::from(self.sample_spacing_cells) <= GRID_COLS
            && self.max_height_above_m > 0.0
            && self.max_depth_below_m >= 0.0
            && self.max_height_sigma_m > 0.0
            && l.max_step_m > 0.0
            && l.max_step_m <= BODY_CLEARANCE_M
            && l.max_slope_rad > 0.0
            && l.max_slope_rad < core::f64::consts::FRAC_PI_2
            && l.max_roughness_m > 0.0
            && (3..=25).contains(&l.plane_min_cells)
            && self.grow_margin_m >= 0.0
            && self.max_wedge_range_m > 0.0
            && self.min_points >= 3
            && self.max_obstacles >= 1
            && usize::from(self.max_obstacles) <= MAX_OBSTACLES
    }
}

/// Why no hazard map was produced (every failure is a value, never a panic).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PerceptionError {
    /// The configuration is out of range ([`PerceptionConfig::is_valid`]).
    InvalidConfig,
    /// The calibration has non-finite or non-positive intrinsics or a mounting that is not a
    /// rotation.
    InvalidCalibration,
    /// The camera pose has a non-finite value or a rotation that is not a rotation (1e-6).
    InvalidPose,
    /// The rover's forward axis or its contact plane is within 30 deg of vertical (no
    /// heading, or no ground plane to sample).
    PoseOutOfRange,
    /// An image is not `IMAGE_WIDTH_PX * IMAGE_HEIGHT_PX` bytes.
    WrongImageSize,
    /// An image has (almost) no contrast ([`VoConfig::min_image_std`]).
    BlankImage,
    /// Too many pixels of an image are clipped at 0 or 255.
    SaturatedImage,
    /// Fewer than [`PerceptionConfig::min_points`] samples were matched and triangulated
    /// (textureless or unmatched images).
    TooFewPoints {
        /// Points accumulated in the grid.
        matched: u16,
    },
    /// [`HazardMapper::start`] was called while a map is being built.
    Busy,
    /// [`HazardMapper::step`] was called without a started map.
    NotStarted,
    /// The frame passed to [`HazardMapper::step`] is not the one the map started with.
    FrameChanged,
}

impl From<crate::vo::VoError> for PerceptionError {
    fn from(e: crate::vo::VoError) -> Self {
        use crate::vo::VoError as V;
        match e {
            V::WrongImageSize => Self::WrongImageSize,
            V::BlankImage => Self::BlankImage,
            V::SaturatedImage => Self::SaturatedImage,
            V::InvalidCalibration => Self::InvalidCalibration,
            _ => Self::InvalidConfig,
        }
    }
}

/// Pose of the left hazcam at capture in the world frame `W` (from the estimator):
/// `p_W = rot_world_from_camera * p_K + position_world_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// Rotation from the camera frame `K` to `W`.
    pub rot_world_from_camera: crate::types::Mat3,
    /// Left camera centre in `W`, m.
    pub position_world_m: crate::types::Vec3,
}

impl CameraPose {
    /// The left camera's pose from the rover's pose in `W` (`p_W = rot_world_from_rover * p_R +
    /// rover_position_world_m`) and the camera mounting of `calibration`.
    pub fn from_rover(
        rot_world_from_rover: &crate::types::Mat3,
        rover_position_world_m: &crate::types::Vec3,
        calibration: &rover_hal::StereoCalibration,
    ) -> Result<Self, PerceptionError> {
        let mount = crate::vo::motion::CameraMount::from_calibration(calibration)
            .map_err(|_| PerceptionError::InvalidCalibration)?;
        Ok(Self {
            rot_world_from_camera: rot_world_from_rover * mount.rot_rover_from_camera,
            position_world_m: rot_world_from_rover * mount.pos_camera_in_rover_m
                + rover_position_world_m,
        })
    }

    /// True when every value is finite and the rotation is orthonormal with determinant +1
    /// (to 1e-6).
    pub fn is_valid(&self) -> bool {
        let r = &self.rot_world_from_camera;
        let finite = r
            .iter()
            .chain(self.position_world_m.iter())
            .all(|v| v.is_finite());
        finite
            && (r.transpose() * r - crate::types::Mat3::identity()).amax() < 1e-6
            && (r.determinant() - 1.0).abs() < 1e-6
    }
}

/// A point of the world `x-y` plane, m (`[x north, y east]`).
pub type Point2 = [f64; 2];

/// The visible wedge (V99 sec. 4: "a wedge of the ground plane, with limited downrange radius R
/// and half-angle alpha"): the annular sector of the world `x-y` plane, apex at the left
/// camera's nadir, within which both hazcams see the ground-plane prior and the grid holds it.
/// A point `p` is inside when its distance `r` from the apex is in `[min_range_m, max_range_m]`
/// and its bearing is within `half_angle_rad` of `heading_rad`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wedge {
    /// Apex `[x, y]` in `W`, m.
    pub apex_m: Point2,
    /// Direction of the wedge's axis, rad from `x_W` (north) towards `y_W` (east).
    pub heading_rad: f64,
    /// Half-angle `alpha`, rad.
    pub half_angle_rad: f64,
    /// Inner radius, m.
    pub min_range_m: f64,
    /// Downrange radius `R`, m (0 when nothing is visible).
    pub max_range_m: f64,
}

impl Wedge {
    /// True when the world point `p` (`[x, y]`, m) is inside the wedge.
    pub fn contains(&self, p: Point2) -> bool {
        let (dx, dy) = (p[0] - self.apex_m[0], p[1] - self.apex_m[1]);
        let r = libm::hypot(dx, dy);
        if !(r >= self.min_range_m && r <= self.max_range_m) {
            return false;
        }
        let (s, c) = libm::sincos(self.heading_rad);
        // Bearing relative to the heading.
        let bearing = libm::atan2(-s * dx + c * dy, c * dx + s * dy);
        libm::fabs(bearing) <= self.half_angle_rad
    }

    /// An empty wedge at `apex_m` (nothing visible).
    pub const fn empty(apex_m: Point2, heading_rad: f64) -> Self {
        Self {
            apex_m,
            heading_rad,
            half_angle_rad: 0.0,
            min_range_m: 0.0,
            max_range_m: 0.0,
        }
    }
}

/// Counts of one map (for telemetry and for judging the map). Counts saturate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MapCounts {
    /// Samples matched along their row (the lattice points inside both images).
    pub samples: u16,
    /// Samples matched, triangulated, precise enough and inside the grid.
    pub matched: u16,
    /// Stereo rejections per reason (the visual odometry's reasons).
    pub rejects: crate::vo::StereoRejectCounts,
    /// Triangulated points dropped for a height standard deviation above the limit.
    pub imprecise: u16,
    /// Triangulated points outside the grid.
    pub outside_grid: u16,
    /// Normalised cross-correlation evaluations of the matcher (row scan, left-right scan,
    /// depth-discontinuity halves, counted up to the rule that ended each match: an upper
    /// bound; the sub-pixel refinement is not a correlation).
    pub ncc_evaluations: u32,
    /// Cells with at least one point.
    pub cells_known: u16,
    /// Cells with points but too few known neighbours for a ground plane (left unknown).
    pub cells_sparse: u16,
    /// Cells classified hazard.
    pub cells_hazard: u16,
    /// Cells whose centre is inside the wedge (before any range cut).
    pub wedge_cells: u16,
    /// Of those, cells covered by points: with points in the cell or in one of its four
    /// neighbours (the sample lattice puts a sample in one cell of `sample_spacing_cells`).
    pub wedge_cells_known: u16,
    /// Connected hazard components found.
    pub components: u16,
    /// Components dropped for fewer than [`PerceptionConfig::min_obstacle_cells`] cells or
    /// [`PerceptionConfig::min_obstacle_points`] points.
    pub small_dropped: u16,
    /// Obstacles dropped because [`PerceptionConfig::max_obstacles`] were already kept (the
    /// farthest are dropped; the wedge's range is cut before the nearest dropped one).
    pub obstacles_dropped: u16,
    /// Vertices removed to fit [`MAX_POLYGON_VERTICES`] (each removal enlarges the polygon).
    pub vertices_reduced: u16,
    /// Flood fills whose queue was full (the component was split in several obstacles).
    pub fill_overflows: u16,
    /// Work items this map used.
    pub work_items: u32,
}

impl MapCounts {
    /// All counts zero (as [`Default`], usable in a `const`).
    pub const EMPTY: Self = Self {
        samples: 0,
        matched: 0,
        rejects: crate::vo::VoQuality::EMPTY.stereo_rejects,
        imprecise: 0,
        outside_grid: 0,
        ncc_evaluations: 0,
        cells_known: 0,
        cells_sparse: 0,
        cells_hazard: 0,
        wedge_cells: 0,
        wedge_cells_known: 0,
        components: 0,
        small_dropped: 0,
        obstacles_dropped: 0,
        vertices_reduced: 0,
        fill_overflows: 0,
        work_items: 0,
    };
}

/// The hazard map of one hazcam pair (V99 sec. 4): obstacles as grown convex polygons and the
/// visible wedge, world frame `W`.
#[derive(Debug, Clone, PartialEq)]
pub struct HazardMap {
    /// Capture time of the pair, microseconds since boot.
    pub capture_t_us: u64,
    /// Obstacles: convex, counter-clockwise in the world `x-y` plane (m), each the hull of a
    /// connected set of hazard cells grown by [`ROVER_HALF_WIDTH_M`] plus
    /// [`PerceptionConfig::grow_margin_m`] (configuration space of a point rover), nearest
    /// first.
    pub obstacles: heapless::Vec<ConvexPolygon, MAX_OBSTACLES>,
    /// The visible wedge.
    pub wedge: Wedge,
    /// The grid's placement (to read [`HazardMapper::grid`]).
    pub grid: GridFrame,
    /// Counts.
    pub counts: MapCounts,
}

impl HazardMap {
    /// An empty map (no obstacles, empty wedge at the origin).
    pub fn empty() -> Self {
        Self::EMPTY
    }

    /// A map with no obstacles and an empty wedge (as [`Self::empty`], usable in a `const`).
    pub const EMPTY: Self = Self {
        capture_t_us: 0,
        obstacles: heapless::Vec::new(),
        wedge: Wedge::empty([0.0, 0.0], 0.0),
        grid: GridFrame {
            origin_world_m: [0.0; 3],
            heading_rad: 0.0,
            heading_cos: 0.0,
            heading_sin: 0.0,
        },
        counts: MapCounts::EMPTY,
    };

    /// Make this map [`Self::empty`] in place (the obstacle list is emptied, not rebuilt as a
    /// temporary).
    pub fn clear(&mut self) {
        self.capture_t_us = 0;
        self.obstacles.clear();
        self.wedge = Wedge::empty([0.0, 0.0], 0.0);
        self.grid = GridFrame::default();
        self.counts = MapCounts::EMPTY;
    }

    /// Fraction of the wedge's grid cells covered by points (0..1; 0 for an empty wedge; see
    /// [`MapCounts::wedge_cells_known`]).
    pub fn wedge_known_fraction(&self) -> f64 {
        if self.counts.wedge_cells == 0 {
            0.0
        } else {
            f64::from(self.counts.wedge_cells_known) / f64::from(self.counts.wedge_cells)
        }
    }
}
