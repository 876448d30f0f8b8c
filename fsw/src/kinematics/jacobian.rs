//! Wheel Jacobians (H04 eq. 13-14) in contact-point form.
//!
//! Eq. 13 equates the rover twist with the motion of each wheel's motion frame `M_i`, which is
//! fixed to the ground (no slip). The unsensed rotations of the contact (the steering slip
//! `xi_i` of Table 2, the steering itself and any lean of the wheel) all turn about axes through
//! the contact point, so the three translational rows of eq. 13 taken at the contact point do
//! not depend on them. Those rows are, for wheel `i` with contact point `p_i` in `R`:
//!
//! ```text
//! [ I  -[p_i]x ] v  =  J_i q_dot_i,     J_i = [ -dp_i/dbeta   -dp_i/drho   r * x_Ci ]
//! ```
//!
//! with `v = [x_dot y_dot z_dot roll pitch yaw]` and `q_dot_i = [beta_dot rho_dot theta_dot_i]`
//! exactly as in eq. 14 (the rear wheels have no `rho` column). This eliminates the vector of
//! unobservable rates `eta` of eq. 15 algebraically.

use super::geometry::{check_suspension, wheel_frames_trusted, RoverGeometry, WheelFrames};
use super::{KinematicsError, SuspensionState};
use crate::types::Vec3;
use nalgebra::SMatrix;
use rover_hal::WHEEL_COUNT;

/// The `3x6` matrix `A_i = [I, -[p_i]x]` that maps the body rates to the velocity of the body
/// point at the contact `p_i` (rover frame `R`, m/s).
pub type ContactRows = SMatrix<f64, 3, 6>;

/// Eq. 14 (H04) for one wheel in contact-point form: `A_i v = J_i q_dot_i`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelJacobian {
    /// Contact point `p_i` in `R`, m.
    pub contact_point_m: Vec3,
    /// Column of `beta_dot`: `-dp_i/dbeta`, m/rad, in `R`.
    pub rocker: Vec3,
    /// Column of the wheel's `rho_dot`: `-dp_i/drho`, m/rad, in `R` (zero for rear wheels).
    pub bogie: Vec3,
    /// Column of `theta_dot_i`: `r * x_Ci`, m/rad, in `R`.
    pub drive: Vec3,
    /// Which bogie angle the `bogie` column belongs to (`None` for the rear wheels).
    pub bogie_index: Option<usize>,
}

impl WheelJacobian {
    /// Build from the eq. 12 frames of one wheel.
    pub fn from_frames(frames: &WheelFrames, wheel_radius_m: f64) -> Self {
        WheelJacobian {
            contact_point_m: frames.contact_point_m,
            rocker: -frames.d_contact_d_rocker,
            bogie: -frames.d_contact_d_bogie,
            drive: frames.rolling_dir * wheel_radius_m,
            bogie_index: frames.bogie,
        }
    }

    /// `A_i = [I, -[p_i]x]` (eq. 13 translational rows at the contact point).
    pub fn contact_rows(&self) -> ContactRows {
        let p = self.contact_point_m;
        ContactRows::from_row_slice(&[
            1.0, 0.0, 0.0, 0.0, p.z, -p.y, //
            0.0, 1.0, 0.0, -p.z, 0.0, p.x, //
            0.0, 0.0, 1.0, p.y, -p.x, 0.0,
        ])
    }

    /// `J_i q_dot_i`: the velocity (m/s, in `R`) that the body point at the contact must have
    /// for the measured rates, `beta_dot`, this wheel's `rho_dot` and `theta_dot_i`.
    pub fn measured_velocity(&self, rocker_rad_s: f64, bogie_rad_s: f64, drive_rad_s: f64) -> Vec3 {
        self.rocker * rocker_rad_s + self.bogie * bogie_rad_s + self.drive * drive_rad_s
    }
}

/// Eq. 13-14 (H04): wheel Jacobians of all six wheels at a suspension state (angles checked).
pub fn wheel_jacobians(
    geometry: &RoverGeometry,
    state: &SuspensionState,
) -> Result<[WheelJacobian; WHEEL_COUNT], KinematicsError> {
    check_suspension(geometry, state)?;
    let frames = wheel_frames_trusted(geometry, state);
    Ok(frames.map(|f| WheelJacobian::from_frames(&f, geometry.wheel_radius_m)))
}
