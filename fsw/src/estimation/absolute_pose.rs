//! Absolute pose update: the rover's world position `x, y` and heading from terrain-map
//! localization (V99 sec. 5, `crate::localization`), gated by the Mahalanobis test (H04
//! eq. 46) and fused by the shared update (H04 eq. 52-56, `fusion`).
//!
//! The measurement `z = [x_N, y_N, psi]` (m, m, rad) of the rover reference point and the
//! heading `psi = atan2(a_y, a_x)` of its forward axis `a = C e_x` (from north towards east)
//! is taken at the current state or at a live clone (the capture time of the hazard map):
//!
//! - position: `r_p = z_xy - p_hat_xy`, `H = [I_2 0]` on `dp` (N frame);
//! - heading: with the rover-frame attitude error, `C = C_hat exp([dtheta]x)`, the rotation in
//!   `N` is `phi = C_hat dtheta`, `da = phi x a`, and
//!   `dpsi = phi_z - a_z (phi_x a_x + phi_y a_y) / (a_x^2 + a_y^2)`, so
//!   `H_psi = g' C_hat` on `dtheta` with `g = [-a_z a_x / h^2, -a_z a_y / h^2, 1]`,
//!   `h^2 = a_x^2 + a_y^2`; `r_psi = wrap(z_psi - psi_hat)` in `(-pi, pi]`.
//!
//! The gate uses the 95 % chi-square quantile for 3 degrees of freedom (7.815), the policy of
//! the relative-pose and sun updates ([`super::gate::chi2_95`]).

use super::fusion::Innovation;
use super::gate::{chi2_95, GateDecision};
use super::state::{clone_index, rot, I_P, I_THETA};
use super::{Ekf, EstError};
use crate::types::{Mat6, Vec3, Vec6};
use nalgebra::{SMatrix, SVector};

/// An absolute pose measurement of the rover in the navigation frame `N`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AbsolutePose {
    /// Time of the pose (the capture of the localized map), microseconds since boot: the
    /// current state time or a live clone's.
    pub t_us: u64,
    /// Rover reference point `[x north, y east]` in `N`, m.
    pub position_m: [f64; 2],
    /// Heading of the rover's forward axis, rad from north towards east.
    pub yaw_rad: f64,
    /// Covariance of `[x, y, yaw]` (m^2, m^2 rad, rad^2), symmetric positive definite.
    pub covariance: [[f64; 3]; 3],
}

/// Smallest horizontal length of the forward axis for a defined heading (`cos 60 deg`).
const MIN_HORIZONTAL: f64 = 0.5;

impl Ekf {
    /// H04 eq. 46 without changing the state: the Mahalanobis test of `m`. The decision's
    /// `residual` holds `[r_x (m), r_y (m), r_yaw (rad)]` in its first three components and its
    /// `residual_covariance` `S` in the upper-left 3x3 block (identity elsewhere), `dof = 3`.
    pub fn gate_absolute_pose(&self, m: &AbsolutePose) -> Result<GateDecision, EstError> {
        let inn = self.absolute_pose_innovation(m)?;
        decision(&inn)
    }

