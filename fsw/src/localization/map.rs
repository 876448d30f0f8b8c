//! The global occupancy map in the world frame `W` and its distance transform (V99 sec. 5:
//! "distances from the occupied cells in the local map to their closest occupied cells in the
//! global map").
//!
//! Cell `(i, j)` covers `x` in `[origin_x + i * MAP_CELL_M, .. + MAP_CELL_M)` (north) and `y`
//! in `[origin_y + j * MAP_CELL_M, .. + MAP_CELL_M)` (east); its index is `i * MAP_SIDE + j`.
//! The distance transform holds, per cell, the squared Euclidean distance in cells^2 between
//! its centre and the nearest occupied cell's centre, truncated at [`MAX_D2_CELLS`] (0 for an
//! occupied cell). It is exact: a column pass (distance to the nearest occupied cell of the
//! column) and a row pass computing the lower envelope of parabolas `f(k) + (j - k)^2`
//! (Felzenszwalb & Huttenlocher 2012, "Distance transforms of sampled functions", alg. 1).
//! Truncating the column pass at 255 keeps every result below 255 exact: a candidate through a
//! truncated column value is at least 255.
//!
//! Memory: 36,864 B of distance transform plus 12,290 B of pyramid (49,154 B, plus 40 B of
//! fields).

use super::{MAP_CELLS, MAP_CELL_M, MAP_SIDE, MAX_D2_CELLS, PYRAMID_LEVELS};
use crate::perception::grid::cell_centre;
use crate::perception::{CellClass, GridFrame, TerrainGrid, GRID_COLS, GRID_ROWS};

/// Cells of the min-pooled pyramid, levels 1 to [`PYRAMID_LEVELS`]
/// (`96^2 + 48^2 + 24^2 + 12^2 + 6^2 + 3^2 + 2^2 + 1^2`).
pub const PYRAMID_CELLS: usize = pyramid_offset(PYRAMID_LEVELS + 1);

/// Side of pyramid level `level` (0: the distance transform), cells.
pub const fn level_side(level: usize) -> usize {
    if level >= usize::BITS as usize {
        return 1;
    }
    let size = 1usize << level;
    MAP_SIDE.div_ceil(size)
}

/// Offset of level `level` (1 to [`PYRAMID_LEVELS`]) in the pyramid array; `level =
/// PYRAMID_LEVELS + 1` gives the total size. Bounded loop, evaluated at compile time.
const fn pyramid_offset(level: usize) -> usize {
    let mut off = 0;
    let mut l = 1;
    while l < level && l <= PYRAMID_LEVELS {
        let s = level_side(l);
        off += s * s;
        l += 1;
    }
    off
}

/// Largest coordinate magnitude accepted for a map point or origin, m.
const MAX_COORD_M: f64 = 1.0e6;

/// The global map: occupancy (as distance 0) and the truncated squared distance transform in
/// cells^2, plus its min-pooled pyramid. Build it with [`GlobalMap::reset`], the `insert_*`
/// functions, then [`GlobalMap::finish`]; the localizer refuses a map that is not finished.
/// 49,194 B; make it a `static` or build it in place ([`GlobalMap::new`] is `const`).
#[derive(Debug, Clone)]
pub struct GlobalMap {
    origin_m: [f64; 2],
    /// Before [`Self::finish`]: 0 occupied, 255 free. After: the distance transform.
    d2: [u8; MAP_CELLS],
    pyramid: [u8; PYRAMID_CELLS],
    occupied: u32,
    ready: bool,
    revision: u32,
    rejected: u32,
}

impl Default for GlobalMap {
    fn default() -> Self {
        Self::new()
    }
}

impl GlobalMap {
    /// An empty map with its corner at the world origin (not finished).
    pub const fn new() -> Self {
        Self {
            origin_m: [0.0, 0.0],
            d2: [MAX_D2_CELLS; MAP_CELLS],
            pyramid: [MAX_D2_CELLS; PYRAMID_CELLS],
            occupied: 0,
            ready: false,
            revision: 0,
            rejected: 0,
        }
    }

