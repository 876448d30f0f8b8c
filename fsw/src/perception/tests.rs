//! Tests of the hazard perception (host only): rendered scenes through the whole mapper (PERC-1
//! to PERC-6, PERC-12), bad inputs (PERC-7), the resumable work items and the memory (PERC-11).
//! The polygon and flood-fill units (PERC-8 to PERC-10) are in `tests_obstacles.rs`.

use super::grid::{cell_centre, CellClass};
use super::render::{render, Scene, Solid};
use super::*;
use crate::kinematics::geometry::WHEEL_RADIUS_M;
use crate::types::{Mat3, Vec3};
use nalgebra::Rotation3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rover_hal::{StereoFrame, IMAGE_PIXELS};
use std::{boxed::Box, println, vec::Vec};

/// Camera pose of the rover at `(x, y)` with yaw `yaw_deg` (clockwise from north seen from
/// above), pitch and roll, its contact plane through the world point `ground` (z down).
fn rover_camera(yaw_deg: f64, pitch_deg: f64, x: f64, y: f64, ground_z: f64) -> CameraPose {
    let rot: Mat3 = Rotation3::from_euler_angles(0.0, pitch_deg.to_radians(), yaw_deg.to_radians())
        .into_inner();
    // The contact plane z_R = r passes through the ground point below the rover.
    let pos = Vec3::new(x, y, ground_z) - rot * Vec3::new(0.0, 0.0, WHEEL_RADIUS_M);
    CameraPose::from_rover(&rot, &pos, &crate::vo::rocky8_hazcam()).unwrap()
}

/// The level rover at `(x, y)` heading `yaw_deg`.
fn level_rover(yaw_deg: f64, x: f64, y: f64) -> CameraPose {
    rover_camera(yaw_deg, 0.0, x, y, 0.0)
}

struct Run {
    mapper: Box<HazardMapper>,
    result: Result<(), PerceptionError>,
}

impl Run {
    fn map(&self) -> &HazardMap {
        self.mapper.map().expect("a finished map")
    }
}

fn map_scene(scene: &Scene, pose: &CameraPose) -> Run {
    let (left, right) = render(scene, pose, &crate::vo::rocky8_hazcam());
    map_images(&left, &right, pose, PerceptionConfig::default())
}

fn map_images(left: &[u8], right: &[u8], pose: &CameraPose, config: PerceptionConfig) -> Run {
    let cal = crate::vo::rocky8_hazcam();
    let mut mapper = Box::new(HazardMapper::new(config, &cal).unwrap());
    let frame = StereoFrame {
        left,
        right,
        capture_t_us: 1_000_000,
        sequence: 1,
    };
    let result = mapper.run_to_completion(&frame, pose).map(|_| ());
    Run { mapper, result }
}

fn print_map(name: &str, run: &Run) {
    println!("{name}: {:?}", run.result);
    if let Some(map) = run.mapper.map() {
        println!("  counts {:?}", map.counts);
        println!("  wedge {:?}", map.wedge);
        for (k, o) in map.obstacles.iter().enumerate() {
            println!(
                "  obstacle {k}: {} vertices, area {:.3} m^2",
                o.vertices.len(),
                o.area()
            );
        }
    }
}

/// The class map as text rows (near row first): `.` unknown, `o` traversable, `#` hazard.
fn class_map(run: &Run) -> Vec<std::string::String> {
    (0..GRID_ROWS)
        .map(|i| {
            (0..GRID_COLS)
                .map(|j| match run.mapper.grid().class(i, j) {
                    CellClass::Unknown => '.',
                    CellClass::Traversable => 'o',
                    CellClass::Hazard => '#',
                })
                .collect()
        })
        .collect()
}

