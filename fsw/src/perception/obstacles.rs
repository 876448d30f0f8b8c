//! Obstacles as convex polygons (V99 sec. 4: "a streamlined local model of convex polygons
//! enveloping detected obstacles"): connected hazard cells by a bounded flood fill, their convex
//! hull (Andrew's monotone chain), fewer vertices by edge extension (each step enlarges the
//! polygon), and growth by the rover's half-width (Minkowski sum with a regular polygon that
//! circumscribes the growth disc).
//!
//! Polygons are counter-clockwise: positive signed area in their `(x, y)` coordinates (grid
//! `x_G, y_G` or world `x_W, y_W`, m; the map between the two is a rotation, which keeps the
//! orientation).

use super::grid::{cell_centre, CellClass, TerrainGrid};
use super::{
    Point2, CELL_SIZE_M, GRID_CELLS, GRID_COLS, GRID_ROWS, GRID_X_MIN_M, GRID_Y_MIN_M, GROW_SIDES,
    MAX_POLYGON_VERTICES,
};

/// A convex obstacle polygon, counter-clockwise, at most [`MAX_POLYGON_VERTICES`] vertices, m.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ConvexPolygon {
    /// Vertices in order, counter-clockwise, no repeated first vertex.
    pub vertices: heapless::Vec<Point2, MAX_POLYGON_VERTICES>,
}

impl ConvexPolygon {
    /// Signed area (positive when counter-clockwise), m^2.
    pub fn area(&self) -> f64 {
        signed_area(&self.vertices)
    }

    /// True when `p` is inside or on the boundary (counter-clockwise convex polygon with at
    /// least three vertices).
    pub fn contains(&self, p: Point2) -> bool {
        contains_convex(&self.vertices, p)
    }

    /// True when the polygon has at least three vertices, every turn is strictly to the left
    /// (convex, counter-clockwise) and every value is finite.
    pub fn is_convex_ccw(&self) -> bool {
        is_convex_ccw(&self.vertices)
    }

    /// Distance from `p` to the polygon, m (0 inside, infinite for fewer than 3 vertices).
    pub fn distance(&self, p: Point2) -> f64 {
        distance_to_polygon(&self.vertices, p)
    }

    /// The first [`MAX_POLYGON_VERTICES`] points of `points` as a polygon (not checked).
    pub fn from_points(points: &[Point2]) -> Self {
        let mut vertices = heapless::Vec::new();
        for &p in points.iter().take(MAX_POLYGON_VERTICES) {
            // Within capacity by the `take`.
            let _ = vertices.push(p);
        }
        Self { vertices }
    }
}

