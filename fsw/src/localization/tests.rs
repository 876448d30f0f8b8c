//! Unit tests of the terrain-map localization (V99 sec. 5): the distance transform, the
//! branch-and-bound against brute force, recovery of a known offset, failures, covariance
//! consistency (NEES), target selection.

use super::search::SearchProgress;
use super::*;
use crate::perception::grid::cell_centre;
use crate::perception::{CellClass, GridFrame, TerrainGrid, GRID_COLS, GRID_ROWS};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::vec::Vec;

/// A rock of the synthetic terrain: centre `[x, y]` (m, `W`) and radius (m).
#[derive(Debug, Clone, Copy)]
struct Rock {
    c: [f64; 2],
    r: f64,
}

/// Random rocks in the square `[-half, half]^2` (m) at `density` per m^2.
fn random_rocks(rng: &mut ChaCha8Rng, half: f64, density: f64) -> Vec<Rock> {
    let count = (density * 4.0 * half * half).round() as usize;
    (0..count)
        .map(|_| Rock {
            c: [rng.random_range(-half..half), rng.random_range(-half..half)],
            r: rng.random_range(0.1..0.4),
        })
        .collect()
}

/// World points of the rocks on a 0.1 m lattice inside each disc (and each centre), every
/// rock displaced by its own offset of `rock_sigma` m per axis (the map's error).
fn rock_points(rocks: &[Rock], rng: &mut ChaCha8Rng, rock_sigma: f64) -> Vec<[f64; 2]> {
    let noise = Normal::new(0.0, rock_sigma.max(1e-12)).unwrap();
    let mut out = Vec::new();
    for r in rocks {
        let off = [noise.sample(rng), noise.sample(rng)];
        out.push([r.c[0] + off[0], r.c[1] + off[1]]);
        let n = (r.r / 0.1).ceil() as i32;
        for a in -n..=n {
            for b in -n..=n {
                let (dx, dy) = (f64::from(a) * 0.1, f64::from(b) * 0.1);
                if dx * dx + dy * dy <= r.r * r.r {
                    out.push([r.c[0] + dx + off[0], r.c[1] + dy + off[1]]);
                }
            }
        }
    }
    out
}

fn build_map(points: &[[f64; 2]]) -> GlobalMap {
    let mut map = GlobalMap::new();
    assert!(map.reset_centred([0.0, 0.0]));
    map.insert_points(points);
    map.finish();
    map
}

/// The hazard grid a rover at the true grid frame `truth` would map: cells whose centre is
/// inside a rock and inside the hazcam wedge (x_G from 0.3 to 3.2 m, 35 deg half-angle), with
/// `drop` of them missed and `false_cells` spurious hazard cells.
fn hazard_grid(
    rocks: &[Rock],
    truth: &GridFrame,
    rng: &mut ChaCha8Rng,
    drop: f64,
    false_cells: usize,
) -> TerrainGrid {
    let mut grid = TerrainGrid::new();
    let tan = 35.0_f64.to_radians().tan();
    for i in 0..GRID_ROWS {
        for j in 0..GRID_COLS {
            let g = cell_centre(i, j);
            if !(g[0] >= 0.3 && g[0] <= 3.2 && g[1].abs() <= g[0] * tan + 0.2) {
                continue;
            }
            let w = truth.to_world_xy(g);
            let inside = rocks.iter().any(|r| {
                let (dx, dy) = (w[0] - r.c[0], w[1] - r.c[1]);
                dx * dx + dy * dy <= r.r * r.r
            });
            if inside && rng.random::<f64>() >= drop {
                grid.set_class(i, j, CellClass::Hazard);
            }
        }
    }
    for _ in 0..false_cells {
        let (i, j) = (
            rng.random_range(3..GRID_ROWS),
            rng.random_range(0..GRID_COLS),
        );
        grid.set_class(i, j, CellClass::Hazard);
    }
    grid
}

