//! Kinematic aiding (RG2): the kinematic interval (eq. 15), its Mahalanobis gate (eq. 46) and
//! the gate policy (fuse, hold, VO-loss fallback), the slip vector, zero-velocity updates.

use super::*;
use crate::kinematics::planar::planar_pose_increment_at;

/// Default [`NavConfig::kin_crab_allowance`]: the crab (lateral slip) a kinematic interval's
/// gate cannot see, 1-sigma, as `tan(crab)` per unit of the cross-slope gravity component
/// (`sin` of the cross slope, from the EKF attitude). The gate (eq. 46) tests the whole
/// interval, but a crab of a few degrees moves one 50 ms interval sideways by less than a
/// millimetre, far below what one test detects; fused as exact, an accepted interval's zero
/// lateral motion is then learnt, against VO's translation, as a heading error
/// (`slope-10-faults`, no sun). A crab is driven by the side force that holds the rover on the
/// cross slope (`W sin(cross slope)`), so the allowance scales with it: 0.5 gives `tan 5 deg`
/// on a 10 deg cross slope, half the crab a Rocky 8 class rover shows there on sand (H05
/// Fig. 9: about 9 deg), and nothing on level ground, where the wheels' lateral constraint
/// holds. Measured with the rigid-wheel simulator, seed 1 (`docs/estimation.md`):
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
fn vertical_constraint_variance(step_m: f64) -> f64 {
    let sigma_z = 0.2 * step_m + 5.0e-4;
    sigma_z * sigma_z
}

/// The slip hold (`NavConfig::slip_hold_cycles`, `slip_hold_rejections`): at least
/// `slip_hold_rejections` (and at least one) of the last `slip_hold_cycles` (at most 32)
/// tested intervals were rejected.
pub(super) fn slip_holding(config: &NavConfig, reject_history: u32) -> bool {
    let window = config.slip_hold_cycles.min(32);
    let mask = if window >= 32 {
        u32::MAX
    } else {
        (1u32 << window).wrapping_sub(1)
    };
    let rejected = (reject_history & mask).count_ones();
    window > 0 && rejected >= config.slip_hold_rejections.max(1)
}

impl Navigator {
    /// Adds one IMU sample's bias-corrected rotation to the rotation since the last joint
    /// reading. A sample that does not follow the previous one by 0 to 50 ms (a gap, time going
    /// backwards) or is not finite drops the integral: the next joint step then has no gyro
    /// input and the estimator uses the contacts alone.
    pub(super) fn integrate_gyro(&mut self, s: &ImuSample) {
        let previous = self.gyro_t_us.replace(s.t_us);
        let dt_us = previous.and_then(|p| s.t_us.checked_sub(p));
        let b_g = self.ekf.state().b_g;
        let w = Vec3::new(
            s.gyro_rad_s[0] - b_g.x,
            s.gyro_rad_s[1] - b_g.y,
            s.gyro_rad_s[2] - b_g.z,
        );
        match (self.gyro_since_joints, dt_us) {
            (Some(q), Some(dt)) if dt <= 50_000 && w.iter().all(|v| v.is_finite()) => {
                let step = crate::types::Quat::from_scaled_axis(w * (dt as f64 * 1e-6));
                self.gyro_since_joints = Some(q * step);
            }
            _ => self.gyro_since_joints = None,
        }
    }

