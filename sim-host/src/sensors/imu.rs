//! IMU model: per-unit scale-factor and axis-misalignment errors, white noise, a constant
//! turn-on bias and a bias random walk on each axis of the gyro and the accelerometer.
//!
//! Per sample `k` (period `dt`): `y_k = M x_k + b_k + n_k`, `n_k ~ N(0, sigma^2)`,
//! `b_{k+1} = b_k + w_k`, `w_k ~ N(0, sigma_walk^2 dt)`, `b_0 ~ N(0, sigma_bias^2)`, with
//! `M = I + diag(s) + A`: `s_i ~ N(0, sigma_scale^2)` the scale-factor error of axis `i` and `A`
//! the small-angle misalignment, its six off-diagonal terms `A_ij ~ N(0, sigma_mis^2)` (axis `i`
//! senses a share `A_ij` of the rate along axis `j`: non-orthogonal and misaligned sensing
//! axes). `M` is drawn once per seed from its own random stream, so that the noise sequences
//! do not depend on it.

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
    /// Gyro scale-factor error of each axis, relative (0.002 = 0.2 %).
    pub gyro_scale_rel: f64,
    /// Gyro axis misalignment, each off-diagonal term, degrees.
    pub gyro_misalignment_deg: f64,
    /// Gyro measurement range, rad/s: readings saturate (clip) there.
    pub gyro_range_rad_s: f64,
    /// Accelerometer measurement range, m/s^2: readings saturate (clip) there.
    pub accel_range_m_s2: f64,
    /// Accelerometer scale-factor error of each axis, relative.
    pub accel_scale_rel: f64,
    /// Accelerometer axis misalignment, each off-diagonal term, degrees.
    pub accel_misalignment_deg: f64,
}

impl Default for ImuParams {
    /// A tactical-grade MEMS IMU (simulator assumption): gyro 0.005 deg/s/sqrt(Hz)-class noise
    /// giving 1e-3 rad/s per 200 Hz sample, 1e-4 rad/s bias; accelerometer 5e-3 m/s^2 per
    /// sample, 5e-3 m/s^2 bias.
    ///
    /// Scale factor 0.2 % (1-sigma) for the gyro and the accelerometer: a simulator assumption
    /// inside the 0.1-0.3 % class of factory-calibrated tactical MEMS units. Misalignment
    /// 0.05 deg (1-sigma) per term: the ADIS16488A data sheet (Analog Devices) states a
    /// +-0.05 deg orthogonal alignment error after factory calibration (the ADIS16495 and
    /// ADIS16467 the same +-0.05 deg axis to axis); taking the +- figure as 1-sigma is
    /// conservative.
    fn default() -> Self {
        Self {
            gyro_noise_rad_s: 1e-3,
            gyro_bias_rad_s: 1e-4,
            gyro_bias_walk_rad_s_sqrt_s: 1e-5,
            accel_noise_m_s2: 5e-3,
            accel_bias_m_s2: 5e-3,
            accel_bias_walk_m_s2_sqrt_s: 1e-4,
            gyro_scale_rel: 0.002,
            gyro_misalignment_deg: 0.05,
            accel_scale_rel: 0.002,
            accel_misalignment_deg: 0.05,
            // ADIS16488A data sheet (Analog Devices): +-450 deg/s and +-18 g dynamic ranges.
            gyro_range_rad_s: 450.0_f64.to_radians(),
            accel_range_m_s2: 18.0 * 9.806_65,
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
    /// Gyro scale and misalignment `M_g` (row-major; `y = M_g w + ...`).
    pub gyro_matrix: [[f64; 3]; 3],
    /// Accelerometer scale and misalignment `M_a` (row-major).
    pub accel_matrix: [[f64; 3]; 3],
}

/// `I + diag(s) + A` with `s ~ N(0, scale^2)` and the off-diagonal `A ~ N(0, mis^2)`; always
/// nine draws, diagonal first, then the off-diagonal terms row by row.
fn sensing_matrix(scale_rel: f64, misalignment_deg: f64, rng: &mut ChaCha8Rng) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0 + scale_rel * normal(rng);
    }
    let mis = misalignment_deg.to_radians();
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            if i != j {
                *v = mis * normal(rng);
            }
        }
    }
    m
}

