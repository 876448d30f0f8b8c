//! Per-camera work: project the shared mesh, rasterize it with a depth buffer, then shade every
//! pixel (albedo at the exact world point under the pixel, interpolated Lambertian shade, sky,
//! Gaussian noise, quantization).
//!
//! The depth buffer stores `1/z` (`z` = depth along the optical axis), which is affine in the
//! pixel coordinates over a planar triangle, so the depth of a pixel is exact for the triangle
//! that covers it. The shading pass recovers the world point under the pixel centre as
//! `P = C + z * R_WK * ((u - c_x) / f_x, (v - c_y) / f_y, 1)`, so the albedo (the texture, the
//! markers) is evaluated per pixel, independently of the mesh resolution, and lands exactly where
//! the pinhole model puts it. Pixel `(i, j)` has its centre at `u = i, v = j`.

use super::mesh::Mesh;
use super::noise::{floor_i64, hash3, mix64};
use super::RenderSettings;
use rayon::prelude::*;

/// Vertices closer than this to the camera plane cull their triangles, m.
const NEAR_M: f64 = 0.02;

/// A pinhole camera placed in the world.
#[derive(Debug, Clone, Copy)]
pub(crate) struct View {
    /// Rotation `W <- K`, row-major.
    pub rot_w_from_k: [[f64; 3]; 3],
    /// Optical centre in `W`, m.
    pub center_w: [f64; 3],
    /// Intrinsics, pixels.
    pub fx: f64,
    /// Focal length along `v`, pixels.
    pub fy: f64,
    /// Principal point `u`, pixels.
    pub cx: f64,
    /// Principal point `v`, pixels.
    pub cy: f64,
}

impl View {
    /// Point in `W` to `(u, v, 1/z)`; `None` behind the near plane.
    #[inline]
    pub(crate) fn project(&self, p: [f64; 3]) -> Option<[f64; 3]> {
        let d = [
            p[0] - self.center_w[0],
            p[1] - self.center_w[1],
            p[2] - self.center_w[2],
        ];
        let r = &self.rot_w_from_k;
        // K = R_WK^T * d.
        let x = r[0][0] * d[0] + r[1][0] * d[1] + r[2][0] * d[2];
        let y = r[0][1] * d[0] + r[1][1] * d[1] + r[2][1] * d[2];
        let z = r[0][2] * d[0] + r[1][2] * d[1] + r[2][2] * d[2];
        if z.is_nan() || z <= NEAR_M {
            return None;
        }
        let iz = 1.0 / z;
        Some([self.cx + self.fx * x * iz, self.cy + self.fy * y * iz, iz])
    }

