//! Placing the rocker-bogie vehicle on the terrain: solve body height, roll, pitch, rocker and
//! bogie angles so that all six wheels touch the ground.
//!
//! Unknowns `u = [z, roll, pitch, beta, rho1, rho2]` (the body's north, east and yaw are given
//! by the motion model). Each wheel is a disc of radius `r` centred on its axle, in the plane
//! normal to its spin axis; its contact is the rim point of largest penetration
//! ([`wheel_contact`]: on a step the rim rests on the edge). The residual of wheel `i` is its
//! clearance `e_i(u)`. Newton's method with a finite-difference 6x6 Jacobian drives `e` to zero.
//! When a joint would pass its limit it is held at the limit, the remaining unknowns are fitted
//! in the least-squares sense, and the body is raised until no wheel penetrates the ground (the
//! wheels that then float are off the ground, as on a real vehicle at its joint limits).

use super::contact::{clearance_at_angle, wheel_contact, WheelContact};
use super::geometry::{VehicleGeometry, WHEELS};
use crate::surface::TerrainSurface;
use nalgebra::{Rotation3, SMatrix, SVector, Vector3};

/// Body pose of the rover in the world frame `W` (x north, y east, z down).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BodyPose {
    /// Position of the rover reference point `R` in `W`, m.
    pub pos_m: [f64; 3],
    /// Yaw (heading from north, positive turning east/right), rad.
    pub yaw_rad: f64,
    /// Pitch (positive nose up), rad.
    pub pitch_rad: f64,
    /// Roll (positive right side down), rad.
    pub roll_rad: f64,
}

impl BodyPose {
    /// Rotation from `R` to `W`: `Rz(yaw) Ry(pitch) Rx(roll)`.
    pub fn rot_w_from_r(&self) -> Rotation3<f64> {
        Rotation3::from_euler_angles(self.roll_rad, self.pitch_rad, self.yaw_rad)
    }
}

/// Suspension angles, rad (H04 Table 2 symbols).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Suspension {
    /// Rocker (differential) angle `beta`.
    pub rocker_rad: f64,
    /// Bogies `[rho1 (right), rho2 (left)]`.
    pub bogie_rad: [f64; 2],
}

/// Mechanical stops of the suspension.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimits {
    /// `|beta|` limit, rad.
    pub rocker_rad: f64,
    /// `|rho|` limit, rad.
    pub bogie_rad: f64,
}

impl JointLimits {
    /// The stops of the truth vehicle, an assumption (no source gives Rocky 8's stops): rocker
    /// +-0.57 rad, bogies +-0.95 rad, inside the range the flight model accepts (+-0.6, +-1.0).
    pub fn rocky8() -> Self {
        Self {
            rocker_rad: 0.57,
            bogie_rad: 0.95,
        }
    }
}

/// Result of a placement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Body pose (north, east, yaw as given; z, roll, pitch solved).
    pub pose: BodyPose,
    /// Solved suspension.
    pub suspension: Suspension,
    /// Wheel contacts in `W` (point, angle, normal, tangent, clearance).
    pub contacts: [WheelContact; WHEELS],
    /// Height of each wheel above the ground at the end (0 for a touching wheel), m.
    pub clearance_m: [f64; WHEELS],
    /// Newton iterations used.
    pub iterations: u32,
    /// A joint limit was active.
    pub at_limit: bool,
}

type Unknowns = SVector<f64, 6>;

/// Contact angles held fixed while the Jacobian is taken by finite differences (the envelope
/// of the rim search: for small pose changes the derivative of the clearance equals the one at
/// the fixed contact angle).
type Angles = [f64; WHEELS];

/// Residuals `e(u)`: the clearance of each wheel (negative: penetration). With `fixed`, the
/// clearance at the given contact angles; otherwise the full rim search of
/// [`wheel_contact`], which also fills `contacts` and `angles`.
#[allow(clippy::too_many_arguments)]
fn residuals(
    geometry: &dyn VehicleGeometry,
    terrain: &dyn TerrainSurface,
    pose: &BodyPose,
    u: &Unknowns,
    steer_rad: &[f64; WHEELS],
    contacts: &mut [WheelContact; WHEELS],
    angles: &mut Angles,
    fixed: bool,
) -> Unknowns {
    let pose = BodyPose {
        pos_m: [pose.pos_m[0], pose.pos_m[1], u[0]],
        yaw_rad: pose.yaw_rad,
        roll_rad: u[1],
        pitch_rad: u[2],
    };
    let rot = pose.rot_w_from_r();
    let p = Vector3::from(pose.pos_m);
    let Some(wheels) = geometry.wheels(u[3], [u[4], u[5]], steer_rad) else {
        // Not finite: a large residual pushes Newton back.
        return Unknowns::repeat(1.0);
    };
    let r = geometry.wheel_radius_m();
    let mut e = Unknowns::zeros();
    for i in 0..WHEELS {
        let c = p + rot * wheels[i].axle_m;
        let s = rot * wheels[i].spin_axis;
        if fixed {
            e[i] = clearance_at_angle(terrain, &c, &s, r, angles[i]);
        } else {
            let hint = angles[i].is_finite().then_some(angles[i]);
            let k = wheel_contact(terrain, &c, &s, r, hint);
            contacts[i] = k;
            angles[i] = k.angle_rad;
            e[i] = k.clearance_m;
        }
    }
    e
}