    /// Gate `m` (eq. 46) and apply it (eq. 52-56) when `gated` is false or the gate accepts
    /// it. Errors: [`EstError::Faulted`], [`EstError::NonFiniteInput`],
    /// [`EstError::InvalidMeasurement`] (non-positive variance, heading undefined: forward axis
    /// within 30 deg of vertical), [`EstError::NoStateAtTime`],
    /// [`EstError::ResidualCovarianceNotPositive`].
    pub fn update_absolute_pose(
        &mut self,
        m: &AbsolutePose,
        gated: bool,
    ) -> Result<GateDecision, EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        let inn = self.absolute_pose_innovation(m)?;
        let mut d = decision(&inn)?;
        if d.accepted || !gated {
            self.fuse(&inn)?;
            d.applied = true;
        }
        Ok(d)
    }

    fn absolute_pose_innovation(&self, m: &AbsolutePose) -> Result<Innovation<3, 6>, EstError> {
        let finite = m.position_m.iter().all(|v| v.is_finite())
            && m.yaw_rad.is_finite()
            && m.covariance.iter().flatten().all(|v| v.is_finite());
        if !finite {
            return Err(EstError::NonFiniteInput);
        }
        if !(0..3).all(|k| m.covariance[k][k] > 0.0) {
            return Err(EstError::InvalidMeasurement);
        }
        // The state at the measurement's time: the current state or a live clone.
        let (q_nr, p_n, i_theta, i_p) = if m.t_us == self.x.t_us {
            (self.x.q_nr, self.x.p_n, I_THETA, I_P)
        } else {
            let (slot, c) = self
                .find_clone(m.t_us)
                .ok_or(EstError::NoStateAtTime { t_us: m.t_us })?;
            let i = clone_index(slot);
            (c.q_nr, c.p_n, i, i + 3)
        };
        let c = rot(&q_nr);
        let a: Vec3 = c * Vec3::x();
        let h2 = a.x * a.x + a.y * a.y;
        if h2.is_nan() || h2 < MIN_HORIZONTAL * MIN_HORIZONTAL {
            return Err(EstError::InvalidMeasurement);
        }
        let yaw_hat = libm::atan2(a.y, a.x);
        let g = Vec3::new(-a.z * a.x / h2, -a.z * a.y / h2, 1.0);
        let h_yaw = g.transpose() * c;
        // Columns [dtheta (3), dp (3)].
        let mut h = SMatrix::<f64, 3, 6>::zeros();
        h[(0, 3)] = 1.0;
        h[(1, 4)] = 1.0;
        for k in 0..3 {
            h[(2, k)] = h_yaw[k];
        }
        let r = SVector::<f64, 3>::new(
            m.position_m[0] - p_n.x,
            m.position_m[1] - p_n.y,
            wrap_pi(m.yaw_rad - yaw_hat),
        );
        let cov =
            SMatrix::<f64, 3, 3>::from_fn(|i, j| 0.5 * (m.covariance[i][j] + m.covariance[j][i]));
        let cols = [i_theta, i_theta + 1, i_theta + 2, i_p, i_p + 1, i_p + 2];
        Ok(Innovation::new(&self.p, cols, h, r, &cov))
    }
}

/// Angle wrapped to `(-pi, pi]`, rad.
fn wrap_pi(a: f64) -> f64 {
    let two_pi = 2.0 * core::f64::consts::PI;
    let w = a - two_pi * libm::floor((a + core::f64::consts::PI) / two_pi);
    if w <= -core::f64::consts::PI {
        w + two_pi
    } else {
        w
    }
}

