//! Trajectories that isolate one component of the flight navigation, computed on the host
//! beside the run (none of them feeds the flight software):
//!
//! - [`Eq15Odometry`]: H04 eq. 15 forward kinematics alone, on the joint encoder readings the
//!   simulator delivers, integrated with its own attitude (the eq. 15 angular rates): no IMU, no
//!   VO, no sun sensor, no learnt wheel-radius scale, no contact-angle estimate. It starts from
//!   the true pose at the start (as the flight software's start pose does).
//! - [`VoRawChain`]: the VO pipeline's relative poses chained as they come out of the
//!   pipeline, before the boresight correction and without the EKF's anchor; a relative pose
//!   whose first capture is not a chained pose (a failed update in between) is bridged with
//!   the true motion over the gap, and the gap is counted.

use crate::vehicle::placement::BodyPose;
use nalgebra::{UnitQuaternion, Vector3};
use std::collections::VecDeque;

/// A pose in `W`: position (north, east, down, m) and attitude `R` to `W`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position, m.
    pub pos_m: Vector3<f64>,
    /// Attitude `R` to `W`.
    pub rot: UnitQuaternion<f64>,
}

impl Pose {
    /// The true pose of the body.
    pub fn of_body(p: &BodyPose) -> Self {
        Self {
            pos_m: Vector3::from(p.pos_m),
            rot: UnitQuaternion::from_rotation_matrix(&p.rot_w_from_r()),
        }
    }

    /// `self` followed by the relative motion `(t, q)` expressed in `self`'s body frame.
    pub fn then(&self, t: &Vector3<f64>, q: &UnitQuaternion<f64>) -> Self {
        Self {
            pos_m: self.pos_m + self.rot * t,
            rot: self.rot * q,
        }
    }

    /// The motion from `self` to `other` in `self`'s body frame.
    pub fn to(&self, other: &Pose) -> (Vector3<f64>, UnitQuaternion<f64>) {
        (
            self.rot.inverse() * (other.pos_m - self.pos_m),
            self.rot.inverse() * other.rot,
        )
    }

    /// As the records store poses: position and quaternion `[x, y, z, w]`.
    pub fn arrays(&self) -> ([f64; 3], [f64; 4]) {
        let q = self.rot.quaternion();
        (
            [self.pos_m.x, self.pos_m.y, self.pos_m.z],
            [q.i, q.j, q.k, q.w],
        )
    }
}

/// H04 eq. 15 odometry on the encoder readings (module docs).
#[derive(Debug, Clone)]
pub struct Eq15Odometry {
    pose: Option<Pose>,
    last: Option<rover_hal::JointState>,
    /// Readings whose eq. 15 solve was refused (non-finite, out of range, fewer than three
    /// wheels): the pose holds over them.
    pub refused: u32,
}

impl Eq15Odometry {
    /// Not started.
    pub fn new() -> Self {
        Self {
            pose: None,
            last: None,
            refused: 0,
        }
    }

    /// The pose so far (`None` before the first reading).
    pub fn pose(&self) -> Option<Pose> {
        self.pose
    }

