//! Zero-velocity and zero-rate updates while the rover is stopped (bias observability).
//!
//! ZUPT: the pseudo-measurement `v_N = 0` with `H = [0 0 I 0 0]`, residual `-v_hat`,
//! `R = sigma_zupt^2 I` (3 dof). Through the velocity-attitude coupling `-C [f]x` of eq. 26 it
//! makes the tilt and the horizontal gyro biases observable, and keeps velocity bounded.
//! Zero rate: with the rover stopped the gyro measures its bias (`w_m = b_g + n`); the
//! pseudo-measurement is the gyro average over the stop with `H = [0 I 0 0 0]`, residual
//! `w_m - b_hat_g`, `R = sigma_rate^2 I`. It makes the vertical gyro bias observable too.

use super::fusion::Innovation;
use super::state::{I_BA, I_BG, I_THETA, I_V};
use super::{Ekf, EstError};
use crate::types::{Mat3, Vec3};
use nalgebra::SMatrix;

impl Ekf {
    /// Covariance inflation after the filter stopped accepting its measurements (a streak of
    /// gate rejections, `Navigator`'s recovery): adds `velocity_sigma_m_s^2` to the velocity
    /// variances and `accel_bias_sigma_m_s2^2` to the accelerometer-bias variances, so that
    /// the next measurement can pull the filter back (the state itself is unchanged). Both
    /// sigmas must be finite and non-negative.
    pub fn inflate_velocity(
        &mut self,
        velocity_sigma_m_s: f64,
        accel_bias_sigma_m_s2: f64,
    ) -> Result<(), EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        let (sv, sb) = (velocity_sigma_m_s, accel_bias_sigma_m_s2);
        if !(sv.is_finite() && sb.is_finite() && sv >= 0.0 && sb >= 0.0) {
            return Err(EstError::NonFiniteInput);
        }
        self.touch();
        for k in 0..3 {
            self.p[(I_V + k, I_V + k)] += sv * sv;
            self.p[(I_BA + k, I_BA + k)] += sb * sb;
        }
        self.check_health()
    }

    /// Heading-covariance inflation after the sun sensor was refused several times in a row
    /// (`Navigator`'s sun streak): adds `sigma_rad^2` to the variance of the rotation about
    /// `N`'s vertical (`P_tt += sigma^2 e e'`, `e = C' z_N` in the rover frame), so the next sun
    /// reading can correct a heading that drifted beyond its covariance. `sigma_rad` must be
    /// finite and non-negative.
    pub fn inflate_heading(&mut self, sigma_rad: f64) -> Result<(), EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        if !(sigma_rad.is_finite() && sigma_rad >= 0.0) {
            return Err(EstError::NonFiniteInput);
        }
        self.touch();
        let e = super::state::rot(&self.x.q_nr).transpose() * Vec3::z();
        let add = e * e.transpose() * (sigma_rad * sigma_rad);
        for r in 0..3 {
            for c in 0..3 {
                self.p[(I_THETA + r, I_THETA + c)] += add[(r, c)];
            }
        }
        self.check_health()
    }

    /// Horizontal position-covariance growth for travel nobody verified (odometry
    /// fused without VO while the gate says it slips): the north and east 1-sigma each grow by
    /// `delta_m` (`P += 2 sigma delta + delta^2` on both diagonals), a systematic error that
    /// does not average out like white noise. `delta_m` must be finite and non-negative.
    pub fn inflate_position(&mut self, delta_m: f64) -> Result<(), EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        if !(delta_m.is_finite() && delta_m >= 0.0) {
            return Err(EstError::NonFiniteInput);
        }
        self.touch();
        for k in 0..2 {
            let i = super::state::I_P + k;
            let sigma = crate::linalg::sqrt(self.p[(i, i)].max(0.0));
            self.p[(i, i)] += 2.0 * sigma * delta_m + delta_m * delta_m;
        }
        self.check_health()
    }

    /// ZUPT at the current state; `t_us` is the time the rover was known to be stopped (within
    /// [`super::EkfConfig::max_measurement_skew_us`] of the state time).
    pub fn update_zero_velocity(&mut self, t_us: u64) -> Result<(), EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        self.check_skew(t_us)?;
        let sigma2 = self.config.zupt_sigma_m_s * self.config.zupt_sigma_m_s;
        let inn = Innovation::new(
            &self.p,
            [I_V, I_V + 1, I_V + 2],
            SMatrix::<f64, 3, 3>::identity(),
            -self.x.v_n,
            &(Mat3::identity() * sigma2),
        );
        self.fuse(&inn)
    }

    /// Zero-rate update at the current state with the gyro average `gyro_mean_rad_s` (rad/s,
    /// rover frame) over a stop ending at `t_us`.
    pub fn update_zero_rate(&mut self, t_us: u64, gyro_mean_rad_s: &Vec3) -> Result<(), EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        if !gyro_mean_rad_s.iter().all(|v| v.is_finite()) {
            return Err(EstError::NonFiniteInput);
        }
        self.check_skew(t_us)?;
        let sigma2 = self.config.zero_rate_sigma_rad_s * self.config.zero_rate_sigma_rad_s;
        let inn = Innovation::new(
            &self.p,
            [I_BG, I_BG + 1, I_BG + 2],
            SMatrix::<f64, 3, 3>::identity(),
            gyro_mean_rad_s - self.x.b_g,
            &(Mat3::identity() * sigma2),
        );
        self.fuse(&inn)
    }
}
