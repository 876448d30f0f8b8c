//! Wheel-terrain contact of a rigid disc on a height field, in the wheel plane.
//!
//! A wheel is a disc of radius `r` centred on its axle `c` in the plane normal to its spin axis
//! `s` (all in `W`: x north, y east, z down). In that plane, `d` is the downward direction
//! (`+z_W` with its `s` component removed) and `f = s x d` the forward direction; the rim point
//! at contact angle `phi` is `q(phi) = c + r (cos(phi) d + sin(phi) f)` (`phi > 0` ahead of the
//! axle). The penetration of the ground at that point is `g(phi) = h(q_x, q_y) + q_z` (height
//! positive up, `z` down). The contact is the rim point of largest penetration over
//! `phi` in `[-pi/2, pi/2]` (the lower half of the rim), found by a coarse scan every 30 deg and
//! a golden-section search in the best interval (to 0.2 deg on a smooth maximum, to 1e-8 rad at
//! an edge); the wheel's clearance is `-max g`.
//!
//! This is the contact geometry of Tarokh & McDermott (2005) and Iagnemma & Dubowsky (2004):
//! on smooth ground the contact lies where the terrain normal, projected into the wheel
//! plane, passes through the axle; on a step the rim rests on the edge, so the contact angle
//! reaches 90 deg when the wheel presses against a vertical face.

use crate::surface::TerrainSurface;
use nalgebra::Vector3;
use std::f64::consts::FRAC_PI_2;

/// Contact of one wheel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelContact {
    /// Contact point in `W`, m: the ground point under the rim point of the contact (the rim
    /// point itself when the wheel touches).
    pub point_w: Vector3<f64>,
    /// Contact angle in the wheel plane, rad (0 straight below the axle, positive ahead).
    pub angle_rad: f64,
    /// Unit direction from the contact point to the axle in `W` (the contact normal projected
    /// into the wheel plane).
    pub normal_w: Vector3<f64>,
    /// Unit rolling tangent at the contact in `W` (`normal` turned by 90 deg towards `f`): the
    /// direction in which the axle moves when the wheel rolls forward without slip.
    pub tangent_w: Vector3<f64>,
    /// Height of the wheel above the ground (negative: penetration), m.
    pub clearance_m: f64,
}

/// In-plane basis `(d, f)` of a wheel with spin axis `s` in `W`.
fn plane_basis(spin_w: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let down = Vector3::z();
    let d = down - spin_w * spin_w.dot(&down);
    let n = d.norm();
    let d = if n > 1e-9 { d / n } else { down };
    (d, spin_w.cross(&d))
}

fn rim_point(
    c: &Vector3<f64>,
    d: &Vector3<f64>,
    f: &Vector3<f64>,
    r: f64,
    phi: f64,
) -> Vector3<f64> {
    let (s, co) = phi.sin_cos();
    c + (d * co + f * s) * r
}

fn penetration(terrain: &dyn TerrainSurface, q: &Vector3<f64>) -> f64 {
    terrain.height_m(q.x, q.y) + q.z
}

/// Coarse scan step, rad.
const SCAN_STEP: f64 = std::f64::consts::FRAC_PI_6;
/// The golden section stops once its interval is below this, rad: at a smooth maximum the
/// height error is second order (`r dphi^2 / 8`, below 0.1 micrometre); edges are located by
/// bisection instead.
const SMOOTH_INTERVAL_RAD: f64 = 0.003;
/// Upper bound on golden-section iterations.
const GOLDEN_ITERATIONS: usize = 20;

/// Samples of the coarse scan within this of the best also get a refinement, m.
const TIE_M: f64 = 1e-3;
/// On a terrain with edges ([`TerrainSurface::has_edges`]), a ground-height difference larger
/// than this between two neighbouring scan samples is searched for an edge (a step face can hide
/// a narrow penetration between two samples that the golden section, which assumes one maximum,
/// would miss), m.
const EDGE_M: f64 = 0.02;
/// Bisection steps that locate an edge (30 deg / 2^30, about 5e-10 rad).
const EDGE_ITERATIONS: usize = 30;