    /// RG2: one checked joint reading (`None`: none this cycle). Kinematic interval, gate,
    /// fusion or slip vector, dead reckoning; zero-velocity update when stopped.
    #[inline(never)]
    pub fn kinematic_cycle(&mut self, joints: Option<&JointState>) {
        let Some(j) = joints else {
            self.cycles_without_joints = self.cycles_without_joints.saturating_add(1);
            return;
        };
        self.cycles_without_joints = 0;
        let previous = self.last_joints.replace(*j);
        if let Some(prev) = previous {
            let step = match &self.traj.nominal_points {
                Some(points) => planar_pose_increment_at(&self.config.geometry, points, &prev, j),
                None => planar_pose_increment(&self.config.geometry, &prev, j),
            };
            if let Ok(step) = step {
                self.traj.wheel_step(step);
            }
        }
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        let t_us = ekf.time_us();
        let Some(start) = self.interval else {
            self.restart_interval(j, t_us);
            return;
        };
        // Body rotation over the joint step from the gyro, in R at the step start.
        let gyro = self
            .gyro_since_joints
            .replace(crate::types::Quat::identity())
            .map(|q| crate::estimation::state::log_quat(&q));
        let pose = self.odometry.update_with_gyro(j, gyro).and_then(|()| {
            let contact_translation = self.odometry.contact_translation_m();
            self.odometry.take().map(|rp| (rp, contact_translation))
        });
        let (mut rp, contact_translation) = match pose {
            Ok(p) => p,
            Err(KinematicsError::TimeNotAdvancing) => return,
            Err(_) => {
                self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
                self.boresight.interrupt();
                self.kin3d_scale.interrupt();
                self.release(Some(start));
                self.interval = None;
                self.restart_interval(j, t_us);
                return;
            }
        };
        if start.t_us() == t_us {
            // No IMU time has passed: keep the interval open.
            return;
        }
        // The interval is labelled with the EKF times of its ends (the joint reading and the
        // IMU sample of a frame carry the same time stamp on this rover).
        rp.t0_us = start.t_us();
        rp.t1_us = t_us;
        // The wheel travel as the EKF measured it (before the radius scale is applied), for the
        // scale's own estimate below.
        let wheel_step = rp.trans_0_1_m.norm();
        // The contact-angle step of the 3D dead reckoning in `N` (unscaled), for its own scale.
        let kin_step_n = ekf
            .clone_pose(start)
            .ok()
            .map(|(q0, _)| q0.transform_vector(&contact_translation));
        let ekf_step = ekf
            .clone_pose(start)
            .map(|(_, p0)| (ekf.state().p_n - p0).norm())
            .ok();
        // Effective wheel radius scale learnt from VO on firm ground (`radius_scale`).
        let k = self.radius_scale.scale;
        rp.trans_0_1_m *= k;
        for r in 3..6 {
            for c in 0..6 {
                let f = if c >= 3 { k * k } else { k };
                rp.covariance[(r, c)] *= f;
                if c < 3 {
                    rp.covariance[(c, r)] *= k;
                }
            }
        }
        if let Ok((q0, _)) = ekf.clone_pose(start) {
            // The track memory needs the contact-angle translation (eq. 15's has no heave of
            // its own to correct, and the EKF's is not this trajectory's).
            let axles = self
                .config
                .odometry
                .contact_translation
                .then(|| self.odometry.axle_centres_m());
            // As `Navigator::kin3d_radius_scale` (field by field: the filter is borrowed).
            let k3 = if self.config.kin3d_radius_scale {
                self.kin3d_scale.scale.scale
            } else {
                1.0
            };
            self.traj.kinematic_step(
                &q0,
                &(contact_translation * k3),
                &ekf.state().q_nr,
                axles.as_ref(),
            );
            self.counters.track_matched = self.traj.track.matched_steps;
            self.counters.track_unmatched = self.traj.track.unmatched_steps;
            if let Ok((_, p0)) = ekf.clone_pose(start) {
                let ekf_step = (ekf.state().p_n - p0).norm();
                let vo_fused = core::mem::take(&mut self.vo_fused_since_interval);
                // Without VO the EKF travel is measured too while the stop-and-go drive
                // anchors the IMU velocity (its slip estimate is the IMU's, eq. 46).
                let imu_anchored = self.config.blind_stop_interval_m > 0.0
                    && (!self.config.vo_enabled
                        || self.cycles_since_vo > self.config.vo_timeout_cycles)
                    && self.cycles_since_zupt <= self.config.blind_anchor_cycles;
                if let Some(r) = self.protection.travel(
                    &self.config.protection,
                    rp.trans_0_1_m.norm(),
                    ekf_step,
                    vo_fused || imu_anchored,
                ) {
                    // Latched like `fault_stop` (the filter is borrowed here).
                    if self.mode == NavMode::Driving {
                        self.mode = NavMode::Stopped;
                        self.fault_response = r;
                        self.counters.fault_stops = self.counters.fault_stops.saturating_add(1);
                    }
                }
            }
        }
        self.cycles_since_vo = self.cycles_since_vo.saturating_add(1);
        // As `Navigator::vo_lost` (field by field: the filter is borrowed here).
        let vo_lost =
            !self.config.vo_enabled || self.cycles_since_vo > self.config.vo_timeout_cycles;
        // Intervals that may carry an IMU shock's velocity error (`Navigator::imu_shock`): no
        // hold, and a rejection is not slip but the velocity still wrong (below).
        let shock = self.shock_grace > 0;
        self.shock_grace = self.shock_grace.saturating_sub(1);
        let holding = slip_holding(&self.config, self.reject_history) && !shock;
        if shock {
            // A shock is the accelerometer's: its error is in the velocity, in all three axes,
            // and with VO alive nothing else observes the vertical between captures. The
            // intervals of its grace are gated and fused on their translation only (the gyro
            // is unaffected; on a rock field the kinematic rotation can disagree with it by
            // several of its sigmas and would refuse the interval) and with the ground
            // vehicle's vertical constraint, so that the accepted ones re-anchor the whole
            // velocity (`rock-field-crawl` seed 1: without the vertical the estimate went
            // 15 m up in 3.5 s before the next VO update pulled it back; with the rotation the
            // intervals after a series of shocks were refused at d2 100-1,000 on 4 mrad of
            // roll and pitch and the velocity error stayed). Without VO the fusion below adds
            // the vertical constraint itself (`fuse_without_vo`).
            for (k, o) in rp.observed.iter_mut().enumerate() {
                *o = k >= 3 && (k < 5 || !vo_lost);
            }
            if !vo_lost {
                if let Some(v) = rp.covariance.get_mut((5, 5)) {
                    *v += vertical_constraint_variance(rp.trans_0_1_m.norm());
                }
            }
        }
        // The gate test (eq. 46) at the odometry's own covariance: the slip detector. With VO
        // alive an accepted interval is fused by the same call (unless holding); without VO the
        // interval is tested here and then fused with the slip allowance below.
        let fusing = !(vo_lost || holding);
        // Cross-slope component of gravity in R (sin of the cross slope).
        let cross = libm::fabs(ekf.state().q_nr.inverse_transform_vector(&Vec3::z()).y);
        let crab = {
            let a = self.config.kin_crab_allowance * cross * rp.trans_0_1_m.norm();
            if a.is_finite() {
                a * a
            } else {
                f64::INFINITY
            }
        };
        let allowance = [0.0, 0.0, 0.0, 0.0, crab, 0.0];
        // The interval as fused: the crab allowance added to its lateral variance.
        let mut fused = rp;
        if crab.is_finite() {
            if let Some(v) = fused.covariance.get_mut((4, 4)) {
                *v += crab;
            }
        } else if let Some(o) = fused.observed.get_mut(4) {
            *o = false;
        }
        // Without fusion the gate keeps the interval's innovation, so that the fusion without
        // VO below does not compute it again (issue 18).
        let mut kept = None;
        let result = if fusing {
            ekf.update_relative_pose_allowance(&rp, allowance)
        } else {
            ekf.gate_relative_pose_kept(&rp).map(|(d, k)| {
                kept = Some(k);
                d
            })
        };
        // The recorder (late VO replay) keeps the interval only when the live filter fused it:
        // a replay on the VO-corrected filter gates it again, but never fuses an interval the
        // live gate rejected as slip (a rejected gated update left the filter unchanged). On a
        // crabbing slope the corrected filter otherwise let some crab-free intervals through
        // and moved the estimate uphill at every VO update (SIL-GNC-4).
        if fusing && result.as_ref().is_ok_and(|d| d.applied) {
            self.recorder.relative_pose(&fused, false);
        }
        // The wheels' motion between captures, for VO's boresight (only intervals fused as
        // slip-free count).
        let usable = fusing && result.as_ref().is_ok_and(|d| d.accepted);
        self.boresight
            .kinematic(&self.config.vo_boresight, &rp, usable, cross);
        match kin_step_n {
            Some(k) => self.kin3d_scale.kinematic(&[k.x, k.y, k.z], usable),
            None => self.kin3d_scale.interrupt(),
        }
        match result {
            Ok(d) => {
                self.counters.kin_tested = self.counters.kin_tested.saturating_add(1);
                self.gate = GateStatus {
                    d2: d.d2,
                    accepted: d.accepted,
                    dof: d.dof as u8,
                    residual: core::array::from_fn(|k| d.residual.get(k).copied().unwrap_or(0.0)),
                    sigma: core::array::from_fn(|k| {
                        crate::linalg::sqrt(
                            d.residual_covariance
                                .get((k, k))
                                .copied()
                                .unwrap_or(0.0)
                                .max(0.0),
                        )
                    }),
                };
                if let Some(e) = ekf_step {
                    // Learn only from intervals the gate accepted while VO anchors the EKF.
                    let anchored =
                        self.cycles_since_vo <= self.config.radius_scale.vo_recent_cycles;
                    self.radius_scale.add(
                        &self.config.radius_scale,
                        wheel_step,
                        e,
                        d.accepted && anchored,
                    );
                }
                let slip = !d.accepted && !shock;
                if shock {
                    self.shock_interval(&rp, d.residual.as_slice(), d.accepted);
                }
                self.reject_history = (self.reject_history << 1) | u32::from(slip);
                if d.accepted {
                    self.reject_streak = 0;
                    // H04: no slip when the kinematics agrees with the estimate.
                    self.slip = SlipVector::default();
                    if holding && !vo_lost {
                        self.counters.kin_held = self.counters.kin_held.saturating_add(1);
                    }
                } else {
                    self.counters.kin_rejected = self.counters.kin_rejected.saturating_add(1);
                    self.reject_streak = self.reject_streak.saturating_add(1);
                    // Slip = EKF minus kinematics = -(measured - predicted), rover frame R0.
                    self.slip = SlipVector {
                        x_m: -d.residual[3],
                        y_m: -d.residual[4],
                        phi_rad: -d.residual[2],
                    };
                }
                // The IMU may carry the motion only while a recent stop anchors its velocity
                // and while its motion is one the wheels allow: a driving rover slips, so
                // its ground travel is at most the wheels' (plus a skid margin); an EKF step
                // longer than that is an IMU error (a shock, a dropped sample), and the
                // kinematics is fused instead.
                let kin_step = crate::linalg::sqrt(
                    rp.trans_0_1_m.x * rp.trans_0_1_m.x + rp.trans_0_1_m.y * rp.trans_0_1_m.y,
                );
                let (ex, ey) = (
                    rp.trans_0_1_m.x - d.residual[3],
                    rp.trans_0_1_m.y - d.residual[4],
                );
                let ekf_step_h = crate::linalg::sqrt(ex * ex + ey * ey);
                let plausible = ekf_step_h <= BLIND_SKID_FACTOR * kin_step + BLIND_SKID_FLOOR_M;
                let anchored_by_zupt = self.config.blind_stop_interval_m > 0.0
                    && self.cycles_since_zupt <= self.config.blind_anchor_cycles
                    && plausible;
                if vo_lost && anchored_by_zupt {
                    // Stop-and-go without VO: the IMU velocity, anchored by the last stop,
                    // carries the motion; the slip vector above measures the kinematics
                    // against it. An interval the gate accepts is not fused either: a slip
                    // below the gate's resolution (the first centimetres after a start) would
                    // otherwise be learnt as an accelerometer bias, which the IMU then carries
                    // into the whole segment.
                    self.counters.kin_imu_carried = self.counters.kin_imu_carried.saturating_add(1);
                } else if vo_lost {
                    self.fuse_without_vo(&mut rp, kept.as_ref(), d.accepted);
                } else if self.reject_streak >= self.config.reject_streak_cycles {
                    // The velocity error the last residual implies (translation residual over
                    // the interval's duration).
                    let dt_s = rp.t1_us.saturating_sub(rp.t0_us) as f64 * 1e-6;
                    let r = crate::linalg::sqrt(
                        d.residual[3] * d.residual[3] + d.residual[4] * d.residual[4],
                    );
                    let implied = if dt_s > 0.0 { r / dt_s } else { 0.0 };
                    self.recover_from_streak(implied);
                }
            }
            Err(e) => {
                self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
                self.ekf_error(e);
            }
        }
        // A stop's zero-velocity update is due; [`Self::zero_velocity_cycle`] applies it half an
        // RG2 period later (group RG2B), so that the two EKF updates of a stop never share a
        // release (issue 18: the RG2 release at most 100,000 instructions).
        if self.is_stopped(j) {
            self.zupt_due = true;
        } else {
            self.zupt_due = false;
            self.cycles_since_zupt = self.cycles_since_zupt.saturating_add(1);
        }
        self.release(Some(start));
        self.interval = None;
        if let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) {
            let result = ekf.clone_at(t_us);
            self.recorder.clone_at(t_us);
            match result {
                Ok(h) => self.interval = Some(h),
                Err(_) => {
                    self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
                }
            }
        }
    }

    /// RG2B, half an RG2 period after [`Self::kinematic_cycle`]: the zero-velocity update
    /// (`v_N = 0`, [`crate::estimation::Ekf::update_zero_velocity`], at the filter's current
    /// time) of the stop the last kinematic cycle saw (its joint reading within
    /// [`NavConfig::stopped_wheel_rate_rad_s`] with a zero command). It is applied only while
    /// the command is still zero: guidance may have started a drive in the meantime, and then
    /// the cycle counts as one without a stop. Nothing is due after a cycle without a joint
    /// reading, an odometry error or a cycle that kept its interval open.
    pub fn zero_velocity_cycle(&mut self) {
        if !core::mem::take(&mut self.zupt_due) {
            return;
        }
        let still = self.command.x_dot_m_s == 0.0
            && self.command.y_dot_m_s == 0.0
            && self.command.yaw_rate_rad_s == 0.0;
        if !still {
            self.cycles_since_zupt = self.cycles_since_zupt.saturating_add(1);
            return;
        }
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        let t_us = ekf.time_us();
        let result = ekf.update_zero_velocity(t_us);
        self.recorder.zero_velocity(t_us);
        match result {
            Ok(()) => {
                self.counters.zupts = self.counters.zupts.saturating_add(1);
                self.cycles_since_zupt = 0;
            }
            Err(e) => self.ekf_error(e),
        }
    }

    pub(super) fn restart_interval(&mut self, j: &JointState, t_us: u64) {
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        if self.odometry.start(j).is_err() {
            self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
            return;
        }
        self.gyro_since_joints = Some(crate::types::Quat::identity());
        self.boresight.interrupt();
        self.kin3d_scale.interrupt();
        let result = ekf.clone_at(t_us);
        self.recorder.clone_at(t_us);
        match result {
            Ok(h) => self.interval = Some(h),
            Err(_) => self.counters.kin_errors = self.counters.kin_errors.saturating_add(1),
        }
    }

    pub(super) fn is_stopped(&self, j: &JointState) -> bool {
        let commanded_zero = self.command.x_dot_m_s == 0.0
            && self.command.y_dot_m_s == 0.0
            && self.command.yaw_rate_rad_s == 0.0;
        commanded_zero
            && j.drive_rate_rad_s
                .iter()
                .all(|r| libm::fabs(*r) < self.config.stopped_wheel_rate_rad_s)
    }

    /// VO lost or off: the interval (already tested by the gate) is fused with a slip allowance
    /// (`vo_loss_slip_fraction` of the step on x, y and yaw), so that slip is not learnt as a
    /// heading error, and, since nothing else observes the vertical, with the ground vehicle's
    /// constraint that it does not move along its own z axis (1-sigma 20 % of the step plus
    /// 0.5 mm; H04 sec. 3 leaves it unobserved). Without VO slip is unobservable: fusing with
    /// the allowance keeps the EKF from running on the IMU alone. With
    /// [`NavConfig::vo_loss_translation_only`] the rotation is not fused: on slipping ground the
    /// wheels' yaw carries the yaw slip, while the gyro (with the sun for its bias) is far
    /// better over an interval.
    ///
    /// The travel fused this way is not verified: the horizontal position sigma grows by the
    /// whole step when the gate rejected it (the slip is unknown, up to 100 %) and by
    /// [`NavConfig::vo_loss_drift_fraction`] of it otherwise (`Ekf::inflate_position`), so that
    /// the position uncertainty honestly covers a rover that spins its wheels in place and
    /// fault protection can refuse an arrival it cannot support.
    ///
    /// `kept`: the interval's innovation from the gate ([`Ekf::gate_relative_pose_kept`]),
    /// fused with the allowance without computing `H P H'` again; without it (or when the
    /// filter changed since) the interval is fused from scratch.
    fn fuse_without_vo(
        &mut self,
        rp: &mut RelativePose,
        kept: Option<&crate::estimation::KeptRelativePose>,
        accepted: bool,
    ) {
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
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
        self.recorder.relative_pose(rp, false);
        let result = match kept {
            Some(k) => match ekf.fuse_kept_relative_pose(k, rp.observed, extra) {
                Err(EstError::StaleMeasurement) => ekf.update_relative_pose(rp, false).map(|_| ()),
                r => r,
            },
            None => ekf.update_relative_pose(rp, false).map(|_| ()),
        };
        if let Err(e) = result {
            self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
            self.ekf_error(e);
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
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
        let result = ekf.inflate_position(delta);
        self.recorder.inflate_position(delta);
        if let Err(e) = result {
            self.ekf_error(e);
        }
    }

    /// One kinematic interval of an IMU shock's grace ([`Navigator::imu_shock`]), gated (and,
    /// accepted, fused) on its translation: [`SHOCK_SETTLED_INTERVALS`] accepted in a row end
    /// the grace (the velocity is anchored again); a rejected one shows that the velocity is
    /// still wrong, by the residual's translation over the interval's duration, and the
    /// velocity covariance grows by that (at least [`NavConfig::streak_velocity_sigma_m_s`], at
    /// most 1 m/s) so that the next interval can correct it. A single accepted interval at the
    /// shock's inflated covariance may leave part of the error with a collapsed covariance
    /// (`rock-field-crawl` seed 1: 0.5 m/s left after five clipped samples, which the slip
    /// hold then kept for 2.5 s: 0.7 m of lateral error until VO pulled it back).
    fn shock_interval(&mut self, rp: &RelativePose, residual: &[f64], accepted: bool) {
        if accepted {
            self.shock_accepted = self.shock_accepted.saturating_add(1);
            if self.shock_accepted >= SHOCK_SETTLED_INTERVALS {
                self.shock_grace = 0;
                self.shock_accepted = 0;
            }
            return;
        }
        self.shock_accepted = 0;
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
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
        let result = ekf.inflate_velocity(v, 0.0);
        self.recorder.inflate_velocity(v, 0.0);
        if let Err(e) = result {
            self.ekf_error(e);
        }
    }

    /// A streak of [`NavConfig::reject_streak_cycles`] gate rejections in a row with no VO
    /// fused in between: either sustained slip or a filter whose velocity has drifted beyond
    /// what its covariance admits (an IMU worse than its configured noise), which would
    /// otherwise coast on the IMU for ever. The velocity covariance is inflated by the velocity
    /// error the last residual implies, `implied_velocity_m_s` (at least
    /// [`NavConfig::streak_velocity_sigma_m_s`], at most 1 m/s), and the accelerometer-bias
    /// covariance by that velocity over the streak's duration (at least
    /// [`NavConfig::streak_accel_bias_sigma_m_s2`], at most 0.5 m/s^2), so that the next
    /// kinematic interval can pull the filter back; counted in [`NavCounters::kin_streaks`].
    fn recover_from_streak(&mut self, implied_velocity_m_s: f64) {
        let Some(ekf) = self.ekf_running.then_some(&mut self.ekf) else {
            return;
        };
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
        let result = ekf.inflate_velocity(v, b);
        self.recorder.inflate_velocity(v, b);
        if let Err(e) = result {
            self.ekf_error(e);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slip_hold_needs_repeated_rejections_in_the_window() {
        let flight = NavConfig::rocky8([0.0; 3], 0.0);
        assert_eq!(flight.slip_hold_cycles, 20);
        assert_eq!(flight.slip_hold_rejections, 1);
        let config = NavConfig {
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
            &NavConfig {
                slip_hold_cycles: 0,
                ..old
            },
            u32::MAX
        ));
        let wide = NavConfig {
            slip_hold_cycles: 100,
            ..config
        };
        assert!(slip_holding(&wide, 0b111 << 29));
    }
}
