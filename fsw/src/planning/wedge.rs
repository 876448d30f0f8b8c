//! The visible wedge of a stereo pair (V99 sec. 4: "the visible region ranged by each stereo
//! pair is roughly a wedge of the ground plane, with limited downrange radius R and half-angle
//! alpha"; chassis (1.5 m, 45 deg), mast (7 m, 15 deg)).

use super::geometry::{add_scaled, dist, point_ok, unit, yaw, ConvexPolygon, GeometryError};
use crate::guidance::{wrap_pi, Point2};

/// Number of chords that approximate the far arc of the wedge in [`Wedge::polygon`]. The
/// chords are inscribed: with a 40 deg half-angle and 5 m range the polygon misses at most
/// 5 (1 - cos 5 deg) = 1.9 cm of the true sector at the arc.
pub const ARC_CHORDS: usize = 8;

/// A sector of the ground plane seen by a stereo pair, in `N` (m, rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wedge {
    /// Apex (camera position projected on the ground), m.
    pub apex: Point2,
    /// Yaw of the wedge axis, rad (from north, positive east).
    pub heading_rad: f64,
    /// Half-angle alpha, rad, in (0, pi/2] (the sector stays convex).
    pub half_angle_rad: f64,
    /// Near range, m (the blind zone in front of the cameras), at least 0.
    pub min_range_m: f64,
    /// Far range R, m, above `min_range_m` and at most 1000 m.
    pub max_range_m: f64,
}

impl Wedge {
    /// Refuses non-finite fields, a half-angle outside (0, pi/2], a negative near range, a far
    /// range not above the near range or beyond 1000 m, and an apex beyond the coordinate limit.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let fields = [
            self.apex[0],
            self.apex[1],
            self.heading_rad,
            self.half_angle_rad,
            self.min_range_m,
            self.max_range_m,
        ];
        if !fields.iter().all(|v| v.is_finite()) {
            return Err(GeometryError::NonFinite);
        }
        let half_ok =
            self.half_angle_rad > 0.0 && self.half_angle_rad <= core::f64::consts::FRAC_PI_2;
        let range_ok = self.min_range_m >= 0.0
            && self.max_range_m > self.min_range_m
            && self.max_range_m <= 1000.0;
        if !(half_ok && range_ok && point_ok(self.apex)) {
            return Err(GeometryError::OutOfRange);
        }
        Ok(())
    }

    /// True when `p` is in the sector: range in `[min_range_m, max_range_m]` and bearing within
    /// the half-angle of the axis (the apex itself is inside only when `min_range_m` is 0).
    pub fn contains(&self, p: Point2) -> bool {
        let r = dist(self.apex, p);
        if r > self.max_range_m || r < self.min_range_m {
            return false;
        }
        if r == 0.0 {
            return true;
        }
        libm::fabs(wrap_pi(yaw(self.apex, p) - self.heading_rad)) <= self.half_angle_rad
    }

    /// The sector as a convex polygon: the apex and [`ARC_CHORDS`] inscribed chords of the far
    /// arc (the near blind zone is not cut out: the planner treats the ground between the rover
    /// and the near range as known from earlier views, see `docs/planning.md`).
    pub fn polygon(&self) -> Result<ConvexPolygon, GeometryError> {
        self.validate()?;
        let mut pts = [[0.0; 2]; ARC_CHORDS + 2];
        if let Some(first) = pts.first_mut() {
            *first = self.apex;
        }
        for (k, slot) in pts.iter_mut().skip(1).enumerate() {
            let f = k as f64 / ARC_CHORDS as f64;
            let a = self.heading_rad - self.half_angle_rad + 2.0 * self.half_angle_rad * f;
            *slot = add_scaled(self.apex, unit(a), self.max_range_m);
        }
        ConvexPolygon::from_points(&pts)
    }

    /// The part of a convex polygon inside the sector polygon ([`Self::polygon`]), or `None`
    /// when none (or a sliver below the minimum area) is inside. More than
    /// [`super::geometry::MAX_VERTICES`] vertices are outer-approximated.
    pub fn clip(&self, polygon: &ConvexPolygon) -> Result<Option<ConvexPolygon>, GeometryError> {
        let sector = self.polygon()?;
        Ok(polygon.intersection(&sector))
    }
}
