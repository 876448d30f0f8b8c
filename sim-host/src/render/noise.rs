//! Deterministic hashing, periodic gradient noise and Gaussian pixel noise.
//!
//! Everything here is a pure function of its integer inputs (no generator state), so any pixel
//! or texel can be computed in any order, on any thread, and give the same bits.

/// SplitMix64 finaliser: a bijective 64-bit mix with full avalanche.
#[inline]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Hash of a seed and two integers.
#[inline]
pub(crate) fn hash3(seed: u64, a: u64, b: u64) -> u64 {
    mix64(seed ^ mix64(a.wrapping_add(mix64(b.wrapping_add(0x9e37_79b9_7f4a_7c15)))))
}

/// `floor(x)` as an integer without a libm call (baseline x86-64 has no `roundsd`); saturates
/// like `as` on huge inputs.
#[inline]
pub(crate) fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    i - i64::from(x < i as f64)
}

/// Uniform value in `[0, 1)` from a hash (53 high bits).
#[inline]
pub(crate) fn unit_f64(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// 16 unit gradient directions for the gradient noise.
const GRADIENTS: [(f64, f64); 16] = {
    // cos and sin of k * 22.5 deg, written out (const fn has no trigonometry).
    const C: [f64; 5] = [
        1.0,
        0.923_879_532_511_286_7,
        std::f64::consts::FRAC_1_SQRT_2,
        0.382_683_432_365_089_8,
        0.0,
    ];
    [
        (C[0], C[4]),
        (C[1], C[3]),
        (C[2], C[2]),
        (C[3], C[1]),
        (C[4], C[0]),
        (-C[3], C[1]),
        (-C[2], C[2]),
        (-C[1], C[3]),
        (-C[0], C[4]),
        (-C[1], -C[3]),
        (-C[2], -C[2]),
        (-C[3], -C[1]),
        (C[4], -C[0]),
        (C[3], -C[1]),
        (C[2], -C[2]),
        (C[1], -C[3]),
    ]
};

/// Quintic fade `6t^5 - 15t^4 + 10t^3` (Perlin 2002).
#[inline]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Periodic 2-D gradient (Perlin) noise. `x`, `y` in lattice cells; the lattice wraps every
/// `period` cells (so a tile whose side is a multiple of the cell size is seamless). Output in
/// about `[-0.7, 0.7]`, zero mean, zero at lattice points. The reference form of
/// [`GradientLattice::noise`], which gives the same bits from a precomputed lattice.
#[cfg(test)]
pub(crate) fn gradient_noise(x: f64, y: f64, period: u64, seed: u64) -> f64 {
    noise_with(x, y, period.max(1) as i64, |i, j| {
        (hash3(seed, i as u64, j as u64) & 15) as usize
    })
}

/// Gradient noise at `(x, y)` on a lattice of period `p >= 1` whose gradient index at the
/// wrapped lattice point `(i, j)` is `grad_index(i, j)` (below 16).
#[cfg(test)]
#[inline(always)]
fn noise_with(x: f64, y: f64, p: i64, grad_index: impl Fn(i64, i64) -> usize) -> f64 {
    let x0 = floor_i64(x);
    let y0 = floor_i64(y);
    let fx = x - x0 as f64;
    let fy = y - y0 as f64;
    let i0 = x0.rem_euclid(p);
    let j0 = y0.rem_euclid(p);
    let i1 = (i0 + 1) % p;
    let j1 = (j0 + 1) % p;
    let grad = |i: i64, j: i64, dx: f64, dy: f64| {
        let (gx, gy) = GRADIENTS[grad_index(i, j) & 15];
        gx * dx + gy * dy
    };
    let n00 = grad(i0, j0, fx, fy);
    let n10 = grad(i1, j0, fx - 1.0, fy);
    let n01 = grad(i0, j1, fx, fy - 1.0);
    let n11 = grad(i1, j1, fx - 1.0, fy - 1.0);
    let u = fade(fx);
    let v = fade(fy);
    let a = n00 + u * (n10 - n00);
    let b = n01 + u * (n11 - n01);
    a + v * (b - a)
}

/// The gradient indices of one periodic noise lattice (`period x period` points, row-major),
/// hashed once: the texture generation evaluates each lattice point for many texels.
#[derive(Debug, Clone)]
pub(crate) struct GradientLattice {
    period: i64,
    grads: Vec<u8>,
}

impl GradientLattice {
    /// The lattice of period `period` (at least 1) and seed `seed`.
    pub(crate) fn new(period: u64, seed: u64) -> Self {
        let p = period.max(1);
        let grads = (0..p * p)
            .map(|n| (hash3(seed, n % p, n / p) & 15) as u8)
            .collect();
        Self {
            period: p as i64,
            grads,
        }
    }

    /// Gradient noise at `(x, y)` (lattice cells): bit-identical to
    /// `gradient_noise(x, y, period, seed)`. The reference form of [`Self::add_row`].
    #[cfg(test)]
    #[inline]
    pub(crate) fn noise(&self, x: f64, y: f64) -> f64 {
        let p = self.period;
        noise_with(x, y, p, |i, j| {
            usize::from(self.grads.get((j * p + i) as usize).copied().unwrap_or(0))
        })
    }

    /// The per-column terms of [`Self::noise`] at `x = i / wavelength` for `i` in `0..n`
    /// (cell, wrapped lattice columns, fraction and fade), computed once for a whole tile.
    pub(crate) fn columns(&self, n: usize, wavelength: f64) -> LatticeColumns {
        let p = self.period;
        let mut c = LatticeColumns {
            i0: Vec::with_capacity(n),
            i1: Vec::with_capacity(n),
            fx: Vec::with_capacity(n),
            u: Vec::with_capacity(n),
        };
        for i in 0..n {
            let x = i as f64 / wavelength;
            let x0 = floor_i64(x);
            let fx = x - x0 as f64;
            let i0 = x0.rem_euclid(p);
            c.i0.push(i0 as usize);
            c.i1.push(((i0 + 1) % p) as usize);
            c.fx.push(fx);
            c.u.push(fade(fx));
        }
        c
    }

    /// `acc[i] += amp * self.noise(i / wavelength, y)` for every column of `cols` (made by
    /// [`Self::columns`] with the same `wavelength`): the same operations as [`Self::noise`],
    /// so the same bits, with the row and column terms computed once.
    pub(crate) fn add_row(&self, cols: &LatticeColumns, y: f64, amp: f64, acc: &mut [f64]) {
        let p = self.period;
        let y0 = floor_i64(y);
        let fy = y - y0 as f64;
        let j0 = y0.rem_euclid(p);
        let j1 = (j0 + 1) % p;
        let v = fade(fy);
        let pu = p as usize;
        let row0 = &self.grads[j0 as usize * pu..(j0 as usize + 1) * pu];
        let row1 = &self.grads[j1 as usize * pu..(j1 as usize + 1) * pu];
        let grad = |g: u8, dx: f64, dy: f64| {
            let (gx, gy) = GRADIENTS[usize::from(g) & 15];
            gx * dx + gy * dy
        };
        for ((((s, &i0), &i1), &fx), &u) in acc
            .iter_mut()
            .zip(&cols.i0)
            .zip(&cols.i1)
            .zip(&cols.fx)
            .zip(&cols.u)
        {
            let n00 = grad(row0[i0], fx, fy);
            let n10 = grad(row0[i1], fx - 1.0, fy);
            let n01 = grad(row1[i0], fx, fy - 1.0);
            let n11 = grad(row1[i1], fx - 1.0, fy - 1.0);
            let a = n00 + u * (n10 - n00);
            let b = n01 + u * (n11 - n01);
            *s += amp * (a + v * (b - a));
        }
    }
}

/// Column terms of one lattice sampled along a tile row ([`GradientLattice::columns`]).
#[derive(Debug, Clone)]
pub(crate) struct LatticeColumns {
    i0: Vec<usize>,
    i1: Vec<usize>,
    fx: Vec<f64>,
    u: Vec<f64>,
}

/// Number of entries of the Gaussian quantile table (a power of two, at most 2^16: indices are
/// 16-bit fields of a hash).
pub(crate) const GAUSS_TABLE_LEN: usize = 1 << 14;
const _: () = assert!(GAUSS_TABLE_LEN.is_power_of_two() && GAUSS_TABLE_LEN <= 1 << 16);

/// The Gaussian quantile table (fixed size, so that masked indices need no bounds check).
pub(crate) type GaussTable = [f32; GAUSS_TABLE_LEN];

/// Table of standard-normal quantiles `Phi^-1((k + 1/2) / N)`, rescaled to unit variance.
///
/// Indexing it with a uniform hash draws from a discrete distribution with the Gaussian's
/// quantiles (tails cut at about 3.9 sigma), at the cost of one hash and one load per pixel.
pub(crate) fn gaussian_table() -> Box<GaussTable> {
    let n = GAUSS_TABLE_LEN;
    let mut t: Vec<f64> = (0..n)
        .map(|k| inverse_normal_cdf((k as f64 + 0.5) / n as f64))
        .collect();
    let var = t.iter().map(|v| v * v).sum::<f64>() / n as f64;
    let s = 1.0 / var.sqrt();
    t.iter_mut().for_each(|v| *v *= s);
    let mut table = Box::new([0.0f32; GAUSS_TABLE_LEN]);
    for (out, v) in table.iter_mut().zip(t) {
        *out = v as f32;
    }
    table
}

/// Inverse of the standard normal CDF (Acklam's rational approximation, relative error
/// 1.15e-9), for `p` in `(0, 1)`.
fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let p_low = 0.02425;
    if p < p_low {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - p_low {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        -inverse_normal_cdf(1.0 - p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_cdf_known_values() {
        assert!(inverse_normal_cdf(0.5).abs() < 1e-12);
        assert!((inverse_normal_cdf(0.975) - 1.959_963_985).abs() < 1e-8);
        assert!((inverse_normal_cdf(0.001) + 3.090_232_306).abs() < 1e-8);
    }

    #[test]
    fn gaussian_table_has_unit_variance_and_zero_mean() {
        let t = gaussian_table();
        let n = t.len() as f64;
        let mean = t.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let var = t.iter().map(|&v| f64::from(v) * f64::from(v)).sum::<f64>() / n;
        assert!(mean.abs() < 1e-6);
        assert!((var - 1.0).abs() < 1e-6);
    }

    #[test]
    fn gradient_noise_wraps_with_its_period() {
        for k in 0..50 {
            let x = 0.37 * k as f64;
            let y = 0.11 * k as f64 + 0.5;
            let a = gradient_noise(x, y, 8, 7);
            let b = gradient_noise(x + 8.0, y - 16.0, 8, 7);
            assert!((a - b).abs() < 1e-9);
            assert!(a.abs() < 1.0);
        }
    }

    #[test]
    fn gradient_lattice_gives_the_same_bits() {
        for (period, seed) in [(1u64, 3u64), (4, 7), (64, 0x1000), (512, 0xde7a_11ed)] {
            let lattice = GradientLattice::new(period, seed);
            for k in 0..400 {
                let x = 0.173 * k as f64 - 9.0;
                let y = 0.291 * k as f64 + 0.25 * (k % 7) as f64 - 20.0;
                let a = gradient_noise(x, y, period, seed);
                assert_eq!(a.to_bits(), lattice.noise(x, y).to_bits(), "{period} {k}");
            }
        }
    }

    #[test]
    fn lattice_rows_give_the_same_bits() {
        // Wavelengths of the texture octaves (powers of two) and two that are not.
        for (period, seed, wavelength) in [
            (1u64, 3u64, 64.0),
            (16, 7, 4.0),
            (8, 0x1000, 16.0),
            (5, 11, 12.8),
            (7, 0xde7a_11ed, 3.0),
        ] {
            let lattice = GradientLattice::new(period, seed);
            let n = 64;
            let cols = lattice.columns(n, wavelength);
            for j in 0..40 {
                let y = j as f64 / wavelength;
                let mut acc = vec![0.25; n];
                lattice.add_row(&cols, y, 0.7, &mut acc);
                for (i, &s) in acc.iter().enumerate() {
                    let reference = 0.25 + 0.7 * lattice.noise(i as f64 / wavelength, y);
                    assert_eq!(s.to_bits(), reference.to_bits(), "{period} {i} {j}");
                }
            }
        }
    }
}