/// Per 0.5 m band of distance from the camera's nadir: (band start m, cells, rms, max abs) of
/// the known cells' mean heights against the scene's surface at the cell centre.
fn height_errors(run: &Run, scene: &Scene) -> Vec<(f64, usize, f64, f64)> {
    let frame = run.map().grid;
    let mut bands: Vec<(f64, usize, f64, f64)> =
        (0..8).map(|b| (b as f64 * 0.5, 0, 0.0, 0.0)).collect();
    for i in 0..GRID_ROWS {
        for j in 0..GRID_COLS {
            let cell = run.mapper.grid().cell(i, j).unwrap();
            if cell.count == 0 {
                continue;
            }
            let g = cell_centre(i, j);
            let [x, y] = frame.to_world_xy(g);
            // Heights in the grid are up from the camera centre (z_W down).
            let truth = scene.height(x, y) + frame.origin_world_m[2];
            let e = cell.mean_m() - truth;
            let b = ((g[0].hypot(g[1]) / 0.5) as usize).min(7);
            bands[b].1 += 1;
            bands[b].2 += e * e;
            bands[b].3 = bands[b].3.max(e.abs());
        }
    }
    for b in bands.iter_mut().filter(|b| b.1 > 0) {
        b.2 = (b.2 / b.1 as f64).sqrt();
    }
    bands
}

/// Adds Gaussian noise of `sigma` grey levels (rounded, clipped) to an image.
fn add_noise(image: &mut [u8], sigma: f64, seed: u64) {
    use rand_distr::{Distribution, Normal};
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sigma).unwrap();
    for p in image.iter_mut() {
        *p = (f64::from(*p) + noise.sample(&mut rng))
            .round()
            .clamp(0.0, 255.0) as u8;
    }
}

/// PERC-1: textured level ground, rover level at two poses (the second with 2 grey levels of
/// image noise): no hazard, no obstacle, the wedge covered by points, cell heights within a few
/// cm of the truth at every range.
#[test]
fn perc_1_flat_ground_has_no_hazards() {
    for (yaw, x, y, noise) in [(0.0, 0.0, 0.0, 0.0), (37.0, 5.0, -3.0, 2.0)] {
        let pose = level_rover(yaw, x, y);
        let scene = Scene::default();
        let (mut left, mut right) = render(&scene, &pose, &crate::vo::rocky8_hazcam());
        if noise > 0.0 {
            add_noise(&mut left, noise, 1);
            add_noise(&mut right, noise, 2);
        }
        let run = map_images(&left, &right, &pose, PerceptionConfig::default());
        print_map(&format!("PERC-1 flat, noise {noise}"), &run);
        assert_eq!(run.result, Ok(()));
        let map = run.map();
        assert!(map.obstacles.is_empty());
        assert_eq!(map.counts.cells_hazard, 0);
        assert!(map.counts.matched > 250, "{}", map.counts.matched);
        // Cells with points but too few neighbours for a plane: a few at the footprint's edge.
        assert!(map.counts.cells_sparse <= 10, "{}", map.counts.cells_sparse);
        // The wedge: apex at the camera's nadir, along the heading, 0.2-0.3 m to 2.8-3 m.
        let w = map.wedge;
        let nadir = pose.position_world_m;
        assert!((w.apex_m[0] - nadir.x).abs() < 1e-9 && (w.apex_m[1] - nadir.y).abs() < 1e-9);
        assert!((w.heading_rad - yaw.to_radians()).abs() < 1e-9);
        assert!(w.max_range_m >= 2.5 && w.max_range_m <= 3.1, "{w:?}");
        assert!(w.min_range_m <= 0.4, "{w:?}");
        assert!(w.half_angle_rad >= 30f64.to_radians(), "{w:?}");
        assert!(
            map.wedge_known_fraction() > 0.9,
            "{}",
            map.wedge_known_fraction()
        );
        // Every cell with points inside the wedge is classified traversable.
        let frame = map.grid;
        for i in 0..GRID_ROWS {
            for j in 0..GRID_COLS {
                let inside = w.contains(frame.to_world_xy(cell_centre(i, j)));
                let known = run.mapper.grid().cell(i, j).unwrap().count > 0;
                if inside && known {
                    assert_ne!(run.mapper.grid().class(i, j), CellClass::Hazard);
                }
            }
        }
        for (start, cells, rms, max) in height_errors(&run, &scene) {
            println!(
                "  range {start:.1}-{:.1} m: {cells} cells, height error rms {:.1} mm, max {:.1} mm",
                start + 0.5,
                rms * 1e3,
                max * 1e3
            );
            assert!(
                rms < 0.01 && max < 0.03,
                "band {start}: rms {rms}, max {max}"
            );
        }
    }
}

