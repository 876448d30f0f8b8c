//! Truth-side hazard check: which terrain features are hazards to the truth vehicle, and when
//! the rover's footprint touches one (`collisions` in `summary.json`).
//!
//! This is the simulator's own judgement, independent of the flight software's hazard grid
//! (`fsw::perception`): it looks at the analytic terrain description, not at images.
//!
//! - **Hazard**: a placed obstacle or a rock of the rock field at least
//!   [`crate::scenario::Scenario::hazard_height_m`] high (default
//!   [`DEFAULT_HAZARD_HEIGHT_M`]).
//! - **Footprint of a hazard**: where it rises more than [`FOOTPRINT_HEIGHT_M`] above the base
//!   terrain: a disc for a rock (the cap `h (1 - (d/r)^2)^2` exceeds `e` inside
//!   `d < r sqrt(1 - sqrt(e/h))`), the rectangle for a block.
//! - **Footprint of the rover**: the rectangle in the body frame `R` spanned by the six wheels
//!   of the truth geometry (this seed's dimensions), grown by the wheel radius fore and aft and
//!   by half the wheel width ([`WHEEL_HALF_WIDTH_M`]) sideways. The body sits inside it.
//! - **Collision**: the two footprints overlap. Each new overlap with a hazard counts one
//!   collision (a rover resting against the same rock counts once until it is clear again).
//!
//! The check runs at the 20 Hz record rate, so a contact shorter than 50 ms at 0.1 m/s (5 mm of
//! travel) could be missed; the closest approach is reported as well.

use crate::terrain::{Obstacle, Terrain};
use crate::vehicle::geometry::TruthGeometry;
use crate::vehicle::placement::BodyPose;

/// Default hazard height, m: twice Rocky 8's 0.10 m wheel radius. The truth vehicle climbs
/// steps of 1.5 wheel radii (SIM-28, `docs/simulator.md`); at two radii a rigid wheel meets
/// the obstacle above its axle height and cannot climb a vertical face by its own traction
/// (the contact normal points backwards), and the belly of the body, whose rocker pivots sit
/// 0.30 m above flat ground at the published dimensions (H04 Table 2), comes within a few
/// centimetres. A simulator assumption, set per scenario with `hazard_height_m`.
pub const DEFAULT_HAZARD_HEIGHT_M: f64 = 0.20;

/// Height above the base terrain where a hazard's footprint begins, m.
pub const FOOTPRINT_HEIGHT_M: f64 = 0.02;

/// Half the width of a Rocky 8 wheel, m (simulator assumption: a 0.12 m wide wheel; no
/// published width in our sources).
pub const WHEEL_HALF_WIDTH_M: f64 = 0.06;

/// Where a hazard is, in the world x-y plane (north, east), m.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Footprint {
    /// A disc: centre and radius.
    Disc { c: [f64; 2], r: f64 },
    /// A convex quadrilateral, counter-clockwise or clockwise.
    Quad([[f64; 2]; 4]),
}

/// One hazard of the terrain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hazard {
    footprint: Footprint,
    /// Height above the base terrain, m.
    pub height_m: f64,
}

impl Hazard {
    /// Centre of the footprint (north, east), m.
    pub fn centre(&self) -> [f64; 2] {
        match self.footprint {
            Footprint::Disc { c, .. } => c,
            Footprint::Quad(q) => [
                0.25 * (q[0][0] + q[1][0] + q[2][0] + q[3][0]),
                0.25 * (q[0][1] + q[1][1] + q[2][1] + q[3][1]),
            ],
        }
    }
}

/// One collision: the first 20 Hz sample at which the rover touched a hazard.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Collision {
    /// Simulated time, s.
    pub t_s: f64,
    /// Index of the hazard in [`HazardMonitor::hazards`].
    pub hazard: usize,
    /// Hazard centre (north, east), m.
    pub at_m: [f64; 2],
}

/// The hazards of a terrain and the running contact check.
#[derive(Debug, Clone)]
pub struct HazardMonitor {
    hazards: Vec<Hazard>,
    touching: Vec<bool>,
    /// Every collision, in time order.
    pub collisions: Vec<Collision>,
    /// Closest approach between the rover footprint and any hazard footprint, m (0 when they
    /// touched; infinity without hazards).
    pub min_distance_m: f64,
    /// Hazard height this monitor uses, m.
    pub hazard_height_m: f64,
}

