//! Per-wheel slip from rigid-wheel terramechanics with quasi-static wheel loads (the default
//! slip model, `slip_model = "terramechanics"`).
//!
//! Each step, from the wheel contacts of the last placement:
//!
//! 1. **Load split.** The rocker-bogie is statically determinate: the normal load of each
//!    wheel follows from the contact points, the pivots, the centre of mass and the direction
//!    of gravity in the body frame ([`rocker_bogie_loads`]); so load moves downhill on a cross
//!    slope, to the rear when the nose is up, and onto a wheel that sits on a rock. Wheels in the
//!    air carry nothing.
//! 2. **What the ground must deliver.** Quasi-static equilibrium of the whole vehicle: the
//!    contact forces balance the weight. With the load shares `w_i` and each wheel's contact
//!    normal `n_i`, rolling tangent `t_i` and spin axis `l_i` (all in `R`), the 3x3 system
//!    `sum_i w_i (lambda n_i + mu t_i + nu l_i) = -g_hat` gives the normal (`lambda`), traction
//!    (`mu`) and side (`nu`) force per unit weight, under the assumption that every wheel on
//!    the ground works at the same traction and side-force utilisation (velocity-controlled
//!    wheels on one rigid body, uniform soil). On a slope this is the weight component along
//!    the motion and across it; at a wheel pressed against a step face its normal force pushes
//!    back and the other wheels must push it up.
//! 3. **Per-wheel slip.** Wheel `i` carries `N_i = lambda w_i W` and must deliver the drawbar
//!    pull `T_i = mu w_i W` (the rigid-wheel drawbar pull already contains the wheel's own
//!    compaction resistance) and the side force `Y_i = nu w_i W`. Its slip ratio and slip angle
//!    invert the Wong-Reece / Ishigami rigid-wheel model of [`crate::soil::rigid_wheel`] (through a
//!    per-wheel [`WheelTable`] built when the run starts) under its own load: the slip ratio at
//!    zero slip angle, the slip angle at that slip ratio, then both once more (the shear moduli
//!    and the lateral shear depend on both); so the six wheels slip differently. A wheel that
//!    cannot deliver its share spins (`s = 1`) or slides at the largest slip angle.
//!
//! The rolling solve ([`crate::vehicle::rolling`]) then moves each axle at
//! `(1 - s_i) r_i theta_dot_i` (`r_i` its own radius) along its tangent
//! (`r_i theta_dot_i / (1 + s_i)` when skidding) and at `tan(alpha_i)` times that sideways. A
//! wheel that is not turning holds (its motor is not back-drivable): no slip is computed for it.
//!
//! Per seed the soil parameters (`c`, `phi`, `K`, `K_y`, `k_phi`) are scaled by
//! `1 + N(0, sigma)` with `sigma` = 5 % (an assumption on soil variability between sites).

use crate::soil::rigid_wheel::WheelTable;
use crate::soil::terramechanics::{
    rocker_bogie_loads, LoadInput, Soil, Wheel, MARS_GRAVITY, ROCKY8_MASS_KG, WONG_REECE_SAND_A0,
    WONG_REECE_SAND_A1,
};
use crate::vehicle::geometry::{TruthGeometry, WHEELS};
use nalgebra::{Matrix3, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Deserialize;

/// Soil parameters as a scenario file gives them explicitly (Bekker, shear and Wong-Reece
/// parameters; see [`Soil`]).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct SoilParams {
    /// Bekker sinkage exponent `n`.
    pub n: f64,
    /// Bekker cohesive modulus `k_c`, N/m^(n+1).
    pub k_c: f64,
    /// Bekker frictional modulus `k_phi`, N/m^(n+2).
    pub k_phi: f64,
    /// Cohesion, Pa.
    pub cohesion_pa: f64,
    /// Internal friction angle, degrees.
    pub friction_angle_deg: f64,
    /// Shear deformation modulus `K`, m.
    pub shear_modulus_m: f64,
    /// Lateral shear deformation modulus `K_y`, m (default `K`).
    #[serde(default)]
    pub lateral_shear_modulus_m: Option<f64>,
    /// Growth of `K` with the slip angle, m/rad (default 0).
    #[serde(default)]
    pub shear_modulus_slope_m_per_rad: f64,
    /// Growth of `K_y` with the slip angle, m/rad (default 0).
    #[serde(default)]
    pub lateral_shear_modulus_slope_m_per_rad: f64,
    /// Wong-Reece `a0` of `theta_m = (a0 + a1 s) theta_1` (default 0.43, Wong & Reece sand).
    #[serde(default)]
    pub theta_m_a0: Option<f64>,
    /// Wong-Reece `a1` (default 0.32, Wong & Reece sand).
    #[serde(default)]
    pub theta_m_a1: Option<f64>,
    /// Rear-to-front sinkage ratio (exit angle; default 0: exit at the bottom of the wheel).
    #[serde(default)]
    pub exit_sinkage_ratio: f64,
}