/// The scene of PERC-2: a hemispherical rock of radius (and height) 0.25 m, 2 m ahead of the
/// rover at `(x, y)` heading `yaw_deg`. Returns the scene and the rock's centre.
fn rock_scene(yaw_deg: f64, x: f64, y: f64) -> (Scene, [f64; 2]) {
    let (s, c) = yaw_deg.to_radians().sin_cos();
    let centre = [x + 2.0 * c, y + 2.0 * s];
    let scene = Scene {
        ramp: None,
        solids: vec![Solid::Hemisphere {
            centre,
            radius: 0.25,
        }],
    };
    (scene, centre)
}

/// PERC-2: a 0.25 m rock 2 m ahead gives one obstacle polygon, convex and counter-clockwise in
/// the world frame, that contains the rock's footprint grown by the rover's half-width and
/// extends no more than 1 m from the rock's centre (footprint 0.25 + half-width 0.35 + margin
/// 0.1 = 0.70 m).
#[test]
fn perc_2_rock_is_one_grown_polygon() {
    for (yaw, x, y) in [(0.0, 0.0, 0.0), (-30.0, 2.0, 1.0)] {
        let pose = level_rover(yaw, x, y);
        let (scene, centre) = rock_scene(yaw, x, y);
        let run = map_scene(&scene, &pose);
        print_map("PERC-2 rock", &run);
        for row in class_map(&run).iter().take(26).skip(12) {
            println!("  {row}");
        }
        assert_eq!(run.result, Ok(()));
        let map = run.map();
        assert_eq!(map.obstacles.len(), 1, "{:?}", map.obstacles);
        let polygon = &map.obstacles[0];
        assert!(polygon.is_convex_ccw());
        let grown = 0.25 + ROVER_HALF_WIDTH_M;
        for k in 0..72 {
            let (s, c) = (k as f64 * 5f64.to_radians()).sin_cos();
            let p = [centre[0] + grown * c, centre[1] + grown * s];
            assert!(polygon.contains(p), "{p:?} not in the obstacle");
        }
        let farthest = polygon
            .vertices
            .iter()
            .map(|v| (v[0] - centre[0]).hypot(v[1] - centre[1]))
            .fold(0.0, f64::max);
        println!(
            "  area {:.2} m^2 (disc of radius {grown:.2} m: {:.2} m^2), farthest vertex {farthest:.2} m",
            polygon.area(),
            core::f64::consts::PI * grown * grown
        );
        assert!(farthest < 1.0, "{farthest}");
        // Hazard cells away from the rock are rare single points (dropped as too small).
        let frame = map.grid;
        let mut far = 0;
        for i in 0..GRID_ROWS {
            for j in 0..GRID_COLS {
                if run.mapper.grid().class(i, j) == CellClass::Hazard {
                    let p = frame.to_world_xy(cell_centre(i, j));
                    let d = (p[0] - centre[0]).hypot(p[1] - centre[1]);
                    if d > 0.45 {
                        far += 1;
                        let count = run.mapper.grid().cell(i, j).unwrap().count;
                        println!("  hazard cell ({i}, {j}) {d:.2} m from the rock, {count} points");
                    }
                }
            }
        }
        assert!(
            far <= 2 && far <= usize::from(map.counts.small_dropped),
            "{far}"
        );
    }
}

/// PERC-3: a box 0.4 x 0.3 m, 0.25 m tall, 1.6-2.0 m ahead and to the left of a rover heading
/// 30 deg: one obstacle containing the box's corners grown by the half-width.
#[test]
fn perc_3_box_is_one_grown_polygon() {
    // World frame aligned with the rover for the scene; the rover turned by 0 here, then the
    // same in a second run at yaw 90 deg (the box turned with it).
    for yaw in [0.0f64, 90.0] {
        let pose = level_rover(yaw, 0.0, 0.0);
        let (s, c) = yaw.to_radians().sin_cos();
        let turn = |p: [f64; 2]| [c * p[0] - s * p[1], s * p[0] + c * p[1]];
        let (lo, hi) = ([1.6, -0.5], [2.0, -0.2]);
        let corners = [lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]].map(turn);
        let (min, max) = (
            [
                corners.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min),
                corners.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min),
            ],
            [
                corners
                    .iter()
                    .map(|p| p[0])
                    .fold(f64::NEG_INFINITY, f64::max),
                corners
                    .iter()
                    .map(|p| p[1])
                    .fold(f64::NEG_INFINITY, f64::max),
            ],
        );
        let scene = Scene {
            ramp: None,
            solids: vec![Solid::Block {
                min,
                max,
                height: 0.25,
            }],
        };
        let run = map_scene(&scene, &pose);
        print_map("PERC-3 box", &run);
        assert_eq!(run.result, Ok(()));
        let map = run.map();
        assert_eq!(map.obstacles.len(), 1);
        let polygon = &map.obstacles[0];
        assert!(polygon.is_convex_ccw());
        for corner in corners {
            for k in 0..24 {
                let (s, c) = (k as f64 * 15f64.to_radians()).sin_cos();
                let p = [
                    corner[0] + ROVER_HALF_WIDTH_M * c,
                    corner[1] + ROVER_HALF_WIDTH_M * s,
                ];
                assert!(polygon.contains(p), "{p:?} not in the obstacle");
            }
        }
        let box_area = (max[0] - min[0]) * (max[1] - min[1]);
        println!(
            "  box {box_area:.2} m^2, obstacle {:.2} m^2",
            polygon.area()
        );
        assert!(polygon.area() < 3.0, "{}", polygon.area());
    }
}