fn diag(sx: f64, sy: f64, syaw: f64) -> [[f64; 3]; 3] {
    [
        [sx * sx, 0.0, 0.0],
        [0.0, sy * sy, 0.0],
        [0.0, 0.0, syaw * syaw],
    ]
}

/// Runs a started search to its end.
fn run(loc: &mut Localizer, map: &GlobalMap) -> Result<LocalizationFix, LocalizationError> {
    for _ in 0..1_000_000 {
        if let SearchProgress::Finished(r) = loc.step(map, 7) {
            return r;
        }
    }
    panic!("search did not end");
}

/// Exact squared distance transform by brute force over the occupied cells.
#[test]
fn distance_transform_is_exact() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for case in 0..4 {
        let mut map = GlobalMap::new();
        assert!(map.reset([0.0, 0.0]));
        let count = [1, 5, 40, 300][case];
        let mut occ = Vec::new();
        for _ in 0..count {
            let (i, j) = (rng.random_range(0..MAP_SIDE), rng.random_range(0..MAP_SIDE));
            occ.push((i as i64, j as i64));
            assert!(map.insert_point(map.cell_centre(i, j)));
        }
        map.finish();
        assert!(map.is_ready());
        for i in 0..MAP_SIDE as i64 {
            for j in 0..MAP_SIDE as i64 {
                let exact = occ
                    .iter()
                    .map(|(a, b)| (a - i) * (a - i) + (b - j) * (b - j))
                    .min()
                    .unwrap()
                    .min(255);
                assert_eq!(
                    i64::from(map.d2_at(i as i32, j as i32)),
                    exact,
                    "cell ({i}, {j}) case {case}"
                );
            }
        }
    }
}

/// The pyramid's window minimum never exceeds the exact minimum and is exact for one cell.
#[test]
fn window_minimum_is_a_lower_bound() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let rocks = random_rocks(&mut rng, 18.0, 0.05);
    let map = build_map(&rock_points(&rocks, &mut rng, 0.0));
    let mut equal = 0;
    for _ in 0..3000 {
        let i0 = rng.random_range(-10..MAP_SIDE as i32 + 5);
        let j0 = rng.random_range(-10..MAP_SIDE as i32 + 5);
        let (wi, wj) = (rng.random_range(0..40), rng.random_range(0..40));
        let (i1, j1) = (i0 + wi, j0 + wj);
        let mut exact = MAX_D2_CELLS;
        for i in i0..=i1 {
            for j in j0..=j1 {
                exact = exact.min(map.d2_at(i, j));
            }
        }
        let bound = map.min_d2_window(i0, i1, j0, j1);
        assert!(bound <= exact, "window {i0}..{i1} x {j0}..{j1}");
        equal += usize::from(bound == exact);
        assert_eq!(map.min_d2_window(i0, i0, j0, j0), map.d2_at(i0, j0));
    }
    assert!(equal > 1500, "bound too loose: {equal} of 3000 exact");
}

