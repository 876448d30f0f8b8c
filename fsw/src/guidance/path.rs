//! Waypoint path with fixed capacity (H04 sec. 5: "a set of linear segments between
//! waypoints").

/// Smallest distance between consecutive waypoints, m. Closer waypoints are a repeated waypoint.
pub const MIN_SEGMENT_M: f64 = 1e-3;

/// A path the guidance refuses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathError {
    /// Fewer than two waypoints.
    TooFewWaypoints,
    /// More waypoints than the path's capacity.
    TooManyWaypoints,
    /// Waypoint `0` has a non-finite coordinate.
    NonFinite(usize),
    /// Waypoint `0` repeats the previous one (closer than [`MIN_SEGMENT_M`]).
    RepeatedWaypoint(usize),
}

/// A point of the path in the navigation frame `N` (x north, y east), m.
pub type Point2 = [f64; 2];

/// A path of at most `N` waypoints in the navigation frame `N`, with the cumulative length at
/// each waypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Path<const N: usize> {
    points: [Point2; N],
    /// Arc length from the first waypoint to waypoint `i`, m.
    along_m: [f64; N],
    len: usize,
}

/// Where a point projects on the path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    /// Index of the segment (from waypoint `segment` to `segment + 1`).
    pub segment: usize,
    /// Arc length of the projected point from the path start, m.
    pub along_m: f64,
    /// Signed cross-track distance, m: positive when the point is to the right of the path
    /// direction (towards +y for a path heading north), as yaw is positive to the right.
    pub cross_track_m: f64,
}

impl<const N: usize> Path<N> {
    /// Build a path from waypoints in `N`, m. Rejects fewer than two waypoints, more than `N`,
    /// non-finite coordinates and repeated waypoints.
    pub fn new(waypoints: &[Point2]) -> Result<Self, PathError> {
        if waypoints.len() < 2 {
            return Err(PathError::TooFewWaypoints);
        }
        if waypoints.len() > N {
            return Err(PathError::TooManyWaypoints);
        }
        let mut points = [[0.0; 2]; N];
        let mut along_m = [0.0; N];
        let mut previous: Option<Point2> = None;
        let mut total = 0.0;
        for (i, ((w, p), a)) in waypoints
            .iter()
            .zip(points.iter_mut())
            .zip(along_m.iter_mut())
            .enumerate()
        {
            if !(w[0].is_finite() && w[1].is_finite()) {
                return Err(PathError::NonFinite(i));
            }
            if let Some(q) = previous {
                let d = distance(q, *w);
                if d < MIN_SEGMENT_M {
                    return Err(PathError::RepeatedWaypoint(i));
                }
                total += d;
            }
            *p = *w;
            *a = total;
            previous = Some(*w);
        }
        Ok(Self {
            points,
            along_m,
            len: waypoints.len(),
        })
    }

    /// The waypoints.
    pub fn waypoints(&self) -> &[Point2] {
        self.points.get(..self.len).unwrap_or(&[])
    }

    /// The last waypoint (the goal).
    pub fn goal(&self) -> Point2 {
        self.waypoints().last().copied().unwrap_or([0.0; 2])
    }

    /// Total length, m.
    pub fn length_m(&self) -> f64 {
        self.along_m
            .get(self.len.saturating_sub(1))
            .copied()
            .unwrap_or(0.0)
    }

    /// The segments as `(start, end, arc length at start)`.
    pub fn segments(&self) -> impl Iterator<Item = (Point2, Point2, f64)> + '_ {
        let w = self.waypoints();
        w.iter()
            .zip(w.iter().skip(1))
            .zip(self.along_m.iter())
            .map(|((a, b), s)| (*a, *b, *s))
    }

    /// Closest point of the path to `p` (ties go to the earlier segment).
    pub fn project(&self, p: Point2) -> Projection {
        let mut best = Projection {
            segment: 0,
            along_m: 0.0,
            cross_track_m: f64::INFINITY,
        };
        let mut best_d2 = f64::INFINITY;
        for (i, (a, b, s0)) in self.segments().enumerate() {
            let d = [b[0] - a[0], b[1] - a[1]];
            let l2 = d[0] * d[0] + d[1] * d[1];
            let t = (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / l2).clamp(0.0, 1.0);
            let q = [a[0] + t * d[0], a[1] + t * d[1]];
            let e = [p[0] - q[0], p[1] - q[1]];
            let d2 = e[0] * e[0] + e[1] * e[1];
            if d2 < best_d2 {
                best_d2 = d2;
                let l = crate::linalg::sqrt(l2);
                // Cross product direction x offset: positive to the right in x-north/y-east.
                let side = d[0] * e[1] - d[1] * e[0];
                best = Projection {
                    segment: i,
                    along_m: s0 + t * l,
                    cross_track_m: libm::copysign(crate::linalg::sqrt(d2), side),
                };
            }
        }
        best
    }
}

/// Euclidean distance, m.
pub fn distance(a: Point2, b: Point2) -> f64 {
    libm::hypot(b[0] - a[0], b[1] - a[1])
}
