#![allow(clippy::needless_range_loop)] // wheel loops index several parallel arrays
//! The simulator's REFERENCE DRIVER: a simple path follower inside the simulator, not flight
//! code. It lets the simulator drive paths before the flight software's guidance exists, and is
//! replaced by the flight software's own motor commands through [`CommandSource::Flight`].
//!
//! - [`DriverMode::TruthCarrot`]: carrot following on the TRUE position (a 0.6 m lookahead on the
//!   path) with the TRUE crab angle (direction of the ground velocity in `R`, low-pass filtered
//!   over 1 s) subtracted from the heading: it sees every slip and so compensates it.
//! - [`DriverMode::OpenLoop`]: holds each segment's heading (true yaw, as a gyro would give)
//!   and ends the segment when wheel odometry has covered its length; no slip compensation, so
//!   on a cross slope the rover drifts downhill (H05 Fig. 9 "without compensation").
//!
//! Motor commands come from the simulator's own planar inverse kinematics: wheel `i` at
//! `(x_i, y_i)` in `R` must move at `(vx - omega y_i, vy + omega x_i)`.

use crate::scenario::{DriverMode, Scenario};
use crate::vehicle::geometry::WHEELS;
use crate::world::{wrap_pi, World, FRAME_US};
use rover_hal::MobilityCommand;

/// Who commands the motors.
pub enum CommandSource {
    /// The simulator's reference driver.
    Reference(ReferenceDriver),
    /// The flight software, through `Mobility::command`.
    Flight,
}

/// The reference driver's state.
#[derive(Debug, Clone)]
pub struct ReferenceDriver {
    mode: DriverMode,
    waypoints: Vec<[f64; 2]>,
    speed_m_s: f64,
    segment: usize,
    odometer_m: f64,
    segment_start_m: f64,
    crab_rad: f64,
    done: bool,
}

/// Lookahead of the carrot, m.
pub const CARROT_LOOKAHEAD_M: f64 = 0.6;
/// Heading gain, 1/s.
const HEADING_GAIN: f64 = 1.0;
/// Largest commanded yaw rate, rad/s.
const MAX_YAW_RATE: f64 = 0.3;

impl ReferenceDriver {
    /// A driver for the path of `scenario` in `mode`.
    pub fn new(scenario: &Scenario, mode: DriverMode) -> Self {
        Self {
            mode,
            waypoints: scenario.waypoints.clone(),
            speed_m_s: scenario.speed_m_s,
            segment: 0,
            odometer_m: 0.0,
            segment_start_m: 0.0,
            crab_rad: 0.0,
            done: false,
        }
    }

    /// True once the driver has finished the path and stopped.
    pub fn done(&self) -> bool {
        self.done
    }

    /// Wheel-odometry distance so far, m.
    pub fn odometer_m(&self) -> f64 {
        self.odometer_m
    }

    /// The motor command for the next step.
    pub fn command(&mut self, world: &World) -> MobilityCommand {
        let t = &world.truth;
        let r = world.geometry.wheel_radius_m;
        let rim: f64 = (0..WHEELS)
            .map(|i| r[i] * t.wheel_rate_rad_s[i] * t.steer_rad[i].cos())
            .sum::<f64>()
            / WHEELS as f64;
        self.odometer_m += rim * FRAME_US as f64 * 1e-6;
        if self.done {
            return hold(world);
        }
        let pos = [t.pose.pos_m[0], t.pose.pos_m[1]];
        let yaw = t.pose.yaw_rad;
        let desired_yaw = match self.mode {
            DriverMode::TruthCarrot => {
                let (carrot, at_end) = carrot(&self.waypoints, pos, CARROT_LOOKAHEAD_M);
                let end = self.waypoints[self.waypoints.len() - 1];
                let to_end = [end[0] - pos[0], end[1] - pos[1]];
                let dist = (to_end[0].powi(2) + to_end[1].powi(2)).sqrt();
                let ahead = to_end[0] * yaw.cos() + to_end[1] * yaw.sin();
                if dist < 0.03 || (at_end && ahead <= 0.0) {
                    self.done = true;
                    return hold(world);
                }
                let v = t.velocity_r_m_s;
                if v[0] > 0.02 {
                    let crab = v[1].atan2(v[0]);
                    self.crab_rad += (crab - self.crab_rad) * (FRAME_US as f64 * 1e-6);
                }
                (carrot[1] - pos[1]).atan2(carrot[0] - pos[0]) - self.crab_rad
            }
            DriverMode::OpenLoop => {
                let a = self.waypoints[self.segment];
                let b = self.waypoints[self.segment + 1];
                let length = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
                if self.odometer_m - self.segment_start_m >= length {
                    self.segment += 1;
                    self.segment_start_m = self.odometer_m;
                    if self.segment + 1 >= self.waypoints.len() {
                        self.done = true;
                        return hold(world);
                    }
                }
                let a = self.waypoints[self.segment];
                let b = self.waypoints[self.segment + 1];
                (b[1] - a[1]).atan2(b[0] - a[0])
            }
        };
        let error = wrap_pi(desired_yaw - yaw);
        let omega = (HEADING_GAIN * error).clamp(-MAX_YAW_RATE, MAX_YAW_RATE);
        let vx = if error.abs() > 0.5 {
            0.0
        } else {
            self.speed_m_s * error.cos()
        };
        inverse_kinematics(&world.wheel_xy(), &r, [vx, 0.0, omega])
    }
}