/// Distance from `p` to the counter-clockwise convex polygon `poly`, m: 0 inside or on the
/// boundary, else the distance to the nearest edge; infinite for fewer than 3 vertices.
pub fn distance_to_polygon(poly: &[Point2], p: Point2) -> f64 {
    let n = poly.len();
    if n < 3 {
        return f64::INFINITY;
    }
    if contains_convex(poly, p) {
        return 0.0;
    }
    let mut best = f64::INFINITY;
    for (k, &a) in poly.iter().enumerate() {
        let Some(&b) = poly.get((k + 1) % n) else {
            continue;
        };
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let length_sq = ex * ex + ey * ey;
        let t = if length_sq > 0.0 {
            (((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / length_sq).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d = libm::hypot(a[0] + t * ex - p[0], a[1] + t * ey - p[1]);
        best = best.min(d);
    }
    best
}

/// `(b - a) x (c - a)`: positive when `a, b, c` turn left (counter-clockwise).
pub fn cross(a: Point2, b: Point2, c: Point2) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Signed area of a polygon (shoelace), m^2.
pub fn signed_area(poly: &[Point2]) -> f64 {
    let n = poly.len();
    let mut twice = 0.0;
    for (k, a) in poly.iter().enumerate() {
        if let Some(b) = poly.get((k + 1) % n) {
            twice += a[0] * b[1] - b[0] * a[1];
        }
    }
    0.5 * twice
}

/// True when `p` is inside or on a counter-clockwise convex polygon (at least 3 vertices).
pub fn contains_convex(poly: &[Point2], p: Point2) -> bool {
    let n = poly.len();
    n >= 3
        && poly.iter().enumerate().all(|(k, &a)| {
            poly.get((k + 1) % n)
                .is_some_and(|&b| cross(a, b, p) >= -1e-12)
        })
}

/// True when `poly` has at least three finite vertices and turns strictly left at each.
pub fn is_convex_ccw(poly: &[Point2]) -> bool {
    let n = poly.len();
    n >= 3
        && poly.iter().all(|v| v[0].is_finite() && v[1].is_finite())
        && (0..n).all(
            |k| match (poly.get(k), poly.get((k + 1) % n), poly.get((k + 2) % n)) {
                (Some(&a), Some(&b), Some(&c)) => cross(a, b, c) > 0.0,
                _ => false,
            },
        )
}

/// Andrew's monotone chain: the convex hull of `points`, which must be sorted by `x`, then `y`
/// (ties allowed), written counter-clockwise to `out` without collinear or repeated vertices,
/// starting at the lowest-`x` point. Returns the number of hull vertices: 0 when `out` has fewer
/// than `2 * points.len()` slots, and fewer than 3 for degenerate (collinear) input.
pub fn convex_hull_sorted(points: &[Point2], out: &mut [Point2]) -> usize {
    let n = points.len();
    if out.len() < 2 * n {
        return 0;
    }
    if n < 3 {
        for (slot, &p) in out.iter_mut().zip(points) {
            *slot = p;
        }
        return n;
    }
    let mut k = 0usize;
    // Lower hull, left to right.
    for &p in points {
        while k >= 2 {
            match (out.get(k - 2), out.get(k - 1)) {
                (Some(&a), Some(&b)) if cross(a, b, p) <= 0.0 => k -= 1,
                _ => break,
            }
        }
        if let Some(slot) = out.get_mut(k) {
            *slot = p;
            k += 1;
        }
    }
    // Upper hull, right to left, without the last point (already the lower hull's end).
    let lower = k + 1;
    for &p in points.iter().rev().skip(1) {
        while k >= lower {
            match (out.get(k - 2), out.get(k - 1)) {
                (Some(&a), Some(&b)) if cross(a, b, p) <= 0.0 => k -= 1,
                _ => break,
            }
        }
        if let Some(slot) = out.get_mut(k) {
            *slot = p;
            k += 1;
        }
    }
    // The last point repeats the first.
    k.saturating_sub(1)
}

/// Reduces a counter-clockwise convex polygon `poly[..len]` to at most `target` (>= 3)
/// vertices. Each step removes the edge whose two neighbouring edges, extended until they meet,
/// add the least area (the edge's two vertices are replaced by the meeting point), so the
/// result contains the input. Returns the new length; if no edge can be removed (the neighbours
/// of every edge diverge), the polygon is replaced by its axis-aligned bounding box (4
/// vertices, also containing it). At most `len - target` steps of `len` candidates each.
pub fn reduce_vertices(poly: &mut [Point2], len: usize, target: usize) -> usize {
    let mut len = len.min(poly.len());
    let target = target.max(4);
    let steps = len;
    for _ in 0..steps {
        if len <= target {
            break;
        }
        let mut best: Option<(f64, usize, Point2)> = None;
        for i in 0..len {
            let at = |k: usize| poly.get((i + len + k - 1) % len).copied();
            // Edge v_i -> v_(i+1); neighbours v_(i-1) -> v_i and v_(i+2) -> v_(i+1).
            let (Some(prev), Some(a), Some(b), Some(next)) = (at(0), at(1), at(2), at(3)) else {
                continue;
            };
            let Some(q) = extension_meet(prev, a, b, next) else {
                continue;
            };
            let added = cross(a, q, b).abs() * 0.5;
            if best.is_none_or(|(area, _, _)| added < area) {
                best = Some((added, i, q));
            }
        }
        let Some((_, i, q)) = best else {
            return bounding_box(poly, len);
        };
        // v_i := q, remove v_(i+1).
        if let Some(slot) = poly.get_mut(i) {
            *slot = q;
        }
        let removed = (i + 1) % len;
        for k in removed..len.saturating_sub(1) {
            if let Some(&v) = poly.get(k + 1) {
                if let Some(slot) = poly.get_mut(k) {
                    *slot = v;
                }
            }
        }
        // (When the removed vertex is the first, the shift moves v_i = q down by one too.)
        len -= 1;
    }
    len
}

/// Where the line `prev -> a` extended beyond `a` meets the line `next -> b` extended beyond
/// `b`; `None` when they are parallel or meet behind (the exterior angles at `a` and `b` sum to
/// 180 deg or more).
fn extension_meet(prev: Point2, a: Point2, b: Point2, next: Point2) -> Option<Point2> {
    let d1 = [a[0] - prev[0], a[1] - prev[1]];
    let d2 = [b[0] - next[0], b[1] - next[1]];
    let denominator = d1[0] * d2[1] - d1[1] * d2[0];
    if !(libm::fabs(denominator) > 1e-15) {
        return None;
    }
    // a + s d1 = b + u d2.
    let w = [b[0] - a[0], b[1] - a[1]];
    let s = (w[0] * d2[1] - w[1] * d2[0]) / denominator;
    let u = (w[0] * d1[1] - w[1] * d1[0]) / denominator;
    (s >= 0.0 && u >= 0.0 && s.is_finite() && u.is_finite())
        .then(|| [a[0] + s * d1[0], a[1] + s * d1[1]])
}

/// Replaces `poly[..len]` by its axis-aligned bounding box (counter-clockwise, 4 vertices) when
/// `poly` has room for 4; returns the new length.
fn bounding_box(poly: &mut [Point2], len: usize) -> usize {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for v in poly.iter().take(len) {
        lo = [lo[0].min(v[0]), lo[1].min(v[1])];
        hi = [hi[0].max(v[0]), hi[1].max(v[1])];
    }
    let corners = [
        [lo[0], lo[1]],
        [hi[0], lo[1]],
        [hi[0], hi[1]],
        [lo[0], hi[1]],
    ];
    if poly.len() < 4 {
        return len;
    }
    for (slot, c) in poly.iter_mut().zip(corners) {
        *slot = c;
    }
    4
}

/// Minkowski sum of the counter-clockwise convex polygon `poly` with the regular `sides`-gon
/// whose inscribed circle has radius `radius_m` (so the sum contains every point within
/// `radius_m` of `poly`), written counter-clockwise to `out`. Returns the number of vertices
/// (at most `poly.len() + sides`), 0 when `out` is too small, `poly` has fewer than 3 vertices,
/// `sides` is not in `3..=64` or the radius is not finite and non-negative. Edges are merged by
/// direction from the lowest vertex of each polygon (`poly.len() + sides` steps).
pub fn grow(poly: &[Point2], radius_m: f64, sides: usize, out: &mut [Point2]) -> usize {
    let n = poly.len();
    let k = sides;
    if n < 3 || !(3..=64).contains(&k) || out.len() < n + k || !(radius_m >= 0.0) {
        return 0;
    }
    if !radius_m.is_finite() {
        return 0;
    }
    // Regular polygon, vertices at -90 deg + m * 360 deg / k, vertex radius r / cos(pi / k).
    let step = 2.0 * core::f64::consts::PI / k as f64;
    let vertex_radius = radius_m / libm::cos(step / 2.0);
    let q = |m: usize| -> Point2 {
        let (s, c) = libm::sincos(-core::f64::consts::FRAC_PI_2 + step * (m % k) as f64);
        [vertex_radius * c, vertex_radius * s]
    };
    // Start of poly: lowest y, then lowest x.
    let mut start = 0usize;
    for (i, v) in poly.iter().enumerate() {
        if let Some(s) = poly.get(start) {
            if v[1] < s[1] || (v[1] == s[1] && v[0] < s[0]) {
                start = i;
            }
        }
    }
    let p = |i: usize| poly.get((start + i) % n).copied().unwrap_or([0.0, 0.0]);
    let (mut i, mut j, mut len) = (0usize, 0usize, 0usize);
    for _ in 0..(n + k) {
        if i >= n && j >= k {
            break;
        }
        let (pi, qj) = (p(i), q(j));
        if let Some(slot) = out.get_mut(len) {
            *slot = [pi[0] + qj[0], pi[1] + qj[1]];
            len += 1;
        }
        let e1 = [p(i + 1)[0] - pi[0], p(i + 1)[1] - pi[1]];
        let e2 = [q(j + 1)[0] - qj[0], q(j + 1)[1] - qj[1]];
        let turn = e1[0] * e2[1] - e1[1] * e2[0];
        if j >= k || (i < n && turn > 0.0) {
            i += 1;
        } else if i >= n || turn < 0.0 {
            j += 1;
        } else {
            i += 1;
            j += 1;
        }
    }
    len
}

/// A connected set of hazard cells found by [`flood_fill`], with the occluded cells behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct Component {
    /// Hazard cells in the component.
    pub cells: u16,
    /// Points in those cells.
    pub points: u32,
    /// Per grid row `i`: the lowest and highest column `j` of the component's cells and shadow
    /// cells (`(u8::MAX, 0)` for a row without any).
    pub rows: [(u8, u8); GRID_ROWS],
    /// The queue was full: some connected hazard cells were left for another component.
    pub overflowed: bool,
}

impl Default for Component {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Component {
    /// No cells (as [`Default`], usable in a `const`).
    pub const EMPTY: Self = Self {
        cells: 0,
        points: 0,
        rows: [(u8::MAX, 0); GRID_ROWS],
        overflowed: false,
    };
}

impl Component {
    fn include(&mut self, i: usize, j: usize) {
        if let Some(row) = self.rows.get_mut(i) {
            let j = j.min(usize::from(u8::MAX - 1)) as u8;
            *row = (row.0.min(j), row.1.max(j));
        }
    }

    /// The convex hull of the component's cells (their squares) in grid coordinates, written
    /// counter-clockwise to `out`; returns the vertex count (0 for an empty component or a too
    /// small `out`, which needs `4 * (GRID_ROWS + 1)` slots).
    pub fn hull(&self, out: &mut [Point2]) -> usize {
        // For each row boundary x_b (b = 0..=GRID_ROWS), the extreme y of the two rows touching
        // it: at most 2 points per boundary, sorted by x then y.
        let mut points = [[0.0f64; 2]; 2 * (GRID_ROWS + 1)];
        let mut n = 0usize;
        for b in 0..=GRID_ROWS {
            let mut span: Option<(u8, u8)> = None;
            for row in [b.checked_sub(1), Some(b)].into_iter().flatten() {
                if let Some(&(lo, hi)) = self.rows.get(row) {
                    if lo <= hi {
                        span = Some(span.map_or((lo, hi), |(a, c)| (a.min(lo), c.max(hi))));
                    }
                }
            }
            if let Some((lo, hi)) = span {
                let x = GRID_X_MIN_M + b as f64 * CELL_SIZE_M;
                let y_lo = GRID_Y_MIN_M + f64::from(lo) * CELL_SIZE_M;
                let y_hi = GRID_Y_MIN_M + (f64::from(hi) + 1.0) * CELL_SIZE_M;
                for y in [y_lo, y_hi] {
                    if let Some(slot) = points.get_mut(n) {
                        *slot = [x, y];
                        n += 1;
                    }
                }
            }
        }
        convex_hull_sorted(points.get(..n).unwrap_or(&[]), out)
    }
}

/// Bounded 8-connected flood fill of the hazard cells from cell index `seed`, breadth first
/// with a ring queue of `Q` cells. Cells are marked in `visited` when queued; a neighbour found
/// while the queue is full is left unmarked and `overflowed` is set: the cell joins this
/// component if a cell dequeued later reaches it again, otherwise a later seed makes it (and
/// what connects to it) another component, so the components still cover every hazard cell. For every hazard cell, up to `shadow_cells` empty cells (no points)
/// straight behind it as seen from the grid origin (the camera's nadir) join the component's
/// extent (the hidden far side of an obstacle). At most [`GRID_CELLS`] cells are dequeued.
pub fn flood_fill<const Q: usize>(
    grid: &TerrainGrid,
    visited: &mut [bool; GRID_CELLS],
    seed: usize,
    shadow_cells: u8,
    out: &mut Component,
) {
    *out = Component::default();
    let mut queue = [0u16; Q];
    let (mut head, mut len) = (0usize, 0usize);
    let is_free_hazard = |visited: &[bool; GRID_CELLS], k: usize| {
        grid.class_at(k) == CellClass::Hazard && visited.get(k) == Some(&false)
    };
    if Q == 0 || !is_free_hazard(visited, seed) {
        return;
    }
    if let (Some(v), Some(slot)) = (visited.get_mut(seed), queue.get_mut(0)) {
        *v = true;
        *slot = seed as u16;
        len = 1;
    }
    for _ in 0..GRID_CELLS {
        if len == 0 {
            break;
        }
        let k = usize::from(queue.get(head).copied().unwrap_or(0));
        head = (head + 1) % Q;
        len -= 1;
        let (i, j) = (k / GRID_COLS, k % GRID_COLS);
        out.cells = out.cells.saturating_add(1);
        out.points = out.points.saturating_add(u32::from(grid.count_at(k)));
        out.include(i, j);
        add_shadow(grid, i, j, shadow_cells, out);
        for di in -1isize..=1 {
            for dj in -1isize..=1 {
                if di == 0 && dj == 0 {
                    continue;
                }
                let (Some(ni), Some(nj)) = (i.checked_add_signed(di), j.checked_add_signed(dj))
                else {
                    continue;
                };
                if ni >= GRID_ROWS || nj >= GRID_COLS {
                    continue;
                }
                let nk = ni * GRID_COLS + nj;
                if !is_free_hazard(visited, nk) {
                    continue;
                }
                if len >= Q {
                    out.overflowed = true;
                    continue;
                }
                if let (Some(v), Some(slot)) =
                    (visited.get_mut(nk), queue.get_mut((head + len) % Q))
                {
                    *v = true;
                    *slot = nk as u16;
                    len += 1;
                }
            }
        }
    }
}

/// Adds to `out` up to `shadow_cells` empty cells straight behind hazard cell `(i, j)` along
/// the ray from the grid origin through its centre (stops at the first cell with points or at
/// the grid's edge).
fn add_shadow(grid: &TerrainGrid, i: usize, j: usize, shadow_cells: u8, out: &mut Component) {
    let [x, y] = cell_centre(i, j);
    let r = libm::hypot(x, y);
    if !(r > 1e-9) {
        return;
    }
    let (ux, uy) = (x / r * CELL_SIZE_M, y / r * CELL_SIZE_M);
    for s in 1..=usize::from(shadow_cells) {
        let (px, py) = (x + ux * s as f64, y + uy * s as f64);
        let Some((si, sj)) = super::grid::cell_of(px, py) else {
            return;
        };
        if (si, sj) == (i, j) {
            continue;
        }
        if grid.cell(si, sj).is_none_or(|c| c.count > 0) {
            return;
        }
        out.include(si, sj);
    }
}

/// The grown convex polygon of a component in grid coordinates and the number of vertices
/// removed to fit [`MAX_POLYGON_VERTICES`]: hull, at most `MAX_POLYGON_VERTICES - GROW_SIDES`
/// hull vertices, Minkowski sum with the regular [`GROW_SIDES`]-gon of inscribed radius
/// `radius_m`. `None` for an empty component.
#[inline(never)]
pub fn component_polygon(component: &Component, radius_m: f64) -> Option<(ConvexPolygon, u16)> {
    let mut hull = [[0.0f64; 2]; 4 * (GRID_ROWS + 1)];
    let n = component.hull(&mut hull);
    if n < 3 {
        return None;
    }
    let target = MAX_POLYGON_VERTICES - GROW_SIDES;
    let reduced_len = reduce_vertices(&mut hull, n, target);
    let mut grown = [[0.0f64; 2]; MAX_POLYGON_VERTICES];
    let m = grow(hull.get(..reduced_len)?, radius_m, GROW_SIDES, &mut grown);
    if m < 3 {
        return None;
    }
    let polygon = ConvexPolygon::from_points(grown.get(..m)?);
    Some((polygon, n.saturating_sub(reduced_len) as u16))
}
