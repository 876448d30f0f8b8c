//! Procedural albedo of sandy ground with pebbles, and a surface wrapper that adds it to a bare
//! height function.
//!
//! The albedo is the product of seamless, periodic layers laid on the world `x, y` plane:
//!
//! - a **fine tile** (default 2048 x 2048 texels of 4 mm, period 8.19 m): six octaves of gradient
//!   noise with wavelengths 16 mm ... 0.51 m, plus about 60 pebbles per square metre (ellipses of
//!   6 mm ... 40 mm radius, darker basalt-like or lighter, with a soft one-texel rim). This is the
//!   structure a hazcam resolves between 0.5 and 5 m: a pixel covers 1.5 mm of ground at 0.6 m
//!   and 1-7 cm (foreshortened) at 2.5-5 m, so pebbles and the short noise octaves give corners
//!   near the rover and the pebble clusters and long octaves give corners far away;
//! - a **coarse layer** baked into the fine tile (same period): four octaves of wavelengths
//!   0.5 ... 4.1 m modulating the brightness by about +-25 %;
//! - a **detail tile** (512 x 512 texels of 1 mm, period 0.51 m, rotated 35 deg): sand grains of
//!   2-16 mm wavelength, seen within about 1 m, faded out for footprints of 4-8 mm.
//!
//! The fine and detail tiles keep box-filtered mip pyramids; [`AlbedoTexture::albedo_filtered`]
//! blends the two levels around a requested footprint (trilinear), which removes the aliasing a
//! point sample would give on distant, foreshortened ground. The whole texture repeats every
//! 8.19 m (default), more than a hazcam sees.

use super::noise::{hash3, unit_f64, GradientLattice, LatticeColumns};
use super::FilteredAlbedo;
use crate::surface::TerrainSurface;
use rayon::prelude::*;
use std::cell::RefCell;
use std::sync::Arc;

/// Parameters of the procedural albedo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextureParams {
    /// Seed of every random choice (noise lattices, pebbles).
    pub seed: u64,
    /// Fine-tile texel size, m.
    pub texel_m: f64,
    /// Fine-tile side, texels, as a power of two (`1 << size_log2`).
    pub size_log2: u32,
    /// Mean albedo of the sand (Mars soil is about 0.25).
    pub mean_albedo: f64,
    /// Relative contrast of the sand noise (standard deviation of the noise factor, about).
    pub sand_contrast: f64,
    /// Pebbles per square metre.
    pub pebbles_per_m2: f64,
    /// Relative amplitude of the coarse (0.5-4 m) brightness modulation.
    pub coarse_contrast: f64,
    /// Relative amplitude of the millimetre detail (sand grains) seen within about 1 m; 0 turns
    /// the layer off (about 30 % faster rendering, less texture right in front of the rover).
    pub detail_contrast: f64,
}

impl Default for TextureParams {
    fn default() -> Self {
        Self {
            seed: 1,
            texel_m: 0.004,
            size_log2: 11,
            mean_albedo: 0.25,
            sand_contrast: 0.22,
            pebbles_per_m2: 60.0,
            coarse_contrast: 0.25,
            detail_contrast: 0.3,
        }
    }
}

/// One periodic square tile of albedo values (`u16`, 65535 = albedo 1), stored in 8x8 blocks
/// so that a bilinear lookup touches one or two cache lines whatever the viewing direction.
/// Each block also keeps a copy of the first column and row of its right, lower and diagonal
/// neighbours (9x9 values, [`PADDED`] per block), so the four taps of any bilinear lookup are
/// always in one block: no branch, one bounds check.
#[derive(Debug, Clone)]
struct Tile {
    size: usize,
    /// log2 of the number of blocks per row.
    blocks_log2: u32,
    data: Vec<u16>,
}

/// Block side, texels.
const BLOCK: usize = 8;
/// Row stride of a padded block, values.
const STRIDE: usize = BLOCK + 1;
/// Values per padded block.
const PADDED: usize = STRIDE * STRIDE;

impl Tile {
    /// A tile from row-major values (`size` a power of two, at least 8).
    fn from_row_major(size: usize, rows: &[u16]) -> Tile {
        let blocks = size / BLOCK;
        let blocks_log2 = blocks.trailing_zeros();
        let mask = size - 1;
        let mut data = vec![0; blocks * blocks * PADDED];
        for (b, block) in data.chunks_exact_mut(PADDED).enumerate() {
            let (bi, bj) = (b & (blocks - 1), b >> blocks_log2);
            for (r, row) in block.chunks_exact_mut(STRIDE).enumerate() {
                let j = (bj * BLOCK + r) & mask;
                for (c, out) in row.iter_mut().enumerate() {
                    *out = rows[j * size + ((bi * BLOCK + c) & mask)];
                }
            }
        }
        Tile {
            size,
            blocks_log2,
            data,
        }
    }