/// LOC-1: on random rock fields with random true offsets, the branch-and-bound returns the
/// brute-force optimum of the discretised pose space (same pose, same likelihood).
#[test]
fn branch_and_bound_matches_brute_force() {
    let mut nodes = Vec::new();
    let mut brute = Vec::new();
    let mut evals = Vec::new();
    let mut peaks = Vec::new();
    for seed in 0..40u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(1000 + seed);
        let density = rng.random_range(0.2..1.0);
        let rocks = random_rocks(&mut rng, 14.0, density);
        let map = build_map(&rock_points(&rocks, &mut rng, 0.03));
        let truth = GridFrame::new(
            [
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
                0.0,
            ],
            rng.random_range(-3.1..3.1),
        );
        let grid = hazard_grid(&rocks, &truth, &mut rng, 0.1, 3);
        let scan = LocalScan::from_grid(&grid);
        if scan.len() < 10 {
            continue;
        }
        let sigma = [0.3, 0.3, 0.05];
        let prior = [
            truth.origin_world_m[0] + rng.random_range(-2.0..2.0) * sigma[0],
            truth.origin_world_m[1] + rng.random_range(-2.0..2.0) * sigma[1],
            truth.heading_rad + rng.random_range(-2.0..2.0) * sigma[2],
        ];
        let mut loc = Localizer::new(LocalizerConfig::default()).unwrap();
        loc.start(&map, &scan, prior, diag(sigma[0], sigma[1], sigma[2]))
            .unwrap();
        let result = run(&mut loc, &map);
        assert!(
            !matches!(
                result,
                Err(LocalizationError::NodeBudgetExceeded | LocalizationError::QueueFull)
            ),
            "seed {seed}: {result:?}"
        );
        let found = loc.best_leaf();
        let w = loc.clone();
        let mut bf = w;
        bf.start(&map, &scan, prior, diag(sigma[0], sigma[1], sigma[2]))
            .unwrap();
        let exact = bf.brute_force(&map);
        assert_eq!(found, exact, "seed {seed}");
        if let Ok(fix) = result {
            nodes.push(fix.nodes);
            evals.push(fix.point_evaluations);
            peaks.push(fix.queue_peak);
            let h = fix.window;
            brute.push(((2 * h[0] + 1) * (2 * h[1] + 1) * (2 * h[2] + 1)) as u32);
        }
    }
    assert!(nodes.len() >= 20, "only {} fixes", nodes.len());
    nodes.sort_unstable();
    evals.sort_unstable();
    std::eprintln!(
        "B&B nodes: median {} max {} (brute force poses median {}), point evaluations max {}, queue peak max {}",
        nodes[nodes.len() / 2],
        nodes[nodes.len() - 1],
        brute[brute.len() / 2],
        evals[evals.len() - 1],
        peaks.iter().max().unwrap()
    );
}

/// LOC-2: a known offset on a synthetic rock field is recovered within one cell and one yaw
/// step.
#[test]
fn recovers_known_offset() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let rocks = random_rocks(&mut rng, 14.0, 0.8);
    let map = build_map(&rock_points(&rocks, &mut rng, 0.0));
    let truth = GridFrame::new([1.3, -2.1, 0.0], 0.7);
    let grid = hazard_grid(&rocks, &truth, &mut rng, 0.0, 0);
    let prior_frame = GridFrame::new([1.3 + 0.5, -2.1 - 0.3, 0.0], 0.7 + 0.035);
    let mut loc = Localizer::new(LocalizerConfig::default()).unwrap();
    let fix = loc
        .localize(&map, &grid, &prior_frame, diag(0.3, 0.3, 0.03))
        .unwrap();
    let err = [
        fix.pose[0] - truth.origin_world_m[0],
        fix.pose[1] - truth.origin_world_m[1],
        fix.pose[2] - truth.heading_rad,
    ];
    std::eprintln!("offset recovery error {err:?}, fix {fix:?}");
    assert!(
        err[0].abs() < MAP_CELL_M && err[1].abs() < MAP_CELL_M,
        "{err:?}"
    );
    assert!(err[2].abs() < fix.yaw_step_rad, "{err:?}");
    // The correction transferred to a point 0.5 m behind the grid origin.
    let behind = [
        prior_frame.origin_world_m[0] - 0.5 * prior_frame.heading_cos,
        prior_frame.origin_world_m[1] - 0.5 * prior_frame.heading_sin,
        prior_frame.heading_rad,
    ];
    let (rover, cov) = fix.transfer(behind).unwrap();
    let truth_behind = truth.to_world_xy([-0.5, 0.0]);
    assert!((rover[0] - truth_behind[0]).abs() < MAP_CELL_M);
    assert!((rover[1] - truth_behind[1]).abs() < MAP_CELL_M);
    assert!(cov[0][0] > 0.0 && cov[1][1] > 0.0);
}

