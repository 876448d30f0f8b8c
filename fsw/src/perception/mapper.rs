//! The resumable hazard mapper: [`HazardMapper`] owns the grid and every scratch buffer and
//! builds one [`HazardMap`] from a hazcam pair in bounded work items, so the executive can run it
//! in the slack of its minor frames like the visual odometry ([`crate::vo::pipeline`]).
//!
//! Work items ([`MapWork`]): image check (8: four row bands of each image), wedge (one per
//! candidate half-angle, [`WEDGE_CANDIDATES`], [`Footprint::wedge_candidate`]), sample (one
//! stereo match and triangulation, after skipping at most [`SKIP_PER_ITEM`] lattice points
//! outside the images), classify (one grid row), obstacle (one connected component: flood fill,
//! hull, growth), finish (1). The sequence of items depends only on the inputs, so a map is
//! bit-identical for any work budget.

use super::footprint::{Footprint, WEDGE_CANDIDATES};
use super::grid::{cell_of, TerrainGrid};
use super::obstacles::{
    component_polygon, distance_to_polygon, flood_fill, Component, ConvexPolygon,
};
use super::{
    CameraPose, HazardMap, MapCounts, PerceptionConfig, PerceptionError, Point2, Wedge, FILL_QUEUE,
    GRID_CELLS, GRID_COLS, GRID_ROWS, MAX_POLYGON_VERTICES, ROVER_HALF_WIDTH_M, WORK_KINDS,
};
use crate::vo::image::{CheckSums, Image, CHECK_BANDS};
use crate::vo::motion::CameraMount;
use crate::vo::stereo::{match_and_triangulate, PinholeStereo, StereoReject};
use crate::vo::VoConfig;
use rover_hal::{StereoCalibration, StereoFrame};

/// Lattice points outside the images skipped by one sample work item at most.
pub const SKIP_PER_ITEM: u16 = 64;
/// Occluded cells behind a hazard cell added to its obstacle (0.3 m: the hidden half of a rock
/// 0.6 m deep; a rock is taken to be about as deep as it is wide).
pub const SHADOW_CELLS: u8 = 3;

/// The kinds of work item of a map, in pipeline order (index into
/// [`PerceptionConfig::work_cost`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapWork {
    /// One row band of the left or the right image check.
    Check = 0,
    /// One candidate half-angle of the visible wedge.
    Wedge = 1,
    /// One stereo sample (match, triangulation, accumulation).
    Sample = 2,
    /// Classification of one grid row.
    Classify = 3,
    /// One obstacle component (flood fill, hull, growth), or the end of the search.
    Obstacle = 4,
    /// The map's commit.
    Finish = 5,
}

impl MapWork {
    /// All kinds, in pipeline order.
    pub const ALL: [MapWork; WORK_KINDS] = [
        MapWork::Check,
        MapWork::Wedge,
        MapWork::Sample,
        MapWork::Classify,
        MapWork::Obstacle,
        MapWork::Finish,
    ];

    /// Lower-case name for reports.
    pub const fn name(self) -> &'static str {
        match self {
            MapWork::Check => "check",
            MapWork::Wedge => "wedge",
            MapWork::Sample => "sample",
            MapWork::Classify => "classify",
            MapWork::Obstacle => "obstacle",
            MapWork::Finish => "finish",
        }
    }
}

/// What [`HazardMapper::step`] reports ([`crate::exec::Progress`]: working, or finished; when
/// `Ok` [`HazardMapper::map`] holds the map).
pub type MapProgress = crate::exec::Progress<Result<(), PerceptionError>>;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Idle,
    Check {
        image: u8,
        band: u8,
        sums: CheckSums,
    },
    Wedge {
        candidate: u8,
    },
    Sample {
        next: u16,
    },
    Classify {
        row: u8,
    },
    Obstacles {
        next: u16,
    },
    Finish,
}