/// The scene of PERC-4: level ground, then a ramp of `slope_deg` rising from 1.4 m ahead.
fn ramp_scene(slope_deg: f64) -> Scene {
    Scene {
        ramp: Some((1.4, slope_deg.to_radians())),
        solids: vec![],
    }
}

/// PERC-4: a 30 deg ramp is a hazard by slope (the plane-fit slope of its cells is within 3 deg
/// of 30 deg), the level ground before it stays traversable; 10 and 15 deg ramps are
/// traversable.
#[test]
fn perc_4_slope_30_deg_is_a_hazard_by_slope() {
    let pose = level_rover(0.0, 0.0, 0.0);
    let limits = HazardLimits::default();
    for slope in [30.0, 15.0, 10.0] {
        let run = map_scene(&ramp_scene(slope), &pose);
        print_map(&format!("PERC-4 ramp {slope} deg"), &run);
        for row in class_map(&run).iter().take(20) {
            println!("  {row}");
        }
        assert_eq!(run.result, Ok(()));
        let map = run.map();
        let frame = map.grid;
        let (mut on_ramp, mut ramp_hazard, mut slopes) = (0, 0, Vec::new());
        for i in 0..GRID_ROWS {
            for j in 0..GRID_COLS {
                let class = run.mapper.grid().class(i, j);
                let [x, _] = frame.to_world_xy(cell_centre(i, j));
                if class == CellClass::Unknown {
                    continue;
                }
                if x < 1.4 - 0.3 {
                    assert_eq!(class, CellClass::Traversable, "level cell ({i}, {j})");
                } else if x > 1.4 + 0.3 {
                    on_ramp += 1;
                    ramp_hazard += usize::from(class == CellClass::Hazard);
                    let m = run.mapper.grid().metrics(i, j, &limits).unwrap();
                    slopes.push(m.slope_rad.to_degrees());
                }
            }
        }
        let mean = slopes.iter().sum::<f64>() / slopes.len().max(1) as f64;
        let worst = slopes.iter().map(|s| (s - slope).abs()).fold(0.0, f64::max);
        println!("  ramp cells {on_ramp}, hazard {ramp_hazard}, slope mean {mean:.1} deg, worst error {worst:.1} deg");
        assert!(on_ramp >= 20, "{on_ramp}");
        assert!(worst < 3.0, "{worst}");
        if slope > 20.0 {
            assert_eq!(ramp_hazard, on_ramp);
            assert!(!map.obstacles.is_empty());
        } else {
            assert_eq!(ramp_hazard, 0);
            assert!(map.obstacles.is_empty());
        }
    }
}

