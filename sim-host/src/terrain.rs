//! Terrain height models: flat yard with rocks, planar slopes, rough terrain, dunes, and a step
//! (for tests). All are analytic (no height grid), so heights are exact and cost no memory.
//!
//! World frame `W`: x north, y east, z down (metres). Heights are positive up; the ground point
//! at `(x, y)` is `(x, y, -height_m(x, y))` in `W`.

use crate::surface::TerrainSurface;
use serde::Deserialize;

/// Deterministic lattice hash of an integer cell and a seed, in `[0, 1)`.
fn lattice(ix: i64, iy: i64, seed: u64) -> f64 {
    let mut h = (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// `floor` as an integer without a library call (inputs are terrain coordinates, far inside
/// the `i64` range).
fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i - 1
    } else {
        i
    }
}

/// Smooth value noise in `[-1, 1]` with unit lattice spacing (quintic interpolation, so its
/// gradient is continuous).
pub fn value_noise(x: f64, y: f64, seed: u64) -> f64 {
    let (ix, iy) = (floor_i64(x), floor_i64(y));
    let (fx, fy) = (ix as f64, iy as f64);
    let (tx, ty) = (x - fx, y - fy);
    let s = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (sx, sy) = (s(tx), s(ty));
    let v00 = lattice(ix, iy, seed);
    let v10 = lattice(ix + 1, iy, seed);
    let v01 = lattice(ix, iy + 1, seed);
    let v11 = lattice(ix + 1, iy + 1, seed);
    let a = v00 + (v10 - v00) * sx;
    let b = v01 + (v11 - v01) * sx;
    2.0 * (a + (b - a) * sy) - 1.0
}

/// Fractal sum of `octaves` value-noise layers: wavelengths `wavelength_m / 2^k`, amplitudes
/// `0.5^k` (normalised so the sum stays in `[-1, 1]`).
pub fn fractal_noise(x: f64, y: f64, wavelength_m: f64, octaves: u32, seed: u64) -> f64 {
    let (mut sum, mut norm, mut amp, mut freq) = (0.0, 0.0, 1.0, 1.0 / wavelength_m);
    for k in 0..octaves {
        sum += amp * value_noise(x * freq, y * freq, seed.wrapping_add(u64::from(k) * 7919));
        norm += amp;
        amp *= 0.5;
        freq *= 2.0;
    }
    sum / norm
}

/// The large-scale shape of the ground.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum BaseShape {
    /// Level ground at height 0.
    Flat,
    /// A plane through the origin tilted by `slope_deg`, falling towards the azimuth
    /// `downhill_azimuth_deg` (clockwise from north, so 90 = downhill towards east).
    Plane {
        /// Slope angle, degrees.
        slope_deg: f64,
        /// Azimuth of the downhill direction, degrees clockwise from north.
        downhill_azimuth_deg: f64,
    },
    /// Dunes: parallel sinusoidal ridges (crests along `crest_azimuth_deg`) of the given
    /// wavelength and amplitude, on top of a regional plane.
    Dunes {
        /// Ridge spacing, m.
        wavelength_m: f64,
        /// Peak-to-mean height, m.
        amplitude_m: f64,
        /// Direction of the crest lines, degrees clockwise from north.
        crest_azimuth_deg: f64,
    },
    /// A step of `height_m` for `x > x_m` (and, if `right_only`, only for `y > 0`).
    Step {
        /// Position of the edge along north, m.
        x_m: f64,
        /// Step height, m (positive up).
        height_m: f64,
        /// Restrict the step to the east half-plane `y > 0`.
        right_only: bool,
    },
}

/// One rock: a smooth cap `h * (1 - (d/r)^2)^2` of radius `r`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rock {
    /// Centre north, m.
    pub x_m: f64,
    /// Centre east, m.
    pub y_m: f64,
    /// Footprint radius, m.
    pub radius_m: f64,
    /// Height above the base, m.
    pub height_m: f64,
}