fn apply(m: &[[f64; 3]; 3], x: &[f64; 3]) -> [f64; 3] {
    m.map(|row| row[0] * x[0] + row[1] * x[1] + row[2] * x[2])
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

impl ImuModel {
    /// A new IMU with its turn-on biases drawn from `rng` and its scale factors and
    /// misalignments from `calib_rng` (18 draws).
    pub fn new(params: ImuParams, rng: &mut ChaCha8Rng, calib_rng: &mut ChaCha8Rng) -> Self {
        let mut gyro_bias = [0.0; 3];
        let mut accel_bias = [0.0; 3];
        for b in &mut gyro_bias {
            *b = params.gyro_bias_rad_s * normal(rng);
        }
        for b in &mut accel_bias {
            *b = params.accel_bias_m_s2 * normal(rng);
        }
        let gyro_matrix = sensing_matrix(
            params.gyro_scale_rel,
            params.gyro_misalignment_deg,
            calib_rng,
        );
        let accel_matrix = sensing_matrix(
            params.accel_scale_rel,
            params.accel_misalignment_deg,
            calib_rng,
        );
        Self {
            params,
            gyro_bias,
            accel_bias,
            gyro_matrix,
            accel_matrix,
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
        let gyro_sensed = apply(&self.gyro_matrix, &gyro_true);
        let accel_sensed = apply(&self.accel_matrix, &accel_true);
        let mut g = [0.0; 3];
        let mut a = [0.0; 3];
        for k in 0..3 {
            g[k] = gyro_sensed[k] + self.gyro_bias[k] + p.gyro_noise_rad_s * normal(rng);
            a[k] = accel_sensed[k] + self.accel_bias[k] + p.accel_noise_m_s2 * normal(rng);
            // A real sensor saturates at its range: it does not report values beyond it.
            g[k] = g[k].clamp(-p.gyro_range_rad_s, p.gyro_range_rad_s);
            a[k] = a[k].clamp(-p.accel_range_m_s2, p.accel_range_m_s2);
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

    /// The default IMU without noise, biases or bias walks (scale factors and misalignments
    /// kept).
    fn noiseless() -> ImuParams {
        ImuParams {
            gyro_noise_rad_s: 0.0,
            gyro_bias_rad_s: 0.0,
            gyro_bias_walk_rad_s_sqrt_s: 0.0,
            accel_noise_m_s2: 0.0,
            accel_bias_m_s2: 0.0,
            accel_bias_walk_m_s2_sqrt_s: 0.0,
            ..ImuParams::default()
        }
    }

    /// SIM-6: readings saturate at the ranges (the ADIS16488A's +-18 g and +-450 deg/s) and
    /// are unchanged inside them.
    #[test]
    fn sim_6_imu_saturates_at_its_range() {
        let params = ImuParams {
            gyro_scale_rel: 0.0,
            gyro_misalignment_deg: 0.0,
            accel_scale_rel: 0.0,
            accel_misalignment_deg: 0.0,
            ..noiseless()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut calib = ChaCha8Rng::seed_from_u64(4);
        let mut imu = ImuModel::new(params, &mut rng, &mut calib);
        let (g, a) = imu.sample([20.0, -0.5, 0.0], [-253.9, 94.8, -3.711], 0.005, &mut rng);
        assert_eq!(g, [params.gyro_range_rad_s, -0.5, 0.0]);
        assert_eq!(a, [-params.accel_range_m_s2, 94.8, -3.711]);
        assert!((params.accel_range_m_s2 - 176.5197).abs() < 1e-3);
    }

    /// SIM-6: white-noise standard deviation, turn-on bias and bias random walk match the
    /// parameters (sample statistics within their expected scatter).
    #[test]
    fn sim_6_imu_noise_statistics() {
        let params = ImuParams {
            gyro_bias_walk_rad_s_sqrt_s: 0.0,
            accel_bias_walk_m_s2_sqrt_s: 0.0,
            accel_scale_rel: 0.0,
            accel_misalignment_deg: 0.0,
            ..ImuParams::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut calib = ChaCha8Rng::seed_from_u64(10);
        let mut imu = ImuModel::new(params, &mut rng, &mut calib);
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
            .map(|_| ImuModel::new(params, &mut rng, &mut calib).gyro_bias[1])
            .collect();
        let (_, s) = mean_std(&biases);
        assert!((s / params.gyro_bias_rad_s - 1.0).abs() < 0.05, "{s}");

        // Bias random walk: after T seconds the bias has moved by sigma_walk * sqrt(T).
        let walk = ImuParams::default();
        let (t_s, dt) = (10.0, 0.005);
        let moves: Vec<f64> = (0..1000)
            .map(|_| {
                let mut imu = ImuModel::new(walk, &mut rng, &mut calib);
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

    /// SIM-6: the per-unit scale factors and misalignments are applied to the true rate and
    /// specific force (a noiseless IMU turned about each axis reads the column of its sensing
    /// matrix), have the stated scatter across units, and come from the calibration stream
    /// only (the noise stream's draws are unchanged).
    #[test]
    fn sim_6_imu_scale_and_misalignment() {
        let params = noiseless();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut calib = ChaCha8Rng::seed_from_u64(4);
        let mut imu = ImuModel::new(params, &mut rng, &mut calib);
        for k in 0..3 {
            let mut x = [0.0; 3];
            x[k] = 0.5;
            let (g, a) = imu.sample(x, x, 0.005, &mut rng);
            for i in 0..3 {
                assert!((g[i] - 0.5 * imu.gyro_matrix[i][k]).abs() < 1e-15);
                assert!((a[i] - 0.5 * imu.accel_matrix[i][k]).abs() < 1e-15);
            }
            // The error is there: not the identity.
            assert!((g[k] - 0.5).abs() > 0.0);
        }
        // Scatter across units: diagonal vs scale, off-diagonal vs misalignment.
        let n = 4000;
        let (mut s2, mut m2) = (0.0, 0.0);
        for _ in 0..n {
            let u = ImuModel::new(params, &mut rng, &mut calib);
            s2 += (u.accel_matrix[1][1] - 1.0).powi(2);
            m2 += u.gyro_matrix[0][2].powi(2);
        }
        let rms = |v: f64| (v / n as f64).sqrt();
        assert!((rms(s2) / params.accel_scale_rel - 1.0).abs() < 0.05);
        let mis = params.gyro_misalignment_deg.to_radians();
        assert!((rms(m2) / mis - 1.0).abs() < 0.05);
        // The noise stream is independent of the calibration: same biases and noise whatever
        // the calibration stream.
        let noisy = ImuParams::default();
        let mut r1 = ChaCha8Rng::seed_from_u64(5);
        let mut r2 = ChaCha8Rng::seed_from_u64(5);
        let a = ImuModel::new(noisy, &mut r1, &mut ChaCha8Rng::seed_from_u64(6));
        let b = ImuModel::new(noisy, &mut r2, &mut ChaCha8Rng::seed_from_u64(7));
        assert_eq!(a.gyro_bias, b.gyro_bias);
        assert_ne!(a.gyro_matrix, b.gyro_matrix);
    }
}