    /// Storage index of texel `(i, j)` (both below `size`).
    #[inline(always)]
    fn index(&self, i: usize, j: usize) -> usize {
        (((j >> 3) << self.blocks_log2) + (i >> 3)) * PADDED + (j & 7) * STRIDE + (i & 7)
    }

    /// Texel `(i, j)`, indices wrapped.
    #[inline(always)]
    fn at(&self, i: usize, j: usize) -> u16 {
        let mask = self.size - 1;
        self.data[self.index(i & mask, j & mask)]
    }

    /// Bilinear sample at texel coordinates (texel centres at integers), wrapping.
    #[inline(always)]
    fn bilinear(&self, u: f64, v: f64) -> f64 {
        // Integer part without a libm call or a saturating conversion: adding 1.5 * 2^52
        // rounds `u - 0.5` to an integer `n` (ties to even) in the low mantissa bits, so
        // `n = floor(u)` or, when `u` is an integer, `u - 1` with weight 1 on the upper tap
        // (the same value: bilinear interpolation is continuous).
        const MAGIC: f64 = 6_755_399_441_055_744.0;
        let tu = (u - 0.5) + MAGIC;
        let tv = (v - 0.5) + MAGIC;
        let fu = u - (tu - MAGIC);
        let fv = v - (tv - MAGIC);
        // The low bits of the mantissa are n in two's complement: the mask wraps the tile.
        let mask = self.size - 1;
        let base = self.index(tu.to_bits() as usize & mask, tv.to_bits() as usize & mask);
        // Taps (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1): offsets 0, 1, 9, 10.
        let q = &self.data[base..base + STRIDE + 2];
        let (a, b, c, d) = (
            f64::from(q[0]),
            f64::from(q[1]),
            f64::from(q[STRIDE]),
            f64::from(q[STRIDE + 1]),
        );
        let top = a + fu * (b - a);
        let bottom = c + fu * (d - c);
        (top + fv * (bottom - top)) * (1.0 / 65535.0)
    }

    /// [`Self::bilinear`] at `(x[k] * scale - 0.5, y[k] * scale - 0.5)` for up to [`BATCH`]
    /// points into `out[k]` (bit-identical to the one-point form). Three passes over the
    /// points: the coordinates (texel fractions and integer parts; plain arithmetic over whole
    /// arrays, which the compiler vectorises), the texel loads, the interpolation (vectorised
    /// too); `scratch` holds the per-point values between the passes (reused between calls,
    /// so that no per-call buffer is zeroed). Not inlined: as a function of its own its slices
    /// are known not to overlap, which the vectorised passes need.
    #[inline(never)]
    fn bilinear_batch(
        &self,
        x: &[f64],
        y: &[f64],
        scale: f64,
        out: &mut [f64],
        scratch: &mut BilinearScratch,
    ) {
        const MAGIC: f64 = 6_755_399_441_055_744.0;
        let n = out.len().min(x.len()).min(y.len()).min(BATCH);
        let (x, y, out) = (&x[..n], &y[..n], &mut out[..n]);
        let mask = self.size - 1;
        let BilinearScratch {
            fu,
            fv,
            base,
            ta,
            tb,
            tc,
            td,
        } = scratch;
        let (fu, fv, base) = (&mut fu[..n], &mut fv[..n], &mut base[..n]);
        for k in 0..n {
            let (u, v) = (x[k] * scale - 0.5, y[k] * scale - 0.5);
            let tu = (u - 0.5) + MAGIC;
            let tv = (v - 0.5) + MAGIC;
            fu[k] = u - (tu - MAGIC);
            fv[k] = v - (tv - MAGIC);
            base[k] = self.index(tu.to_bits() as usize & mask, tv.to_bits() as usize & mask);
        }
        let (ta, tb, tc, td) = (&mut ta[..n], &mut tb[..n], &mut tc[..n], &mut td[..n]);
        for k in 0..n {
            // Taps (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1): offsets 0, 1, 9, 10.
            let q = &self.data[base[k]..base[k] + STRIDE + 2];
            ta[k] = i32::from(q[0]);
            tb[k] = i32::from(q[1]);
            tc[k] = i32::from(q[STRIDE]);
            td[k] = i32::from(q[STRIDE + 1]);
        }
        for k in 0..n {
            let (a, b, c, d) = (
                f64::from(ta[k]),
                f64::from(tb[k]),
                f64::from(tc[k]),
                f64::from(td[k]),
            );
            let top = a + fu[k] * (b - a);
            let bottom = c + fu[k] * (d - c);
            out[k] = (top + fv[k] * (bottom - top)) * (1.0 / 65535.0);
        }
    }

    /// The next mip level: 2x2 box average.
    fn halve(&self) -> Tile {
        let n = self.size / 2;
        let mut rows = vec![0u16; n * n];
        for j in 0..n {
            for i in 0..n {
                let s = |a: usize, b: usize| u32::from(self.at(a, b));
                let sum = s(2 * i, 2 * j)
                    + s(2 * i + 1, 2 * j)
                    + s(2 * i, 2 * j + 1)
                    + s(2 * i + 1, 2 * j + 1);
                rows[j * n + i] = ((sum + 2) / 4) as u16;
            }
        }
        Tile::from_row_major(n, &rows)
    }
}