impl HazardMonitor {
    /// The hazards of `terrain` at least `hazard_height_m` high.
    pub fn new(terrain: &Terrain, hazard_height_m: f64) -> Self {
        let mut hazards = Vec::new();
        let disc = |x: f64, y: f64, r: f64, h: f64| {
            let k = 1.0 - (FOOTPRINT_HEIGHT_M / h).sqrt();
            Hazard {
                footprint: Footprint::Disc {
                    c: [x, y],
                    r: r * k.max(0.0).sqrt(),
                },
                height_m: h,
            }
        };
        for r in terrain.rocks() {
            if r.height_m >= hazard_height_m {
                hazards.push(disc(r.x_m, r.y_m, r.radius_m, r.height_m));
            }
        }
        for o in &terrain.spec().obstacles {
            match *o {
                Obstacle::Rock {
                    x_m,
                    y_m,
                    radius_m,
                    height_m,
                } if height_m >= hazard_height_m => {
                    hazards.push(disc(x_m, y_m, radius_m, height_m));
                }
                Obstacle::Block {
                    x_m,
                    y_m,
                    length_m,
                    width_m,
                    height_m,
                    yaw_deg,
                } if height_m >= hazard_height_m => {
                    let (s, c) = yaw_deg.to_radians().sin_cos();
                    let (a, b) = (0.5 * length_m, 0.5 * width_m);
                    let corner = |u: f64, v: f64| [x_m + u * c - v * s, y_m + u * s + v * c];
                    hazards.push(Hazard {
                        footprint: Footprint::Quad([
                            corner(a, b),
                            corner(-a, b),
                            corner(-a, -b),
                            corner(a, -b),
                        ]),
                        height_m,
                    });
                }
                _ => {}
            }
        }
        Self {
            touching: vec![false; hazards.len()],
            hazards,
            collisions: Vec::new(),
            min_distance_m: f64::INFINITY,
            hazard_height_m,
        }
    }

    /// The hazards, in the order rock field, then placed obstacles.
    pub fn hazards(&self) -> &[Hazard] {
        &self.hazards
    }

    /// Check the rover at `pose` (truth) with `geometry` at simulated time `t_s`.
    pub fn check(&mut self, t_s: f64, pose: &BodyPose, geometry: &TruthGeometry) {
        if self.hazards.is_empty() {
            return;
        }
        let rect = rover_rectangle(pose, geometry);
        for (i, h) in self.hazards.iter().enumerate() {
            let d = match h.footprint {
                Footprint::Disc { c, r } => (polygon_point_distance(&rect, c) - r).max(0.0),
                Footprint::Quad(q) => polygon_distance(&rect, &q),
            };
            self.min_distance_m = self.min_distance_m.min(d);
            let touching = d <= 0.0;
            if touching && !self.touching[i] {
                self.collisions.push(Collision {
                    t_s,
                    hazard: i,
                    at_m: h.centre(),
                });
            }
            self.touching[i] = touching;
        }
    }
}

