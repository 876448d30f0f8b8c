//! Sun-sensor absolute attitude update, processed sequentially (RB sec. 5, eq. 16-21).
//!
//! The sensor gives the unit vector towards the sun in the rover frame, `s_R`; the filter knows
//! the sun's direction in `N`, `s_N` (ephemeris, [`super::EkfConfig::sun`], at the reading's time). With the
//! rover-frame attitude error, `s_R = C' s_N = exp(-[dtheta]x) C_hat' s_N ~ s_hat + [s_hat]x
//! dtheta`. Only the two directions perpendicular to `s_hat` carry information (a rotation about
//! the sun line is unobservable), so the measurement is the projection of `s_R` on a tangent
//! basis `e_1, e_2` of `s_hat`: `z_i = e_i' s_R`, `z_hat_i = 0`, `H_i = e_i' [s_hat]x` on
//! `dtheta`, `R_i = sigma_sun^2`. Unless the sun is at the zenith this includes the heading.
//! As in RB sec. 5.1 the two components are processed one after the other as scalar updates
//! (eq. 17: scalar `S`, eq. 19: `W = P H' / S`), equivalent to the joint update because their
//! noises are independent. The pair is first gated with 2 degrees of freedom (eq. 46).

use super::fusion::Innovation;
use super::gate::{chi2_95, CHI2_95};
use super::state::{rot, skew, I_THETA};
use super::{Ekf, EstError};
use crate::types::Vec3;
use nalgebra::{SMatrix, SVector};
use rover_hal::SunReading;

/// Outcome of a sun-sensor update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunUpdate {
    /// Mahalanobis squared distance of the 2-component residual (eq. 46).
    pub d2: f64,
    /// True when the gate accepted the reading and both scalar updates were applied.
    pub applied: bool,
    /// Residual `[e_1' s_R, e_2' s_R]`, rad (small-angle).
    pub residual: [f64; 2],
}

impl Ekf {
    /// RB sec. 5.1: sequential sun-sensor update at the current state. The reading's time must
    /// be within [`super::EkfConfig::max_measurement_skew_us`] of the state time; the direction
    /// must be finite and of unit length (within 1%).
    pub fn update_sun(&mut self, reading: &SunReading) -> Result<SunUpdate, EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        let s_n = match self.config.sun.and_then(|e| e.sun_dir_n(reading.t_us)) {
            Some(s) if reading.sun_in_view => s,
            _ => return Err(EstError::SunUnavailable),
        };
        let s_r = Vec3::from(reading.sun_dir_rover);
        if !s_r.iter().all(|v| v.is_finite()) {
            return Err(EstError::NonFiniteInput);
        }
        if libm::fabs(s_r.norm() - 1.0) > 0.01 || libm::fabs(s_n.norm() - 1.0) > 0.01 {
            return Err(EstError::InvalidMeasurement);
        }
        self.check_skew(reading.t_us)?;
        let sigma2 = self.config.sun_sigma_rad * self.config.sun_sigma_rad;
        let s_hat = rot(&self.x.q_nr).transpose() * s_n;
        let (e1, e2) = tangent_basis(&s_hat);
        let sx = skew(&s_hat);
        let cols = [I_THETA, I_THETA + 1, I_THETA + 2];
        // Joint 2-dof gate (eq. 46).
        let mut h2 = SMatrix::<f64, 2, 3>::zeros();
        h2.row_mut(0).copy_from(&(e1.transpose() * sx));
        h2.row_mut(1).copy_from(&(e2.transpose() * sx));
        let r2 = SVector::<f64, 2>::new(e1.dot(&s_r), e2.dot(&s_r));
        let joint = Innovation::new(
            &self.p,
            cols,
            h2,
            r2,
            &(SMatrix::<f64, 2, 2>::identity() * sigma2),
        );
        let d2 = joint
            .mahalanobis2()
            .ok_or(EstError::ResidualCovarianceNotPositive)?;
        let threshold = chi2_95(2).unwrap_or(CHI2_95[2]);
        let residual = [r2[0], r2[1]];
        if d2 > threshold {
            return Ok(SunUpdate {
                d2,
                applied: false,
                residual,
            });
        }
        // Sequential scalar updates (RB eq. 16-21); the second is re-linearized at the state
        // corrected by the first.
        for e in [e1, e2] {
            let s_hat = rot(&self.x.q_nr).transpose() * s_n;
            let h = SMatrix::<f64, 1, 3>::from(e.transpose() * skew(&s_hat));
            let r = SVector::<f64, 1>::new(e.dot(&(s_r - s_hat)));
            let inn = Innovation::new(&self.p, cols, h, r, &SMatrix::<f64, 1, 1>::new(sigma2));
            self.fuse(&inn)?;
        }
        Ok(SunUpdate {
            d2,
            applied: true,
            residual,
        })
    }

    /// Refuse a measurement time too far from the state time.
    pub(crate) fn check_skew(&self, t_us: u64) -> Result<(), EstError> {
        let skew_us = t_us.abs_diff(self.x.t_us);
        if skew_us > self.config.max_measurement_skew_us {
            return Err(EstError::StaleMeasurement);
        }
        Ok(())
    }
}

/// Two unit vectors perpendicular to the unit vector `s` and to each other.
fn tangent_basis(s: &Vec3) -> (Vec3, Vec3) {
    let a = if libm::fabs(s.x) < 0.6 {
        Vec3::x()
    } else {
        Vec3::y()
    };
    let e1 = s.cross(&a);
    let e1 = e1 / crate::linalg::sqrt(e1.dot(&e1));
    let e2 = s.cross(&e1);
    (e1, e2)
}
