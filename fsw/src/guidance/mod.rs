//! # Guidance: carrot heading and slip-compensated path following (H04 sec. 5, H05 sec. V)
//!
//! Each RG2 cycle (`T_S`, default 50 ms) [`Guidance::step`] takes the rover pose
//! `[x y phi]` in the navigation frame `N` (x north, y east, yaw from north, positive right), the
//! slip vector over the last period (EKF minus kinematics, rover frame) and returns the rover
//! command `[x_dot y_dot phi_dot]` (rover frame, m/s and rad/s) for inverse kinematics:
//!
//! 1. carrot heading ([`carrot::carrot`], eq. 47): `phi_err = phi_carrot - phi_pose`;
//! 2. heading loop ([`control::heading_loop`], eq. 48) and crab loop ([`control::crab_loop`],
//!    eq. 49) driven by the slip vector; without slip they reduce to a heading controller;
//! 3. `x_dot` the largest that keeps every wheel within its drive-motor speed
//!    ([`control::limit_forward_speed`]), reduced near the goal;
//! 4. stop at the goal within a tolerance.
//!
//! Motion is continuous (H05 sec. V.C): nothing here waits for a stop; slip estimates arrive
//! while driving and act at the next cycle.

pub mod carrot;
pub mod control;
pub mod path;

pub use carrot::{wrap_pi, Carrot};
pub use path::{Path, PathError, Point2, Projection};

/// Guidance settings. Gains follow eq. 48-49 (H04) with the slip sign convention of
/// [`SlipVector`] (EKF minus kinematics), so `k2` and `k3` are negative to oppose slip.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidanceConfig {
    /// Nominal carrot circle radius, m.
    pub carrot_radius_m: f64,
    /// Eq. 48 heading-error gain `K1` (dimensionless; `K1 / T_S` is the loop gain in 1/s).
    pub k1: f64,
    /// Eq. 48 yaw-slip gain `K2`.
    pub k2: f64,
    /// Eq. 49 lateral-slip gain `K3`.
    pub k3: f64,
    /// Sample period `T_S` of the loops, s.
    pub sample_period_s: f64,
    /// Cruise speed cap for `x_dot`, m/s.
    pub cruise_speed_m_s: f64,
    /// Largest ground speed of any wheel (drive-motor limit times wheel radius), m/s.
    pub max_wheel_speed_m_s: f64,
    /// Yaw-rate command limit, rad/s.
    pub max_yaw_rate_rad_s: f64,
    /// Crab-speed command limit, m/s.
    pub max_crab_speed_m_s: f64,
    /// Goal reached when the rover is closer than this, m.
    pub goal_tolerance_m: f64,
    /// Forward speed near the goal is at most `approach_gain_per_s * distance`, 1/s.
    pub approach_gain_per_s: f64,
    /// Smallest forward speed while approaching the goal, m/s.
    pub min_speed_m_s: f64,
    /// Wheel contact points in the rover frame `(x, y)`, m (from kinematics).
    pub wheel_xy_m: [[f64; 2]; 6],
}

impl GuidanceConfig {
    /// Defaults for a Rocky 8 class rover at 20 Hz with the given wheel contact points.
    pub fn rocky8(wheel_xy_m: [[f64; 2]; 6]) -> Self {
        Self {
            carrot_radius_m: 0.6,
            k1: 0.02,
            k2: -1.0,
            k3: -1.0,
            sample_period_s: 0.05,
            cruise_speed_m_s: 0.08,
            max_wheel_speed_m_s: 0.12,
            max_yaw_rate_rad_s: 0.25,
            max_crab_speed_m_s: 0.06,
            goal_tolerance_m: 0.05,
            approach_gain_per_s: 0.5,
            min_speed_m_s: 0.01,
            wheel_xy_m,
        }
    }
}

/// Rover pose in the navigation frame `N`: position (m) and yaw from north (rad, positive
/// right).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose2 {
    /// North, m.
    pub x_m: f64,
    /// East, m.
    pub y_m: f64,
    /// Yaw, rad.
    pub phi_rad: f64,
}

/// Slip over the last sample period, rover frame: EKF motion minus kinematic motion (H04 sec.
/// 4-5). Zero when the Mahalanobis gate accepted the kinematics.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SlipVector {
    /// Forward slip, m.
    pub x_m: f64,
    /// Lateral slip, m (positive to the right).
    pub y_m: f64,
    /// Yaw slip, rad.
    pub phi_rad: f64,
}

/// What guidance commands.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidanceCommand {
    /// Forward speed, m/s (rover x).
    pub x_dot_m_s: f64,
    /// Crab speed, m/s (rover y, right).
    pub y_dot_m_s: f64,
    /// Yaw rate, rad/s (positive right).
    pub phi_dot_rad_s: f64,
    /// Heading error of eq. 47, rad.
    pub phi_err_rad: f64,
    /// The carrot.
    pub carrot: Carrot,
    /// Where the rover projects on the path (cross-track error).
    pub projection: Projection,
    /// Distance to the goal, m.
    pub goal_distance_m: f64,
    /// True once the goal was reached (the command is then zero).
    pub goal_reached: bool,
}

