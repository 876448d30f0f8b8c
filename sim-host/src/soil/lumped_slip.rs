//! The lumped slip model (an option, `slip_model = "lumped"`): one slip ratio and one slip
//! angle for the whole vehicle from the slope along and across it, applied to every wheel on
//! the ground by the rolling solve. Its lateral constant `k_lat` was chosen so that 10 deg of
//! sand gives the drift of H05 Fig. 9, and its contact patch is a fixed assumption; the
//! default per-wheel terramechanics model ([`crate::soil::per_wheel_slip`], `slip_model = "terramechanics"`,
//! the rigid-wheel law of [`crate::soil::rigid_wheel`]) derives both from published soil values
//! (see `docs/simulator.md`). This model runs the reference cases SIL-SLIP-1/2.
//!
//! What follows is the model: how much the rover's ground velocity falls short of
//! (longitudinal) and departs sideways from (lateral, downhill) the velocity its wheels
//! command.
//!
//! **Longitudinal.** The soil's net traction coefficient as a function of the slip ratio `s`
//! follows the Janosi-Hanamoto shear law integrated over a contact patch of length `L`
//! (Wong, *Theory of Ground Vehicles*, ch. 2):
//!
//! `mu(s) = mu_max * (1 - K/(s L) * (1 - exp(-s L / K)))`, `mu_max = c A / W + tan(phi)`,
//!
//! with soil cohesion `c`, internal friction angle `phi`, shear deformation modulus `K`, total
//! contact area `A` and weight `W`. Driving demands `mu_d = sin(theta_up) + c_rr` (the weight
//! component along the motion on a slope `theta_up`, plus rolling resistance from sinkage). The
//! slip ratio is the `s` where `mu(s) = mu_d` (bisection); `s = 1` if the soil cannot deliver it
//! (the rover digs in). Downhill (`mu_d < 0`) the wheels skid forward: `s = -s(|mu_d|) / 2`.
//! The ground speed along the wheel heading is `(1 - s) * v_wheel`.
//!
//! **Lateral.** The side force needed to hold the rover against the cross-slope component of
//! gravity, `mu_y = sin(theta_cross)`, is delivered by the wheels only while they crab at a slip
//! angle `alpha` with `mu_y = mu_max (1 - exp(-tan(alpha) / k_lat))`; so the rover drifts
//! downhill at `|v| tan(alpha)` while it drives, and does not drift while it stands still.
//!
//! **Randomness.** Per seed the soil parameters are scaled by `1 + N(0, sigma_param)`, and both
//! slips carry an Ornstein-Uhlenbeck perturbation (standard deviation `noise`, correlation time
//! `noise_tau_s`), drawn from the simulator's slip random stream.

use crate::soil::per_wheel_slip::SlipState;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Deserialize;

/// Soil parameters of the slip model.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct LumpedSoil {
    /// Cohesion `c` times contact area over weight, `c A / W` (dimensionless).
    pub cohesion_term: f64,
    /// Internal friction angle `phi`, degrees.
    pub friction_angle_deg: f64,
    /// Shear deformation modulus over contact-patch length, `K / L` (dimensionless).
    pub shear_modulus_ratio: f64,
    /// Rolling-resistance coefficient `c_rr` (sinkage), dimensionless.
    pub rolling_resistance: f64,
    /// Lateral slip-angle constant `k_lat` (dimensionless).
    pub lateral_constant: f64,
    /// Standard deviation of the Ornstein-Uhlenbeck slip perturbation (slip ratio units).
    pub noise: f64,
    /// Correlation time of the perturbation, s.
    pub noise_tau_s: f64,
    /// Relative per-seed scatter of the soil parameters (1-sigma).
    pub sigma_param: f64,
}

