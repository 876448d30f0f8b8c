//! # KinAiding: the kinematic interval, its slip gate and the gate policy (RG2)
//!
//! Each RG2 joint reading extends the **kinematic interval** (H04 eq. 15 forward kinematics,
//! [`KinematicOdometry`]), which starts at an EKF clone and ends at the current state. The
//! interval's 5-dof [`RelativePose`] (radius scale applied) is tested by the **Mahalanobis
//! gate** (eq. 46) at the odometry's own covariance:
//!
//! - with VO alive, an accepted interval is fused by the same call (eq. 28-45), unless a **slip
//!   hold** is in progress ([`KinAidingConfig::slip_hold_cycles`]); its lateral translation
//!   carries the **crab allowance** ([`KinAidingConfig::crab_allowance`]);
//! - a rejected interval is **slip**: the slip vector is EKF minus kinematics (minus the
//!   residual), the input of the slip-compensating guidance (H04 sec. 5);
//! - without VO (off, or none fused for [`VoHealth::timeout_cycles`]) the tested interval is
//!   fused with a slip allowance and the vertical constraint ([`policy`]), or, in the
//!   stop-and-go drive while a recent stop anchors the IMU velocity, not fused at all;
//! - the intervals of an **IMU shock's grace** ([`KinAiding::imu_shock`]) are gated and fused
//!   on their translation with the vertical constraint; their rejections are not slip;
//! - a **streak** of rejections with no VO fused inflates the velocity covariance.
//!
//! A stop of the rover (zero command, wheels still) makes the next RG2B's **zero-velocity
//! update** due ([`KinAiding::zero_velocity_cycle`]). The component also keeps the EKF's
//! **wheel-radius scale** ([`RadiusScale`]) and feeds the [`Calibration`] and the diagnostic
//! dead reckoning ([`Trajectories`]).
//!
//! The reasons and measured effects of the policy's rules are in the design notes
//! (`docs/notes/`): notes 0016 (slip hold), 0017 (crab allowance), 0022 (shock grace), 0023
//! (fusion without VO), 0024 (stop-and-go).

mod policy;
mod types;

use policy::{slip_holding, vertical_constraint_variance};
pub use policy::{BLIND_SKID_FACTOR, BLIND_SKID_FLOOR_M, KIN_CRAB_ALLOWANCE};
pub use types::{KinAidingConfig, KinCounters, KinInputs, KinOutcome, Travel, VoHealth};

use super::calibration::Calibration;
use super::diagnostics::Trajectories;
use super::filter::NavFilter;
use super::radius::RadiusScale;
use super::status::GateStatus;
use crate::estimation::{CloneHandle, GateDecision, KeptRelativePose};
use crate::guidance::SlipVector;
use crate::kinematics::planar::planar_pose_increment_at;
use crate::kinematics::{
    planar_pose_increment, KinematicOdometry, KinematicsError, RoverGeometry, VehicleCommand,
};
use crate::types::{Quat, RelativePose, Vec3};
use rover_hal::{ImuSample, JointState, WHEEL_COUNT};

/// The kinematic aiding component.
pub struct KinAiding {
    config: KinAidingConfig,
    odometry: KinematicOdometry,
    interval: Option<CloneHandle>,
    last_joints: Option<JointState>,
    /// Body rotation since the last joint reading the odometry took, integrated from the
    /// bias-corrected gyro samples (the gyro input of the contact-angle estimator, V99 sec. 6);
    /// `None` until an interval has started or after a gap in the IMU samples.
    gyro_since_joints: Option<Quat>,
    /// Time stamp of the last IMU sample integrated into `gyro_since_joints`, us.
    gyro_t_us: Option<u64>,
    /// RG2 cycles without a checked joint reading.
    missing_cycles: u32,
    /// Gate verdicts of the last 32 tested intervals, newest in bit 0 (1: rejected).
    reject_history: u32,
    /// Gate rejections in a row with no VO fused meanwhile.
    reject_streak: u32,
    /// Kinematic intervals still to come that may carry an IMU shock's velocity error: their
    /// rejections are not slip (no hold, not in `reject_history`).
    shock_grace: u8,
    /// Intervals of the shock's grace accepted in a row.
    shock_accepted: u8,
    /// RG2 cycles since the last zero-velocity update.
    cycles_since_zupt: u32,
    /// The last kinematic cycle saw a stop: [`Self::zero_velocity_cycle`] applies its ZUPT.
    zupt_due: bool,
    radius_scale: RadiusScale,
    slip: SlipVector,
    gate: GateStatus,
    counters: KinCounters,
}