/// Parameters of a procedural rock field.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct RockField {
    /// Rocks per square metre (the power-law field; ignored with `abundance_k`).
    #[serde(default)]
    pub density_per_m2: f64,
    /// Largest rock height, m (heights are drawn with a power law towards small rocks; ignored
    /// with `abundance_k`).
    #[serde(default)]
    pub max_height_m: f64,
    /// Total fractional area covered by rocks `k` of the Golombek & Rapp (1997) size-frequency
    /// model of the Viking and Pathfinder sites, `F_k(D) = k exp(-q(k) D)`,
    /// `q(k) = 1.79 + 0.152 / k` (cumulative fractional area of rocks of diameter `D` or
    /// larger; Golombek et al. 2003, JGR 108(E12) 8086). Viking Lander 1: 0.07, Viking Lander
    /// 2: 0.16-0.18, Pathfinder: 0.19. When positive, rocks of diameter at least
    /// `min_diameter_m` (up to 3 m) are drawn from it with height half the diameter, and
    /// `density_per_m2` and `max_height_m` are ignored (`docs/simulator.md`). 0 (the
    /// default): the power-law field of `density_per_m2` and `max_height_m`.
    #[serde(default)]
    pub abundance_k: f64,
    /// Smallest rock diameter of the `abundance_k` model, m (default 0.1).
    #[serde(default = "default_min_diameter")]
    pub min_diameter_m: f64,
    /// Half-size of the square area that gets rocks, m (centred on the origin).
    pub half_extent_m: f64,
    /// Disc around each listed point that stays free of rocks (the path), m.
    #[serde(default)]
    pub keep_clear_m: f64,
}

fn default_min_diameter() -> f64 {
    0.1
}

/// Terrain description as it appears in a scenario file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct TerrainSpec {
    /// Large-scale shape.
    pub base: BaseShape,
    /// Amplitude of the rough-terrain noise, m (0 for none).
    #[serde(default)]
    pub roughness_m: f64,
    /// Longest wavelength of the roughness, m.
    #[serde(default = "default_rough_wavelength")]
    pub roughness_wavelength_m: f64,
    /// Optional rock field.
    #[serde(default)]
    pub rocks: Option<RockField>,
    /// Placed obstacles (blocks with vertical faces, rocks), on top of base and roughness.
    #[serde(default)]
    pub obstacles: Vec<Obstacle>,
}

/// A placed obstacle. Where obstacles and the rock field overlap, the highest wins.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Obstacle {
    /// A flat-topped block with vertical faces (a ledge or a slab of bedrock): a rectangle of
    /// `length_m` along `yaw_deg` (clockwise from north) by `width_m`, centred on `(x_m, y_m)`,
    /// `height_m` high. Its edges are steps up and down.
    Block {
        /// Centre north, m.
        x_m: f64,
        /// Centre east, m.
        y_m: f64,
        /// Length along `yaw_deg`, m.
        length_m: f64,
        /// Width across, m.
        width_m: f64,
        /// Height, m.
        height_m: f64,
        /// Orientation of the length, degrees clockwise from north.
        #[serde(default)]
        yaw_deg: f64,
    },
    /// A rock: the smooth cap `h (1 - (d/r)^2)^2` of the rock field, placed by hand.
    Rock {
        /// Centre north, m.
        x_m: f64,
        /// Centre east, m.
        y_m: f64,
        /// Footprint radius, m.
        radius_m: f64,
        /// Height, m.
        height_m: f64,
    },
}

