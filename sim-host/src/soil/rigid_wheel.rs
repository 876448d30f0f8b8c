//! Rigid wheel on deformable soil: the Wong-Reece stress distribution as used for small
//! planetary-rover wheels (Wong & Reece, J. Terramechanics 4(1), 1967; Iagnemma & Dubowsky,
//! *Mobile Robots in Rough Terrain*, Springer 2004; Ishigami, Miwa, Nagatani, Yoshida,
//! J. Field Robotics 24(3), 2007). See `docs/terramechanics.md` for the equations, parameters
//! and simplifications; the conventions (slip ratio, slip angle) are those of
//! [`crate::soil::terramechanics`].
//!
//! Angles `theta` are measured on the rim from the vertical through the axle, positive towards
//! the front; the soil touches the rim from the exit angle `theta_2 <= 0` to the entry angle
//! `theta_1`, the sinkage is `z = r (1 - cos theta_1)` and the rear sinkage `lambda z`
//! (`theta_2 = -acos(1 - lambda (1 - cos theta_1))`, Ishigami et al. 2007).
//!
//! - Normal stress, front region (`theta_m <= theta <= theta_1`):
//!   `sigma = r^n (k_c/b + k_phi) (cos theta - cos theta_1)^n`; rear region
//!   (`theta_2 <= theta < theta_m`): the same with `theta` replaced by the equivalent front
//!   angle `theta_1 - (theta - theta_2)/(theta_m - theta_2) (theta_1 - theta_m)`, with
//!   `theta_m = (a0 + a1 s) theta_1`.
//! - Shear (Janosi-Hanamoto): `tau_x = (c + sigma tan phi)(1 - exp(-j_x / K_x))`,
//!   `j_x = r [(theta_1 - theta) - (1 - s)(sin theta_1 - sin theta)]` for `s >= 0`;
//!   `tau_y = (c + sigma tan phi)(1 - exp(-j_y / K_y))`,
//!   `j_y = r (1 - s)(theta_1 - theta) tan |alpha|`.
//! - Forces: drawbar pull `F_x = r b int (tau_x cos theta - sigma sin theta)`, vertical
//!   `F_z = r b int (tau_x sin theta + sigma cos theta)`, side force magnitude
//!   `F_y = r b int tau_y` (no side-wall bulldozing term).
//! - `theta_1` is found so that `F_z` equals the wheel load (bisection, fixed iterations).
//!
//! The exact functions ([`wheel_forces`], [`slip_for_drawbar_pull`],
//! [`slip_angle_for_side_force`]) integrate over `theta` with 8-point Gauss-Legendre rules on
//! the front and the rear region and bisect with fixed iteration counts; they are the
//! reference. A [`WheelTable`] caches the same model on a grid of load, slip ratio and slip
//! angle when a run starts, so the six wheels at 200 Hz cost a few table look-ups each; tests
//! check the table against the exact functions.

use crate::soil::terramechanics::{Soil, Wheel};

/// Number of bisection iterations (interval width / 2^40).
const BISECTION_ITERATIONS: usize = 40;

/// Upper bound of the slip-angle search, rad (80 deg).
pub const MAX_SLIP_ANGLE_RAD: f64 = 80.0 * std::f64::consts::PI / 180.0;

/// Largest entry angle the sinkage search considers, rad (70 deg: sinkage 0.66 radius).
/// A load that needs more is reported as `buried`, with the forces at this angle.
pub const MAX_ENTRY_ANGLE_RAD: f64 = 70.0 * std::f64::consts::PI / 180.0;

/// Smallest entry angle of the table, rad (0.5 deg).
const MIN_ENTRY_ANGLE_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;

/// Gauss-Legendre nodes on `[-1, 1]` (8 points; symmetric pairs).
const GL_X: [f64; 4] = [
    0.183_434_642_495_649_8,
    0.525_532_409_916_329,
    0.796_666_477_413_626_7,
    0.960_289_856_497_536_3,
];
/// Gauss-Legendre weights of [`GL_X`].
const GL_W: [f64; 4] = [
    0.362_683_783_378_362,
    0.313_706_645_877_887_3,
    0.222_381_034_453_374_5,
    0.101_228_536_290_376_3,
];

/// Forces of the soil on the wheel at one entry angle (body of the integrals).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Integrals {
    /// Drawbar pull, N (positive forward).
    fx: f64,
    /// Side-force magnitude, N (opposing the lateral sliding).
    fy: f64,
    /// Vertical force, N.
    fz: f64,
}

/// Everything that is fixed for one evaluation except the entry angle.
#[derive(Debug, Clone, Copy)]
struct Condition {
    /// `r^n (k_c/b + k_phi)`, Pa.
    k_eq: f64,
    n: f64,
    c: f64,
    tan_phi: f64,
    r: f64,
    b: f64,
    s: f64,
    a: f64,
    lambda: f64,
    tan_alpha: f64,
    k_x: f64,
    k_y: f64,
}

impl Condition {
    fn new(soil: &Soil, wheel: &Wheel, slip_ratio: f64, alpha_rad: f64) -> Self {
        let r = wheel.radius_m;
        let b = wheel.width_m;
        let s = slip_ratio.clamp(-1.0, 1.0);
        let alpha = alpha_rad.abs().min(MAX_SLIP_ANGLE_RAD);
        Self {
            k_eq: r.powf(soil.n) * (soil.k_c / b + soil.k_phi),
            n: soil.n,
            c: soil.cohesion_pa,
            tan_phi: soil.phi_rad.tan(),
            r,
            b,
            s,
            a: (soil.theta_m_a0 + soil.theta_m_a1 * s).clamp(0.0, 1.0),
            lambda: soil.exit_sinkage_ratio.clamp(0.0, 1.0),
            tan_alpha: alpha.tan(),
            k_x: soil.k_x(alpha),
            k_y: soil.k_y(alpha),
        }
    }

