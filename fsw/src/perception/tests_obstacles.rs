//! Unit tests of the obstacle geometry (host only): convex hull (PERC-8), growth and vertex
//! reduction (PERC-9), flood fill (PERC-10).

use super::grid::{cell_centre, CellClass};
use super::obstacles::{
    component_polygon, contains_convex, convex_hull_sorted, distance_to_polygon, flood_fill, grow,
    is_convex_ccw, reduce_vertices, signed_area, Component,
};
use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::{println, vec::Vec};

fn sorted(mut points: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    points.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    points
}

/// PERC-8: the monotone-chain hull of random points is convex, counter-clockwise, made of
/// input points, contains every point, and every input point that is a strict corner of the
/// brute-force hull is a vertex.
#[test]
fn perc_8_convex_hull() {
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    for trial in 0..200 {
        let n = rng.random_range(3..60);
        let grid = trial % 2 == 0; // half the trials on a coarse grid: collinear and repeated
        let points: Vec<[f64; 2]> = (0..n)
            .map(|_| {
                if grid {
                    [
                        rng.random_range(0..6) as f64 * 0.1,
                        rng.random_range(0..6) as f64 * 0.1,
                    ]
                } else {
                    [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)]
                }
            })
            .collect();
        let points = sorted(points);
        let mut out = vec![[0.0; 2]; 2 * n];
        let h = convex_hull_sorted(&points, &mut out);
        let hull = &out[..h];
        if h < 3 {
            // Degenerate: all points collinear.
            assert!(points
                .iter()
                .all(|&p| super::obstacles::cross(points[0], points[n - 1], p).abs() < 1e-12));
            continue;
        }
        assert!(is_convex_ccw(hull), "{hull:?}");
        assert!(signed_area(hull) > 0.0);
        for p in &points {
            assert!(contains_convex(hull, *p));
        }
        for v in hull {
            assert!(points.contains(v));
        }
        // Brute force: a point is a strict corner when some direction makes it the unique
        // extreme; test 360 directions.
        for k in 0..360 {
            let (s, c) = (k as f64).to_radians().sin_cos();
            let best = points
                .iter()
                .map(|p| p[0] * c + p[1] * s)
                .fold(f64::NEG_INFINITY, f64::max);
            let extremes: Vec<_> = points
                .iter()
                .filter(|p| p[0] * c + p[1] * s > best - 1e-12)
                .collect();
            if extremes.len() == 1 {
                assert!(hull.contains(extremes[0]));
            }
        }
    }
    // Too small an output buffer: no hull.
    let pts = sorted(vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    assert_eq!(convex_hull_sorted(&pts, &mut [[0.0; 2]; 4]), 0);
}

/// PERC-9: growth: the Minkowski sum with the circumscribing octagon contains every point within
/// the radius of the polygon, stays within radius / cos(22.5 deg) of it, and is convex and
/// counter-clockwise; vertex reduction keeps the polygon inside the reduced one.
#[test]
fn perc_9_growth_and_vertex_reduction() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for _ in 0..100 {
        let n = rng.random_range(3..40);
        let points = sorted(
            (0..n)
                .map(|_| [rng.random_range(-1.0..1.0), rng.random_range(-0.5..0.5)])
                .collect(),
        );
        let mut hull = vec![[0.0; 2]; 2 * n];
        let h = convex_hull_sorted(&points, &mut hull);
        if h < 3 {
            continue;
        }
        let original = hull[..h].to_vec();
        // Reduction to at most 5 vertices contains the original.
        let m = reduce_vertices(&mut hull, h, 5);
        let reduced = &hull[..m];
        assert!(m <= 5, "{m}");
        assert!(is_convex_ccw(reduced), "{reduced:?}");
        for p in &original {
            assert!(contains_convex(reduced, *p), "{p:?}");
        }
        // Growth.
        let radius = rng.random_range(0.0..0.5);
        let mut out = vec![[0.0; 2]; h + GROW_SIDES];
        let g = grow(&original, radius, GROW_SIDES, &mut out);
        let grown = &out[..g];
        assert!(g >= 3 && g <= h + GROW_SIDES);
        assert!(radius == 0.0 || is_convex_ccw(grown), "{grown:?}");
        let outer = radius / (core::f64::consts::PI / GROW_SIDES as f64).cos();
        for _ in 0..200 {
            // A point within the radius of the polygon: a boundary point plus an offset.
            let k = rng.random_range(0..h);
            let (a, b) = (original[k], original[(k + 1) % h]);
            let t = rng.random_range(0.0..1.0);
            let angle: f64 = rng.random_range(0.0..core::f64::consts::TAU);
            let r = radius * rng.random_range(0.0..0.999f64).sqrt();
            let p = [
                a[0] + t * (b[0] - a[0]) + r * angle.cos(),
                a[1] + t * (b[1] - a[1]) + r * angle.sin(),
            ];
            assert!(radius == 0.0 || contains_convex(grown, p));
        }
        for v in grown {
            assert!(distance_to_polygon(&original, *v) <= outer + 1e-9);
        }
    }
    // Bad input.
    let square = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    assert_eq!(grow(&square, f64::NAN, 8, &mut [[0.0; 2]; 12]), 0);
    assert_eq!(grow(&square, 0.1, 8, &mut [[0.0; 2]; 11]), 0);
    assert_eq!(grow(&square[..2], 0.1, 8, &mut [[0.0; 2]; 12]), 0);
}

