//! The terrain mesh seen by the cameras: a polar grid around the stereo head.
//!
//! Vertices sit at ground points `(x, y) = c + r (cos theta, sin theta)` around the point `c`
//! below the middle of the stereo head, at the terrain height there. Azimuths `theta` are
//! uniform over the cameras' azimuth span; ranges `r` start at 0 and grow so that one mesh
//! step subtends about `step_rad` as seen from the head:
//!
//! `dr = step_rad * min((r^2 + h^2) / h, sqrt(r^2 + h^2) / sin_min)`
//!
//! The first term is the spacing that keeps a constant angle on flat ground seen from height `h`;
//! the second caps it where the ground is seen at grazing angles, so that slopes facing the
//! cameras at up to `90 deg - asin(sin_min)` incidence still get steps of `step_rad`. Triangles
//! are therefore a few pixels across everywhere in the image, whatever the range.
//!
//! Each vertex carries its Lambertian shade (view independent), computed from the normal of the
//! mesh itself (central differences along `r` and `theta`), so both cameras share one mesh.

use super::Sun;
use crate::surface::TerrainSurface;
use rayon::prelude::*;

/// Largest number of range rows (bounds the work on degenerate inputs).
pub(crate) const MAX_ROWS: usize = 4096;
/// Largest number of azimuth columns.
pub(crate) const MAX_COLS: usize = 4096;

/// Footprint of the mesh.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MeshSpec {
    /// Centre of the polar grid in `W`, m.
    pub center_xy: [f64; 2],
    /// Height of the stereo head above the ground below it, m (clamped positive).
    pub head_height_m: f64,
    /// First azimuth, rad (from `x` towards `y` in `W`).
    pub azimuth_min_rad: f64,
    /// Last azimuth, rad.
    pub azimuth_max_rad: f64,
    /// The grid closes on itself (`azimuth_max = azimuth_min + 2 pi`).
    pub full_circle: bool,
    /// Angular step, rad.
    pub step_rad: f64,
    /// Sine of the smallest grazing angle kept at full resolution.
    pub sin_min: f64,
    /// Largest range, m.
    pub max_range_m: f64,
}

/// A grid of `rows x cols` vertices, row-major (row = range, column = azimuth).
#[derive(Debug, Default, Clone)]
pub(crate) struct Mesh {
    /// Rows (ranges).
    pub rows: usize,
    /// Columns (azimuths).
    pub cols: usize,
    /// Vertex positions in `W`, m.
    pub pos: Vec<[f64; 3]>,
    /// Vertex shade factor (ambient + direct), dimensionless.
    pub shade: Vec<f32>,
    /// Ranges of the rows, m.
    ranges: Vec<f64>,
    /// `(cos, sin)` of the column azimuths.
    dirs: Vec<(f64, f64)>,
}

impl Mesh {
    /// Rebuild the mesh in place (keeps allocations between frames).
    pub(crate) fn build<S: TerrainSurface + ?Sized>(
        &mut self,
        surface: &S,
        spec: &MeshSpec,
        sun: &Sun,
        ambient: f64,
    ) {
        let h = spec.head_height_m.max(0.05);
        let step = spec.step_rad.max(1e-4);
        let sin_min = spec.sin_min.clamp(0.05, 1.0);
        self.ranges.clear();
        let mut r = 0.0f64;
        self.ranges.push(r);
        while r < spec.max_range_m && self.ranges.len() < MAX_ROWS {
            let rho2 = r * r + h * h;
            let dr = step * (rho2 / h).min(rho2.sqrt() / sin_min);
            r = (r + dr).min(spec.max_range_m);
            self.ranges.push(r);
        }
        let span = if spec.full_circle {
            std::f64::consts::TAU
        } else {
            (spec.azimuth_max_rad - spec.azimuth_min_rad).max(0.0)
        };
        let cols = ((span / step).ceil() as usize + 1).clamp(2, MAX_COLS);
        self.dirs.clear();
        for j in 0..cols {
            let theta = spec.azimuth_min_rad + span * j as f64 / (cols - 1) as f64;
            self.dirs.push((theta.cos(), theta.sin()));
        }
        if spec.full_circle {
            // Close the seam exactly: the last column is the first.
            self.dirs[cols - 1] = self.dirs[0];
        }
        self.rows = self.ranges.len();
        self.cols = cols;
        let n = self.rows * cols;
        self.pos.resize(n, [0.0; 3]);
        self.shade.resize(n, 0.0);
        let (ranges, dirs) = (&self.ranges, &self.dirs);
        let [cx, cy] = spec.center_xy;
        self.pos
            .par_chunks_mut(cols)
            .zip(ranges.par_iter())
            .for_each(|(row, &r)| {
                for (p, &(c, s)) in row.iter_mut().zip(dirs.iter()) {
                    let x = cx + r * c;
                    let y = cy + r * s;
                    *p = [x, y, -surface.height_m(x, y)];
                }
            });
        let pos = &self.pos;
        let rows = self.rows;
        let full = spec.full_circle;
        let s_w = sun.direction_w;
        self.shade
            .par_chunks_mut(cols)
            .enumerate()
            .for_each(|(k, row)| {
                for (j, out) in row.iter_mut().enumerate() {
                    let n_w = mesh_normal(pos, rows, cols, k, j, full).unwrap_or_else(|| {
                        let p = pos[k * cols + j];
                        let [nx, ny, nu] = surface.normal_up(p[0], p[1]);
                        [nx, ny, -nu]
                    });
                    let cos_i = n_w[0] * s_w[0] + n_w[1] * s_w[1] + n_w[2] * s_w[2];
                    *out = (ambient + (1.0 - ambient) * cos_i.max(0.0)) as f32;
                }
            });
    }
}

/// Upward unit normal in `W` (`z` component negative) of the mesh at vertex `(k, j)`, from
/// central differences; `None` where the grid is degenerate (range 0).
fn mesh_normal(
    pos: &[[f64; 3]],
    rows: usize,
    cols: usize,
    k: usize,
    j: usize,
    full_circle: bool,
) -> Option<[f64; 3]> {
    let at = |k: usize, j: usize| pos[k * cols + j];
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let (k0, k1) = (k.saturating_sub(1), (k + 1).min(rows - 1));
    let (j0, j1) = if full_circle {
        // Columns 0 and cols-1 coincide: step over the duplicate.
        let prev = if j == 0 { cols - 2 } else { j - 1 };
        let next = if j + 1 >= cols { 1 } else { j + 1 };
        (prev, next)
    } else {
        (j.saturating_sub(1), (j + 1).min(cols - 1))
    };
    let tr = sub(at(k1, j), at(k0, j));
    let tt = sub(at(k, j1), at(k, j0));
    let mut n = [
        tr[1] * tt[2] - tr[2] * tt[1],
        tr[2] * tt[0] - tr[0] * tt[2],
        tr[0] * tt[1] - tr[1] * tt[0],
    ];
    let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let scale = (tr[0] * tr[0] + tr[1] * tr[1]).sqrt() * (tt[0] * tt[0] + tt[1] * tt[1]).sqrt();
    if norm.is_nan() || norm <= 1e-9 * scale || scale < 1e-18 {
        return None;
    }
    if n[2] > 0.0 {
        n = [-n[0], -n[1], -n[2]];
    }
    Some([n[0] / norm, n[1] / norm, n[2] / norm])
}