impl KinAiding {
    /// Placeholder (the compile-time value of a static navigator before its initialisation).
    pub const EMPTY: Self = Self {
        config: policy::EMPTY_CONFIG,
        odometry: KinematicOdometry::new(crate::kinematics::ROCKY8, policy::EMPTY_CONFIG.odometry),
        interval: None,
        last_joints: None,
        gyro_since_joints: None,
        gyro_t_us: None,
        missing_cycles: 0,
        reject_history: 0,
        reject_streak: 0,
        shock_grace: 0,
        shock_accepted: 0,
        cycles_since_zupt: u32::MAX,
        zupt_due: false,
        radius_scale: RadiusScale::new(),
        slip: SlipVector {
            x_m: 0.0,
            y_m: 0.0,
            phi_rad: 0.0,
        },
        gate: GateStatus::EMPTY,
        counters: policy::NO_COUNTERS,
    };

    /// Rewrites the component for a new drive with `config` on `geometry`: no interval, no
    /// joints seen, nothing learnt.
    pub fn init(&mut self, config: &KinAidingConfig, geometry: &RoverGeometry) {
        self.config = *config;
        self.odometry = KinematicOdometry::new(*geometry, config.odometry);
        self.interval = None;
        self.last_joints = None;
        self.gyro_since_joints = None;
        self.gyro_t_us = None;
        self.missing_cycles = 0;
        self.reject_history = 0;
        self.reject_streak = 0;
        self.shock_grace = 0;
        self.shock_accepted = 0;
        self.cycles_since_zupt = u32::MAX;
        self.zupt_due = false;
        self.radius_scale = RadiusScale::new();
        self.slip = SlipVector::default();
        self.gate = GateStatus::default();
        self.counters = KinCounters::default();
    }

    /// Counters.
    pub fn counters(&self) -> KinCounters {
        self.counters
    }

    /// The slip vector of the last RG2 cycle (EKF minus kinematics, rover frame; zero when the
    /// gate accepted the kinematics).
    pub fn slip(&self) -> SlipVector {
        self.slip
    }

    /// The gate result of the last kinematic interval.
    pub fn gate(&self) -> GateStatus {
        self.gate
    }

    /// The last checked joint reading.
    pub fn last_joints(&self) -> Option<JointState> {
        self.last_joints
    }

    /// RG2 cycles since the last checked joint reading (fault protection's sensor hold).
    pub fn joint_gap_cycles(&self) -> u32 {
        self.missing_cycles
    }

    /// The effective wheel-radius scale applied to the kinematic translation (1 = nominal).
    pub fn radius_scale(&self) -> f64 {
        self.radius_scale.scale
    }

    /// The contact angles estimated over windows of travel (rad, relative to the six wheels'
    /// mean; [`KinematicOdometry::windowed_contact_angles_rad`]), for the rough-terrain inverse
    /// kinematics.
    pub fn windowed_contact_angles_rad(&self) -> [f64; WHEEL_COUNT] {
        self.odometry.windowed_contact_angles_rad()
    }

    /// The rover stood at rest during the alignment: its velocity counts as anchored, as after
    /// a zero-velocity update (the stop-and-go drive without VO starts anchored).
    pub fn anchor_at_rest(&mut self) {
        self.cycles_since_zupt = 0;
    }

    /// A VO update was fused: the streak of gate rejections without VO ends.
    pub fn vo_fused(&mut self) {
        self.reject_streak = 0;
    }

    /// The IMU's time base changed ([`NavFilter::rebase`]): the interval and the gyro integral
    /// belong to the old time base and are dropped.
    pub fn rebase(&mut self) {
        self.interval = None;
        self.gyro_since_joints = None;
        self.gyro_t_us = None;
    }