/// Why guidance produced no command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GuidanceError {
    /// The pose or slip contains a non-finite number.
    NonFiniteInput,
    /// The configuration is invalid (non-positive period, radius or speed).
    BadConfig,
    /// No carrot could be found (circle never met the path).
    NoCarrot,
}

/// Path follower state: the path (capacity `N` waypoints), its settings and the goal latch.
#[derive(Debug, Clone, PartialEq)]
pub struct Guidance<const N: usize> {
    path: Path<N>,
    config: GuidanceConfig,
    goal_reached: bool,
}

impl<const N: usize> Guidance<N> {
    /// A follower for `path` with `config`.
    pub fn new(path: Path<N>, config: GuidanceConfig) -> Result<Self, GuidanceError> {
        let c = &config;
        let positive = [
            c.carrot_radius_m,
            c.sample_period_s,
            c.max_wheel_speed_m_s,
            c.goal_tolerance_m,
        ];
        let non_negative = [
            c.cruise_speed_m_s,
            c.max_yaw_rate_rad_s,
            c.max_crab_speed_m_s,
            c.approach_gain_per_s,
            c.min_speed_m_s,
        ];
        if positive.iter().any(|v| !v.is_finite() || *v <= 0.0)
            || non_negative.iter().any(|v| !v.is_finite() || *v < 0.0)
            || [c.k1, c.k2, c.k3].iter().any(|v| !v.is_finite())
            || c.wheel_xy_m.iter().flatten().any(|v| !v.is_finite())
        {
            return Err(GuidanceError::BadConfig);
        }
        Ok(Self {
            path,
            config,
            goal_reached: false,
        })
    }

    /// The path.
    pub fn path(&self) -> &Path<N> {
        &self.path
    }

    /// The settings.
    pub fn config(&self) -> &GuidanceConfig {
        &self.config
    }

    /// True once the goal was reached.
    pub fn goal_reached(&self) -> bool {
        self.goal_reached
    }

    /// One guidance cycle (eq. 47-49). Non-finite inputs give an error; the caller then stops
    /// the rover (safe fallback).
    pub fn step(
        &mut self,
        pose: Pose2,
        slip: SlipVector,
    ) -> Result<GuidanceCommand, GuidanceError> {
        let inputs = [
            pose.x_m,
            pose.y_m,
            pose.phi_rad,
            slip.x_m,
            slip.y_m,
            slip.phi_rad,
        ];
        if inputs.iter().any(|v| !v.is_finite()) {
            return Err(GuidanceError::NonFiniteInput);
        }
        let c = self.config;
        let position = [pose.x_m, pose.y_m];
        let carrot = carrot::carrot(&self.path, position, c.carrot_radius_m)
            .ok_or(GuidanceError::NoCarrot)?;
        let projection = self.path.project(position);
        let goal_distance_m = path::distance(position, self.path.goal());
        // Eq. 47.
        let phi_err_rad = wrap_pi(carrot.heading_rad - pose.phi_rad);
        if goal_distance_m <= c.goal_tolerance_m {
            self.goal_reached = true;
        }
        if self.goal_reached {
            return Ok(GuidanceCommand {
                x_dot_m_s: 0.0,
                y_dot_m_s: 0.0,
                phi_dot_rad_s: 0.0,
                phi_err_rad,
                carrot,
                projection,
                goal_distance_m,
                goal_reached: true,
            });
        }
        // Eq. 48 and 49, limited.
        let phi_dot = crate::linalg::clamp(
            control::heading_loop(phi_err_rad, slip.phi_rad, c.k1, c.k2, c.sample_period_s),
            -c.max_yaw_rate_rad_s,
            c.max_yaw_rate_rad_s,
        );
        let y_dot = crate::linalg::clamp(
            control::crab_loop(slip.y_m, c.k3, c.sample_period_s),
            -c.max_crab_speed_m_s,
            c.max_crab_speed_m_s,
        );
        // Forward speed: cruise, reduced while the heading error is large and near the goal.
        let heading_factor = libm::cos(phi_err_rad).max(0.0);
        let approach = (c.approach_gain_per_s * goal_distance_m).max(c.min_speed_m_s);
        let cap = (c.cruise_speed_m_s * heading_factor).min(approach);
        let (x_dot, y_dot, phi_dot) =
            control::limit_forward_speed(&c.wheel_xy_m, y_dot, phi_dot, c.max_wheel_speed_m_s, cap)
                .ok_or(GuidanceError::BadConfig)?;
        Ok(GuidanceCommand {
            x_dot_m_s: x_dot,
            y_dot_m_s: y_dot,
            phi_dot_rad_s: phi_dot,
            phi_err_rad,
            carrot,
            projection,
            goal_distance_m,
            goal_reached: false,
        })
    }
}

#[cfg(test)]
mod tests;