impl LumpedSoil {
    /// Loose dry sand: `c` ~ 1 kPa over ~0.06 m^2 of contact on ~560 N of Mars weight
    /// (Rocky 8 ~150 kg), `phi` = 30 deg, `K` = 2.5 cm over a 10 cm patch, sinkage resistance 0.08
    /// (Wong, Table 2.3 "dry sand"; Bekker); `k_lat` chosen so a 10 deg cross slope gives about
    /// 8 deg of crab (H05 Fig. 9 shows a clear downhill drift over 4.5 m).
    pub fn loose_sand() -> Self {
        Self {
            cohesion_term: 0.1,
            friction_angle_deg: 30.0,
            shear_modulus_ratio: 0.25,
            rolling_resistance: 0.08,
            lateral_constant: 0.55,
            noise: 0.02,
            noise_tau_s: 2.0,
            sigma_param: 0.05,
        }
    }
    /// Firm soil (packed, cohesive: Wong's "sandy loam"): `phi` = 35 deg, `K` = 1 cm over 10 cm.
    pub fn firm_soil() -> Self {
        Self {
            cohesion_term: 0.25,
            friction_angle_deg: 35.0,
            shear_modulus_ratio: 0.1,
            rolling_resistance: 0.03,
            lateral_constant: 0.08,
            noise: 0.005,
            noise_tau_s: 2.0,
            sigma_param: 0.05,
        }
    }
    /// Peak traction coefficient `mu_max = c A / W + tan(phi)`.
    pub fn mu_max(&self) -> f64 {
        self.cohesion_term + self.friction_angle_deg.to_radians().tan()
    }
    /// Janosi-Hanamoto traction coefficient at slip ratio `s` in `(0, 1]`.
    pub fn traction(&self, s: f64) -> f64 {
        if s <= 0.0 {
            return 0.0;
        }
        let x = s / self.shear_modulus_ratio;
        self.mu_max() * (1.0 - (1.0 - (-x).exp()) / x)
    }
    /// Steady longitudinal slip ratio for a traction demand `mu_d`.
    pub fn longitudinal_slip(&self, mu_d: f64) -> f64 {
        let demand = mu_d.abs();
        let s = if self.traction(1.0) <= demand {
            1.0
        } else {
            let (mut lo, mut hi) = (0.0, 1.0);
            for _ in 0..50 {
                let mid = 0.5 * (lo + hi);
                if self.traction(mid) < demand {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            0.5 * (lo + hi)
        };
        if mu_d >= 0.0 {
            s
        } else {
            -0.5 * s
        }
    }
    /// Steady lateral slip angle for a side-force demand `mu_y`, rad (sign of `mu_y`).
    pub fn lateral_slip_angle(&self, mu_y: f64) -> f64 {
        let ratio = (mu_y.abs() / self.mu_max()).min(0.999);
        let tan_alpha = -self.lateral_constant * (1.0 - ratio).ln();
        tan_alpha.atan().copysign(mu_y)
    }
}

/// The slip state of one run.
#[derive(Debug, Clone)]
pub struct LumpedSlip {
    soil: LumpedSoil,
    enabled: bool,
    ou_long: f64,
    ou_lat: f64,
}

impl LumpedSlip {
    /// A slip model for `soil`, with its per-seed parameter scatter drawn from `rng`.
    /// `enabled = false` turns slip off (ground velocity equals the wheel velocity).
    pub fn new(soil: LumpedSoil, enabled: bool, rng: &mut ChaCha8Rng) -> Self {
        let mut scale = |v: f64| {
            let n: f64 = StandardNormal.sample(rng);
            v * (1.0 + soil.sigma_param * n).max(0.5)
        };
        let drawn = LumpedSoil {
            cohesion_term: scale(soil.cohesion_term),
            friction_angle_deg: scale(soil.friction_angle_deg),
            shear_modulus_ratio: scale(soil.shear_modulus_ratio),
            rolling_resistance: scale(soil.rolling_resistance),
            lateral_constant: scale(soil.lateral_constant),
            ..soil
        };
        Self {
            soil: drawn,
            enabled,
            ou_long: 0.0,
            ou_lat: 0.0,
        }
    }

    /// The soil parameters of this run (after the per-seed draw).
    pub fn soil(&self) -> &LumpedSoil {
        &self.soil
    }

    /// Slip for one step of `dt_s`: `slope_along` and `slope_cross` are the terrain slope
    /// angles along the motion (positive uphill) and across the rover (positive: the right side
    /// is downhill), rad.
    pub fn step(
        &mut self,
        slope_along_rad: f64,
        slope_cross_rad: f64,
        dt_s: f64,
        rng: &mut ChaCha8Rng,
    ) -> SlipState {
        let decay = (-dt_s / self.soil.noise_tau_s.max(1e-3)).exp();
        let gain = self.soil.noise * (1.0 - decay * decay).sqrt();
        let (n1, n2): (f64, f64) = (rng.sample(StandardNormal), rng.sample(StandardNormal));
        self.ou_long = decay * self.ou_long + gain * n1;
        self.ou_lat = decay * self.ou_lat + gain * n2;
        if !self.enabled {
            return SlipState::default();
        }
        let mu_d = slope_along_rad.sin() + self.soil.rolling_resistance;
        let s = (self.soil.longitudinal_slip(mu_d) + self.ou_long).clamp(-0.5, 1.0);
        let alpha = self.soil.lateral_slip_angle(slope_cross_rad.sin()) + self.ou_lat;
        SlipState {
            slip_ratio: s,
            slip_angle_rad: alpha,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SIM-5: longitudinal slip grows with uphill slope and lateral slip with cross slope, sand
    /// slips more than firm soil, and flat firm soil slips little.
    #[test]
    fn sim_5_slip_grows_with_slope() {
        let sand = LumpedSoil::loose_sand();
        let firm = LumpedSoil::firm_soil();
        let mut prev_s = -1.0;
        let mut prev_a = -1.0;
        for deg in [0.0f64, 5.0, 10.0, 15.0, 20.0] {
            let th = deg.to_radians();
            let s = sand.longitudinal_slip(th.sin() + sand.rolling_resistance);
            let a = sand.lateral_slip_angle(th.sin());
            assert!(s > prev_s && a >= prev_a, "{deg} deg: s {s} a {a}");
            let sf = firm.longitudinal_slip(th.sin() + firm.rolling_resistance);
            assert!(sf < s);
            assert!(firm.lateral_slip_angle(th.sin()) < a || deg == 0.0);
            prev_s = s;
            prev_a = a;
        }
        let flat_firm = firm.longitudinal_slip(firm.rolling_resistance);
        assert!(flat_firm < 0.02, "{flat_firm}");
        // 10 deg cross slope on sand: crab of several degrees (>= 0.5 m over 4.5 m).
        let a10 = sand.lateral_slip_angle(10f64.to_radians().sin());
        assert!(4.5 * a10.tan() >= 0.5, "{}", a10.to_degrees());
        // Traction law: mu(s) increases and tends to mu_max.
        assert!(sand.traction(0.1) < sand.traction(0.5));
        assert!(sand.traction(1.0) < sand.mu_max());
    }

    /// SIM-5: per-seed scatter and noise are deterministic for a seed and differ across seeds.
    #[test]
    fn sim_5_random_per_seed() {
        use rand::SeedableRng;
        let run = |seed| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut m = LumpedSlip::new(LumpedSoil::loose_sand(), true, &mut rng);
            (0..100)
                .map(|_| m.step(0.1, 0.17, 0.05, &mut rng).slip_ratio)
                .sum::<f64>()
        };
        assert_eq!(run(1), run(1));
        assert_ne!(run(1), run(2));
    }
}
