//! Placing the rocker-bogie vehicle on the terrain: solve body height, roll, pitch, rocker and
//! bogie angles so that all six wheels touch the ground.
//!
//! Unknowns `u = [z, roll, pitch, beta, rho1, rho2]` (the body's north, east and yaw are given
//! by the motion model). Each wheel is a disc of its own radius `r_i` centred on its axle, in the plane
//! normal to its spin axis; its contact is the rim point of largest penetration
//! ([`wheel_contact`]: on a step the rim rests on the edge). The residual of wheel `i` is its
//! clearance `e_i(u)`. Newton's method with a finite-difference 6x6 Jacobian drives `e` to zero.
//! When a joint would pass its limit it is held at the limit, the remaining unknowns are fitted
//! in the least-squares sense, and the body is raised until no wheel penetrates the ground (the
//! wheels that then float are off the ground, as on a real vehicle at its joint limits).

use super::contact::{
    edge_contact_ahead, face_contact, ground_contact_below, wheel_contact, WheelContact,
};
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

/// Unknowns `[z, roll, pitch, beta, rho1, rho2, dx, dy, dyaw]`: the last three correct the
/// body's north, east and yaw (free only when the placement may move them, see
/// [`place_cached`]).
type Unknowns = SVector<f64, 9>;
/// Clearances of the six wheels.
type Residuals = SVector<f64, 6>;