/// A tile and its box-filtered mip pyramid, sampled trilinearly by footprint.
#[derive(Debug, Clone)]
struct Pyramid {
    levels: Vec<Tile>,
    inv_texel: f64,
    /// Texels per metre of each level.
    scales: Vec<f64>,
}

impl Pyramid {
    fn new(base: Tile, texel_m: f64) -> Self {
        let mut levels = vec![base];
        while let Some(last) = levels.last() {
            if last.size <= BLOCK {
                break;
            }
            let next = last.halve();
            levels.push(next);
        }
        let scales = (0..levels.len())
            .map(|i| 1.0 / (texel_m * (1u64 << i) as f64))
            .collect();
        Self {
            levels,
            inv_texel: 1.0 / texel_m,
            scales,
        }
    }

    /// Bilinear sample of level `i` at world `(x, y)`.
    #[inline(always)]
    fn at_level(&self, i: usize, x_m: f64, y_m: f64) -> f64 {
        let scale = self.scales[i];
        self.levels[i].bilinear(x_m * scale - 0.5, y_m * scale - 0.5)
    }

    /// Level of [`Self::sample_nearest_level`].
    #[inline(always)]
    fn nearest_level(&self, footprint_m: f64) -> usize {
        let ratio = footprint_m * self.inv_texel;
        let top = self.levels.len() - 1;
        if ratio > 1.414 {
            ((fast_log2(ratio) + 0.5) as usize).min(top)
        } else {
            0
        }
    }

    /// As [`Self::sample`] without blending levels (one lookup; for low-contrast layers).
    #[inline(always)]
    fn sample_nearest_level(&self, x_m: f64, y_m: f64, footprint_m: f64) -> f64 {
        self.at_level(self.nearest_level(footprint_m), x_m, y_m)
    }

    /// Level `i0` and blend weight `t` towards level `i0 + 1` of [`Self::sample`]
    /// (`t = 0` on the last level).
    #[inline(always)]
    fn level_blend(&self, footprint_m: f64) -> (usize, f64) {
        let ratio = footprint_m * self.inv_texel;
        let top = (self.levels.len() - 1) as f64;
        let level = if ratio > 1.0 {
            fast_log2(ratio).min(top)
        } else {
            0.0
        };
        let i0 = level as usize;
        let t = ((level - i0 as f64 - 0.375) * 4.0).clamp(0.0, 1.0);
        if i0 + 1 < self.levels.len() {
            (i0, t)
        } else {
            (i0, 0.0)
        }
    }

    /// Value at world `(x, y)` averaged over about `footprint_m`: level
    /// `log2(footprint / texel)`, blended with the next level over the middle quarter of each
    /// octave (one lookup for three quarters of the pixels, no sharp level seams).
    #[inline(always)]
    fn sample(&self, x_m: f64, y_m: f64, footprint_m: f64) -> f64 {
        let (i0, t) = self.level_blend(footprint_m);
        let a = self.at_level(i0, x_m, y_m);
        if t > 0.0 {
            a + t * (self.at_level(i0 + 1, x_m, y_m) - a)
        } else {
            a
        }
    }
}

/// Points per batch of [`AlbedoTexture::albedo_filtered_batch`].
const BATCH: usize = 64;

/// Per-point values of [`Tile::bilinear_batch`]: texel fractions, storage indices and the four
/// taps.
struct BilinearScratch {
    fu: [f64; BATCH],
    fv: [f64; BATCH],
    base: [usize; BATCH],
    ta: [i32; BATCH],
    tb: [i32; BATCH],
    tc: [i32; BATCH],
    td: [i32; BATCH],
}

/// Working arrays of [`AlbedoTexture::albedo_filtered_batch`] for one batch: fine level per
/// point and the first points of the runs of equal level (fine, blend, detail); the points blending with the next fine level (batch index, level, weight, world
/// coordinates); the points with a detail layer (batch index, level, weight, rotated
/// coordinates); the looked-up values and the lookups' scratch.
struct BatchScratch {
    level: [u8; BATCH],
    fine_runs: [u8; BATCH],
    blend_runs: [u8; BATCH],
    detail_runs: [u8; BATCH],
    bk: [u8; BATCH],
    bl: [u8; BATCH],
    bt: [f64; BATCH],
    bx: [f64; BATCH],
    by: [f64; BATCH],
    dk: [u8; BATCH],
    dl: [u8; BATCH],
    dw: [f64; BATCH],
    dx: [f64; BATCH],
    dy: [f64; BATCH],
    values: [f64; BATCH],
    bilinear: BilinearScratch,
}

