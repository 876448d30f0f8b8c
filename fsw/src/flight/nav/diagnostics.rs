//! Diagnostic trajectories, kept beside the estimator for the ground and the simulator's
//! comparisons; none of them feeds the EKF. One of them, the 3D kinematics, is also the
//! navigation pose of a rover driving without slip compensation (H05 Fig. 9 baseline).
//!
//! | trajectory | translation | attitude |
//! |---|---|---|
//! | `kin2d` | planar wheel odometry | planar wheel odometry |
//! | `kin3d` | contact-angle kinematics (V99 sec. 6), its heave from the track memory | EKF attitude at each interval start |
//! | `dr` | planar wheel odometry step in `R` | gyro integration from the aligned attitude, alignment bias (RB sec. 6 "dead reckoning") |
//! | `vo` | VO relative poses chained | VO relative poses chained |

use super::PoseEstimate;
use crate::kinematics::track::{tilt_step, TrackConfig, TrackMemory};
use crate::kinematics::{wheel_contact_points, RoverGeometry, SuspensionState};
use crate::types::{Quat, RelativePose, Vec3};
use rover_hal::{ImuSample, WHEEL_COUNT};

/// Longest IMU sample gap the gyro dead reckoning integrates across, us; a longer gap (or time
/// going backwards) skips that sample's rotation and counts it in [`Trajectories::dr_gaps`].
const DR_MAX_GAP_US: u64 = 50_000;

/// The diagnostic trajectories of the navigator (all in `N`, m, rotations `R` to `N`).
#[derive(Debug, Clone, Copy)]
pub struct Trajectories {
    /// 3D kinematics: the contact-angle translation (eq. 15 without it) rotated by the EKF
    /// attitude at each interval start, its vertical from the track memory.
    kin3d: PoseEstimate,
    /// The front axles' remembered paths for `kin3d`'s heave ([`crate::kinematics::track`]).
    track: TrackMemory,
    /// Planar wheel odometry `[north m, east m, yaw rad]`.
    kin2d: [f64; 3],
    /// Dead reckoning: gyro attitude with the wheel odometry step (RB's comparison baseline).
    dr: PoseEstimate,
    /// Gyro bias removed by the dead reckoning (the alignment's estimate, held), rad/s.
    dr_bias: Vec3,
    /// Time of the last gyro sample integrated into `dr`, us.
    dr_t_us: Option<u64>,
    /// Samples whose rotation the dead reckoning could not integrate (gap, non-finite).
    dr_gaps: u32,
    /// VO-only: VO relative poses chained from the EKF pose of the first keyframe.
    vo: Option<PoseEstimate>,
    /// The planar model's wheel contact points (m, `R`, zero suspension state), evaluated once
    /// at initialisation for [`Self::wheel_step`]'s increments; `None` if the geometry has none.
    nominal_points: Option<[Vec3; WHEEL_COUNT]>,
}

impl Trajectories {
    /// Placeholder at the origin, level, heading north (the compile-time value of a statically
    /// allocated navigator before its initialisation writes [`Self::new`]'s).
    pub const EMPTY: Self = Self {
        kin3d: PoseEstimate::EMPTY,
        track: TrackMemory::new(TrackConfig {
            enabled: false,
            spacing_m: 0.0,
            lateral_tolerance_m: 0.0,
            gain: 0.0,
            max_step_m: 0.0,
        }),
        kin2d: [0.0; 3],
        dr: PoseEstimate::EMPTY,
        dr_bias: crate::types::VEC3_ZERO,
        dr_t_us: None,
        dr_gaps: 0,
        vo: None,
        nominal_points: None,
    };

    /// All trajectories at `p0` (m, `N`) with heading `yaw0` (rad), the planar model on the
    /// contact points of `geometry`, the 3D kinematics' track memory tuned by `track`.
    pub fn new(p0: Vec3, yaw0: f64, geometry: &RoverGeometry, track: TrackConfig) -> Self {
        let q0 = Quat::from_euler_angles(0.0, 0.0, yaw0);
        let pose = PoseEstimate { p_n: p0, q_nr: q0 };
        Self {
            kin3d: pose,
            track: TrackMemory::new(track),
            kin2d: [p0.x, p0.y, yaw0],
            dr: pose,
            dr_bias: Vec3::zeros(),
            dr_t_us: None,
            dr_gaps: 0,
            vo: None,
            nominal_points: wheel_contact_points(geometry, &SuspensionState::default()).ok(),
        }
    }

    /// Restart the attitude-carrying trajectories at the aligned pose (after the alignment at
    /// rest): the 3D kinematics and the dead reckoning take the aligned attitude, the dead
    /// reckoning keeps the aligned gyro bias `b_g` (rad/s) for the rest of the drive.
    pub fn aligned(&mut self, pose: PoseEstimate, b_g: Vec3, t_us: u64) {
        self.kin3d = pose;
        self.track.reset();
        self.dr = pose;
        self.dr_bias = b_g;
        self.dr_t_us = Some(t_us);
        self.kin2d = [pose.p_n.x, pose.p_n.y, super::yaw_of(&pose.q_nr)];
    }

