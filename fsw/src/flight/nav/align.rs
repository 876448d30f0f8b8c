//! Alignment at rest: tilt from the averaged specific force, gyro bias from the averaged rate
//! (eq. 26 with v = 0), heading from the sun sensor (RB sec. 5.1: the sun's direction in the
//! levelled rover frame against its ephemeris direction in `N`), and the start of the EKF with
//! the covariance of those estimates.
//!
//! The alignment ends when [`NavConfig::align_samples`] IMU samples are averaged and at least
//! one sun reading was taken. Without a sun reading for [`NavConfig::align_sun_wait_samples`]
//! more samples (sun out of view, sensor failed, no ephemeris) the heading of the plan
//! ([`NavConfig::initial_yaw_rad`], 1-sigma [`NavConfig::initial_yaw_sigma_rad`]) is used and
//! [`NavCounters::heading_from_plan`] counts it.

use super::*;

/// Sums of the stationary IMU samples during alignment.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Alignment {
    count: u32,
    gyro: [f64; 3],
    accel: [f64; 3],
    /// Sums of squares of the samples (dispersion test).
    gyro_sq: [f64; 3],
    accel_sq: [f64; 3],
    /// Sum of the unit sun vectors read in `R` during the alignment.
    sun: [f64; 3],
    /// Sun readings summed.
    sun_count: u32,
    /// Time of the last sun reading summed, us (the ephemeris is evaluated there).
    sun_t_us: u64,
}

impl Alignment {
    /// No samples yet (as [`Default`], usable in a `const`).
    pub(super) const EMPTY: Self = Self {
        count: 0,
        gyro: [0.0; 3],
        accel: [0.0; 3],
        gyro_sq: [0.0; 3],
        accel_sq: [0.0; 3],
        sun: [0.0; 3],
        sun_count: 0,
        sun_t_us: 0,
    };
}

impl Alignment {
    /// Adds one sun reading in `R` (unit vector, finite; others are ignored).
    pub(super) fn add_sun(&mut self, reading: &SunReading) {
        let s = reading.sun_dir_rover;
        let norm = crate::linalg::sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
        let unit = libm::fabs(norm - 1.0) < 0.01;
        if !reading.sun_in_view || !unit {
            return;
        }
        for (acc, v) in self.sun.iter_mut().zip(s.iter()) {
            *acc += v;
        }
        self.sun_count = self.sun_count.saturating_add(1);
        self.sun_t_us = reading.t_us;
    }
}

/// Heading (rad) and its 1-sigma (rad) from the averaged sun vector `s_r` (`R`), the tilt
/// `(roll, pitch)` with 1-sigma `tilt_sigma` (rad) and the ephemeris direction `s_n`: with
/// `v = R_y(pitch) R_x(roll) s_R` the sun in the levelled frame, `yaw = az(s_N) - az(v)`,
/// `az(u) = atan2(u_y, u_x)`; variance `(sigma_sun^2 / n) / cos^2(el) + sigma_tilt^2 tan^2(el)`
/// for a sun at elevation `el`. `None` when the sun is within 5 deg of the zenith (no azimuth).
fn sun_heading(
    s_r: Vec3,
    roll: f64,
    pitch: f64,
    tilt_sigma: f64,
    s_n: Vec3,
    sun_sigma_rad: f64,
    n: u32,
) -> Option<(f64, f64)> {
    let v = Quat::from_euler_angles(roll, pitch, 0.0) * s_r.normalize();
    let horizontal = crate::linalg::sqrt(v.x * v.x + v.y * v.y);
    let horizontal_n = crate::linalg::sqrt(s_n.x * s_n.x + s_n.y * s_n.y);
    let min = libm::sin(5.0_f64.to_radians());
    if !(horizontal > min && horizontal_n > min) {
        return None;
    }
    let yaw = crate::guidance::wrap_pi(libm::atan2(s_n.y, s_n.x) - libm::atan2(v.y, v.x));
    let tan_el = libm::fabs(v.z) / horizontal;
    let var = sun_sigma_rad * sun_sigma_rad / f64::from(n.max(1)) / (horizontal * horizontal)
        + tilt_sigma * tilt_sigma * tan_el * tan_el;
    let sigma = crate::linalg::sqrt(var).max(1.0e-3);
    (yaw.is_finite() && sigma.is_finite()).then_some((yaw, sigma))
}