    /// The integrals at entry angle `theta_1`.
    fn integrals(&self, theta_1: f64) -> Integrals {
        if theta_1 <= 0.0 {
            return Integrals::default();
        }
        let theta_m = self.a * theta_1;
        let (sin1, cos1) = theta_1.sin_cos();
        let theta_2 = -(1.0 - self.lambda * (1.0 - cos1)).acos();
        let mut out = Integrals::default();
        // Front region [theta_m, theta_1] and rear region [theta_2, theta_m].
        for (lo, hi, front) in [(theta_m, theta_1, true), (theta_2, theta_m, false)] {
            let half = 0.5 * (hi - lo);
            if half <= 0.0 {
                continue;
            }
            let mid = 0.5 * (hi + lo);
            for (x, w) in GL_X.iter().zip(GL_W) {
                for theta in [mid - half * x, mid + half * x] {
                    let equivalent = if front {
                        theta
                    } else {
                        theta_1 - (theta - theta_2) / (theta_m - theta_2) * (theta_1 - theta_m)
                    };
                    let depth = (equivalent.cos() - cos1).max(0.0);
                    let sigma = if self.n == 1.0 {
                        self.k_eq * depth
                    } else {
                        self.k_eq * depth.powf(self.n)
                    };
                    let (sin_t, cos_t) = theta.sin_cos();
                    let arc = theta_1 - theta;
                    let chord = sin1 - sin_t;
                    // Shear displacements: driving (Wong); skidding with the contact time
                    // taken from the ground speed (see the module docs of terramechanics).
                    let (j_x, travel) = if self.s >= 0.0 {
                        (self.r * (arc - (1.0 - self.s) * chord), 1.0 - self.s)
                    } else {
                        (self.r * ((1.0 + self.s) * arc - chord), 1.0)
                    };
                    let j_y = self.r * travel * arc * self.tan_alpha;
                    let tau_max = self.c + sigma * self.tan_phi;
                    let tau_x = j_x.signum() * tau_max * -(-j_x.abs() / self.k_x).exp_m1();
                    let tau_y = tau_max * -(-j_y / self.k_y).exp_m1();
                    let weight = w * half * self.r * self.b;
                    out.fx += weight * (tau_x * cos_t - sigma * sin_t);
                    out.fz += weight * (tau_x * sin_t + sigma * cos_t);
                    out.fy += weight * tau_y;
                }
            }
        }
        out
    }

    /// Entry angle at which the vertical force carries `load_n`: bisection (fixed iterations)
    /// on `[0, MAX_ENTRY_ANGLE_RAD]`; the second value is `true` (buried) if even the largest
    /// angle does not carry the load.
    fn entry_angle(&self, load_n: f64) -> (f64, Integrals, bool) {
        let top = self.integrals(MAX_ENTRY_ANGLE_RAD);
        if top.fz < load_n {
            return (MAX_ENTRY_ANGLE_RAD, top, true);
        }
        let (mut lo, mut hi) = (0.0, MAX_ENTRY_ANGLE_RAD);
        for _ in 0..BISECTION_ITERATIONS {
            let mid = 0.5 * (lo + hi);
            if self.integrals(mid).fz < load_n {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let theta_1 = 0.5 * (lo + hi);
        (theta_1, self.integrals(theta_1), false)
    }
}

/// Steady-state forces of the soil on a rigid wheel.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WheelForces {
    /// Entry angle `theta_1`, rad.
    pub entry_angle_rad: f64,
    /// Sinkage `r (1 - cos theta_1)`, m.
    pub sinkage_m: f64,
    /// Drawbar pull (thrust minus resistance), N, along the rolling direction.
    pub drawbar_pull_n: f64,
    /// Side force, N, along the wheel's `+y` (opposes the lateral sliding).
    pub side_force_n: f64,
    /// Vertical force of the stress integrals, N (equals the load unless `buried`).
    pub vertical_n: f64,
    /// The soil cannot carry the load at the largest entry angle considered.
    pub buried: bool,
}

/// Forces on `wheel` under `load_n` at slip ratio `slip_ratio` and slip angle `alpha_rad`
/// (exact model: the entry angle is solved by bisection). Zero, negative or non-finite load
/// gives zero forces.
pub fn wheel_forces(
    soil: &Soil,
    wheel: &Wheel,
    load_n: f64,
    slip_ratio: f64,
    alpha_rad: f64,
) -> WheelForces {
    if !load_n.is_finite() || load_n <= 0.0 || slip_ratio.is_nan() || alpha_rad.is_nan() {
        return WheelForces::default();
    }
    let cond = Condition::new(soil, wheel, slip_ratio, alpha_rad);
    let (theta_1, f, buried) = cond.entry_angle(load_n);
    WheelForces {
        entry_angle_rad: theta_1,
        sinkage_m: wheel.radius_m * (1.0 - theta_1.cos()),
        drawbar_pull_n: f.fx,
        side_force_n: if alpha_rad == 0.0 {
            0.0
        } else {
            -alpha_rad.signum() * f.fy
        },
        vertical_n: f.fz,
        buried,
    }
}

/// Result of a slip-ratio inversion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlipSolution {
    /// Slip ratio (module convention), in `[-1, 1]`.
    pub slip_ratio: f64,
    /// The soil cannot deliver the demand: `slip_ratio` is then 1 (drive) or -1 (skid).
    pub saturated: bool,
}

