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

use super::lens_rig::quantize;
use super::mesh::Mesh;
use super::noise::{floor_i64, hash3, mix64, GaussTable, GAUSS_TABLE_LEN};
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
    /// Pixels whose value is used (`width * height`, row-major), or `None` for all: the
    /// shading pass looks up the albedo only for these (the others get an arbitrary value).
    used: Option<Vec<bool>>,
    /// Triangles that reached the pixel loop in the last frame.
    pub triangles_drawn: usize,
}

/// Tolerance of the inclusive edge test, in barycentric units: pixel centres on a shared edge
/// (or within rounding of it) belong to both triangles, so shared edges never leave holes.
const EDGE_TOL: f64 = 1e-7;

/// Pixels per knot of the footprint stretch, which is interpolated linearly between knots along
/// each row (it varies slowly; it only selects mip levels).
const STRETCH_KNOT_PX: usize = 16;

/// Pixels that share one 64-bit noise hash (16 bits each).
const NOISE_GROUP: usize = 4;

impl Frame {
    /// Buffers for a `width x height` image.
    pub(crate) fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            inv_z: vec![0.0; width * height],
            shade: vec![0.0; width * height],
            used: None,
            triangles_drawn: 0,
        }
    }

    /// Shade only the pixels where `used` is true (`width * height` values, row-major; the
    /// others get an arbitrary value), or every pixel for `None` or a slice of another size.
    /// The used pixels get the same values as without the mask.
    pub(crate) fn set_used(&mut self, used: Option<Vec<bool>>) {
        self.used = used.filter(|u| u.len() == self.width * self.height);
    }

    /// Rasterize `mesh` with its vertices projected into this camera (`proj`: `(u, v, 1/z)` per
    /// vertex, `1/z <= 0` for culled vertices).
    pub(crate) fn rasterize(&mut self, mesh: &Mesh, proj: &[[f64; 3]]) {
        self.inv_z.fill(0.0);
        self.triangles_drawn = 0;
        let cols = mesh.cols;
        for k in 0..mesh.rows.saturating_sub(1) {
            let row0 = &proj[k * cols..(k + 1) * cols];
            let row1 = &proj[(k + 1) * cols..(k + 2) * cols];
            let sh0 = &mesh.shade[k * cols..(k + 1) * cols];
            let sh1 = &mesh.shade[(k + 1) * cols..(k + 2) * cols];
            for j in 0..cols.saturating_sub(1) {
                let (p00, p01, p10, p11) = (row0[j], row0[j + 1], row1[j], row1[j + 1]);
                let (s00, s01, s10, s11) = (sh0[j], sh0[j + 1], sh1[j], sh1[j + 1]);
                self.triangle([p00, p01, p10], [s00, s01, s10]);
                self.triangle([p01, p11, p10], [s01, s11, s10]);
            }
        }
    }

    /// Rasterize one projected triangle with the depth test: every pixel centre inside (edges
    /// included) gets the triangle's `1/z` and shade where it is nearer than what is there.
    #[inline]
    fn triangle(&mut self, p: [[f64; 3]; 3], s: [f32; 3]) {
        let [a, b, c] = p;
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
        let umax = floor_i64(uhi.min(wmax)) as f64;
        let vmin = (-floor_i64(-vlo)).max(0);
        let vmax = floor_i64(vhi.min(hmax));
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
        // Barycentrics l1 (towards b), l2 (towards c) and l0 = 1 - l1 - l2 are affine in
        // (u, v): l = l_u * (u - a_u) + l_v * (v - a_v) + l(a).
        let l1_du = e2[1] * inv_area;
        let l1_dv = -e2[0] * inv_area;
        let l2_du = -e1[1] * inv_area;
        let l2_dv = e1[0] * inv_area;
        let bounds = EdgeBounds::new(a[0], [l1_du, l1_dv], [l2_du, l2_dv]);
        // 1/z and shade are affine too: value(u, v) = value(a) + d_u (u - a_u) + d_v (v - a_v).
        let (dzb, dzc) = (b[2] - a[2], c[2] - a[2]);
        let (sa, sb, sc) = (f64::from(s[0]), f64::from(s[1]), f64::from(s[2]));
        let (dsb, dsc) = (sb - sa, sc - sa);
        let iz_du = l1_du * dzb + l2_du * dzc;
        let iz_dv = l1_dv * dzb + l2_dv * dzc;
        let sh_du = l1_du * dsb + l2_du * dsc;
        let sh_dv = l1_dv * dsb + l2_dv * dsc;
        let width = self.width;
        for v in vmin..=vmax {
            let dv = v as f64 - a[1];
            let Some((first_u, last_u)) = bounds.span(dv, umin, umax) else {
                continue;
            };
            let first = -floor_i64(-first_u);
            let last = floor_i64(last_u);
            if first > last {
                continue;
            }
            // Depth and shade at the first pixel, then per-pixel steps.
            let du0 = first as f64 - a[0];
            let iz0 = a[2] + iz_du * du0 + iz_dv * dv;
            let sh0 = sa + sh_du * du0 + sh_dv * dv;
            let row = v as usize * width;
            let (start, end) = (row + first as usize, row + last as usize + 1);
            depth_test(
                &mut self.inv_z[start..end],
                &mut self.shade[start..end],
                (iz0, iz_du),
                (sh0, sh_du),
            );
        }
    }

    /// Shade every pixel into `out` (8-bit, row-major; only the used ones, [`Self::set_used`]).
    /// `albedo(x, y, footprint, out)` gives the ground reflectance of a run of points;
    /// `noise_key` selects this image's noise; `gauss` is the quantile table. Returns the number
    /// of sky pixels (of the whole image, used or not).
    pub(crate) fn shade_into<A: Fn(&[f64], &[f64], &[f64], &mut [f64]) + Sync>(
        &self,
        view: &View,
        settings: &RenderSettings,
        albedo: &A,
        noise_key: (u64, u64),
        gauss: &GaussTable,
        out: &mut [u8],
    ) -> usize {
        let width = self.width;
        // Ray of pixel (i, v): ray_w(0, v) + i * step (affine in i).
        let r0 = view.ray_w(0.0, 0.0);
        let r1 = view.ray_w(1.0, 0.0);
        let shader = RowShader {
            view,
            albedo,
            gauss,
            width,
            // Table indices are 16-bit fields of the hash (the table has at most 2^16 entries).
            table_mask: (GAUSS_TABLE_LEN - 1) as u64,
            sigma: settings.noise_sigma_dn,
            exposure: settings.exposure_dn,
            sky_dn: settings.sky_dn,
            key: hash3(noise_key.0, noise_key.1, 0x006e_6f69_7365),
            step: [r1[0] - r0[0], r1[1] - r0[1], r1[2] - r0[2]],
        };
        let knots = width.div_ceil(STRETCH_KNOT_PX) + 1;
        let knot_table = footprint_knots(view, self.height, knots);
        let used = self.used.as_deref();
        out.par_chunks_mut(width)
            .zip(self.inv_z.par_chunks(width))
            .zip(self.shade.par_chunks(width))
            .zip(knot_table.par_chunks(knots))
            .enumerate()
            .map_init(
                || RowScratch::new(width),
                |s, (j, (((row, inv_z), shade), knot))| {
                    let used = used.map(|u| &u[j * width..(j + 1) * width]);
                    shader.shade_row(s, j, row, inv_z, shade, knot, used)
                },
            )
            .sum()
    }
}