    /// A new encoder reading `j` with the true pose `truth` (used only for the first reading).
    /// The suspension rates are the angle increments over the interval, the drive rates the
    /// drive-angle increments over it (the encoders count angle); the body rates of eq. 15 are
    /// integrated over the interval with the attitude at its middle.
    pub fn update(&mut self, j: &rover_hal::JointState, truth: &BodyPose) {
        let (Some(last), Some(pose)) = (self.last, self.pose) else {
            self.pose = Some(Pose::of_body(truth));
            self.last = Some(*j);
            return;
        };
        if j.t_us <= last.t_us {
            return;
        }
        let dt = (j.t_us - last.t_us) as f64 * 1e-6;
        let rates = fsw::kinematics::SuspensionRates {
            rocker_rad_s: (j.rocker_rad - last.rocker_rad) / dt,
            bogie_rad_s: [
                (j.bogie_rad[0] - last.bogie_rad[0]) / dt,
                (j.bogie_rad[1] - last.bogie_rad[1]) / dt,
            ],
        };
        let drive: [f64; rover_hal::WHEEL_COUNT] =
            std::array::from_fn(|i| (j.drive_angle_rad[i] - last.drive_angle_rad[i]) / dt);
        let mut joints = *j;
        joints.drive_rate_rad_s = drive;
        self.last = Some(*j);
        match fsw::kinematics::forward_kinematics_from_joints(
            &fsw::kinematics::ROCKY8,
            &joints,
            &rates,
        ) {
            Ok(s) => {
                let b = s.body_rates;
                let v = Vector3::new(b[0], b[1], b[2]);
                let w = Vector3::new(b[3], b[4], b[5]);
                let half = UnitQuaternion::from_scaled_axis(w * (0.5 * dt));
                let mid = pose.rot * half;
                self.pose = Some(Pose {
                    pos_m: pose.pos_m + mid * (v * dt),
                    rot: mid * half,
                });
            }
            Err(_) => self.refused += 1,
        }
    }
}

impl Default for Eq15Odometry {
    fn default() -> Self {
        Self::new()
    }
}

/// The raw VO chain (module docs).
#[derive(Debug, Clone, Default)]
pub struct VoRawChain {
    /// Chained poses at the capture times of the last relative poses (keyframes among them).
    poses: VecDeque<(u64, Pose)>,
    /// Relative poses whose first capture was not chained (bridged with the true motion).
    pub gaps: u32,
}

impl VoRawChain {
    /// Chain the relative pose from the capture at `t0_us` to the one at `t1_us` (translation
    /// `t` m and rotation `q`, in the body frame at `t0`); `truth_at` gives the true pose at a
    /// capture time. Returns the chained pose at `t1`, or `None` when the truth at a capture is
    /// not known.
    pub fn push(
        &mut self,
        t0_us: u64,
        t1_us: u64,
        t: &Vector3<f64>,
        q: &UnitQuaternion<f64>,
        truth_at: impl Fn(u64) -> Option<Pose>,
    ) -> Option<Pose> {
        let base = match self.poses.iter().rev().find(|(tk, _)| *tk == t0_us) {
            Some((_, p)) => *p,
            None => {
                let t0 = truth_at(t0_us)?;
                let base = match self.poses.back() {
                    // Bridge the gap from the last chained pose with the true motion.
                    Some((tl, pl)) => {
                        self.gaps += 1;
                        let (dt, dq) = truth_at(*tl)?.to(&t0);
                        pl.then(&dt, &dq)
                    }
                    None => t0,
                };
                self.poses.push_back((t0_us, base));
                base
            }
        };
        let p1 = base.then(t, q);
        self.poses.push_back((t1_us, p1));
        while self.poses.len() > 64 {
            self.poses.pop_front();
        }
        Some(p1)
    }
}

/// One kinematic interval of the slip gate against the truth: the flight slip vector of the
/// interval (EKF minus kinematics, H04 eq. 44) beside the true slip over the same frames, the
/// true motion minus the motion H04 eq. 15 explains from the encoders ([`Eq15Odometry`]),
/// both in the true body frame at the interval's start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlipInterval {
    /// End of the interval (the frame the gate decided), s.
    pub t_s: f64,
    /// Flight slip vector `[x m, y m, yaw rad]`.
    pub flight: [f64; 3],
    /// True slip `[x m, y m, yaw rad]`.
    pub truth: [f64; 3],
    /// True horizontal travel over the interval, m.
    pub travel_m: f64,
    /// The gate accepted the interval's kinematics (no slip detected).
    pub accepted: bool,
}

/// Where an interval of [`SlipInterval`] started: the true pose and the eq. 15 pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlipMark {
    truth: Pose,
    eq15: Pose,
}

impl SlipMark {
    /// A mark at the true pose `truth` and the eq. 15 pose `eq15`.
    pub fn new(truth: Pose, eq15: Pose) -> Self {
        Self { truth, eq15 }
    }

