//! Zero-velocity and zero-rate updates while the rover is stopped (bias observability).
//!
//! ZUPT: the pseudo-measurement `v_N = 0` with `H = [0 0 I 0 0]`, residual `-v_hat`,
//! `R = sigma_zupt^2 I` (3 dof). Through the velocity-attitude coupling `-C [f]x` of eq. 26 it
//! makes the tilt and the horizontal gyro biases observable, and keeps velocity bounded.
//! Zero rate: with the rover stopped the gyro measures its bias (`w_m = b_g + n`); the
//! pseudo-measurement is the gyro average over the stop with `H = [0 I 0 0 0]`, residual
//! `w_m - b_hat_g`, `R = sigma_rate^2 I`. It makes the vertical gyro bias observable too.

use super::fusion::Innovation;
use super::state::{I_BG, I_V};
use super::{Ekf, EstError};
use crate::types::{Mat3, Vec3};
use nalgebra::SMatrix;

impl Ekf {
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