impl BatchScratch {
    const fn new() -> Self {
        Self {
            level: [0; BATCH],
            fine_runs: [0; BATCH],
            blend_runs: [0; BATCH],
            detail_runs: [0; BATCH],
            bk: [0; BATCH],
            bl: [0; BATCH],
            bt: [0.0; BATCH],
            bx: [0.0; BATCH],
            by: [0.0; BATCH],
            dk: [0; BATCH],
            dl: [0; BATCH],
            dw: [0.0; BATCH],
            dx: [0.0; BATCH],
            dy: [0.0; BATCH],
            values: [0.0; BATCH],
            bilinear: BilinearScratch {
                fu: [0.0; BATCH],
                fv: [0.0; BATCH],
                base: [0; BATCH],
                ta: [0; BATCH],
                tb: [0; BATCH],
                tc: [0; BATCH],
                td: [0; BATCH],
            },
        }
    }
}

thread_local! {
    /// The working arrays of this thread's batches (set up once per thread, not zeroed per
    /// call).
    static BATCH_SCRATCH: RefCell<BatchScratch> = const { RefCell::new(BatchScratch::new()) };
}

/// Procedural albedo texture of sandy ground with pebbles (see the module documentation).
///
/// Indexed by world `x, y` (frame `W`, m); deterministic from [`TextureParams::seed`]
/// (generation is parallel, but every texel is a pure function of the seed and its index).
#[derive(Debug, Clone)]
pub struct AlbedoTexture {
    params: TextureParams,
    fine: Pyramid,
    detail: Pyramid,
    /// `(sin, cos)` of the detail layer's rotation.
    detail_rotation: (f64, f64),
}

/// Detail tile side, texels, and texel size, m.
const DETAIL_SIZE: usize = 512;
const DETAIL_TEXEL_M: f64 = 0.001;
/// Rotation of the detail layer against the world axes, rad (so its 0.5 m period never lines up
/// with the fine tile).
const DETAIL_ANGLE_RAD: f64 = 0.61;

impl AlbedoTexture {
    /// Generate the texture (about 1 s on one core for the default 2048^2 tile).
    pub fn new(params: TextureParams) -> Self {
        let size_log2 = params.size_log2.clamp(6, 13);
        let size = 1usize << size_log2;
        let fine = Pyramid::new(fine_tile(&params, size), params.texel_m);
        let detail = Pyramid::new(detail_tile(&params, DETAIL_SIZE), DETAIL_TEXEL_M);
        Self {
            params,
            fine,
            detail,
            detail_rotation: DETAIL_ANGLE_RAD.sin_cos(),
        }
    }

    /// The parameters this texture was made from.
    pub fn params(&self) -> &TextureParams {
        &self.params
    }

    /// Period of the texture, m.
    pub fn period_m(&self) -> f64 {
        self.params.texel_m * self.fine.levels[0].size as f64
    }

    /// Point-sampled albedo at world `(x_m, y_m)` (finest levels, bilinear), in `[0, 1]`.
    pub fn albedo(&self, x_m: f64, y_m: f64) -> f64 {
        self.albedo_filtered(x_m, y_m, 0.0)
    }

    /// Albedo at world `(x_m, y_m)` averaged over a footprint of about `footprint_m` (m): the
    /// fine pyramid is sampled trilinearly at level `log2(footprint / texel)`; the millimetre
    /// detail layer fades out between footprints of one and one and a half fine texels.
    pub fn albedo_filtered(&self, x_m: f64, y_m: f64, footprint_m: f64) -> f64 {
        self.filtered(x_m, y_m, footprint_m)
    }

    /// [`Self::albedo_filtered`], always inlined.
    #[inline(always)]
    fn filtered(&self, x_m: f64, y_m: f64, footprint_m: f64) -> f64 {
        let fine = self.fine.sample(x_m, y_m, footprint_m);
        // The detail tile stores 0.5 * factor so that factors up to 2 fit in u16.
        let mut albedo = fine;
        let weight = self.detail_weight(footprint_m);
        if weight > 0.0 {
            albedo *= self.detail_factor(x_m, y_m, footprint_m, weight);
        }
        albedo.clamp(0.0, 1.0)
    }

    /// Weight of the detail layer at a footprint (0: none).
    #[inline(always)]
    fn detail_weight(&self, footprint_m: f64) -> f64 {
        if self.params.detail_contrast > 0.0 {
            (3.0 - 2.0 * footprint_m * self.fine.inv_texel).min(1.0)
        } else {
            0.0
        }
    }

    /// Factor of the detail layer with weight `weight`.
    #[inline(always)]
    fn detail_factor(&self, x_m: f64, y_m: f64, footprint_m: f64, weight: f64) -> f64 {
        let (s, c) = self.detail_rotation;
        let (u, v) = (c * x_m - s * y_m, s * x_m + c * y_m);
        let detail = self.detail.sample_nearest_level(u, v, footprint_m);
        1.0 + weight * (2.0 * detail - 1.0)
    }

