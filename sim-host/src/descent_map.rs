//! The uplinked global map for terrain-map localization (V99 sec. 5, `fsw::localization`):
//! the rocks and blocks a descent or orbital image shows, as occupied world points, made from
//! the simulator's own terrain truth with the image's resolution and errors.
//!
//! Model (each figure an input, the defaults cited):
//! - **Pixel scale** `pixel_m`: the ground sample distance. MSL's Mars Descent Imager (MARDI)
//!   took 1600 x 1200 images from 3.7 km (about 2.5 m/pixel) down to 5 m (0.33 cm/pixel)
//!   (Malin Space Science Systems, "MSL MARDI instrument description"): about 0.68 mrad per
//!   pixel, so [`DescentImage::mardi`] at 150 m gives 0.10 m/pixel over a 163 x 122 m frame.
//!   HiRISE gives 0.25-0.32 m/pixel (McEwen et al. 2007, JGR 112, E05S02),
//!   [`DescentImage::hirise`].
//! - **Detection**: a rock or block is mapped when its footprint is at least
//!   `min_detect_px` pixels across and it stands at least `min_height_m` high (what the rover's
//!   hazard grid flags: its step limit is 0.10 m, `docs/perception.md`). Golombek et al. 2008
//!   (JGR 113, E00A09) count HiRISE rocks from about 1.5 m diameter (5-6 pixels, from their
//!   shadows); the MARDI default takes 3 pixels.
//! - **Outline**: the pixels whose centres lie where the rock's cap `h (1 - (d/r)^2)^2` rises
//!   above `outline_height_m` (a block: its rectangle); a detected rock smaller than a pixel
//!   keeps its centre pixel.
//! - **Errors**: each feature's outline is displaced by its own centroiding error
//!   (`feature_sigma_px`, per axis), and the whole map by the map-tie error between the image
//!   and the rover's world frame `W` (`tie_sigma_m` per axis, `tie_rotation_sigma_rad` about
//!   the map centre). The tie defaults (one pixel, 0.2 deg) are assumptions: the rover's start
//!   is found in the image to about a pixel; no published figure in our sources.

use crate::terrain::{Obstacle, Terrain};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// MARDI's angular pixel scale, rad: 2.5 m/pixel from 3.7 km (MSSS instrument description).
pub const MARDI_IFOV_RAD: f64 = 2.5 / 3700.0;

/// The image the global map is made from, and its errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DescentImage {
    /// Ground sample distance, m/pixel.
    pub pixel_m: f64,
    /// Smallest footprint diameter detected, pixels.
    pub min_detect_px: f64,
    /// Lowest feature mapped, m.
    pub min_height_m: f64,
    /// Height above the base terrain where a rock's outline is drawn, m.
    pub outline_height_m: f64,
    /// Per-feature centroiding error, pixels (1-sigma per axis).
    pub feature_sigma_px: f64,
    /// Map-tie translation error, m (1-sigma per axis).
    pub tie_sigma_m: f64,
    /// Map-tie rotation error about the map centre, rad (1-sigma).
    pub tie_rotation_sigma_rad: f64,
}

impl DescentImage {
    /// A MARDI frame taken from `altitude_m` (pixel = [`MARDI_IFOV_RAD`] x altitude),
    /// 3-pixel detection, rocks from 0.10 m high, outline at 0.05 m, half a pixel of
    /// centroiding error, one pixel and 0.2 deg of map tie.
    pub fn mardi(altitude_m: f64) -> Self {
        let pixel_m = MARDI_IFOV_RAD * altitude_m;
        Self {
            pixel_m,
            min_detect_px: 3.0,
            min_height_m: 0.10,
            outline_height_m: 0.05,
            feature_sigma_px: 0.5,
            tie_sigma_m: pixel_m,
            tie_rotation_sigma_rad: 0.2_f64.to_radians(),
        }
    }

    /// A HiRISE orthoimage: 0.25 m/pixel (McEwen et al. 2007), rocks from 1.5 m diameter
    /// (6 pixels, Golombek et al. 2008), half a pixel of centroiding error, one pixel and
    /// 0.2 deg of map tie.
    pub fn hirise() -> Self {
        Self {
            pixel_m: 0.25,
            min_detect_px: 6.0,
            min_height_m: 0.10,
            outline_height_m: 0.05,
            feature_sigma_px: 0.5,
            tie_sigma_m: 0.25,
            tie_rotation_sigma_rad: 0.2_f64.to_radians(),
        }
    }
}