impl SoilParams {
    /// The soil.
    pub fn soil(&self) -> Soil {
        Soil {
            n: self.n,
            k_c: self.k_c,
            k_phi: self.k_phi,
            cohesion_pa: self.cohesion_pa,
            phi_rad: self.friction_angle_deg.to_radians(),
            shear_k_m: self.shear_modulus_m,
            shear_k_slope_m_per_rad: self.shear_modulus_slope_m_per_rad,
            shear_k_y_m: self.lateral_shear_modulus_m.unwrap_or(self.shear_modulus_m),
            shear_k_y_slope_m_per_rad: self.lateral_shear_modulus_slope_m_per_rad,
            theta_m_a0: self.theta_m_a0.unwrap_or(WONG_REECE_SAND_A0),
            theta_m_a1: self.theta_m_a1.unwrap_or(WONG_REECE_SAND_A1),
            exit_sinkage_ratio: self.exit_sinkage_ratio,
            source: "scenario file",
        }
    }
}

/// Relative per-seed scatter of the soil parameters (1 sigma), an assumption.
pub const SOIL_SCATTER: f64 = 0.05;

/// Centre of mass of the truth vehicle in `R`, m: an assumption (no published figure for
/// Rocky 8): on the centre line, 0.25 m above the axles.
pub fn centre_of_mass() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, -0.25)
}

/// One wheel's contact as the slip model needs it, in `R`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelGround {
    /// Whether the wheel touches the ground.
    pub touching: bool,
    /// Contact point, m.
    pub point: Vector3<f64>,
    /// Unit contact normal (contact to axle).
    pub normal: Vector3<f64>,
    /// Unit rolling tangent.
    pub tangent: Vector3<f64>,
    /// Unit spin axis.
    pub spin: Vector3<f64>,
    /// Rim speed `r_i theta_dot_i` (the wheel's own radius), m/s.
    pub rim_speed_m_s: f64,
}

/// One wheel's slip over a step.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WheelSlip {
    /// Normal load, N.
    pub load_n: f64,
    /// Longitudinal slip ratio (`[-1, 1]`, see [`crate::soil::terramechanics`]).
    pub slip_ratio: f64,
    /// Slip angle, rad (positive: sliding towards the wheel's `+y`).
    pub slip_angle_rad: f64,
    /// The soil could not deliver this wheel's share.
    pub saturated: bool,
    /// Axle speed along the rolling tangent, m/s.
    pub ground_speed_m_s: f64,
    /// Axle speed along the spin axis, m/s.
    pub lateral_m_s: f64,
}

/// Slip of the whole vehicle over one step (load-weighted means over the wheels on the
/// ground), for telemetry and reports.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SlipState {
    /// Mean longitudinal slip ratio.
    pub slip_ratio: f64,
    /// Mean slip angle, rad (positive: drift to the rover's right).
    pub slip_angle_rad: f64,
}