/// LOC-3: featureless terrain and a map without the seen rocks fail with an error value.
#[test]
fn featureless_terrain_fails() {
    let mut loc = Localizer::new(LocalizerConfig::default()).unwrap();
    let frame = GridFrame::new([0.0, 0.0, 0.0], 0.0);
    // An empty map is not ready.
    let mut empty = GlobalMap::new();
    assert!(empty.reset_centred([0.0, 0.0]));
    empty.finish();
    let grid = TerrainGrid::new();
    assert_eq!(
        loc.localize(&empty, &grid, &frame, diag(0.3, 0.3, 0.03)),
        Err(LocalizationError::MapNotReady)
    );
    // Rocks far away, nothing in view: too few points.
    let map = build_map(&[[10.0, 10.0], [12.0, -9.0]]);
    assert_eq!(
        loc.localize(&map, &grid, &frame, diag(0.3, 0.3, 0.03)),
        Err(LocalizationError::TooFewPoints { points: 0 })
    );
    // Rocks in view that the map does not have: too few inliers.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let rocks = random_rocks(&mut rng, 14.0, 0.8);
    let grid = hazard_grid(&rocks, &frame, &mut rng, 0.0, 0);
    let r = loc.localize(&map, &grid, &frame, diag(0.3, 0.3, 0.03));
    assert!(
        matches!(r, Err(LocalizationError::TooFewInliers { .. })),
        "{r:?}"
    );
    // A single rock in view: many poses fit nearly as well (ambiguous or too few inliers).
    let one = [Rock {
        c: [1.5, 0.0],
        r: 0.35,
    }];
    let map = build_map(&rock_points(&one, &mut rng, 0.0));
    let grid = hazard_grid(&one, &frame, &mut rng, 0.0, 0);
    let r = loc.localize(&map, &grid, &frame, diag(0.3, 0.3, 0.03));
    assert!(r.is_err(), "{r:?}");
}

/// LOC-4: non-finite prior, covariance or points give errors.
#[test]
fn non_finite_inputs_are_refused() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let rocks = random_rocks(&mut rng, 14.0, 0.8);
    let map = build_map(&rock_points(&rocks, &mut rng, 0.0));
    let frame = GridFrame::new([0.0, 0.0, 0.0], 0.0);
    let grid = hazard_grid(&rocks, &frame, &mut rng, 0.0, 0);
    let scan = LocalScan::from_grid(&grid);
    let mut loc = Localizer::new(LocalizerConfig::default()).unwrap();
    let cov = diag(0.3, 0.3, 0.03);
    for bad in [f64::NAN, f64::INFINITY] {
        assert_eq!(
            loc.localize_scan(&map, &scan, [bad, 0.0, 0.0], cov),
            Err(LocalizationError::InvalidPrior)
        );
        assert_eq!(
            loc.localize_scan(&map, &scan, [0.0, 0.0, bad], cov),
            Err(LocalizationError::InvalidPrior)
        );
        let mut c = cov;
        c[1][1] = bad;
        assert_eq!(
            loc.localize_scan(&map, &scan, [0.0; 3], c),
            Err(LocalizationError::InvalidPrior)
        );
        let mut s = LocalScan::new();
        assert_eq!(s.push([bad, 1.0]), Err(LocalizationError::InvalidPoint));
        assert_eq!(s.push([1.0, bad]), Err(LocalizationError::InvalidPoint));
    }
    let mut c = cov;
    c[0][0] = -1.0;
    assert_eq!(
        loc.localize_scan(&map, &scan, [0.0; 3], c),
        Err(LocalizationError::InvalidPrior)
    );
    // Too uncertain for the window.
    assert_eq!(
        loc.localize_scan(&map, &scan, [0.0; 3], diag(5.0, 5.0, 0.03)),
        Err(LocalizationError::PriorTooUncertain)
    );
    // A map with non-finite points refuses them.
    let mut m = GlobalMap::new();
    assert!(m.reset_centred([0.0, 0.0]));
    assert_eq!(
        m.insert_points(&[[f64::NAN, 0.0], [0.0, f64::INFINITY], [1.0, 1.0]]),
        1
    );
    assert_eq!(m.rejected_points(), 2);
    assert!(!m.reset([f64::NAN, 0.0]));
    // A map changed during the search is detected.
    let mut map2 = map.clone();
    loc.start(&map2, &scan, [0.0; 3], cov).unwrap();
    map2.insert_point([3.0, 3.0]);
    map2.finish();
    assert_eq!(
        loc.step(&map2, 1),
        SearchProgress::Finished(Err(LocalizationError::MapChanged))
    );
    assert_eq!(
        loc.step(&map2, 1),
        SearchProgress::Finished(Err(LocalizationError::NotStarted))
    );
    assert!(Localizer::new(LocalizerConfig {
        sigma_m: f64::NAN,
        ..LocalizerConfig::default()
    })
    .is_err());
}

