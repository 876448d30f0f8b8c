//! The common planar (2D) kinematic model, kept for comparison with the full model (H04 sec. 3
//! motivation and Fig. 17: on rough terrain the planar model accumulates > 30 % error).
//!
//! Planar assumption: the rover moves in its own `x-y` plane, the suspension is ignored (the
//! contact points are those at `beta = rho = 0`) and each wheel's contact moves at
//! `r * theta_dot_i` in its steering direction `psi_i`:
//! `[x_dot - yaw * y_i, y_dot + yaw * x_i] = r theta_dot_i [cos psi_i, sin psi_i]`,
//! solved by least squares (centroid form, no matrix inverse).

use super::geometry::{wheel_contact_points, RoverGeometry};
use super::{BodyRates, KinematicsError, SuspensionState};
use crate::types::Vec3;
use rover_hal::{JointState, WHEEL_COUNT};

/// Planar-model body rates `[x_dot, y_dot, 0, 0, 0, yaw]` (rover frame `R`, m/s, rad/s) from
/// drive rates (rad/s) and steering angles (rad) of the valid wheels. Errors: non-finite input,
/// steering out of range, fewer than two valid wheels.
pub fn planar_body_rates(
    geometry: &RoverGeometry,
    drive_rad_s: &[f64; WHEEL_COUNT],
    steer_rad: &[f64; WHEEL_COUNT],
    wheel_valid: &[bool; WHEEL_COUNT],
) -> Result<BodyRates, KinematicsError> {
    let points = wheel_contact_points(geometry, &SuspensionState::default())?;
    planar_body_rates_at(geometry, &points, drive_rad_s, steer_rad, wheel_valid)
}

/// [`planar_body_rates`] with the nominal contact points `points` (m, `R`: the contact points at
/// the zero suspension state, [`wheel_contact_points`]) already evaluated: the caller that runs
/// it every joint reading computes them once (the timing budget).
pub(crate) fn planar_body_rates_at(
    geometry: &RoverGeometry,
    points: &[Vec3; WHEEL_COUNT],
    drive_rad_s: &[f64; WHEEL_COUNT],
    steer_rad: &[f64; WHEEL_COUNT],
    wheel_valid: &[bool; WHEEL_COUNT],
) -> Result<BodyRates, KinematicsError> {
    let mut count: u8 = 0;
    let (mut cx, mut cy, mut vx, mut vy) = (0.0, 0.0, 0.0, 0.0);
    let mut velocities = [(0.0, 0.0); WHEEL_COUNT];
    let wheels = points
        .iter()
        .zip(wheel_valid.iter())
        .zip(drive_rad_s.iter().zip(steer_rad.iter()))
        .zip(velocities.iter_mut());
    for (((p, valid), (&d, &s)), velocity) in wheels {
        if !*valid {
            continue;
        }
        if !(d.is_finite() && s.is_finite()) {
            return Err(KinematicsError::NonFinite);
        }
        if libm::fabs(s) > geometry.limits.steer_rad {
            return Err(KinematicsError::JointOutOfRange);
        }
        let speed = geometry.wheel_radius_m * d;
        *velocity = (speed * libm::cos(s), speed * libm::sin(s));
        count = count.saturating_add(1);
        cx += p.x;
        cy += p.y;
        vx += velocity.0;
        vy += velocity.1;
    }
    if count < 2 {
        return Err(KinematicsError::Unobservable {
            valid_wheels: count,
        });
    }
    let n = f64::from(count);
    let (cx, cy, vx, vy) = (cx / n, cy / n, vx / n, vy / n);
    let (mut num, mut den) = (0.0, 0.0);
    for ((p, valid), velocity) in points.iter().zip(wheel_valid.iter()).zip(velocities.iter()) {
        if *valid {
            let (qx, qy) = (p.x - cx, p.y - cy);
            num += qx * velocity.1 - qy * velocity.0;
            den += qx * qx + qy * qy;
        }
    }
    if den.is_nan() || den <= 0.0 {
        return Err(KinematicsError::Singular);
    }
    let yaw = num / den;
    // Rates at the centroid moved to the origin of R: v = v_c - yaw z x c.
    Ok(BodyRates::new(
        vx + yaw * cy,
        vy - yaw * cx,
        0.0,
        0.0,
        0.0,
        yaw,
    ))
}

/// Planar-model pose increment `[dx (m), dy (m), dyaw (rad)]` in the rover frame at `prev`
/// between two joint readings (drive angle differences, mean steering angles), integrated along
/// a circular arc. Errors: as [`planar_body_rates`].
pub fn planar_pose_increment(
    geometry: &RoverGeometry,
    prev: &JointState,
    cur: &JointState,
) -> Result<[f64; 3], KinematicsError> {
    let points = wheel_contact_points(geometry, &SuspensionState::default())?;
    planar_pose_increment_at(geometry, &points, prev, cur)
}

/// [`planar_pose_increment`] with the nominal contact points already evaluated (see
/// [`planar_body_rates_at`]).
pub(crate) fn planar_pose_increment_at(
    geometry: &RoverGeometry,
    points: &[Vec3; WHEEL_COUNT],
    prev: &JointState,
    cur: &JointState,
) -> Result<[f64; 3], KinematicsError> {
    let valid: [bool; WHEEL_COUNT] =
        core::array::from_fn(|i| prev.wheel_valid[i] && cur.wheel_valid[i]);
    let drive: [f64; WHEEL_COUNT] =
        core::array::from_fn(|i| cur.drive_angle_rad[i] - prev.drive_angle_rad[i]);
    let steer: [f64; WHEEL_COUNT] =
        core::array::from_fn(|i| 0.5 * (cur.steer_angle_rad[i] + prev.steer_angle_rad[i]));
    let t = planar_body_rates_at(geometry, points, &drive, &steer, &valid)?;
    let (dx, dy, dyaw) = (t[0], t[1], t[5]);
    // Exact integration of constant body rates over the unit "time" of the increments.
    let (s, c) = (libm::sin(dyaw), libm::cos(dyaw));
    let (a, b) = if libm::fabs(dyaw) > 1e-9 {
        (s / dyaw, (1.0 - c) / dyaw)
    } else {
        (1.0 - dyaw * dyaw / 6.0, dyaw / 2.0)
    };
    Ok([a * dx - b * dy, b * dx + a * dy, dyaw])
}