    /// Empties the map and places its corner (the low `x`, low `y` corner of cell `(0, 0)`) at
    /// `origin_m` (`[x north, y east]`, m, `W`). False (map unchanged) for a non-finite origin
    /// or one beyond 1e6 m.
    pub fn reset(&mut self, origin_m: [f64; 2]) -> bool {
        if !origin_m
            .iter()
            .all(|v| v.is_finite() && libm::fabs(*v) <= MAX_COORD_M)
        {
            return false;
        }
        self.origin_m = origin_m;
        self.d2.iter_mut().for_each(|v| *v = MAX_D2_CELLS);
        self.pyramid.iter_mut().for_each(|v| *v = MAX_D2_CELLS);
        self.occupied = 0;
        self.ready = false;
        self.revision = self.revision.wrapping_add(1);
        self.rejected = 0;
        true
    }

    /// Empties the map and centres it on `centre_m` (`[x, y]`, m, `W`). False for a
    /// non-finite centre.
    pub fn reset_centred(&mut self, centre_m: [f64; 2]) -> bool {
        let half = MAP_SIDE as f64 * MAP_CELL_M / 2.0;
        self.reset([centre_m[0] - half, centre_m[1] - half])
    }

    /// The low corner of cell `(0, 0)`, m (`W`).
    pub fn origin_m(&self) -> [f64; 2] {
        self.origin_m
    }

    /// Occupied cells.
    pub fn occupied_cells(&self) -> u32 {
        self.occupied
    }

    /// Points refused since the last reset (non-finite or outside the map).
    pub fn rejected_points(&self) -> u32 {
        self.rejected
    }

    /// True when the distance transform is up to date ([`Self::finish`] after the last
    /// insertion) and at least one cell is occupied.
    pub fn is_ready(&self) -> bool {
        self.ready && self.occupied > 0
    }

    /// A counter that changes with every reset, insertion and finish (the localizer checks
    /// that the map did not change during a search).
    pub fn revision(&self) -> u32 {
        self.revision
    }

    /// The cell `(i, j)` holding world point `p` (`[x, y]`, m), `None` outside or non-finite.
    pub fn cell_of(&self, p: [f64; 2]) -> Option<(usize, usize)> {
        let u = (p[0] - self.origin_m[0]) / MAP_CELL_M;
        let v = (p[1] - self.origin_m[1]) / MAP_CELL_M;
        let side = MAP_SIDE as f64;
        if !(u >= 0.0 && u < side && v >= 0.0 && v < side) {
            return None;
        }
        // Non-negative and below MAP_SIDE: truncation is the floor.
        Some((u as usize, v as usize))
    }