/// A tiny node budget gives the budget error, never a pose.
#[test]
fn node_budget_gives_an_error() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let rocks = random_rocks(&mut rng, 14.0, 0.8);
    let map = build_map(&rock_points(&rocks, &mut rng, 0.0));
    let frame = GridFrame::new([0.0, 0.0, 0.0], 0.3);
    let grid = hazard_grid(&rocks, &frame, &mut rng, 0.0, 0);
    let config = LocalizerConfig {
        max_nodes: 20,
        ..LocalizerConfig::default()
    };
    let mut loc = Localizer::new(config).unwrap();
    let prior = GridFrame::new([0.4, -0.4, 0.0], 0.33);
    assert_eq!(
        loc.localize(&map, &grid, &prior, diag(0.5, 0.5, 0.05)),
        Err(LocalizationError::NodeBudgetExceeded)
    );
}

/// Outcome of one NEES trial.
struct NeesTrial {
    nees: f64,
    err: [f64; 3],
    sigma: [f64; 3],
}

/// Random trials: truth drawn around the prior from the prior covariance, the map's rocks
/// displaced by `rock_sigma`; returns the NEES of the fixes and the number of failures.
fn nees_trials(
    seed: u64,
    trials: usize,
    density: f64,
    rock_sigma: f64,
    config: LocalizerConfig,
) -> (Vec<NeesTrial>, usize) {
    let mut out = Vec::new();
    let mut failures = 0;
    let mut loc = Localizer::new(config).unwrap();
    for k in 0..trials {
        let mut rng = ChaCha8Rng::seed_from_u64(seed + k as u64);
        let rocks = random_rocks(&mut rng, 14.0, density);
        let map = build_map(&rock_points(&rocks, &mut rng, rock_sigma));
        let truth = GridFrame::new(
            [
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
                0.0,
            ],
            rng.random_range(-3.1..3.1),
        );
        let grid = hazard_grid(&rocks, &truth, &mut rng, 0.1, 2);
        let s = [0.3, 0.3, 0.03];
        let n = Normal::new(0.0, 1.0).unwrap();
        let prior = GridFrame::new(
            [
                truth.origin_world_m[0] + s[0] * n.sample(&mut rng),
                truth.origin_world_m[1] + s[1] * n.sample(&mut rng),
                0.0,
            ],
            truth.heading_rad + s[2] * n.sample(&mut rng),
        );
        match loc.localize(&map, &grid, &prior, diag(s[0], s[1], s[2])) {
            Ok(fix) => {
                let e = [
                    fix.pose[0] - truth.origin_world_m[0],
                    fix.pose[1] - truth.origin_world_m[1],
                    fix.pose[2] - truth.heading_rad,
                ];
                let p = nalgebra::Matrix3::from_fn(|r, c| fix.covariance[r][c]);
                let ev = nalgebra::Vector3::new(e[0], e[1], e[2]);
                let nees = (ev.transpose() * p.try_inverse().unwrap() * ev)[(0, 0)];
                let sigma = [0, 1, 2].map(|k| fix.covariance[k][k].sqrt());
                out.push(NeesTrial {
                    nees,
                    err: e,
                    sigma,
                });
            }
            Err(e) => {
                failures += 1;
                if std::env::var("LOC_VERBOSE").is_ok() {
                    std::eprintln!("trial {k}: {e:?}");
                }
            }
        }
    }
    (out, failures)
}