impl Obstacle {
    /// Height of this obstacle at `(x, y)` (0 outside), m.
    pub fn height_m(&self, x: f64, y: f64) -> f64 {
        match *self {
            Obstacle::Block {
                x_m,
                y_m,
                length_m,
                width_m,
                height_m,
                yaw_deg,
            } => {
                let (s, c) = yaw_deg.to_radians().sin_cos();
                let (dx, dy) = (x - x_m, y - y_m);
                let along = dx * c + dy * s;
                let across = -dx * s + dy * c;
                if along.abs() <= 0.5 * length_m && across.abs() <= 0.5 * width_m {
                    height_m
                } else {
                    0.0
                }
            }
            Obstacle::Rock {
                x_m,
                y_m,
                radius_m,
                height_m,
            } => {
                let d2 = ((x - x_m).powi(2) + (y - y_m).powi(2)) / (radius_m * radius_m);
                if d2 < 1.0 {
                    let c = 1.0 - d2;
                    height_m * c * c
                } else {
                    0.0
                }
            }
        }
    }
}

fn default_rough_wavelength() -> f64 {
    2.0
}

/// Cell size of the rock lookup grid, m.
const ROCK_CELL_M: f64 = 1.0;

/// An analytic terrain: base shape plus fractal roughness plus rocks.
#[derive(Debug, Clone)]
pub struct Terrain {
    spec: TerrainSpec,
    seed: u64,
    rocks: Vec<Rock>,
    /// Rock indices per grid cell (row-major), for constant-time lookups.
    cells: Vec<Vec<u32>>,
    grid_origin_m: f64,
    grid_n: usize,
    plane_gradient: [f64; 2],
}

/// The Golombek & Rapp (1997) rock size-frequency model (as written in Golombek et al. 2003,
/// JGR 108(E12) 8086): the cumulative fractional area covered by rocks of diameter `D` or
/// larger is `F_k(D) = k exp(-q D)`, `q = 1.79 + 0.152 / k`, so the number of rocks per m^2 per
/// metre of diameter is `n(D) = -F'(D) / (pi D^2 / 4) = 4 k q exp(-q D) / (pi D^2)`. Rocks
/// between `min_diameter_m` and 3 m are drawn from `n` by its tabulated inverse distribution.
#[derive(Debug, Clone)]
struct GolombekRapp {
    /// Diameters of the table, m.
    d: Vec<f64>,
    /// Cumulative number per m^2 from the smallest diameter up to each `d`.
    cum: Vec<f64>,
}

impl GolombekRapp {
    /// Height over diameter of a rock: about one half at the Viking sites (the ratio of the
    /// MER landing-hazard models built on Golombek & Rapp's height-diameter data, Golombek et
    /// al. 2003).
    const HEIGHT_RATIO: f64 = 0.5;
    const MAX_DIAMETER_M: f64 = 3.0;
    const STEPS: usize = 4000;

    fn new(k: f64, min_diameter_m: f64) -> Self {
        let k = k.clamp(1e-3, 0.9);
        let q = 1.79 + 0.152 / k;
        let d0 = min_diameter_m.clamp(0.01, 1.0);
        let n = |d: f64| 4.0 * k * q * (-q * d).exp() / (std::f64::consts::PI * d * d);
        let h = (Self::MAX_DIAMETER_M - d0) / Self::STEPS as f64;
        let mut d = Vec::with_capacity(Self::STEPS + 1);
        let mut cum = Vec::with_capacity(Self::STEPS + 1);
        let mut acc = 0.0;
        for i in 0..=Self::STEPS {
            let x = d0 + i as f64 * h;
            if i > 0 {
                acc += 0.5 * h * (n(x - h) + n(x));
            }
            d.push(x);
            cum.push(acc);
        }
        Self { d, cum }
    }

    /// Rocks per m^2 between the smallest and the largest diameter.
    fn density_per_m2(&self) -> f64 {
        self.cum.last().copied().unwrap_or(0.0)
    }

    /// The diameter at the fraction `u` (0-1) of the number distribution, m.
    fn diameter(&self, u: f64) -> f64 {
        let target = u.clamp(0.0, 1.0) * self.density_per_m2();
        let i = self
            .cum
            .partition_point(|c| *c < target)
            .clamp(1, self.d.len() - 1);
        let (c0, c1) = (self.cum[i - 1], self.cum[i]);
        let t = if c1 > c0 {
            (target - c0) / (c1 - c0)
        } else {
            0.0
        };
        self.d[i - 1] + t * (self.d[i] - self.d[i - 1])
    }
}