/// Golden-section search for the largest `g` in `[a, b]`; returns `(phi, g)`.
fn golden(g: &dyn Fn(f64) -> f64, mut a: f64, mut b: f64) -> (f64, f64) {
    let ratio = 0.5 * (5f64.sqrt() - 1.0);
    let mut x1 = b - ratio * (b - a);
    let mut x2 = a + ratio * (b - a);
    let (mut g1, mut g2) = (g(x1), g(x2));
    for _ in 0..GOLDEN_ITERATIONS {
        if b - a < SMOOTH_INTERVAL_RAD {
            break;
        }
        if g1 >= g2 {
            b = x2;
            x2 = x1;
            g2 = g1;
            x1 = b - ratio * (b - a);
            g1 = g(x1);
        } else {
            a = x1;
            x1 = x2;
            g1 = g2;
            x2 = a + ratio * (b - a);
            g2 = g(x2);
        }
    }
    if g1 >= g2 {
        (x1, g1)
    } else {
        (x2, g2)
    }
}

/// Local maximum of `g` near `h` by successive parabolas through three samples (spacing 2 deg,
/// then 0.2 deg); falls back to a golden section when the samples do not bracket a maximum.
fn parabolic(g: &dyn Fn(f64) -> f64, h: f64) -> (f64, f64) {
    let mut centre = h;
    let mut best = (h, f64::NEG_INFINITY);
    for delta in [0.035, 0.0035] {
        let lo = (centre - delta).max(-FRAC_PI_2);
        let hi = (centre + delta).min(FRAC_PI_2);
        let (g0, g1, g2) = (g(lo), g(centre), g(hi));
        for (phi, v) in [(lo, g0), (centre, g1), (hi, g2)] {
            if v > best.1 {
                best = (phi, v);
            }
        }
        if g1 < g0 || g1 < g2 || hi - lo < 1.5 * delta {
            return golden(
                g,
                (h - 0.5 * SCAN_STEP).max(-FRAC_PI_2),
                (h + 0.5 * SCAN_STEP).min(FRAC_PI_2),
            );
        }
        let curvature = g0 - 2.0 * g1 + g2;
        if curvature >= 0.0 {
            break;
        }
        centre = (centre + 0.5 * delta * (g0 - g2) / curvature).clamp(lo, hi);
    }
    let v = g(centre);
    if v > best.1 {
        best = (centre, v);
    }
    best
}

/// The edge between neighbouring `samples` (contact angle, penetration) with the largest
/// penetration on its high side: bisection on the ground height under the rim between two
/// samples whose heights differ by more than [`EDGE_M`]. Returns `(phi, penetration)`.
fn best_edge(
    terrain: &dyn TerrainSurface,
    c_w: &Vector3<f64>,
    d: &Vector3<f64>,
    f: &Vector3<f64>,
    r: f64,
    samples: &[(f64, f64)],
) -> Option<(f64, f64)> {
    let height = |phi: f64| {
        let q = rim_point(c_w, d, f, r, phi);
        terrain.height_m(q.x, q.y)
    };
    let mut best: Option<(f64, f64)> = None;
    for pair in samples.windows(2) {
        let (lo, hi) = (pair[0].0, pair[1].0);
        let (h_lo, h_hi) = (height(lo), height(hi));
        if (h_hi - h_lo).abs() <= EDGE_M {
            continue;
        }
        let mid_height = 0.5 * (h_lo + h_hi);
        let (mut a, mut b) = (lo, hi);
        for _ in 0..EDGE_ITERATIONS {
            let m = 0.5 * (a + b);
            if (height(m) > mid_height) == (h_lo > mid_height) {
                a = m;
            } else {
                b = m;
            }
        }
        let high_side = if h_hi > h_lo { b } else { a };
        let v = penetration(terrain, &rim_point(c_w, d, f, r, high_side));
        if best.is_none_or(|(_, bv)| v > bv) {
            best = Some((high_side, v));
        }
    }
    best
}

