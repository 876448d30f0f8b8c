//! Joint encoders: drive and steering encoders quantised to their counts per revolution with
//! additive noise, rocker and bogie potentiometers quantised to their ADC step.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::Deserialize;
use std::f64::consts::TAU;

/// Encoder parameters.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default)]
pub struct EncoderParams {
    /// Drive encoder counts per wheel revolution (after the gearbox).
    pub drive_counts_per_rev: u32,
    /// Steering encoder counts per revolution.
    pub steer_counts_per_rev: u32,
    /// Rocker/bogie potentiometer step, rad.
    pub suspension_step_rad: f64,
    /// Additive noise on the steering and suspension angles, rad (1-sigma).
    pub angle_noise_rad: f64,
    /// Additive noise on the drive rates, rad/s (1-sigma).
    pub rate_noise_rad_s: f64,
}

impl Default for EncoderParams {
    /// Simulator assumptions for a Rocky 8 class rover: 4096 counts per wheel turn, 16384 per
    /// steering turn, 12-bit potentiometers over 360 deg, 1 mrad and 5 mrad/s noise.
    fn default() -> Self {
        Self {
            drive_counts_per_rev: 4096,
            steer_counts_per_rev: 16384,
            suspension_step_rad: TAU / 4096.0,
            angle_noise_rad: 1e-3,
            rate_noise_rad_s: 5e-3,
        }
    }
}

/// Quantise `angle` to `counts_per_rev` steps (truncation towards minus infinity, as a counter).
pub fn quantise(angle_rad: f64, counts_per_rev: u32) -> f64 {
    let step = TAU / f64::from(counts_per_rev.max(1));
    (angle_rad / step).floor() * step
}

/// Round `angle` to the nearest multiple of `step`.
fn round_to(angle_rad: f64, step_rad: f64) -> f64 {
    if step_rad > 0.0 {
        (angle_rad / step_rad).round() * step_rad
    } else {
        angle_rad
    }
}

impl EncoderParams {
    /// Drive angle reading, rad.
    pub fn drive_angle(&self, true_rad: f64) -> f64 {
        quantise(true_rad, self.drive_counts_per_rev)
    }
    /// Drive rate reading, rad/s.
    pub fn drive_rate(&self, true_rad_s: f64, rng: &mut ChaCha8Rng) -> f64 {
        let n: f64 = rng.sample(StandardNormal);
        true_rad_s + self.rate_noise_rad_s * n
    }
    /// Steering angle reading, rad.
    pub fn steer_angle(&self, true_rad: f64, rng: &mut ChaCha8Rng) -> f64 {
        let n: f64 = rng.sample(StandardNormal);
        round_to(
            true_rad + self.angle_noise_rad * n,
            TAU / f64::from(self.steer_counts_per_rev.max(1)),
        )
    }
    /// Rocker or bogie reading, rad.
    pub fn suspension_angle(&self, true_rad: f64, rng: &mut ChaCha8Rng) -> f64 {
        let n: f64 = rng.sample(StandardNormal);
        round_to(
            true_rad + self.angle_noise_rad * n,
            self.suspension_step_rad,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// SIM-7: drive angles are quantised to the counts per revolution; steering noise has the
    /// stated standard deviation.
    #[test]
    fn sim_7_encoder_quantisation_and_noise() {
        let p = EncoderParams::default();
        let step = TAU / 4096.0;
        for k in 0..1000 {
            let a = k as f64 * 0.0123;
            let q = p.drive_angle(a);
            assert!(a - q >= 0.0 && a - q < step);
            assert!(((q / step).round() * step - q).abs() < 1e-12);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let n = 20_000;
        let v: Vec<f64> = (0..n).map(|_| p.steer_angle(0.3, &mut rng) - 0.3).collect();
        let m = v.iter().sum::<f64>() / n as f64;
        let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n as f64).sqrt();
        // Noise 1 mrad plus quantisation (step 0.38 mrad, variance step^2/12).
        let q = TAU / 16384.0;
        let expected = (1e-6 + q * q / 12.0).sqrt();
        assert!((s / expected - 1.0).abs() < 0.03, "{s} {expected}");
        assert!(m.abs() < 5e-5);
    }
}