/// Keep the steering, stop the wheels.
fn hold(world: &World) -> MobilityCommand {
    MobilityCommand {
        steer_angle_rad: world.command.steer_angle_rad,
        wheel_rate_rad_s: [0.0; WHEELS],
    }
}

/// Planar inverse kinematics of the simulator: steering angles (positive turns the wheel right,
/// as in `fsw::kinematics`) and wheel rates for the body twist `[vx, vy, omega]` (m/s, m/s, rad/s in `R`),
/// for wheels of radii `radius_m` (wheel order; the reference driver uses the true radii).
pub fn inverse_kinematics(
    xy: &[[f64; 2]; WHEELS],
    radius_m: &[f64; WHEELS],
    twist: [f64; 3],
) -> MobilityCommand {
    let mut c = MobilityCommand::default();
    for i in 0..WHEELS {
        let vx = twist[0] - twist[2] * xy[i][1];
        let vy = twist[1] + twist[2] * xy[i][0];
        let speed = (vx * vx + vy * vy).sqrt();
        if speed < 1e-9 {
            continue;
        }
        let mut psi = vy.atan2(vx);
        let mut rate = speed / radius_m[i];
        if psi.abs() > std::f64::consts::FRAC_PI_2 {
            psi -= std::f64::consts::PI.copysign(psi);
            rate = -rate;
        }
        c.steer_angle_rad[i] = psi;
        c.wheel_rate_rad_s[i] = rate;
    }
    c
}

/// The carrot: the point `lookahead` further along the path than the point closest to `pos`;
/// also says whether it was clamped to the path's end.
pub fn carrot(path: &[[f64; 2]], pos: [f64; 2], lookahead: f64) -> ([f64; 2], bool) {
    let (s_closest, _) = closest_arc(path, pos);
    point_at(path, s_closest + lookahead)
}

/// Arc length of the path point closest to `pos`, and the distance to it.
pub fn closest_arc(path: &[[f64; 2]], pos: [f64; 2]) -> (f64, f64) {
    let (mut best_s, mut best_d, mut s0) = (0.0, f64::INFINITY, 0.0);
    for w in path.windows(2) {
        let (dx, dy) = (w[1][0] - w[0][0], w[1][1] - w[0][1]);
        let len = (dx * dx + dy * dy).sqrt();
        let u = if len > 0.0 {
            (((pos[0] - w[0][0]) * dx + (pos[1] - w[0][1]) * dy) / (len * len)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d = ((pos[0] - w[0][0] - u * dx).powi(2) + (pos[1] - w[0][1] - u * dy).powi(2)).sqrt();
        if d < best_d {
            best_d = d;
            best_s = s0 + u * len;
        }
        s0 += len;
    }
    (best_s, best_d)
}

fn point_at(path: &[[f64; 2]], s: f64) -> ([f64; 2], bool) {
    let mut s0 = 0.0;
    for w in path.windows(2) {
        let (dx, dy) = (w[1][0] - w[0][0], w[1][1] - w[0][1]);
        let len = (dx * dx + dy * dy).sqrt();
        if s <= s0 + len && len > 0.0 {
            let u = (s - s0) / len;
            return ([w[0][0] + u * dx, w[0][1] + u * dy], false);
        }
        s0 += len;
    }
    (path[path.len() - 1], true)
}
