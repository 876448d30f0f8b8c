//! # Rocker-bogie kinematics (H04 sec. 3 and Appendix A; H05 sec. III)
//!
//! - [`geometry`]: the D-H table of Rocky 8 as data ([`ROCKY8`], H04 Table 2, frames of Table 1),
//!   the per-wheel transforms of eq. 12 and the wheel contact points.
//! - [`jacobian`]: wheel Jacobians (eq. 13-14) in the contact-point form used by the solvers.
//! - [`forward`]: forward kinematics, body rates from joint rates by least squares (eq. 15).
//! - [`odometry`]: vehicle odometry, forward kinematics integrated into a
//!   [`crate::types::RelativePose`] with covariance (the measurement of H04 sec. 4).
//! - [`inverse`]: inverse kinematics (eq. 16-25), command `[x_dot y_dot phi_dot]` to steering
//!   angles and wheel rates, and the speed scaling that respects the wheel-rate limit.
//! - [`contact`]: contact-angle kinematic estimation (V99 sec. 6, Balaram 1999): body
//!   displacement and the six wheel/terrain contact angles per step, optionally with the gyro.
//! - [`planar`]: the common planar (2D) model for comparison (H04 Fig. 17).
//! - [`track`]: track memory, the body heave from the front axles' remembered path (V99 sec. 6,
//!   the common mode of the contact angles).
//!
//! Frames: rover frame `R` x forward, y right, z down (the base frame of the D-H table, no
//! extra transform is needed). Body rates are ordered `[x_dot, y_dot, z_dot, roll, pitch, yaw]`:
//! the velocity of the origin of `R` (m/s) and the angular velocity of `R` (rad/s), both relative
//! to the ground and expressed in `R`. H04 eq. 14 orders the same vector
//! `[x y z phi p r]` (yaw, pitch, roll); we use roll, pitch, yaw order, as the IMU does.
//! See `docs/kinematics.md` for the frame drawing, the resolved ambiguities and the
//! equation-to-function map.

pub mod contact;
pub mod forward;
pub mod geometry;
pub mod inverse;
pub mod jacobian;
pub mod odometry;
pub mod planar;
pub mod track;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_contact;
#[cfg(test)]
mod tests_ik_contact;
#[cfg(test)]
mod tests_inverse;

pub use contact::{
    contact_jacobians, contact_kinematics, ContactConfig, ContactStep, MAX_CONTACT_ITERATIONS,
};
pub use forward::{forward_kinematics, forward_kinematics_from_joints, ForwardSolution};
pub use geometry::{
    wheel_contact_points, wheel_frames, RoverGeometry, WheelFrames, ROCKY8, WHEEL_RADIUS_M,
};
pub use inverse::{
    instantaneous_centre, inverse_kinematics, inverse_kinematics_contact, max_speed_scale,
    max_speed_scale_contact, ContactAngles, Icr, InverseSolution, VehicleCommand,
};
pub use jacobian::{wheel_jacobians, WheelJacobian};
pub use odometry::{KinematicOdometry, OdometryConfig};
pub use planar::{planar_body_rates, planar_pose_increment};

use crate::types::Vec6;
use rover_hal::WHEEL_COUNT;

/// Body rates `[x_dot, y_dot, z_dot (m/s), roll, pitch, yaw (rad/s)]` of the rover frame `R`
/// relative to the ground, expressed in `R` (the vector `v` of H04 eq. 14, reordered).
pub type BodyRates = Vec6;

/// Suspension and steering angles (H04 Table 2 joint variables), rad.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SuspensionState {
    /// Rocker (differential) angle `beta`, rad.
    pub rocker_rad: f64,
    /// Bogie angles `[rho_1 (right), rho_2 (left)]`, rad.
    pub bogie_rad: [f64; 2],
    /// Steering angles `psi_i`, rad, index `wheel - 1`; positive turns the wheel to the right
    /// (about `+z_R`).
    pub steer_rad: [f64; WHEEL_COUNT],
}

impl SuspensionState {
    /// The suspension state of a joint reading (angles only).
    pub fn from_joints(joints: &rover_hal::JointState) -> Self {
        SuspensionState {
            rocker_rad: joints.rocker_rad,
            bogie_rad: joints.bogie_rad,
            steer_rad: joints.steer_angle_rad,
        }
    }
}

/// Rates of the suspension joints, rad/s (the encoders give angles; the caller differentiates).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SuspensionRates {
    /// `beta_dot`, rad/s.
    pub rocker_rad_s: f64,
    /// `[rho_1_dot, rho_2_dot]`, rad/s.
    pub bogie_rad_s: [f64; 2],
}

/// Why a kinematics computation refused its input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KinematicsError {
    /// An input was NaN or infinite.
    NonFinite,
    /// A rocker, bogie or steering angle is outside the geometry's limits.
    JointOutOfRange,
    /// The suspension encoders are flagged invalid.
    SuspensionInvalid,
    /// Fewer than three valid wheels with non-collinear contacts: the body rates are not
    /// observable (the count of valid wheels is given).
    Unobservable {
        /// Number of wheels that were valid.
        valid_wheels: u8,
    },
    /// A small linear system was singular (degenerate geometry).
    Singular,
    /// No steering angle within the limits realises the command at this wheel (index
    /// `wheel - 1`).
    SteeringLimit {
        /// Wheel index (`wheel - 1`).
        wheel: u8,
    },
    /// The command needs a wheel rate above the drive limit at this wheel (index `wheel - 1`).
    WheelRateLimit {
        /// Wheel index (`wheel - 1`).
        wheel: u8,
    },
    /// Time stamps did not advance (odometry).
    TimeNotAdvancing,
    /// The odometry interval was not started.
    NotStarted,
}
