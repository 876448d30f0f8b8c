//! Planar geometry of the RoverBug planner (V99 sec. 4): convex obstacle polygons, segment and
//! point tests, tangents from a point, polygon intersection.
//!
//! Frame: the navigation frame `N` projected on the ground plane, `[x, y]` = (north, east) in
//! metres. Angles are `atan2(y, x)`, i.e. yaw from north, positive towards east (to the rover's
//! right). A polygon is stored with positive signed area in `(x, y)` ("counter-clockwise" about
//! +z in the mathematical sense; because z points down in `N`, this is clockwise on a north-up
//! map seen from above). Input of either orientation is accepted: every polygon is rebuilt as
//! the convex hull of its points.

use crate::guidance::{wrap_pi, Point2};
use heapless::Vec;

/// Most vertices of a stored polygon. Larger inputs are reduced by an outer approximation
/// ([`ConvexPolygon::from_points`]), so the stored polygon always contains the input.
pub const MAX_VERTICES: usize = 12;

/// Most points accepted by [`ConvexPolygon::from_points`].
pub const MAX_INPUT_POINTS: usize = 32;

/// Distance tolerance, m: a point within `EPS_M` of a polygon's boundary is on the boundary,
/// and a segment must pass deeper than `EPS_M` inside a polygon to hit it.
pub const EPS_M: f64 = 1e-6;

/// Smallest accepted polygon area, m^2 (a 1 mm x 1 mm square).
pub const MIN_AREA_M2: f64 = 1e-6;

/// Largest accepted coordinate magnitude, m (keeps products of coordinates exact enough).
pub const MAX_COORDINATE_M: f64 = 1e6;

/// Why a polygon or wedge was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GeometryError {
    /// A coordinate, angle or range is NaN or infinite.
    NonFinite,
    /// A coordinate is beyond [`MAX_COORDINATE_M`] or a range/angle is out of its domain.
    OutOfRange,
    /// More than [`MAX_INPUT_POINTS`] points.
    TooManyPoints,
    /// Fewer than three non-collinear points, or an area below [`MIN_AREA_M2`].
    Degenerate,
}

/// Where a point lies with respect to a polygon (tolerance [`EPS_M`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointLocation {
    /// Farther than `EPS_M` outside.
    Outside,
    /// Within `EPS_M` of the boundary.
    Boundary,
    /// Deeper than `EPS_M` inside.
    Inside,
}

/// The directions under which a convex polygon is seen from a point outside it or on its
/// boundary: every direction from the point into the polygon lies in `[lo_rad, hi_rad]`
/// (unwrapped yaw, `lo_rad <= hi_rad`, width at most pi). `lo_vertex` / `hi_vertex` are the
/// tangent vertices (indices into [`ConvexPolygon::vertices`]); on a tie in angle the farther
/// vertex is taken. The `hi` tangent is on the observer's right (yaw positive right).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AngularInterval {
    /// Smallest yaw towards the polygon, rad.
    pub lo_rad: f64,
    /// Largest yaw towards the polygon, rad.
    pub hi_rad: f64,
    /// Vertex seen at `lo_rad`.
    pub lo_vertex: usize,
    /// Vertex seen at `hi_rad`.
    pub hi_vertex: usize,
}

/// A convex polygon in the ground plane of `N`, m, positive orientation, no collinear or
/// repeated vertices, area at least [`MIN_AREA_M2`], with its outward unit edge normals and a
/// bounding circle (used to skip far polygons cheaply).
#[derive(Debug, Clone, PartialEq)]
pub struct ConvexPolygon {
    vertices: Vec<Point2, MAX_VERTICES>,
    /// Outward unit normal of the edge from vertex `i` to vertex `i + 1`.
    normals: Vec<Point2, MAX_VERTICES>,
    center: Point2,
    radius_m: f64,
}

/// `a - b`.
pub fn sub(a: Point2, b: Point2) -> Point2 {
    [a[0] - b[0], a[1] - b[1]]
}

/// `a + s b`.
pub fn add_scaled(a: Point2, b: Point2, s: f64) -> Point2 {
    [a[0] + s * b[0], a[1] + s * b[1]]
}

/// Dot product.
pub fn dot(a: Point2, b: Point2) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

/// z component of the cross product `a x b` (positive when `b` is at larger yaw than `a`).
pub fn cross(a: Point2, b: Point2) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

