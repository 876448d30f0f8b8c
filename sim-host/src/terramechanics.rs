//! Terramechanics of a rigid wheel on deformable soil, and the quasi-static wheel loads of a
//! rocker-bogie: ground-truth building blocks for the vehicle model (see
//! `docs/terramechanics.md` for the equations, the parameter sources and the simplifications).
//!
//! Everything here is a cheap pure function (closed forms, or bisection with a fixed number of
//! iterations) so it can be called for six wheels at 200 Hz.
//!
//! **Conventions.**
//! - Units are SI: m, N, Pa, rad. The soil's friction angle is stored in **radians**
//!   ([`Soil::phi_rad`]); the constructors convert the published degrees.
//! - Slip ratio `s` (dimensionless, in `[-1, 1]`), with `r w` the wheel's circumferential speed
//!   and `V` its forward ground speed: driving (`r w >= V`) `s = 1 - V / (r w)` (Wong's slip
//!   `i`); skidding (`V > r w`) `s = r w / V - 1`, i.e. `s = i_s / (1 - i_s)` with Wong's skid
//!   `i_s = 1 - V / (r w)` (which runs from 0 to minus infinity). So `s = 1` is a wheel spinning
//!   in place and `s = -1` a locked wheel sliding. Ground speed from wheel speed:
//!   `V = r w (1 - s)` for `s >= 0`, `V = r w / (1 + s)` for `s < 0`.
//! - Slip angle `alpha`: the angle of the wheel centre's ground velocity from the wheel's
//!   heading, positive towards the wheel's `+y` (right). The lateral soil force opposes the
//!   lateral sliding, so [`lateral_force`] is negative for positive `alpha`.
//! - The rover body frame `R`: `x` forward, `y` right, `z` down.

use nalgebra::{Matrix6, Vector3, Vector6};

/// Number of bisection iterations of the inverse functions (interval width / 2^40).
const BISECTION_ITERATIONS: usize = 40;

/// Upper bound of the slip-angle search of [`slip_angle_for_side_force`], rad (80 deg).
pub const MAX_SLIP_ANGLE_RAD: f64 = 80.0 * std::f64::consts::PI / 180.0;

/// Mars surface gravity, m/s^2 (NASA Mars Fact Sheet: 3.71 m/s^2; 3.711 as commonly quoted).
pub const MARS_GRAVITY: f64 = 3.711;

/// Bekker pressure-sinkage and Mohr-Coulomb / Janosi-Hanamoto shear parameters of a soil.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Soil {
    /// Bekker sinkage exponent `n` (dimensionless).
    pub n: f64,
    /// Bekker cohesive modulus `k_c`, N/m^(n+1).
    pub k_c: f64,
    /// Bekker frictional modulus `k_phi`, N/m^(n+2).
    pub k_phi: f64,
    /// Cohesion `c`, Pa.
    pub cohesion_pa: f64,
    /// Internal friction angle `phi`, **radians**.
    pub phi_rad: f64,
    /// Janosi-Hanamoto shear deformation modulus `K` (longitudinal), m.
    pub shear_k_m: f64,
    /// Lateral shear deformation modulus `K_y` (Ishigami et al. 2007), m.
    pub shear_k_y_m: f64,
    /// Where the values come from.
    pub source: &'static str,
}

impl Soil {
    /// Dry sand (Land Locomotion Laboratory): Wong, *Theory of Ground Vehicles*, Table 2.3:
    /// `n` 1.1, `k_c` 0.99 kN/m^(n+1), `k_phi` 1528.43 kN/m^(n+2), `c` 1.04 kPa, `phi` 28.0 deg.
    /// `K` = 2.5 cm: Wong's typical value for loose sand (ch. 2, Janosi-Hanamoto shear); the
    /// same set with `K` = 0.0254 m is quoted by Hindawi TSWJ 2014 (396382), Table 2, which
    /// gives `k_c` = 0.95 instead of 0.99 (the Wong table value is kept). `K_y`: no published
    /// value for this soil was found, so `K_y = K` (isotropic shear; an assumption).
    pub fn dry_sand() -> Self {
        Self {
            n: 1.1,
            k_c: 0.99e3,
            k_phi: 1528.43e3,
            cohesion_pa: 1.04e3,
            phi_rad: 28.0_f64.to_radians(),
            shear_k_m: 0.025,
            shear_k_y_m: 0.025,
            source: "Wong, Theory of Ground Vehicles, Table 2.3, dry sand (LLL); K = 2.5 cm \
                     (Wong, loose sand); K_y = K (assumption)",
        }
    }

    /// Sandy loam, moisture about 15 % (Land Locomotion Laboratory), a firm soil: Wong,
    /// *Theory of Ground Vehicles*, Table 2.3: `n` 0.7, `k_c` 5.27 kN/m^(n+1), `k_phi`
    /// 1515.04 kN/m^(n+2), `c` 1.72 kPa, `phi` 29 deg. `K` = 1 cm: Wong's typical value for
    /// firm sandy terrain. `K_y = K` (assumption, as for [`Soil::dry_sand`]).
    pub fn sandy_loam() -> Self {
        Self {
            n: 0.7,
            k_c: 5.27e3,
            k_phi: 1515.04e3,
            cohesion_pa: 1.72e3,
            phi_rad: 29.0_f64.to_radians(),
            shear_k_m: 0.01,
            shear_k_y_m: 0.01,
            source: "Wong, Theory of Ground Vehicles, Table 2.3, sandy loam ~15 % moisture \
                     (LLL); K = 1 cm (Wong, firm sandy terrain); K_y = K (assumption)",
        }
    }