/// The uplinked map: occupied world points (`[x north, y east]`, m, as the ground believes
/// them: with the errors) and what was mapped.
#[derive(Debug, Clone, PartialEq)]
pub struct DescentMap {
    /// Occupied points, one per outline pixel, m (`W`).
    pub points: Vec<[f64; 2]>,
    /// Features mapped.
    pub features_mapped: usize,
    /// Features inside the area but too small or too low to be mapped.
    pub features_missed: usize,
    /// The map-tie translation drawn, m.
    pub tie_offset_m: [f64; 2],
    /// The map-tie rotation drawn, rad.
    pub tie_rotation_rad: f64,
}

/// One feature's outline: a disc where the cap rises above the outline height, or a
/// rectangle.
enum Outline {
    Disc {
        c: [f64; 2],
        r: f64,
    },
    Rect {
        c: [f64; 2],
        half: [f64; 2],
        yaw: f64,
    },
}

impl Outline {
    fn centre(&self) -> [f64; 2] {
        match *self {
            Outline::Disc { c, .. } | Outline::Rect { c, .. } => c,
        }
    }

    /// Radius of a disc containing the outline, m.
    fn reach(&self) -> f64 {
        match *self {
            Outline::Disc { r, .. } => r,
            Outline::Rect { half, .. } => half[0].hypot(half[1]),
        }
    }

    fn contains(&self, p: [f64; 2]) -> bool {
        match *self {
            Outline::Disc { c, r } => (p[0] - c[0]).hypot(p[1] - c[1]) <= r,
            Outline::Rect { c, half, yaw } => {
                let (s, co) = yaw.sin_cos();
                let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
                (dx * co + dy * s).abs() <= half[0] && (-dx * s + dy * co).abs() <= half[1]
            }
        }
    }
}

/// The rocks and blocks of `terrain` as outlines at the height `image` outlines them (a rock's
/// cap where it rises above `outline_height_m`), with their heights.
fn mapped_features(terrain: &Terrain, image: &DescentImage) -> Vec<(Outline, f64)> {
    let mut features: Vec<(Outline, f64)> = Vec::new();
    let cap_radius =
        |r: f64, h: f64| r * (1.0 - (image.outline_height_m / h).sqrt()).max(0.0).sqrt();
    for r in terrain.rocks() {
        features.push((
            Outline::Disc {
                c: [r.x_m, r.y_m],
                r: cap_radius(r.radius_m, r.height_m),
            },
            r.height_m,
        ));
    }
    for o in &terrain.spec().obstacles {
        match *o {
            Obstacle::Rock {
                x_m,
                y_m,
                radius_m,
                height_m,
            } => features.push((
                Outline::Disc {
                    c: [x_m, y_m],
                    r: cap_radius(radius_m, height_m),
                },
                height_m,
            )),
            Obstacle::Block {
                x_m,
                y_m,
                length_m,
                width_m,
                height_m,
                yaw_deg,
            } => features.push((
                Outline::Rect {
                    c: [x_m, y_m],
                    half: [0.5 * length_m, 0.5 * width_m],
                    yaw: yaw_deg.to_radians(),
                },
                height_m,
            )),
        }
    }
    features
}

/// The pixel centres (corner of the pixel grid of `px` at `centre_m`) inside `outline`; its
/// centre when no pixel centre is.
fn outline_pixels(outline: &Outline, centre_m: [f64; 2], px: f64) -> Vec<[f64; 2]> {
    let c = outline.centre();
    let reach = outline.reach();
    let lo = |v: f64, o: f64| ((v - reach - o) / px).floor() as i64;
    let hi = |v: f64, o: f64| ((v + reach - o) / px).ceil() as i64;
    let mut own = Vec::new();
    for a in lo(c[0], centre_m[0])..=hi(c[0], centre_m[0]) {
        for b in lo(c[1], centre_m[1])..=hi(c[1], centre_m[1]) {
            let p = [
                centre_m[0] + (a as f64 + 0.5) * px,
                centre_m[1] + (b as f64 + 0.5) * px,
            ];
            if outline.contains(p) {
                own.push(p);
            }
        }
    }
    if own.is_empty() {
        own.push(c);
    }
    own
}