/// The bounds on `u` of a triangle's pixel centres on a row, from its edge functions.
///
/// Each edge function bounds u on a row: l + l_u (u - a_u) >= -tol gives u >= (or <=, as
/// l_u > 0 or < 0) a_u + (-tol - l) / l_u, with l = l_v (v - a_v) + l(a): an affine bound
/// bound0 + bound_dv * (v - a_v). Lower bounds go in `lo`, upper ones in `hi`, the active ones
/// first (the other slots keep an infinite, inactive bound); an edge along u (l_u = 0) only
/// bounds v, which the bounding box does. The l_u sum to 0, so a triangle has at most two
/// bounds on each side (a third only with NaN slopes).
struct EdgeBounds {
    lo: [(f64, f64); 3],
    hi: [(f64, f64); 3],
    /// A third bound on a side (NaN slopes).
    third: bool,
}

impl EdgeBounds {
    /// The bounds of the triangle with first vertex at `u = a_u` and barycentric slopes
    /// `l1 = [l1_du, l1_dv]` (towards the second vertex), `l2` (towards the third).
    #[inline]
    fn new(a_u: f64, l1: [f64; 2], l2: [f64; 2]) -> Self {
        let [l1_du, l1_dv] = l1;
        let [l2_du, l2_dv] = l2;
        let mut lo = [(f64::NEG_INFINITY, 0.0); 3];
        let mut hi = [(f64::INFINITY, 0.0); 3];
        let (mut n_lo, mut n_hi) = (0, 0);
        for (l_a, l_du, l_dv) in [
            (0.0, l1_du, l1_dv),
            (0.0, l2_du, l2_dv),
            (1.0, -(l1_du + l2_du), -(l1_dv + l2_dv)),
        ] {
            if l_du != 0.0 {
                let r = 1.0 / l_du;
                let bound = (a_u + (-EDGE_TOL - l_a) * r, -l_dv * r);
                if l_du > 0.0 {
                    lo[n_lo] = bound;
                    n_lo += 1;
                } else {
                    hi[n_hi] = bound;
                    n_hi += 1;
                }
            }
        }
        Self {
            lo,
            hi,
            third: n_lo > 2 || n_hi > 2,
        }
    }