/// Slip ratio at which the drawbar pull of [`wheel_forces`] (at slip angle `alpha_rad`)
/// equals `demand_n` (N, positive forward): bisection (fixed iterations) on `s` in `[-1, 1]`;
/// `saturated` with `s = 1` when the demand exceeds the pull at `s = 1`, with `s = -1` when it
/// is below the pull at `s = -1`.
pub fn slip_for_drawbar_pull(
    soil: &Soil,
    wheel: &Wheel,
    load_n: f64,
    alpha_rad: f64,
    demand_n: f64,
) -> SlipSolution {
    let dp = |s: f64| wheel_forces(soil, wheel, load_n, s, alpha_rad).drawbar_pull_n;
    if demand_n.is_nan() || dp(1.0) < demand_n {
        return SlipSolution {
            slip_ratio: 1.0,
            saturated: true,
        };
    }
    if dp(-1.0) > demand_n {
        return SlipSolution {
            slip_ratio: -1.0,
            saturated: true,
        };
    }
    let (mut lo, mut hi) = (-1.0, 1.0);
    for _ in 0..BISECTION_ITERATIONS {
        let mid = 0.5 * (lo + hi);
        if dp(mid) < demand_n {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    SlipSolution {
        slip_ratio: 0.5 * (lo + hi),
        saturated: false,
    }
}

/// Slip angle, rad, at which the side force of [`wheel_forces`] (at `slip_ratio`) equals
/// `demand_n` (N, along the wheel's `+y`), and whether the soil saturates. The angle has the
/// **opposite** sign of the demand (the soil pushes against the sliding). Bisection (fixed
/// iterations) on `|alpha|` in `[0, 80 deg]`; saturated (and `|alpha|` = 80 deg) when the
/// demand exceeds the side force at 80 deg.
pub fn slip_angle_for_side_force(
    soil: &Soil,
    wheel: &Wheel,
    load_n: f64,
    slip_ratio: f64,
    demand_n: f64,
) -> (f64, bool) {
    if demand_n == 0.0 || demand_n.is_nan() {
        return (0.0, false);
    }
    let sign = -demand_n.signum();
    let target = demand_n.abs();
    let f = |a: f64| -wheel_forces(soil, wheel, load_n, slip_ratio, a).side_force_n;
    if f(MAX_SLIP_ANGLE_RAD) < target {
        return (sign * MAX_SLIP_ANGLE_RAD, true);
    }
    let (mut lo, mut hi) = (0.0, MAX_SLIP_ANGLE_RAD);
    for _ in 0..BISECTION_ITERATIONS {
        let mid = 0.5 * (lo + hi);
        if f(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (sign * 0.5 * (lo + hi), false)
}

/// Slip ratios of the table (denser near 0, where the drawbar pull changes fastest).
const TABLE_SLIPS: [f64; 31] = [
    -1.0, -0.8, -0.6, -0.45, -0.35, -0.25, -0.18, -0.12, -0.08, -0.05, -0.03, -0.015, 0.0, 0.01,
    0.02, 0.035, 0.05, 0.07, 0.1, 0.14, 0.2, 0.26, 0.33, 0.4, 0.5, 0.6, 0.7, 0.8, 0.87, 0.94, 1.0,
];
/// Slip angles of the table, degrees.
const TABLE_ALPHAS_DEG: [f64; 17] = [
    0.0, 1.0, 2.0, 3.5, 5.0, 7.0, 9.0, 12.0, 15.0, 19.0, 24.0, 30.0, 38.0, 46.0, 56.0, 68.0, 80.0,
];
/// Loads of the table: geometric from [`TABLE_LOAD_MIN_N`], ratio `exp(TABLE_LOAD_STEP)`.
const TABLE_LOADS: usize = 40;
/// Smallest load of the table, N.
const TABLE_LOAD_MIN_N: f64 = 0.5;
/// Natural-log step of the table loads (0.5 N to about 1.3 kN).
const TABLE_LOAD_STEP: f64 = 0.2;
/// Entry angles at which the model is evaluated to build the table.
const TABLE_ENTRY_ANGLES: usize = 48;

/// One cell of a [`WheelTable`]: forces per unit load and sinkage.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Cell {
    /// Drawbar pull / load.
    dp: f64,
    /// Side-force magnitude / load.
    fy: f64,
    /// Sinkage, m.
    z: f64,
}

/// The rigid-wheel model of one wheel on one soil, tabulated over load (geometric grid),
/// slip ratio and slip-angle magnitude when a run starts; queries interpolate linearly
/// (log-load, slip, angle) and invert by scanning the tabulated curve. Building it evaluates
/// the stress integrals on a grid of entry angles for each (slip, angle) and resamples the
/// result at the table loads (no root finding).
#[derive(Debug, Clone)]
pub struct WheelTable {
    cells: Vec<Cell>,
}

/// Interpolation position on an axis: lower index and fraction.
#[derive(Debug, Clone, Copy)]
struct Pos {
    i: usize,
    t: f64,
}

fn pos_in(grid: &[f64], v: f64) -> Pos {
    let last = grid.len() - 1;
    if v <= grid[0] {
        return Pos { i: 0, t: 0.0 };
    }
    if v >= grid[last] {
        return Pos {
            i: last - 1,
            t: 1.0,
        };
    }
    let i = grid.partition_point(|&g| g <= v) - 1;
    Pos {
        i,
        t: (v - grid[i]) / (grid[i + 1] - grid[i]),
    }
}

impl WheelTable {
    /// Tabulate the model for `soil` and `wheel`.
    pub fn new(soil: &Soil, wheel: &Wheel) -> Self {
        let ns = TABLE_SLIPS.len();
        let na = TABLE_ALPHAS_DEG.len();
        let mut cells = vec![Cell::default(); TABLE_LOADS * ns * na];
        let step = (MAX_ENTRY_ANGLE_RAD - MIN_ENTRY_ANGLE_RAD) / (TABLE_ENTRY_ANGLES - 1) as f64;
        let thetas: Vec<f64> = (0..TABLE_ENTRY_ANGLES)
            .map(|k| MIN_ENTRY_ANGLE_RAD + step * k as f64)
            .collect();
        let mut column = vec![Integrals::default(); TABLE_ENTRY_ANGLES];
        for (js, &s) in TABLE_SLIPS.iter().enumerate() {
            for (ja, &a_deg) in TABLE_ALPHAS_DEG.iter().enumerate() {
                let cond = Condition::new(soil, wheel, s, a_deg.to_radians());
                for (c, &th) in column.iter_mut().zip(&thetas) {
                    *c = cond.integrals(th);
                }
                // Resample at the table loads: the first entry angle whose vertical force
                // reaches the load (interpolated in log force between grid angles).
                let mut k = 0;
                for jl in 0..TABLE_LOADS {
                    let load = Self::load(jl);
                    while k < TABLE_ENTRY_ANGLES && column[k].fz < load {
                        k += 1;
                    }
                    let cell = if k == 0 {
                        let f = column[0];
                        Cell {
                            dp: f.fx / f.fz.max(1e-12),
                            fy: f.fy / f.fz.max(1e-12),
                            z: wheel.radius_m * (1.0 - thetas[0].cos()),
                        }
                    } else if k == TABLE_ENTRY_ANGLES {
                        // Buried: what the largest entry angle delivers.
                        let f = column[k - 1];
                        Cell {
                            dp: f.fx / load,
                            fy: f.fy / load,
                            z: wheel.radius_m * (1.0 - thetas[k - 1].cos()),
                        }
                    } else {
                        let (f0, f1) = (column[k - 1], column[k]);
                        let t = ((load.ln() - f0.fz.max(1e-12).ln())
                            / (f1.fz.ln() - f0.fz.max(1e-12).ln()))
                        .clamp(0.0, 1.0);
                        let th = thetas[k - 1] + t * (thetas[k] - thetas[k - 1]);
                        let lerp = |a: f64, b: f64| a + t * (b - a);
                        Cell {
                            dp: lerp(f0.fx / f0.fz.max(1e-12), f1.fx / f1.fz),
                            fy: lerp(f0.fy / f0.fz.max(1e-12), f1.fy / f1.fz),
                            z: wheel.radius_m * (1.0 - th.cos()),
                        }
                    };
                    cells[Self::index(jl, js, ja)] = cell;
                }
            }
        }
        Self { cells }
    }

    fn load(jl: usize) -> f64 {
        TABLE_LOAD_MIN_N * (TABLE_LOAD_STEP * jl as f64).exp()
    }

    fn index(jl: usize, js: usize, ja: usize) -> usize {
        (jl * TABLE_SLIPS.len() + js) * TABLE_ALPHAS_DEG.len() + ja
    }

    fn load_pos(load_n: f64) -> Pos {
        let x = (load_n / TABLE_LOAD_MIN_N).ln() / TABLE_LOAD_STEP;
        let top = (TABLE_LOADS - 1) as f64;
        let x = x.clamp(0.0, top);
        let i = (x.floor() as usize).min(TABLE_LOADS - 2);
        Pos { i, t: x - i as f64 }
    }

    fn alpha_pos(alpha_rad: f64) -> Pos {
        pos_in(&TABLE_ALPHAS_DEG, alpha_rad.abs().to_degrees())
    }

    /// Cell interpolated over load and angle at slip index `js`.
    fn at_slip(&self, l: Pos, js: usize, a: Pos) -> Cell {
        let c = |jl: usize, ja: usize| self.cells[Self::index(jl, js, ja)];
        let mix = |x: Cell, y: Cell, t: f64| Cell {
            dp: x.dp + t * (y.dp - x.dp),
            fy: x.fy + t * (y.fy - x.fy),
            z: x.z + t * (y.z - x.z),
        };
        let lo = mix(c(l.i, a.i), c(l.i, a.i + 1), a.t);
        let hi = mix(c(l.i + 1, a.i), c(l.i + 1, a.i + 1), a.t);
        mix(lo, hi, l.t)
    }

    /// Interpolated forces (same meaning as [`wheel_forces`]; `entry_angle_rad` and
    /// `vertical_n` are not tabulated: `vertical_n` is the load).
    pub fn forces(&self, load_n: f64, slip_ratio: f64, alpha_rad: f64) -> WheelForces {
        if !load_n.is_finite() || load_n <= 0.0 || slip_ratio.is_nan() || alpha_rad.is_nan() {
            return WheelForces::default();
        }
        let l = Self::load_pos(load_n);
        let a = Self::alpha_pos(alpha_rad);
        let s = pos_in(&TABLE_SLIPS, slip_ratio);
        let c0 = self.at_slip(l, s.i, a);
        let c1 = self.at_slip(l, s.i + 1, a);
        let lerp = |x: f64, y: f64| x + s.t * (y - x);
        let fy = lerp(c0.fy, c1.fy) * load_n;
        let z = lerp(c0.z, c1.z);
        WheelForces {
            entry_angle_rad: 0.0,
            sinkage_m: z,
            drawbar_pull_n: lerp(c0.dp, c1.dp) * load_n,
            side_force_n: if alpha_rad == 0.0 {
                0.0
            } else {
                -alpha_rad.signum() * fy
            },
            vertical_n: load_n,
            buried: false,
        }
    }

    /// Slip ratio at which the tabulated drawbar pull (at `alpha_rad`) equals `demand_n`: the
    /// first crossing of the tabulated curve from `s = -1` upwards, interpolated linearly;
    /// saturated as [`slip_for_drawbar_pull`].
    pub fn slip_for_drawbar_pull(
        &self,
        load_n: f64,
        alpha_rad: f64,
        demand_n: f64,
    ) -> SlipSolution {
        if !load_n.is_finite() || load_n <= 0.0 || demand_n.is_nan() {
            return SlipSolution {
                slip_ratio: 1.0,
                saturated: true,
            };
        }
        let l = Self::load_pos(load_n);
        let a = Self::alpha_pos(alpha_rad);
        let target = demand_n / load_n;
        let mut prev = self.at_slip(l, 0, a).dp;
        if prev > target {
            return SlipSolution {
                slip_ratio: -1.0,
                saturated: true,
            };
        }
        for js in 1..TABLE_SLIPS.len() {
            let dp = self.at_slip(l, js, a).dp;
            if dp >= target {
                let t = if dp > prev {
                    (target - prev) / (dp - prev)
                } else {
                    1.0
                };
                let s0 = TABLE_SLIPS[js - 1];
                return SlipSolution {
                    slip_ratio: s0 + t * (TABLE_SLIPS[js] - s0),
                    saturated: false,
                };
            }
            prev = dp;
        }
        SlipSolution {
            slip_ratio: 1.0,
            saturated: true,
        }
    }

    /// Slip angle at which the tabulated side force (at `slip_ratio`) equals `demand_n`, and
    /// whether the soil saturates (same meaning as [`slip_angle_for_side_force`]).
    pub fn slip_angle_for_side_force(
        &self,
        load_n: f64,
        slip_ratio: f64,
        demand_n: f64,
    ) -> (f64, bool) {
        if demand_n == 0.0 || demand_n.is_nan() {
            return (0.0, false);
        }
        let sign = -demand_n.signum();
        if !load_n.is_finite() || load_n <= 0.0 {
            return (sign * MAX_SLIP_ANGLE_RAD, true);
        }
        let l = Self::load_pos(load_n);
        let s = pos_in(&TABLE_SLIPS, slip_ratio);
        let target = demand_n.abs() / load_n;
        let fy_at = |ja: usize| {
            let a = if ja + 1 < TABLE_ALPHAS_DEG.len() {
                Pos { i: ja, t: 0.0 }
            } else {
                Pos { i: ja - 1, t: 1.0 }
            };
            let c0 = self.at_slip(l, s.i, a).fy;
            let c1 = self.at_slip(l, s.i + 1, a).fy;
            c0 + s.t * (c1 - c0)
        };
        let mut prev = 0.0;
        for ja in 1..TABLE_ALPHAS_DEG.len() {
            let fy = fy_at(ja);
            if fy >= target {
                let t = if fy > prev {
                    (target - prev) / (fy - prev)
                } else {
                    1.0
                };
                let a0 = TABLE_ALPHAS_DEG[ja - 1];
                let deg = a0 + t * (TABLE_ALPHAS_DEG[ja] - a0);
                return (sign * deg.to_radians(), false);
            }
            prev = fy;
        }
        (sign * MAX_SLIP_ANGLE_RAD, true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::soil::terramechanics::{MARS_GRAVITY, ROCKY8_MASS_KG};

    fn soils() -> [(&'static str, Soil); 4] {
        [
            (
                "Ishigami regolith simulant",
                Soil::ishigami_regolith_simulant(),
            ),
            ("Wong sandy loam", Soil::sandy_loam()),
            ("DLR Mars simulant", Soil::mars_dlr_simulant()),
            ("Wong dry sand", Soil::dry_sand()),
        ]
    }

    /// One sixth of Rocky 8's Mars weight, N.
    fn w6() -> f64 {
        ROCKY8_MASS_KG * MARS_GRAVITY / 6.0
    }

    /// Midpoint rule with many points over `[0, theta_1]`, written from the equations of the
    /// module docs independently of `Condition::integrals`.
    fn fine(soil: &Soil, wheel: &Wheel, theta_1: f64, s: f64, alpha: f64) -> (f64, f64, f64) {
        let (r, b) = (wheel.radius_m, wheel.width_m);
        let k = r.powf(soil.n) * (soil.k_c / b + soil.k_phi);
        let theta_m = (soil.theta_m_a0 + soil.theta_m_a1 * s) * theta_1;
        let z = 1.0 - theta_1.cos();
        let theta_2 = -(1.0 - soil.exit_sinkage_ratio * z).acos();
        let steps = 20_000;
        let d = (theta_1 - theta_2) / steps as f64;
        let (mut fx, mut fy, mut fz) = (0.0, 0.0, 0.0);
        for i in 0..steps {
            let th = theta_2 + (i as f64 + 0.5) * d;
            let eq = if th >= theta_m {
                th
            } else {
                theta_1 - (th - theta_2) / (theta_m - theta_2) * (theta_1 - theta_m)
            };
            let sigma = k * (eq.cos() - theta_1.cos()).max(0.0).powf(soil.n);
            let j_x = if s >= 0.0 {
                r * ((theta_1 - th) - (1.0 - s) * (theta_1.sin() - th.sin()))
            } else {
                r * ((1.0 + s) * (theta_1 - th) - (theta_1.sin() - th.sin()))
            };
            let j_y = r * (1.0 - s.max(0.0)) * (theta_1 - th) * alpha.tan();
            let tmax = soil.cohesion_pa + sigma * soil.phi_rad.tan();
            let tx = j_x.signum() * tmax * (1.0 - (-j_x.abs() / soil.k_x(alpha)).exp());
            let ty = tmax * (1.0 - (-j_y / soil.k_y(alpha)).exp());
            fx += r * b * (tx * th.cos() - sigma * th.sin()) * d;
            fz += r * b * (tx * th.sin() + sigma * th.cos()) * d;
            fy += r * b * ty * d;
        }
        (fx, fy, fz)
    }

    #[test]
    fn gauss_legendre_matches_fine_quadrature() {
        let wheel = Wheel::rocky8();
        for (name, soil) in soils() {
            for th_deg in [5.0_f64, 15.0, 30.0, 50.0] {
                for s in [-0.7, -0.1, 0.0, 0.1, 0.4, 1.0] {
                    for a_deg in [0.0_f64, 10.0, 45.0] {
                        let a = a_deg.to_radians();
                        let th = th_deg.to_radians();
                        let g = Condition::new(&soil, &wheel, s, a).integrals(th);
                        let (fx, fy, fz) = fine(&soil, &wheel, th, s, a);
                        let tol = 2e-3 * fz.abs().max(1e-3);
                        assert!(
                            (g.fx - fx).abs() < tol
                                && (g.fy - fy).abs() < tol
                                && (g.fz - fz).abs() < tol,
                            "{name} theta_1 {th_deg} s {s} alpha {a_deg}: {g:?} vs {fx} {fy} {fz}"
                        );
                    }
                }
            }
        }
    }

    /// The bisection on the entry angle assumes the vertical force grows with it.
    #[test]
    fn vertical_force_grows_with_entry_angle() {
        let wheel = Wheel::rocky8();
        for (name, soil) in soils() {
            for &s in &TABLE_SLIPS {
                for &a in &TABLE_ALPHAS_DEG {
                    let c = Condition::new(&soil, &wheel, s, a.to_radians());
                    let mut prev = 0.0;
                    for k in 1..=120 {
                        let fz = c.integrals(MAX_ENTRY_ANGLE_RAD * k as f64 / 120.0).fz;
                        assert!(fz > prev, "{name} s {s} alpha {a} k {k}");
                        prev = fz;
                    }
                }
            }
        }
    }

    #[test]
    fn vertical_balance_and_zero_loads() {
        let wheel = Wheel::rocky8();
        for (name, soil) in soils() {
            for load in [5.0, w6(), 200.0] {
                for s in [-0.5, 0.0, 0.3, 1.0] {
                    let f = wheel_forces(&soil, &wheel, load, s, 0.2);
                    if f.buried {
                        // Only the weak soils bury a wheel.
                        assert!(f.vertical_n < load, "{name} {f:?}");
                        assert!(name == "DLR Mars simulant" || name == "Wong dry sand");
                    } else {
                        assert!((f.vertical_n - load).abs() < 1e-6 * load, "{name} {f:?}");
                    }
                    assert!(f.sinkage_m > 0.0 && (f.side_force_n < 0.0 || s == 1.0));
                }
            }
        }
        let soil = Soil::ishigami_regolith_simulant();
        for load in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                wheel_forces(&soil, &wheel, load, 0.3, 0.1),
                WheelForces::default()
            );
        }
        // Far more load than the soil carries at the largest entry angle.
        assert!(wheel_forces(&soil, &wheel, 1e6, 0.3, 0.0).buried);
    }

    /// Drawbar pull against slip for the Rocky 8 wheel under a sixth of the Mars weight.
    /// The two soils of the scenarios (`loose_sand`, `firm_soil`): increasing with slip over
    /// `[-1, 1]`, positive and saturating at high slip, negative under skid. `loose_sand`
    /// (rear contact, `lambda` 0.9) is close to zero at zero slip (free-rolling slip near 0);
    /// the soils with the exit at the bottom of the wheel resist at zero slip. The weak soils
    /// (DLR simulant, Wong's dry sand) never reach a positive pull: the wheel cannot even
    /// propel itself on level ground.
    #[test]
    fn drawbar_pull_against_slip_has_the_expected_shape() {
        let wheel = Wheel::rocky8();
        for (name, soil) in soils() {
            let dp = |s: f64| wheel_forces(&soil, &wheel, w6(), s, 0.0).drawbar_pull_n;
            let scenario_soil = name == "Ishigami regolith simulant" || name == "Wong sandy loam";
            if scenario_soil {
                let mut prev = f64::NEG_INFINITY;
                for k in -50..=50 {
                    let s = k as f64 / 50.0;
                    let v = dp(s);
                    assert!(v > prev, "{name}: not increasing at s = {s}");
                    prev = v;
                }
                assert!(dp(1.0) > 0.0, "{name}");
                // Saturating: the last 20 % of slip adds less than the first 20 %.
                assert!(dp(1.0) - dp(0.8) < dp(0.2) - dp(0.0), "{name}");
            } else {
                assert!((0..=20).all(|k| dp(k as f64 / 20.0) < 0.0), "{name}");
            }
            assert!(dp(-1.0) < dp(0.0) && dp(-1.0) < 0.0, "{name}");
        }
        let ishigami = Soil::ishigami_regolith_simulant();
        let dp0 = wheel_forces(&ishigami, &wheel, w6(), 0.0, 0.0).drawbar_pull_n;
        assert!(dp0.abs() < 0.05 * w6(), "{dp0}");
        let free = slip_for_drawbar_pull(&ishigami, &wheel, w6(), 0.0, 0.0);
        assert!(!free.saturated && free.slip_ratio.abs() < 0.05, "{free:?}");
        let loam = Soil::sandy_loam();
        assert!(wheel_forces(&loam, &wheel, w6(), 0.0, 0.0).drawbar_pull_n < 0.0);
        let free = slip_for_drawbar_pull(&loam, &wheel, w6(), 0.0, 0.0);
        assert!(!free.saturated && free.slip_ratio > 0.0, "{free:?}");
    }

    /// Sinkage of the Rocky 8 wheel under a sixth of the Mars weight: positive and below a
    /// sixth of the diameter (Wong's stated validity range of rigid-wheel sinkage). This is a
    /// plausibility range, not a published measurement for this wheel.
    #[test]
    fn sinkage_is_plausible_and_grows_with_slip_and_load() {
        let wheel = Wheel::rocky8();
        let soil = Soil::ishigami_regolith_simulant();
        let z = |load: f64, s: f64| wheel_forces(&soil, &wheel, load, s, 0.0).sinkage_m;
        let z0 = z(w6(), 0.0);
        assert!(z0 > 0.002 && z0 < wheel.diameter_m() / 6.0, "{z0}");
        assert!(z(w6(), 0.5) > z0 && z(2.0 * w6(), 0.0) > z0);
        let firm = wheel_forces(&Soil::sandy_loam(), &wheel, w6(), 0.0, 0.0).sinkage_m;
        assert!(firm < z0);
    }

    #[test]
    fn side_force_grows_with_angle_and_falls_with_slip() {
        let wheel = Wheel::rocky8();
        for (name, soil) in soils() {
            let fy = |s: f64, a: f64| -wheel_forces(&soil, &wheel, w6(), s, a).side_force_n;
            let mut prev = 0.0;
            for k in 1..=16 {
                let v = fy(0.1, (5.0 * k as f64).to_radians());
                assert!(v > prev, "{name}: at {} deg", 5 * k);
                prev = v;
            }
            assert!(fy(0.6, 0.3) < fy(0.1, 0.3), "{name}");
            assert!(fy(1.0, 0.3).abs() < 1e-9, "{name}");
            let f = wheel_forces(&soil, &wheel, w6(), 0.1, -0.3).side_force_n;
            assert!((f - fy(0.1, 0.3)).abs() < 1e-9, "{name}: odd in alpha");
        }
    }

    #[test]
    fn inverses_round_trip_and_saturate() {
        let wheel = Wheel::rocky8();
        let soil = Soil::ishigami_regolith_simulant();
        let load = w6();
        let dp = |s: f64, a: f64| wheel_forces(&soil, &wheel, load, s, a).drawbar_pull_n;
        let (lo, hi) = (dp(-1.0, 0.1), dp(1.0, 0.1));
        for k in 1..10 {
            let demand = lo + (hi - lo) * k as f64 / 10.0;
            let sol = slip_for_drawbar_pull(&soil, &wheel, load, 0.1, demand);
            assert!(!sol.saturated);
            assert!((dp(sol.slip_ratio, 0.1) - demand).abs() < 1e-6 * load);
        }
        let sat = slip_for_drawbar_pull(&soil, &wheel, load, 0.1, hi + 1.0);
        assert!(sat.saturated && sat.slip_ratio == 1.0);
        let sat = slip_for_drawbar_pull(&soil, &wheel, load, 0.1, lo - 1.0);
        assert!(sat.saturated && sat.slip_ratio == -1.0);
        let f80 = -wheel_forces(&soil, &wheel, load, 0.2, MAX_SLIP_ANGLE_RAD).side_force_n;
        for k in 1..10 {
            let demand = f80 * k as f64 / 10.0;
            let (a, sat) = slip_angle_for_side_force(&soil, &wheel, load, 0.2, demand);
            assert!(!sat && a < 0.0);
            let back = wheel_forces(&soil, &wheel, load, 0.2, a).side_force_n;
            assert!((back - demand).abs() < 1e-6 * load);
        }
        let (a, sat) = slip_angle_for_side_force(&soil, &wheel, load, 0.2, -1.01 * f80);
        assert!(sat && a == MAX_SLIP_ANGLE_RAD);
        assert_eq!(
            slip_angle_for_side_force(&soil, &wheel, load, 0.2, 0.0),
            (0.0, false)
        );
    }

    /// The table against the exact model at points between its grid nodes (away from burial:
    /// within one load step of it the table mixes buried and carried cells).
    #[test]
    fn table_matches_the_exact_model() {
        let wheel = Wheel::rocky8();
        for (name, soil) in soils() {
            let table = WheelTable::new(&soil, &wheel);
            let mut worst: [f64; 3] = [0.0; 3];
            for load in [3.3, 27.0, 61.0, w6(), 137.0, 260.0] {
                for s in [-0.93, -0.42, -0.06, 0.004, 0.027, 0.12, 0.31, 0.55, 0.91] {
                    for a_deg in [0.0_f64, 2.6, 8.0, 21.0, 50.0] {
                        let a = a_deg.to_radians();
                        if wheel_forces(&soil, &wheel, 1.25 * load, s, a).buried {
                            continue;
                        }
                        let e = wheel_forces(&soil, &wheel, load, s, a);
                        let t = table.forces(load, s, a);
                        let d = [
                            (t.drawbar_pull_n - e.drawbar_pull_n).abs() / load,
                            (t.side_force_n - e.side_force_n).abs() / load,
                            (t.sinkage_m - e.sinkage_m).abs(),
                        ];
                        for (w, v) in worst.iter_mut().zip(d) {
                            *w = w.max(v);
                        }
                    }
                }
            }
            println!(
                "{name}: worst |dDP|/W {:.4}, |dFy|/W {:.4}, |dz| {:.5} m",
                worst[0], worst[1], worst[2]
            );
            assert!(
                worst[0] < 0.01 && worst[1] < 0.01 && worst[2] < 5e-4,
                "{name}: {worst:?}"
            );
            // Inverses: the slip the table finds gives the demanded pull in the exact model.
            for load in [27.0, w6(), 180.0] {
                let hi = wheel_forces(&soil, &wheel, load, 1.0, 0.1).drawbar_pull_n;
                let lo = wheel_forces(&soil, &wheel, load, -1.0, 0.1).drawbar_pull_n;
                for k in 1..10 {
                    let demand = lo + (hi - lo) * k as f64 / 10.0;
                    let sol = table.slip_for_drawbar_pull(load, 0.1, demand);
                    let back = wheel_forces(&soil, &wheel, load, sol.slip_ratio, 0.1);
                    assert!(
                        !sol.saturated && (back.drawbar_pull_n - demand).abs() < 0.015 * load,
                        "{name} load {load} demand {demand}: {sol:?} {back:?}"
                    );
                }
                let f60 = -wheel_forces(&soil, &wheel, load, 0.2, 60f64.to_radians()).side_force_n;
                for k in 1..10 {
                    let demand = f60 * k as f64 / 10.0;
                    let (a, sat) = table.slip_angle_for_side_force(load, 0.2, demand);
                    let back = wheel_forces(&soil, &wheel, load, 0.2, a).side_force_n;
                    assert!(
                        !sat && (back - demand).abs() < 0.015 * load,
                        "{name} load {load} side {demand}: {a} {back}"
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod figures {
    use super::*;
    use crate::soil::terramechanics::{
        rocker_bogie_loads, LoadInput, MARS_GRAVITY, ROCKY8_MASS_KG,
    };

    /// Largest slope a single wheel of `wheel` carrying the weight share `w` can climb: the
    /// largest `theta` at which the drawbar pull at 100 % slip under `w cos theta` still
    /// reaches `w sin theta` (bisection).
    fn climbable_slope_deg(soil: &Soil, wheel: &Wheel, w: f64) -> f64 {
        let ok = |t: f64| {
            let best = (0..=20)
                .map(|k| {
                    wheel_forces(soil, wheel, w * t.cos(), k as f64 / 20.0, 0.0).drawbar_pull_n
                })
                .fold(f64::NEG_INFINITY, f64::max);
            best >= w * t.sin()
        };
        if !ok(0.0) {
            return 0.0;
        }
        let (mut lo, mut hi) = (0.0, 1.2);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if ok(mid) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo.to_degrees()
    }

    /// The single-wheel figures of `docs/terramechanics.md` (outcomes of the model; printed
    /// with `cargo test -p sim-host --release --lib rigid_wheel::figures -- --nocapture`).
    #[test]
    fn print_figures() {
        let wheel = Wheel::rocky8();
        let loads = rocker_bogie_loads(&LoadInput::rocky8_level()).unwrap();
        let w6 = ROCKY8_MASS_KG * MARS_GRAVITY / 6.0;
        let soils = [
            (
                "loose_sand (Ishigami 2007)",
                Soil::ishigami_regolith_simulant(),
            ),
            ("firm_soil (Wong sandy loam)", Soil::sandy_loam()),
            ("mars_simulant (DLR)", Soil::mars_dlr_simulant()),
            ("wong_dry_sand", Soil::dry_sand()),
        ];
        for (name, soil) in soils {
            println!("{name}:");
            for (pos, i) in [("front", 0), ("middle", 2), ("rear", 4)] {
                let n = loads[i];
                let f0 = wheel_forces(&soil, &wheel, n, 0.0, 0.0);
                let free = slip_for_drawbar_pull(&soil, &wheel, n, 0.0, 0.0);
                let d = |s: f64| wheel_forces(&soil, &wheel, n, s, 0.0);
                println!(
                    "  {pos:6} N {n:6.2}: z(s=0) {:5.1} mm, theta_1 {:4.1} deg, DP(0) {:6.2} N ({:+.3} W), free-rolling s {:.3}{}, DP(0.2) {:6.2} N ({:+.3} W), DP(0.5) {:6.2} N ({:+.3} W), DP(1) {:6.2} N, z(0.2) {:5.1} mm",
                    f0.sinkage_m * 1e3,
                    f0.entry_angle_rad.to_degrees(),
                    f0.drawbar_pull_n,
                    f0.drawbar_pull_n / n,
                    free.slip_ratio,
                    if free.saturated { " SAT" } else { "" },
                    d(0.2).drawbar_pull_n,
                    d(0.2).drawbar_pull_n / n,
                    d(0.5).drawbar_pull_n,
                    d(0.5).drawbar_pull_n / n,
                    d(1.0).drawbar_pull_n,
                    d(0.2).sinkage_m * 1e3,
                );
            }
            println!(
                "  W/6 = {w6:.2} N: single wheel climbs {:.1} deg",
                climbable_slope_deg(&soil, &wheel, w6)
            );
            for deg in [0.0_f64, 5.0, 10.0, 15.0, 20.0, 25.0] {
                let t = deg.to_radians();
                let sol = slip_for_drawbar_pull(&soil, &wheel, w6 * t.cos(), 0.0, w6 * t.sin());
                print!(
                    "  uphill {deg:2.0} deg: s {:.3}{};",
                    sol.slip_ratio,
                    if sol.saturated { " SAT" } else { "" }
                );
            }
            println!();
            for deg in [10.0_f64, 15.0, 20.0] {
                let t = deg.to_radians();
                let nl = w6 * t.cos();
                let sol = slip_for_drawbar_pull(&soil, &wheel, nl, 0.0, 0.0);
                let (a, sat) =
                    slip_angle_for_side_force(&soil, &wheel, nl, sol.slip_ratio, w6 * t.sin());
                let sol2 = slip_for_drawbar_pull(&soil, &wheel, nl, a, 0.0);
                let (a2, sat2) =
                    slip_angle_for_side_force(&soil, &wheel, nl, sol2.slip_ratio, w6 * t.sin());
                print!(
                    "  cross {deg:2.0} deg: s {:.3}, alpha {:.1} deg{} (first pass {:.1}{});",
                    sol2.slip_ratio,
                    a2.to_degrees(),
                    if sat2 { " SAT" } else { "" },
                    a.to_degrees(),
                    if sat { " SAT" } else { "" }
                );
            }
            println!();
        }
        let start = std::time::Instant::now();
        for _ in 0..6 {
            let _ = WheelTable::new(&Soil::ishigami_regolith_simulant(), &wheel);
        }
        println!("six tables built in {:.3} s", start.elapsed().as_secs_f64());
        // Sensitivity of loose_sand to its exit-angle ratio (0.9 in one transcription, 1 in
        // another; 0 is the Wong-Reece exit at the bottom of the wheel).
        for lambda in [0.0, 0.9, 1.0] {
            let soil = Soil {
                exit_sinkage_ratio: lambda,
                ..Soil::ishigami_regolith_simulant()
            };
            let f = |s: f64| wheel_forces(&soil, &wheel, w6, s, 0.0);
            let free = slip_for_drawbar_pull(&soil, &wheel, w6, 0.0, 0.0);
            println!(
                "loose_sand lambda {lambda}: W/6 z {:.1} mm, DP(0) {:+.3} W, free-rolling s {:.3}, DP(0.2) {:+.3} W, DP(0.5) {:+.3} W, climbs {:.1} deg",
                f(0.0).sinkage_m * 1e3,
                f(0.0).drawbar_pull_n / w6,
                free.slip_ratio,
                f(0.2).drawbar_pull_n / w6,
                f(0.5).drawbar_pull_n / w6,
                climbable_slope_deg(&soil, &wheel, w6)
            );
        }
    }
}