/// The global map of `terrain`'s rocks and blocks inside the square of side `side_m`
/// centred on `centre_m` (north, east, m) as `image` shows them, with its errors drawn from
/// `seed`. The pixel grid is aligned with `W` and has a corner at `centre_m`.
pub fn descent_map(
    terrain: &Terrain,
    image: &DescentImage,
    centre_m: [f64; 2],
    side_m: f64,
    seed: u64,
) -> DescentMap {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xDE5C_E27A);
    let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
    let tie_offset_m = [image.tie_sigma_m * normal(), image.tie_sigma_m * normal()];
    let tie_rotation_rad = image.tie_rotation_sigma_rad * normal();
    let features = mapped_features(terrain, image);
    let half_side = 0.5 * side_m;
    let inside = |p: [f64; 2]| {
        (p[0] - centre_m[0]).abs() <= half_side && (p[1] - centre_m[1]).abs() <= half_side
    };
    let px = image.pixel_m;
    let (mut points, mut mapped, mut missed) = (Vec::new(), 0, 0);
    let (st, ct) = tie_rotation_rad.sin_cos();
    for (outline, height) in &features {
        let c = outline.centre();
        if !inside(c) {
            continue;
        }
        let diameter = match outline {
            Outline::Disc { r, .. } => 2.0 * r,
            Outline::Rect { half, .. } => 2.0 * half[0].min(half[1]),
        };
        if *height < image.min_height_m || diameter < image.min_detect_px * px {
            missed += 1;
            continue;
        }
        mapped += 1;
        let err = [
            image.feature_sigma_px * px * normal(),
            image.feature_sigma_px * px * normal(),
        ];
        let own = outline_pixels(outline, centre_m, px);
        for p in own {
            // Feature error, then the map tie about the map centre.
            let q = [p[0] + err[0] - centre_m[0], p[1] + err[1] - centre_m[1]];
            points.push([
                centre_m[0] + ct * q[0] - st * q[1] + tie_offset_m[0],
                centre_m[1] + st * q[0] + ct * q[1] + tie_offset_m[1],
            ]);
        }
    }
    DescentMap {
        points,
        features_mapped: mapped,
        features_missed: missed,
        tie_offset_m,
        tie_rotation_rad,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::{BaseShape, TerrainSpec};

    fn terrain(obstacles: Vec<Obstacle>) -> Terrain {
        let spec = TerrainSpec {
            base: BaseShape::Flat,
            roughness_m: 0.0,
            roughness_wavelength_m: 1.0,
            rocks: None,
            obstacles,
        };
        Terrain::new(spec, 1, &[])
    }

    fn rock(x_m: f64, y_m: f64, radius_m: f64, height_m: f64) -> Obstacle {
        Obstacle::Rock {
            x_m,
            y_m,
            radius_m,
            height_m,
        }
    }

    /// SIM-LOC-1: the mapped rocks are where the truth has them (within the errors), the
    /// small and low ones are missed, and the map localizes in `fsw`'s global map.
    #[test]
    fn descent_map_holds_the_detectable_rocks() {
        let t = terrain(vec![
            rock(3.0, 1.0, 0.5, 0.25),
            rock(-4.0, 2.0, 0.4, 0.20),
            rock(1.0, -5.0, 0.05, 0.2),  // 0.1 m across: below 3 pixels
            rock(-2.0, -2.0, 0.6, 0.05), // too low
            Obstacle::Block {
                x_m: 6.0,
                y_m: -3.0,
                length_m: 1.0,
                width_m: 0.5,
                height_m: 0.3,
                yaw_deg: 30.0,
            },
        ]);
        let image = DescentImage::mardi(150.0);
        assert!((image.pixel_m - 0.1014).abs() < 1e-3);
        let map = descent_map(&t, &image, [0.0, 0.0], 30.0, 7);
        assert_eq!(map.features_mapped, 3);
        assert_eq!(map.features_missed, 2);
        // Same seed, same map; another seed, other errors.
        assert_eq!(map, descent_map(&t, &image, [0.0, 0.0], 30.0, 7));
        assert_ne!(
            map.points,
            descent_map(&t, &image, [0.0, 0.0], 30.0, 8).points
        );
        // Every point lies near a mapped feature (outline + 4 sigma of the errors).
        let tol = 4.0 * (image.feature_sigma_px * image.pixel_m + image.tie_sigma_m) + 0.2;
        let centres = [[3.0, 1.0], [-4.0, 2.0], [6.0, -3.0]];
        for p in &map.points {
            let near = centres
                .iter()
                .any(|c| (p[0] - c[0]).hypot(p[1] - c[1]) < 0.6 + tol);
            assert!(near, "{p:?}");
        }
        // The first rock's outline: r sqrt(1 - sqrt(0.05 / 0.25)) = 0.37 m, about 42 pixels.
        let first = map
            .points
            .iter()
            .filter(|p| (p[0] - 3.0).hypot(p[1] - 1.0) < 0.8)
            .count();
        assert!((30..=55).contains(&first), "{first}");
        // Into the flight global map: the rock centre is occupied or next to it.
        let mut g = fsw::localization::GlobalMap::new();
        assert!(g.reset_centred([0.0, 0.0]));
        assert_eq!(g.insert_points(&map.points), map.points.len());
        g.finish();
        let (i, j) = g.cell_of([3.0, 1.0]).unwrap();
        assert!(g.d2_at(i as i32, j as i32) <= 2);
    }

    /// The map-tie error has the configured spread over seeds.
    #[test]
    fn tie_error_statistics() {
        let t = terrain(vec![rock(0.0, 0.0, 0.5, 0.25)]);
        let image = DescentImage::hirise();
        let n = 400;
        let mut sum2 = 0.0;
        for seed in 0..n {
            let m = descent_map(&t, &image, [0.0, 0.0], 20.0, seed);
            sum2 += m.tie_offset_m[0].powi(2) + m.tie_offset_m[1].powi(2);
            // HiRISE misses a 0.75 m rock (below 6 pixels of 0.25 m).
            assert_eq!(m.features_mapped, 0);
        }
        let rms = (sum2 / (2.0 * n as f64)).sqrt();
        assert!(
            (rms - image.tie_sigma_m).abs() < 0.15 * image.tie_sigma_m,
            "{rms}"
        );
    }

    /// Summary of localizations along a scenario path.
    #[derive(Debug)]
    struct PathRun {
        stops: usize,
        fixes: usize,
        rms: [f64; 3],
        max_nodes: u32,
        max_points: usize,
        failures: Vec<fsw::localization::LocalizationError>,
        mapped: usize,
    }

    /// Along the path of `scenario` (its truth rocks), every `spacing_m`: a panorama of 8
    /// hazcam views turned in place (45 deg apart), each an ideal hazard grid (cells where a
    /// rock rises more than 0.05 m, inside the hazcam wedge), merged into one local scan
    /// ([`fsw::localization::LocalScan::append_grid`]) and matched against the MARDI map from
    /// 150 m; prior errors 0.3 m and 0.02 rad.
    fn path_run(scenario: &crate::scenario::Scenario, spacing_m: f64) -> PathRun {
        use fsw::localization::{GlobalMap, LocalScan, Localizer, LocalizerConfig};
        use fsw::perception::grid::cell_centre;
        use fsw::perception::{CellClass, GridFrame, TerrainGrid, GRID_COLS, GRID_ROWS};
        let sc = scenario;
        let t = Terrain::new(
            sc.terrain.clone(),
            sc.terrain_seed.unwrap_or(sc.seed),
            &sc.waypoints,
        );
        let image = DescentImage {
            min_height_m: 0.05,
            ..DescentImage::mardi(150.0)
        };
        let centre = [5.0, 5.0];
        let dm = descent_map(&t, &image, centre, 36.0, sc.seed);
        let mut g = GlobalMap::new();
        assert!(g.reset_centred(centre));
        g.insert_points(&dm.points);
        g.finish();
        let mut loc = Localizer::new(LocalizerConfig::default()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
        let tan = 35f64.to_radians().tan();
        let grid_at = |truth: &GridFrame| {
            let mut grid = TerrainGrid::new();
            for i in 0..GRID_ROWS {
                for j in 0..GRID_COLS {
                    let c = cell_centre(i, j);
                    if !(c[0] >= 0.3 && c[0] <= 2.8 && c[1].abs() <= c[0] * tan) {
                        continue;
                    }
                    let p = truth.to_world_xy(c);
                    let high = t.rocks().iter().any(|r| {
                        let d2 = ((p[0] - r.x_m).powi(2) + (p[1] - r.y_m).powi(2))
                            / (r.radius_m * r.radius_m);
                        d2 < 1.0 && r.height_m * (1.0 - d2).powi(2) > 0.05
                    });
                    if high {
                        grid.set_class(i, j, CellClass::Hazard);
                    }
                }
            }
            grid
        };
        let mut run = PathRun {
            stops: 0,
            fixes: 0,
            rms: [0.0; 3],
            max_nodes: 0,
            max_points: 0,
            failures: Vec::new(),
            mapped: dm.features_mapped,
        };
        for w in sc.waypoints.windows(2) {
            let d = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            let heading = (w[1][1] - w[0][1]).atan2(w[1][0] - w[0][0]);
            for k in 0..(d / spacing_m).floor() as usize {
                let f = k as f64 * spacing_m / d;
                let at = [
                    w[0][0] + f * (w[1][0] - w[0][0]),
                    w[0][1] + f * (w[1][1] - w[0][1]),
                ];
                let s = [0.3, 0.3, 0.02];
                let est = [at[0] + s[0] * normal(), at[1] + s[1] * normal()];
                let est_heading = heading + s[2] * normal();
                let truth0 = GridFrame::new([at[0], at[1], 0.0], heading);
                let reference = GridFrame::new([est[0], est[1], 0.0], est_heading);
                let mut scan = LocalScan::new();
                for v in 0..8 {
                    let turn = f64::from(v) * std::f64::consts::FRAC_PI_4;
                    let truth = GridFrame::new([at[0], at[1], 0.0], heading + turn);
                    let frame = GridFrame::new([est[0], est[1], 0.0], est_heading + turn);
                    scan.append_grid(&grid_at(&truth), &frame, &reference, 32);
                }
                run.stops += 1;
                run.max_points = run.max_points.max(scan.len());
                let prior = [est[0], est[1], est_heading];
                let cov = [
                    [s[0] * s[0], 0.0, 0.0],
                    [0.0, s[1] * s[1], 0.0],
                    [0.0, 0.0, s[2] * s[2]],
                ];
                match loc.localize_scan(&g, &scan, prior, cov) {
                    Ok(fix) => {
                        run.fixes += 1;
                        run.max_nodes = run.max_nodes.max(fix.nodes);
                        let e = [
                            fix.pose[0] - truth0.origin_world_m[0],
                            fix.pose[1] - truth0.origin_world_m[1],
                            fix.pose[2] - heading,
                        ];
                        for (a, b) in run.rms.iter_mut().zip(e) {
                            *a += b * b;
                        }
                    }
                    Err(e) => run.failures.push(e),
                }
            }
        }
        let n = run.fixes.max(1) as f64;
        run.rms = run.rms.map(|v| (v / n).sqrt());
        run
    }

    /// SIM-LOC-2: `marsyard-25m` (Golombek & Rapp field of the Viking Lander 2 site, k = 0.17,
    /// kept 0.9 m clear of the path) and a rockier variant (k = 0.4, the dense rock fields
    /// around craters of Golombek et al. 2008; 0.5 m clear): panoramas every 2.5 m matched
    /// against the MARDI map from 150 m. The yard gives a few fixes (measured 4 of 10; every
    /// failure an error value); the rocky one localizes at most stops within the map's own
    /// error (measured 10 of 10).
    #[test]
    fn scenario_paths_localize_against_the_descent_map() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/marsyard-25m.toml");
        let sc = crate::scenario::Scenario::load(&path).unwrap();
        let yard = path_run(&sc, 2.5);
        eprintln!("marsyard-25m: {yard:?}");
        let mut rocky = sc.clone();
        if let Some(field) = rocky.terrain.rocks.as_mut() {
            field.abundance_k = 0.4;
            field.keep_clear_m = 0.5;
        }
        let rocky = path_run(&rocky, 2.5);
        eprintln!("rocky variant: {rocky:?}");
        assert_eq!(yard.stops, 10);
        assert!(
            rocky.mapped > 2 * yard.mapped,
            "{} {}",
            rocky.mapped,
            yard.mapped
        );
        assert!(rocky.fixes >= 7, "{rocky:?}");
        assert!(rocky.rms[0] < 0.25 && rocky.rms[1] < 0.25, "{rocky:?}");
    }
}