/// Builds hazard maps (V99 sec. 4) with all buffers preallocated: the terrain grid, the flood
/// fill's marks and component, the map. Use: [`Self::start`] with a stereo frame and the
/// camera pose at capture, then [`Self::step`] with the same frame until it reports
/// [`MapProgress::Finished`] (or [`Self::run_to_completion`]); the map is then [`Self::map`].
#[derive(Debug, Clone)]
pub struct HazardMapper {
    config: PerceptionConfig,
    camera: PinholeStereo,
    mount: CameraMount,
    grid: TerrainGrid,
    visited: [bool; GRID_CELLS],
    component: Component,
    /// Geometry of the capture (pose, ground-plane prior, grid frame).
    view: Footprint,
    phase: Phase,
    frame_t_us: u64,
    frame_sequence: u32,
    /// Best wedge so far and its area (m^2).
    wedge: (f64, Wedge),
    /// Range from the wedge's apex below which every kept obstacle lies (cut when an obstacle
    /// is dropped), m.
    range_cut_m: f64,
    work: MapCounts,
    map: HazardMap,
    map_valid: bool,
}

impl crate::exec::FrameJob for HazardMapper {
    type Error = PerceptionError;
    const NOT_STARTED: PerceptionError = PerceptionError::NotStarted;
    const FRAME_CHANGED: PerceptionError = PerceptionError::FrameChanged;

    fn running(&self) -> bool {
        self.phase != Phase::Idle
    }

    fn frame(&self) -> crate::exec::FrameKey {
        crate::exec::FrameKey {
            capture_t_us: self.frame_t_us,
            sequence: self.frame_sequence,
        }
    }

    fn stop(&mut self) {
        self.phase = Phase::Idle;
    }

    fn items(&self) -> u32 {
        self.work.work_items
    }
}

impl HazardMapper {
    /// A mapper for `calibration` with `config`; [`PerceptionError::InvalidConfig`] or
    /// [`PerceptionError::InvalidCalibration`] when they are out of range.
    pub fn new(
        config: PerceptionConfig,
        calibration: &StereoCalibration,
    ) -> Result<Self, PerceptionError> {
        let mut mapper = Self::EMPTY;
        mapper.init(config, calibration)?;
        Ok(mapper)
    }

    /// A placeholder without calibration (default settings, zero camera, empty grid and map):
    /// the compile-time value of a statically allocated navigator's hazard mapper before
    /// [`Self::init`]. Not meant to run ([`Self::init`] first).
    pub const EMPTY: Self = Self {
        config: PerceptionConfig::DEFAULT,
        camera: PinholeStereo {
            fx_px: 0.0,
            fy_px: 0.0,
            cx_px: 0.0,
            cy_px: 0.0,
            baseline_m: 0.0,
        },
        mount: CameraMount {
            rot_rover_from_camera: crate::types::zero_matrix::<3, 3>(),
            pos_camera_in_rover_m: crate::types::VEC3_ZERO,
        },
        grid: TerrainGrid::new(),
        visited: [false; GRID_CELLS],
        component: Component::EMPTY,
        view: Footprint::EMPTY,
        phase: Phase::Idle,
        frame_t_us: 0,
        frame_sequence: 0,
        wedge: (0.0, Wedge::empty([0.0, 0.0], 0.0)),
        range_cut_m: f64::INFINITY,
        work: MapCounts::EMPTY,
        map: HazardMap::EMPTY,
        map_valid: false,
    };

    /// [`Self::new`] in place: this mapper becomes the one `new(config, calibration)` returns
    /// (every field rewritten, the grid and the map cleared in loops: no 34 KB temporary on the
    /// stack). Errors as [`Self::new`]; on error nothing is changed.
    pub fn init(
        &mut self,
        config: PerceptionConfig,
        calibration: &StereoCalibration,
    ) -> Result<(), PerceptionError> {
        if !config.is_valid() {
            return Err(PerceptionError::InvalidConfig);
        }
        let camera = PinholeStereo::from_calibration(calibration)?;
        let mount = CameraMount::from_calibration(calibration)?;
        self.config = config;
        self.camera = camera;
        self.mount = mount;
        self.grid.clear();
        self.visited.fill(false);
        self.component = Component::EMPTY;
        self.view = Footprint::level(camera);
        self.phase = Phase::Idle;
        self.frame_t_us = 0;
        self.frame_sequence = 0;
        self.wedge = (0.0, Wedge::empty([0.0, 0.0], 0.0));
        self.range_cut_m = f64::INFINITY;
        self.work = MapCounts::EMPTY;
        self.map.clear();
        self.map_valid = false;
        Ok(())
    }

    /// The configuration.
    pub fn config(&self) -> &PerceptionConfig {
        &self.config
    }

