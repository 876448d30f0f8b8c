//! The local measurement: occupied points of one hazard grid in the grid frame `G` (x_G
//! forward, y_G right, m; V99 sec. 5: "the occupied cells in the local map").
//!
//! [`LocalScan::from_grid`] merges the 0.1 m hazard cells of [`TerrainGrid`] into blocks of
//! 2 x 2 cells (the 0.2 m of the global map, [`super::MAP_CELL_M`]): one point per block with a
//! hazard cell, at the mean of its hazard cells' centres, so that the four cells of one map
//! cell do not count as four independent measurements. With more than [`MAX_POINTS`] blocks,
//! an even stride over the blocks in row order keeps [`MAX_POINTS`] of them (deterministic).

use super::{LocalizationError, MAX_POINTS};
use crate::perception::grid::cell_centre;
use crate::perception::{CellClass, GridFrame, TerrainGrid, GRID_COLS, GRID_ROWS};

/// Largest distance of a scan point from the grid origin, m.
const MAX_POINT_M: f64 = 100.0;
/// Side of a block of hazard cells merged into one point, cells.
const BLOCK: usize = 2;
const BLOCK_ROWS: usize = GRID_ROWS.div_ceil(BLOCK);
const BLOCK_COLS: usize = GRID_COLS.div_ceil(BLOCK);

/// Occupied points of one local map in the grid frame `G` (`[x_G, y_G]`, m), at most
/// [`MAX_POINTS`] (4 KB).
#[derive(Debug, Clone, Default)]
pub struct LocalScan {
    points: heapless::Vec<[f64; 2], MAX_POINTS>,
}

impl LocalScan {
    /// An empty scan.
    pub const fn new() -> Self {
        Self {
            points: heapless::Vec::new(),
        }
    }

    /// Removes every point.
    pub fn clear(&mut self) {
        self.points.clear();
    }

    /// The points, `[x_G, y_G]`, m.
    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True without points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Adds the point `p` (`[x_G, y_G]`, m). Errors: [`LocalizationError::InvalidPoint`] for a
    /// non-finite point or one beyond 100 m, [`LocalizationError::ScanFull`].
    pub fn push(&mut self, p: [f64; 2]) -> Result<(), LocalizationError> {
        if !(p.iter().all(|v| v.is_finite()) && libm::hypot(p[0], p[1]) <= MAX_POINT_M) {
            return Err(LocalizationError::InvalidPoint);
        }
        self.points.push(p).map_err(|_| LocalizationError::ScanFull)
    }

    /// The scan of the hazard cells of `grid`: one point per 2 x 2 block of cells holding a
    /// hazard cell, at the mean of their centres (`[x_G, y_G]`, m); more than [`MAX_POINTS`]
    /// blocks are thinned by an even stride in row order.
    pub fn from_grid(grid: &TerrainGrid) -> Self {
        let mut scan = Self::new();
        scan.append_blocks(grid, MAX_POINTS, |p| p);
        scan
    }

    /// Appends the hazard blocks of another grid placed at `frame` to this scan, expressed in
    /// the grid frame `reference` (a local map from several captures, V99 sec. 5: "six stereo
    /// pairs were used to build an elevation map"; the frames' relative placement comes from
    /// the estimator, e.g. the captures of a turn in place). At most `max_new` points are
    /// added (an even stride over the grid's blocks) and never beyond [`MAX_POINTS`]. Returns
    /// the points added.
    pub fn append_grid(
        &mut self,
        grid: &TerrainGrid,
        frame: &GridFrame,
        reference: &GridFrame,
        max_new: usize,
    ) -> usize {
        let before = self.len();
        let room = MAX_POINTS.saturating_sub(before).min(max_new);
        self.append_blocks(grid, room, |p| {
            let w = frame.to_world_xy(p);
            let g = reference.to_grid(&crate::types::Vec3::new(w[0], w[1], 0.0));
            [g[0], g[1]]
        });
        self.len() - before
    }

    /// Appends the hazard blocks of `grid`, taken through `to_scan`, thinned to `keep` by an
    /// even stride in row order.
    fn append_blocks(
        &mut self,
        grid: &TerrainGrid,
        keep: usize,
        to_scan: impl Fn([f64; 2]) -> [f64; 2],
    ) {
        let total = Self::blocks(grid, |_, _| {});
        let keep = total.min(keep);
        let mut index = 0usize;
        Self::blocks(grid, |_, p| {
            // Bresenham stride: block `index` is kept when floor((index + 1) keep / total)
            // steps up.
            if total > 0 && ((index + 1) * keep) / total > (index * keep) / total {
                // A point that is not finite or beyond 100 m (a frame far off) is refused,
                // and a full scan simply stops growing.
                let _ = self.push(to_scan(p));
            }
            index += 1;
        });
    }

    /// Calls `visit(block_index, point)` for every block with a hazard cell, in row order, and
    /// returns their number.
    fn blocks(grid: &TerrainGrid, mut visit: impl FnMut(usize, [f64; 2])) -> usize {
        let mut count = 0;
        for bi in 0..BLOCK_ROWS {
            for bj in 0..BLOCK_COLS {
                let (mut n, mut sx, mut sy) = (0u32, 0.0, 0.0);
                for i in bi * BLOCK..(bi * BLOCK + BLOCK).min(GRID_ROWS) {
                    for j in bj * BLOCK..(bj * BLOCK + BLOCK).min(GRID_COLS) {
                        if grid.class(i, j) == CellClass::Hazard {
                            let c = cell_centre(i, j);
                            n += 1;
                            sx += c[0];
                            sy += c[1];
                        }
                    }
                }
                if n > 0 {
                    let k = f64::from(n);
                    visit(bi * BLOCK_COLS + bj, [sx / k, sy / k]);
                    count += 1;
                }
            }
        }
        count
    }
}
