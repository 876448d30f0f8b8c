//! Planner unit and property tests (PLN-1 .. PLN-6, `docs/planning.md`). The closed-loop
//! worlds (PLN-7 .. PLN-9) are in `tests_world.rs`.

use super::geometry::*;
use super::ltg::{segment_clear, tangent_at_vertex, CandidateQuery, LocalTangentGraph, MAX_NODES};
use super::memory::{InsertOutcome, ObstacleMemory, MEMORY_CAPACITY};
use super::planner::*;
use super::wedge::Wedge;
use crate::guidance::Point2;
use core::f64::consts::PI;
use proptest::prelude::*;
use std::vec::Vec;

/// Regular `n`-gon of circumradius `r` about `c`, first vertex at yaw `phase`.
pub(super) fn regular(c: Point2, r: f64, n: usize, phase: f64) -> ConvexPolygon {
    let pts: Vec<Point2> = (0..n)
        .map(|k| {
            let a = phase + 2.0 * PI * k as f64 / n as f64;
            [c[0] + r * a.cos(), c[1] + r * a.sin()]
        })
        .collect();
    ConvexPolygon::from_points(&pts).unwrap()
}

/// Axis-aligned rectangle.
pub(super) fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> ConvexPolygon {
    ConvexPolygon::from_points(&[[x0, y0], [x1, y0], [x1, y1], [x0, y1]]).unwrap()
}

/// Independent strict point-in-convex-polygon test (cross products against each edge, no
/// normals): inside when left of every edge by more than `tol` metres.
pub(super) fn strictly_inside(poly: &ConvexPolygon, p: Point2, tol: f64) -> bool {
    let v = poly.vertices();
    (0..v.len()).all(|i| {
        let a = v[i];
        let b = v[(i + 1) % v.len()];
        let e = [b[0] - a[0], b[1] - a[1]];
        let l = (e[0] * e[0] + e[1] * e[1]).sqrt();
        (e[0] * (p[1] - a[1]) - e[1] * (p[0] - a[0])) / l > tol
    })
}

/// Independent distance from a point to a convex polygon (0 inside), m.
pub(super) fn distance_to(poly: &ConvexPolygon, p: Point2) -> f64 {
    if strictly_inside(poly, p, 0.0) {
        return 0.0;
    }
    let v = poly.vertices();
    (0..v.len())
        .map(|i| point_segment_distance(p, v[i], v[(i + 1) % v.len()]))
        .fold(f64::INFINITY, f64::min)
}

// ---------------------------------------------------------------------------------------------
// PLN-1: polygons are validated and normalised.

/// PLN-1: any orientation becomes positive; collinear and repeated points are dropped;
/// non-finite, out-of-range, too many and degenerate inputs are refused with an error value.
#[test]
fn pln_1_polygon_construction_and_refusals() {
    // Clockwise square with a collinear midpoint and a repeated vertex.
    let p = ConvexPolygon::from_points(&[
        [0.0, 0.0],
        [0.0, 1.0],
        [0.0, 2.0],
        [2.0, 2.0],
        [2.0, 2.0],
        [2.0, 0.0],
    ])
    .unwrap();
    assert_eq!(p.len(), 4);
    assert!((p.area_m2() - 4.0).abs() < 1e-12);
    // Interior points are left of every edge (positive orientation).
    assert!(strictly_inside(&p, [1.0, 1.0], 0.5));
    assert_eq!(
        ConvexPolygon::from_points(&[[0.0, 0.0], [f64::NAN, 1.0], [1.0, 0.0]]),
        Err(GeometryError::NonFinite)
    );
    assert_eq!(
        ConvexPolygon::from_points(&[[0.0, 0.0], [2e6, 1.0], [1.0, 0.0]]),
        Err(GeometryError::OutOfRange)
    );
    assert_eq!(
        ConvexPolygon::from_points(&[[0.0, 0.0]; MAX_INPUT_POINTS + 1]),
        Err(GeometryError::TooManyPoints)
    );
    // Collinear, repeated, too few, tiny.
    for bad in [
        &[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]][..],
        &[[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]][..],
        &[[0.0, 0.0], [1.0, 0.0]][..],
        &[[0.0, 0.0], [1e-4, 0.0], [0.0, 1e-4]][..],
        &[][..],
    ] {
        assert_eq!(
            ConvexPolygon::from_points(bad),
            Err(GeometryError::Degenerate),
            "{bad:?}"
        );
    }
}

