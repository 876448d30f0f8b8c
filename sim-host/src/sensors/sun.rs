//! Sun sensor (RB sec. 3): the unit vector towards the sun in the rover frame `R`, with
//! angular noise, valid when the sun is inside the sensor's upward-looking cone.

use nalgebra::{Rotation3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::Deserialize;

/// Sun sensor and sun parameters.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default)]
pub struct SunParams {
    /// Sun azimuth, degrees clockwise from north.
    pub azimuth_deg: f64,
    /// Sun elevation above the horizon, degrees.
    pub elevation_deg: f64,
    /// Angular noise on each of the two axes across the line of sight, rad (1-sigma).
    pub noise_rad: f64,
    /// Half-angle of the sensor's field of view around `-z_R` (up), degrees.
    pub fov_half_deg: f64,
}

impl Default for SunParams {
    /// Sun 40 deg up in the south-east; 0.01 rad noise (a coarse digital sun sensor; RB used
    /// 0.314 rad for its simulation); 60 deg half-angle cone.
    fn default() -> Self {
        Self {
            azimuth_deg: 135.0,
            elevation_deg: 40.0,
            noise_rad: 0.01,
            fov_half_deg: 60.0,
        }
    }
}

impl SunParams {
    /// Unit vector towards the sun in `W` (x north, y east, z down).
    pub fn sun_w(&self) -> Vector3<f64> {
        let (sa, ca) = self.azimuth_deg.to_radians().sin_cos();
        let (se, ce) = self.elevation_deg.to_radians().sin_cos();
        Vector3::new(ce * ca, ce * sa, -se)
    }

    /// Reading for a rover whose attitude is `rot_w_from_r`: `(vector in R, in view)`.
    pub fn measure(&self, rot_w_from_r: &Rotation3<f64>, rng: &mut ChaCha8Rng) -> ([f64; 3], bool) {
        let s = rot_w_from_r.inverse() * self.sun_w();
        // Two axes across the line of sight.
        let helper = if s.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = s.cross(&helper).normalize();
        let e2 = s.cross(&e1);
        let (n1, n2): (f64, f64) = (rng.sample(StandardNormal), rng.sample(StandardNormal));
        let m = (s + e1 * (self.noise_rad * n1) + e2 * (self.noise_rad * n2)).normalize();
        let in_view = -s.z >= self.fov_half_deg.to_radians().cos();
        ([m.x, m.y, m.z], in_view)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// SIM-8: level rover facing north sees the sun at its azimuth and elevation, with the
    /// stated angular noise; a sun behind the sensor cone is reported out of view.
    #[test]
    fn sim_8_sun_direction_noise_and_view() {
        let p = SunParams::default();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let level = Rotation3::identity();
        let n = 20_000;
        let mut sum2 = 0.0;
        for _ in 0..n {
            let (v, in_view) = p.measure(&level, &mut rng);
            assert!(in_view);
            let v = Vector3::from(v);
            sum2 += v.angle(&p.sun_w()).powi(2);
        }
        // The angle is Rayleigh: E[angle^2] = 2 sigma^2.
        let rms = (sum2 / n as f64 / 2.0).sqrt();
        assert!((rms / p.noise_rad - 1.0).abs() < 0.03, "{rms}");
        let low = SunParams {
            elevation_deg: 10.0,
            ..p
        };
        assert!(!low.measure(&level, &mut rng).1);
    }
}