    /// The span `[first_u, last_u]` of the row `dv = v - a_v` within `[umin, umax]`: the
    /// largest lower and smallest upper bound (a NaN bound is ignored, an inactive one is
    /// infinite, so both stay within the bounding box); `None` when empty.
    #[inline]
    fn span(&self, dv: f64, umin: f64, umax: f64) -> Option<(f64, f64)> {
        let at = |(b0, b1): (f64, f64)| b0 + b1 * dv;
        let (mut first_u, mut last_u) = (umin, umax);
        let (l, h) = if self.third { (3, 3) } else { (2, 2) };
        for &b in &self.lo[..l] {
            let b = at(b);
            if b > first_u {
                first_u = b;
            }
        }
        for &b in &self.hi[..h] {
            let b = at(b);
            if b < last_u {
                last_u = b;
            }
        }
        (first_u <= last_u).then_some((first_u, last_u))
    }
}

/// Depth test of a row span: where the triangle's `1/z` (`iz0 + k iz_du` at the span's
/// `k`-th pixel) is nearer than `depth`, it and the shade (`sh0 + k sh_du`) are written.
#[inline]
fn depth_test(
    depth: &mut [f32],
    shade: &mut [f32],
    (iz0, iz_du): (f64, f64),
    (sh0, sh_du): (f64, f64),
) {
    // Branch-free depth test (pixels on shared edges make it unpredictable).
    for (k, (d, sh)) in depth.iter_mut().zip(shade.iter_mut()).enumerate() {
        let t = f64::from(k as i32);
        let iz = (iz0 + t * iz_du) as f32;
        let s = (sh0 + t * sh_du) as f32;
        // All ones where this triangle is nearer (bit select, so that the compiler does not
        // turn it back into a branch).
        let m = u32::from(iz > *d).wrapping_neg();
        *sh = f32::from_bits((s.to_bits() & m) | (sh.to_bits() & !m));
        *d = f32::from_bits((iz.to_bits() & m) | (d.to_bits() & !m));
    }
}

/// Footprint per unit depth, (1 / f_x) * stretch, at knots every [`STRETCH_KNOT_PX`] pixels
/// along each of the `height` rows (`knots` per row): the footprint across the ray is
/// z / f_x, stretched by 1 / sqrt(cos i) for the foreshortening on level ground (geometric
/// mean of the two axes).
fn footprint_knots(view: &View, height: usize, knots: usize) -> Vec<f64> {
    let inv_fx = 1.0 / view.fx;
    (0..height * knots)
        .map(|n| {
            let (j, k) = (n / knots, n % knots);
            let ray = view.ray_w((k * STRETCH_KNOT_PX) as f64, j as f64);
            let len = (ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2]).sqrt();
            inv_fx * (len / ray[2].abs().max(0.05 * len)).sqrt()
        })
        .collect()
}