/// PLN-1: a 32-gon is reduced to `MAX_VERTICES` by an outer approximation: every input point
/// stays inside, and the area grows by little.
#[test]
fn pln_1_outer_reduction_contains_input() {
    let pts: Vec<Point2> = (0..32)
        .map(|k| {
            let a = 2.0 * PI * k as f64 / 32.0;
            [3.0 + a.cos(), -2.0 + 0.5 * a.sin()]
        })
        .collect();
    let p = ConvexPolygon::from_points(&pts).unwrap();
    assert_eq!(p.len(), MAX_VERTICES);
    for q in &pts {
        assert_ne!(p.locate(*q), PointLocation::Outside, "{q:?}");
    }
    let ellipse = PI * 1.0 * 0.5;
    assert!(p.area_m2() > 0.97 * ellipse && p.area_m2() < 1.06 * ellipse);
}

/// PLN-1: miter inflation keeps every point within the offset inside and moves each edge out
/// by exactly the offset.
#[test]
fn pln_1_inflation() {
    let p = regular([1.0, 2.0], 1.0, 7, 0.3);
    let q = p.inflate(0.2).unwrap();
    assert_eq!(q.len(), p.len());
    for i in 0..p.len() {
        // Each inflated edge is 0.2 m outside the original edge line.
        let d = dot(p.normal(i), sub(q.vertex(i), p.vertex(i)));
        assert!((d - 0.2).abs() < 1e-12);
    }
    for k in 0..360 {
        let a = 2.0 * PI * k as f64 / 360.0;
        let boundary = p.closest_boundary_point([1.0 + 5.0 * a.cos(), 2.0 + 5.0 * a.sin()]);
        let out = add_scaled(boundary, unit(a), 0.2 - 1e-9);
        assert_ne!(q.locate(out), PointLocation::Outside);
    }
    assert_eq!(p.inflate(-0.1), Err(GeometryError::OutOfRange));
    assert_eq!(p.inflate(f64::NAN), Err(GeometryError::NonFinite));
}

// ---------------------------------------------------------------------------------------------
// PLN-2: segment and point tests.