    /// True while a map is being built.
    pub fn is_busy(&self) -> bool {
        self.phase != Phase::Idle
    }

    /// The last finished map, `None` before the first one or after a failed one.
    pub fn map(&self) -> Option<&HazardMap> {
        self.map_valid.then_some(&self.map)
    }

    /// The terrain grid of the last (or the running) map: cells and classes in the grid frame
    /// of [`HazardMap::grid`].
    pub fn grid(&self) -> &TerrainGrid {
        &self.grid
    }

    /// Starts a map of `frame` taken at camera pose `pose`. Errors: [`PerceptionError::Busy`],
    /// [`PerceptionError::WrongImageSize`], [`PerceptionError::InvalidPose`] (non-finite or not
    /// a rotation), [`PerceptionError::PoseOutOfRange`] (the rover's forward axis or its
    /// contact plane's normal more than 60 deg from level or vertical respectively).
    pub fn start(&mut self, frame: &StereoFrame, pose: &CameraPose) -> Result<(), PerceptionError> {
        if self.is_busy() {
            return Err(PerceptionError::Busy);
        }
        Image::new(frame.left)?;
        Image::new(frame.right)?;
        self.view = Footprint::new(pose, &self.mount, self.camera, &self.config)?;
        let apex = self.view.frame.to_world_xy([0.0, 0.0]);
        self.grid.clear();
        self.visited = [false; GRID_CELLS];
        self.wedge = (0.0, Wedge::empty(apex, self.view.frame.heading_rad));
        self.range_cut_m = f64::INFINITY;
        self.work = MapCounts::default();
        self.map_valid = false;
        self.map.obstacles.clear();
        self.frame_t_us = frame.capture_t_us;
        self.frame_sequence = frame.sequence;
        self.phase = Phase::Check {
            image: 0,
            band: 0,
            sums: CheckSums::default(),
        };
        Ok(())
    }

    /// The kind of the next work item, `None` when no map is being built.
    pub fn next_work(&self) -> Option<MapWork> {
        Some(match self.phase {
            Phase::Idle => return None,
            Phase::Check { .. } => MapWork::Check,
            Phase::Wedge { .. } => MapWork::Wedge,
            Phase::Sample { .. } => MapWork::Sample,
            Phase::Classify { .. } => MapWork::Classify,
            Phase::Obstacles { .. } => MapWork::Obstacle,
            Phase::Finish => MapWork::Finish,
        })
    }

    /// Advances the running map by work items until their costs
    /// ([`PerceptionConfig::work_cost`], units of about 10 000 rover-CPU instructions) reach
    /// `quantum`: at least one item; the last may go past the quantum by its own cost. `frame`
    /// must be the frame given to [`Self::start`] ([`PerceptionError::FrameChanged`] otherwise,
    /// which abandons the map).
    pub fn step(&mut self, frame: &StereoFrame, quantum: u32) -> MapProgress {
        crate::exec::step_frame_job(
            self,
            frame,
            quantum,
            || match (Image::new(frame.left), Image::new(frame.right)) {
                (Ok(left), Ok(right)) => Some((left, right)),
                _ => None,
            },
            |m, (left, right)| {
                let cost = m
                    .next_work()
                    .and_then(|k| m.config.work_cost.get(k as usize).copied())
                    .unwrap_or(1);
                m.work.work_items = m.work.work_items.saturating_add(1);
                (cost, m.work_item(left, right))
            },
        )
    }

    /// Upper bound of the work items of one map: image check, wedge candidates, one item per
    /// lattice point at most, grid rows, one item per component (at most one per cell) and
    /// the end of the search, finish.
    pub const MAX_ITEMS: usize =
        2 * CHECK_BANDS + WEDGE_CANDIDATES as usize + 2 * GRID_CELLS + GRID_ROWS + 8;

    /// Builds a whole map ([`Self::start`], then [`Self::step`] until finished). For tests and
    /// for callers without a time budget.
    pub fn run_to_completion(
        &mut self,
        frame: &StereoFrame,
        pose: &CameraPose,
    ) -> Result<&HazardMap, PerceptionError> {
        self.start(frame, pose)?;
        let mut result = Err(PerceptionError::NotStarted);
        for _ in 0..Self::MAX_ITEMS {
            if let MapProgress::Finished(r) = self.step(frame, 1) {
                result = r;
                break;
            }
        }
        if self.is_busy() {
            self.phase = Phase::Idle;
        }
        result.map(|()| &self.map)
    }