/// What shading a row needs of its image: the view, the albedo, the noise and the exposure.
struct RowShader<'a, A> {
    view: &'a View,
    albedo: &'a A,
    gauss: &'a GaussTable,
    width: usize,
    table_mask: u64,
    sigma: f64,
    exposure: f64,
    sky_dn: f64,
    /// This image's noise key.
    key: u64,
    /// Ray step per pixel along a row, `W`.
    step: [f64; 3],
}

impl<A: Fn(&[f64], &[f64], &[f64], &mut [f64]) + Sync> RowShader<'_, A> {
    /// Shade row `j` into `row`; returns its sky pixels.
    #[allow(clippy::too_many_arguments)]
    fn shade_row(
        &self,
        s: &mut RowScratch,
        j: usize,
        row: &mut [u8],
        inv_z: &[f32],
        shade: &[f32],
        knot: &[f64],
        used: Option<&[bool]>,
    ) -> usize {
        let width = self.width;
        if let Some(u) = used {
            if !u.iter().any(|&b| b) {
                // No pixel of this row is used: only the sky count.
                row.fill(0);
                return inv_z.len() - inv_z.iter().filter(|&&iz| iz > 0.0).count();
            }
        }
        fill_stretch(&mut s.stretch[..width], knot);
        let n = self.ground_points(s, j, inv_z, used);
        let albedos = &mut s.albedos[..n];
        (self.albedo)(&s.xs[..n], &s.ys[..n], &s.fs[..n], albedos);
        let (exposure, sky_dn) = (self.exposure, self.sky_dn);
        let mut sky = 0usize;
        // Noise-free value of pixel `i` (sky counted), the albedos taken in order.
        let value =
            |i: usize, iz: f32, sh: f32, albedos: &mut core::slice::Iter<f64>, sky: &mut usize| {
                if iz > 0.0 {
                    if used.is_none_or(|u| u[i]) {
                        let a = albedos.next().copied().unwrap_or(0.0);
                        exposure * a * f64::from(sh)
                    } else {
                        0.0
                    }
                } else {
                    *sky += 1;
                    sky_dn
                }
            };
        if self.sigma == 0.0 {
            // No noise (the noise term would be +-0, the table is finite, which leaves every
            // sum as it is, NaN included): each byte straight from the noise-free value below.
            if n == width {
                for ((o, &a), &sh) in row.iter_mut().zip(albedos.iter()).zip(shade) {
                    *o = quantize(exposure * a * f64::from(sh));
                }
                return sky;
            }
            let mut albedos = albedos.iter();
            for (i, ((o, &iz), &sh)) in row.iter_mut().zip(inv_z).zip(shade).enumerate() {
                *o = quantize(value(i, iz, sh, &mut albedos, &mut sky));
            }
            return sky;
        }
        // Noise-free value per pixel (a plain loop where the whole row is ground).
        let clean = &mut s.clean[..width];
        if n == width {
            for ((c, &a), &sh) in clean.iter_mut().zip(albedos.iter()).zip(shade) {
                *c = exposure * a * f64::from(sh);
            }
        } else {
            let mut albedos = albedos.iter();
            for (i, ((c, &iz), &sh)) in clean.iter_mut().zip(inv_z).zip(shade).enumerate() {
                *c = value(i, iz, sh, &mut albedos, &mut sky);
            }
        }
        self.add_noise(j, row, clean);
        sky
    }

    /// World points and footprints of row `j`'s ground pixels (the used ones) into the
    /// scratch's `xs`, `ys`, `fs`; returns how many.
    fn ground_points(
        &self,
        s: &mut RowScratch,
        j: usize,
        inv_z: &[f32],
        used: Option<&[bool]>,
    ) -> usize {
        let base = self.view.ray_w(0.0, j as f64);
        let [cx, cy, _] = self.view.center_w;
        let step = self.step;
        let RowScratch {
            stretch,
            xs,
            ys,
            fs,
            ..
        } = s;
        let stretch = &stretch[..self.width];
        let mut n = 0;
        let mut point = |i: usize, iz: f32, st: f64| {
            let fi = i as u32 as f64;
            let z = f64::from(1.0 / iz);
            xs[n] = cx + z * (base[0] + fi * step[0]);
            ys[n] = cy + z * (base[1] + fi * step[1]);
            fs[n] = z * st;
            n += 1;
        };
        match used {
            None => {
                for (i, (&iz, &st)) in inv_z.iter().zip(stretch.iter()).enumerate() {
                    if iz > 0.0 {
                        point(i, iz, st);
                    }
                }
            }
            Some(u) => {
                for (i, ((&iz, &st), &u)) in inv_z.iter().zip(stretch.iter()).zip(u).enumerate() {
                    if iz > 0.0 && u {
                        point(i, iz, st);
                    }
                }
            }
        }
        n
    }

    /// Noise on the noise-free values `clean` of row `j`, quantised into `row`: one hash per
    /// group of four pixels, 16 bits of it per pixel.
    fn add_noise(&self, j: usize, row: &mut [u8], clean: &[f64]) {
        let width = self.width;
        let (key, gauss, table_mask, sigma) = (self.key, self.gauss, self.table_mask, self.sigma);
        let first_id = ((j * width) / NOISE_GROUP) as u64;
        let quantize = |out: &mut [u8], clean: &[f64], g: usize| {
            let id = first_id + g as u64;
            let h = mix64(key ^ id.wrapping_mul(0x9e37_79b9_7f4a_7c15));
            for (q, (o, &c)) in out.iter_mut().zip(clean).enumerate() {
                let g = gauss[((h >> (16 * q)) & table_mask) as usize];
                let noise = sigma * f64::from(g);
                // Round half up; NaN gives 0 (through i32: the clamped value fits, and the
                // conversion is cheaper than the saturating one to u8).
                *o = ((c + noise).clamp(0.0, 255.0) + 0.5) as i32 as u8;
            }
        };
        let full = width / NOISE_GROUP * NOISE_GROUP;
        let (row_full, row_tail) = row.split_at_mut(full);
        let (clean_full, clean_tail) = clean.split_at(full);
        for (g, (out, clean)) in row_full
            .chunks_exact_mut(NOISE_GROUP)
            .zip(clean_full.chunks_exact(NOISE_GROUP))
            .enumerate()
        {
            quantize(out, clean, g);
        }
        if !row_tail.is_empty() {
            quantize(row_tail, clean_tail, full / NOISE_GROUP);
        }
    }
}

/// Footprint stretch per pixel of a row, linear between its knots.
fn fill_stretch(stretch: &mut [f64], knot: &[f64]) {
    for (k, out) in stretch.chunks_mut(STRETCH_KNOT_PX).enumerate() {
        let (k0, k1) = (knot[k], knot[k + 1]);
        for (t, o) in out.iter_mut().enumerate() {
            let t = t as u32 as f64 * (1.0 / STRETCH_KNOT_PX as f64);
            *o = k0 + t * (k1 - k0);
        }
    }
}

/// Per-row working arrays of [`Frame::shade_into`] (one set per parallel job, reused for its
/// rows; every entry read is written first for the same row).
struct RowScratch {
    stretch: Vec<f64>,
    xs: Vec<f64>,
    ys: Vec<f64>,
    fs: Vec<f64>,
    albedos: Vec<f64>,
    clean: Vec<f64>,
}

impl RowScratch {
    fn new(width: usize) -> Self {
        Self {
            stretch: vec![0.0; width],
            xs: vec![0.0; width],
            ys: vec![0.0; width],
            fs: vec![0.0; width],
            albedos: vec![0.0; width],
            clean: vec![0.0; width],
        }
    }
}