    /// World `[x, y]` of the centre of cell `(i, j)`, m.
    pub fn cell_centre(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.origin_m[0] + (i as f64 + 0.5) * MAP_CELL_M,
            self.origin_m[1] + (j as f64 + 0.5) * MAP_CELL_M,
        ]
    }

    /// Marks the cells holding world points `points` (`[x north, y east]`, m, `W`) occupied:
    /// what the ground uplinks from a descent or orbital image. Returns the points accepted;
    /// non-finite points and points outside the map are refused and counted
    /// ([`Self::rejected_points`]). The map needs [`Self::finish`] afterwards.
    pub fn insert_points(&mut self, points: &[[f64; 2]]) -> usize {
        let mut accepted = 0;
        for p in points {
            if self.insert_point(*p) {
                accepted += 1;
            }
        }
        accepted
    }

    /// Marks the cell holding world point `p` occupied; false when refused.
    pub fn insert_point(&mut self, p: [f64; 2]) -> bool {
        self.ready = false;
        self.revision = self.revision.wrapping_add(1);
        let Some(cell) = self
            .cell_of(p)
            .and_then(|(i, j)| self.d2.get_mut(i * MAP_SIDE + j))
        else {
            self.rejected = self.rejected.saturating_add(1);
            return false;
        };
        if *cell != 0 {
            *cell = 0;
            self.occupied = self.occupied.saturating_add(1);
        }
        true
    }

    /// Adds the hazard cells of a perception grid placed at `frame` (the rover's own map of
    /// terrain it has seen: V99 sec. 5, "a previously generated elevation map"): each hazard
    /// cell's centre, taken to `W` by [`GridFrame::to_world_xy`]. Returns the cells accepted.
    pub fn insert_grid_hazards(&mut self, grid: &TerrainGrid, frame: &GridFrame) -> usize {
        let mut accepted = 0;
        for i in 0..GRID_ROWS {
            for j in 0..GRID_COLS {
                if grid.class(i, j) == CellClass::Hazard
                    && self.insert_point(frame.to_world_xy(cell_centre(i, j)))
                {
                    accepted += 1;
                }
            }
        }
        accepted
    }

    /// Computes the distance transform and its pyramid from the occupied cells (about 40
    /// operations per cell). Call after the insertions and before localizing.
    pub fn finish(&mut self) {
        // Keep only the occupancy (a finished map holds distances).
        self.d2
            .iter_mut()
            .for_each(|v| *v = if *v == 0 { 0 } else { MAX_D2_CELLS });
        self.column_pass();
        self.row_pass();
        self.build_pyramid();
        self.ready = true;
        self.revision = self.revision.wrapping_add(1);
    }

    /// Squared distance of cell `(i, j)` to the nearest occupied cell, cells^2 (truncated at
    /// [`MAX_D2_CELLS`]); [`MAX_D2_CELLS`] outside the map.
    pub fn d2_at(&self, i: i32, j: i32) -> u8 {
        if i < 0 || j < 0 {
            return MAX_D2_CELLS;
        }
        let (i, j) = (i as usize, j as usize);
        if i >= MAP_SIDE || j >= MAP_SIDE {
            return MAX_D2_CELLS;
        }
        self.d2
            .get(i * MAP_SIDE + j)
            .copied()
            .unwrap_or(MAX_D2_CELLS)
    }

    /// Smallest squared distance (cells^2) over the cells `[i0, i1] x [j0, j1]` (inclusive,
    /// may extend beyond the map; cells outside read [`MAX_D2_CELLS`]), or a lower bound of
    /// it: the minimum over the at most 2 x 2 pyramid cells of the smallest level whose cells
    /// are at least as wide as the window. Exact for a single cell.
    pub fn min_d2_window(&self, i0: i32, i1: i32, j0: i32, j1: i32) -> u8 {
        let last = MAP_SIDE as i32 - 1;
        let (i0, i1, j0, j1) = (i0.max(0), i1.min(last), j0.max(0), j1.min(last));
        if i0 > i1 || j0 > j1 {
            return MAX_D2_CELLS;
        }
        let width = (i1 - i0 + 1).max(j1 - j0 + 1);
        if width == 1 {
            return self.d2_at(i0, j0);
        }
        // Smallest level with 2^level >= width (width <= MAP_SIDE after clipping).
        let mut level = 0usize;
        while level < PYRAMID_LEVELS && (1i32 << level) < width {
            level += 1;
        }
        let side = level_side(level) as i32;
        let (a0, a1, b0, b1) = (i0 >> level, i1 >> level, j0 >> level, j1 >> level);
        let mut best = MAX_D2_CELLS;
        // At most two blocks per axis (the window is no wider than a block); clamped anyway.
        for a in a0..=a1.min(a0 + 1).min(side - 1) {
            for b in b0..=b1.min(b0 + 1).min(side - 1) {
                best = best.min(self.level_value(level, a, b));
            }
        }
        best
    }

    /// Value of pyramid cell `(a, b)` of `level` (0: the distance transform).
    fn level_value(&self, level: usize, a: i32, b: i32) -> u8 {
        if level == 0 {
            return self.d2_at(a, b);
        }
        let side = level_side(level);
        if a < 0 || b < 0 || a as usize >= side || b as usize >= side {
            return MAX_D2_CELLS;
        }
        self.pyramid
            .get(pyramid_offset(level) + a as usize * side + b as usize)
            .copied()
            .unwrap_or(MAX_D2_CELLS)
    }

    /// Column pass: squared distance to the nearest occupied cell of the same column `j`
    /// (two sweeps along `i`), truncated at 255.
    fn column_pass(&mut self) {
        let far = MAP_SIDE as u32 * 2;
        for j in 0..MAP_SIDE {
            let mut dist = [far; MAP_SIDE];
            let mut last = far;
            for (i, d) in dist.iter_mut().enumerate() {
                let occupied = self.d2.get(i * MAP_SIDE + j) == Some(&0);
                last = if occupied { 0 } else { (last + 1).min(far) };
                *d = last;
            }
            last = far;
            for (i, d) in dist.iter_mut().enumerate().rev() {
                let occupied = self.d2.get(i * MAP_SIDE + j) == Some(&0);
                last = if occupied { 0 } else { (last + 1).min(far) };
                *d = (*d).min(last);
            }
            for (i, d) in dist.iter().enumerate() {
                if let Some(v) = self.d2.get_mut(i * MAP_SIDE + j) {
                    *v = (d * d).min(u32::from(MAX_D2_CELLS)) as u8;
                }
            }
        }
    }

    /// Row pass: `D(i, j) = min_k f(k) + (j - k)^2` with `f` the column pass of row `i`,
    /// through the lower envelope of the parabolas (Felzenszwalb & Huttenlocher, alg. 1),
    /// truncated at 255.
    fn row_pass(&mut self) {
        for i in 0..MAP_SIDE {
            let Some(row) = self.d2.get_mut(i * MAP_SIDE..(i + 1) * MAP_SIDE) else {
                continue;
            };
            let mut f = [0i64; MAP_SIDE];
            for (dst, src) in f.iter_mut().zip(row.iter()) {
                *dst = i64::from(*src);
            }
            lower_envelope(&f, row);
        }
    }

    /// Levels 1 to [`PYRAMID_LEVELS`]: each cell the minimum of the (up to) 2 x 2 cells below.
    fn build_pyramid(&mut self) {
        for level in 1..=PYRAMID_LEVELS {
            let side = level_side(level);
            for a in 0..side {
                for b in 0..side {
                    let (a2, b2) = (2 * a as i32, 2 * b as i32);
                    let v = self
                        .level_value(level - 1, a2, b2)
                        .min(self.level_value(level - 1, a2 + 1, b2))
                        .min(self.level_value(level - 1, a2, b2 + 1))
                        .min(self.level_value(level - 1, a2 + 1, b2 + 1));
                    if let Some(slot) = self.pyramid.get_mut(pyramid_offset(level) + a * side + b) {
                        *slot = v;
                    }
                }
            }
        }
    }
}