/// The slip model of one run.
#[derive(Debug, Clone)]
pub struct SlipModel {
    soil: Soil,
    /// The rigid-wheel model of each wheel (its own radius; width as [`Wheel::rocky8`]),
    /// tabulated for this run's soil.
    tables: Vec<WheelTable>,
    enabled: bool,
    weight_n: f64,
}

/// The rigid-wheel tables of wheels of radii `radii_m` (width as [`Wheel::rocky8`]) on `soil`.
fn tables_for(soil: &Soil, radii_m: &[f64; WHEELS]) -> Vec<WheelTable> {
    radii_m
        .iter()
        .map(|&radius_m| {
            WheelTable::new(
                soil,
                &Wheel {
                    radius_m,
                    ..Wheel::rocky8()
                },
            )
        })
        .collect()
}

/// Rim speed below which a wheel counts as not turning, m/s.
const STILL_M_S: f64 = 1e-5;

impl SlipModel {
    /// A slip model for `soil` and wheels of radii `wheel_radii_m` (wheel order), with the
    /// per-seed scatter drawn from `rng`. `enabled = false` turns slip off (every axle moves at
    /// its rim speed). Each wheel's force law uses its own radius.
    pub fn new(
        soil: Soil,
        wheel_radii_m: [f64; WHEELS],
        enabled: bool,
        rng: &mut ChaCha8Rng,
    ) -> Self {
        let mut scale = |v: f64| {
            let n: f64 = StandardNormal.sample(rng);
            v * (1.0 + SOIL_SCATTER * n).max(0.5)
        };
        let drawn = Soil {
            cohesion_pa: scale(soil.cohesion_pa),
            phi_rad: scale(soil.phi_rad),
            shear_k_m: scale(soil.shear_k_m),
            shear_k_y_m: scale(soil.shear_k_y_m),
            k_phi: scale(soil.k_phi),
            ..soil
        };
        let tables = if enabled {
            tables_for(&drawn, &wheel_radii_m)
        } else {
            Vec::new()
        };
        Self {
            soil: drawn,
            tables,
            enabled,
            weight_n: ROCKY8_MASS_KG * MARS_GRAVITY,
        }
    }

    /// The soil of this run (after the per-seed draw).
    pub fn soil(&self) -> &Soil {
        &self.soil
    }

    /// Per-wheel slip for the wheel contacts `ground` (in `R`), the geometry at rocker angle
    /// `rocker_rad` and gravity direction `gravity_r` (unit, `R`).
    pub fn wheel_slips(
        &self,
        geometry: &TruthGeometry,
        rocker_rad: f64,
        ground: &[WheelGround; WHEELS],
        gravity_r: &Vector3<f64>,
    ) -> ([WheelSlip; WHEELS], SlipState) {
        let mut out = [WheelSlip::default(); WHEELS];
        for (o, g) in out.iter_mut().zip(ground) {
            o.ground_speed_m_s = g.rim_speed_m_s;
        }
        if !self.enabled {
            return (out, SlipState::default());
        }
        let input = LoadInput {
            contacts: ground.map(|g| g.point),
            rocker_pivot_right: geometry.rocker_pivot(0),
            rocker_pivot_left: geometry.rocker_pivot(1),
            bogie_pivot_right: geometry.bogie_pivot(0, rocker_rad),
            bogie_pivot_left: geometry.bogie_pivot(1, rocker_rad),
            centre_of_mass: centre_of_mass(),
            gravity_dir: *gravity_r,
            weight_n: self.weight_n,
        };
        let Some(mut loads) = rocker_bogie_loads(&input) else {
            return (out, SlipState::default());
        };
        for (l, g) in loads.iter_mut().zip(ground) {
            if !g.touching {
                *l = 0.0;
            }
        }
        let total: f64 = loads.iter().sum();
        if total <= 0.0 {
            return (out, SlipState::default());
        }
        // Force per unit weight the ground must deliver: normal, traction, side.
        let mut a = Matrix3::zeros();
        for (l, g) in loads.iter().zip(ground) {
            let w = l / total;
            let cols = [g.normal, g.tangent, g.spin];
            for (k, c) in cols.iter().enumerate() {
                let col = a.column(k) + c * w;
                a.set_column(k, &col);
            }
        }
        let Some(x) = a.lu().solve(&(-gravity_r)) else {
            return (out, SlipState::default());
        };
        let (lambda, mu, nu) = (x[0], x[1], x[2]);
        let (mut mean_s, mut mean_a, mut weight) = (0.0, 0.0, 0.0);
        for i in 0..WHEELS {
            let g = &ground[i];
            let share = loads[i] / total * self.weight_n;
            let normal = (lambda * share).max(0.0);
            if !g.touching || normal <= 0.0 {
                continue;
            }
            let still = g.rim_speed_m_s.abs() < STILL_M_S;
            if still {
                out[i].load_n = normal;
                continue;
            }
            out[i] = wheel_slip(&self.tables[i], g, normal, [mu, nu], share);
            let (s, alpha) = (out[i].slip_ratio, out[i].slip_angle_rad);
            mean_s += normal * s;
            mean_a += normal * alpha * g.spin.y.signum();
            weight += normal;
        }
        let state = if weight > 0.0 {
            SlipState {
                slip_ratio: mean_s / weight,
                slip_angle_rad: mean_a / weight,
            }
        } else {
            SlipState::default()
        };
        (out, state)
    }
}