    /// DLR mechanical Mars soil simulant, **as commonly quoted** (not checked against the
    /// primary source): `n` 0.8, `k_c` 5.79 kN/m^(n+1), `k_phi` 180 kN/m^(n+2), `c` 0.3 kPa,
    /// `phi` 17.8 deg, attributed to "Strength of soil deposits along MER traverses" (NASA) in
    /// the soil table of Project Chrono's SCM deformable-terrain demo. `K` = 1 cm is the
    /// value that table uses (it is not part of the cited set). `K_y = K` (assumption).
    /// For comparison, Mars soils measured in place have larger friction angles and small
    /// cohesion: Sojourner (Moore et al., JGR 104(E4), 1999) cloddy deposits `phi` 34-39 deg,
    /// drift 26-28 deg; MER trenches (Sullivan et al., JGR 2011) `phi` 30-37 deg, `c` 0-2 kPa.
    pub fn mars_dlr_simulant() -> Self {
        Self {
            n: 0.8,
            k_c: 5.79e3,
            k_phi: 180.0e3,
            cohesion_pa: 0.3e3,
            phi_rad: 17.8_f64.to_radians(),
            shear_k_m: 0.01,
            shear_k_y_m: 0.01,
            source: "DLR Mars soil simulant as commonly quoted (Project Chrono SCM demo table, \
                     citing 'Strength of soil deposits along MER traverses', NASA); K = 1 cm \
                     from that table; K_y = K (assumption)",
        }
    }

    /// Peak shear force of a contact area `area_m2` under `normal_load_n`: `c A + W tan(phi)`
    /// (Mohr-Coulomb with uniform normal pressure), N.
    pub fn max_shear_force(&self, area_m2: f64, normal_load_n: f64) -> f64 {
        if normal_load_n <= 0.0 || area_m2 <= 0.0 {
            return 0.0;
        }
        self.cohesion_pa * area_m2 + normal_load_n * self.phi_rad.tan()
    }
}

/// A rigid, smooth (no grousers) cylindrical wheel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wheel {
    /// Radius, m.
    pub radius_m: f64,
    /// Width `b`, m.
    pub width_m: f64,
}

impl Wheel {
    /// Rocky 8 wheel: radius 0.10 m (the project's geometry: contacts 0.10 m below the axles);
    /// width 0.08 m is an **assumption** (no published figure found).
    pub fn rocky8() -> Self {
        Self {
            radius_m: 0.10,
            width_m: 0.08,
        }
    }

    /// Diameter `D`, m.
    pub fn diameter_m(&self) -> f64 {
        2.0 * self.radius_m
    }
}

/// Steady-state contact patch of a rigid wheel on deformable soil.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Patch {
    /// Static sinkage `z0`, m.
    pub sinkage_m: f64,
    /// Contact length `L` (chord from the lowest point to the entry point), m.
    pub contact_length_m: f64,
    /// Contact area `b L`, m^2.
    pub area_m2: f64,
    /// Compaction (motion) resistance `R_c`, N.
    pub compaction_resistance_n: f64,
}

/// Contact patch of `wheel` on `soil` under `normal_load_n` (Bekker/Wong rigid wheel, steady
/// state). Sinkage (Wong, *Theory of Ground Vehicles*, ch. 2, rigid wheel):
/// `z0 = [3 W / ((3 - n)(k_c + b k_phi) sqrt(D))]^(2/(2n+1))`; compaction resistance (Bekker)
/// `R_c = (k_c + b k_phi) z0^(n+1) / (n+1)`, equal to Wong's closed form
/// `(b (k_c/b + k_phi))^(-1/(2n+1)) [3W/((3-n) sqrt D)]^((2n+2)/(2n+1)) / (n+1)`; contact length
/// `L = sqrt(D z0 - z0^2)` (with `z0` capped at the radius for the chord). Zero, negative or
/// non-finite load gives the zero patch.
pub fn patch(soil: &Soil, wheel: &Wheel, normal_load_n: f64) -> Patch {
    if !normal_load_n.is_finite() || normal_load_n <= 0.0 {
        return Patch::default();
    }
    let b = wheel.width_m;
    let d = wheel.diameter_m();
    let n = soil.n;
    let k_eq = soil.k_c + b * soil.k_phi; // N/m^(n+1)
    let z0 = (3.0 * normal_load_n / ((3.0 - n) * k_eq * d.sqrt())).powf(2.0 / (2.0 * n + 1.0));
    let zc = z0.min(wheel.radius_m);
    let contact_length_m = (d * zc - zc * zc).max(0.0).sqrt();
    Patch {
        sinkage_m: z0,
        contact_length_m,
        area_m2: b * contact_length_m,
        compaction_resistance_n: k_eq * z0.powf(n + 1.0) / (n + 1.0),
    }
}

/// `g(x) = 1 - (1 - exp(-x)) / x` for `x >= 0`: the fraction of the peak shear mobilised over a
/// patch whose far end has shear displacement `x` times the shear modulus. `g(0) = 0`,
/// increasing, `g -> 1`. Series near 0 to avoid cancellation.
fn shear_fraction(x: f64) -> f64 {
    if x <= 0.0 {
        0.0
    } else if x < 1e-4 {
        x / 2.0 - x * x / 6.0 + x * x * x / 24.0
    } else {
        1.0 + (-x).exp_m1() / x
    }
}

/// Longitudinal soil thrust on the wheel, N, along the rolling direction (positive forward);
/// this is the drawbar force **before** subtracting the compaction resistance `R_c`.
/// Janosi-Hanamoto shear `tau = (c + sigma tan phi)(1 - exp(-j/K))` integrated over the patch
/// with uniform normal pressure and shear displacement `j(x) = |s| x` (`x` from the entry
/// point), i.e. `F = (c A + W tan phi) [1 - K/(|s| L) (1 - exp(-|s| L / K))]`, with the sign of
/// `s`. For skid (`s < 0`) `j = |s| x` is Wong's skidding-wheel displacement
/// `|i_s| x / (1 + |i_s|)` in this module's slip convention (see the module docs). Odd in `s`,
/// continuous (and smooth) at 0; `s` is clamped to `[-1, 1]`.
pub fn longitudinal_force(soil: &Soil, patch: &Patch, normal_load_n: f64, slip_ratio: f64) -> f64 {
    let f_max = soil.max_shear_force(patch.area_m2, normal_load_n);
    if f_max <= 0.0 || soil.shear_k_m <= 0.0 || slip_ratio.is_nan() {
        return 0.0;
    }
    let s = slip_ratio.clamp(-1.0, 1.0);
    let x = s.abs() * patch.contact_length_m / soil.shear_k_m;
    s.signum() * f_max * shear_fraction(x)
}

