//! Truth trajectory generator and noisy, biased IMU for the estimator tests.
//!
//! The rover drives along its body x axis at a constant speed while yaw, pitch and roll follow
//! sinusoids (turns on a rolling slope). Attitude and velocity are analytic; position is
//! integrated with Simpson's rule; angular rate and specific force come from central differences
//! of the analytic attitude and velocity (error O(h^2), h = 1e-4 s, far below the IMU noise).

use crate::estimation::state::{exp_quat, log_quat, rot};
use crate::estimation::{ImuNoise, MARS_GRAVITY_M_S2};
use crate::types::{Mat6, Quat, RelativePose, Vec3};
use nalgebra::UnitQuaternion;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rover_hal::ImuSample;

/// A smooth drive: speed (m/s), and yaw/pitch/roll sinusoids `a0 + a sin(w t + phase)`.
#[derive(Debug, Clone, Copy)]
pub struct Motion {
    pub speed_m_s: f64,
    pub yaw: [f64; 4],
    pub pitch: [f64; 4],
    pub roll: [f64; 4],
}

impl Motion {
    pub fn at_rest() -> Self {
        Self {
            speed_m_s: 0.0,
            yaw: [0.3, 0.0, 0.0, 0.0],
            pitch: [0.0; 4],
            roll: [0.0; 4],
        }
    }

    pub fn drive(speed_m_s: f64) -> Self {
        Self {
            speed_m_s,
            yaw: [0.2, 0.5, 2.0 * core::f64::consts::PI / 60.0, 0.0],
            pitch: [0.05, 0.12, 2.0 * core::f64::consts::PI / 23.0, 0.3],
            roll: [-0.03, 0.1, 2.0 * core::f64::consts::PI / 17.0, 1.1],
        }
    }

    fn angle(a: &[f64; 4], t: f64) -> f64 {
        a[0] + a[1] * libm::sin(a[2] * t + a[3])
    }

    /// True attitude `q_nr` at `t` (s): yaw about z (down), pitch about y, roll about x.
    pub fn q_nr(&self, t: f64) -> Quat {
        UnitQuaternion::from_euler_angles(
            Self::angle(&self.roll, t),
            Self::angle(&self.pitch, t),
            Self::angle(&self.yaw, t),
        )
    }

    /// True velocity in `N` (m/s): along the body x axis.
    pub fn v_n(&self, t: f64) -> Vec3 {
        rot(&self.q_nr(t)) * Vec3::new(self.speed_m_s, 0.0, 0.0)
    }

    /// Angular rate in `R` (rad/s).
    pub fn omega_r(&self, t: f64) -> Vec3 {
        let h = 1.0e-4;
        log_quat(&(self.q_nr(t - h).inverse() * self.q_nr(t + h))) / (2.0 * h)
    }

    /// Specific force in `R` (m/s^2), `C' (a - g)`.
    pub fn f_r(&self, t: f64) -> Vec3 {
        let h = 1.0e-4;
        let a = (self.v_n(t + h) - self.v_n(t - h)) / (2.0 * h);
        rot(&self.q_nr(t)).transpose() * (a - Vec3::new(0.0, 0.0, MARS_GRAVITY_M_S2))
    }
}

/// True pose at a time.
#[derive(Debug, Clone, Copy)]
pub struct TruePose {
    pub t_us: u64,
    pub q_nr: Quat,
    pub v_n: Vec3,
    pub p_n: Vec3,
}

/// Truth integrator and IMU model stepping at a fixed rate.
pub struct Truth {
    pub motion: Motion,
    pub dt_us: u64,
    pub pose: TruePose,
    pub gyro_bias: Vec3,
    pub accel_bias: Vec3,
    pub noise: ImuNoise,
}

pub fn gauss3(rng: &mut ChaCha8Rng) -> Vec3 {
    Vec3::new(
        rng.sample(StandardNormal),
        rng.sample(StandardNormal),
        rng.sample(StandardNormal),
    )
}