/// LOC-5: the covariance covers the true error: mean NEES per degree of freedom between 0.3
/// and 3 over random trials (independent point errors: stereo and quantisation only).
#[test]
fn covariance_is_consistent() {
    let (trials, failures) = nees_trials(5000, 150, 0.4, 0.0, LocalizerConfig::default());
    assert!(
        trials.len() >= 100,
        "{} fixes, {failures} failures",
        trials.len()
    );
    let mean = trials.iter().map(|t| t.nees).sum::<f64>() / trials.len() as f64 / 3.0;
    let rms = |k: usize| {
        (trials.iter().map(|t| t.err[k] * t.err[k]).sum::<f64>() / trials.len() as f64).sqrt()
    };
    std::eprintln!(
        "NEES per dof {mean:.2} over {} fixes ({failures} failures); rms error x {:.3} m y {:.3} m yaw {:.4} rad",
        trials.len(),
        rms(0),
        rms(1),
        rms(2)
    );
    assert!((0.3..=3.0).contains(&mean), "NEES per dof {mean}");
}

/// The hazard blocks of a full grid are thinned to MAX_POINTS, deterministically.
#[test]
fn scan_subsampling_is_deterministic() {
    let mut grid = TerrainGrid::new();
    for i in 0..GRID_ROWS {
        for j in 0..GRID_COLS {
            grid.set_class(i, j, CellClass::Hazard);
        }
    }
    let a = LocalScan::from_grid(&grid);
    let b = LocalScan::from_grid(&grid);
    assert_eq!(a.len(), MAX_POINTS);
    assert_eq!(a.points(), b.points());
    // The kept points span the grid (first and last rows of blocks).
    let xs: Vec<f64> = a.points().iter().map(|p| p[0]).collect();
    assert!(xs.iter().cloned().fold(f64::INFINITY, f64::min) < 0.3);
    assert!(xs.iter().cloned().fold(0.0, f64::max) > 3.5);
    // A second grid turned 90 deg right in place lands rotated in the first one's frame.
    let reference = GridFrame::new([1.0, 2.0, 0.0], 0.3);
    let right = GridFrame::new([1.0, 2.0, 0.0], 0.3 + core::f64::consts::FRAC_PI_2);
    let mut one = TerrainGrid::new();
    one.set_class(20, 24, CellClass::Hazard);
    let mut s = LocalScan::new();
    assert_eq!(s.append_grid(&one, &right, &reference, 10), 1);
    let c = cell_centre(20, 24);
    assert!((s.points()[0][0] + c[1]).abs() < 1e-9 && (s.points()[0][1] - c[0]).abs() < 1e-9);
    assert_eq!(s.append_grid(&grid, &reference, &reference, 5), 5);
    assert_eq!(s.len(), 6);
    // One hazard cell gives one point at its centre.
    let mut one = TerrainGrid::new();
    one.set_class(5, 7, CellClass::Hazard);
    let s = LocalScan::from_grid(&one);
    assert_eq!(s.points(), &[cell_centre(5, 7)]);
}

