//! The terrain grid (V99 sec. 4, "elevation map"): per-cell statistics of the triangulated
//! points in the local-level grid frame `G`, and the hazard classification of each cell by
//! step, slope and roughness (`docs/perception.md`).
//!
//! Cell `(i, j)` covers `x_G` in `[GRID_X_MIN_M + i * CELL_SIZE_M, .. + CELL_SIZE_M)` and `y_G`
//! in `[GRID_Y_MIN_M + j * CELL_SIZE_M, .. + CELL_SIZE_M)`; its index is `i * GRID_COLS + j`.
//! Heights are up-positive, relative to the grid origin's height (the camera centre), stored in
//! millimetres.

use super::{
    HazardLimits, Point2, CELL_SIZE_M, GRID_CELLS, GRID_COLS, GRID_ROWS, GRID_X_MIN_M, GRID_Y_MIN_M,
};
use crate::types::Vec3;

/// Placement of the grid frame `G` in the world frame `W`: origin at `origin_world_m` (the left
/// camera centre at capture; the grid's `x-y` origin is its nadir and heights are measured from
/// its height), `x_G` at `heading_rad` from north towards east, `y_G` to its right, `z_G = z_W`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GridFrame {
    /// Origin in `W`, m.
    pub origin_world_m: [f64; 3],
    /// Heading of `x_G`, rad from `x_W` (north) towards `y_W` (east).
    pub heading_rad: f64,
    /// `cos(heading_rad)`.
    pub heading_cos: f64,
    /// `sin(heading_rad)`.
    pub heading_sin: f64,
}

impl GridFrame {
    /// A grid frame at `origin_world_m` with `x_G` at `heading_rad`.
    pub fn new(origin_world_m: [f64; 3], heading_rad: f64) -> Self {
        let (s, c) = libm::sincos(heading_rad);
        Self {
            origin_world_m,
            heading_rad,
            heading_cos: c,
            heading_sin: s,
        }
    }

    /// A world point `p_W` (m) in grid coordinates `[x_G, y_G, height]` (m, height up from the
    /// origin).
    pub fn to_grid(&self, p: &Vec3) -> [f64; 3] {
        let [ox, oy, oz] = self.origin_world_m;
        let (c, s) = (self.heading_cos, self.heading_sin);
        let (dx, dy) = (p.x - ox, p.y - oy);
        [c * dx + s * dy, -s * dx + c * dy, oz - p.z]
    }

    /// Grid `[x_G, y_G]` to world `[x, y]`, m.
    pub fn to_world_xy(&self, g: Point2) -> Point2 {
        let [ox, oy, _] = self.origin_world_m;
        let (c, s) = (self.heading_cos, self.heading_sin);
        [ox + c * g[0] - s * g[1], oy + s * g[0] + c * g[1]]
    }

    /// The world point (m) at grid `[x_G, y_G]` and `height` (m, up from the origin).
    pub fn to_world(&self, g: Point2, height_m: f64) -> Vec3 {
        let [x, y] = self.to_world_xy(g);
        Vec3::new(x, y, self.origin_world_m[2] - height_m)
    }
}

/// The cell `(i, j)` holding grid point `(x_G, y_G)` (m), `None` outside the grid or non-finite.
pub fn cell_of(x_g: f64, y_g: f64) -> Option<(usize, usize)> {
    let u = (x_g - GRID_X_MIN_M) / CELL_SIZE_M;
    let v = (y_g - GRID_Y_MIN_M) / CELL_SIZE_M;
    // NaN fails both range tests; non-negative and in range, so truncation is the floor.
    if !(u >= 0.0 && u < GRID_ROWS as f64 && v >= 0.0 && v < GRID_COLS as f64) {
        return None;
    }
    Some((u as usize, v as usize))
}

/// Grid coordinates `[x_G, y_G]` (m) of the centre of cell `(i, j)`.
pub fn cell_centre(i: usize, j: usize) -> Point2 {
    [
        GRID_X_MIN_M + (i as f64 + 0.5) * CELL_SIZE_M,
        GRID_Y_MIN_M + (j as f64 + 0.5) * CELL_SIZE_M,
    ]
}

/// Points of one cell: count, lowest and highest height, sum of heights (mm, up from the grid
/// origin). The sum of up to `u16::MAX` heights of at most 32.767 m fits in `i32`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Cell {
    /// Points accumulated (saturating; no more points are added at `u16::MAX`).
    pub count: u16,
    /// Lowest height, mm.
    pub min_mm: i16,
    /// Highest height, mm.
    pub max_mm: i16,
    /// Sum of the heights, mm.
    pub sum_mm: i32,
}