    /// [`Self::albedo_filtered`] of many points: `out[k]` for `(x_m[k], y_m[k],
    /// footprint_m[k])` (bit-identical to the one-point form). The lookups of each layer run
    /// as separate tight loops over up to 64 points, which lets the processor overlap their
    /// memory accesses; the renderer calls this once per row of ground pixels. The working
    /// arrays are kept per thread (every entry read is written first in the same call, so the
    /// values never depend on earlier calls).
    pub fn albedo_filtered_batch(
        &self,
        x_m: &[f64],
        y_m: &[f64],
        footprint_m: &[f64],
        out: &mut [f64],
    ) {
        let done = BATCH_SCRATCH
            .try_with(|cell| match cell.try_borrow_mut() {
                Ok(mut scratch) => {
                    self.batch_with(x_m, y_m, footprint_m, out, &mut scratch);
                    true
                }
                Err(_) => false,
            })
            .unwrap_or(false);
        if !done {
            let mut scratch = Box::new(BatchScratch::new());
            self.batch_with(x_m, y_m, footprint_m, out, &mut scratch);
        }
    }

    /// [`Self::albedo_filtered_batch`] with the working arrays `s`.
    fn batch_with(
        &self,
        x_m: &[f64],
        y_m: &[f64],
        footprint_m: &[f64],
        out: &mut [f64],
        s: &mut BatchScratch,
    ) {
        let n = out
            .len()
            .min(x_m.len())
            .min(y_m.len())
            .min(footprint_m.len());
        for start in (0..n).step_by(BATCH) {
            let end = (start + BATCH).min(n);
            let x = &x_m[start..end];
            let y = &y_m[start..end];
            let f = &footprint_m[start..end];
            let out = &mut out[start..end];
            let plan = self.plan_batch(x, y, f, s);
            self.look_up_batch(x, y, out, s, &plan);
            for o in out.iter_mut() {
                *o = o.clamp(0.0, 1.0);
            }
        }
    }