/// LOC-6: target selection picks the heading whose wedge holds the rocks.
#[test]
fn target_selection_prefers_rocky_heading() {
    // Rocks 2 m east of the apex, none elsewhere.
    let rocks = [
        Rock {
            c: [0.0, 2.0],
            r: 0.3,
        },
        Rock {
            c: [0.5, 1.8],
            r: 0.2,
        },
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let map = build_map(&rock_points(&rocks, &mut rng, 0.0));
    let headings = [
        0.0,
        core::f64::consts::FRAC_PI_2,
        core::f64::consts::PI,
        -core::f64::consts::FRAC_PI_2,
    ];
    let choice = select_target(&map, [0.0, 0.0], &headings, &TargetWedge::default()).unwrap();
    assert_eq!(choice.index, 1);
    assert!(choice.occupied_cells >= 5);
    // Nothing to see: no target.
    assert!(select_target(
        &map,
        [0.0, 0.0],
        &[core::f64::consts::PI],
        &TargetWedge::default()
    )
    .is_none());
    assert!(select_target(&map, [f64::NAN, 0.0], &headings, &TargetWedge::default()).is_none());
    // The own hazard grid inserted into a map lands where it was seen.
    let frame = GridFrame::new([1.0, 2.0, 0.0], 0.5);
    let mut grid = TerrainGrid::new();
    grid.set_class(10, 24, CellClass::Hazard);
    let mut own = GlobalMap::new();
    assert!(own.reset_centred([0.0, 0.0]));
    assert_eq!(own.insert_grid_hazards(&grid, &frame), 1);
    own.finish();
    let w = frame.to_world_xy(cell_centre(10, 24));
    let (i, j) = own.cell_of(w).unwrap();
    assert_eq!(own.d2_at(i as i32, j as i32), 0);
}

/// Survey of the covariance consistency against the map's rock error (run by hand with
/// `--ignored --nocapture`; figures in `docs/localization.md`).
#[test]
#[ignore]
fn nees_survey() {
    for (density, rock_sigma) in [(0.4, 0.0), (0.4, 0.05), (0.4, 0.1), (0.8, 0.0), (0.2, 0.0)] {
        let (t, failures) = nees_trials(9000, 300, density, rock_sigma, LocalizerConfig::default());
        let gross = t.iter().filter(|t| t.nees > 3.0 * 11.34).count();
        let n = t.len() as f64;
        let mean = t.iter().map(|t| t.nees).sum::<f64>() / n / 3.0;
        let axis = |k: usize| {
            t.iter()
                .map(|t| (t.err[k] / t.sigma[k]).powi(2))
                .sum::<f64>()
                / n
        };
        let rms = |k: usize| (t.iter().map(|t| t.err[k] * t.err[k]).sum::<f64>() / n).sqrt();
        let sig = |k: usize| t.iter().map(|t| t.sigma[k]).sum::<f64>() / n;
        std::eprintln!(
            "density {density} rock sigma {rock_sigma}: fixes {} failures {failures} gross {gross} NEES/dof {mean:.2} axis NEES x {:.2} y {:.2} yaw {:.2}; rms err {:.3} {:.3} {:.4}; mean sigma {:.3} {:.3} {:.4}",
            t.len(), axis(0), axis(1), axis(2), rms(0), rms(1), rms(2), sig(0), sig(1), sig(2)
        );
    }
}

/// Node counts against the prior's size (run by hand with `--ignored --nocapture`; figures in
/// `docs/localization.md`).
#[test]
#[ignore]
fn node_survey() {
    for (sxy, syaw) in [
        (0.1, 0.01),
        (0.3, 0.03),
        (0.6, 0.05),
        (1.0, 0.1),
        (2.0, 0.2),
    ] {
        let mut nodes = Vec::new();
        let mut evals = Vec::new();
        let mut queue = 0;
        let mut poses = 0;
        let mut fails = 0;
        for k in 0..60u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(300 + k);
            let rocks = random_rocks(&mut rng, 14.0, 0.5);
            let map = build_map(&rock_points(&rocks, &mut rng, 0.05));
            let truth = GridFrame::new([0.5, -0.5, 0.0], rng.random_range(-3.1..3.1));
            let grid = hazard_grid(&rocks, &truth, &mut rng, 0.1, 2);
            let n = Normal::new(0.0, 1.0).unwrap();
            let prior = GridFrame::new(
                [
                    0.5 + sxy * n.sample(&mut rng),
                    -0.5 + sxy * n.sample(&mut rng),
                    0.0,
                ],
                truth.heading_rad + syaw * n.sample(&mut rng),
            );
            let mut loc = Localizer::new(LocalizerConfig::default()).unwrap();
            match loc.localize(&map, &grid, &prior, diag(sxy, sxy, syaw)) {
                Ok(fix) => {
                    nodes.push(fix.nodes);
                    evals.push(fix.point_evaluations);
                    queue = queue.max(fix.queue_peak);
                    let h = fix.window;
                    poses = poses.max((2 * h[0] + 1) * (2 * h[1] + 1) * (2 * h[2] + 1));
                }
                Err(e) => {
                    if fails == 0 {
                        std::eprintln!("prior {sxy} m: first failure {e:?}");
                    }
                    fails += 1;
                }
            }
        }
        nodes.sort_unstable();
        evals.sort_unstable();
        if nodes.is_empty() {
            std::eprintln!("prior {sxy} m {syaw} rad: no fix ({fails} failures)");
            continue;
        }
        std::eprintln!(
            "prior {sxy} m {syaw} rad: fixes {} fails {fails}; nodes median {} max {}; point evaluations max {}; queue peak {queue}; poses in window max {poses}",
            nodes.len(), nodes[nodes.len() / 2], nodes[nodes.len() - 1], evals[evals.len() - 1]
        );
    }
}