    /// The interval from `self` to `end` with the flight's slip vector and gate decision.
    pub fn interval(
        &self,
        end: &SlipMark,
        t_s: f64,
        flight: [f64; 3],
        accepted: bool,
    ) -> SlipInterval {
        let (dt, dq) = self.truth.to(&end.truth);
        let (de, de_q) = self.eq15.to(&end.eq15);
        // Each displacement in its own body frame at the start: the motion the body made
        // and the motion the kinematics explains, as the gate compares them.
        let yaw = |q: &UnitQuaternion<f64>| q.euler_angles().2;
        let slip_yaw = wrap(yaw(&dq) - yaw(&de_q));
        SlipInterval {
            t_s,
            flight,
            truth: [dt.x - de.x, dt.y - de.y, slip_yaw],
            travel_m: dt.x.hypot(dt.y),
            accepted,
        }
    }
}

/// `a` wrapped to `[-pi, pi)`.
pub fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chain of exact relative poses reproduces the truth, also across a gap.
    #[test]
    fn raw_chain_of_exact_steps_is_exact() {
        let truth = |t: u64| {
            let s = t as f64 * 1e-6;
            Some(Pose {
                pos_m: Vector3::new(0.1 * s, 0.02 * s * s, 0.0),
                rot: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05 * s),
            })
        };
        let mut c = VoRawChain::default();
        let mut last = None;
        for (t0, t1) in [
            (0, 1_000_000),
            (1_000_000, 2_000_000),
            (3_000_000, 4_000_000),
        ] {
            let (dt, dq) = truth(t0).and_then(|a| Some(a.to(&truth(t1)?))).unwrap();
            last = c.push(t0, t1, &dt, &dq, truth);
        }
        let p = last.unwrap();
        let t = truth(4_000_000).unwrap();
        assert!((p.pos_m - t.pos_m).norm() < 1e-12);
        assert!(p.rot.angle_to(&t.rot) < 1e-12);
        assert_eq!(c.gaps, 1);
    }

    /// A biased step shows up in the chain (the chain is not the truth).
    #[test]
    fn raw_chain_keeps_step_errors() {
        let truth = |t: u64| {
            Some(Pose {
                pos_m: Vector3::new(t as f64 * 1e-7, 0.0, 0.0),
                rot: UnitQuaternion::identity(),
            })
        };
        let mut c = VoRawChain::default();
        let mut last = None;
        for k in 0..10u64 {
            let step = Vector3::new(0.1 * 1.05, 0.0, 0.0);
            last = c.push(
                k * 1_000_000,
                (k + 1) * 1_000_000,
                &step,
                &UnitQuaternion::identity(),
                truth,
            );
        }
        let p = last.unwrap();
        assert!((p.pos_m.x - 1.05).abs() < 1e-12, "{}", p.pos_m.x);
    }

    /// Straight rolling at a constant wheel rate on flat ground: eq. 15 integrates the wheel
    /// travel (radius times angle) forward and holds the attitude.
    #[test]
    fn eq15_rolls_straight_on_flat_ground() {
        let r = fsw::kinematics::ROCKY8.wheel_radius_m;
        let mut o = Eq15Odometry::new();
        let start = BodyPose::default();
        for k in 0..=100u64 {
            let j = rover_hal::JointState {
                t_us: k * 10_000,
                drive_angle_rad: [0.01 * k as f64; 6],
                wheel_valid: [true; 6],
                suspension_valid: true,
                ..rover_hal::JointState::default()
            };
            o.update(&j, &start);
        }
        let p = o.pose().unwrap();
        let x0 = Pose::of_body(&start).pos_m.x;
        assert!(
            (p.pos_m.x - x0 - r * 1.0).abs() < 1e-9,
            "{}",
            p.pos_m.x - x0
        );
        assert!(p.rot.angle_to(&Pose::of_body(&start).rot) < 1e-9);
        assert_eq!(o.refused, 0);
    }
}