/// How far outside its rim [`edge_contact_ahead`] looks for a step face, m.
pub const EDGE_PROBE_M: f64 = 1e-3;

/// A second contact on a step edge or face ahead of the wheel (`direction` +1: at positive
/// contact angles, -1: negative), when the terrain has edges: a wheel standing on the ground and
/// pressed against a step face touches both, and the vertical clearance of [`wheel_contact`]
/// does not see a face that the rim only touches. The rim is probed [`EDGE_PROBE_M`] outside
/// its radius over the forward quarter; the edge where the probe enters the step gives the
/// contact angle, and the clearance is the distance along that radius from the rim to the step
/// (negative: overlap). The placement and the rolling solve follow this contact when it is the
/// closer one (the wheel climbs the face; the ground only holds it from below and lets go as it
/// rises). `None` when no step is within the probe.
pub fn edge_contact_ahead(
    terrain: &dyn TerrainSurface,
    c_w: &Vector3<f64>,
    spin_w: &Vector3<f64>,
    r: f64,
    direction: f64,
) -> Option<WheelContact> {
    if !terrain.has_edges() || direction == 0.0 {
        return None;
    }
    let (d, f) = plane_basis(spin_w);
    let probe = r + EDGE_PROBE_M;
    let step = FRAC_PI_2 / 6.0;
    let samples: [(f64, f64); 7] = std::array::from_fn(|k| {
        let phi = direction.signum() * k as f64 * step;
        (
            phi,
            penetration(terrain, &rim_point(c_w, &d, &f, probe, phi)),
        )
    });
    let (phi, v) = best_edge(terrain, c_w, &d, &f, probe, &samples)?;
    if v <= 0.0 {
        return None;
    }
    // Along the radius at that angle, where the ray enters the step: the edge's distance from
    // the axle, so the clearance is measured along the contact normal (a face shows no vertical
    // clearance at all).
    let (s, co) = phi.sin_cos();
    let radial = d * co + f * s;
    let inside = |rho: f64| penetration(terrain, &(c_w + radial * rho)) > 0.0;
    let (mut a, mut b) = (0.5 * r, probe);
    if inside(a) {
        return None;
    }
    for _ in 0..EDGE_ITERATIONS {
        let m = 0.5 * (a + b);
        if inside(m) {
            b = m;
        } else {
            a = m;
        }
    }
    Some(WheelContact {
        point_w: c_w + radial * b,
        angle_rad: phi,
        normal_w: -radial,
        tangent_w: f * co - d * s,
        clearance_m: b - r,
    })
}

/// Bisection steps of [`face_contact`] along a ray (r over 2^27, below 0.001 um).
const RAY_ITERATIONS: usize = 27;
/// How far [`face_contact`]'s scan looks along the rim's normals, in wheel radii.
const FACE_SCAN_REACH: f64 = 1.5;
/// Golden-section steps of [`face_contact`] over the contact angle.
const FACE_GOLDEN_ITERATIONS: usize = 14;

