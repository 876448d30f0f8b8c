//! Carrot heading (H04 sec. 5, eq. 47; H05 sec. V.A, eq. 19).

use super::path::{distance, Path, Point2};

/// Largest number of times the carrot circle is grown when it does not meet the path.
pub const MAX_RADIUS_DOUBLINGS: u32 = 16;

/// The carrot: the point where a circle around the rover meets the path, furthest along it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Carrot {
    /// Carrot point in the navigation frame `N` (x north, y east), m.
    pub point: Point2,
    /// Arc length of the carrot along the path, m.
    pub along_m: f64,
    /// Circle radius that met the path, m (the nominal radius unless it had to grow).
    pub radius_m: f64,
    /// Heading from the rover to the carrot in `N`, rad (0 north, +pi/2 east).
    pub heading_rad: f64,
}

/// The carrot for a rover at `position` (`N`, m): the intersection of the circle of radius
/// `radius_m` around the rover with the path that is furthest along the path; the goal itself
/// when the goal lies inside the circle. When the circle meets no segment the radius doubles
/// (at most [`MAX_RADIUS_DOUBLINGS`] times; `None` after that or for a non-finite input).
pub fn carrot<const N: usize>(path: &Path<N>, position: Point2, radius_m: f64) -> Option<Carrot> {
    let finite = position[0].is_finite() && position[1].is_finite() && radius_m.is_finite();
    if !finite || radius_m <= 0.0 {
        return None;
    }
    let goal = path.goal();
    let mut r = radius_m;
    for _ in 0..=MAX_RADIUS_DOUBLINGS {
        let found = if distance(position, goal) <= r {
            Some((goal, path.length_m()))
        } else {
            furthest_intersection(path, position, r)
        };
        if let Some((point, along_m)) = found {
            let heading_rad = libm::atan2(point[1] - position[1], point[0] - position[0]);
            return Some(Carrot {
                point,
                along_m,
                radius_m: r,
                heading_rad,
            });
        }
        r *= 2.0;
    }
    None
}

/// Intersection of the circle `|q - c| = r` with the path furthest along it.
fn furthest_intersection<const N: usize>(
    path: &Path<N>,
    c: Point2,
    r: f64,
) -> Option<(Point2, f64)> {
    let mut best: Option<(Point2, f64)> = None;
    for (a, b, s0) in path.segments() {
        let d = [b[0] - a[0], b[1] - a[1]];
        let f = [a[0] - c[0], a[1] - c[1]];
        // |f + t d|^2 = r^2  ->  (d.d) t^2 + 2 (f.d) t + (f.f - r^2) = 0
        let qa = d[0] * d[0] + d[1] * d[1];
        let qb = 2.0 * (f[0] * d[0] + f[1] * d[1]);
        let qc = f[0] * f[0] + f[1] * f[1] - r * r;
        let disc = qb * qb - 4.0 * qa * qc;
        if disc < 0.0 || qa <= 0.0 {
            continue;
        }
        let root = crate::linalg::sqrt(disc);
        // The larger root is further along this segment; fall back to the smaller one.
        for t in [(-qb + root) / (2.0 * qa), (-qb - root) / (2.0 * qa)] {
            if (0.0..=1.0).contains(&t) {
                let along = s0 + t * crate::linalg::sqrt(qa);
                if best.is_none_or(|(_, s)| along > s) {
                    best = Some(([a[0] + t * d[0], a[1] + t * d[1]], along));
                }
                break;
            }
        }
    }
    best
}

/// Angle wrapped to `(-pi, pi]`, rad.
pub fn wrap_pi(angle_rad: f64) -> f64 {
    let two_pi = 2.0 * core::f64::consts::PI;
    let mut a = libm::remainder(angle_rad, two_pi);
    if a <= -core::f64::consts::PI {
        a += two_pi;
    }
    a
}