/// Lateral soil force on the wheel, N, along the wheel's `+y` (right), after Ishigami, Miwa,
/// Nagatani, Yoshida, J. Field Robotics 24(3), 2007: lateral shear displacement
/// `j_y(x) = (1 - s) x tan(alpha)` along the patch (for skid, `s < 0`, the factor is 1: the
/// contact time is `x / V`, as in [`longitudinal_force`]), `tau_y = (c + sigma tan phi)(1 -
/// exp(-j_y / K_y))`, integrated with uniform normal pressure:
/// `F_y = -sign(alpha) (c A + W tan phi) [1 - K_y/(L (1-s) tan|a|) (1 - exp(-L (1-s) tan|a| /
/// K_y))]`. Opposes the lateral sliding; 0 at `alpha = 0` and at `s = 1`. No bulldozing term
/// (Ishigami's side-wall term is left out). `|alpha|` is clamped below 90 deg.
pub fn lateral_force(
    soil: &Soil,
    patch: &Patch,
    normal_load_n: f64,
    slip_ratio: f64,
    slip_angle_rad: f64,
) -> f64 {
    let f_max = soil.max_shear_force(patch.area_m2, normal_load_n);
    if f_max <= 0.0 || soil.shear_k_y_m <= 0.0 || slip_ratio.is_nan() || slip_angle_rad.is_nan() {
        return 0.0;
    }
    let travel = 1.0 - slip_ratio.clamp(0.0, 1.0);
    let a = slip_angle_rad.abs().min(89.9_f64.to_radians());
    let x = patch.contact_length_m * travel * a.tan() / soil.shear_k_y_m;
    -slip_angle_rad.signum() * f_max * shear_fraction(x)
}

/// Result of [`slip_for_traction`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlipSolution {
    /// Slip ratio (module convention), in `[-1, 1]`.
    pub slip_ratio: f64,
    /// The soil cannot deliver the demand: `slip_ratio` is then 1 (drive) or -1 (skid).
    pub saturated: bool,
}