/// The contact of the rim with a step face or edge ahead (`direction` +1: positive contact
/// angles, -1: negative), measured along the rim's normals: for each contact angle `phi` the
/// distance `b(phi)` from the axle along the radius to where the ray enters the terrain, and
/// the contact is the angle of smallest `b` (a coarse scan every 15 deg and a golden section).
/// So a wheel pressed against a vertical face below its axle touches it at 90 deg with a
/// horizontal normal, and a wheel on the corner touches the corner. Only terrain higher than
/// the ground under the axle by more than [`EDGE_M`] counts (the face of a step, not the
/// ground the wheel stands on), and only within [`EDGE_PROBE_M`] outside the rim. The
/// clearance is `min b - r` (negative: overlap). `None` on terrain without edges or when no
/// face is within reach.
pub fn face_contact(
    terrain: &dyn TerrainSurface,
    c_w: &Vector3<f64>,
    spin_w: &Vector3<f64>,
    r: f64,
    direction: f64,
) -> Option<WheelContact> {
    if !terrain.has_edges() || direction == 0.0 {
        return None;
    }
    let (d, f) = plane_basis(spin_w);
    // The scan looks further than the probe (a corner within the probe can lie between two
    // samples whose rays meet the face only further out); the result must be within the probe.
    let reach = FACE_SCAN_REACH * r;
    let base = terrain.height_m(c_w.x, c_w.y);
    let inside = |q: &Vector3<f64>| penetration(terrain, q) > 0.0;
    let entry = |phi: f64| -> f64 {
        let (s, co) = phi.sin_cos();
        let radial = d * co + f * s;
        let (mut a, mut b) = (0.5 * r, reach);
        if inside(&(c_w + radial * a)) || !inside(&(c_w + radial * b)) {
            return f64::INFINITY;
        }
        for _ in 0..RAY_ITERATIONS {
            let m = 0.5 * (a + b);
            if inside(&(c_w + radial * m)) {
                b = m;
            } else {
                a = m;
            }
        }
        let q = c_w + radial * b;
        if terrain.height_m(q.x, q.y) > base + EDGE_M {
            b
        } else {
            f64::INFINITY
        }
    };
    let sign = direction.signum();
    let step = FRAC_PI_2 / 6.0;
    let (mut best_phi, mut best) = (0.0, f64::INFINITY);
    for k in 0..7 {
        let phi = sign * k as f64 * step;
        let b = entry(phi);
        if b < best {
            (best_phi, best) = (phi, b);
        }
    }
    if !best.is_finite() {
        return None;
    }
    // Golden section for the smallest b around the best sample, within the quarter.
    let (lo, hi) = if sign > 0.0 {
        (0.0, FRAC_PI_2)
    } else {
        (-FRAC_PI_2, 0.0)
    };
    let (mut a, mut b) = ((best_phi - step).max(lo), (best_phi + step).min(hi));
    let ratio = 0.5 * (5f64.sqrt() - 1.0);
    let mut x1 = b - ratio * (b - a);
    let mut x2 = a + ratio * (b - a);
    let (mut e1, mut e2) = (entry(x1), entry(x2));
    for _ in 0..FACE_GOLDEN_ITERATIONS {
        if e1 <= e2 {
            b = x2;
            (x2, e2) = (x1, e1);
            x1 = b - ratio * (b - a);
            e1 = entry(x1);
        } else {
            a = x1;
            (x1, e1) = (x2, e2);
            x2 = a + ratio * (b - a);
            e2 = entry(x2);
        }
    }
    for (phi, e) in [(x1, e1), (x2, e2)] {
        if e < best {
            (best_phi, best) = (phi, e);
        }
    }
    if best > r + EDGE_PROBE_M {
        return None;
    }
    let (s, co) = best_phi.sin_cos();
    let radial = d * co + f * s;
    Some(WheelContact {
        point_w: c_w + radial * best,
        angle_rad: best_phi,
        normal_w: -radial,
        tangent_w: f * co - d * s,
        clearance_m: best - r,
    })
}

/// Samples of [`ground_contact_below`]'s scan.
const BELOW_SAMPLES: usize = 10;

