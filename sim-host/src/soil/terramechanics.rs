//! Soil and wheel parameters, and the quasi-static wheel loads of a rocker-bogie: ground-truth
//! building blocks for the vehicle model (see `docs/terramechanics.md` for the equations, the
//! parameter sources and the simplifications). The wheel-soil force law is in
//! [`crate::soil::rigid_wheel`].
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
//!   lateral sliding, so it is negative for positive `alpha`.
//! - The rover body frame `R`: `x` forward, `y` right, `z` down.

use nalgebra::{Matrix6, Vector3, Vector6};

/// Mars surface gravity, m/s^2 (NASA Mars Fact Sheet: 3.71 m/s^2; 3.711 as commonly quoted).
pub const MARS_GRAVITY: f64 = 3.711;

/// Pressure-sinkage (Bekker), shear (Mohr-Coulomb / Janosi-Hanamoto) and stress-distribution
/// (Wong-Reece) parameters of a soil, as the rigid-wheel model of [`crate::soil::rigid_wheel`] uses
/// them.
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
    /// Janosi-Hanamoto shear deformation modulus `K_x` (longitudinal) at zero slip angle, m.
    pub shear_k_m: f64,
    /// Growth of `K_x` with the slip angle `|alpha|`, m/rad (Ishigami et al. 2007 fit
    /// `K_x = K_x0 + k |alpha|`; 0 when the source gives a constant).
    pub shear_k_slope_m_per_rad: f64,
    /// Lateral shear deformation modulus `K_y` (Ishigami et al. 2007) at zero slip angle, m.
    pub shear_k_y_m: f64,
    /// Growth of `K_y` with `|alpha|`, m/rad.
    pub shear_k_y_slope_m_per_rad: f64,
    /// Wong-Reece maximum-stress angle coefficients: `theta_m = (a0 + a1 s) theta_1`.
    pub theta_m_a0: f64,
    /// See [`Soil::theta_m_a0`].
    pub theta_m_a1: f64,
    /// Rear-to-front sinkage ratio `lambda` that sets the exit angle
    /// `theta_2 = -acos(1 - lambda (1 - cos theta_1))` (Ishigami et al. 2007's "wheel sinkage
    /// ratio"); 0 puts the exit at the bottom of the wheel (`theta_2 = 0`, no rebound).
    pub exit_sinkage_ratio: f64,
    /// Where the values come from.
    pub source: &'static str,
}

/// Wong & Reece (1967) coefficients of the maximum-stress angle for sand,
/// `theta_m / theta_1 = c1 + c2 i` with `c1 = 0.43`, `c2 = 0.32`, as quoted in Wong, *Theory of
/// Ground Vehicles*, ch. 2 (not checked against the 1967 paper). Used for the soils whose source
/// gives no stress-distribution coefficients.
pub const WONG_REECE_SAND_A0: f64 = 0.43;
/// See [`WONG_REECE_SAND_A0`].
pub const WONG_REECE_SAND_A1: f64 = 0.32;

impl Soil {
    /// The lunar regolith simulant of Ishigami, Miwa, Nagatani, Yoshida, "Terramechanics-based
    /// model for steering maneuver of planetary exploration rovers on loose soil", *J. Field
    /// Robotics* 24(3), 2007, soil-parameter table: `c` 0.8 kPa, `phi` 37.2 deg, `k_c`
    /// 1.37e3 N/m^(n+1), `k_phi` 8.14e5 N/m^(n+2), `n` 1.0, `a0` 0.40, `a1` 0.15,
    /// `K_x = 0.043 |alpha| + 0.036` m, `K_y = 0.020 |alpha| + 0.013` m (`alpha` in rad), wheel
    /// sinkage ratio `lambda` 0.9 (exit angle); measured
    /// with single-wheel tests of a 0.18 m diameter, 0.11 m wide rigid wheel. The values were
    /// read from two independent public transcriptions of the table (Ishigami-model code in
    /// public repositories), not from a stored copy of the paper; the soil density (1.6e3
    /// kg/m^3) and the bulldozing angle (26.4 deg) of the same table are not used (no bulldozing
    /// term). This is the `loose_sand` preset.
    pub fn ishigami_regolith_simulant() -> Self {
        Self {
            n: 1.0,
            k_c: 1.37e3,
            k_phi: 8.14e5,
            cohesion_pa: 0.8e3,
            phi_rad: 37.2_f64.to_radians(),
            shear_k_m: 0.036,
            shear_k_slope_m_per_rad: 0.043,
            shear_k_y_m: 0.013,
            shear_k_y_slope_m_per_rad: 0.020,
            theta_m_a0: 0.40,
            theta_m_a1: 0.15,
            exit_sinkage_ratio: 0.9,
            source: "Ishigami, Miwa, Nagatani, Yoshida, J. Field Robotics 24(3), 2007, soil \
                     table (lunar regolith simulant, 0.18 m x 0.11 m wheel), as transcribed in \
                     public code",
        }
    }