/// Eq. 46 on the 3-component innovation, reported in the 6-slot [`GateDecision`].
fn decision(inn: &Innovation<3, 6>) -> Result<GateDecision, EstError> {
    let d2 = inn
        .mahalanobis2()
        .ok_or(EstError::ResidualCovarianceNotPositive)?;
    let threshold = chi2_95(3).ok_or(EstError::InvalidMeasurement)?;
    let mut residual = Vec6::zeros();
    residual.fixed_rows_mut::<3>(0).copy_from(&inn.r);
    let mut s = Mat6::identity();
    s.fixed_view_mut::<3, 3>(0, 0).copy_from(&inn.s);
    Ok(GateDecision {
        accepted: d2 <= threshold,
        d2,
        dof: 3,
        threshold,
        residual,
        residual_covariance: s,
        applied: false,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimation::state::{exp_quat, I_P, I_THETA};
    use crate::estimation::{CoreCov, EkfConfig, NominalState};

    fn filter(yaw: f64, pitch: f64) -> Ekf {
        let mut x = NominalState::at_rest(1_000);
        // Heading about z_N (down), then pitch about the rover's y axis.
        x.q_nr = exp_quat(&Vec3::new(0.0, 0.0, yaw)) * exp_quat(&Vec3::new(0.0, pitch, 0.0));
        x.p_n = Vec3::new(3.0, -2.0, 0.0);
        let mut p = CoreCov::zeros();
        let s = [0.02, 1e-4, 0.01, 1e-3, 0.5];
        for b in 0..5 {
            for k in 0..3 {
                p[(3 * b + k, 3 * b + k)] = s[b] * s[b];
            }
        }
        Ekf::new(EkfConfig::default(), x, &p).unwrap()
    }

    fn yaw_var(ekf: &Ekf) -> f64 {
        let s = ekf.heading_sigma_rad();
        s * s
    }

    fn measurement(ekf: &Ekf, dx: f64, dy: f64, dyaw: f64) -> AbsolutePose {
        let a = rot(&ekf.state().q_nr) * Vec3::x();
        AbsolutePose {
            t_us: ekf.time_us(),
            position_m: [ekf.state().p_n.x + dx, ekf.state().p_n.y + dy],
            yaw_rad: libm::atan2(a.y, a.x) + dyaw,
            covariance: [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 1e-4]],
        }
    }

    /// LOC-EKF-1: a consistent absolute pose is accepted, moves the state towards it and
    /// reduces the position and heading variances.
    #[test]
    fn consistent_update_reduces_covariance() {
        for (yaw, pitch) in [(0.3, 0.0), (-2.5, 0.2), (3.1, -0.15)] {
            let mut ekf = filter(yaw, pitch);
            let (px0, py0, v0) = (
                ekf.covariance()[(I_P, I_P)],
                ekf.covariance()[(I_P + 1, I_P + 1)],
                yaw_var(&ekf),
            );
            let m = measurement(&ekf, 0.3, -0.2, 0.01);
            let d = ekf.update_absolute_pose(&m, true).unwrap();
            assert!(d.accepted && d.applied && d.dof == 3, "{d:?}");
            let p = ekf.covariance();
            assert!(p[(I_P, I_P)] < 0.1 * px0 && p[(I_P + 1, I_P + 1)] < 0.1 * py0);
            assert!(yaw_var(&ekf) < 0.5 * v0, "{} {}", yaw_var(&ekf), v0);
            // Position pulled most of the way (prior 0.5 m against 0.1 m).
            let x = ekf.state().p_n;
            assert!((x.x - (3.0 + 0.3 * 0.25 / 0.26)).abs() < 1e-3, "{x:?}");
            assert!((x.y - (-2.0 - 0.2 * 0.25 / 0.26)).abs() < 1e-3, "{x:?}");
            // Heading moved towards the measurement (prior 0.02 rad against 0.01 rad).
            let a = rot(&ekf.state().q_nr) * Vec3::x();
            let dyaw = wrap_pi(libm::atan2(a.y, a.x) - (m.yaw_rad - 0.01));
            assert!((dyaw - 0.008).abs() < 1e-3, "{dyaw}");
        }
    }

    /// LOC-EKF-2: a 10-sigma outlier is rejected by the gate and changes nothing.
    #[test]
    fn ten_sigma_outlier_is_rejected() {
        let mut ekf = filter(1.0, 0.05);
        // Innovation sigma along x: sqrt(0.25 + 0.01) = 0.51 m.
        let m = measurement(&ekf, 10.0 * 0.51, 0.0, 0.0);
        let before = (*ekf.state(), *ekf.covariance());
        let d = ekf.update_absolute_pose(&m, true).unwrap();
        assert!(!d.accepted && !d.applied && d.d2 > 90.0, "{d:?}");
        assert_eq!(*ekf.state(), before.0);
        assert_eq!(*ekf.covariance(), before.1);
        // A heading outlier too: innovation sigma sqrt(4e-4 + 1e-4) rad.
        let m = measurement(&ekf, 0.0, 0.0, 10.0 * crate::linalg::sqrt(5e-4));
        assert!(!ekf.gate_absolute_pose(&m).unwrap().accepted);
    }

    /// The update at a clone (the capture time) and refused inputs.
    #[test]
    fn clone_time_and_refused_inputs() {
        let mut ekf = filter(0.5, 0.0);
        let h = ekf.clone_at(1_000).unwrap();
        let m = measurement(&ekf, 0.1, 0.1, 0.0);
        let m_clone = AbsolutePose {
            t_us: h.t_us(),
            ..m
        };
        assert!(ekf.update_absolute_pose(&m_clone, true).unwrap().applied);
        assert!(ekf.covariance()[(I_P, I_P)] < 0.05);
        let stale = AbsolutePose { t_us: 5, ..m };
        assert_eq!(
            ekf.update_absolute_pose(&stale, true),
            Err(EstError::NoStateAtTime { t_us: 5 })
        );
        let nan = AbsolutePose {
            yaw_rad: f64::NAN,
            ..m
        };
        assert_eq!(
            ekf.update_absolute_pose(&nan, true),
            Err(EstError::NonFiniteInput)
        );
        let mut zero = m;
        zero.covariance[2][2] = 0.0;
        assert_eq!(
            ekf.update_absolute_pose(&zero, true),
            Err(EstError::InvalidMeasurement)
        );
        // Heading wrap: a measurement across +-pi is a small residual.
        let ekf = filter(core::f64::consts::PI - 0.001, 0.0);
        let mut m = measurement(&ekf, 0.0, 0.0, 0.002);
        m.yaw_rad -= 2.0 * core::f64::consts::PI;
        assert!(m.yaw_rad < -core::f64::consts::FRAC_PI_2);
        let d = ekf.gate_absolute_pose(&m).unwrap();
        assert!((d.residual[2] - 0.002).abs() < 1e-9, "{d:?}");
        assert_eq!(I_THETA, 0);
    }
}