/// PERC-5: a rover standing on a 10 deg slope, pitched up with it: the prior follows the
/// contact plane, the slope is traversable, heights within a few cm.
#[test]
fn perc_5_rover_on_a_slope() {
    let slope = 10f64;
    // The ramp starts 5 m behind the rover; the ground at the rover is (5 m) tan 10 deg high.
    let scene = Scene {
        ramp: Some((-5.0, slope.to_radians())),
        solids: vec![],
    };
    let ground_z = -scene.height(0.0, 0.0);
    let pose = rover_camera(0.0, slope, 0.0, 0.0, ground_z);
    let run = map_scene(&scene, &pose);
    print_map("PERC-5 on a 10 deg slope", &run);
    assert_eq!(run.result, Ok(()));
    let map = run.map();
    assert!(map.obstacles.is_empty());
    assert_eq!(map.counts.cells_hazard, 0);
    assert!(map.counts.matched > 250);
    for (start, cells, rms, max) in height_errors(&run, &scene) {
        println!(
            "  range {start:.1} m: {cells} cells, rms {:.1} mm, max {:.1} mm",
            rms * 1e3,
            max * 1e3
        );
        assert!(
            rms < 0.015 && max < 0.04,
            "band {start}: rms {rms}, max {max}"
        );
    }
}

/// The scene of PERC-6: blocks 0.2 m wide and 0.15 m tall on a staggered lattice (0.5 m by
/// 0.5 m) inside the footprint of the level rover at the origin heading north.
fn blocks_scene() -> Scene {
    let mut solids = Vec::new();
    for (a, x) in [0.7f64, 1.2, 1.7, 2.2, 2.7].into_iter().enumerate() {
        let half_width = (x + 0.7) * 0.55 - 0.1;
        for b in -4..=4 {
            let y = 0.5 * b as f64 + 0.25 * (a % 2) as f64;
            if y.abs() <= half_width {
                solids.push(Solid::Block {
                    min: [x - 0.1, y - 0.1],
                    max: [x + 0.1, y + 0.1],
                    height: 0.15,
                });
            }
        }
    }
    Scene { ramp: None, solids }
}

/// PERC-6: more separate obstacles than the map keeps (`max_obstacles` = 8 here, 16 at most):
/// the nearest are kept, the others counted as dropped, and the wedge's range is cut before the
/// nearest dropped one, so no dropped obstacle lies in the reported wedge.
#[test]
fn perc_6_too_many_obstacles_are_dropped_and_the_wedge_cut() {
    let pose = level_rover(0.0, 0.0, 0.0);
    let scene = blocks_scene();
    let (left, right) = render(&scene, &pose, &crate::vo::rocky8_hazcam());
    let config = PerceptionConfig {
        max_obstacles: 8,
        ..PerceptionConfig::default()
    };
    let run = map_images(&left, &right, &pose, config);
    print_map("PERC-6 many rocks", &run);
    for row in class_map(&run).iter().take(34) {
        println!("  {row}");
    }
    assert_eq!(run.result, Ok(()));
    let map = run.map();
    assert_eq!(map.obstacles.len(), 8);
    assert!(map.counts.obstacles_dropped > 0);
    let apex = map.wedge.apex_m;
    let kept_max = map
        .obstacles
        .iter()
        .map(|o| o.distance(apex))
        .fold(0.0, f64::max);
    println!(
        "  dropped {}, wedge cut at {:.2} m, farthest kept obstacle {kept_max:.2} m",
        map.counts.obstacles_dropped, map.wedge.max_range_m
    );
    assert!(map.wedge.max_range_m < 2.5);
    // Every block is either inside a kept obstacle or outside the wedge.
    for s in &scene.solids {
        let Solid::Block { min, max, .. } = *s else {
            continue;
        };
        let centre = [(min[0] + max[0]) / 2.0, (min[1] + max[1]) / 2.0];
        let covered = map.obstacles.iter().any(|o| o.contains(centre));
        let near = (centre[0] - apex[0]).hypot(centre[1] - apex[1]);
        assert!(
            covered || !map.wedge.contains(centre) || near > map.wedge.max_range_m,
            "block at {centre:?} neither an obstacle nor outside the wedge"
        );
    }
}