/// A localizer that localized, initialised in place (`Localizer::init`), is the new one.
#[test]
fn in_place_init_equals_new() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let rocks = random_rocks(&mut rng, 14.0, 0.8);
    let map = build_map(&rock_points(&rocks, &mut rng, 0.0));
    let truth = GridFrame::new([1.3, -2.1, 0.0], 0.7);
    let grid = hazard_grid(&rocks, &truth, &mut rng, 0.0, 0);
    let prior_frame = GridFrame::new([1.8, -2.4, 0.0], 0.735);
    let config = LocalizerConfig::default();
    let fresh = Localizer::new(config).unwrap();
    let mut used = Localizer::new(LocalizerConfig {
        sigma_m: 0.2,
        ..config
    })
    .unwrap();
    assert!(used
        .localize(&map, &grid, &prior_frame, diag(0.3, 0.3, 0.03))
        .is_ok());
    assert_ne!(format!("{used:?}"), format!("{fresh:?}"));
    used.init(config).unwrap();
    assert_eq!(format!("{used:?}"), format!("{fresh:?}"));
}

/// LOC-9: the search's cell of a point (truncation and one correction) equals
/// `libm::floor` on both signs, at integers, next to them and at the edges of its range, and
/// refuses what `libm::floor` would put outside +-1e6 or NaN.
#[test]
fn loc_9_floor_cell_equals_libm_floor() {
    let reference = |u: f64, v: f64| {
        let (fu, fv) = (libm::floor(u), libm::floor(v));
        let lim = 1.0e6;
        (fu >= -lim && fu <= lim && fv >= -lim && fv <= lim).then_some((fu as i32, fv as i32))
    };
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut values: Vec<f64> = (0..20_000)
        .map(|_| rng.random_range(-300.0..300.0))
        .collect();
    for k in -5..=5 {
        let k = f64::from(k);
        values.extend([k, k - 1e-12, k + 1e-12, k - 0.5, k + 0.5]);
    }
    values.extend([
        1.0e6,
        1.0e6 + 0.999,
        1.0e6 + 1.0,
        -1.0e6,
        -1.0e6 - 1e-9,
        5e9,
        -5e9,
    ]);
    values.extend([f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.0]);
    for w in values.windows(2) {
        assert_eq!(
            search::Localizer::floor_cell(w[0], w[1]),
            reference(w[0], w[1]),
            "{} {}",
            w[0],
            w[1]
        );
    }
}