/// PLN-2: segment / polygon interior test on crossing, touching, grazing and contained cases;
/// point location with its tolerance.
#[test]
fn pln_2_segment_and_point_cases() {
    let sq = rect(0.0, 0.0, 2.0, 2.0);
    assert!(sq.segment_hits_interior([-1.0, 1.0], [3.0, 1.0])); // through
    assert!(sq.segment_hits_interior([0.5, 0.5], [1.5, 1.5])); // inside
    assert!(sq.segment_hits_interior([-1.0, 1.0], [0.5, 1.0])); // ends inside
    assert!(!sq.segment_hits_interior([-1.0, 0.0], [3.0, 0.0])); // along an edge
    assert!(!sq.segment_hits_interior([-1.0, -1.0], [3.0, 3.0 - 8.0])); // outside
    assert!(sq.segment_hits_interior([-1.0, 3.0], [3.0, -1.0])); // the diagonal
    assert!(!sq.segment_hits_interior([1.0, 3.0], [3.0, 1.0])); // touches vertex (2,2) only
    assert!(!sq.segment_hits_interior([-1.0, 1.0], [1.0, 3.0])); // through vertex (0,2) only
    assert!(!sq.segment_hits_interior([0.0, 0.0], [2.0, 0.0])); // the edge itself
    assert!(sq.segment_hits_interior([1.0, 1.0], [1.0, 1.0])); // point inside
    assert!(!sq.segment_hits_interior([0.0, 1.0], [0.0, 1.0])); // point on boundary
    assert!(!sq.segment_hits_interior([-1.0, 1.0], [-1.0, 1.0])); // point outside
                                                                  // 1e-7 m deep: below the tolerance; 1e-5 m: a hit.
    assert!(!sq.segment_hits_interior([-1.0, 1e-7], [3.0, 1e-7]));
    assert!(sq.segment_hits_interior([-1.0, 1e-5], [3.0, 1e-5]));
    assert_eq!(sq.locate([1.0, 1.0]), PointLocation::Inside);
    assert_eq!(sq.locate([2.0, 1.0]), PointLocation::Boundary);
    assert_eq!(sq.locate([2.0 + 1e-7, 1.0]), PointLocation::Boundary);
    assert_eq!(sq.locate([2.1, 1.0]), PointLocation::Outside);
    assert!((sq.distance([3.0, 3.0]) - 2f64.sqrt()).abs() < 1e-12);
    assert_eq!(sq.distance([1.0, 1.0]), 0.0);
    assert_eq!(sq.closest_boundary_point([1.0, 0.2]), [1.0, 0.0]);
    // Overlap with a gap.
    let other = rect(2.05, 0.0, 3.0, 1.0);
    assert!(!sq.overlaps(&other, 0.01));
    assert!(sq.overlaps(&other, 0.1));
    assert!((sq.intersection_area_m2(&rect(1.0, 1.0, 3.0, 3.0)) - 1.0).abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------------
// PLN-3: tangents.

/// PLN-3: from outside, the tangent vertices are the two whose supporting line leaves the
/// whole polygon on one side (brute force over every vertex); on the boundary the interval is
/// the interior cone; inside there is none.
#[test]
fn pln_3_tangent_cases() {
    let hex = regular([0.0, 0.0], 1.0, 6, 0.1);
    let support = |p: Point2, v: usize| {
        let d = sub(hex.vertex(v), p);
        let s: Vec<f64> = hex
            .vertices()
            .iter()
            .map(|w| cross(d, sub(*w, p)))
            .collect();
        s.iter().all(|c| *c >= -1e-12) || s.iter().all(|c| *c <= 1e-12)
    };
    for k in 0..72 {
        let a = 2.0 * PI * k as f64 / 72.0;
        let p = [3.0 * a.cos(), 3.0 * a.sin()];
        let iv = hex.angular_interval(p).unwrap();
        assert!(
            support(p, iv.lo_vertex) && support(p, iv.hi_vertex),
            "k {k}"
        );
        assert!(iv.hi_rad > iv.lo_rad && iv.hi_rad - iv.lo_rad < PI);
        assert!(tangent_at_vertex(&hex, iv.lo_vertex, p));
        assert!(tangent_at_vertex(&hex, iv.hi_vertex, p));
        // Every other vertex is strictly inside the interval.
        for v in 0..6 {
            if v != iv.lo_vertex && v != iv.hi_vertex {
                let y = wrap(yaw(p, hex.vertex(v)) - iv.lo_rad);
                assert!(y > 0.0 && y < iv.hi_rad - iv.lo_rad);
                assert!(!support(p, v));
            }
        }
        // The hi tangent is to the observer's right: larger yaw.
        assert!(wrap(yaw(p, hex.vertex(iv.hi_vertex)) - yaw(p, hex.vertex(iv.lo_vertex))) > 0.0);
    }
    // On an edge: width pi, tangents are the edge's ends.
    let sq = rect(0.0, 0.0, 2.0, 2.0);
    let iv = sq.angular_interval([1.0, 0.0]).unwrap();
    assert!((iv.hi_rad - iv.lo_rad - PI).abs() < 1e-9);
    let ends = [sq.vertex(iv.lo_vertex), sq.vertex(iv.hi_vertex)];
    assert!(ends.contains(&[0.0, 0.0]) && ends.contains(&[2.0, 0.0]));
    // At a vertex: the interior angle (pi/2), tangents are the neighbours.
    let iv = sq.angular_interval([0.0, 0.0]).unwrap();
    assert!((iv.hi_rad - iv.lo_rad - PI / 2.0).abs() < 1e-9);
    // Collinear edge seen end-on: the farther vertex on the tangent ray.
    let iv = sq.angular_interval([-1.0, 0.0]).unwrap();
    assert_eq!(sq.vertex(iv.lo_vertex), [2.0, 0.0]);
    // Inside: no tangent.
    assert!(sq.angular_interval([1.0, 1.0]).is_none());
}

fn wrap(a: f64) -> f64 {
    crate::guidance::wrap_pi(a)
}

// ---------------------------------------------------------------------------------------------
// PLN-4: the visible wedge.

/// PLN-4: wedge validation, containment, and clipping of polygons inside, across and outside.
#[test]
fn pln_4_wedge_cases() {
    let w = Wedge {
        apex: [0.0, 0.0],
        heading_rad: 0.0,
        half_angle_rad: 40f64.to_radians(),
        min_range_m: 0.0,
        max_range_m: 5.0,
    };
    assert_eq!(w.validate(), Ok(()));
    let bad = [
        Wedge {
            heading_rad: f64::NAN,
            ..w
        },
        Wedge {
            half_angle_rad: 0.0,
            ..w
        },
        Wedge {
            half_angle_rad: 1.6,
            ..w
        },
        Wedge {
            max_range_m: 0.0,
            ..w
        },
        Wedge {
            min_range_m: -1.0,
            ..w
        },
        Wedge {
            apex: [f64::INFINITY, 0.0],
            ..w
        },
    ];
    assert_eq!(bad[0].validate(), Err(GeometryError::NonFinite));
    assert_eq!(bad[5].validate(), Err(GeometryError::NonFinite));
    for b in &bad[1..5] {
        assert_eq!(b.validate(), Err(GeometryError::OutOfRange));
        assert!(b.polygon().is_err());
    }
    assert!(w.contains([4.9, 0.0]) && !w.contains([5.1, 0.0]));
    assert!(w.contains([1.0, 0.8]) && !w.contains([1.0, 0.9]));
    assert!(!w.contains([-1.0, 0.0]));
    let near = Wedge {
        min_range_m: 0.5,
        ..w
    };
    assert!(!near.contains([0.3, 0.0]) && near.contains([0.6, 0.0]));
    // Inside: unchanged.
    let inside = regular([3.0, 0.0], 0.5, 8, 0.0);
    let c = w.clip(&inside).unwrap().unwrap();
    assert!((c.area_m2() - inside.area_m2()).abs() < 1e-9);
    // Behind the apex or beyond the range: nothing.
    assert!(w
        .clip(&regular([-2.0, 0.0], 0.5, 8, 0.0))
        .unwrap()
        .is_none());
    assert!(w.clip(&regular([7.0, 0.0], 0.5, 8, 0.0)).unwrap().is_none());
    // Across the left ray (yaw -40 deg): the clipped part is inside the wedge and matches a
    // Monte Carlo estimate of the visible area.
    let across = rect(2.0, -3.0, 3.0, 0.0);
    let c = w.clip(&across).unwrap().unwrap();
    for v in c.vertices() {
        assert!(w.contains(*v) || dist(*v, [0.0, 0.0]) <= 5.0 + 1e-9);
        assert!(yaw([0.0, 0.0], *v) >= -40f64.to_radians() - 1e-9);
    }
    let mut hits = 0;
    let n = 200;
    for i in 0..n {
        for j in 0..n {
            let p = [
                2.0 + (i as f64 + 0.5) / n as f64,
                -3.0 + 3.0 * (j as f64 + 0.5) / n as f64,
            ];
            if w.contains(p) {
                hits += 1;
            }
        }
    }
    let visible = 3.0 * hits as f64 / (n * n) as f64;
    assert!(
        (c.area_m2() - visible).abs() < 0.01,
        "{} vs {visible}",
        c.area_m2()
    );
}

// ---------------------------------------------------------------------------------------------
// PLN-5: the local tangent graph against a brute-force visibility graph.

/// Shortest path on the complete visibility graph (every free pair of nodes), Dijkstra O(n^2).
fn brute_force_shortest(owned: &[ConvexPolygon], start: Point2, goal: Point2) -> f64 {
    let polys: Vec<&ConvexPolygon> = owned.iter().collect();
    let mut nodes = vec![start, goal];
    for (k, p) in polys.iter().enumerate() {
        for v in p.vertices() {
            if !polys
                .iter()
                .enumerate()
                .any(|(j, q)| j != k && q.locate(*v) == PointLocation::Inside)
            {
                nodes.push(*v);
            }
        }
    }
    let n = nodes.len();
    let mut d = vec![f64::INFINITY; n];
    let mut done = vec![false; n];
    d[0] = 0.0;
    for _ in 0..n {
        let Some(u) = (0..n)
            .filter(|i| !done[*i] && d[*i].is_finite())
            .min_by(|a, b| d[*a].total_cmp(&d[*b]))
        else {
            break;
        };
        done[u] = true;
        for v in 0..n {
            if !done[v] && segment_clear(owned, nodes[u], nodes[v]) {
                d[v] = d[v].min(d[u] + dist(nodes[u], nodes[v]));
            }
        }
    }
    d[1]
}

fn random_polygon(rng: &mut impl rand::Rng) -> ConvexPolygon {
    loop {
        let c = [rng.random_range(1.0..9.0), rng.random_range(-4.0..4.0)];
        let r = rng.random_range(0.3..1.5);
        let n = rng.random_range(3..9);
        let pts: Vec<Point2> = (0..n)
            .map(|_| {
                let a = rng.random_range(0.0..2.0 * PI);
                let s = rng.random_range(0.3..1.0);
                [c[0] + r * s * a.cos(), c[1] + r * s * a.sin()]
            })
            .collect();
        if let Ok(p) = ConvexPolygon::from_points(&pts) {
            if p.area_m2() > 0.01 {
                return p;
            }
        }
    }
}

fn random_free_point(rng: &mut impl rand::Rng, polys: &[&ConvexPolygon], x: (f64, f64)) -> Point2 {
    loop {
        let p = [rng.random_range(x.0..x.1), rng.random_range(-4.0..4.0)];
        if polys.iter().all(|q| q.locate(p) == PointLocation::Outside) {
            return p;
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, .. ProptestConfig::default() })]

    /// PLN-5: with everything visible, the LTG (tangent edges only) gives the same shortest
    /// path length to the goal as the complete visibility graph; every LTG edge of the path is
    /// collision-free (independent sampling) and tangent at its polygon vertices (every vertex
    /// of the polygon on one side of the line, checked by brute force).
    #[test]
    fn pln_5_ltg_matches_visibility_graph(seed in any::<u64>(), count in 1usize..7) {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let owned: Vec<ConvexPolygon> = (0..count).map(|_| random_polygon(&mut rng)).collect();
        let polys: Vec<&ConvexPolygon> = owned.iter().collect();
        let start = random_free_point(&mut rng, &polys, (-1.0, 1.0));
        let goal = random_free_point(&mut rng, &polys, (9.0, 11.0));
        let mut ltg = LocalTangentGraph::new();
        ltg.solve(start, &polys, &owned);
        prop_assert!(ltg.len() <= MAX_NODES);
        let summary = ltg.candidates(&owned, &CandidateQuery {
            center: start,
            radius_m: 1e4,
            goal,
            threshold_m: f64::INFINITY,
            epsilon_m: 0.0,
            sticky: None,
        });
        let brute = brute_force_shortest(&owned, start, goal);
        let ltg_len = summary.best.map_or(f64::INFINITY, |b| b.cost_m);
        if brute.is_finite() {
            prop_assert!((ltg_len - brute).abs() <= 1e-9 * (1.0 + brute), "ltg {} brute {}", ltg_len, brute);
        } else {
            prop_assert!(ltg_len.is_infinite());
        }
        if let Some(best) = summary.best {
            let mut path = [[0.0; 2]; 64];
            let n = ltg.path_to(best.node, &mut path);
            prop_assert!(n >= 1);
            let mut pts: Vec<Point2> = path[..n].to_vec();
            pts.push(best.exit);
            prop_assert_eq!(best.exit, goal);
            let mut length = 0.0;
            for w in pts.windows(2) {
                length += dist(w[0], w[1]);
                for s in 0..=200 {
                    let t = s as f64 / 200.0;
                    let q = add_scaled(w[0], sub(w[1], w[0]), t);
                    for poly in &polys {
                        prop_assert!(!strictly_inside(poly, q, 1e-6), "edge {:?} enters a polygon", w);
                    }
                }
            }
            prop_assert!((length - ltg_len).abs() < 1e-9 * (1.0 + length));
            // Bends are at polygon vertices and both legs support the polygon there.
            for k in 1..pts.len() - 1 {
                let v = pts[k];
                let owner = polys.iter().find(|p| p.vertices().contains(&v));
                prop_assert!(owner.is_some(), "bend not at a vertex");
                let poly = owner.unwrap();
                for other in [pts[k - 1], pts[k + 1]] {
                    let d = sub(other, v);
                    let s: Vec<f64> = poly.vertices().iter().map(|w| cross(d, sub(*w, v))).collect();
                    let scale = 1e-9 * (1.0 + dot(d, d));
                    prop_assert!(s.iter().all(|c| *c >= -scale) || s.iter().all(|c| *c <= scale));
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// PLN-6: memory, defined responses of the step function.

/// PLN-6: the memory merges repeated views of one obstacle, keeps distinct ones apart, and on
/// overflow evicts the farthest polygon or drops a farther new one, counting both.
#[test]
fn pln_6_memory_merge_and_overflow() {
    let mut m = ObstacleMemory::new(0.05);
    let a = regular([5.0, 0.0], 1.0, 8, 0.0);
    assert_eq!(m.insert(&a, [0.0, 0.0], None), InsertOutcome::Added(0));
    // A partial view (clipped) of the same rock merges into it.
    let part = a.intersection(&rect(4.0, -2.0, 5.2, 2.0)).unwrap();
    assert_eq!(m.insert(&part, [0.0, 0.0], None), InsertOutcome::Merged(0));
    assert_eq!(m.len(), 1);
    // A shifted view overlapping by most of its area: merged into the hull.
    let shifted = regular([5.3, 0.0], 1.0, 8, 0.0);
    assert_eq!(
        m.insert(&shifted, [0.0, 0.0], None),
        InsertOutcome::Merged(0)
    );
    assert!(m.grown()[0].area_m2() > a.area_m2());
    // A touching neighbour is separate but in the same component.
    let b = rect(6.2, -0.5, 8.0, 0.5);
    assert_eq!(m.insert(&b, [0.0, 0.0], None), InsertOutcome::Added(1));
    m.refresh_components();
    assert_eq!(m.component(0), m.component(1));
    let far = regular([20.0, 0.0], 0.5, 6, 0.0);
    assert_eq!(m.insert(&far, [0.0, 0.0], None), InsertOutcome::Added(2));
    m.refresh_components();
    assert_ne!(m.component(2), m.component(0));
    // Fill up with distinct rocks along y.
    for k in 3..MEMORY_CAPACITY {
        let r = regular([-10.0, 3.0 * k as f64], 0.5, 6, 0.0);
        assert_eq!(m.insert(&r, [0.0, 0.0], None), InsertOutcome::Added(k));
    }
    // Full: a near new rock evicts the farthest ([-10, 93]).
    let near = regular([0.0, -3.0], 0.5, 6, 0.0);
    let evicted = m.insert(&near, [0.0, 0.0], None);
    assert_eq!(evicted, InsertOutcome::Evicted(MEMORY_CAPACITY - 1));
    // A new rock farther than all: dropped.
    let farther = regular([500.0, 0.0], 0.5, 6, 0.0);
    assert_eq!(m.insert(&farther, [0.0, 0.0], None), InsertOutcome::Dropped);
    let s = m.stats();
    assert_eq!((s.evicted, s.dropped, s.merged), (1, 1, 2));
    assert_eq!(m.len(), MEMORY_CAPACITY);
}

fn wedge_at(p: Point2, heading: f64) -> Wedge {
    Wedge {
        apex: p,
        heading_rad: heading,
        half_angle_rad: 40f64.to_radians(),
        min_range_m: 0.0,
        max_range_m: 5.0,
    }
}

/// PLN-6: bad input is refused without changing state; the goal inside an obstacle is
/// unreachable; a rover inside the clearance band escapes; a goal behind asks for a gaze;
/// verdicts latch until a new goal.
#[test]
fn pln_6_step_defined_responses() {
    let mut p = Planner::new(PlannerConfig::default()).unwrap();
    let w = wedge_at([0.0, 0.0], 0.0);
    assert_eq!(p.plan([0.0, 0.0], 0.0, &w, &[]), Err(PlanError::NoGoal));
    assert_eq!(p.set_goal([f64::NAN, 0.0]), Err(PlanError::OutOfRange));
    p.set_goal([10.0, 0.0]).unwrap();
    assert_eq!(
        p.plan([f64::NAN, 0.0], 0.0, &w, &[]),
        Err(PlanError::NonFinitePose)
    );
    assert_eq!(
        p.plan([0.0, 0.0], f64::INFINITY, &w, &[]),
        Err(PlanError::NonFinitePose)
    );
    let bad = Wedge {
        half_angle_rad: 0.0,
        ..w
    };
    assert_eq!(
        p.plan([0.0, 0.0], 0.0, &bad, &[]),
        Err(PlanError::BadWedge(GeometryError::OutOfRange))
    );
    assert_eq!(p.counters().calls, 0);
    assert!(Planner::new(PlannerConfig {
        goal_tolerance_m: f64::NAN,
        ..PlannerConfig::default()
    })
    .is_err());

    // Open ground: drive straight, cut at the wedge's range.
    let out = p.plan([0.0, 0.0], 0.0, &w, &[]).unwrap();
    assert_eq!(out.status, PlanStatus::Driving);
    let path = out.path.unwrap();
    assert!((path.length_m() - 5.0).abs() < 0.03, "{}", path.length_m());
    assert_eq!(out.mode, Mode::MotionToGoal);

    // Goal behind: gaze towards it, no path.
    let out = p
        .plan([0.0, 0.0], PI, &wedge_at([0.0, 0.0], PI), &[])
        .unwrap();
    assert_eq!(out.status, PlanStatus::Gaze);
    assert!(out.path.is_none());
    assert!(out.gaze_heading_rad.unwrap().abs() < 1e-9);

    // Rover inside the clearance band of a rock (but not the rock): an escape leg first.
    let rock = rect(0.5, -1.0, 1.5, 1.0);
    let out = p
        .plan([0.47, 0.0], 0.0, &w, core::slice::from_ref(&rock))
        .unwrap();
    assert!(out.escaped);
    assert_eq!(out.status, PlanStatus::Driving);
    let first = out.path.unwrap().waypoints()[1];
    assert!((first[0] - 0.45).abs() < 1e-9);

    // Goal inside a rock: unreachable, latched until a new goal.
    p.set_goal([1.0, 0.0]).unwrap();
    let out = p
        .plan([-2.0, 0.0], 0.0, &wedge_at([-2.0, 0.0], 0.0), &[])
        .unwrap();
    assert_eq!(
        out.status,
        PlanStatus::Unreachable(UnreachableReason::GoalInObstacle)
    );
    let out = p
        .plan([-2.0, 0.0], 0.0, &wedge_at([-2.0, 0.0], 0.0), &[])
        .unwrap();
    assert_eq!(
        out.status,
        PlanStatus::Unreachable(UnreachableReason::GoalInObstacle)
    );
    p.set_goal([-2.0, 3.0]).unwrap();
    let out = p
        .plan([-2.0, 2.95], 0.0, &wedge_at([-2.0, 0.0], 0.0), &[])
        .unwrap();
    assert_eq!(out.status, PlanStatus::Reached);

    // A goal behind every direction the cameras can see: gaze requests are bounded.
    let mut p = Planner::new(PlannerConfig {
        max_consecutive_gazes: 3,
        ..PlannerConfig::default()
    })
    .unwrap();
    p.set_goal([-10.0, 0.0]).unwrap();
    let mut last = PlanStatus::Driving;
    for _ in 0..5 {
        last = p.plan([0.0, 0.0], 0.0, &w, &[]).unwrap().status;
    }
    assert_eq!(last, PlanStatus::Blocked(BlockedReason::GazeLimit));
}

/// The planner can be built in a static (const constructor, no pass through the stack).
static STATIC_PLANNER: Result<Planner, PlanError> = Planner::new(PlannerConfig::DEFAULT);

/// PLN-6: `size_of` of the planner state and the worst-case loop counts are within the
/// figures published in `docs/planning.md`.
#[test]
fn pln_6_memory_footprint() {
    assert!(STATIC_PLANNER.is_ok());
    let planner = core::mem::size_of::<Planner>();
    let ltg = core::mem::size_of::<LocalTangentGraph>();
    let memory = core::mem::size_of::<ObstacleMemory>();
    let output = core::mem::size_of::<PlannerOutput>();
    println!(
        "size_of Planner {planner} B (LTG scratch {ltg} B, memory {memory} B), output {output} B"
    );
    assert!(planner < 40_000, "{planner}");
    assert!(output < 512, "{output}");
}

/// PLN-6: a worst-case scene (32 remembered 12-gons within range, more than the LTG holds):
/// one step stays within the analytic bounds of `docs/planning.md` (LTG node pairs at most
/// MAX_NODES^2 / 2, at most two LTG solutions per step) and reports the local overflow.
#[test]
fn pln_6_worst_case_work() {
    let mut p = Planner::new(PlannerConfig::DEFAULT).unwrap();
    p.set_goal([30.0, 0.0]).unwrap();
    let mut rocks = Vec::new();
    for i in 0..8 {
        for j in 0..4 {
            let c = [
                1.0 + 0.55 * i as f64,
                -2.0 + 1.3 * j as f64 + 0.2 * (i % 2) as f64,
            ];
            rocks.push(regular(c, 0.25, 12, 0.1 * (i + j) as f64));
        }
    }
    let w = wedge_at([0.0, 0.0], 0.0);
    let out = p.plan([0.0, 0.0], 0.0, &w, &rocks).unwrap();
    let c = p.counters();
    println!(
        "worst case: status {:?}, memory {}, LTG solves {}, pairs {}, segment checks {}, local overflows {}",
        out.status,
        p.memory().len(),
        c.ltg_solves,
        c.max_ltg_pairs,
        c.max_segment_checks,
        c.local_overflows
    );
    assert_eq!(p.memory().len(), MEMORY_CAPACITY);
    assert!(c.local_overflows >= 1);
    assert!(c.ltg_solves <= 2);
    assert!(c.max_ltg_pairs as usize <= MAX_NODES * MAX_NODES / 2);
    assert!(c.max_segment_checks <= c.max_ltg_pairs);
    assert!(matches!(out.status, PlanStatus::Driving | PlanStatus::Gaze));
}

/// A planner that planned, initialised in place (`Planner::init`), is the new one; so is the
/// compile-time placeholder `Planner::EMPTY` for the default configuration.
#[test]
fn pln_in_place_init_equals_new() {
    let config = PlannerConfig::default();
    let fresh = Planner::new(config).unwrap();
    assert_eq!(format!("{:?}", Planner::EMPTY), format!("{fresh:?}"));
    let mut used = Planner::new(PlannerConfig {
        clearance_m: 0.3,
        ..config
    })
    .unwrap();
    used.set_goal([10.0, 0.0]).unwrap();
    let w = wedge_at([0.0, 0.0], 0.0);
    let rock =
        ConvexPolygon::from_points(&[[3.0, -0.5], [4.0, -0.5], [4.0, 0.5], [3.0, 0.5]]).unwrap();
    assert!(used.plan([0.0, 0.0], 0.0, &w, &[rock]).is_ok());
    assert_ne!(format!("{used:?}"), format!("{fresh:?}"));
    used.init(config).unwrap();
    assert_eq!(format!("{used:?}"), format!("{fresh:?}"));
}

/// PLN-6 (minimum reach): a path handed to guidance takes the rover at least `min_reach_m`
/// away, measured straight from the rover to the path's end, however the route bends. Swept
/// over rovers inside the clearance band in front of a rock (escape leg first, which skips the
/// gaze test) and beside it, headings of -60 to 60 deg and goals round the rock, with the
/// default configuration and the flight's (`min_reach_m` 0.1 m, clearance 0.15 m). Without the
/// rule a boundary-following route cut by the wedge right after the escape leg gives a 6.7 cm
/// polyline ending 5 cm away, inside guidance's stopping tolerance (`rockfield-goal`: a rover
/// holding and mapping on one spot until fault protection stops it).
#[test]
fn pln_6_every_driven_path_ends_min_reach_away() {
    let rock = rect(0.5, -1.0, 1.5, 1.0);
    let configs = [
        PlannerConfig::default(),
        PlannerConfig {
            clearance_m: 0.15,
            min_reach_m: 0.1,
            ..PlannerConfig::default()
        },
    ];
    let goals = [
        [3.0, 0.0],
        [1.0, 3.0],
        [3.0, 2.0],
        [-1.0, 3.0],
        [1.0, -3.0],
        [3.0, -1.5],
    ];
    let (mut driven, mut gazes, mut short) = (0, 0, 0);
    for config in configs {
        let band = config.clearance_m;
        for k in 0..12 {
            // In front of the rock (x just below 0.5) and beside it (y just beyond 1.0).
            let depth = band * (0.05 + 0.9 * f64::from(k % 4) / 3.0);
            let along = -0.9 + 0.6 * f64::from(k / 4);
            let positions = [[0.5 - depth, along], [1.0 + along * 0.5, 1.0 + depth]];
            for position in positions {
                for h in 0..7 {
                    let heading = (-60.0 + 20.0 * f64::from(h)).to_radians();
                    for goal in goals {
                        let mut p = Planner::new(config).unwrap();
                        p.set_goal(goal).unwrap();
                        let w = wedge_at(position, heading);
                        let out = p
                            .plan(position, heading, &w, core::slice::from_ref(&rock))
                            .unwrap();
                        match out.status {
                            PlanStatus::Driving => {
                                driven += 1;
                                let path = out.path.unwrap();
                                let end = *path.waypoints().last().unwrap();
                                let reach = dist(position, end);
                                if reach < config.min_reach_m {
                                    short += 1;
                                    eprintln!(
                                        "short drive {reach:.4} m from {position:?} heading \
                                         {heading:.2} to {goal:?}: {:?}",
                                        path.waypoints()
                                    );
                                }
                            }
                            PlanStatus::Gaze => gazes += 1,
                            _ => {}
                        }
                    }
                }
            }
        }
    }
    assert_eq!(
        short, 0,
        "{short} of {driven} driven paths end within min_drive"
    );
    assert!(driven > 100 && gazes > 10, "driven {driven}, gazes {gazes}");
}