/// PERC-7: bad inputs are errors, never fake obstacles.
#[test]
fn perc_7_bad_inputs_are_errors() {
    let pose = level_rover(0.0, 0.0, 0.0);
    let blank = vec![128u8; IMAGE_PIXELS];
    let run = map_images(&blank, &blank, &pose, PerceptionConfig::default());
    assert_eq!(run.result, Err(PerceptionError::BlankImage));
    assert!(run.mapper.map().is_none());
    let white = vec![255u8; IMAGE_PIXELS];
    let black = vec![0u8; IMAGE_PIXELS];
    let run = map_images(&white, &black, &pose, PerceptionConfig::default());
    assert!(matches!(
        run.result,
        Err(PerceptionError::BlankImage | PerceptionError::SaturatedImage)
    ));
    // Contrast but no texture along the rows (a vertical ramp): every match is ambiguous.
    let ramp: Vec<u8> = (0..IMAGE_PIXELS)
        .map(|k| (40 + (k / rover_hal::IMAGE_WIDTH_PX) * 160 / 480) as u8)
        .collect();
    let run = map_images(&ramp, &ramp, &pose, PerceptionConfig::default());
    println!("PERC-7 textureless: {:?}", run.result);
    assert!(matches!(
        run.result,
        Err(PerceptionError::TooFewPoints { .. })
    ));
    // Poses.
    let (left, right) = render(&Scene::default(), &pose, &crate::vo::rocky8_hazcam());
    let mut bad = pose;
    bad.position_world_m.x = f64::NAN;
    let run = map_images(&left, &right, &bad, PerceptionConfig::default());
    assert_eq!(run.result, Err(PerceptionError::InvalidPose));
    let mut bad = pose;
    bad.rot_world_from_camera[(0, 0)] = f64::NAN;
    let run = map_images(&left, &right, &bad, PerceptionConfig::default());
    assert_eq!(run.result, Err(PerceptionError::InvalidPose));
    let mut bad = pose;
    bad.rot_world_from_camera *= 1.1;
    let run = map_images(&left, &right, &bad, PerceptionConfig::default());
    assert_eq!(run.result, Err(PerceptionError::InvalidPose));
    let steep = rover_camera(0.0, 70.0, 0.0, 0.0, 0.0);
    let run = map_images(&left, &right, &steep, PerceptionConfig::default());
    assert_eq!(run.result, Err(PerceptionError::PoseOutOfRange));
    let run = map_images(&left[1..], &right, &pose, PerceptionConfig::default());
    assert_eq!(run.result, Err(PerceptionError::WrongImageSize));
    // Configuration and calibration.
    let cal = crate::vo::rocky8_hazcam();
    let config = PerceptionConfig {
        max_height_sigma_m: f64::NAN,
        ..PerceptionConfig::default()
    };
    assert!(HazardMapper::new(config, &cal).is_err());
    let config = PerceptionConfig {
        limits: HazardLimits {
            max_step_m: 0.5,
            ..HazardLimits::default()
        },
        ..PerceptionConfig::default()
    };
    assert_eq!(
        HazardMapper::new(config, &cal).err(),
        Some(PerceptionError::InvalidConfig)
    );
    let mut bad_cal = cal;
    bad_cal.baseline_m = 0.0;
    assert_eq!(
        HazardMapper::new(PerceptionConfig::default(), &bad_cal).err(),
        Some(PerceptionError::InvalidCalibration)
    );
}

/// PERC-11: the map built in slices of a work budget equals the map built at once; the frame
/// must not change; the memory of the mapper and the map.
#[test]
fn perc_11_resumable_and_memory() {
    let pose = level_rover(0.0, 0.0, 0.0);
    let (scene, _) = rock_scene(0.0, 0.0, 0.0);
    let (left, right) = render(&scene, &pose, &crate::vo::rocky8_hazcam());
    let whole = map_images(&left, &right, &pose, PerceptionConfig::default());
    let cal = crate::vo::rocky8_hazcam();
    let mut mapper = Box::new(HazardMapper::new(PerceptionConfig::default(), &cal).unwrap());
    let frame = StereoFrame {
        left: &left,
        right: &right,
        capture_t_us: 7,
        sequence: 3,
    };
    assert_eq!(
        mapper.step(&frame, 10),
        MapProgress::Finished(Err(PerceptionError::NotStarted))
    );
    mapper.start(&frame, &pose).unwrap();
    assert_eq!(mapper.start(&frame, &pose), Err(PerceptionError::Busy));
    let mut slices = 0;
    let result = loop {
        slices += 1;
        assert!(slices < 1000);
        if let MapProgress::Finished(r) = mapper.step(&frame, 100) {
            break r;
        }
    };
    assert_eq!(result, Ok(()));
    let sliced = mapper.map().unwrap();
    let mut expected = whole.map().clone();
    expected.capture_t_us = 7;
    expected.counts.work_items = sliced.counts.work_items;
    assert_eq!(*sliced, expected);
    println!(
        "PERC-11 {} work items in {slices} slices of 100 units",
        sliced.counts.work_items
    );
    // A changed frame abandons the map.
    mapper.start(&frame, &pose).unwrap();
    let other = StereoFrame {
        sequence: 4,
        ..frame
    };
    assert_eq!(
        mapper.step(&other, 10),
        MapProgress::Finished(Err(PerceptionError::FrameChanged))
    );
    assert!(!mapper.is_busy());
    let sizes = (
        core::mem::size_of::<HazardMapper>(),
        core::mem::size_of::<TerrainGrid>(),
        core::mem::size_of::<HazardMap>(),
        core::mem::size_of::<ConvexPolygon>(),
    );
    println!(
        "PERC-11 memory: mapper {} B (grid {} B), map {} B, polygon {} B",
        sizes.0, sizes.1, sizes.2, sizes.3
    );
    assert!(sizes.0 < 40 * 1024);
}