    /// The levels of one batch of at most [`BATCH`] points into `s`.
    ///
    /// Levels from one fast_log2 per point: its integer part is the exponent of the ratio
    /// footprint / texel and its fraction the mantissa (the same values as
    /// Pyramid::level_blend and Pyramid::nearest_level with a four times finer texel). The
    /// points that blend with the next fine level and those with a detail layer are gathered on
    /// the way (batch index, level, weight, coordinates). Runs of equal level (the level
    /// changes slowly along a row) are noted on the way: the first point of each run of the
    /// fine lookups, the blends and the details.
    #[inline(always)]
    fn plan_batch(&self, x: &[f64], y: &[f64], f: &[f64], s: &mut BatchScratch) -> BatchPlan {
        let fine_top = self.fine.levels.len() - 1;
        let detail_top = self.detail.levels.len() - 1;
        let detail_on = self.params.detail_contrast > 0.0;
        let (sin, cos) = self.detail_rotation;
        let inv_texel = self.fine.inv_texel;
        let count = x.len();
        let level = &mut s.level[..count];
        let (mut blends, mut details) = (0, 0);
        let (mut fine_runs, mut blend_runs, mut detail_runs) = (0, 0, 0);
        let (mut fine_prev, mut blend_prev, mut detail_prev) = (u8::MAX, u8::MAX, u8::MAX);
        for k in 0..count {
            let ratio = f[k] * inv_texel;
            let bits = ratio.to_bits();
            let exponent = ((bits >> 52) & 0x7ff) as i64 - 1023;
            let fraction =
                f64::from_bits((bits & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000) - 1.0;
            let i0 = if ratio <= 1.0 || exponent < 0 {
                0
            } else if exponent as usize >= fine_top {
                fine_top
            } else {
                let t = ((fraction - 0.375) * 4.0).clamp(0.0, 1.0);
                if t > 0.0 {
                    let lv = exponent as u8 + 1;
                    if lv != blend_prev {
                        s.blend_runs[blend_runs] = blends as u8;
                        blend_runs += 1;
                        blend_prev = lv;
                    }
                    s.bk[blends] = k as u8;
                    s.bl[blends] = lv;
                    s.bt[blends] = t;
                    s.bx[blends] = x[k];
                    s.by[blends] = y[k];
                    blends += 1;
                }
                exponent as usize
            };
            let lv = i0 as u8;
            if lv != fine_prev {
                s.fine_runs[fine_runs] = k as u8;
                fine_runs += 1;
                fine_prev = lv;
            }
            level[k] = lv;
            let weight = (3.0 - 2.0 * ratio).min(1.0);
            if detail_on && weight > 0.0 {
                // Detail texel = fine texel / 4: log2 of its ratio is exponent + 2 +
                // fraction, rounded to the nearest level.
                let d = if ratio * 4.0 > 1.414 {
                    ((exponent + 2 + i64::from(fraction >= 0.5)).max(0) as usize).min(detail_top)
                } else {
                    0
                };
                let d = d as u8;
                if d != detail_prev {
                    s.detail_runs[detail_runs] = details as u8;
                    detail_runs += 1;
                    detail_prev = d;
                }
                s.dk[details] = k as u8;
                s.dl[details] = d;
                s.dw[details] = weight;
                s.dx[details] = cos * x[k] - sin * y[k];
                s.dy[details] = sin * x[k] + cos * y[k];
                details += 1;
            }
        }
        BatchPlan {
            count,
            blends,
            details,
            fine_runs,
            blend_runs,
            detail_runs,
        }
    }

    /// The lookups of one planned batch into `out`, run by run, each through the tile's batch
    /// lookup: the fine level, the blend with the next level, the detail layer (before the
    /// clamp).
    #[inline(always)]
    fn look_up_batch(
        &self,
        x: &[f64],
        y: &[f64],
        out: &mut [f64],
        s: &mut BatchScratch,
        plan: &BatchPlan,
    ) {
        let BatchPlan {
            count,
            blends,
            details,
            fine_runs,
            blend_runs,
            detail_runs,
        } = *plan;
        // Lookups run by run, each through the tile's batch lookup.
        for r in 0..fine_runs {
            let k = usize::from(s.fine_runs[r]);
            let e = run_end(&s.fine_runs[..fine_runs], r, count);
            let lv = usize::from(s.level[k]);
            let (tile, scale) = (&self.fine.levels[lv], self.fine.scales[lv]);
            tile.bilinear_batch(&x[k..e], &y[k..e], scale, &mut out[k..e], &mut s.bilinear);
        }
        // The blend with the next level, for the points with t > 0.
        let values = &mut s.values;
        for r in 0..blend_runs {
            let j = usize::from(s.blend_runs[r]);
            let e = run_end(&s.blend_runs[..blend_runs], r, blends);
            let lv = usize::from(s.bl[j]);
            let (tile, scale) = (&self.fine.levels[lv], self.fine.scales[lv]);
            let (bx, by) = (&s.bx[j..e], &s.by[j..e]);
            tile.bilinear_batch(bx, by, scale, &mut values[j..e], &mut s.bilinear);
        }
        for ((&k, &t), &value) in s.bk[..blends]
            .iter()
            .zip(&s.bt[..blends])
            .zip(&values[..blends])
        {
            let o = &mut out[usize::from(k)];
            *o += t * (value - *o);
        }
        // The detail layer, in its rotated coordinates.
        for r in 0..detail_runs {
            let j = usize::from(s.detail_runs[r]);
            let e = run_end(&s.detail_runs[..detail_runs], r, details);
            let d = usize::from(s.dl[j]);
            let (tile, scale) = (&self.detail.levels[d], self.detail.scales[d]);
            let (dx, dy) = (&s.dx[j..e], &s.dy[j..e]);
            tile.bilinear_batch(dx, dy, scale, &mut values[j..e], &mut s.bilinear);
        }
        for ((&k, &weight), &value) in s.dk[..details]
            .iter()
            .zip(&s.dw[..details])
            .zip(&values[..details])
        {
            out[usize::from(k)] *= 1.0 + weight * (2.0 * value - 1.0);
        }
    }
}

/// What [`AlbedoTexture::plan_batch`] found in a batch: its points, blends and details, and
/// the runs of equal level of each.
#[derive(Clone, Copy)]
struct BatchPlan {
    count: usize,
    blends: usize,
    details: usize,
    fine_runs: usize,
    blend_runs: usize,
    detail_runs: usize,
}

/// End of run `r` whose first points are `starts` (the last run ends at `count`).
#[inline(always)]
fn run_end(starts: &[u8], r: usize, count: usize) -> usize {
    starts.get(r + 1).map_or(count, |&e| usize::from(e))
}

/// `log2(x)` for `x >= 1` to within 0.09 (exponent plus linear mantissa), enough to choose
/// and blend mip levels.
#[inline]
fn fast_log2(x: f64) -> f64 {
    let bits = x.to_bits();
    let exponent = ((bits >> 52) & 0x7ff) as f64 - 1023.0;
    let mantissa = f64::from_bits((bits & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000);
    exponent + (mantissa - 1.0)
}

/// Fine tile: sand noise plus pebbles.
fn fine_tile(p: &TextureParams, size: usize) -> Tile {
    let seed = p.seed;
    // Octaves: wavelength in texels 128, 64, ..., 4 (0.51 m ... 16 mm at 4 mm texels).
    let octaves: [(f64, f64); 6] = [
        (128.0, 1.0),
        (64.0, 0.85),
        (32.0, 0.75),
        (16.0, 0.7),
        (8.0, 0.6),
        (4.0, 0.45),
    ];
    let norm: f64 = 1.0 / octaves.iter().map(|o| o.1 * o.1).sum::<f64>().sqrt();
    let layers = octave_layers(&octaves, size, |k| seed.wrapping_add(k * 0x1000));
    let mut field = vec![0f32; size * size];
    // Gradient noise has a standard deviation near 0.2 per octave.
    layered_noise(&layers, size, &mut field, |s| (s * norm * 5.0) as f32);
    // Coarse layer: a quarter-resolution tile of the same period, bilinear.
    let coarse = coarse_tile(p, size / 4);
    let mut albedo: Vec<f32> = field
        .iter()
        .enumerate()
        .map(|(idx, &n)| {
            let (i, j) = ((idx % size) as f64, (idx / size) as f64);
            let factor = 2.0 * coarse.bilinear((i + 0.5) / 4.0 - 0.5, (j + 0.5) / 4.0 - 0.5);
            (factor * p.mean_albedo * (1.0 + p.sand_contrast * f64::from(n))) as f32
        })
        .collect();
    stamp_pebbles(p, size, &mut albedo);
    let rows: Vec<u16> = albedo
        .iter()
        .map(|&a| (f64::from(a).clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    Tile::from_row_major(size, &rows)
}

/// Pebbles: soft-edged ellipses blended over the sand, wrapping around the tile edges.
fn stamp_pebbles(p: &TextureParams, size: usize, albedo: &mut [f32]) {
    let texel = p.texel_m;
    let area_m2 = (size as f64 * texel).powi(2);
    let count = (p.pebbles_per_m2.max(0.0) * area_m2).round() as u64;
    let mask = size - 1;
    for k in 0..count {
        let h = |n: u64| unit_f64(hash3(p.seed ^ 0x005e_b1e5, k, n));
        let cx = h(0) * size as f64;
        let cy = h(1) * size as f64;
        // Radius: mostly small, a few large (power law), 6 mm ... 40 mm.
        let radius_m = 0.006 * (40.0f64 / 6.0).powf(h(2).powi(2));
        let a = radius_m / texel;
        let b = a * (0.55 + 0.45 * h(3));
        let theta = h(4) * std::f64::consts::PI;
        let (st, ct) = theta.sin_cos();
        // Half dark basalt-like (0.35-0.7 of the mean), half light (1.3-1.9 of the mean).
        let tone = if h(5) < 0.5 {
            0.35 + 0.35 * h(6)
        } else {
            1.3 + 0.6 * h(6)
        };
        let pebble_albedo = (p.mean_albedo * tone) as f32;
        let reach = a.ceil() as i64 + 1;
        let (ci, cj) = (cx.floor() as i64, cy.floor() as i64);
        for dj in -reach..=reach {
            for di in -reach..=reach {
                let x = (ci + di) as f64 + 0.5 - cx;
                let y = (cj + dj) as f64 + 0.5 - cy;
                let xr = ct * x + st * y;
                let yr = -st * x + ct * y;
                // Signed distance to the ellipse rim, texels (approximate).
                let r = ((xr / a).powi(2) + (yr / b).powi(2)).sqrt();
                let d = (r - 1.0) * b;
                let w = (0.5 - d).clamp(0.0, 1.0) as f32;
                if w > 0.0 {
                    // Slight darkening towards the rim reads as relief.
                    let rim = (1.0 - 0.25 * r.min(1.0).powi(4)) as f32;
                    let idx = (((cj + dj) as usize) & mask) * size + (((ci + di) as usize) & mask);
                    let cell = &mut albedo[idx];
                    *cell += w * (pebble_albedo * rim - *cell);
                }
            }
        }
    }
}

/// Coarse tile (16 mm texels at the default size): wavelengths 0.5-4.1 m, stores
/// `0.5 * (1 + contrast * noise)`.
fn coarse_tile(p: &TextureParams, size: usize) -> Tile {
    let octaves: [(f64, f64); 4] = [(256.0, 1.0), (128.0, 0.7), (64.0, 0.5), (32.0, 0.35)];
    let norm: f64 = 1.0 / octaves.iter().map(|o| o.1 * o.1).sum::<f64>().sqrt();
    let seed = p.seed ^ 0xc0a7_5e00;
    // Per octave: wavelength (small tiles: none beyond the tile, so the tile stays seamless),
    // amplitude and the hashed lattice.
    let layers: Vec<(f64, f64, GradientLattice)> = octaves
        .iter()
        .enumerate()
        .map(|(k, &(wavelength, amp))| {
            let wavelength = wavelength.min(size as f64);
            let period = ((size as f64 / wavelength) as u64).max(1);
            (
                wavelength,
                amp,
                GradientLattice::new(period, seed.wrapping_add(k as u64)),
            )
        })
        .collect();
    let mut rows = vec![0u16; size * size];
    layered_noise(&layers, size, &mut rows, |s| {
        let factor = (1.0 + p.coarse_contrast * s * norm * 5.0).clamp(0.2, 1.99);
        (0.5 * factor * 65535.0).round() as u16
    });
    Tile::from_row_major(size, &rows)
}

/// `out[j * size + i] = finish(sum over layers of amp * lattice.noise(i / wavelength,
/// j / wavelength))`, the sum taken in layer order from 0 (as a per-texel loop would), one row
/// at a time with each lattice's column terms computed once.
fn layered_noise<T: Send>(
    layers: &[(f64, f64, GradientLattice)],
    size: usize,
    out: &mut [T],
    finish: impl Fn(f64) -> T + Sync,
) {
    let columns: Vec<LatticeColumns> = layers
        .iter()
        .map(|(wavelength, _, lattice)| lattice.columns(size, *wavelength))
        .collect();
    out.par_chunks_mut(size).enumerate().for_each_init(
        || vec![0.0f64; size],
        |acc, (j, row)| {
            acc.fill(0.0);
            for ((wavelength, amp, lattice), cols) in layers.iter().zip(&columns) {
                lattice.add_row(cols, j as f64 / wavelength, *amp, acc);
            }
            for (o, &s) in row.iter_mut().zip(acc.iter()) {
                *o = finish(s);
            }
        },
    );
}

/// Per octave of `octaves` (`(wavelength, amplitude)`, texels): the wavelength (small tiles:
/// none beyond the tile, so the tile stays seamless), the amplitude and the hashed gradient
/// lattice of period `size / wavelength`, seeded with `seed_of(octave index)`.
fn octave_layers(
    octaves: &[(f64, f64)],
    size: usize,
    seed_of: impl Fn(u64) -> u64,
) -> Vec<(f64, f64, GradientLattice)> {
    octaves
        .iter()
        .enumerate()
        .map(|(k, &(wavelength, amp))| {
            let wavelength = wavelength.min(size as f64);
            let period = (size as f64 / wavelength) as u64;
            (
                wavelength,
                amp,
                GradientLattice::new(period, seed_of(k as u64)),
            )
        })
        .collect()
}

/// Detail tile (1 mm texels, period 0.51 m): sand grain noise of wavelengths 2-16 mm,
/// stores `0.5 * (1 + contrast * noise)`.
fn detail_tile(p: &TextureParams, size: usize) -> Tile {
    let octaves: [(f64, f64); 4] = [(16.0, 1.0), (8.0, 0.9), (4.0, 0.8), (2.0, 0.6)];
    let norm: f64 = 1.0 / octaves.iter().map(|o| o.1 * o.1).sum::<f64>().sqrt();
    let seed = p.seed ^ 0xde7a_11ed;
    let layers = octave_layers(&octaves, size, |k| seed.wrapping_add(k));
    let mut rows = vec![0u16; size * size];
    layered_noise(&layers, size, &mut rows, |s| {
        let factor = (1.0 + p.detail_contrast * s * norm * 5.0).clamp(0.2, 1.99);
        (0.5 * factor * 65535.0).round() as u16
    });
    Tile::from_row_major(size, &rows)
}

/// A terrain whose heights and normals come from `inner` and whose albedo is the procedural
/// texture (the inner surface's own albedo is ignored).
#[derive(Debug, Clone)]
pub struct TexturedSurface<H> {
    /// The surface giving the heights.
    pub inner: H,
    /// The albedo texture (shared: it is several megabytes).
    pub texture: Arc<AlbedoTexture>,
}

impl<H> TexturedSurface<H> {
    /// Wrap `inner` with `texture`.
    pub fn new(inner: H, texture: Arc<AlbedoTexture>) -> Self {
        Self { inner, texture }
    }
}

impl<H: TerrainSurface> TerrainSurface for TexturedSurface<H> {
    fn height_m(&self, x_m: f64, y_m: f64) -> f64 {
        self.inner.height_m(x_m, y_m)
    }
    fn albedo(&self, x_m: f64, y_m: f64) -> f64 {
        self.texture.albedo(x_m, y_m)
    }
    fn normal_up(&self, x_m: f64, y_m: f64) -> [f64; 3] {
        self.inner.normal_up(x_m, y_m)
    }
}

impl<H: TerrainSurface> FilteredAlbedo for TexturedSurface<H> {
    #[inline(always)]
    fn albedo_filtered(&self, x_m: f64, y_m: f64, footprint_m: f64) -> f64 {
        self.texture.filtered(x_m, y_m, footprint_m)
    }
    fn albedo_filtered_batch(
        &self,
        x_m: &[f64],
        y_m: &[f64],
        footprint_m: &[f64],
        out: &mut [f64],
    ) {
        self.texture
            .albedo_filtered_batch(x_m, y_m, footprint_m, out);
    }
}

/// A bare height function `(x_m, y_m) -> height_m` (positive up) as a [`TerrainSurface`] with a
/// uniform albedo of 0.5; wrap it in [`TexturedSurface`] to give it texture.
#[derive(Debug, Clone, Copy)]
pub struct HeightFn<F>(pub F);

impl<F: Fn(f64, f64) -> f64 + Sync> TerrainSurface for HeightFn<F> {
    fn height_m(&self, x_m: f64, y_m: f64) -> f64 {
        (self.0)(x_m, y_m)
    }
    fn albedo(&self, _x_m: f64, _y_m: f64) -> f64 {
        0.5
    }
}

impl<F: Fn(f64, f64) -> f64 + Sync> FilteredAlbedo for HeightFn<F> {}