/// A grid whose hazard cells are the `#` of `rows` (row 0 first, column 0 first), one point
/// each.
fn grid_from(rows: &[&str]) -> TerrainGrid {
    let mut grid = TerrainGrid::new();
    for (i, row) in rows.iter().enumerate() {
        for (j, ch) in row.chars().enumerate() {
            if ch == '#' {
                grid.add_point(i, j, -0.5);
                grid.set_class(i, j, CellClass::Hazard);
            } else if ch == 'o' {
                grid.add_point(i, j, -0.7);
                grid.set_class(i, j, CellClass::Traversable);
            }
        }
    }
    grid
}

/// PERC-10: the flood fill is 8-connected, bounded by its queue (a full queue splits the
/// component and says so; the parts still cover every cell), adds the shadow cells behind a
/// hazard and its hull covers the cells.
#[test]
fn perc_10_flood_fill() {
    let rows = [
        "oooooooooooooooooooooooo",
        "oooo##oooooooooooooooooo",
        "ooooo#oooooooooo#ooooooo",
        "oooooo#ooooooooooooooooo",
        "oooooooooooooooooooooooo",
    ];
    let grid = grid_from(&rows);
    let mut visited = [false; GRID_CELLS];
    let mut component = Component::default();
    flood_fill::<FILL_QUEUE>(&grid, &mut visited, GRID_COLS + 4, 0, &mut component);
    assert_eq!(component.cells, 4); // diagonal neighbours are connected
    assert!(!component.overflowed);
    assert_eq!(component.rows[1], (4, 5));
    assert_eq!(component.rows[3], (6, 6));
    // The isolated cell is another component; a visited seed gives an empty one.
    flood_fill::<FILL_QUEUE>(&grid, &mut visited, GRID_COLS + 4, 0, &mut component);
    assert_eq!(component.cells, 0);
    flood_fill::<FILL_QUEUE>(&grid, &mut visited, 2 * GRID_COLS + 16, 0, &mut component);
    assert_eq!(component.cells, 1);
    // A solid 12 x 20 block of hazard cells with queues of 8 and 1 cells: the fill overflows,
    // and the components found from every seed cover all 240 cells exactly once (a queue of 8
    // still reaches every cell from other queued ones; a queue of 1 splits the block).
    let block: Vec<std::string::String> = (0..12).map(|_| "#".repeat(20)).collect();
    let block_rows: Vec<&str> = block.iter().map(|s| s.as_str()).collect();
    let grid = grid_from(&block_rows);
    fn cover<const Q: usize>(grid: &TerrainGrid) -> (usize, usize, usize) {
        let mut visited = [false; GRID_CELLS];
        let mut component = Component::default();
        let (mut total, mut parts, mut overflows) = (0, 0, 0);
        for seed in 0..GRID_CELLS {
            flood_fill::<Q>(grid, &mut visited, seed, 0, &mut component);
            if component.cells > 0 {
                total += usize::from(component.cells);
                parts += 1;
                overflows += usize::from(component.overflowed);
                let mut hull = [[0.0; 2]; 4 * (GRID_ROWS + 1)];
                assert!(component.hull(&mut hull) >= 3);
            }
        }
        (total, parts, overflows)
    }
    let (total, parts, overflows) = cover::<8>(&grid);
    println!("PERC-10 queue of 8: {parts} parts, {overflows} overflowed, {total} cells");
    assert_eq!((total, parts), (240, 1));
    assert!(overflows > 0);
    let (total, parts, overflows) = cover::<1>(&grid);
    println!("PERC-10 queue of 1: {parts} parts, {overflows} overflowed, {total} cells");
    assert_eq!(total, 240);
    assert!(overflows > 0 && parts > 1);
    // With the full queue the block is one component.
    let mut visited = [false; GRID_CELLS];
    flood_fill::<FILL_QUEUE>(&grid, &mut visited, 0, 0, &mut component);
    assert_eq!((component.cells, component.overflowed), (240, false));
    // Shadow: a hazard cell with empty cells behind it (seen from the origin) extends the
    // component by up to 3 cells along the ray.
    let mut grid = TerrainGrid::new();
    let centre_col = GRID_COLS / 2;
    grid.add_point(10, centre_col, -0.4);
    grid.set_class(10, centre_col, CellClass::Hazard);
    let mut visited = [false; GRID_CELLS];
    flood_fill::<FILL_QUEUE>(
        &grid,
        &mut visited,
        10 * GRID_COLS + centre_col,
        3,
        &mut component,
    );
    assert_eq!(component.cells, 1);
    let occupied: Vec<usize> = (0..GRID_ROWS)
        .filter(|&i| component.rows[i].0 <= component.rows[i].1)
        .collect();
    assert_eq!(occupied, vec![10, 11, 12, 13]);
    // The grown polygon of one cell contains the cell grown by the radius.
    let (polygon, reduced) = component_polygon(&component, 0.3).unwrap();
    assert_eq!(reduced, 0);
    assert!(polygon.is_convex_ccw());
    let [x, y] = cell_centre(10, centre_col);
    assert!(polygon.contains([x - 0.05 - 0.299, y]));
    assert!(polygon.contains([x + 0.35 + 0.299, y]));
}
