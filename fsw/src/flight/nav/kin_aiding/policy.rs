//! The gate policy's rules beyond H04's gate (module doc of [`super`]): the fusion without VO,
//! the shock grace, the streak recovery, the slip hold's statistical trigger, and their
//! constants.

use super::{KinAiding, KinAidingConfig, KinCounters};
use crate::estimation::{EstError, KeptRelativePose};
use crate::flight::nav::filter::NavFilter;
use crate::flight::nav::RG2_PERIOD_S;
use crate::types::RelativePose;

/// Default [`KinAidingConfig::crab_allowance`]: the crab (lateral slip) a kinematic interval's
/// gate cannot see, 1-sigma, as `tan(crab)` per unit of the cross-slope gravity component
/// (`sin` of the cross slope, from the EKF attitude). The gate (eq. 46) tests the whole
/// interval, but a crab of a few degrees moves one 50 ms interval sideways by less than a
/// millimetre, far below what one test detects; fused as exact, an accepted interval's zero
/// lateral motion is then learnt, against VO's translation, as a heading error
/// (`slope-10-faults`, no sun). A crab is driven by the side force that holds the rover on the
/// cross slope (`W sin(cross slope)`), so the allowance scales with it: 0.5 gives `tan 5 deg`
/// on a 10 deg cross slope, half the crab a Rocky 8 class rover shows there on sand (H05
/// Fig. 9: about 9 deg), and nothing on level ground, where the wheels' lateral constraint
/// holds. Measured with the rigid-wheel simulator, seed 1 (note 0017):
/// `slope-10-faults` EKF error 10.3 %, 0.45 m cross-track and goal missed without the
/// allowance, 0.55 %, 0.05 m and goal reached with it; the gate's false alarms on `flat-firm`
/// without slip 7.8 % without, 8.4 % with it (10.3 % with a constant `tan 5 deg`).
pub const KIN_CRAB_ALLOWANCE: f64 = 0.5;

/// Stop-and-go without VO: the EKF's horizontal step over a kinematic interval may exceed
/// the wheels' by this factor (downhill skid) before the IMU is judged wrong.
pub const BLIND_SKID_FACTOR: f64 = 1.5;
/// ... plus this floor, m (the odometry's noise over a short interval).
pub const BLIND_SKID_FLOOR_M: f64 = 0.01;

/// The ground vehicle's vertical constraint on a kinematic interval of `step_m` (m, its 3D
/// translation): the rover does not move along its own `z` axis, 1-sigma 20 % of the step plus
/// 0.5 mm (H04 sec. 3 leaves the vertical unobserved); the variance, m^2, added to the
/// interval's `z` where the flight software fuses it (VO lost, an IMU shock's grace).
pub(super) fn vertical_constraint_variance(step_m: f64) -> f64 {
    let sigma_z = 0.2 * step_m + 5.0e-4;
    sigma_z * sigma_z
}

/// The slip hold ([`KinAidingConfig::slip_hold_cycles`], `slip_hold_rejections`): at least
/// `slip_hold_rejections` (and at least one) of the last `slip_hold_cycles` (at most 32)
/// tested intervals were rejected.
pub(super) fn slip_holding(config: &KinAidingConfig, reject_history: u32) -> bool {
    let window = config.slip_hold_cycles.min(32);
    let mask = if window >= 32 {
        u32::MAX
    } else {
        (1u32 << window).wrapping_sub(1)
    };
    let rejected = (reject_history & mask).count_ones();
    window > 0 && rejected >= config.slip_hold_rejections.max(1)
}

/// Most kinematic intervals after an IMU shock whose rejections are not slip
/// ([`KinAiding::imu_shock`]): 20 intervals (1 s of RG2), one slip-hold window of the flight
/// configuration. The grace ends earlier once [`SHOCK_SETTLED_INTERVALS`] intervals in a row
/// were accepted (and fused): the velocity is anchored again. Why: note 0022.
pub(super) const SHOCK_GRACE_INTERVALS: u8 = 20;

/// Intervals accepted in a row that end an IMU shock's grace: two, so that the interval after
/// the first correction confirms it.
pub(super) const SHOCK_SETTLED_INTERVALS: u8 = 2;

