//! Rocker-bogie mobility: joint encoders and wheel/steering motor commands.

use crate::Error;

/// Number of wheels of a six-wheel rocker-bogie rover (Rocky 8).
pub const WHEEL_COUNT: usize = 6;

/// Joint state of the 15-DOF rocker-bogie mechanism (H04 sec. 3, Table 2 symbols).
///
/// Arrays are indexed by wheel number minus one (1 right front, 2 left front, 3 right middle,
/// 4 left middle, 5 right rear, 6 left rear).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointState {
    /// Time of the reading, microseconds since boot.
    pub t_us: u64,
    /// Drive wheel angle `theta_i`, rad, positive rolling the rover forward.
    pub drive_angle_rad: [f64; WHEEL_COUNT],
    /// Drive wheel rate `theta_dot_i`, rad/s.
    pub drive_rate_rad_s: [f64; WHEEL_COUNT],
    /// Steering angle `psi_i` about the steering axis, rad, zero straight ahead.
    pub steer_angle_rad: [f64; WHEEL_COUNT],
    /// Rocker (differential) angle `beta`, rad.
    pub rocker_rad: f64,
    /// Bogie angles `[rho_1 (right), rho_2 (left)]`, rad.
    pub bogie_rad: [f64; 2],
    /// Per-wheel validity of the drive and steering encoders (false: encoder fault).
    pub wheel_valid: [bool; WHEEL_COUNT],
    /// Validity of the rocker and bogie encoders.
    pub suspension_valid: bool,
}

/// Motor command for one control cycle (H04 eq. 21-25 outputs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MobilityCommand {
    /// Commanded steering angles `psi_i`, rad.
    pub steer_angle_rad: [f64; WHEEL_COUNT],
    /// Commanded wheel rates `theta_dot_i`, rad/s.
    pub wheel_rate_rad_s: [f64; WHEEL_COUNT],
}

/// Joint encoders and the twelve drive and steering motors.
pub trait Mobility {
    /// Error type of this mobility system.
    type Error: Error;

    /// Read all joint encoders.
    fn read_joints(&mut self) -> Result<JointState, Self::Error>;

    /// Command the six steering angles and six wheel rates. The device applies its own rate
    /// limits and saturation; it rejects non-finite values with
    /// [`crate::ErrorKind::InvalidRequest`].
    fn command(&mut self, command: &MobilityCommand) -> Result<(), Self::Error>;

    /// Stop all wheels now (wheel rates to zero, steering held).
    fn stop(&mut self) -> Result<(), Self::Error>;
}