impl Cell {
    /// Mean height, m (0 for an empty cell).
    pub fn mean_m(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            f64::from(self.sum_mm) / f64::from(self.count) * 1e-3
        }
    }
}

/// Class of a grid cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum CellClass {
    /// No points, or too few known neighbours for a ground plane.
    #[default]
    Unknown = 0,
    /// Step, slope and roughness within [`HazardLimits`].
    Traversable = 1,
    /// Step, slope or roughness beyond [`HazardLimits`].
    Hazard = 2,
}

/// The terrain measures of one cell (for the classification, tests and telemetry).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellMetrics {
    /// Slope of the local ground plane (5x5 cells), rad.
    pub slope_rad: f64,
    /// Step: the cell's highest point above the lowest point of its 3x3 neighbourhood, both
    /// relative to the local ground plane, m.
    pub step_m: f64,
    /// Root-mean-square residual of the cell means kept in the plane fit, m.
    pub roughness_m: f64,
    /// Height of the local ground plane at the cell centre, m (up from the grid origin).
    pub ground_m: f64,
    /// Known cells used by the plane fit (after trimming).
    pub plane_cells: u8,
}

/// Half side of the plane-fit neighbourhood, cells (5x5 cells, 0.5 m: the rover's track and
/// wheelbase are 0.62 and 0.75 m).
pub const PLANE_HALF: usize = 2;
/// Half side of the step neighbourhood, cells (3x3 cells, 0.3 m: a wheel diameter of 0.2 m
/// plus a cell).
pub const STEP_HALF: usize = 1;
const PLANE_SIDE: usize = 2 * PLANE_HALF + 1;
const PLANE_MAX: usize = PLANE_SIDE * PLANE_SIDE;

/// Largest height accepted in the grid, m (the `i16` millimetre range with a margin).
pub const MAX_ABS_HEIGHT_M: f64 = 30.0;

/// A plane `z = a + b x + c y` over cell offsets `(x, y)` in metres from the centre cell.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Plane {
    a: f64,
    b: f64,
    c: f64,
}

impl Plane {
    fn at(&self, x: f64, y: f64) -> f64 {
        self.a + self.b * x + self.c * y
    }
}

/// Least-squares plane through `points[k]` (x, y, z) where `keep[k]`, `None` with fewer than
/// three points or collinear ones.
fn fit(points: &[[f64; 3]], keep: &[bool]) -> Option<Plane> {
    let (mut n, mut sx, mut sy, mut sz) = (0.0, 0.0, 0.0, 0.0);
    for (p, _) in points.iter().zip(keep).filter(|(_, &k)| k) {
        n += 1.0;
        sx += p[0];
        sy += p[1];
        sz += p[2];
    }
    if n < 3.0 {
        return None;
    }
    let (mx, my, mz) = (sx / n, sy / n, sz / n);
    let (mut sxx, mut sxy, mut syy, mut sxz, mut syz) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (p, _) in points.iter().zip(keep).filter(|(_, &k)| k) {
        let (x, y, z) = (p[0] - mx, p[1] - my, p[2] - mz);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
        sxz += x * z;
        syz += y * z;
    }
    let det = sxx * syy - sxy * sxy;
    // Three cells in an L give det = 2 * CELL^4 / 3; collinear cells give 0.
    if !(det > 0.1 * CELL_SIZE_M * CELL_SIZE_M * CELL_SIZE_M * CELL_SIZE_M) {
        return None;
    }
    let b = (sxz * syy - syz * sxy) / det;
    let c = (syz * sxx - sxz * sxy) / det;
    Some(Plane {
        a: mz - b * mx - c * my,
        b,
        c,
    })
}

/// The terrain grid: cell statistics and classes, fixed size ([`GRID_CELLS`] cells).
#[derive(Debug, Clone)]
pub struct TerrainGrid {
    cells: [Cell; GRID_CELLS],
    classes: [CellClass; GRID_CELLS],
}

impl Default for TerrainGrid {
    fn default() -> Self {
        Self::new()
    }
}