/// The slip of one rolling wheel on the ground `g` under the normal load `normal`, N, that
/// carries `share` of the weight, N, where the ground must deliver the traction and side force
/// `[mu, nu]` per unit weight: the slip ratio for the drawbar pull and the slip angle for the
/// side force, each solved twice (the slip angle changes the drawbar pull).
fn wheel_slip(
    table: &WheelTable,
    g: &WheelGround,
    normal: f64,
    [mu, nu]: [f64; 2],
    share: f64,
) -> WheelSlip {
    // Drawbar pull along the driving direction: the share of the weight's component (the
    // wheel's own compaction resistance is inside the rigid-wheel drawbar pull).
    let demand = g.rim_speed_m_s.signum() * mu * share;
    let side = nu * share;
    let first = table.slip_for_drawbar_pull(normal, 0.0, demand);
    let (alpha0, _) = table.slip_angle_for_side_force(normal, first.slip_ratio, side);
    let sol = table.slip_for_drawbar_pull(normal, alpha0, demand);
    let (alpha, side_saturated) = table.slip_angle_for_side_force(normal, sol.slip_ratio, side);
    let s = sol.slip_ratio;
    let ground_speed = if s >= 0.0 {
        g.rim_speed_m_s * (1.0 - s)
    } else {
        g.rim_speed_m_s / (1.0 + s).max(1e-3)
    };
    WheelSlip {
        load_n: normal,
        slip_ratio: s,
        slip_angle_rad: alpha,
        saturated: sol.saturated || side_saturated,
        ground_speed_m_s: ground_speed,
        lateral_m_s: ground_speed.abs() * alpha.tan(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vehicle::geometry::{rocky8, VehicleGeometry};
    use rand::SeedableRng;

    /// The rover standing on a plane (body parallel to it): contact normals along `-z_R`,
    /// gravity `gravity` in `R` (tilted on a slope).
    fn level_ground(g: &TruthGeometry, rim: f64, _gravity: Vector3<f64>) -> [WheelGround; WHEELS] {
        let w = g.wheels(0.0, [0.0, 0.0], &[0.0; 6]).unwrap();
        let up = -Vector3::z();
        std::array::from_fn(|i| WheelGround {
            touching: true,
            point: w[i].axle_m - up * g.wheel_radius_m[i],
            normal: up,
            tangent: up.cross(&w[i].spin_axis).normalize(),
            spin: w[i].spin_axis,
            rim_speed_m_s: rim,
        })
    }

    fn model(soil: Soil) -> SlipModel {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut m = SlipModel::new(soil, [0.1; WHEELS], true, &mut rng);
        m.soil = soil;
        m.tables = tables_for(&soil, &[0.1; WHEELS]);
        m
    }

    /// SIM-16: slip grows with the uphill slope on both scenario soils; on a cross slope the
    /// wheels slide downhill and the downhill wheels carry more load; the middle wheels, which
    /// carry most load, slip differently from the others; a wheel that is not turning does not
    /// slip; slip off gives the rim speed. (The old model's "sand slips more than the firm soil"
    /// does not hold for the published sets: the Ishigami et al. regolith simulant, with
    /// `phi` 37.2 deg and contact behind the axle, needs less slip than Wong's loam.)
    #[test]
    fn sim_16_per_wheel_slip() {
        let g = rocky8();
        for soil in [Soil::ishigami_regolith_simulant(), Soil::sandy_loam()] {
            let mut previous = -1.0;
            for deg in [0.0f64, 3.0, 6.0] {
                // Uphill: gravity tilted backwards in R (nose up).
                let th = deg.to_radians();
                let grav = Vector3::new(-th.sin(), 0.0, th.cos());
                let m = model(soil);
                let (w, s) = m.wheel_slips(&g, 0.0, &level_ground(&g, 0.1, grav), &grav);
                assert!(s.slip_ratio > previous, "{deg} deg: {s:?}");
                previous = s.slip_ratio;
                assert!((w[2].slip_ratio - w[0].slip_ratio).abs() > 1e-3, "{w:?}");
            }
        }
        // Cross slope of 10 deg, right side downhill: gravity has a +y component in R.
        let th = 10f64.to_radians();
        let grav = Vector3::new(0.0, th.sin(), th.cos());
        let loam = model(Soil::sandy_loam());
        let (w, s) = loam.wheel_slips(&g, 0.0, &level_ground(&g, 0.1, grav), &grav);
        assert!(
            s.slip_angle_rad > 0.0,
            "drifts to the right (downhill): {s:?}"
        );
        assert!(
            w[0].load_n > w[1].load_n && w[2].load_n > w[3].load_n,
            "{w:?}"
        );
        assert!(w.iter().all(|x| x.lateral_m_s > 0.0), "{w:?}");
        let (w, _) = loam.wheel_slips(&g, 0.0, &level_ground(&g, 0.0, grav), &grav);
        assert!(w
            .iter()
            .all(|x| x.ground_speed_m_s == 0.0 && x.lateral_m_s == 0.0));
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let off = SlipModel::new(
            Soil::ishigami_regolith_simulant(),
            [0.1; WHEELS],
            false,
            &mut rng,
        );
        let (w, _) = off.wheel_slips(&g, 0.0, &level_ground(&g, 0.1, grav), &grav);
        assert!(w
            .iter()
            .all(|x| x.ground_speed_m_s == 0.1 && x.lateral_m_s == 0.0));
    }

    /// Cost of one six-wheel step on a 10 deg cross slope (printed with `--nocapture`; the
    /// bound only catches a gross regression: 6 wheels at 200 Hz must stay far below real time).
    #[test]
    fn six_wheel_step_is_cheap() {
        let g = rocky8();
        let th = 10f64.to_radians();
        let grav = Vector3::new(0.0, th.sin(), th.cos());
        let m = model(Soil::ishigami_regolith_simulant());
        let ground = level_ground(&g, 0.1, grav);
        let n = 20_000;
        let start = std::time::Instant::now();
        let mut acc = 0.0;
        for _ in 0..n {
            let (_, s) = m.wheel_slips(&g, 0.0, &ground, &grav);
            acc += s.slip_angle_rad;
        }
        let per = start.elapsed().as_secs_f64() / n as f64;
        println!(
            "wheel_slips: {:.1} us per six-wheel step ({acc:.3})",
            per * 1e6
        );
        assert!(per < 200e-6, "{per}");
    }
}
