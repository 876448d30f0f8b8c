//! IMU model: white noise, a constant turn-on bias and a bias random walk on each axis of the
//! gyro and the accelerometer.
//!
//! Per sample `k` (period `dt`): `y_k = x_k + b_k + n_k`, `n_k ~ N(0, sigma^2)`,
//! `b_{k+1} = b_k + w_k`, `w_k ~ N(0, sigma_walk^2 dt)`, `b_0 ~ N(0, sigma_bias^2)`.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::Deserialize;

/// IMU noise parameters (1-sigma).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default)]
pub struct ImuParams {
    /// Gyro white noise per sample, rad/s.
    pub gyro_noise_rad_s: f64,
    /// Gyro turn-on bias, rad/s.
    pub gyro_bias_rad_s: f64,
    /// Gyro bias random walk, rad/s per sqrt(s).
    pub gyro_bias_walk_rad_s_sqrt_s: f64,
    /// Accelerometer white noise per sample, m/s^2.
    pub accel_noise_m_s2: f64,
    /// Accelerometer turn-on bias, m/s^2.
    pub accel_bias_m_s2: f64,
    /// Accelerometer bias random walk, m/s^2 per sqrt(s).
    pub accel_bias_walk_m_s2_sqrt_s: f64,
}

impl Default for ImuParams {
    /// A tactical-grade MEMS IMU (simulator assumption): gyro 0.005 deg/s/sqrt(Hz)-class noise
    /// giving 1e-3 rad/s per 200 Hz sample, 1e-4 rad/s bias; accelerometer 5e-3 m/s^2 per
    /// sample, 5e-3 m/s^2 bias.
    fn default() -> Self {
        Self {
            gyro_noise_rad_s: 1e-3,
            gyro_bias_rad_s: 1e-4,
            gyro_bias_walk_rad_s_sqrt_s: 1e-5,
            accel_noise_m_s2: 5e-3,
            accel_bias_m_s2: 5e-3,
            accel_bias_walk_m_s2_sqrt_s: 1e-4,
        }
    }
}

/// The state of a simulated IMU.
#[derive(Debug, Clone)]
pub struct ImuModel {
    params: ImuParams,
    /// Current gyro bias, rad/s.
    pub gyro_bias: [f64; 3],
    /// Current accelerometer bias, m/s^2.
    pub accel_bias: [f64; 3],
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

impl ImuModel {
    /// A new IMU with its turn-on biases drawn from `rng`.
    pub fn new(params: ImuParams, rng: &mut ChaCha8Rng) -> Self {
        let mut gyro_bias = [0.0; 3];
        let mut accel_bias = [0.0; 3];
        for b in &mut gyro_bias {
            *b = params.gyro_bias_rad_s * normal(rng);
        }
        for b in &mut accel_bias {
            *b = params.accel_bias_m_s2 * normal(rng);
        }
        Self {
            params,
            gyro_bias,
            accel_bias,
        }
    }

    /// Measure the true angular rate (rad/s) and specific force (m/s^2), both in `R`, then
    /// advance the biases by `dt_s`.
    pub fn sample(
        &mut self,
        gyro_true: [f64; 3],
        accel_true: [f64; 3],
        dt_s: f64,
        rng: &mut ChaCha8Rng,
    ) -> ([f64; 3], [f64; 3]) {
        let p = &self.params;
        let mut g = [0.0; 3];
        let mut a = [0.0; 3];
        for k in 0..3 {
            g[k] = gyro_true[k] + self.gyro_bias[k] + p.gyro_noise_rad_s * normal(rng);
            a[k] = accel_true[k] + self.accel_bias[k] + p.accel_noise_m_s2 * normal(rng);
        }
        let sq = dt_s.sqrt();
        for k in 0..3 {
            self.gyro_bias[k] += p.gyro_bias_walk_rad_s_sqrt_s * sq * normal(rng);
            self.accel_bias[k] += p.accel_bias_walk_m_s2_sqrt_s * sq * normal(rng);
        }
        (g, a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn mean_std(v: &[f64]) -> (f64, f64) {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64;
        (m, var.sqrt())
    }

    /// SIM-6: white-noise standard deviation, turn-on bias and bias random walk match the
    /// parameters (sample statistics within their expected scatter).
    #[test]
    fn sim_6_imu_noise_statistics() {
        let params = ImuParams {
            gyro_bias_walk_rad_s_sqrt_s: 0.0,
            accel_bias_walk_m_s2_sqrt_s: 0.0,
            ..ImuParams::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut imu = ImuModel::new(params, &mut rng);
        let (bg, ba) = (imu.gyro_bias, imu.accel_bias);
        let n = 40_000;
        let mut gx = Vec::with_capacity(n);
        let mut az = Vec::with_capacity(n);
        for _ in 0..n {
            let (g, a) = imu.sample([0.0; 3], [0.0, 0.0, -3.711], 0.005, &mut rng);
            gx.push(g[0]);
            az.push(a[2]);
        }
        let (m, s) = mean_std(&gx);
        // Standard error of the std estimate ~ s / sqrt(2n) = 0.35 %; allow 2 %.
        assert!((s / params.gyro_noise_rad_s - 1.0).abs() < 0.02, "{s}");
        assert!((m - bg[0]).abs() < 4.0 * params.gyro_noise_rad_s / (n as f64).sqrt());
        let (m, s) = mean_std(&az);
        assert!((s / params.accel_noise_m_s2 - 1.0).abs() < 0.02, "{s}");
        assert!((m - (-3.711 + ba[2])).abs() < 4.0 * params.accel_noise_m_s2 / (n as f64).sqrt());

        // Turn-on bias scatter across many IMUs.
        let biases: Vec<f64> = (0..4000)
            .map(|_| ImuModel::new(params, &mut rng).gyro_bias[1])
            .collect();
        let (_, s) = mean_std(&biases);
        assert!((s / params.gyro_bias_rad_s - 1.0).abs() < 0.05, "{s}");

        // Bias random walk: after T seconds the bias has moved by sigma_walk * sqrt(T).
        let walk = ImuParams::default();
        let (t_s, dt) = (10.0, 0.005);
        let moves: Vec<f64> = (0..1000)
            .map(|_| {
                let mut imu = ImuModel::new(walk, &mut rng);
                let b0 = imu.accel_bias[0];
                for _ in 0..(t_s / dt) as usize {
                    imu.sample([0.0; 3], [0.0; 3], dt, &mut rng);
                }
                imu.accel_bias[0] - b0
            })
            .collect();
        let (_, s) = mean_std(&moves);
        let expected = walk.accel_bias_walk_m_s2_sqrt_s * t_s.sqrt();
        assert!((s / expected - 1.0).abs() < 0.1, "{s} vs {expected}");
    }
}