impl Terrain {
    /// Build the terrain of `spec` for `seed`; `clear_path` are points (north, east, m) around
    /// which the rock field keeps `keep_clear_m` free.
    pub fn new(spec: TerrainSpec, seed: u64, clear_path: &[[f64; 2]]) -> Self {
        let plane_gradient = match spec.base {
            BaseShape::Plane {
                slope_deg,
                downhill_azimuth_deg,
            } => {
                let t = slope_deg.to_radians().tan();
                let a = downhill_azimuth_deg.to_radians();
                [-t * a.cos(), -t * a.sin()]
            }
            _ => [0.0, 0.0],
        };
        let mut rocks = Vec::new();
        let (mut grid_origin_m, mut grid_n) = (0.0, 0);
        if let Some(field) = &spec.rocks {
            let half = field.half_extent_m.max(0.0);
            let golombek = (field.abundance_k > 0.0)
                .then(|| GolombekRapp::new(field.abundance_k, field.min_diameter_m));
            let density = golombek
                .as_ref()
                .map_or(field.density_per_m2, |g| g.density_per_m2());
            let count = (density * 4.0 * half * half).round() as u64;
            for k in 0..count {
                let u = |j: i64| lattice(k as i64, j, seed ^ 0x5EED_0F0C);
                let x = (2.0 * u(0) - 1.0) * half;
                let y = (2.0 * u(1) - 1.0) * half;
                let (height, radius) = match &golombek {
                    Some(g) => {
                        let d = g.diameter(u(2));
                        (GolombekRapp::HEIGHT_RATIO * d, 0.5 * d)
                    }
                    None => {
                        // Power law: many small rocks, few large ones.
                        let height = field.max_height_m * u(2).powi(3).max(0.02);
                        (height, height * (1.5 + 1.5 * u(3)))
                    }
                };
                let clear = clear_path.windows(2).all(|w| {
                    point_segment_distance([x, y], w[0], w[1]) > field.keep_clear_m + radius
                });
                if clear {
                    rocks.push(Rock {
                        x_m: x,
                        y_m: y,
                        radius_m: radius,
                        height_m: height,
                    });
                }
            }
            grid_origin_m = -half - 2.0;
            grid_n = ((2.0 * half + 4.0) / ROCK_CELL_M).ceil() as usize;
        }
        let mut cells = vec![Vec::new(); grid_n * grid_n];
        for (i, r) in rocks.iter().enumerate() {
            let lo = |c: f64| ((c - r.radius_m - grid_origin_m) / ROCK_CELL_M).floor();
            let hi = |c: f64| ((c + r.radius_m - grid_origin_m) / ROCK_CELL_M).floor();
            let clamp = |v: f64| (v.max(0.0) as usize).min(grid_n.saturating_sub(1));
            for gx in clamp(lo(r.x_m))..=clamp(hi(r.x_m)) {
                for gy in clamp(lo(r.y_m))..=clamp(hi(r.y_m)) {
                    cells[gx * grid_n + gy].push(i as u32);
                }
            }
        }
        Self {
            spec,
            seed,
            rocks,
            cells,
            grid_origin_m,
            grid_n,
            plane_gradient,
        }
    }

    /// The rocks of this terrain.
    pub fn rocks(&self) -> &[Rock] {
        &self.rocks
    }

    /// The description this terrain was built from.
    pub fn spec(&self) -> &TerrainSpec {
        &self.spec
    }