/// Placeholder settings (zero everywhere; replaced by [`KinAiding::init`]).
pub(super) const EMPTY_CONFIG: KinAidingConfig = KinAidingConfig {
    odometry: crate::kinematics::OdometryConfig {
        drive_increment_noise_rad: 0.0,
        drive_fraction: 0.0,
        steer_noise_rad: 0.0,
        suspension_increment_noise_rad: 0.0,
        radius_scale_sigma: 0.0,
        wheel_radius_sigma: 0.0,
        articulation_fraction: 0.0,
        observed: [false; 6],
        contact_angles: false,
        contact_translation: false,
        contact: crate::kinematics::ContactConfig {
            residual_sigma_m: 0.0,
            step_sigma_rad: 0.0,
            level_sigma_rad: 0.0,
            level_sigma_no_gyro_rad: 0.0,
            min_drive_increment_rad: 0.0,
            max_angle_rad: 0.0,
            iterations: 0,
            zero_mean: false,
            window_travel_m: 0.0,
        },
    },
    slip_hold_cycles: 0,
    slip_hold_rejections: 0,
    vo_loss_slip_fraction: 0.0,
    vo_loss_translation_only: false,
    vo_loss_drift_fraction: 0.0,
    crab_allowance: 0.0,
    reject_streak_cycles: 0,
    streak_velocity_sigma_m_s: 0.0,
    streak_accel_bias_sigma_m_s2: 0.0,
    blind_anchor_cycles: 0,
    stopped_wheel_rate_rad_s: 0.0,
    radius_scale: crate::flight::nav::radius::RadiusScaleConfig {
        window_m: 0.0,
        gain: 0.0,
        max_deviation: 0.0,
        vo_recent_cycles: 0,
    },
};

/// All counters zero (as [`KinCounters::default`], usable in a `const`).
pub(super) const NO_COUNTERS: KinCounters = KinCounters {
    kin_tested: 0,
    kin_rejected: 0,
    kin_held: 0,
    kin_ungated: 0,
    kin_streaks: 0,
    kin_errors: 0,
    zupts: 0,
    kin_imu_carried: 0,
    imu_shocks: 0,
};

impl KinAiding {
    /// VO lost or off: the interval (already tested by the gate) is fused with a slip allowance
    /// (`vo_loss_slip_fraction` of the step on x, y and yaw), so that slip is not learnt as a
    /// heading error, and, since nothing else observes the vertical, with the ground vehicle's
    /// constraint that it does not move along its own z axis (1-sigma 20 % of the step plus
    /// 0.5 mm; H04 sec. 3 leaves it unobserved). Without VO slip is unobservable: fusing with
    /// the allowance keeps the EKF from running on the IMU alone. With
    /// [`KinAidingConfig::vo_loss_translation_only`] the rotation is not fused: on slipping ground the
    /// wheels' yaw carries the yaw slip, while the gyro (with the sun for its bias) is far
    /// better over an interval.
    ///
    /// The travel fused this way is not verified: the horizontal position sigma grows by the
    /// whole step when the gate rejected it (the slip is unknown, up to 100 %) and by
    /// [`KinAidingConfig::vo_loss_drift_fraction`] of it otherwise ([`NavFilter::inflate_position`]), so that
    /// the position uncertainty honestly covers a rover that spins its wheels in place and
    /// fault protection can refuse an arrival it cannot support.
    ///
    /// `kept`: the interval's innovation from the gate ([`crate::estimation::Ekf::gate_relative_pose_kept`]),
    /// fused with the allowance without computing `H P H'` again; without it (or when the
    /// filter changed since) the interval is fused from scratch.
    pub(super) fn fuse_without_vo(
        &mut self,
        rp: &mut RelativePose,
        kept: Option<&KeptRelativePose>,
        accepted: bool,
        filter: &mut NavFilter,
    ) {
        if !filter.is_running() {
            return;
        }
        self.counters.kin_ungated = self.counters.kin_ungated.saturating_add(1);
        let step = rp.trans_0_1_m.norm();
        let yaw = libm::fabs(crate::estimation::state::log_quat(&rp.rot_0_1).z);
        let f = self.config.vo_loss_slip_fraction;
        // Added variances of [rx, ry, rz, x, y, z].
        let extra = [
            0.0,
            0.0,
            (f * yaw) * (f * yaw) + 1.0e-8,
            (f * step) * (f * step),
            (f * step) * (f * step),
            vertical_constraint_variance(step),
        ];
        if let Some(o) = rp.observed.get_mut(5) {
            *o = true;
        }
        for (k, e) in extra.iter().enumerate() {
            rp.covariance[(k, k)] += e;
        }
        if self.config.vo_loss_translation_only {
            for o in rp.observed.iter_mut().take(3) {
                *o = false;
            }
        }
        filter.record_relative_pose(rp);
        let result = match filter.live() {
            Some(ekf) => match kept {
                Some(k) => match ekf.fuse_kept_relative_pose(k, rp.observed, extra) {
                    Err(EstError::StaleMeasurement) => {
                        ekf.update_relative_pose(rp, false).map(|_| ())
                    }
                    r => r,
                },
                None => ekf.update_relative_pose(rp, false).map(|_| ()),
            },
            None => Ok(()),
        };
        if let Err(e) = result {
            self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
            filter.error(e);
            return;
        }
        let horizontal = crate::linalg::sqrt(
            rp.trans_0_1_m.x * rp.trans_0_1_m.x + rp.trans_0_1_m.y * rp.trans_0_1_m.y,
        );
        let delta = if accepted {
            self.config.vo_loss_drift_fraction * horizontal
        } else {
            horizontal
        };
        filter.inflate_position(delta);
    }