/// Residuals `e(u)`: the clearance of each wheel (negative: penetration). With `fixed`, the
/// distance of each axle from the tangent plane at its contact of the last rim search (point
/// and normal in `contacts`) less the radius: the linearisation Newton iterates on, exact at a
/// step edge as at a smooth surface; otherwise the full rim search of [`wheel_contact`]
/// (vertical clearance), which fills `contacts`.
#[allow(clippy::too_many_arguments)]
fn residuals(
    geometry: &dyn VehicleGeometry,
    terrain: &dyn TerrainSurface,
    pose: &BodyPose,
    u: &Unknowns,
    steer_rad: &[f64; WHEELS],
    contacts: &mut [WheelContact; WHEELS],
    fixed: bool,
    lifted: &[bool; WHEELS],
) -> Residuals {
    let pose = BodyPose {
        pos_m: [pose.pos_m[0] + u[6], pose.pos_m[1] + u[7], u[0]],
        yaw_rad: pose.yaw_rad + u[8],
        roll_rad: u[1],
        pitch_rad: u[2],
    };
    let rot = pose.rot_w_from_r();
    let p = Vector3::from(pose.pos_m);
    let Some(wheels) = geometry.wheels(u[3], [u[4], u[5]], steer_rad) else {
        // Not finite: a large residual pushes Newton back.
        return Residuals::repeat(1.0);
    };
    let mut e = Residuals::zeros();
    for i in 0..WHEELS {
        let r = geometry.wheel_radius_m(i);
        let c = p + rot * wheels[i].axle_m;
        let s = rot * wheels[i].spin_axis;
        let k = &mut contacts[i];
        if fixed {
            e[i] = (c - k.point_w).dot(&k.normal_w) - r;
        } else if lifted[i] && k.angle_rad.abs() > LIFTED_ANGLE_RAD {
            // Held by a step face, off the ground: it follows the face (measured along the
            // rim's normals) unless it touches the ground below or leaves the face.
            let direction = k.angle_rad.signum();
            let below =
                ground_contact_below(terrain, &c, &s, r, k.angle_rad.abs() - LIFTED_ANGLE_RAD);
            let face = face_contact(terrain, &c, &s, r, direction);
            *k = match face {
                Some(f) if below.clearance_m >= f.clearance_m.min(0.0) => f,
                _ => wheel_contact(terrain, &c, &s, r, Some(k.angle_rad)),
            };
            e[i] = k.clearance_m;
        } else {
            let hint = k.angle_rad.is_finite().then_some(k.angle_rad);
            let mut best = wheel_contact(terrain, &c, &s, r, hint);
            // A step face or edge the rim touches, ahead or behind, measured along its normal:
            // it holds the wheel when it is (about) as close as the ground.
            for direction in [1.0, -1.0] {
                if let Some(edge) = edge_contact_ahead(terrain, &c, &s, r, direction) {
                    if edge.clearance_m < best.clearance_m + EDGE_PREFERENCE_M {
                        best = edge;
                    }
                }
            }
            *k = best;
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
        geometry,
        terrain,
        pose,
        guess,
        steer_rad,
        limits,
        &mut None,
        None,
        false,
        &[false; WHEELS],
    )
}

/// A wheel lifted off the ground by the force model follows its step-face contact while that
/// contact is more than this off the vertical below the axle, rad; the ground is searched up
/// to this much short of it.
pub const LIFTED_ANGLE_RAD: f64 = 0.35;

/// A step edge is taken as a wheel's contact when its clearance is below the ground contact's
/// plus this, m: at equal distance the edge is the one the wheel must climb.
const EDGE_PREFERENCE_M: f64 = 1e-6;

/// Convergence tolerance of Newton on the tangent planes (largest distance), m.
const TOLERANCE_M: f64 = 1e-9;
/// Largest clearance of the confirming rim search that ends the placement, m (the rim search
/// locates a smooth maximum to about 0.1 micrometre).
const CONFIRM_M: f64 = 1e-6;

/// Jacobian `d e / d u` kept between placements (chord method).
pub type PlacementJacobian = SMatrix<f64, 6, 9>;

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
/// `previous_contacts` are the contacts of the previous placement: Newton starts on their tangent
/// planes, and the rim search follows their contact angles (see [`wheel_contact`]).
///
/// With `move_planar`, the correction may also move the body's north, east and yaw: each
/// Newton step is the minimum-norm correction of all nine unknowns (metres and radians), the
/// projection onto the contact constraints nearest to the integrated pose. A wheel that has
/// rolled into a step face is then pushed back off the face by the overlap instead of being
/// lifted by the much larger vertical penetration the face shows near a 90 deg contact angle.
/// Without it (the initial placement), north, east and yaw are held.
///
/// `lifted[i]`: the force model ([`super::forces`]) carries wheel `i` on a step face or edge
/// only (it has been lifted off the ground below). Such a wheel's contact is its face contact
/// measured along the rim's normals ([`face_contact`]), not the vertical clearance, unless the
/// ground below touches first or the face is no longer within reach; so the placement does not
/// set a climbing wheel back on the ground.
#[allow(clippy::too_many_arguments)]
pub fn place_cached(
    geometry: &dyn VehicleGeometry,
    terrain: &dyn TerrainSurface,
    pose: &BodyPose,
    guess: &Suspension,
    steer_rad: &[f64; WHEELS],
    limits: &JointLimits,
    cache: &mut Option<PlacementJacobian>,
    previous_contacts: Option<&[WheelContact; WHEELS]>,
    move_planar: bool,
    lifted: &[bool; WHEELS],
) -> Placement {
    let mut u = Unknowns::from_column_slice(&[
        pose.pos_m[2],
        pose.roll_rad,
        pose.pitch_rad,
        guess.rocker_rad,
        guess.bogie_rad[0],
        guess.bogie_rad[1],
        0.0,
        0.0,
        0.0,
    ]);
    let mut contacts = previous_contacts.copied().unwrap_or([no_contact(); WHEELS]);
    let mut iterations = 0;
    let mut free = [
        true,
        true,
        true,
        true,
        true,
        true,
        move_planar,
        move_planar,
        move_planar,
    ];
    let lim = [
        f64::INFINITY,
        f64::INFINITY,
        f64::INFINITY,
        limits.rocker_rad,
        limits.bogie_rad,
        limits.bogie_rad,
        f64::INFINITY,
        f64::INFINITY,
        f64::INFINITY,
    ];
    let mut previous = f64::INFINITY;
    let eval = |u: &Unknowns, contacts: &mut [WheelContact; WHEELS], fixed| {
        residuals(
            geometry, terrain, pose, u, steer_rad, contacts, fixed, lifted,
        )
    };
    // Newton on the distances to the contacts' tangent planes, with a
    // full rim search at the start and to confirm convergence: a contact that moves to another
    // part of the rim (a rock entering ahead of the axle) restarts the iterations there.
    let mut fixed = previous_contacts.is_some();
    for _ in 0..40 {
        iterations += 1;
        let e = eval(&u, &mut contacts, fixed);
        let size = e.amax();
        if fixed && size < TOLERANCE_M {
            fixed = false;
            continue;
        }
        if !fixed && size < CONFIRM_M {
            break;
        }
        fixed = true;
        let stale = size > 0.25 * previous;
        previous = size;
        let jac = match cache {
            Some(j) if !stale => *j,
            _ => {
                let j = finite_difference_jacobian(&eval, &u, &mut contacts);
                *cache = Some(j);
                j
            }
        };
        let Some(step) = newton_step(jac, &free, &e) else {
            break;
        };
        u -= step;
        for k in 3..6 {
            if u[k].abs() > lim[k] {
                u[k] = u[k].clamp(-lim[k], lim[k]);
                free[k] = false;
            }
        }
    }
    let at_limit = free.iter().any(|f| !f);
    let e = raised_residuals(&eval, &mut u, &mut contacts, at_limit);
    placement(pose, &u, contacts, &e, iterations, at_limit)
}

/// Finite-difference step of the placement Jacobian (at fixed contact angles), m or rad.
const JACOBIAN_STEP: f64 = 1e-7;

/// The Jacobian `d e / d u` at `u` by forward differences at fixed contact angles.
fn finite_difference_jacobian(
    eval: &impl Fn(&Unknowns, &mut [WheelContact; WHEELS], bool) -> Residuals,
    u: &Unknowns,
    contacts: &mut [WheelContact; WHEELS],
) -> PlacementJacobian {
    let h = JACOBIAN_STEP;
    let mut j = PlacementJacobian::zeros();
    let e0 = eval(u, contacts, true);
    for k in 0..9 {
        let mut up = *u;
        up[k] += h;
        let ep = eval(&up, contacts, true);
        j.set_column(k, &((ep - e0) / h));
    }
    j
}

/// The Newton step for residuals `e`: the minimum-norm step over the `free` unknowns (the
/// damping keeps it defined when a joint stop leaves fewer than six), at most 0.2 in any
/// unknown so a bad start cannot throw the solution far away. `None` when the normal matrix
/// cannot be factored.
fn newton_step(mut jac: PlacementJacobian, free: &[bool; 9], e: &Residuals) -> Option<Unknowns> {
    for (k, is_free) in free.iter().enumerate() {
        if !is_free {
            jac.set_column(k, &Residuals::zeros());
        }
    }
    let jjt = jac * jac.transpose() + SMatrix::<f64, 6, 6>::identity() * 1e-12;
    let y = jjt.cholesky().map(|c| c.solve(e))?;
    let mut step = jac.transpose() * y;
    let big = step.amax();
    if big > 0.2 {
        step *= 0.2 / big;
    }
    Some(step)
}

/// The residuals at the solution `u`; at a joint stop the body is first raised until no wheel
/// penetrates (three passes: the contacts move a little).
fn raised_residuals(
    eval: &impl Fn(&Unknowns, &mut [WheelContact; WHEELS], bool) -> Residuals,
    u: &mut Unknowns,
    contacts: &mut [WheelContact; WHEELS],
    at_limit: bool,
) -> Residuals {
    let mut e = eval(u, contacts, false);
    if at_limit {
        for _ in 0..3 {
            let lowest = e.min();
            if lowest < 0.0 {
                u[0] += lowest;
            }
            e = eval(u, contacts, false);
        }
    }
    e
}

/// The placement of the unknowns `u` (relative to `pose` in north, east and yaw).
fn placement(
    pose: &BodyPose,
    u: &Unknowns,
    contacts: [WheelContact; WHEELS],
    e: &Residuals,
    iterations: u32,
    at_limit: bool,
) -> Placement {
    let mut clearance = [0.0; WHEELS];
    for (c, v) in clearance.iter_mut().zip(e.iter()) {
        *c = *v;
    }
    Placement {
        pose: BodyPose {
            pos_m: [pose.pos_m[0] + u[6], pose.pos_m[1] + u[7], u[0]],
            yaw_rad: pose.yaw_rad + u[8],
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