impl Navigator {
    pub(super) fn accumulate_alignment(&mut self, s: &ImuSample) {
        let a = &mut self.align;
        a.count = a.count.saturating_add(1);
        for k in 0..3 {
            a.gyro[k] += s.gyro_rad_s[k];
            a.accel[k] += s.accel_m_s2[k];
            a.gyro_sq[k] += s.gyro_rad_s[k] * s.gyro_rad_s[k];
            a.accel_sq[k] += s.accel_m_s2[k] * s.accel_m_s2[k];
        }
        let sun_wait_over = a.count
            >= self
                .config
                .align_samples
                .saturating_add(self.config.align_sun_wait_samples);
        if a.count < self.config.align_samples || (a.sun_count == 0 && !sun_wait_over) {
            return;
        }
        let n = f64::from(a.count);
        // Dispersion test (issue 20): a rover that moved, a shock or a spike within the sensor's
        // range would be averaged into the attitude and the gyro bias; restart instead.
        let std = |sum: &[f64; 3], sq: &[f64; 3]| {
            (0..3).fold(0.0_f64, |m, k| {
                let mean = sum[k] / n;
                m.max(crate::linalg::sqrt((sq[k] / n - mean * mean).max(0.0)))
            })
        };
        let (gyro_std, accel_std) = (std(&a.gyro, &a.gyro_sq), std(&a.accel, &a.accel_sq));
        let c = &self.config;
        let steady =
            gyro_std <= c.align_max_gyro_std_rad_s && accel_std <= c.align_max_accel_std_m_s2;
        if !steady {
            self.align = Alignment::default();
            self.counters.align_restarts = self.counters.align_restarts.saturating_add(1);
            return;
        }
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
        let c = &self.config;
        let tilt_sigma = c.accel_bias_sigma_m_s2 / g;
        let sun = match (a.sun_count, c.ekf.sun.and_then(|e| e.sun_dir_n(a.sun_t_us))) {
            (k, Some(s_n)) if k > 0 => sun_heading(
                Vec3::new(a.sun[0], a.sun[1], a.sun[2]),
                roll,
                pitch,
                tilt_sigma,
                s_n,
                c.ekf.sun_sigma_rad,
                k,
            ),
            _ => None,
        };
        let (yaw, yaw_sigma) = match sun {
            Some(h) => {
                self.counters.heading_from_sun = self.counters.heading_from_sun.saturating_add(1);
                h
            }
            None if sun_wait_over => {
                self.counters.heading_from_plan = self.counters.heading_from_plan.saturating_add(1);
                (c.initial_yaw_rad, c.initial_yaw_sigma_rad)
            }
            // A sun reading without an azimuth (zenith) or ephemeris: keep waiting for the
            // timeout.
            None => return,
        };
        let q = Quat::from_euler_angles(roll, pitch, yaw);
        let x0 = NominalState {
            t_us: s.t_us,
            q_nr: q,
            b_g: Vec3::new(a.gyro[0] / n, a.gyro[1] / n, a.gyro[2] / n),
            v_n: Vec3::zeros(),
            b_a: Vec3::zeros(),
            p_n: Vec3::from(self.config.initial_position_n_m),
        };
        let gyro_avg_sigma =
            c.ekf.imu_noise.gyro_rad_s_sqrt_hz * crate::linalg::sqrt(200.0 / n) + 1.0e-6;
        let mut p0 = CoreCov::zeros();
        let diag = [
            tilt_sigma,
            tilt_sigma,
            yaw_sigma,
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
                // The rover was at rest during the alignment: its velocity is anchored as after
                // a zero-velocity update (the stop-and-go drive without VO starts anchored).
                self.cycles_since_zupt = 0;
            }
            Err(e) => {
                self.align = Alignment::default();
                self.ekf_error(e);
            }
        }
    }
}