    fn base_height(&self, x: f64, y: f64) -> f64 {
        match self.spec.base {
            BaseShape::Flat => 0.0,
            BaseShape::Plane { .. } => self.plane_gradient[0] * x + self.plane_gradient[1] * y,
            BaseShape::Dunes {
                wavelength_m,
                amplitude_m,
                crest_azimuth_deg,
            } => {
                // Distance across the crests.
                let a = crest_azimuth_deg.to_radians();
                let across = -x * a.sin() + y * a.cos();
                amplitude_m * (2.0 * std::f64::consts::PI * across / wavelength_m).sin()
            }
            BaseShape::Step {
                x_m,
                height_m,
                right_only,
            } => {
                if x > x_m && (!right_only || y > 0.0) {
                    height_m
                } else {
                    0.0
                }
            }
        }
    }

    fn rock_height(&self, x: f64, y: f64) -> f64 {
        if self.grid_n == 0 {
            return 0.0;
        }
        let gx = ((x - self.grid_origin_m) / ROCK_CELL_M).floor();
        let gy = ((y - self.grid_origin_m) / ROCK_CELL_M).floor();
        let n = self.grid_n as f64;
        if gx < 0.0 || gy < 0.0 || gx >= n || gy >= n {
            return 0.0;
        }
        let cell = &self.cells[gx as usize * self.grid_n + gy as usize];
        let mut h: f64 = 0.0;
        for &i in cell {
            let r = &self.rocks[i as usize];
            let d2 = ((x - r.x_m).powi(2) + (y - r.y_m).powi(2)) / (r.radius_m * r.radius_m);
            if d2 < 1.0 {
                let c = 1.0 - d2;
                h = h.max(r.height_m * c * c);
            }
        }
        h
    }
}

/// Distance from `p` to the segment `a`-`b` (2D), m.
pub fn point_segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    ((p[0] - a[0] - t * dx).powi(2) + (p[1] - a[1] - t * dy).powi(2)).sqrt()
}

impl TerrainSurface for Terrain {
    fn has_edges(&self) -> bool {
        matches!(self.spec.base, BaseShape::Step { .. })
            || self
                .spec
                .obstacles
                .iter()
                .any(|o| matches!(o, Obstacle::Block { .. }))
    }

    fn height_m(&self, x_m: f64, y_m: f64) -> f64 {
        let mut top = self.rock_height(x_m, y_m);
        for o in &self.spec.obstacles {
            top = top.max(o.height_m(x_m, y_m));
        }
        let mut h = self.base_height(x_m, y_m) + top;
        if self.spec.roughness_m > 0.0 {
            h += self.spec.roughness_m
                * fractal_noise(x_m, y_m, self.spec.roughness_wavelength_m, 3, self.seed);
        }
        h
    }