    /// RG1, after the filter propagated `s`: adds the sample's rotation, corrected by the
    /// filter's gyro bias `b_g` (rad/s), to the rotation since the last joint reading (the
    /// contact-angle estimator's gyro input; only when the odometry uses the contact angles).
    /// A sample that does not follow the previous one by 0 to 50 ms (a gap, time going
    /// backwards) or is not finite drops the integral: the next joint step then has no gyro
    /// input and the estimator uses the contacts alone.
    pub fn gyro(&mut self, s: &ImuSample, b_g: &Vec3) {
        let odometry = &self.config.odometry;
        if !(odometry.contact_angles || odometry.contact_translation) {
            return;
        }
        let previous = self.gyro_t_us.replace(s.t_us);
        let dt_us = previous.and_then(|p| s.t_us.checked_sub(p));
        let w = Vec3::new(
            s.gyro_rad_s[0] - b_g.x,
            s.gyro_rad_s[1] - b_g.y,
            s.gyro_rad_s[2] - b_g.z,
        );
        match (self.gyro_since_joints, dt_us) {
            (Some(q), Some(dt)) if dt <= 50_000 && w.iter().all(|v| v.is_finite()) => {
                let step = Quat::from_scaled_axis(w * (dt as f64 * 1e-6));
                self.gyro_since_joints = Some(q * step);
            }
            _ => self.gyro_since_joints = None,
        }
    }

    /// An IMU shock: an accelerometer sample saturated at the sensor's range or refused beyond
    /// it. A clipped or missing sample leaves up to the range times the sample period
    /// (0.88 m/s for 18 g0 over 5 ms) in the velocity, which the kinematic gate would read as
    /// slip and refuse to correct. The velocity variances grow by `velocity_sigma_m_s^2` (m/s;
    /// recorded for the late-VO replay) so that the next kinematic interval or VO pose
    /// re-anchors the velocity; the intervals that follow are in the shock's grace (at most
    /// [`policy::SHOCK_GRACE_INTERVALS`], until [`policy::SHOCK_SETTLED_INTERVALS`] in a row
    /// are accepted): gated at that covariance without a slip hold (a hold in progress ends),
    /// their rejections not counted as slip. Counted in [`KinCounters::imu_shocks`]. Why:
    /// note 0022.
    pub fn imu_shock(&mut self, velocity_sigma_m_s: f64, filter: &mut NavFilter) {
        self.counters.imu_shocks = self.counters.imu_shocks.saturating_add(1);
        self.shock_grace = policy::SHOCK_GRACE_INTERVALS;
        self.shock_accepted = 0;
        self.reject_history = 0;
        self.reject_streak = 0;
        if !filter.is_running() {
            return;
        }
        if !(velocity_sigma_m_s.is_finite() && velocity_sigma_m_s > 0.0) {
            return;
        }
        filter.inflate_velocity(velocity_sigma_m_s, 0.0);
    }