    /// One work item; the result when the map is finished.
    fn work_item(&mut self, left: &Image, right: &Image) -> Option<Result<(), PerceptionError>> {
        match self.phase {
            Phase::Idle => return Some(Err(PerceptionError::NotStarted)),
            Phase::Check {
                image,
                band,
                mut sums,
            } => {
                let img = if image == 0 { left } else { right };
                let checked = img.check_band(usize::from(band), &mut sums);
                if let Err(e) = checked {
                    return Some(Err(e.into()));
                }
                self.phase = if usize::from(band) + 1 < CHECK_BANDS {
                    Phase::Check {
                        image,
                        band: band + 1,
                        sums,
                    }
                } else {
                    if let Err(e) = sums.finish(&self.config.stereo) {
                        return Some(Err(e.into()));
                    }
                    if image == 0 {
                        Phase::Check {
                            image: 1,
                            band: 0,
                            sums: CheckSums::default(),
                        }
                    } else {
                        Phase::Wedge { candidate: 0 }
                    }
                };
            }
            Phase::Wedge { candidate } => {
                let found = self
                    .view
                    .wedge_candidate(candidate, self.config.max_wedge_range_m);
                if let Some((area, wedge)) = found {
                    if area > self.wedge.0 {
                        self.wedge = (area, wedge);
                    }
                }
                self.phase = if candidate + 1 < WEDGE_CANDIDATES {
                    Phase::Wedge {
                        candidate: candidate + 1,
                    }
                } else {
                    Phase::Sample { next: 0 }
                };
            }
            Phase::Sample { next } => {
                let next = self.sample_item(next, left, right);
                self.phase = if usize::from(next) < self.lattice_points() {
                    Phase::Sample { next }
                } else if self.work.matched < self.config.min_points {
                    return Some(Err(PerceptionError::TooFewPoints {
                        matched: self.work.matched,
                    }));
                } else {
                    Phase::Classify { row: 0 }
                };
            }
            Phase::Classify { row } => {
                self.classify_item(usize::from(row));
                self.phase = if usize::from(row) + 1 < GRID_ROWS {
                    Phase::Classify { row: row + 1 }
                } else {
                    Phase::Obstacles { next: 0 }
                };
            }
            Phase::Obstacles { next } => {
                self.phase = match self.obstacle_item(usize::from(next)) {
                    Some(next) => Phase::Obstacles {
                        next: next.min(usize::from(u16::MAX)) as u16,
                    },
                    None => Phase::Finish,
                };
            }
            Phase::Finish => {
                self.finish();
                return Some(Ok(()));
            }
        }
        None
    }

    /// Number of lattice points (sample candidates): every row of the grid, every
    /// `sample_spacing_cells`-th column.
    fn lattice_points(&self) -> usize {
        let s = usize::from(self.config.sample_spacing_cells.max(1));
        GRID_ROWS * GRID_COLS.div_ceil(s)
    }

    /// Grid `[x_G, y_G]` (m) of lattice point `k`: the centre of cell `(i, j)` with `i = k /
    /// ceil(GRID_COLS / s)` and `j = (k mod ceil(GRID_COLS / s)) s + (i mod s)` for the spacing
    /// `s` (a checkerboard for `s = 2`: one sample in `s` cells, every row and column sampled);
    /// `None` when `j` falls off the grid.
    fn lattice_point(&self, k: usize) -> Option<Point2> {
        let s = usize::from(self.config.sample_spacing_cells.max(1));
        let per_row = GRID_COLS.div_ceil(s);
        let i = k / per_row;
        let j = (k % per_row) * s + i % s;
        (i < GRID_ROWS && j < GRID_COLS).then(|| super::grid::cell_centre(i, j))
    }

    /// One sample work item from lattice point `next`: skips at most [`SKIP_PER_ITEM`] points
    /// outside the images, matches the first one inside. Returns the next lattice point.
    fn sample_item(&mut self, next: u16, left: &Image, right: &Image) -> u16 {
        let end = self.lattice_points();
        let mut k = usize::from(next);
        for _ in 0..SKIP_PER_ITEM {
            if k >= end {
                break;
            }
            let g = self.lattice_point(k);
            k += 1;
            if let Some((x, y, disparity)) = g.and_then(|g| self.view.in_view(g)) {
                self.sample(x, y, disparity, left, right);
                break;
            }
        }
        k.min(usize::from(u16::MAX)) as u16
    }