impl TerrainGrid {
    /// An empty grid (every cell unknown).
    pub const fn new() -> Self {
        Self {
            cells: [Cell {
                count: 0,
                min_mm: 0,
                max_mm: 0,
                sum_mm: 0,
            }; GRID_CELLS],
            classes: [CellClass::Unknown; GRID_CELLS],
        }
    }

    /// Empties every cell.
    pub fn clear(&mut self) {
        self.cells.iter_mut().for_each(|c| *c = Cell::default());
        self.classes
            .iter_mut()
            .for_each(|c| *c = CellClass::Unknown);
    }

    /// Cell `(i, j)`, `None` outside the grid.
    pub fn cell(&self, i: usize, j: usize) -> Option<&Cell> {
        if j >= GRID_COLS {
            return None;
        }
        self.cells.get(i.checked_mul(GRID_COLS)?.checked_add(j)?)
    }

    /// Cell at signed `(i + di, j + dj)`, `None` outside the grid.
    fn cell_offset(&self, i: usize, j: usize, di: isize, dj: isize) -> Option<&Cell> {
        self.cell(i.checked_add_signed(di)?, j.checked_add_signed(dj)?)
    }

    /// Class of cell `(i, j)` ([`CellClass::Unknown`] outside the grid).
    pub fn class(&self, i: usize, j: usize) -> CellClass {
        if j >= GRID_COLS {
            return CellClass::Unknown;
        }
        i.checked_mul(GRID_COLS)
            .and_then(|k| k.checked_add(j))
            .and_then(|k| self.classes.get(k))
            .copied()
            .unwrap_or(CellClass::Unknown)
    }

    /// Class of the cell with index `k` ([`CellClass::Unknown`] outside the grid).
    pub fn class_at(&self, k: usize) -> CellClass {
        self.classes.get(k).copied().unwrap_or(CellClass::Unknown)
    }

    /// Points of the cell with index `k` (0 outside the grid).
    pub fn count_at(&self, k: usize) -> u16 {
        self.cells.get(k).map_or(0, |c| c.count)
    }

    /// Adds a point of height `height_m` (m, up from the grid origin) to cell `(i, j)`. False
    /// (nothing added) outside the grid, for a non-finite height or one beyond
    /// [`MAX_ABS_HEIGHT_M`], or in a full cell.
    pub fn add_point(&mut self, i: usize, j: usize, height_m: f64) -> bool {
        if j >= GRID_COLS || !(libm::fabs(height_m) <= MAX_ABS_HEIGHT_M) {
            return false;
        }
        let Some(cell) = i
            .checked_mul(GRID_COLS)
            .and_then(|k| k.checked_add(j))
            .and_then(|k| self.cells.get_mut(k))
        else {
            return false;
        };
        if cell.count == u16::MAX {
            return false;
        }
        // Within +-30 000 mm after the check above.
        let mm = libm::round(height_m * 1000.0) as i16;
        if cell.count == 0 {
            cell.min_mm = mm;
            cell.max_mm = mm;
        } else {
            cell.min_mm = cell.min_mm.min(mm);
            cell.max_mm = cell.max_mm.max(mm);
        }
        cell.count += 1;
        // At most 65 535 * 30 000 = 1.97e9 in magnitude, within i32 (saturating regardless).
        cell.sum_mm = cell.sum_mm.saturating_add(i32::from(mm));
        true
    }

