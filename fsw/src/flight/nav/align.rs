//! Alignment at rest: tilt from the averaged specific force, gyro bias from the averaged rate
//! (eq. 26 with v = 0), and the start of the EKF.

use super::*;

/// Sums of the stationary IMU samples during alignment.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Alignment {
    count: u32,
    gyro: [f64; 3],
    accel: [f64; 3],
}

impl Navigator {
    pub(super) fn accumulate_alignment(&mut self, s: &ImuSample) {
        let a = &mut self.align;
        a.count = a.count.saturating_add(1);
        for k in 0..3 {
            a.gyro[k] += s.gyro_rad_s[k];
            a.accel[k] += s.accel_m_s2[k];
        }
        if a.count < self.config.align_samples {
            return;
        }
        let n = f64::from(a.count);
        let f = Vec3::new(a.accel[0] / n, a.accel[1] / n, a.accel[2] / n);
        let g = f.norm();
        if !(g.is_finite() && g > 0.1) {
            // No usable gravity reference: start again.
            self.align = Alignment::default();
            return;
        }
        // At rest f = -C' g_N: the rover-frame down axis is -f / |f| (eq. 26 with v = 0).
        let pitch = libm::asin((f.x / g).clamp(-1.0, 1.0));
        let roll = libm::atan2(-f.y, -f.z);
        let q = Quat::from_euler_angles(roll, pitch, self.config.initial_yaw_rad);
        let x0 = NominalState {
            t_us: s.t_us,
            q_nr: q,
            b_g: Vec3::new(a.gyro[0] / n, a.gyro[1] / n, a.gyro[2] / n),
            v_n: Vec3::zeros(),
            b_a: Vec3::zeros(),
            p_n: Vec3::from(self.config.initial_position_n_m),
        };
        let c = &self.config;
        let tilt_sigma = c.accel_bias_sigma_m_s2 / g;
        let gyro_avg_sigma = c.ekf.imu_noise.gyro_rad_s_sqrt_hz * libm::sqrt(200.0 / n) + 1.0e-6;
        let mut p0 = CoreCov::zeros();
        let diag = [
            tilt_sigma,
            tilt_sigma,
            c.initial_yaw_sigma_rad,
            gyro_avg_sigma,
            gyro_avg_sigma,
            gyro_avg_sigma,
            c.ekf.zupt_sigma_m_s,
            c.ekf.zupt_sigma_m_s,
            c.ekf.zupt_sigma_m_s,
            c.accel_bias_sigma_m_s2,
            c.accel_bias_sigma_m_s2,
            c.accel_bias_sigma_m_s2,
            c.initial_position_sigma_m,
            c.initial_position_sigma_m,
            c.initial_position_sigma_m,
        ];
        for (i, s) in diag.iter().enumerate() {
            p0[(i, i)] = s * s;
        }
        match self.ekf.reset(x0, &p0) {
            Ok(()) => {
                let pose = PoseEstimate {
                    p_n: x0.p_n,
                    q_nr: x0.q_nr,
                };
                self.traj.aligned(pose, x0.b_g, s.t_us);
                self.ekf_running = true;
                self.mode = NavMode::Driving;
            }
            Err(e) => {
                self.align = Alignment::default();
                self.ekf_error(e);
            }
        }
    }
}