    /// RG1: one checked IMU sample rotates the dead-reckoning attitude (first order in the
    /// sample period, bias-corrected with the aligned bias).
    pub fn gyro(&mut self, s: &ImuSample) {
        let previous = self.dr_t_us.replace(s.t_us);
        let dt = previous.and_then(|p| s.t_us.checked_sub(p));
        let w = Vec3::new(
            s.gyro_rad_s[0] - self.dr_bias.x,
            s.gyro_rad_s[1] - self.dr_bias.y,
            s.gyro_rad_s[2] - self.dr_bias.z,
        );
        match dt {
            Some(dt) if dt <= DR_MAX_GAP_US && w.iter().all(|v| v.is_finite()) => {
                let step = Quat::from_scaled_axis(w * (dt as f64 * 1e-6));
                self.dr.q_nr = crate::estimation::state::renormalize(&(self.dr.q_nr * step));
            }
            _ => self.dr_gaps = self.dr_gaps.saturating_add(1),
        }
    }

    /// RG2: one planar wheel-odometry increment `[dx m, dy m, dyaw rad]` in `R` at the
    /// previous reading: `kin2d` integrates it with its own heading, the dead reckoning rotates
    /// the translation by its gyro attitude (mid-step yaw from the wheel increment).
    pub fn wheel_step(&mut self, step: [f64; 3]) {
        let [dx, dy, dyaw] = step;
        if !(dx.is_finite() && dy.is_finite() && dyaw.is_finite()) {
            return;
        }
        let yaw = self.kin2d[2] + 0.5 * dyaw;
        let (s, c) = (libm::sin(yaw), libm::cos(yaw));
        self.kin2d[0] += dx * c - dy * s;
        self.kin2d[1] += dx * s + dy * c;
        self.kin2d[2] = crate::guidance::wrap_pi(self.kin2d[2] + dyaw);
        self.dr.p_n += self.dr.q_nr.transform_vector(&Vec3::new(dx, dy, 0.0));
    }

    /// RG2: the kinematic interval's translation `trans_0_1_m` (m, `R` at its start: the
    /// contact-angle estimator's, V99 sec. 6, or eq. 15's) rotated by the EKF attitude `q0` of
    /// the start; the attitude becomes the EKF's current `q_now`. With the track memory on
    /// ([`TrackConfig::enabled`]) and `axles_r_m` (the axle centres of the interval's last
    /// step, m, `R`), the step's vertical moves towards the height of the ground the front
    /// wheels already rolled over, at the step's 3D length ([`tilt_step`]); the front axles
    /// then extend the remembered paths.
    pub fn kinematic_step(
        &mut self,
        q0: &Quat,
        trans_0_1_m: &Vec3,
        q_now: &Quat,
        axles_r_m: Option<&[Vec3; WHEEL_COUNT]>,
    ) {
        let mut t = q0.to_rotation_matrix() * trans_0_1_m;
        let r_now = q_now.to_rotation_matrix().into_inner();
        if let Some(axles) = axles_r_m {
            let predicted = self.kin3d.p_n + t;
            if let Some(dz) = self.track.correction(&predicted, &r_now, axles) {
                t = tilt_step(&t, dz);
            }
        }
        self.kin3d.p_n += t;
        self.kin3d.q_nr = *q_now;
        if let Some(axles) = axles_r_m {
            self.track.record(&self.kin3d.p_n, &r_now, axles);
        }
    }

    /// 3D kinematics: the contact-angle translation rotated by the EKF attitude at each
    /// interval start, its vertical from the track memory (`N`).
    pub fn kin3d(&self) -> PoseEstimate {
        self.kin3d
    }

    /// Planar wheel odometry `[north m, east m, yaw rad]`.
    pub fn kin2d(&self) -> [f64; 3] {
        self.kin2d
    }

    /// Dead reckoning: gyro attitude with the wheel odometry step (`N`).
    pub fn dead_reckoning(&self) -> PoseEstimate {
        self.dr
    }

    /// The VO-only pose, once started.
    pub fn vo(&self) -> Option<PoseEstimate> {
        self.vo
    }

    /// Steps of the 3D dead reckoning whose vertical the track memory corrected, and steps
    /// without a match.
    pub fn track_steps(&self) -> (u32, u32) {
        (self.track.matched_steps, self.track.unmatched_steps)
    }

    /// The planar model's wheel contact points (zero suspension state, m, `R`).
    pub fn nominal_points(&self) -> Option<&[Vec3; WHEEL_COUNT]> {
        self.nominal_points.as_ref()
    }

    /// True once the VO-only trajectory has started.
    pub fn vo_started(&self) -> bool {
        self.vo.is_some()
    }

    /// VO made a new keyframe without a previous one (start, or after an outage): the VO-only
    /// trajectory is anchored again at the next VO pose.
    pub fn vo_restart(&mut self) {
        self.vo = None;
    }

    /// Background: a VO relative pose between two keyframes; `anchor` is the EKF pose of its
    /// first keyframe, used when the VO-only trajectory starts (or restarts after an outage).
    pub fn vo_step(&mut self, anchor: Option<PoseEstimate>, rp: &RelativePose) {
        if self.vo.is_none() {
            self.vo = anchor;
        }
        if let Some(v) = self.vo.as_mut() {
            v.p_n += v.q_nr.transform_vector(&rp.trans_0_1_m);
            v.q_nr = crate::estimation::state::renormalize(&(v.q_nr * rp.rot_0_1));
        }
    }
}