    /// Matches the left pixel `(x, y)` whose prior disparity is `disparity` (pixels) over the
    /// window of heights `-max_depth_below_m..max_height_above_m` about the prior, triangulates
    /// (H04 eq. 1-8), checks the height precision and adds the point to the grid.
    fn sample(&mut self, x: f64, y: f64, disparity: f64, left: &Image, right: &Image) {
        let h = self.view.camera_height_m;
        // A surface `t` above the prior along the pixel's ray is at (h - t) / h of the prior
        // point's depth.
        let far = h / (h + self.config.max_depth_below_m);
        let near = h / (h - self.config.max_height_above_m);
        let stereo = &self.config.stereo;
        let lo = libm::floor(disparity * far) - 1.0;
        let hi = libm::ceil(disparity * near) + 1.0;
        let lo = lo.max(f64::from(stereo.min_disparity_px));
        let hi = hi.min(f64::from(stereo.max_disparity_px));
        if !(hi >= lo + 4.0) {
            return;
        }
        // Both within 1..=max_disparity_px after the clamps.
        let config = VoConfig {
            min_disparity_px: lo as u16,
            max_disparity_px: hi as u16,
            ..*stereo
        };
        self.work.samples = self.work.samples.saturating_add(1);
        let result = match_and_triangulate(&self.camera, left, right, (x, y), None, &config);
        let evaluations = ncc_evaluations(&config, result.as_ref().err().copied());
        self.work.ncc_evaluations = self.work.ncc_evaluations.saturating_add(evaluations);
        let point = match result {
            Ok((point, _)) => point,
            Err(reason) => {
                self.work.rejects.count(reason);
                return;
            }
        };
        let n = &self.view.down_in_camera;
        let height_variance = (n.transpose() * point.covariance * n).x;
        if !(height_variance <= self.config.max_height_sigma_m * self.config.max_height_sigma_m) {
            self.work.imprecise = self.work.imprecise.saturating_add(1);
            return;
        }
        let pose = &self.view.pose;
        let world = pose.rot_world_from_camera * point.position_m + pose.position_world_m;
        let [gx, gy, height] = self.view.frame.to_grid(&world);
        let added = cell_of(gx, gy).is_some_and(|(i, j)| self.grid.add_point(i, j, height));
        if added {
            self.work.matched = self.work.matched.saturating_add(1);
        } else {
            self.work.outside_grid = self.work.outside_grid.saturating_add(1);
        }
    }

    /// Classifies grid row `row` and counts its cells, and its cells inside the wedge.
    fn classify_item(&mut self, row: usize) {
        let (known, sparse, hazard) = self.grid.classify_row(row, &self.config.limits);
        let w = &mut self.work;
        w.cells_known = w.cells_known.saturating_add(known);
        w.cells_sparse = w.cells_sparse.saturating_add(sparse);
        w.cells_hazard = w.cells_hazard.saturating_add(hazard);
        let wedge = self.wedge.1;
        let local = Wedge {
            apex_m: [0.0, 0.0],
            heading_rad: 0.0,
            ..wedge
        };
        for j in 0..GRID_COLS {
            if local.contains(super::grid::cell_centre(row, j)) {
                self.work.wedge_cells = self.work.wedge_cells.saturating_add(1);
                let has_points = |i: Option<usize>, j: Option<usize>| {
                    i.zip(j)
                        .and_then(|(i, j)| self.grid.cell(i, j))
                        .is_some_and(|c| c.count > 0)
                };
                let covered = has_points(Some(row), Some(j))
                    || has_points(row.checked_sub(1), Some(j))
                    || has_points(row.checked_add(1), Some(j))
                    || has_points(Some(row), j.checked_sub(1))
                    || has_points(Some(row), j.checked_add(1));
                if covered {
                    self.work.wedge_cells_known = self.work.wedge_cells_known.saturating_add(1);
                }
            }
        }
    }