/// The rim's contact with the ground over contact angles `[-pi/2, phi_max]` only: the lower
/// ground under a wheel whose contact of largest penetration ([`wheel_contact`]) is a step face
/// or edge at a larger angle (a wheel standing on the ground and pressed against a face touches
/// both). A scan of [`BELOW_SAMPLES`] angles and a golden section around the best; the contact
/// is measured like [`wheel_contact`]'s (vertical clearance under the rim point).
pub fn ground_contact_below(
    terrain: &dyn TerrainSurface,
    c_w: &Vector3<f64>,
    spin_w: &Vector3<f64>,
    r: f64,
    phi_max: f64,
) -> WheelContact {
    let (d, f) = plane_basis(spin_w);
    let hi = phi_max.clamp(-FRAC_PI_2, FRAC_PI_2);
    let step = (hi + FRAC_PI_2) / (BELOW_SAMPLES - 1) as f64;
    let g = |phi: f64| penetration(terrain, &rim_point(c_w, &d, &f, r, phi));
    let (mut best_phi, mut best) = (-FRAC_PI_2, f64::NEG_INFINITY);
    for k in 0..BELOW_SAMPLES {
        let phi = -FRAC_PI_2 + k as f64 * step;
        let v = g(phi);
        if v > best {
            (best_phi, best) = (phi, v);
        }
    }
    let (phi, v) = golden(
        &g,
        (best_phi - step).max(-FRAC_PI_2),
        (best_phi + step).min(hi),
    );
    if v > best {
        (best_phi, best) = (phi, v);
    }
    contact_at(c_w, &d, &f, r, best_phi, best)
}

/// Contact of a wheel of radius `r` centred at `c_w` with spin axis `spin_w` (unit, `W`).
/// `hint` is the contact angle of the previous step, rad: its neighbourhood is searched too,
/// so a contact on an edge is followed from step to step.
pub fn wheel_contact(
    terrain: &dyn TerrainSurface,
    c_w: &Vector3<f64>,
    spin_w: &Vector3<f64>,
    r: f64,
    hint: Option<f64>,
) -> WheelContact {
    let (d, f) = plane_basis(spin_w);
    let g = |phi: f64| penetration(terrain, &rim_point(c_w, &d, &f, r, phi));
    // Coarse scan of the lower half of the rim.
    let mut samples = [(0.0, 0.0); 7];
    let (mut best_phi, mut best) = (0.0, f64::NEG_INFINITY);
    for (k, sample) in samples.iter_mut().enumerate() {
        let phi = (k as f64 - 3.0) * SCAN_STEP;
        let v = g(phi);
        *sample = (phi, v);
        if v > best {
            best = v;
            best_phi = phi;
        }
    }
    let coarse_best = best;
    // Edges: bisect on the ground height between neighbouring samples that differ a lot, and
    // evaluate the rim just on the high side.
    let mut edge_best = (best_phi, best);
    if terrain.has_edges() {
        if let Some(e) = best_edge(terrain, c_w, &d, &f, r, &samples) {
            if e.1 > edge_best.1 {
                edge_best = e;
            }
        }
    }
    let mut refine = |centre: f64, half: f64| {
        let (phi, v) = golden(
            &g,
            (centre - half).max(-FRAC_PI_2),
            (centre + half).min(FRAC_PI_2),
        );
        if v > best {
            best = v;
            best_phi = phi;
        }
    };
    let hint = hint
        .filter(|h| h.is_finite())
        .map(|h| h.clamp(-FRAC_PI_2, FRAC_PI_2));
    for (phi, v) in samples {
        // A sample next to the previous contact is covered by the narrower search below.
        let near_hint = hint.is_some_and(|h| (h - phi).abs() < 0.5 * SCAN_STEP);
        if v >= coarse_best - TIE_M && !near_hint {
            refine(phi, SCAN_STEP);
        }
    }
    if let Some(h) = hint {
        // Around the previous contact: two parabolic steps, then a golden section only when
        // the maximum is not bracketed near the hint.
        let (phi, v) = parabolic(&g, h);
        if v > best {
            best = v;
            best_phi = phi;
        }
    }
    if edge_best.1 > best {
        (best_phi, best) = edge_best;
    }
    contact_at(c_w, &d, &f, r, best_phi, best)
}