/// Felzenszwalb & Huttenlocher's 1-D squared distance transform of `f` (alg. 1, integer
/// parabolas, the intersections in exact rational comparisons), written to `out` truncated
/// at 255. Every loop is bounded by `MAP_SIDE`.
fn lower_envelope(f: &[i64; MAP_SIDE], out: &mut [u8]) {
    let n = MAP_SIDE;
    // v: parabola vertices of the envelope; the boundary between parabola k-1 and k is the
    // intersection of parabolas v[k-1] and v[k].
    let mut v = [0usize; MAP_SIDE];
    let mut k = 0usize;
    let val = |q: usize| f.get(q).copied().unwrap_or(i64::from(MAX_D2_CELLS));
    // Intersection abscissa of parabolas p < q as the fraction (num, den), den > 0.
    let cross = |p: usize, q: usize| {
        let (pi, qi) = (p as i64, q as i64);
        ((val(q) + qi * qi) - (val(p) + pi * pi), 2 * (qi - pi))
    };
    for q in 1..n {
        // Pop parabolas hidden by q: s(v[k], q) <= s(v[k-1], v[k]).
        for _ in 0..n {
            if k == 0 {
                break;
            }
            let (Some(&vk), Some(&vk1)) = (v.get(k), v.get(k - 1)) else {
                break;
            };
            let (n1, d1) = cross(vk, q);
            let (n0, d0) = cross(vk1, vk);
            // n1/d1 <= n0/d0 with positive denominators.
            if n1 * d0 <= n0 * d1 {
                k -= 1;
            } else {
                break;
            }
        }
        k += 1;
        if let Some(slot) = v.get_mut(k) {
            *slot = q;
        }
    }
    let mut j = 0usize;
    for (q, o) in out.iter_mut().enumerate().take(n) {
        // Advance while the boundary after parabola j lies left of q: s(v[j], v[j+1]) < q.
        for _ in 0..n {
            if j >= k {
                break;
            }
            let (Some(&a), Some(&b)) = (v.get(j), v.get(j + 1)) else {
                break;
            };
            let (num, den) = cross(a, b);
            if num < (q as i64) * den {
                j += 1;
            } else {
                break;
            }
        }
        let vj = v.get(j).copied().unwrap_or(q);
        let d = q as i64 - vj as i64;
        *o = (d * d + val(vj)).clamp(0, i64::from(MAX_D2_CELLS)) as u8;
    }
}