/// Euclidean norm, m.
pub fn norm(a: Point2) -> f64 {
    libm::hypot(a[0], a[1])
}

/// Distance between two points, m.
pub fn dist(a: Point2, b: Point2) -> f64 {
    norm(sub(a, b))
}

/// Yaw of the direction from `from` to `to`, rad in (-pi, pi].
pub fn yaw(from: Point2, to: Point2) -> f64 {
    libm::atan2(to[1] - from[1], to[0] - from[0])
}

/// Unit vector at yaw `angle_rad`.
pub fn unit(angle_rad: f64) -> Point2 {
    [libm::cos(angle_rad), libm::sin(angle_rad)]
}

/// True when both coordinates are finite and within [`MAX_COORDINATE_M`].
pub fn point_ok(p: Point2) -> bool {
    p[0].is_finite()
        && p[1].is_finite()
        && libm::fabs(p[0]) <= MAX_COORDINATE_M
        && libm::fabs(p[1]) <= MAX_COORDINATE_M
}

/// Distance from `p` to the segment `a`-`b`, m.
pub fn point_segment_distance(p: Point2, a: Point2, b: Point2) -> f64 {
    let d = sub(b, a);
    let l2 = dot(d, d);
    let t = if l2 > 0.0 {
        (dot(sub(p, a), d) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    dist(p, add_scaled(a, d, t))
}

/// Signed area (shoelace) of a closed polyline, m^2; positive for positive orientation.
fn signed_area(points: &[Point2]) -> f64 {
    let mut twice = 0.0;
    for (i, p) in points.iter().enumerate() {
        let q = points.get(i + 1).or(points.first()).copied().unwrap_or(*p);
        twice += cross(*p, q);
    }
    0.5 * twice
}

/// True when `o -> a -> b` turns left by more than a relative tolerance (1e-12 of the
/// product of the legs: collinear and repeated points do not count as a turn).
fn turns_left(o: Point2, a: Point2, b: Point2) -> bool {
    let u = sub(a, o);
    let v = sub(b, o);
    cross(u, v) > 1e-12 * norm(u) * norm(v)
}

/// Convex hull by Andrew's monotone chain into `out` (positive orientation, collinear and
/// repeated points dropped). Returns the vertex count. `pts` is sorted in place (insertion sort,
/// at most `MAX_INPUT_POINTS^2 / 2` comparisons).
fn monotone_chain(pts: &mut [Point2], out: &mut [Point2; 2 * MAX_INPUT_POINTS + 2]) -> usize {
    let n = pts.len();
    for i in 1..n {
        let mut j = i;
        while j > 0 {
            let (Some(a), Some(b)) = (pts.get(j - 1).copied(), pts.get(j).copied()) else {
                break;
            };
            if (a[0], a[1]) > (b[0], b[1]) {
                pts.swap(j - 1, j);
                j -= 1;
            } else {
                break;
            }
        }
    }
    let mut k = 0usize;
    // Lower hull.
    for p in pts.iter() {
        while k >= 2 {
            let (Some(o), Some(a)) = (out.get(k - 2).copied(), out.get(k - 1).copied()) else {
                break;
            };
            if turns_left(o, a, *p) {
                break;
            }
            k -= 1;
        }
        if let Some(slot) = out.get_mut(k) {
            *slot = *p;
            k += 1;
        }
    }
    // Upper hull.
    let lower = k + 1;
    for p in pts.iter().rev().skip(1) {
        while k >= lower {
            let (Some(o), Some(a)) = (out.get(k - 2).copied(), out.get(k - 1).copied()) else {
                break;
            };
            if turns_left(o, a, *p) {
                break;
            }
            k -= 1;
        }
        if let Some(slot) = out.get_mut(k) {
            *slot = *p;
            k += 1;
        }
    }
    // The last point repeats the first.
    k.saturating_sub(1)
}

/// Vertices closer than this to the previous vertex are dropped from a hull, m: sub-millimetre
/// edges (from clipping and merging) have unreliable normals and make the miter offset and the
/// tangent tests flicker.
pub const MIN_EDGE_M: f64 = 1e-3;

/// Drops hull vertices within [`MIN_EDGE_M`] of the previous kept vertex (cyclically). The
/// polygon stays convex and loses less than a millimetre. Returns the new count.
fn drop_close_vertices(buf: &mut [Point2], n: usize) -> usize {
    let mut kept = 0usize;
    for i in 0..n {
        let Some(p) = buf.get(i).copied() else { break };
        let close = kept > 0 && buf.get(kept - 1).is_some_and(|q| dist(*q, p) < MIN_EDGE_M);
        if !close {
            if let Some(slot) = buf.get_mut(kept) {
                *slot = p;
            }
            kept += 1;
        }
    }
    // Closing pair.
    while kept > 1 {
        let (Some(first), Some(last)) = (buf.first().copied(), buf.get(kept - 1).copied()) else {
            break;
        };
        if dist(first, last) < MIN_EDGE_M {
            kept -= 1;
        } else {
            break;
        }
    }
    kept
}

/// Outer approximation of a convex polygon by one with at most `target` vertices: repeatedly
/// removes the edge whose two neighbouring edges, extended until they meet, add the least area
/// (the result contains the input). Needs `target >= 5` (then a removable edge always exists:
/// the exterior angles sum to 2 pi). Returns the new vertex count.
fn reduce_outer(buf: &mut [Point2], mut n: usize, target: usize) -> usize {
    let mut guard = buf.len();
    while n > target && guard > 0 {
        guard -= 1;
        let mut best: Option<(usize, Point2, f64)> = None;
        for i in 0..n {
            let g = |k: usize| buf.get(k % n).copied().unwrap_or([0.0; 2]);
            let (p_prev, p_i, p_next, p_next2) = (g(i + n - 1), g(i), g(i + 1), g(i + 2));
            let d1 = sub(p_i, p_prev);
            let d2 = sub(p_next2, p_next);
            let c = cross(d1, d2);
            if c <= 1e-12 * norm(d1) * norm(d2) {
                continue;
            }
            let t = cross(sub(p_next, p_i), d2) / c;
            if !(t >= 0.0 && t.is_finite()) {
                continue;
            }
            let w = add_scaled(p_i, d1, t);
            let added = 0.5 * libm::fabs(cross(sub(p_next, p_i), sub(w, p_i)));
            if best.is_none_or(|b| added < b.2) {
                best = Some((i, w, added));
            }
        }
        let Some((i, w, _)) = best else {
            return n;
        };
        // Replace vertex i by w and remove vertex i + 1 (cyclically).
        if let Some(slot) = buf.get_mut(i) {
            *slot = w;
        }
        let remove = (i + 1) % n;
        for k in remove..n.saturating_sub(1) {
            if let Some(next) = buf.get(k + 1).copied() {
                if let Some(slot) = buf.get_mut(k) {
                    *slot = next;
                }
            }
        }
        n -= 1;
    }
    n
}

impl ConvexPolygon {
    /// The convex hull of `points` (m, in `N`), any order and orientation, reduced to at most
    /// [`MAX_VERTICES`] by an outer approximation when the hull has more. Refuses non-finite or
    /// out-of-range coordinates, more than [`MAX_INPUT_POINTS`] points, and hulls with fewer
    /// than three vertices or less than [`MIN_AREA_M2`] area (V99 sec. 4: "convex polygons
    /// enveloping detected obstacles").
    pub fn from_points(points: &[Point2]) -> Result<Self, GeometryError> {
        if points.len() > MAX_INPUT_POINTS {
            return Err(GeometryError::TooManyPoints);
        }
        let mut pts = [[0.0; 2]; MAX_INPUT_POINTS];
        for (slot, p) in pts.iter_mut().zip(points.iter()) {
            if !(p[0].is_finite() && p[1].is_finite()) {
                return Err(GeometryError::NonFinite);
            }
            if !point_ok(*p) {
                return Err(GeometryError::OutOfRange);
            }
            *slot = *p;
        }
        let n_in = points.len();
        let mut hull = [[0.0; 2]; 2 * MAX_INPUT_POINTS + 2];
        let n = monotone_chain(pts.get_mut(..n_in).unwrap_or(&mut []), &mut hull);
        let n = drop_close_vertices(&mut hull, n);
        if n < 3 {
            return Err(GeometryError::Degenerate);
        }
        let n = reduce_outer(&mut hull, n, MAX_VERTICES);
        Self::from_convex(hull.get(..n).unwrap_or(&[]))
    }

    /// Builds the polygon from vertices already convex and positively oriented (hull output,
    /// miter offset); checks the count and the area.
    fn from_convex(vertices: &[Point2]) -> Result<Self, GeometryError> {
        if vertices.len() < 3 || vertices.len() > MAX_VERTICES {
            return Err(GeometryError::Degenerate);
        }
        if !vertices.iter().all(|p| point_ok(*p)) {
            return Err(GeometryError::OutOfRange);
        }
        if signed_area(vertices) < MIN_AREA_M2 {
            return Err(GeometryError::Degenerate);
        }
        let mut v: Vec<Point2, MAX_VERTICES> = Vec::new();
        let mut normals: Vec<Point2, MAX_VERTICES> = Vec::new();
        let mut center = [0.0; 2];
        for (i, p) in vertices.iter().enumerate() {
            let q = vertices
                .get(i + 1)
                .or(vertices.first())
                .copied()
                .unwrap_or(*p);
            let d = sub(q, *p);
            let l = norm(d);
            if l <= 0.0 {
                return Err(GeometryError::Degenerate);
            }
            // Positive orientation: the outward normal is the edge direction turned to lower
            // yaw, (d_y, -d_x).
            let _ = normals.push([d[1] / l, -d[0] / l]);
            let _ = v.push(*p);
            center = add_scaled(center, *p, 1.0);
        }
        let inv = 1.0 / vertices.len() as f64;
        center = [center[0] * inv, center[1] * inv];
        let radius_m = vertices
            .iter()
            .map(|p| dist(*p, center))
            .fold(0.0, f64::max);
        Ok(Self {
            vertices: v,
            normals,
            center,
            radius_m,
        })
    }

    /// The vertices, m, positive orientation.
    pub fn vertices(&self) -> &[Point2] {
        &self.vertices
    }

    /// Number of vertices (3 to [`MAX_VERTICES`]).
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    /// Always false (a polygon has at least three vertices); for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// Vertex `i` modulo the vertex count, m.
    pub fn vertex(&self, i: usize) -> Point2 {
        let n = self.vertices.len().max(1);
        self.vertices.get(i % n).copied().unwrap_or(self.center)
    }

    /// Outward unit normal of edge `i` (vertex `i` to `i + 1`), modulo the count.
    pub fn normal(&self, i: usize) -> Point2 {
        let n = self.normals.len().max(1);
        self.normals.get(i % n).copied().unwrap_or([0.0; 2])
    }

    /// Vertex average, m (strictly inside).
    pub fn center(&self) -> Point2 {
        self.center
    }

    /// Radius of the circle about [`Self::center`] holding every vertex, m.
    pub fn radius_m(&self) -> f64 {
        self.radius_m
    }

    /// Area, m^2.
    pub fn area_m2(&self) -> f64 {
        signed_area(&self.vertices)
    }

    /// Largest signed edge distance `max_i n_i . (p - v_i)`, m: negative inside (minus the
    /// depth), zero on the boundary, positive outside (the Euclidean distance when `p` faces one
    /// edge, a lower bound near a vertex).
    pub fn edge_distance(&self, p: Point2) -> f64 {
        self.vertices
            .iter()
            .zip(self.normals.iter())
            .map(|(v, n)| dot(*n, sub(p, *v)))
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// Where `p` lies (tolerance [`EPS_M`]).
    pub fn locate(&self, p: Point2) -> PointLocation {
        let e = self.edge_distance(p);
        if e > EPS_M {
            PointLocation::Outside
        } else if e >= -EPS_M {
            PointLocation::Boundary
        } else {
            PointLocation::Inside
        }
    }

    /// Euclidean distance from `p` to the polygon, m (zero on or inside it).
    pub fn distance(&self, p: Point2) -> f64 {
        if self.edge_distance(p) <= 0.0 {
            return 0.0;
        }
        let mut best = f64::INFINITY;
        for i in 0..self.len() {
            best = best.min(point_segment_distance(
                p,
                self.vertex(i),
                self.vertex(i + 1),
            ));
        }
        best
    }

    /// The boundary point closest to `p`, m.
    pub fn closest_boundary_point(&self, p: Point2) -> Point2 {
        let mut best = (f64::INFINITY, self.vertex(0));
        for i in 0..self.len() {
            let a = self.vertex(i);
            let d = sub(self.vertex(i + 1), a);
            let l2 = dot(d, d);
            let t = if l2 > 0.0 {
                (dot(sub(p, a), d) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let q = add_scaled(a, d, t);
            let e = dist(p, q);
            if e < best.0 {
                best = (e, q);
            }
        }
        best.1
    }

    /// True when the segment `a`-`b` passes deeper than [`EPS_M`] into the interior
    /// (Cyrus-Beck clipping against the edge half-planes moved inwards by `EPS_M`). Touching
    /// the boundary or running along an edge is not a hit; a zero-length segment hits when the
    /// point is inside.
    pub fn segment_hits_interior(&self, a: Point2, b: Point2) -> bool {
        // Cheap rejection with the bounding circle.
        if point_segment_distance(self.center, a, b) > self.radius_m + EPS_M {
            return false;
        }
        let d = sub(b, a);
        let mut t0 = 0.0f64;
        let mut t1 = 1.0f64;
        for (v, n) in self.vertices.iter().zip(self.normals.iter()) {
            // Inside the shrunk half-plane: n . (a + t d - v) + EPS <= 0.
            let num = dot(*n, sub(a, *v)) + EPS_M;
            let den = dot(*n, d);
            if libm::fabs(den) <= 1e-15 {
                if num > 0.0 {
                    return false;
                }
                continue;
            }
            let t = -num / den;
            if den < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
            if t0 > t1 {
                return false;
            }
        }
        // A zero-length segment: inside all shrunk half-planes.
        t1 >= t0
    }

    /// Mitered outward offset by `offset_m` (every edge moved out by `offset_m`, vertices at the
    /// intersections of the moved edges): contains every point within `offset_m` of the polygon.
    /// Refuses a negative or non-finite offset and vertices sharper than 0.1 deg.
    pub fn inflate(&self, offset_m: f64) -> Result<Self, GeometryError> {
        if !offset_m.is_finite() {
            return Err(GeometryError::NonFinite);
        }
        if offset_m < 0.0 {
            return Err(GeometryError::OutOfRange);
        }
        let n = self.len();
        let mut out = [[0.0; 2]; MAX_VERTICES];
        for (i, slot) in out.iter_mut().enumerate().take(n) {
            let n_in = self.normal(i + n - 1);
            let n_out = self.normal(i);
            let c = 1.0 + dot(n_in, n_out);
            if c < 1e-6 {
                return Err(GeometryError::Degenerate);
            }
            let m = [(n_in[0] + n_out[0]) / c, (n_in[1] + n_out[1]) / c];
            *slot = add_scaled(self.vertex(i), m, offset_m);
        }
        Self::from_convex(out.get(..n).unwrap_or(&[]))
    }

    /// The directions under which the polygon is seen from `p` (tangent vertices), or `None`
    /// when `p` is inside (deeper than [`EPS_M`]). From a point on the boundary the interval is
    /// the interior cone at that point (width pi on an edge, the interior angle at a vertex);
    /// vertices within 10 `EPS_M` of `p` are skipped.
    pub fn angular_interval(&self, p: Point2) -> Option<AngularInterval> {
        if self.locate(p) == PointLocation::Inside {
            return None;
        }
        let reference = yaw(p, self.center);
        let mut lo: Option<(f64, f64, usize)> = None;
        let mut hi: Option<(f64, f64, usize)> = None;
        for (i, v) in self.vertices.iter().enumerate() {
            let r = dist(*v, p);
            if r <= 10.0 * EPS_M {
                continue;
            }
            let rel = wrap_pi(yaw(p, *v) - reference);
            let tie = 1e-12;
            if lo.is_none_or(|(a, d, _)| rel < a - tie || (rel <= a + tie && r > d)) {
                lo = Some((rel, r, i));
            }
            if hi.is_none_or(|(a, d, _)| rel > a + tie || (rel >= a - tie && r > d)) {
                hi = Some((rel, r, i));
            }
        }
        let ((lo_rel, _, lo_vertex), (hi_rel, _, hi_vertex)) = (lo?, hi?);
        Some(AngularInterval {
            lo_rad: reference + lo_rel,
            hi_rad: reference + hi_rel,
            lo_vertex,
            hi_vertex,
        })
    }

    /// True when the two polygons overlap or are closer than `gap_m` (separating-axis test over
    /// both polygons' edge normals).
    pub fn overlaps(&self, other: &ConvexPolygon, gap_m: f64) -> bool {
        if dist(self.center, other.center) > self.radius_m + other.radius_m + gap_m {
            return false;
        }
        let separated = |a: &ConvexPolygon, b: &ConvexPolygon| {
            a.vertices.iter().zip(a.normals.iter()).any(|(v, n)| {
                b.vertices
                    .iter()
                    .map(|w| dot(*n, sub(*w, *v)))
                    .fold(f64::INFINITY, f64::min)
                    > gap_m
            })
        };
        !(separated(self, other) || separated(other, self))
    }

    /// Area of the intersection with `other`, m^2 (Sutherland-Hodgman clipping).
    pub fn intersection_area_m2(&self, other: &ConvexPolygon) -> f64 {
        let mut buf = [[0.0; 2]; CLIP_CAPACITY];
        let n = clip_convex(self.vertices(), other, &mut buf);
        if n < 3 {
            return 0.0;
        }
        signed_area(buf.get(..n).unwrap_or(&[])).max(0.0)
    }

    /// The intersection with `other` as a polygon (outer-approximated to [`MAX_VERTICES`]), or
    /// `None` when it is empty or degenerate.
    pub fn intersection(&self, other: &ConvexPolygon) -> Option<ConvexPolygon> {
        let mut buf = [[0.0; 2]; CLIP_CAPACITY];
        let n = clip_convex(self.vertices(), other, &mut buf);
        if n < 3 {
            return None;
        }
        ConvexPolygon::from_points(buf.get(..n.min(MAX_INPUT_POINTS)).unwrap_or(&[])).ok()
    }

    /// The portion `[t0, t1]` (parameters along `a + t (b - a)`, `0 <= t0 <= t1 <= 1`) of the
    /// segment inside the polygon or within [`EPS_M`] of it, or `None`.
    pub fn clip_segment(&self, a: Point2, b: Point2) -> Option<(f64, f64)> {
        let d = sub(b, a);
        let mut t0 = 0.0f64;
        let mut t1 = 1.0f64;
        for (v, n) in self.vertices.iter().zip(self.normals.iter()) {
            let num = dot(*n, sub(a, *v)) - EPS_M;
            let den = dot(*n, d);
            if libm::fabs(den) <= 1e-15 {
                if num > 0.0 {
                    return None;
                }
                continue;
            }
            let t = -num / den;
            if den < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
            if t0 > t1 {
                return None;
            }
        }
        Some((t0, t1))
    }
}

/// Capacity of the clipping buffers: a convex n-gon clipped by a convex m-gon has at most
/// n + m vertices.
pub const CLIP_CAPACITY: usize = 2 * MAX_VERTICES + 2;

/// Sutherland-Hodgman: `subject` (convex, positive) clipped by `clip`; result into `out`,
/// returns the vertex count (0 when empty).
fn clip_convex(
    subject: &[Point2],
    clip: &ConvexPolygon,
    out: &mut [Point2; CLIP_CAPACITY],
) -> usize {
    let mut n = 0;
    for (slot, p) in out.iter_mut().zip(subject.iter()) {
        *slot = *p;
        n += 1;
    }
    let mut tmp = [[0.0; 2]; CLIP_CAPACITY];
    for (v, normal) in clip.vertices.iter().zip(clip.normals.iter()) {
        if n == 0 {
            return 0;
        }
        let side = |p: Point2| dot(*normal, sub(p, *v));
        let mut m = 0;
        for i in 0..n {
            let (Some(cur), Some(nxt)) = (out.get(i).copied(), out.get((i + 1) % n).copied())
            else {
                break;
            };
            let (sc, sn) = (side(cur), side(nxt));
            if sc <= 0.0 {
                if let Some(slot) = tmp.get_mut(m) {
                    *slot = cur;
                    m += 1;
                }
            }
            if (sc < 0.0 && sn > 0.0) || (sc > 0.0 && sn < 0.0) {
                let t = sc / (sc - sn);
                if let Some(slot) = tmp.get_mut(m) {
                    *slot = add_scaled(cur, sub(nxt, cur), t);
                    m += 1;
                }
            }
        }
        n = m.min(CLIP_CAPACITY);
        out.copy_from_slice(&tmp);
    }
    n
}