    /// One kinematic interval of an IMU shock's grace ([`KinAiding::imu_shock`]), gated (and,
    /// accepted, fused) on its translation: [`SHOCK_SETTLED_INTERVALS`] accepted in a row end
    /// the grace (the velocity is anchored again); a rejected one shows that the velocity is
    /// still wrong, by the residual's translation over the interval's duration, and the
    /// velocity covariance grows by that (at least [`KinAidingConfig::streak_velocity_sigma_m_s`], at
    /// most 1 m/s) so that the next interval can correct it. A single accepted interval at the
    /// shock's inflated covariance may leave part of the error with a collapsed covariance
    /// (`rock-field-crawl` seed 1: 0.5 m/s left after five clipped samples, which the slip
    /// hold then kept for 2.5 s: 0.7 m of lateral error until VO pulled it back).
    pub(super) fn shock_interval(
        &mut self,
        rp: &RelativePose,
        residual: &[f64],
        accepted: bool,
        filter: &mut NavFilter,
    ) {
        if accepted {
            self.shock_accepted = self.shock_accepted.saturating_add(1);
            if self.shock_accepted >= SHOCK_SETTLED_INTERVALS {
                self.shock_grace = 0;
                self.shock_accepted = 0;
            }
            return;
        }
        self.shock_accepted = 0;
        if !filter.is_running() {
            return;
        }
        let dt_s = rp.t1_us.saturating_sub(rp.t0_us) as f64 * 1e-6;
        let (rx, ry, rz) = (
            residual.get(3).copied().unwrap_or(0.0),
            residual.get(4).copied().unwrap_or(0.0),
            residual.get(5).copied().unwrap_or(0.0),
        );
        let r = crate::linalg::sqrt(rx * rx + ry * ry + rz * rz);
        let implied = if dt_s > 0.0 && r.is_finite() {
            r / dt_s
        } else {
            0.0
        };
        let v = crate::linalg::clamp(implied, self.config.streak_velocity_sigma_m_s, 1.0);
        filter.inflate_velocity(v, 0.0);
    }

    /// A streak of [`KinAidingConfig::reject_streak_cycles`] gate rejections in a row with no VO
    /// fused in between: either sustained slip or a filter whose velocity has drifted beyond
    /// what its covariance admits (an IMU worse than its configured noise), which would
    /// otherwise coast on the IMU for ever. The velocity covariance is inflated by the velocity
    /// error the last residual implies, `implied_velocity_m_s` (at least
    /// [`KinAidingConfig::streak_velocity_sigma_m_s`], at most 1 m/s), and the accelerometer-bias
    /// covariance by that velocity over the streak's duration (at least
    /// [`KinAidingConfig::streak_accel_bias_sigma_m_s2`], at most 0.5 m/s^2), so that the next
    /// kinematic interval can pull the filter back; counted in [`KinCounters::kin_streaks`].
    pub(super) fn recover_from_streak(
        &mut self,
        implied_velocity_m_s: f64,
        filter: &mut NavFilter,
    ) {
        if !filter.is_running() {
            return;
        }
        let c = &self.config;
        let implied = if implied_velocity_m_s.is_finite() {
            implied_velocity_m_s
        } else {
            0.0
        };
        let v = crate::linalg::clamp(implied, c.streak_velocity_sigma_m_s, 1.0);
        let streak_s = f64::from(c.reject_streak_cycles.max(1)) * RG2_PERIOD_S;
        let b = crate::linalg::clamp(v / streak_s, c.streak_accel_bias_sigma_m_s2, 0.5);
        self.reject_streak = 0;
        self.counters.kin_streaks = self.counters.kin_streaks.saturating_add(1);
        filter.inflate_velocity(v, b);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slip_hold_needs_repeated_rejections_in_the_window() {
        let flight = crate::flight::nav::NavConfig::rocky8([0.0; 3], 0.0).kin;
        assert_eq!(flight.slip_hold_cycles, 20);
        assert_eq!(flight.slip_hold_rejections, 1);
        let config = KinAidingConfig {
            slip_hold_rejections: 3,
            ..flight
        };
        // One or two false alarms in the last 20 tests: no hold.
        assert!(!slip_holding(&config, 0));
        assert!(!slip_holding(&config, 0b1));
        assert!(!slip_holding(&config, 0b1000_0000_0000_0000_0001));
        // Three in the window: hold; the oldest leaves the window after 20 tests.
        assert!(slip_holding(&config, 0b1000_0000_0000_0000_0011));
        assert!(!slip_holding(&config, 0b1_0000_0000_0000_0000_0011));
        // With one rejection as the trigger (the flight default) every rejection holds.
        let old = flight;
        assert!(slip_holding(&old, 0b1000_0000_0000_0000_0000));
        assert!(!slip_holding(&old, 0b1_0000_0000_0000_0000_0000));
        // A window of 0 never holds; a window over 32 is the whole history.
        assert!(!slip_holding(
            &KinAidingConfig {
                slip_hold_cycles: 0,
                ..old
            },
            u32::MAX
        ));
        let wide = KinAidingConfig {
            slip_hold_cycles: 100,
            ..config
        };
        assert!(slip_holding(&wide, 0b111 << 29));
    }
}