    /// Ray through pixel `(u, v)` in `W` (not normalised; its `K` z-component is 1).
    #[inline]
    pub(crate) fn ray_w(&self, u: f64, v: f64) -> [f64; 3] {
        let k = [(u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0];
        let r = &self.rot_w_from_k;
        [
            r[0][0] * k[0] + r[0][1] * k[1] + r[0][2] * k[2],
            r[1][0] * k[0] + r[1][1] * k[1] + r[1][2] * k[2],
            r[2][0] * k[0] + r[2][1] * k[1] + r[2][2] * k[2],
        ]
    }
}

/// Depth and shade buffers of one camera.
#[derive(Debug, Default, Clone)]
pub(crate) struct Frame {
    width: usize,
    height: usize,
    /// `1/z` per pixel, 0 where no triangle was drawn (sky).
    inv_z: Vec<f32>,
    /// Interpolated shade per pixel.
    shade: Vec<f32>,
    /// Projected vertices `(u, v, 1/z)`, `1/z = -1` when culled.
    proj: Vec<[f64; 3]>,
    /// Triangles that reached the pixel loop in the last frame.
    pub triangles_drawn: usize,
}

impl Frame {
    /// Buffers for a `width x height` image.
    pub(crate) fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            inv_z: vec![0.0; width * height],
            shade: vec![0.0; width * height],
            proj: Vec::new(),
            triangles_drawn: 0,
        }
    }

    /// Project and rasterize `mesh` as seen by `view`.
    pub(crate) fn rasterize(&mut self, mesh: &Mesh, view: &View) {
        self.inv_z.iter_mut().for_each(|v| *v = 0.0);
        self.proj.clear();
        self.proj.extend(
            mesh.pos
                .iter()
                .map(|&p| view.project(p).unwrap_or([0.0, 0.0, -1.0])),
        );
        self.triangles_drawn = 0;
        let cols = mesh.cols;
        for k in 0..mesh.rows.saturating_sub(1) {
            for j in 0..cols.saturating_sub(1) {
                let i00 = k * cols + j;
                let i01 = i00 + 1;
                let i10 = i00 + cols;
                let i11 = i10 + 1;
                self.triangle(mesh, i00, i01, i10);
                self.triangle(mesh, i01, i11, i10);
            }
        }
    }

    /// Rasterize one triangle (vertex indices into the mesh) with the depth test.
    #[inline]
    fn triangle(&mut self, mesh: &Mesh, ia: usize, ib: usize, ic: usize) {
        let (a, b, c) = (self.proj[ia], self.proj[ib], self.proj[ic]);
        if a[2] <= 0.0 || b[2] <= 0.0 || c[2] <= 0.0 {
            return;
        }
        let (ulo, uhi) = (a[0].min(b[0]).min(c[0]), a[0].max(b[0]).max(c[0]));
        let (vlo, vhi) = (a[1].min(b[1]).min(c[1]), a[1].max(b[1]).max(c[1]));
        let (wmax, hmax) = ((self.width - 1) as f64, (self.height - 1) as f64);
        if !(uhi >= 0.0 && vhi >= 0.0 && ulo <= wmax && vlo <= hmax) {
            return;
        }
        // Pixel centres inside the bounding box (ceil of the low ends, floor of the high ends).
        let umin = (-floor_i64(-ulo)).max(0) as f64;
        let umax = (floor_i64(uhi.min(wmax))) as f64;
        let vmin = (-floor_i64(-vlo)).max(0) as f64;
        let vmax = (floor_i64(vhi.min(hmax))) as f64;
        if umin > umax || vmin > vmax {
            return;
        }
        let e1 = [b[0] - a[0], b[1] - a[1]];
        let e2 = [c[0] - a[0], c[1] - a[1]];
        let area = e1[0] * e2[1] - e1[1] * e2[0];
        if area.abs() < 1e-12 {
            return;
        }
        let inv_area = 1.0 / area;
        self.triangles_drawn += 1;
        let (sa, sb, sc) = (
            f64::from(mesh.shade[ia]),
            f64::from(mesh.shade[ib]),
            f64::from(mesh.shade[ic]),
        );
        let (za, dzb, dzc) = (a[2], b[2] - a[2], c[2] - a[2]);
        let (dsb, dsc) = (sb - sa, sc - sa);
        // Barycentrics l1 (towards b) and l2 (towards c) are affine in (u, v).
        let l1_du = e2[1] * inv_area;
        let l2_du = -e1[1] * inv_area;
        const EPS: f64 = -1e-9;
        let mut v = vmin;
        while v <= vmax {
            let dv = v - a[1];
            let du0 = umin - a[0];
            let mut l1 = (du0 * e2[1] - dv * e2[0]) * inv_area;
            let mut l2 = (e1[0] * dv - e1[1] * du0) * inv_area;
            let row = v as usize * self.width;
            let mut u = umin;
            while u <= umax {
                if l1 >= EPS && l2 >= EPS && l1 + l2 <= 1.0 - EPS {
                    let iz = (za + l1 * dzb + l2 * dzc) as f32;
                    let idx = row + u as usize;
                    if iz > self.inv_z[idx] {
                        self.inv_z[idx] = iz;
                        self.shade[idx] = (sa + l1 * dsb + l2 * dsc) as f32;
                    }
                }
                l1 += l1_du;
                l2 += l2_du;
                u += 1.0;
            }
            v += 1.0;
        }
    }

    /// Shade every pixel into `out` (8-bit, row-major). `albedo(x, y, footprint)` gives the
    /// ground reflectance; `noise_key` selects this image's noise; `gauss` is the quantile
    /// table. Returns the number of sky pixels.
    pub(crate) fn shade_into<A: Fn(f64, f64, f64) -> f64 + Sync>(
        &self,
        view: &View,
        settings: &RenderSettings,
        albedo: &A,
        noise_key: (u64, u64),
        gauss: &[f32],
        out: &mut [u8],
    ) -> usize {
        let width = self.width;
        let table_mask = (gauss.len() - 1) as u64;
        let bits = table_mask.count_ones();
        let sigma = settings.noise_sigma_dn;
        let inv_fx = 1.0 / view.fx;
        let key = hash3(noise_key.0, noise_key.1, 0x006e_6f69_7365);
        out.par_chunks_mut(width)
            .enumerate()
            .map(|(j, row)| {
                let v = j as f64;
                let mut sky = 0usize;
                for (i, px) in row.iter_mut().enumerate() {
                    let idx = j * width + i;
                    let iz = self.inv_z[idx];
                    let clean = if iz > 0.0 {
                        let z = 1.0 / f64::from(iz);
                        let ray = view.ray_w(i as f64, v);
                        let x = view.center_w[0] + z * ray[0];
                        let y = view.center_w[1] + z * ray[1];
                        // Footprint across the ray z / f_x, stretched by 1 / sqrt(cos i) for
                        // the foreshortening on level ground (geometric mean of the two axes).
                        let len = (ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2]).sqrt();
                        let stretch = (len / ray[2].abs().max(0.05 * len)).sqrt();
                        let footprint = z * inv_fx * stretch;
                        settings.exposure_dn * albedo(x, y, footprint) * f64::from(self.shade[idx])
                    } else {
                        sky += 1;
                        settings.sky_dn
                    };
                    let noise = if sigma > 0.0 {
                        let h = mix64(key ^ (idx as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
                        sigma * f64::from(gauss[((h >> (64 - bits)) & table_mask) as usize])
                    } else {
                        0.0
                    };
                    // Round half up; NaN saturates to 0.
                    *px = ((clean + noise).clamp(0.0, 255.0) + 0.5) as u8;
                }
                sky
            })
            .sum()
    }
}