/// Slip ratio at which [`longitudinal_force`] equals `demand_n` (N, positive forward).
/// Bisection (40 iterations) on `s` in `[0, 1]` for a positive demand, on `[-1, 0]` for a
/// negative one; `saturated` (and `s = +-1`) when `|demand|` exceeds the force at `|s| = 1`.
pub fn slip_for_traction(
    soil: &Soil,
    patch: &Patch,
    normal_load_n: f64,
    demand_n: f64,
) -> SlipSolution {
    if demand_n == 0.0 || demand_n.is_nan() {
        return SlipSolution {
            slip_ratio: 0.0,
            saturated: false,
        };
    }
    let sign = demand_n.signum();
    let target = demand_n.abs();
    let f = |s: f64| longitudinal_force(soil, patch, normal_load_n, s);
    if f(1.0) < target {
        return SlipSolution {
            slip_ratio: sign,
            saturated: true,
        };
    }
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..BISECTION_ITERATIONS {
        let mid = 0.5 * (lo + hi);
        if f(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    SlipSolution {
        slip_ratio: sign * 0.5 * (lo + hi),
        saturated: false,
    }
}

/// Slip angle, rad, at which [`lateral_force`] (at `slip_ratio`) equals `demand_n` (N, along the
/// wheel's `+y`), and whether the soil saturates. The returned angle has the **opposite** sign
/// of the demand (the soil pushes against the sliding), so `lateral_force(.., alpha) ==
/// demand`. Bisection (40 iterations) on `|alpha|` in `[0, 80 deg]`; saturated (and `|alpha|` =
/// 80 deg) when the demand exceeds the force at 80 deg.
pub fn slip_angle_for_side_force(
    soil: &Soil,
    patch: &Patch,
    normal_load_n: f64,
    slip_ratio: f64,
    demand_n: f64,
) -> (f64, bool) {
    if demand_n == 0.0 || demand_n.is_nan() {
        return (0.0, false);
    }
    let alpha_sign = -demand_n.signum();
    let target = demand_n.abs();
    // Magnitude of the side force at |alpha| = a.
    let f = |a: f64| -lateral_force(soil, patch, normal_load_n, slip_ratio, a);
    if f(MAX_SLIP_ANGLE_RAD) < target {
        return (alpha_sign * MAX_SLIP_ANGLE_RAD, true);
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
    (alpha_sign * 0.5 * (lo + hi), false)
}

/// Inputs of [`rocker_bogie_loads`], all in the rover body frame `R` (`x` forward, `y` right,
/// `z` down), metres. Wheels are indexed 0..5 = wheels 1 RF, 2 LF, 3 RM, 4 LM, 5 RR, 6 LR
/// (right = indices 0, 2, 4); front and middle wheels are on the bogies, rear wheels on the
/// rockers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoadInput {
    /// Wheel-ground contact points.
    pub contacts: [Vector3<f64>; 6],
    /// Right rocker pivot (differential axis end).
    pub rocker_pivot_right: Vector3<f64>,
    /// Left rocker pivot.
    pub rocker_pivot_left: Vector3<f64>,
    /// Right bogie pivot.
    pub bogie_pivot_right: Vector3<f64>,
    /// Left bogie pivot.
    pub bogie_pivot_left: Vector3<f64>,
    /// Centre of mass.
    pub centre_of_mass: Vector3<f64>,
    /// Direction of gravity in `R` (normalised internally); `(0, 0, 1)` on level ground.
    pub gravity_dir: Vector3<f64>,
    /// Total weight, N.
    pub weight_n: f64,
}

impl LoadInput {
    /// Rocky 8 at zero joint angles on level ground (the project's geometry: axles at
    /// x = 0.393 / 0.0005 / -0.354 m, y = +-0.3111 m, z = 0, contacts 0.10 m below; rocker
    /// pivots at (-0.142, +-0.3111, -0.202), bogie pivots at (0.129, +-0.3111, -0.127)), with
    /// an **assumed** centre of mass at (0, 0, -0.25) m, an **assumed** mass of 150 kg (the
    /// project's figure, `docs/simulator.md`; not confirmed from a publication) and Mars
    /// gravity.
    pub fn rocky8_level() -> Self {
        let y = 0.3111;
        let c = |x: f64, y: f64| Vector3::new(x, y, 0.10);
        Self {
            contacts: [
                c(0.393, y),
                c(0.393, -y),
                c(0.0005, y),
                c(0.0005, -y),
                c(-0.354, y),
                c(-0.354, -y),
            ],
            rocker_pivot_right: Vector3::new(-0.142, y, -0.202),
            rocker_pivot_left: Vector3::new(-0.142, -y, -0.202),
            bogie_pivot_right: Vector3::new(0.129, y, -0.127),
            bogie_pivot_left: Vector3::new(0.129, -y, -0.127),
            centre_of_mass: Vector3::new(0.0, 0.0, -0.25),
            gravity_dir: Vector3::new(0.0, 0.0, 1.0),
            weight_n: ROCKY8_MASS_KG * MARS_GRAVITY,
        }
    }
}

/// Rocky 8 mass used for figures and tests, kg: an **assumption** (the project's figure).
pub const ROCKY8_MASS_KG: f64 = 150.0;

/// Indices of the right wheels (1 RF, 3 RM, 5 RR), the left wheels, and the bogie wheels.
const RIGHT: [usize; 3] = [0, 2, 4];
const LEFT: [usize; 3] = [1, 3, 5];
const BOGIE_RIGHT: [usize; 2] = [0, 2];
const BOGIE_LEFT: [usize; 2] = [1, 3];

/// Equilibrium matrix `A N = b` of the rocker-bogie (rows: force along gravity, two whole-vehicle
/// moments about the CoM, right bogie, left bogie, differential).
fn load_system(input: &LoadInput, g: &Vector3<f64>) -> (Matrix6<f64>, Vector6<f64>) {
    // Two unit axes perpendicular to gravity.
    let x = Vector3::x();
    let y = Vector3::y();
    let seed = if g.dot(&x).abs() < 0.9 { x } else { y };
    let e1 = (seed - g * g.dot(&seed)).normalize();
    let e2 = g.cross(&e1);
    let mut a = Matrix6::zeros();
    let mut b = Vector6::zeros();
    // Ground reaction on wheel i: -N_i g at P_i. Moment about a point Q: -N_i (P_i - Q) x g.
    let arm = |i: usize, q: &Vector3<f64>| (input.contacts[i] - q).cross(g);
    for i in 0..6 {
        a[(0, i)] = 1.0;
        let m = arm(i, &input.centre_of_mass);
        a[(1, i)] = m.dot(&e1);
        a[(2, i)] = m.dot(&e2);
    }
    b[0] = input.weight_n;
    for &i in &BOGIE_RIGHT {
        a[(3, i)] = arm(i, &input.bogie_pivot_right).dot(&y);
    }
    for &i in &BOGIE_LEFT {
        a[(4, i)] = arm(i, &input.bogie_pivot_left).dot(&y);
    }
    // Differential: an ideal differential imposes theta_R = -theta_L on the rocker angles, so
    // (virtual work) it applies the same torque about +y to both rockers; hence the ground
    // moments about the two rocker pivot axes (both taken about +y) are equal: M_R - M_L = 0.
    for &i in &RIGHT {
        a[(5, i)] = arm(i, &input.rocker_pivot_right).dot(&y);
    }
    for &i in &LEFT {
        a[(5, i)] = -arm(i, &input.rocker_pivot_left).dot(&y);
    }
    (a, b)
}

/// Quasi-static normal loads of the six wheels of a rocker-bogie, N (index 0..5 = wheels 1 RF,
/// 2 LF, 3 RM, 4 LM, 5 RR, 6 LR). Contact forces are along gravity only (friction ignored for
/// the split), links massless, joints frictionless. Six equations: force balance along gravity,
/// whole-vehicle moment balance about two axes perpendicular to gravity through the CoM, zero
/// moment of each bogie's two loads about its pivot axis (`y_R`), and the differential (equal
/// ground moments about the right and left rocker pivot axes, both about `+y_R`). If a load
/// comes out negative the most negative one is set to zero and the rest re-solved in the
/// least-squares sense with the force balance weighted to hold (at most 6 passes; the sum is
/// then exactly the weight). `None` if the 6x6 system is degenerate or an input is not finite.
pub fn rocker_bogie_loads(input: &LoadInput) -> Option<[f64; 6]> {
    let finite = input
        .contacts
        .iter()
        .all(|p| p.iter().all(|v| v.is_finite()))
        && [
            input.rocker_pivot_right,
            input.rocker_pivot_left,
            input.bogie_pivot_right,
            input.bogie_pivot_left,
            input.centre_of_mass,
            input.gravity_dir,
        ]
        .iter()
        .all(|p| p.iter().all(|v| v.is_finite()))
        && input.weight_n.is_finite();
    let g_norm = input.gravity_dir.norm();
    if !finite || g_norm < 1e-9 {
        return None;
    }
    if input.weight_n <= 0.0 {
        return Some([0.0; 6]);
    }
    let g = input.gravity_dir / g_norm;
    let (a, b) = load_system(input, &g);
    let svd = a.svd(false, false);
    let smax = svd.singular_values.max();
    let smin = svd.singular_values.min();
    if smin.is_nan() || smin <= 1e-10 * smax {
        return None;
    }
    let mut n = a.lu().solve(&b)?;
    let mut zeroed = [false; 6];
    // Row weights for the least-squares passes: the force balance must hold.
    let mut w = Matrix6::identity();
    w[(0, 0)] = 1e4;
    let aw = w * a;
    let bw = w * b;
    for _ in 0..6 {
        let (imin, vmin) =
            n.iter().enumerate().fold(
                (0, f64::INFINITY),
                |acc, (i, &v)| if v < acc.1 { (i, v) } else { acc },
            );
        if vmin >= 0.0 {
            break;
        }
        zeroed[imin] = true;
        // Normal equations on the free loads; zeroed loads pinned by identity rows.
        let mut m = aw.transpose() * aw;
        let mut r = aw.transpose() * bw;
        for (j, &z) in zeroed.iter().enumerate() {
            if z {
                for k in 0..6 {
                    m[(j, k)] = 0.0;
                    m[(k, j)] = 0.0;
                }
                m[(j, j)] = 1.0;
                r[j] = 0.0;
            }
        }
        n = m.svd(true, true).solve(&r, 1e-12).ok()?;
        for (j, &z) in zeroed.iter().enumerate() {
            if z {
                n[j] = 0.0;
            }
        }
    }
    let mut out = [0.0; 6];
    for (o, v) in out.iter_mut().zip(n.iter()) {
        *o = v.max(0.0);
    }
    let sum: f64 = out.iter().sum();
    if sum.is_nan() || sum <= 0.0 {
        return None;
    }
    let scale = input.weight_n / sum;
    for o in &mut out {
        *o *= scale;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn soils() -> [Soil; 3] {
        [
            Soil::dry_sand(),
            Soil::sandy_loam(),
            Soil::mars_dlr_simulant(),
        ]
    }

    /// One sixth of Rocky 8's Mars weight, N.
    fn w6() -> f64 {
        ROCKY8_MASS_KG * MARS_GRAVITY / 6.0
    }

    #[test]
    fn zero_negative_and_nan_loads_give_zero_patch_and_forces() {
        let (s, w) = (Soil::dry_sand(), Wheel::rocky8());
        for load in [0.0, -10.0, f64::NAN, f64::INFINITY] {
            let p = patch(&s, &w, load);
            assert_eq!(p, Patch::default(), "load {load}");
            assert_eq!(longitudinal_force(&s, &p, load, 0.5), 0.0);
            assert_eq!(lateral_force(&s, &p, load, 0.2, 0.3), 0.0);
            let sol = slip_for_traction(&s, &p, load, 10.0);
            assert!(sol.saturated && sol.slip_ratio == 1.0);
        }
    }

    #[test]
    fn dry_sand_sinkage_matches_hand_computation() {
        // z0 = [3 W / ((3 - n)(k_c + b k_phi) sqrt D)]^(2/(2n+1)), W = 100 N, b = 0.08, D = 0.2:
        // k_c + b k_phi = 990 + 0.08 * 1528430 = 123264.4; 300 / (1.9 * 123264.4 * 0.4472136)
        // = 2.86427e-3; ^(1/1.6) -> 0.0256 m (computed here independently of `patch`).
        let k_eq = 990.0 + 0.08 * 1_528_430.0;
        let base: f64 = 300.0 / (1.9 * k_eq * 0.2_f64.sqrt());
        let expected = base.powf(1.0 / 1.6);
        assert!((expected - 0.0256).abs() < 0.0005, "{expected}");
        let p = patch(&Soil::dry_sand(), &Wheel::rocky8(), 100.0);
        assert!((p.sinkage_m - expected).abs() < 1e-12);
        let l = (0.2 * expected - expected * expected).sqrt();
        assert!((p.contact_length_m - l).abs() < 1e-12);
        assert!((p.area_m2 - 0.08 * l).abs() < 1e-12);
    }

    #[test]
    fn compaction_resistance_equals_wongs_closed_form() {
        let wheel = Wheel::rocky8();
        let (b, d) = (wheel.width_m, wheel.diameter_m());
        for soil in soils() {
            for load in [20.0, 92.8, 300.0] {
                let n = soil.n;
                let e = 2.0 * n + 1.0;
                let closed = (b * (soil.k_c / b + soil.k_phi)).powf(-1.0 / e)
                    * (3.0 * load / ((3.0 - n) * d.sqrt())).powf((2.0 * n + 2.0) / e)
                    / (n + 1.0);
                let p = patch(&soil, &wheel, load);
                let rel = (p.compaction_resistance_n - closed).abs() / closed;
                assert!(
                    rel < 1e-10,
                    "{} load {load}: {} vs {closed}",
                    soil.source,
                    p.compaction_resistance_n
                );
            }
        }
    }

    #[test]
    fn sinkage_and_resistance_grow_with_load_and_firm_soil_sinks_less() {
        let wheel = Wheel::rocky8();
        for soil in soils() {
            let mut prev = Patch::default();
            for k in 1..=20 {
                let p = patch(&soil, &wheel, 10.0 * k as f64);
                assert!(p.sinkage_m > prev.sinkage_m);
                assert!(p.contact_length_m > prev.contact_length_m);
                assert!(p.compaction_resistance_n > prev.compaction_resistance_n);
                prev = p;
            }
        }
        let sand = patch(&Soil::dry_sand(), &wheel, w6());
        let loam = patch(&Soil::sandy_loam(), &wheel, w6());
        assert!(loam.sinkage_m < sand.sinkage_m);
    }

    /// Midpoint-rule integral of the Janosi-Hanamoto shear over the patch with uniform
    /// pressure: an independent check of the closed forms.
    fn integrate_shear(soil: &Soil, p: &Patch, load: f64, j_per_x: f64, k: f64) -> f64 {
        let steps = 20_000;
        let dx = p.contact_length_m / steps as f64;
        let sigma = load / p.area_m2;
        let tau_max = soil.cohesion_pa + sigma * soil.phi_rad.tan();
        (0..steps)
            .map(|i| {
                let x = (i as f64 + 0.5) * dx;
                tau_max * (1.0 - (-j_per_x * x / k).exp()) * p.area_m2 / p.contact_length_m * dx
            })
            .sum()
    }

    #[test]
    fn longitudinal_force_matches_numerical_integration() {
        let soil = Soil::dry_sand();
        let p = patch(&soil, &Wheel::rocky8(), w6());
        for s in [0.01, 0.1, 0.3, 0.7, 1.0] {
            let f = longitudinal_force(&soil, &p, w6(), s);
            let num = integrate_shear(&soil, &p, w6(), s, soil.shear_k_m);
            assert!((f - num).abs() < 1e-6 * num.max(1.0), "s {s}: {f} vs {num}");
            // Skid: same magnitude, opposite sign, in this module's convention.
            let fs = longitudinal_force(&soil, &p, w6(), -s);
            assert!((fs + f).abs() < 1e-12);
        }
    }

    #[test]
    fn longitudinal_force_is_monotone_continuous_and_bounded() {
        for soil in soils() {
            let p = patch(&soil, &Wheel::rocky8(), w6());
            let f_max = soil.max_shear_force(p.area_m2, w6());
            assert_eq!(longitudinal_force(&soil, &p, w6(), 0.0), 0.0);
            let eps = 1e-9;
            let (fp, fm) = (
                longitudinal_force(&soil, &p, w6(), eps),
                longitudinal_force(&soil, &p, w6(), -eps),
            );
            assert!(fp > 0.0 && fm < 0.0 && fp.abs() < 1e-6 && fm.abs() < 1e-6);
            let mut prev = f64::NEG_INFINITY;
            for k in -1000..=1000 {
                let s = k as f64 / 1000.0;
                let f = longitudinal_force(&soil, &p, w6(), s);
                assert!(f > prev, "not increasing at s = {s}");
                assert!(f.abs() < f_max);
                prev = f;
            }
            // Clamped beyond |s| = 1.
            assert_eq!(
                longitudinal_force(&soil, &p, w6(), 3.0),
                longitudinal_force(&soil, &p, w6(), 1.0)
            );
        }
    }

    #[test]
    fn lateral_force_matches_integration_and_opposes_sliding() {
        let soil = Soil::sandy_loam();
        let p = patch(&soil, &Wheel::rocky8(), w6());
        for (s, a) in [(0.0, 0.05), (0.2, 0.3), (0.5, 1.0), (-0.3, 0.2)] {
            let f = lateral_force(&soil, &p, w6(), s, a);
            let travel = 1.0 - f64::max(s, 0.0);
            let num = integrate_shear(&soil, &p, w6(), travel * f64::tan(a), soil.shear_k_y_m);
            assert!(f < 0.0);
            assert!((f + num).abs() < 1e-6 * num, "s {s} a {a}: {f} vs {num}");
            assert!((lateral_force(&soil, &p, w6(), s, -a) + f).abs() < 1e-12);
        }
        assert_eq!(lateral_force(&soil, &p, w6(), 0.3, 0.0), 0.0);
        assert_eq!(lateral_force(&soil, &p, w6(), 1.0, 0.5), 0.0);
    }

    #[test]
    fn lateral_force_grows_with_slip_angle_and_falls_with_slip() {
        for soil in soils() {
            let p = patch(&soil, &Wheel::rocky8(), w6());
            let mut prev = 0.0;
            for k in 1..=80 {
                let a = (k as f64).to_radians();
                let f = -lateral_force(&soil, &p, w6(), 0.1, a);
                assert!(f > prev, "not increasing at {k} deg");
                prev = f;
            }
            let mut prev = f64::INFINITY;
            for k in 0..=100 {
                let f = -lateral_force(&soil, &p, w6(), k as f64 / 100.0, 0.3);
                assert!(f < prev || (k == 0), "not decreasing at s {k}%");
                prev = f;
            }
        }
    }

    #[test]
    fn slip_for_traction_inverts_and_is_monotone() {
        for soil in soils() {
            let p = patch(&soil, &Wheel::rocky8(), w6());
            let f1 = longitudinal_force(&soil, &p, w6(), 1.0);
            let mut prev = -2.0;
            for k in -99..=99 {
                let demand = f1 * k as f64 / 100.0;
                let sol = slip_for_traction(&soil, &p, w6(), demand);
                assert!(!sol.saturated);
                assert!(
                    sol.slip_ratio > prev,
                    "slip not increasing with demand at {k}%"
                );
                prev = sol.slip_ratio;
                let back = longitudinal_force(&soil, &p, w6(), sol.slip_ratio);
                assert!((back - demand).abs() < 1e-6 * f1, "{back} vs {demand}");
            }
            let sat = slip_for_traction(&soil, &p, w6(), 1.01 * f1);
            assert!(sat.saturated && sat.slip_ratio == 1.0);
            let sat = slip_for_traction(&soil, &p, w6(), -1.01 * f1);
            assert!(sat.saturated && sat.slip_ratio == -1.0);
            let zero = slip_for_traction(&soil, &p, w6(), 0.0);
            assert!(!zero.saturated && zero.slip_ratio == 0.0);
        }
    }

    #[test]
    fn slip_angle_for_side_force_inverts_and_is_monotone() {
        for soil in soils() {
            let p = patch(&soil, &Wheel::rocky8(), w6());
            let s = 0.1;
            let f80 = -lateral_force(&soil, &p, w6(), s, MAX_SLIP_ANGLE_RAD);
            let mut prev = 0.0;
            for k in 1..=99 {
                let demand = f80 * k as f64 / 100.0;
                let (a, sat) = slip_angle_for_side_force(&soil, &p, w6(), s, demand);
                assert!(!sat);
                // Positive demand (+y force) needs the wheel sliding towards -y.
                assert!(a < 0.0 && -a > prev, "angle not increasing at {k}%");
                prev = -a;
                let back = lateral_force(&soil, &p, w6(), s, a);
                assert!((back - demand).abs() < 1e-6 * f80);
                let (am, _) = slip_angle_for_side_force(&soil, &p, w6(), s, -demand);
                assert!((am + a).abs() < 1e-12);
            }
            let (a, sat) = slip_angle_for_side_force(&soil, &p, w6(), s, 1.01 * f80);
            assert!(sat && (a + MAX_SLIP_ANGLE_RAD).abs() < 1e-15);
            assert_eq!(
                slip_angle_for_side_force(&soil, &p, w6(), s, 0.0),
                (0.0, false)
            );
        }
    }

    fn sum(n: &[f64; 6]) -> f64 {
        n.iter().sum()
    }

    /// Level Rocky 8, hand-computed: by symmetry each side carries W/2; the bogie pair acts at
    /// the bogie pivot (x_b = 0.129), so pitch about the CoM (x_c = 0) gives the rear wheel
    /// N_r = (W/2)(x_b - x_c)/(x_b - x_r) = (W/2)(0.129/0.483); the bogie splits the rest with
    /// N_f/N_m = (x_b - x_m)/(x_f - x_b) = 0.1285/0.264.
    #[test]
    fn level_rocky8_loads_match_hand_computation() {
        let input = LoadInput::rocky8_level();
        let w = input.weight_n;
        let n = rocker_bogie_loads(&input).expect("loads");
        let side = w / 2.0;
        let rear = side * 0.129 / 0.483;
        let bogie = side - rear;
        let front = bogie * 0.1285 / 0.3925;
        let middle = bogie * 0.264 / 0.3925;
        let expected = [front, front, middle, middle, rear, rear];
        for i in 0..6 {
            assert!(
                (n[i] - expected[i]).abs() < 1e-9 * w,
                "wheel {}: {} vs {}",
                i + 1,
                n[i],
                expected[i]
            );
        }
        assert!((sum(&n) - w).abs() < 1e-9 * w);
        // Bogie balance about its pivot.
        assert!((n[0] * (0.393 - 0.129) + n[2] * (0.0005 - 0.129)).abs() < 1e-9 * w);
    }

    fn rotated(input: &LoadInput, g: Vector3<f64>) -> LoadInput {
        LoadInput {
            gravity_dir: g,
            ..*input
        }
    }

    #[test]
    fn cross_slope_transfers_load_downhill() {
        let level = rocker_bogie_loads(&LoadInput::rocky8_level()).unwrap();
        for deg in [10.0_f64, 15.0, 20.0] {
            let r = deg.to_radians();
            // Right side downhill: gravity has a +y component in R.
            let input = rotated(
                &LoadInput::rocky8_level(),
                Vector3::new(0.0, r.sin(), r.cos()),
            );
            let n = rocker_bogie_loads(&input).unwrap();
            assert!((sum(&n) - input.weight_n).abs() < 1e-9 * input.weight_n);
            for (&ri, &li) in RIGHT.iter().zip(LEFT.iter()) {
                assert!(
                    n[ri] > level[ri] && n[li] < level[li],
                    "{deg} deg wheel {}",
                    ri + 1
                );
            }
            // Mirror: left side downhill.
            let m =
                rocker_bogie_loads(&rotated(&input, Vector3::new(0.0, -r.sin(), r.cos()))).unwrap();
            for (&ri, &li) in RIGHT.iter().zip(LEFT.iter()) {
                assert!((m[li] - n[ri]).abs() < 1e-9 * input.weight_n);
            }
        }
    }

    #[test]
    fn nose_up_pitch_transfers_load_to_rear() {
        let level = rocker_bogie_loads(&LoadInput::rocky8_level()).unwrap();
        let mut prev_rear = level[4];
        for deg in [5.0_f64, 10.0, 20.0] {
            let r = deg.to_radians();
            // Nose up: body x points up-slope, so gravity has a -x component in R.
            let input = rotated(
                &LoadInput::rocky8_level(),
                Vector3::new(-r.sin(), 0.0, r.cos()),
            );
            let n = rocker_bogie_loads(&input).unwrap();
            assert!((sum(&n) - input.weight_n).abs() < 1e-9 * input.weight_n);
            assert!(n[4] > prev_rear && n[5] > prev_rear - 1e-9);
            assert!(n[0] + n[2] < level[0] + level[2]);
            prev_rear = n[4];
        }
    }

    /// The differential: with an asymmetric layout the solution must satisfy, independently
    /// recomputed here, the force and moment balance, both bogie balances and equal (same-sign)
    /// ground moments about the two rocker pivot axes. With the CoM ahead of the rocker pivots,
    /// both moments are non-zero and equal; an opposite-sign differential would force them to
    /// cancel.
    #[test]
    fn differential_transmits_equal_moments() {
        let mut input = LoadInput::rocky8_level();
        input.contacts[0].x = 0.45; // right front further out
        input.contacts[4].x = -0.30; // right rear further in
        input.centre_of_mass = Vector3::new(0.05, 0.02, -0.25);
        let n = rocker_bogie_loads(&input).unwrap();
        let w = input.weight_n;
        assert!(n.iter().all(|&v| v > 0.0));
        assert!((sum(&n) - w).abs() < 1e-9 * w);
        // Level ground: the moment of N_i about a lateral axis through point q is N_i (x_i - x_q)
        // (same sign convention on both sides).
        let mom = |idx: &[usize], qx: f64| -> f64 {
            idx.iter().map(|&i| n[i] * (input.contacts[i].x - qx)).sum()
        };
        let m_r = mom(&RIGHT, input.rocker_pivot_right.x);
        let m_l = mom(&LEFT, input.rocker_pivot_left.x);
        assert!(m_r.abs() > 1.0, "moment should be non-trivial: {m_r}");
        assert!((m_r - m_l).abs() < 1e-9 * w, "{m_r} vs {m_l}");
        assert!(mom(&BOGIE_RIGHT, 0.129).abs() < 1e-9 * w);
        assert!(mom(&BOGIE_LEFT, 0.129).abs() < 1e-9 * w);
        let all = [0, 1, 2, 3, 4, 5];
        assert!(mom(&all, input.centre_of_mass.x).abs() < 1e-9 * w);
        let roll: f64 = (0..6).map(|i| n[i] * (input.contacts[i].y - 0.02)).sum();
        assert!(roll.abs() < 1e-9 * w);
    }

    #[test]
    fn steep_pitch_lifts_front_wheels_without_negative_loads() {
        let r = 50.0_f64.to_radians();
        let input = rotated(
            &LoadInput::rocky8_level(),
            Vector3::new(-r.sin(), 0.0, r.cos()),
        );
        // The plain 6x6 solution has negative front loads here (CoM behind the rear axle).
        let (a, b) = load_system(&input, &input.gravity_dir.normalize());
        let plain = a.lu().solve(&b).unwrap();
        assert!(plain.iter().any(|&v| v < 0.0));
        let n = rocker_bogie_loads(&input).unwrap();
        assert!(n.iter().all(|&v| v >= 0.0));
        assert!(n.contains(&0.0));
        assert!((sum(&n) - input.weight_n).abs() < 1e-9 * input.weight_n);
    }

    #[test]
    fn degenerate_or_invalid_layouts_give_none() {
        let mut input = LoadInput::rocky8_level();
        input.contacts = [Vector3::new(0.0, 0.0, 0.1); 6];
        assert!(rocker_bogie_loads(&input).is_none());
        let mut input = LoadInput::rocky8_level();
        input.centre_of_mass.x = f64::NAN;
        assert!(rocker_bogie_loads(&input).is_none());
        let mut input = LoadInput::rocky8_level();
        input.gravity_dir = Vector3::zeros();
        assert!(rocker_bogie_loads(&input).is_none());
        let mut input = LoadInput::rocky8_level();
        input.weight_n = 0.0;
        assert_eq!(rocker_bogie_loads(&input), Some([0.0; 6]));
    }

    /// The figures of `docs/terramechanics.md` (outcomes of the model; printed with
    /// `--nocapture`). Checks only internal consistency.
    #[test]
    fn print_figures() {
        let wheel = Wheel::rocky8();
        let input = LoadInput::rocky8_level();
        let loads = rocker_bogie_loads(&input).unwrap();
        println!("Rocky 8 level loads (N), W = {:.2} N:", input.weight_n);
        for (i, l) in loads.iter().enumerate() {
            println!("  wheel {} : {:.2}", i + 1, l);
        }
        let names = ["dry sand", "sandy loam", "Mars DLR simulant"];
        println!("Patch per wheel at the level loads (front / middle / rear):");
        for (name, soil) in names.iter().zip(soils()) {
            for (pos, i) in [("front", 0), ("middle", 2), ("rear", 4)] {
                let p = patch(&soil, &wheel, loads[i]);
                println!(
                    "  {name:18} {pos:6} N {:6.2} N: z0 {:6.2} mm, L {:5.1} mm, A {:6.1} cm^2, R_c {:5.2} N ({:.3} N/N), F(s=1) {:5.2} N",
                    loads[i],
                    p.sinkage_m * 1e3,
                    p.contact_length_m * 1e3,
                    p.area_m2 * 1e4,
                    p.compaction_resistance_n,
                    p.compaction_resistance_n / loads[i],
                    longitudinal_force(&soil, &p, loads[i], 1.0),
                );
                assert!(p.sinkage_m > 0.0);
            }
        }
        let wi = w6();
        println!("Uphill, W_i = W/6 = {wi:.2} N, normal load W_i cos(theta), demand W_i sin(theta) + R_c:");
        for (name, soil) in names.iter().zip(soils()) {
            for deg in [0.0_f64, 5.0, 10.0, 15.0, 20.0] {
                let t = deg.to_radians();
                let nl = wi * t.cos();
                let p = patch(&soil, &wheel, nl);
                let demand = wi * t.sin() + p.compaction_resistance_n;
                let sol = slip_for_traction(&soil, &p, nl, demand);
                println!(
                    "  {name:18} {deg:4.0} deg: demand {demand:6.2} N, s = {:.3}{}",
                    sol.slip_ratio,
                    if sol.saturated { " SATURATED" } else { "" }
                );
            }
        }
        println!("Cross slope, normal W_i cos(theta), side demand W_i sin(theta), longitudinal demand R_c:");
        for (name, soil) in names.iter().zip(soils()) {
            for deg in [10.0_f64, 20.0] {
                let t = deg.to_radians();
                let nl = wi * t.cos();
                let p = patch(&soil, &wheel, nl);
                let sol = slip_for_traction(&soil, &p, nl, p.compaction_resistance_n);
                let (a, sat) =
                    slip_angle_for_side_force(&soil, &p, nl, sol.slip_ratio, wi * t.sin());
                println!(
                    "  {name:18} {deg:4.0} deg: s = {:.3}{}, alpha = {:.1} deg{}",
                    sol.slip_ratio,
                    if sol.saturated { " SATURATED" } else { "" },
                    a.to_degrees(),
                    if sat { " SATURATED" } else { "" }
                );
            }
        }
    }
}