    /// The terrain measures of cell `(i, j)`: the least-squares plane through the mean
    /// heights of the known cells of its 5x5 neighbourhood, refitted once without the cells
    /// whose residual exceeds `limits.max_step_m` (an obstacle in the window must not tilt the
    /// ground), then slope, step (3x3 neighbourhood, relative to the plane) and roughness.
    /// `None` for an empty cell or fewer than `limits.plane_min_cells` known cells (or
    /// collinear ones).
    pub fn metrics(&self, i: usize, j: usize, limits: &HazardLimits) -> Option<CellMetrics> {
        let centre = *self.cell(i, j)?;
        if centre.count == 0 {
            return None;
        }
        let mut points = [[0.0f64; 3]; PLANE_MAX];
        let mut n = 0usize;
        let half = PLANE_HALF as isize;
        for di in -half..=half {
            for dj in -half..=half {
                let Some(cell) = self.cell_offset(i, j, di, dj) else {
                    continue;
                };
                if cell.count == 0 {
                    continue;
                }
                if let Some(slot) = points.get_mut(n) {
                    *slot = [
                        di as f64 * CELL_SIZE_M,
                        dj as f64 * CELL_SIZE_M,
                        cell.mean_m(),
                    ];
                    n += 1;
                }
            }
        }
        let min_cells = usize::from(limits.plane_min_cells).max(3);
        if n < min_cells {
            return None;
        }
        let points = points.get(..n)?;
        let mut keep = [true; PLANE_MAX];
        let keep_n = keep.get_mut(..n)?;
        let mut plane = fit(points, keep_n)?;
        let mut trimmed = 0usize;
        for (p, k) in points.iter().zip(keep_n.iter_mut()) {
            if !(libm::fabs(p[2] - plane.at(p[0], p[1])) <= limits.max_step_m) {
                *k = false;
                trimmed += 1;
            }
        }
        if trimmed > 0 {
            match (n - trimmed >= min_cells)
                .then(|| fit(points, keep_n))
                .flatten()
            {
                Some(refit) => plane = refit,
                // Too few cells agree: keep the first fit over every cell (its residuals then
                // count in the roughness).
                None => keep_n.iter_mut().for_each(|k| *k = true),
            }
        }
        let (mut sum_sq, mut kept) = (0.0, 0u8);
        for (p, _) in points.iter().zip(keep_n.iter()).filter(|(_, &k)| k) {
            let r = p[2] - plane.at(p[0], p[1]);
            sum_sq += r * r;
            kept = kept.saturating_add(1);
        }
        let roughness_m = crate::linalg::sqrt(sum_sq / f64::from(kept.max(1)));
        let slope_rad = libm::atan(libm::hypot(plane.b, plane.c));
        // Step: the centre's highest point above the lowest point of the 3x3 neighbourhood.
        let top = f64::from(centre.max_mm) * 1e-3 - plane.at(0.0, 0.0);
        let mut bottom = f64::INFINITY;
        let step_half = STEP_HALF as isize;
        for di in -step_half..=step_half {
            for dj in -step_half..=step_half {
                let Some(cell) = self.cell_offset(i, j, di, dj) else {
                    continue;
                };
                if cell.count > 0 {
                    let (x, y) = (di as f64 * CELL_SIZE_M, dj as f64 * CELL_SIZE_M);
                    bottom = bottom.min(f64::from(cell.min_mm) * 1e-3 - plane.at(x, y));
                }
            }
        }
        let metrics = CellMetrics {
            slope_rad,
            step_m: top - bottom,
            roughness_m,
            ground_m: plane.a,
            plane_cells: kept,
        };
        let finite = [slope_rad, metrics.step_m, roughness_m, plane.a]
            .iter()
            .all(|v| v.is_finite());
        finite.then_some(metrics)
    }

    /// Classifies row `i` of the grid ([`Self::metrics`] against `limits`) and returns
    /// `(known, sparse, hazard)` cell counts of the row. Rows outside the grid count nothing.
    pub fn classify_row(&mut self, i: usize, limits: &HazardLimits) -> (u16, u16, u16) {
        let (mut known, mut sparse, mut hazard) = (0u16, 0u16, 0u16);
        for j in 0..GRID_COLS {
            let count = self.cell(i, j).map_or(0, |c| c.count);
            let class = if count == 0 {
                CellClass::Unknown
            } else {
                known += 1;
                match self.metrics(i, j, limits) {
                    None => {
                        sparse += 1;
                        CellClass::Unknown
                    }
                    Some(m) => {
                        let hazardous = !(m.step_m <= limits.max_step_m
                            && m.slope_rad <= limits.max_slope_rad
                            && m.roughness_m <= limits.max_roughness_m);
                        if hazardous {
                            hazard += 1;
                            CellClass::Hazard
                        } else {
                            CellClass::Traversable
                        }
                    }
                }
            };
            if let Some(slot) = i
                .checked_mul(GRID_COLS)
                .and_then(|k| k.checked_add(j))
                .and_then(|k| self.classes.get_mut(k))
            {
                *slot = class;
            }
        }
        (known, sparse, hazard)
    }

    /// Sets the class of cell `(i, j)` (tests and the flood fill's unit tests).
    pub fn set_class(&mut self, i: usize, j: usize, class: CellClass) {
        if j >= GRID_COLS {
            return;
        }
        if let Some(slot) = i
            .checked_mul(GRID_COLS)
            .and_then(|k| k.checked_add(j))
            .and_then(|k| self.classes.get_mut(k))
        {
            *slot = class;
        }
    }
}