    /// From cell index `next`, finds the next unvisited hazard cell and turns its component into
    /// an obstacle. Returns the cell index to continue from, `None` when the grid is done.
    fn obstacle_item(&mut self, next: usize) -> Option<usize> {
        let seed = (next..GRID_CELLS).find(|&k| {
            self.grid.class_at(k) == super::CellClass::Hazard && self.visited.get(k) == Some(&false)
        })?;
        flood_fill::<FILL_QUEUE>(
            &self.grid,
            &mut self.visited,
            seed,
            SHADOW_CELLS,
            &mut self.component,
        );
        let w = &mut self.work;
        w.components = w.components.saturating_add(1);
        if self.component.overflowed {
            w.fill_overflows = w.fill_overflows.saturating_add(1);
        }
        if self.component.cells < self.config.min_obstacle_cells
            || self.component.points < u32::from(self.config.min_obstacle_points)
        {
            w.small_dropped = w.small_dropped.saturating_add(1);
            return Some(seed + 1);
        }
        let radius = ROVER_HALF_WIDTH_M + self.config.grow_margin_m;
        let Some((polygon, reduced)) = component_polygon(&self.component, radius) else {
            return Some(seed + 1);
        };
        w.vertices_reduced = w.vertices_reduced.saturating_add(reduced);
        let mut corners = [[0.0f64; 2]; MAX_POLYGON_VERTICES];
        for (slot, &v) in corners.iter_mut().zip(polygon.vertices.iter()) {
            *slot = self.view.frame.to_world_xy(v);
        }
        let world =
            ConvexPolygon::from_points(corners.get(..polygon.vertices.len()).unwrap_or(&[]));
        let full = self.map.obstacles.len() >= usize::from(self.config.max_obstacles);
        if full || self.map.obstacles.push(world).is_err() {
            // Full: this component is the farthest so far (seeds go from near to far rows);
            // drop it and cut the wedge before it, so the planner does not take it as free.
            w.obstacles_dropped = w.obstacles_dropped.saturating_add(1);
            let cut = distance_to_polygon(&polygon.vertices, [0.0, 0.0]);
            self.range_cut_m = self.range_cut_m.min(cut);
        }
        Some(seed + 1)
    }

    /// Commits the map: the wedge (cut before any dropped obstacle), the grid frame, the
    /// counts.
    fn finish(&mut self) {
        let mut wedge = self.wedge.1;
        if self.range_cut_m < wedge.max_range_m {
            wedge.max_range_m = self.range_cut_m.max(wedge.min_range_m);
        }
        self.map.capture_t_us = self.frame_t_us;
        self.map.wedge = wedge;
        self.map.grid = self.view.frame;
        self.map.counts = self.work;
        self.map_valid = true;
    }
}

/// Correlations of one match of [`match_and_triangulate`] ended by `reject` (`None`: matched),
/// counted up to the stage that ended it: the row scan (every `stereo_coarse_step`-th disparity
/// of the window, then the two neighbours of the best), the range-end neighbours, the
/// depth-discontinuity halves (5 regions over `2 half_window_px + 1` disparities), the
/// left-right scan (every `left_right_step`-th disparity, then the columns within half a step).
pub fn ncc_evaluations(config: &VoConfig, reject: Option<StereoReject>) -> u32 {
    let span = u32::from(
        config
            .max_disparity_px
            .saturating_sub(config.min_disparity_px),
    );
    let step = u32::from(config.stereo_coarse_step.max(1));
    let scan = span / step + 1 + if step > 1 { 2 } else { 0 };
    let range_end = 2;
    let halves = 5 * (2 * u32::from(config.half_window_px) + 1);
    let lr_step = u32::from(config.left_right_step.max(1));
    let lr_span = if config.left_right_window_px == 0 {
        span
    } else {
        (2 * u32::from(config.left_right_window_px)).min(span)
    };
    let left_right = lr_span / lr_step + 1 + 2 * (lr_step / 2);
    match reject {
        Some(
            StereoReject::OutOfImage | StereoReject::WeakCorrelation | StereoReject::Ambiguous,
        ) => scan,
        Some(StereoReject::RangeEnd) => scan + range_end,
        Some(StereoReject::Discontinuity | StereoReject::RefinementFailed) => {
            scan + range_end + halves
        }
        _ => scan + range_end + halves + left_right,
    }
}