/// Writes the rendered pairs of the test scenes to `$PERC_DUMP` (for measuring the mapper on
/// the rover-CPU model).
#[test]
#[ignore]
fn perc_dump_scenes() {
    let Ok(dir) = std::env::var("PERC_DUMP") else {
        return;
    };
    let pose = level_rover(0.0, 0.0, 0.0);
    let scenes = [
        ("flat", Scene::default()),
        ("rock", rock_scene(0.0, 0.0, 0.0).0),
        ("ramp30", ramp_scene(30.0)),
        ("blocks", blocks_scene()),
    ];
    for (name, scene) in scenes {
        let (l, r) = render(&scene, &pose, &crate::vo::rocky8_hazcam());
        std::fs::write(format!("{dir}/{name}_left.raw"), &l).unwrap();
        std::fs::write(format!("{dir}/{name}_right.raw"), &r).unwrap();
    }
}

/// PERC-12: the step threshold (0.10 m) in both directions, and an obstacle taller than the
/// disparity window (0.45 m above the prior): 0.4 m wide boxes of 0.12 m and 0.6 m at 2 m are
/// obstacles, a box of 0.07 m and a dome of 0.08 m are not.
#[test]
fn perc_12_detection_limits() {
    let pose = level_rover(0.0, 0.0, 0.0);
    let block = |height: f64| Solid::Block {
        min: [1.8, 0.1],
        max: [2.2, 0.5],
        height,
    };
    let cases = [
        ("box 0.12 m", block(0.12), true),
        ("box 0.60 m", block(0.6), true),
        ("box 0.07 m", block(0.07), false),
        (
            "dome 0.08 m",
            Solid::Hemisphere {
                centre: [2.0, 0.3],
                radius: 0.08,
            },
            false,
        ),
    ];
    for (name, solid, obstacle) in cases {
        let scene = Scene {
            ramp: None,
            solids: vec![solid],
        };
        let run = map_scene(&scene, &pose);
        assert_eq!(run.result, Ok(()));
        let map = run.map();
        println!(
            "PERC-12 {name}: {} hazard cells, {} obstacles",
            map.counts.cells_hazard,
            map.obstacles.len()
        );
        assert_eq!(map.obstacles.len(), usize::from(obstacle), "{name}");
        if obstacle {
            assert!(map.obstacles[0].contains([2.0, 0.3]), "{name}");
        }
    }
}

#[test]
fn perc_in_place_init_equals_new() {
    let cal = crate::vo::rocky8_hazcam();
    let config = PerceptionConfig::default();
    let fresh = Box::new(HazardMapper::new(config, &cal).unwrap());
    // A mapper that made a map, initialised in place, is the new one.
    let (scene, _) = rock_scene(0.0, 0.0, 0.0);
    let mut run = map_scene(&scene, &level_rover(0.0, 0.0, 0.0));
    assert!(run.result.is_ok());
    assert_ne!(format!("{:?}", run.mapper), format!("{fresh:?}"));
    run.mapper.init(config, &cal).unwrap();
    assert_eq!(format!("{:?}", run.mapper), format!("{fresh:?}"));
    let bad = PerceptionConfig {
        max_wedge_range_m: f64::NAN,
        ..config
    };
    assert!(run.mapper.init(bad, &cal).is_err());
    assert_eq!(format!("{:?}", run.mapper), format!("{fresh:?}"));
}