/// The rover footprint in the world x-y plane: corners counter-clockwise seen from above
/// (x north, y east: the order front-left, rear-left, rear-right, front-right... any convex
/// order works for the distance functions).
fn rover_rectangle(pose: &BodyPose, g: &TruthGeometry) -> [[f64; 2]; 4] {
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for (a, r) in g.axle_m.iter().zip(g.wheel_radius_m) {
        x0 = x0.min(a.x - r);
        x1 = x1.max(a.x + r);
        y0 = y0.min(a.y - WHEEL_HALF_WIDTH_M);
        y1 = y1.max(a.y + WHEEL_HALF_WIDTH_M);
    }
    // The footprint is the horizontal projection of the body-frame rectangle.
    let rot = pose.rot_w_from_r();
    let corner = |x: f64, y: f64| {
        let v = rot * nalgebra::Vector3::new(x, y, 0.0);
        [pose.pos_m[0] + v.x, pose.pos_m[1] + v.y]
    };
    [
        corner(x1, y1),
        corner(x0, y1),
        corner(x0, y0),
        corner(x1, y0),
    ]
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

fn segment_point_distance(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    let ab = sub(b, a);
    let len2 = dot(ab, ab);
    let t = if len2 > 0.0 {
        (dot(sub(p, a), ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let q = [a[0] + t * ab[0], a[1] + t * ab[1]];
    dot(sub(p, q), sub(p, q)).sqrt()
}

/// Whether `p` is inside the convex polygon `poly` (either orientation, boundary included).
fn inside(poly: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut sign = 0.0f64;
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        let e = sub(b, a);
        let cross = e[0] * (p[1] - a[1]) - e[1] * (p[0] - a[0]);
        if cross != 0.0 {
            if sign != 0.0 && cross.signum() != sign {
                return false;
            }
            sign = cross.signum();
        }
    }
    true
}

/// Distance from `p` to the convex polygon `poly` (0 inside).
fn polygon_point_distance(poly: &[[f64; 2]], p: [f64; 2]) -> f64 {
    if inside(poly, p) {
        return 0.0;
    }
    (0..poly.len())
        .map(|i| segment_point_distance(poly[i], poly[(i + 1) % poly.len()], p))
        .fold(f64::INFINITY, f64::min)
}

/// Distance between two convex polygons (0 when they overlap).
fn polygon_distance(a: &[[f64; 2]], b: &[[f64; 2]]) -> f64 {
    let overlap = !separated(a, b) && !separated(b, a);
    if overlap {
        return 0.0;
    }
    let one_way = |p: &[[f64; 2]], q: &[[f64; 2]]| {
        p.iter()
            .map(|&v| polygon_point_distance(q, v))
            .fold(f64::INFINITY, f64::min)
    };
    one_way(a, b).min(one_way(b, a))
}

/// Whether an edge normal of `a` separates `a` and `b` (separating-axis test).
fn separated(a: &[[f64; 2]], b: &[[f64; 2]]) -> bool {
    (0..a.len()).any(|i| {
        let e = sub(a[(i + 1) % a.len()], a[i]);
        let n = [-e[1], e[0]];
        let project = |poly: &[[f64; 2]]| {
            poly.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                    let s = dot(n, v);
                    (lo.min(s), hi.max(s))
                })
        };
        let (a0, a1) = project(a);
        let (b0, b1) = project(b);
        a1 < b0 || b1 < a0
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::{BaseShape, TerrainSpec};

    fn terrain(obstacles: Vec<Obstacle>) -> Terrain {
        Terrain::new(
            TerrainSpec {
                base: BaseShape::Flat,
                roughness_m: 0.0,
                roughness_wavelength_m: 2.0,
                rocks: None,
                obstacles,
            },
            1,
            &[],
        )
    }

    fn pose(x: f64, y: f64, yaw_deg: f64) -> BodyPose {
        BodyPose {
            pos_m: [x, y, 0.0],
            yaw_rad: yaw_deg.to_radians(),
            pitch_rad: 0.0,
            roll_rad: 0.0,
        }
    }

    #[test]
    fn low_obstacles_are_not_hazards() {
        let t = terrain(vec![
            Obstacle::Rock {
                x_m: 2.0,
                y_m: 0.0,
                radius_m: 0.3,
                height_m: 0.1,
            },
            Obstacle::Rock {
                x_m: 4.0,
                y_m: 0.0,
                radius_m: 0.4,
                height_m: 0.3,
            },
        ]);
        let m = HazardMonitor::new(&t, DEFAULT_HAZARD_HEIGHT_M);
        assert_eq!(m.hazards().len(), 1);
        assert_eq!(m.hazards()[0].centre(), [4.0, 0.0]);
    }

    #[test]
    fn rock_contact_counts_once_per_approach() {
        let t = terrain(vec![Obstacle::Rock {
            x_m: 2.0,
            y_m: 0.0,
            radius_m: 0.4,
            height_m: 0.3,
        }]);
        let g = TruthGeometry::rocky8();
        let mut m = HazardMonitor::new(&t, DEFAULT_HAZARD_HEIGHT_M);
        // Footprint radius 0.4 sqrt(1 - sqrt(0.02/0.3)) = 0.322 m; the rover's front is
        // 0.493 m ahead of R.
        let front = 0.393 + 0.10;
        let r_eff = 0.4 * (1.0 - (0.02f64 / 0.3).sqrt()).sqrt();
        m.check(0.0, &pose(2.0 - r_eff - front - 0.05, 0.0, 0.0), &g);
        assert!(m.collisions.is_empty());
        assert!(
            (m.min_distance_m - 0.05).abs() < 1e-3,
            "{}",
            m.min_distance_m
        );
        m.check(0.05, &pose(2.0 - r_eff - front + 0.01, 0.0, 0.0), &g);
        m.check(0.10, &pose(2.0 - r_eff - front + 0.02, 0.0, 0.0), &g);
        assert_eq!(m.collisions.len(), 1);
        // Back off and touch again: a second collision.
        m.check(0.15, &pose(0.0, 0.0, 0.0), &g);
        m.check(0.20, &pose(2.0 - r_eff - front + 0.01, 0.0, 0.0), &g);
        assert_eq!(m.collisions.len(), 2);
    }

    #[test]
    fn passing_beside_a_block_is_clear_and_measured() {
        // A 1 m square block whose near edge is 1 m east of the rover's centre line.
        let t = terrain(vec![Obstacle::Block {
            x_m: 3.0,
            y_m: 1.5,
            length_m: 1.0,
            width_m: 1.0,
            height_m: 0.4,
            yaw_deg: 0.0,
        }]);
        let g = TruthGeometry::rocky8();
        let mut m = HazardMonitor::new(&t, DEFAULT_HAZARD_HEIGHT_M);
        for k in 0..=60 {
            m.check(f64::from(k), &pose(0.1 * f64::from(k), 0.0, 0.0), &g);
        }
        assert!(m.collisions.is_empty());
        let half_width = 0.3111 + WHEEL_HALF_WIDTH_M;
        assert!((m.min_distance_m - (1.0 - half_width)).abs() < 1e-6);
        // Heading east towards it: a collision.
        m.check(61.0, &pose(3.0, 0.6, 90.0), &g);
        assert_eq!(m.collisions.len(), 1);
    }
}