fn contact_at(
    c_w: &Vector3<f64>,
    d: &Vector3<f64>,
    f: &Vector3<f64>,
    r: f64,
    phi: f64,
    penetration_m: f64,
) -> WheelContact {
    let (s, co) = phi.sin_cos();
    let radial = d * co + f * s;
    WheelContact {
        // On the ground under the rim point (the rim point itself when touching).
        point_w: c_w + radial * r - Vector3::z() * penetration_m,
        angle_rad: phi,
        normal_w: -radial,
        // Rolling forward moves the axle perpendicular to the radius, towards f at phi = 0.
        tangent_w: f * co - d * s,
        clearance_m: -penetration_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::{BaseShape, Terrain};
    use crate::vehicle::tests::terrain;

    /// Roll one wheel (spin axis east, moving north) without slip: each step moves the axle by
    /// `r dtheta` along the contact tangent, then lowers or raises it onto the ground (the
    /// holonomic projection). Returns `(total wheel rotation, horizontal advance)` from `x0`
    /// until the axle reaches `x1`.
    fn roll(t: &Terrain, x0: f64, x1: f64, r: f64) -> (f64, f64, f64) {
        let spin = Vector3::y();
        let mut c = Vector3::new(x0, 0.0, -(t.height_m(x0, 0.0) + r));
        let dtheta = 1e-4;
        let (mut theta, mut max_angle) = (0.0, 0.0f64);
        let mut hint = None;
        for _ in 0..200_000 {
            if c.x >= x1 {
                break;
            }
            let k = wheel_contact(t, &c, &spin, r, hint);
            hint = Some(k.angle_rad);
            max_angle = max_angle.max(k.angle_rad);
            c += k.tangent_w * (r * dtheta);
            theta += dtheta;
            // Project: settle the wheel onto the ground (vertical only).
            for _ in 0..3 {
                let k = wheel_contact(t, &c, &spin, r, hint);
                c.z += k.clearance_m;
            }
        }
        (theta, c.x - x0, max_angle)
    }

    /// SIM-14: a wheel of radius `r` meeting a vertical step of height `r` touches its edge at
    /// a contact angle of 90 deg and rolls over it through pi/2 rad (rim travel 1.57 r) while
    /// its axle advances `r` horizontally (within 3 %); on flat ground the rim travel equals
    /// the distance (within 0.1 %).
    #[test]
    fn sim_14_wheel_climbs_a_step_of_one_radius() {
        let r = 0.1;
        let step = terrain(BaseShape::Step {
            x_m: 1.0,
            height_m: r,
            right_only: false,
        });
        // From touching the face (axle r before the edge) to standing on top (axle over the edge).
        let (theta, advance, max_angle) = roll(&step, 1.0 - r - 1e-6, 1.0, r);
        assert!(
            (theta - FRAC_PI_2).abs() < 0.03 * FRAC_PI_2,
            "rotation {theta}"
        );
        assert!((advance - r).abs() < 0.03 * r, "advance {advance}");
        assert!(max_angle > 1.5, "contact angle {max_angle}");
        let flat = terrain(BaseShape::Flat);
        let (theta, advance, _) = roll(&flat, 0.0, 1.0, r);
        assert!(
            ((theta * r) - advance).abs() < 1e-3 * advance,
            "{theta} {advance}"
        );
    }

    /// SIM-14: on a plane the contact lies where the plane's normal through the axle meets it
    /// (contact angle = the slope along the wheel plane), and the clearance is measured along
    /// the vertical.
    #[test]
    fn sim_14_contact_on_a_slope() {
        let t = terrain(BaseShape::Plane {
            slope_deg: 20.0,
            downhill_azimuth_deg: 180.0,
        });
        let r = 0.1;
        // Rising towards north at 20 deg: the contact is ahead of the axle by 20 deg.
        let h = t.height_m(0.0, 0.0);
        let lift = r / 20f64.to_radians().cos();
        let c = Vector3::new(0.0, 0.0, -(h + lift + 0.01));
        let k = wheel_contact(&t, &c, &Vector3::y(), r, None);
        assert!(
            (k.angle_rad - 20f64.to_radians()).abs() < 2e-3,
            "{}",
            k.angle_rad
        );
        assert!((k.clearance_m - 0.01).abs() < 1e-4, "{}", k.clearance_m);
        assert!(k.tangent_w.z < 0.0, "rolling forward climbs");
    }
}