    /// RG2: one checked joint reading (`None`: none this cycle). The wheel step of the diagnostic
    /// planar odometry; then, with the filter running, the kinematic interval: closed at the
    /// filter's current time, gated and fused or turned into the slip vector (module doc), the
    /// dead reckoning and the calibration fed, a stop's zero-velocity update made due, and the
    /// next interval started at a new clone.
    #[inline(never)]
    pub fn cycle(
        &mut self,
        joints: Option<&JointState>,
        inputs: &KinInputs,
        geometry: &RoverGeometry,
        filter: &mut NavFilter,
        diag: &mut Trajectories,
        cal: &mut Calibration,
    ) -> KinOutcome {
        let mut outcome = KinOutcome::default();
        let Some(j) = joints else {
            self.missing_cycles = self.missing_cycles.saturating_add(1);
            return outcome;
        };
        self.missing_cycles = 0;
        let previous = self.last_joints.replace(*j);
        if let Some(prev) = previous {
            let step = match diag.nominal_points() {
                Some(points) => planar_pose_increment_at(geometry, points, &prev, j),
                None => planar_pose_increment(geometry, &prev, j),
            };
            if let Ok(step) = step {
                diag.wheel_step(step);
            }
        }
        let Some(t_us) = filter.running().map(|e| e.time_us()) else {
            return outcome;
        };
        let Some(start) = self.interval else {
            self.restart_interval(j, t_us, filter, cal);
            return outcome;
        };
        let (mut rp, contact_translation) = match self.measure(j) {
            Ok(p) => p,
            Err(KinematicsError::TimeNotAdvancing) => return outcome,
            Err(_) => {
                self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
                cal.interrupt();
                filter.release(Some(start));
                self.interval = None;
                self.restart_interval(j, t_us, filter, cal);
                return outcome;
            }
        };
        if start.t_us() == t_us {
            // No IMU time has passed: keep the interval open.
            return outcome;
        }
        // The interval is labelled with the EKF times of its ends (the joint reading and the
        // IMU sample of a frame carry the same time stamp on this rover).
        rp.t0_us = start.t_us();
        rp.t1_us = t_us;
        let steps = self.dead_reckoning(
            &mut rp,
            start,
            &contact_translation,
            inputs,
            filter,
            diag,
            cal,
        );
        outcome.travel = steps.travel;
        outcome.closed = true;
        self.test_and_fuse(&mut rp, &steps, inputs, filter, cal);
        // A stop's zero-velocity update is due; [`Self::zero_velocity_cycle`] applies it half an
        // RG2 period later (group RG2B), so that the two EKF updates of a stop never share a
        // release (the RG2 release budget of 100,000 instructions, `docs/results/timing.md`).
        if is_stopped(&self.config, &inputs.command, j) {
            self.zupt_due = true;
        } else {
            self.zupt_due = false;
            self.cycles_since_zupt = self.cycles_since_zupt.saturating_add(1);
        }
        filter.release(Some(start));
        self.interval = None;
        if let Some(result) = filter.clone_recorded(t_us) {
            match result {
                Ok(h) => self.interval = Some(h),
                Err(_) => self.counters.kin_errors = self.counters.kin_errors.saturating_add(1),
            }
        }
        outcome
    }

    /// The odometry step of joint reading `j` with the gyro rotation since the last reading
    /// (in `R` at the step start), and the interval it closes: eq. 15's relative pose and the
    /// contact-angle translation of the 3D dead reckoning (m, `R` at the interval start).
    #[inline(never)]
    fn measure(&mut self, j: &JointState) -> Result<(RelativePose, Vec3), KinematicsError> {
        let gyro = self
            .gyro_since_joints
            .replace(Quat::identity())
            .map(|q| crate::estimation::state::log_quat(&q));
        self.odometry.update_with_gyro(j, gyro)?;
        let contact_translation = self.odometry.contact_translation_m();
        self.odometry.take().map(|rp| (rp, contact_translation))
    }