    /// Dry sand (Land Locomotion Laboratory): Wong, *Theory of Ground Vehicles*, Table 2.3:
    /// `n` 1.1, `k_c` 0.99 kN/m^(n+1), `k_phi` 1528.43 kN/m^(n+2), `c` 1.04 kPa, `phi` 28.0 deg.
    /// `K` = 2.5 cm: Wong's typical value for loose sand (ch. 2, Janosi-Hanamoto shear); the
    /// same set with `K` = 0.0254 m is quoted by Hindawi TSWJ 2014 (396382), Table 2, which
    /// gives `k_c` = 0.95 instead of 0.99 (the Wong table value is kept). `K_y`: no published
    /// value for this soil was found, so `K_y = K` (isotropic shear; an assumption).
    /// `theta_m`: [`WONG_REECE_SAND_A0`], [`WONG_REECE_SAND_A1`]; exit angle 0 (no rebound,
    /// Wong-Reece for sand). Plate (bevameter) values
    /// of a vehicle-scale soil; preset `wong_dry_sand` (the `loose_sand` of earlier versions).
    pub fn dry_sand() -> Self {
        Self {
            n: 1.1,
            k_c: 0.99e3,
            k_phi: 1528.43e3,
            cohesion_pa: 1.04e3,
            phi_rad: 28.0_f64.to_radians(),
            shear_k_m: 0.025,
            shear_k_slope_m_per_rad: 0.0,
            shear_k_y_m: 0.025,
            shear_k_y_slope_m_per_rad: 0.0,
            theta_m_a0: WONG_REECE_SAND_A0,
            theta_m_a1: WONG_REECE_SAND_A1,
            exit_sinkage_ratio: 0.0,
            source: "Wong, Theory of Ground Vehicles, Table 2.3, dry sand (LLL); K = 2.5 cm \
                     (Wong, loose sand); K_y = K (assumption); theta_m: Wong-Reece sand",
        }
    }

    /// Sandy loam, moisture about 15 % (Land Locomotion Laboratory), a firm soil: Wong,
    /// *Theory of Ground Vehicles*, Table 2.3: `n` 0.7, `k_c` 5.27 kN/m^(n+1), `k_phi`
    /// 1515.04 kN/m^(n+2), `c` 1.72 kPa, `phi` 29 deg. `K` = 1 cm: Wong's typical value for
    /// firm sandy terrain. `K_y = K` (assumption, as for [`Soil::dry_sand`]). `theta_m`: the
    /// Wong-Reece sand coefficients (an assumption for a loam). The `firm_soil` preset: no
    /// published small-wheel parameter set of a firm soil was found.
    pub fn sandy_loam() -> Self {
        Self {
            n: 0.7,
            k_c: 5.27e3,
            k_phi: 1515.04e3,
            cohesion_pa: 1.72e3,
            phi_rad: 29.0_f64.to_radians(),
            shear_k_m: 0.01,
            shear_k_slope_m_per_rad: 0.0,
            shear_k_y_m: 0.01,
            shear_k_y_slope_m_per_rad: 0.0,
            theta_m_a0: WONG_REECE_SAND_A0,
            theta_m_a1: WONG_REECE_SAND_A1,
            exit_sinkage_ratio: 0.0,
            source: "Wong, Theory of Ground Vehicles, Table 2.3, sandy loam ~15 % moisture \
                     (LLL); K = 1 cm (Wong, firm sandy terrain); K_y = K (assumption); \
                     theta_m: Wong-Reece sand (assumption)",
        }
    }

    /// DLR mechanical Mars soil simulant, **as commonly quoted** (not checked against the
    /// primary source): `n` 0.8, `k_c` 5.79 kN/m^(n+1), `k_phi` 180 kN/m^(n+2), `c` 0.3 kPa,
    /// `phi` 17.8 deg, attributed to "Strength of soil deposits along MER traverses" (NASA) in
    /// the soil table of Project Chrono's SCM deformable-terrain demo. `K` = 1 cm is the
    /// value that table uses (it is not part of the cited set). `K_y = K` (assumption).
    /// `theta_m`: the Wong-Reece sand coefficients (assumption).
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
            shear_k_slope_m_per_rad: 0.0,
            shear_k_y_m: 0.01,
            shear_k_y_slope_m_per_rad: 0.0,
            theta_m_a0: WONG_REECE_SAND_A0,
            theta_m_a1: WONG_REECE_SAND_A1,
            exit_sinkage_ratio: 0.0,
            source: "DLR Mars soil simulant as commonly quoted (Project Chrono SCM demo table, \
                     citing 'Strength of soil deposits along MER traverses', NASA); K = 1 cm \
                     from that table; K_y = K (assumption); theta_m: Wong-Reece sand \
                     (assumption)",
        }
    }

    /// Longitudinal shear deformation modulus `K_x` at slip angle `alpha` (rad), m.
    pub fn k_x(&self, alpha_rad: f64) -> f64 {
        self.shear_k_m + self.shear_k_slope_m_per_rad * alpha_rad.abs()
    }

    /// Lateral shear deformation modulus `K_y` at slip angle `alpha` (rad), m.
    pub fn k_y(&self, alpha_rad: f64) -> f64 {
        self.shear_k_y_m + self.shear_k_y_slope_m_per_rad * alpha_rad.abs()
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

    /// The load figures of `docs/terramechanics.md` (printed with `--nocapture`).
    #[test]
    fn print_load_figures() {
        let input = LoadInput::rocky8_level();
        let loads = rocker_bogie_loads(&input).unwrap();
        println!("Rocky 8 level loads (N), W = {:.2} N:", input.weight_n);
        for (i, l) in loads.iter().enumerate() {
            println!("  wheel {} : {:.2}", i + 1, l);
        }
        assert!((sum(&loads) - input.weight_n).abs() < 1e-9 * input.weight_n);
    }
}