/// Place the vehicle at the north/east/yaw of `pose`, starting Newton from `pose` (height,
/// roll, pitch) and `guess` (the previous step's solution).
pub fn place(
    geometry: &dyn VehicleGeometry,
    terrain: &dyn TerrainSurface,
    pose: &BodyPose,
    guess: &Suspension,
    steer_rad: &[f64; WHEELS],
    limits: &JointLimits,
) -> Placement {
    place_cached(
        geometry, terrain, pose, guess, steer_rad, limits, &mut None, None,
    )
}

/// Jacobian `d e / d u` kept between placements (chord method).
pub type PlacementJacobian = SMatrix<f64, 6, 6>;

fn no_contact() -> WheelContact {
    WheelContact {
        point_w: Vector3::zeros(),
        angle_rad: 0.0,
        normal_w: -Vector3::z(),
        tangent_w: Vector3::x(),
        clearance_m: 0.0,
    }
}

/// [`place`] reusing the Jacobian of an earlier placement (the chord method: between two 5 ms
/// steps the configuration barely changes). The Jacobian is recomputed by finite differences
/// (at fixed contact angles) when there is none or when an iteration reduces the residual by
/// less than 4x; the solution is the same (to the 1e-9 m tolerance), only cheaper.
/// `previous_angles` are the contact angles of the previous placement (followed by the rim
/// search, see [`wheel_contact`]).
#[allow(clippy::too_many_arguments)]
pub fn place_cached(
    geometry: &dyn VehicleGeometry,
    terrain: &dyn TerrainSurface,
    pose: &BodyPose,
    guess: &Suspension,
    steer_rad: &[f64; WHEELS],
    limits: &JointLimits,
    cache: &mut Option<PlacementJacobian>,
    previous_angles: Option<[f64; WHEELS]>,
) -> Placement {
    let mut u = Unknowns::new(
        pose.pos_m[2],
        pose.roll_rad,
        pose.pitch_rad,
        guess.rocker_rad,
        guess.bogie_rad[0],
        guess.bogie_rad[1],
    );
    let mut contacts = [no_contact(); WHEELS];
    let mut angles = previous_angles.unwrap_or([f64::NAN; WHEELS]);
    let mut iterations = 0;
    let mut free = [true; 6];
    let lim = [
        f64::INFINITY,
        f64::INFINITY,
        f64::INFINITY,
        limits.rocker_rad,
        limits.bogie_rad,
        limits.bogie_rad,
    ];
    let h = 1e-7;
    let mut previous = f64::INFINITY;
    let eval = |u: &Unknowns, contacts: &mut [WheelContact; WHEELS], angles: &mut Angles, fixed| {
        residuals(
            geometry, terrain, pose, u, steer_rad, contacts, angles, fixed,
        )
    };
    // Newton on the clearances at fixed contact angles (the envelope of the rim search), with a
    // full rim search at the start and to confirm convergence: a contact that moves to another
    // part of the rim (a rock entering ahead of the axle) restarts the iterations there.
    let mut fixed = previous_angles.is_some_and(|a| a.iter().all(|v| v.is_finite()));
    for _ in 0..40 {
        iterations += 1;
        let e = eval(&u, &mut contacts, &mut angles, fixed);
        let size = e.amax();
        if size < 1e-9 {
            if fixed {
                fixed = false;
                continue;
            }
            break;
        }
        fixed = true;
        let stale = size > 0.25 * previous;
        previous = size;
        let mut jac = match cache {
            Some(j) if !stale => *j,
            _ => {
                let mut j = PlacementJacobian::zeros();
                let mut scratch = [no_contact(); WHEELS];
                let e0 = eval(&u, &mut scratch, &mut angles, true);
                for k in 0..6 {
                    let mut up = u;
                    up[k] += h;
                    let ep = eval(&up, &mut scratch, &mut angles, true);
                    j.set_column(k, &((ep - e0) / h));
                }
                *cache = Some(j);
                j
            }
        };
        for (k, is_free) in free.iter().enumerate() {
            if !is_free {
                jac.set_column(k, &Unknowns::zeros());
            }
        }
        // Least squares on the free unknowns (Levenberg damping keeps it defined).
        let jtj = jac.transpose() * jac + SMatrix::<f64, 6, 6>::identity() * 1e-12;
        let Some(step) = jtj.cholesky().map(|c| c.solve(&(jac.transpose() * e))) else {
            break;
        };
        let mut step = step;
        // Limit the step so a bad start cannot throw the solution far away.
        let big = step.amax();
        if big > 0.2 {
            step *= 0.2 / big;
        }
        u -= step;
        for k in 3..6 {
            if u[k].abs() > lim[k] {
                u[k] = u[k].clamp(-lim[k], lim[k]);
                free[k] = false;
            }
        }
    }
    let mut e = eval(&u, &mut contacts, &mut angles, false);
    let at_limit = free.iter().any(|f| !f);
    if at_limit {
        // Raise the body until no wheel penetrates (three passes: the contacts move a little).
        for _ in 0..3 {
            let lowest = e.min();
            if lowest < 0.0 {
                u[0] += lowest;
            }
            e = eval(&u, &mut contacts, &mut angles, false);
        }
    }
    let mut clearance = [0.0; WHEELS];
    for (c, v) in clearance.iter_mut().zip(e.iter()) {
        *c = *v;
    }
    Placement {
        pose: BodyPose {
            pos_m: [pose.pos_m[0], pose.pos_m[1], u[0]],
            yaw_rad: pose.yaw_rad,
            roll_rad: u[1],
            pitch_rad: u[2],
        },
        suspension: Suspension {
            rocker_rad: u[3],
            bogie_rad: [u[4], u[5]],
        },
        contacts,
        clearance_m: clearance,
        iterations,
        at_limit,
    }
}