    /// The non-rendering albedo: a deterministic fractal value noise (wavelengths 4 m down to
    /// 0.25 m) around 0.35, darker on rocks. The rendered cameras replace it with their own
    /// texture; this one exists so that every `TerrainSurface` user has a defined albedo.
    fn albedo(&self, x_m: f64, y_m: f64) -> f64 {
        let n = fractal_noise(x_m, y_m, 4.0, 5, self.seed ^ 0x00A1_BED0);
        let rock = if self.rock_height(x_m, y_m) > 0.005 {
            -0.1
        } else {
            0.0
        };
        (0.35 + 0.15 * n + rock).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(slope_deg: f64, az: f64) -> Terrain {
        Terrain::new(
            TerrainSpec {
                base: BaseShape::Plane {
                    slope_deg,
                    downhill_azimuth_deg: az,
                },
                roughness_m: 0.0,
                roughness_wavelength_m: 2.0,
                rocks: None,
                obstacles: Vec::new(),
            },
            1,
            &[],
        )
    }

    /// SIM-1: a planar slope has the stated angle and falls towards the stated azimuth.
    #[test]
    fn sim_1_plane_slope_and_direction() {
        let t = plane(10.0, 90.0);
        // Downhill towards east: height decreases with y.
        let dh = t.height_m(0.0, 1.0) - t.height_m(0.0, 0.0);
        assert!((dh + 10f64.to_radians().tan()).abs() < 1e-12);
        assert!(t.height_m(1.0, 0.0).abs() < 1e-12);
        let n = t.normal_up(0.3, 0.2);
        assert!((n[2] - 10f64.to_radians().cos()).abs() < 1e-9);
        assert!(n[1] > 0.0, "up-normal leans downhill (east)");
    }

    /// SIM-1: noise and rocks are deterministic per seed, bounded, and the rock field keeps
    /// the path clear.
    #[test]
    fn sim_1_rocks_and_noise() {
        for k in 0..1000 {
            let v = value_noise(k as f64 * 0.37, k as f64 * 0.11, 3);
            assert!((-1.0..=1.0).contains(&v));
        }
        let spec = TerrainSpec {
            base: BaseShape::Flat,
            roughness_m: 0.0,
            roughness_wavelength_m: 2.0,
            rocks: Some(RockField {
                density_per_m2: 0.5,
                max_height_m: 0.2,
                half_extent_m: 10.0,
                keep_clear_m: 0.8,
                abundance_k: 0.0,
                min_diameter_m: 0.1,
            }),
            obstacles: Vec::new(),
        };
        let path = [[0.0, 0.0], [8.0, 0.0]];
        let a = Terrain::new(spec.clone(), 5, &path);
        let b = Terrain::new(spec, 5, &path);
        assert!(a.rocks().len() > 50);
        assert_eq!(a.rocks(), b.rocks());
        for k in 0..80 {
            assert_eq!(a.height_m(k as f64 * 0.1, 0.3), 0.0);
        }
        let r = a.rocks()[0];
        assert!((a.height_m(r.x_m, r.y_m) - r.height_m).abs() < 1e-12);
    }

    /// The Golombek & Rapp field reproduces its model: the number of rocks per m^2 of at
    /// least 0.1, 0.3 and 0.5 m diameter (closed-form integral of `n(D)`, 0.1-3 m, for the
    /// Viking Lander 2 abundance k = 0.17) within the Poisson scatter of a 40 m square.
    #[test]
    fn golombek_rapp_field_follows_its_size_frequency_model() {
        let k = 0.17;
        let spec = TerrainSpec {
            base: BaseShape::Flat,
            roughness_m: 0.0,
            roughness_wavelength_m: 2.0,
            rocks: Some(RockField {
                density_per_m2: 0.0,
                max_height_m: 0.0,
                half_extent_m: 20.0,
                keep_clear_m: 0.0,
                abundance_k: k,
                min_diameter_m: 0.1,
            }),
            obstacles: Vec::new(),
        };
        let t = Terrain::new(spec, 3, &[]);
        let area = 1600.0;
        // Reference: Simpson's rule on n(D) = 4 k q exp(-q D) / (pi D^2), independent of the
        // generator's trapezoid table.
        let q = 1.79 + 0.152 / k;
        let n = |d: f64| 4.0 * k * q * (-q * d).exp() / (std::f64::consts::PI * d * d);
        let cumulative = |d0: f64| {
            let m = 20_000;
            let h = (3.0 - d0) / m as f64;
            (0..=m)
                .map(|i| {
                    let w = if i == 0 || i == m {
                        1.0
                    } else if i % 2 == 1 {
                        4.0
                    } else {
                        2.0
                    };
                    w * n(d0 + i as f64 * h)
                })
                .sum::<f64>()
                * h
                / 3.0
        };
        for d0 in [0.1, 0.3, 0.5] {
            let expected = cumulative(d0) * area;
            let got = t.rocks().iter().filter(|r| 2.0 * r.radius_m >= d0).count() as f64;
            assert!(
                (got - expected).abs() <= 4.0 * expected.sqrt() + 1.0,
                "D >= {d0}: {got} rocks, model {expected:.1}"
            );
        }
        // Height half the diameter.
        for r in t.rocks() {
            assert!((r.height_m - r.radius_m).abs() < 1e-12);
        }
    }
}