impl Truth {
    pub fn new(motion: Motion, dt_us: u64, gyro_bias: Vec3, accel_bias: Vec3) -> Self {
        Self {
            motion,
            dt_us,
            pose: TruePose {
                t_us: 0,
                q_nr: motion.q_nr(0.0),
                v_n: motion.v_n(0.0),
                p_n: Vec3::zeros(),
            },
            gyro_bias,
            accel_bias,
            noise: ImuNoise::default(),
        }
    }

    /// The IMU sample at the current truth time (noise and biases from `rng`).
    pub fn imu(&self, rng: &mut ChaCha8Rng) -> ImuSample {
        let t = self.pose.t_us as f64 * 1e-6;
        let sdt = crate::linalg::sqrt(self.dt_us as f64 * 1e-6);
        let w = self.motion.omega_r(t)
            + self.gyro_bias
            + gauss3(rng) * (self.noise.gyro_rad_s_sqrt_hz / sdt);
        let f = self.motion.f_r(t)
            + self.accel_bias
            + gauss3(rng) * (self.noise.accel_m_s2_sqrt_hz / sdt);
        ImuSample {
            t_us: self.pose.t_us,
            gyro_rad_s: [w.x, w.y, w.z],
            accel_m_s2: [f.x, f.y, f.z],
            valid: true,
        }
    }

    /// Advance the truth by one IMU period (bias random walks included).
    pub fn advance(&mut self, rng: &mut ChaCha8Rng) {
        let t0 = self.pose.t_us as f64 * 1e-6;
        let dt = self.dt_us as f64 * 1e-6;
        let m = &self.motion;
        self.pose.p_n += (m.v_n(t0) + m.v_n(t0 + 0.5 * dt) * 4.0 + m.v_n(t0 + dt)) * (dt / 6.0);
        self.pose.t_us += self.dt_us;
        self.pose.q_nr = m.q_nr(t0 + dt);
        self.pose.v_n = m.v_n(t0 + dt);
        let sdt = crate::linalg::sqrt(dt);
        self.gyro_bias += gauss3(rng) * (self.noise.gyro_bias_rad_s2_sqrt_hz * sdt);
        self.accel_bias += gauss3(rng) * (self.noise.accel_bias_m_s3_sqrt_hz * sdt);
    }
}

/// A relative pose between two true poses with noise `sigma = [rot (rad); trans (m)]` drawn in
/// the `RelativePose` convention (true = exp([n]x) meas, true = meas + n_p), plus `slip_m`
/// (m, in `R0`) added to the measured translation.
pub fn relative_pose(
    a: &TruePose,
    b: &TruePose,
    sigma: &[f64; 6],
    observed: [bool; 6],
    slip_m: Vec3,
    rng: &mut ChaCha8Rng,
) -> RelativePose {
    let rot_true = a.q_nr.inverse() * b.q_nr;
    let trans_true = rot(&a.q_nr).transpose() * (b.p_n - a.p_n);
    let n = [0usize; 6].map(|_| rng.sample::<f64, _>(StandardNormal));
    let n_theta = Vec3::new(n[0] * sigma[0], n[1] * sigma[1], n[2] * sigma[2]);
    let n_p = Vec3::new(n[3] * sigma[3], n[4] * sigma[4], n[5] * sigma[5]);
    let mut covariance = Mat6::zeros();
    for (k, s) in sigma.iter().enumerate() {
        covariance[(k, k)] = s * s;
    }
    let mut trans = trans_true - n_p + slip_m;
    let rot_meas = exp_quat(&(-n_theta)) * rot_true;
    // An unobserved translation component carries garbage, as a real sensor would.
    for k in 0..3 {
        if !observed[3 + k] {
            trans[k] += 0.37;
        }
    }
    RelativePose {
        t0_us: a.t_us,
        t1_us: b.t_us,
        rot_0_1: rot_meas,
        trans_0_1_m: trans,
        covariance,
        observed,
    }
}