    /// The closed interval `rp` (labelled with its clone `start` and the filter's time) on the
    /// filter's poses: the wheel-radius scale applied to its translation and covariance, the
    /// dead reckoning's step (the contact-angle translation rotated by the EKF attitude at the
    /// interval start, scaled by the calibration's dead-reckoning scale), and the travel of the
    /// interval for fault protection.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn dead_reckoning(
        &mut self,
        rp: &mut RelativePose,
        start: CloneHandle,
        contact_translation: &Vec3,
        inputs: &KinInputs,
        filter: &NavFilter,
        diag: &mut Trajectories,
        cal: &Calibration,
    ) -> IntervalSteps {
        let mut steps = IntervalSteps {
            wheel_m: rp.trans_0_1_m.norm(),
            ekf_m: None,
            dr_step_n: None,
            travel: None,
        };
        let Some(ekf) = filter.running() else {
            return steps;
        };
        // The contact-angle step of the 3D dead reckoning in `N` (unscaled), for its own scale.
        steps.dr_step_n = ekf
            .clone_pose(start)
            .ok()
            .map(|(q0, _)| q0.transform_vector(contact_translation));
        steps.ekf_m = ekf
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
            let k3 = cal.dr_scale().0;
            diag.kinematic_step(
                &q0,
                &(contact_translation * k3),
                &ekf.state().q_nr,
                axles.as_ref(),
            );
            if let Ok((_, p0)) = ekf.clone_pose(start) {
                let ekf_step = (ekf.state().p_n - p0).norm();
                // Without VO the EKF travel is measured too while the stop-and-go drive
                // anchors the IMU velocity (its slip estimate is the IMU's, eq. 46).
                let imu_anchored = inputs.stop_and_go
                    && inputs.vo.lost()
                    && self.cycles_since_zupt <= self.config.blind_anchor_cycles;
                steps.travel = Some(Travel {
                    wheel_m: rp.trans_0_1_m.norm(),
                    ekf_m: ekf_step,
                    imu_anchored,
                });
            }
        }
        steps
    }

    /// The gate test of the closed interval `rp` (eq. 46) and the policy that follows (module
    /// doc): fusion, hold, shock grace, slip vector, fusion without VO, streak recovery.
    #[inline(never)]
    fn test_and_fuse(
        &mut self,
        rp: &mut RelativePose,
        steps: &IntervalSteps,
        inputs: &KinInputs,
        filter: &mut NavFilter,
        cal: &mut Calibration,
    ) {
        // VO's timeout counts this cycle (the navigator adds it to VO's health afterwards).
        let cycles_since_vo = inputs.vo.cycles_since_fused.saturating_add(1);
        let vo_lost = !inputs.vo.enabled || cycles_since_vo > inputs.vo.timeout_cycles;
        // Intervals that may carry an IMU shock's velocity error: no hold, and a rejection is
        // not slip but the velocity still wrong (below).
        let shock = self.shock_grace > 0;
        self.shock_grace = self.shock_grace.saturating_sub(1);
        let holding = slip_holding(&self.config, self.reject_history) && !shock;
        if shock {
            // A shock is the accelerometer's: its error is in the velocity, in all three axes,
            // and with VO alive nothing else observes the vertical between captures. The
            // intervals of its grace are gated and fused on their translation only (the gyro
            // is unaffected) and with the ground vehicle's vertical constraint, so that the
            // accepted ones re-anchor the whole velocity. Without VO the fusion without VO adds
            // the vertical constraint itself.
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
        // interval is tested here and then fused with the slip allowance.
        let fusing = !(vo_lost || holding);
        let Some(gated) = gate_interval(rp, fusing, self.config.crab_allowance, filter) else {
            return;
        };
        let usable = fusing && gated.result.as_ref().is_ok_and(|d| d.accepted);
        cal.kinematic(rp, usable, gated.cross, steps.dr_step_n);
        match gated.result {
            Ok(d) => {
                let verdict = Verdict {
                    cycles_since_vo,
                    vo_lost,
                    shock,
                    holding,
                    stop_and_go: inputs.stop_and_go,
                };
                self.verdict(&d, rp, gated.kept.as_ref(), steps, &verdict, filter);
            }
            Err(e) => {
                self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
                filter.error(e);
            }
        }
    }

    /// The gate's decision `d` on the interval `rp`: counters, gate status, radius scale, shock
    /// grace, slip history and vector, and the policy without VO or after a streak.
    fn verdict(
        &mut self,
        d: &GateDecision,
        rp: &mut RelativePose,
        kept: Option<&KeptRelativePose>,
        steps: &IntervalSteps,
        v: &Verdict,
        filter: &mut NavFilter,
    ) {
        self.counters.kin_tested = self.counters.kin_tested.saturating_add(1);
        self.gate = GateStatus::of(d);
        if let Some(e) = steps.ekf_m {
            // Learn only from intervals the gate accepted while VO anchors the EKF.
            let anchored = v.cycles_since_vo <= self.config.radius_scale.vo_recent_cycles;
            self.radius_scale.add(
                &self.config.radius_scale,
                steps.wheel_m,
                e,
                d.accepted && anchored,
            );
        }
        let slip = !d.accepted && !v.shock;
        if v.shock {
            self.shock_interval(rp, d.residual.as_slice(), d.accepted, filter);
        }
        self.reject_history = (self.reject_history << 1) | u32::from(slip);
        if d.accepted {
            self.reject_streak = 0;
            // H04: no slip when the kinematics agrees with the estimate.
            self.slip = SlipVector::default();
            if v.holding && !v.vo_lost {
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
        // The IMU may carry the motion only while a recent stop anchors its velocity and while
        // its motion is one the wheels allow: a driving rover slips, so its ground travel is at
        // most the wheels' (plus a skid margin); an EKF step longer than that is an IMU error
        // (a shock, a dropped sample), and the kinematics is fused instead.
        let kin_step = crate::linalg::sqrt(
            rp.trans_0_1_m.x * rp.trans_0_1_m.x + rp.trans_0_1_m.y * rp.trans_0_1_m.y,
        );
        let (ex, ey) = (
            rp.trans_0_1_m.x - d.residual[3],
            rp.trans_0_1_m.y - d.residual[4],
        );
        let ekf_step_h = crate::linalg::sqrt(ex * ex + ey * ey);
        let plausible = ekf_step_h <= BLIND_SKID_FACTOR * kin_step + BLIND_SKID_FLOOR_M;
        let anchored_by_zupt =
            v.stop_and_go && self.cycles_since_zupt <= self.config.blind_anchor_cycles && plausible;
        if v.vo_lost && anchored_by_zupt {
            // Stop-and-go without VO: the IMU velocity, anchored by the last stop, carries the
            // motion; the slip vector above measures the kinematics against it. An interval
            // the gate accepts is not fused either: a slip below the gate's resolution (the
            // first centimetres after a start) would otherwise be learnt as an accelerometer
            // bias, which the IMU then carries into the whole segment.
            self.counters.kin_imu_carried = self.counters.kin_imu_carried.saturating_add(1);
        } else if v.vo_lost {
            self.fuse_without_vo(rp, kept, d.accepted, filter);
        } else if self.reject_streak >= self.config.reject_streak_cycles {
            // The velocity error the last residual implies (translation residual over the
            // interval's duration).
            let dt_s = rp.t1_us.saturating_sub(rp.t0_us) as f64 * 1e-6;
            let r =
                crate::linalg::sqrt(d.residual[3] * d.residual[3] + d.residual[4] * d.residual[4]);
            let implied = if dt_s > 0.0 { r / dt_s } else { 0.0 };
            self.recover_from_streak(implied, filter);
        }
    }

    /// RG2B, half an RG2 period after [`Self::cycle`]: the zero-velocity update (`v_N = 0`,
    /// [`crate::estimation::Ekf::update_zero_velocity`], at the filter's current time) of the
    /// stop the last kinematic cycle saw (its joint reading within
    /// [`KinAidingConfig::stopped_wheel_rate_rad_s`] with a zero command). It is applied only
    /// while `command` (the rover command now) is still zero: guidance may have started a drive
    /// in the meantime, and then the cycle counts as one without a stop. Nothing is due after a
    /// cycle without a joint reading, an odometry error or a cycle that kept its interval open.
    pub fn zero_velocity_cycle(&mut self, command: &VehicleCommand, filter: &mut NavFilter) {
        if !core::mem::take(&mut self.zupt_due) {
            return;
        }
        let still =
            command.x_dot_m_s == 0.0 && command.y_dot_m_s == 0.0 && command.yaw_rate_rad_s == 0.0;
        if !still {
            self.cycles_since_zupt = self.cycles_since_zupt.saturating_add(1);
            return;
        }
        if filter.zero_velocity() == Some(true) {
            self.counters.zupts = self.counters.zupts.saturating_add(1);
            self.cycles_since_zupt = 0;
        }
    }

    fn restart_interval(
        &mut self,
        j: &JointState,
        t_us: u64,
        filter: &mut NavFilter,
        cal: &mut Calibration,
    ) {
        if !filter.is_running() {
            return;
        }
        if self.odometry.start(j).is_err() {
            self.counters.kin_errors = self.counters.kin_errors.saturating_add(1);
            return;
        }
        self.gyro_since_joints = Some(Quat::identity());
        cal.interrupt();
        match filter.clone_recorded(t_us) {
            Some(Ok(h)) => self.interval = Some(h),
            Some(Err(_)) => self.counters.kin_errors = self.counters.kin_errors.saturating_add(1),
            None => {}
        }
    }
}

/// The closed interval's lengths and steps on the filter's poses.
#[derive(Debug, Clone, Copy)]
struct IntervalSteps {
    /// Wheel travel as the EKF measured it, before the radius scale, m.
    wheel_m: f64,
    /// EKF travel over the interval, m (`None`: the start clone is gone).
    ekf_m: Option<f64>,
    /// The dead reckoning's unscaled step in `N`, m.
    dr_step_n: Option<Vec3>,
    /// The travel for fault protection.
    travel: Option<Travel>,
}

/// The state a gate decision is judged in.
#[derive(Debug, Clone, Copy)]
struct Verdict {
    /// RG2 cycles since the last fused VO update, this one counted.
    cycles_since_vo: u32,
    vo_lost: bool,
    shock: bool,
    holding: bool,
    stop_and_go: bool,
}

/// The gate test of a closed interval on the live filter.
struct Gated {
    /// Cross-slope component of gravity in `R` (`|sin|` of the cross slope).
    cross: f64,
    result: Result<GateDecision, crate::estimation::EstError>,
    /// The interval's innovation when it was tested without fusion.
    kept: Option<KeptRelativePose>,
}

/// The gate test (eq. 46) of `rp` on the live filter: with `fusing` the accepted interval is
/// fused at once with the crab allowance on its lateral translation (and recorded); otherwise
/// it is tested and its innovation kept. `None` when the filter does not run.
#[inline(never)]
fn gate_interval(
    rp: &RelativePose,
    fusing: bool,
    crab_allowance: f64,
    filter: &mut NavFilter,
) -> Option<Gated> {
    let ekf = filter.live()?;
    // Cross-slope component of gravity in R (sin of the cross slope).
    let cross = libm::fabs(ekf.state().q_nr.inverse_transform_vector(&Vec3::z()).y);
    let crab = {
        let a = crab_allowance * cross * rp.trans_0_1_m.norm();
        if a.is_finite() {
            a * a
        } else {
            f64::INFINITY
        }
    };
    let allowance = [0.0, 0.0, 0.0, 0.0, crab, 0.0];
    // The interval as fused: the crab allowance added to its lateral variance.
    let mut fused = *rp;
    if crab.is_finite() {
        if let Some(v) = fused.covariance.get_mut((4, 4)) {
            *v += crab;
        }
    } else if let Some(o) = fused.observed.get_mut(4) {
        *o = false;
    }
    // Without fusion the gate keeps the interval's innovation, so that the fusion without VO
    // does not compute it again.
    let mut kept = None;
    let result = if fusing {
        ekf.update_relative_pose_allowance(rp, allowance)
    } else {
        ekf.gate_relative_pose_kept(rp).map(|(d, k)| {
            kept = Some(k);
            d
        })
    };
    // The recorder (late VO replay) keeps the interval only when the live filter fused it: a
    // replay on the VO-corrected filter gates it again, but never fuses an interval the live
    // gate rejected as slip (a rejected gated update left the filter unchanged).
    if fusing && result.as_ref().is_ok_and(|d| d.applied) {
        filter.record_relative_pose(&fused);
    }
    Some(Gated {
        cross,
        result,
        kept,
    })
}

/// The rover stands: a zero `command` and every measured wheel rate of `j` below the
/// configuration's threshold.
fn is_stopped(config: &KinAidingConfig, command: &VehicleCommand, j: &JointState) -> bool {
    let commanded_zero =
        command.x_dot_m_s == 0.0 && command.y_dot_m_s == 0.0 && command.yaw_rate_rad_s == 0.0;
    commanded_zero
        && j.drive_rate_rad_s
            .iter()
            .all(|r| libm::fabs(*r) < config.stopped_wheel_rate_rad_s)
}
