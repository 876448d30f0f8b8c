//! Placing the rocker-bogie vehicle on the terrain: solve body height, roll, pitch, rocker and
//! bogie angles so that all six wheels touch the ground.
//!
//! Unknowns `u = [z, roll, pitch, beta, rho1, rho2]` (the body's north, east and yaw are given
//! by the motion model). Each wheel is a disc of radius `r` centred on its axle, in the plane
//! normal to its spin axis; its contact point is the point of the disc furthest along the
//! terrain's downward normal. The residual of wheel `i` is the height of that point above the
//! terrain, `e_i(u)`. Newton's method with a finite-difference 6x6 Jacobian drives `e` to zero.
//! When a joint would pass its limit it is held at the limit, the remaining unknowns are fitted
//! in the least-squares sense, and the body is raised until no wheel penetrates the ground (the
//! wheels that then float are off the ground, as on a real vehicle at its joint limits).

use super::geometry::{VehicleGeometry, WHEELS};
use crate::surface::TerrainSurface;
use fsw::kinematics::RoverGeometry;
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
    /// The stops of the truth vehicle: 95 % of the range the flight geometry accepts (no source
    /// gives Rocky 8's stops; the margin keeps every simulated state inside the flight range).
    pub fn of(geometry: &RoverGeometry) -> Self {
        Self {
            rocker_rad: 0.95 * geometry.limits.rocker_rad,
            bogie_rad: 0.95 * geometry.limits.bogie_rad,
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
    /// Wheel contact points in `W`, m.
    pub contacts_w: [[f64; 3]; WHEELS],
    /// Height of each wheel above the ground at the end (0 for a touching wheel), m.
    pub clearance_m: [f64; WHEELS],
    /// Newton iterations used.
    pub iterations: u32,
    /// A joint limit was active.
    pub at_limit: bool,
}

type Unknowns = SVector<f64, 6>;

/// Upward terrain normals in `W` under the six axles, with the axle's north/east where each
/// was evaluated; kept between placements and refreshed when the axle has moved more than
/// [`NORMAL_REFRESH_M`].
pub type NormalCache = [Option<([f64; 2], Vector3<f64>)>; WHEELS];

/// Horizontal axle motion after which the terrain normal under it is evaluated again, m.
pub const NORMAL_REFRESH_M: f64 = 0.002;

/// Residuals `e(u)`. The terrain normal under each axle comes from `normals` (see
/// [`NormalCache`]).
fn residuals(
    geometry: &dyn VehicleGeometry,
    terrain: &dyn TerrainSurface,
    pose: &BodyPose,
    u: &Unknowns,
    steer_rad: &[f64; WHEELS],
    contacts: &mut [[f64; 3]; WHEELS],
    normals: &mut NormalCache,
) -> Unknowns {
    let pose = BodyPose {
        pos_m: [pose.pos_m[0], pose.pos_m[1], u[0]],
        yaw_rad: pose.yaw_rad,
        roll_rad: u[1],
        pitch_rad: u[2],
    };
    let susp = Suspension {
        rocker_rad: u[3],
        bogie_rad: [u[4], u[5]],
    };
    let rot = pose.rot_w_from_r();
    let p = Vector3::from(pose.pos_m);
    let Some(wheels) = geometry.wheels(susp.rocker_rad, susp.bogie_rad, steer_rad) else {
        // Outside the geometry's range: a large residual pushes Newton back.
        return Unknowns::repeat(1.0);
    };
    let r = geometry.wheel_radius_m();
    let mut e = Unknowns::zeros();
    for i in 0..WHEELS {
        let c = p + rot * wheels[i].axle_m;
        let s = rot * wheels[i].spin_axis;
        let up = match normals[i] {
            Some((xy, n))
                if (xy[0] - c.x).powi(2) + (xy[1] - c.y).powi(2)
                    < NORMAL_REFRESH_M * NORMAL_REFRESH_M =>
            {
                n
            }
            _ => {
                let n = terrain.normal_up(c.x, c.y);
                // Upward normal in W (z down).
                let n = Vector3::new(n[0], n[1], -n[2]);
                normals[i] = Some(([c.x, c.y], n));
                n
            }
        };
        let perp = up - s * up.dot(&s);
        let norm = perp.norm();
        let dir = if norm > 1e-9 {
            perp / norm
        } else {
            Vector3::new(0.0, 0.0, -1.0)
        };
        let contact = c - dir * r;
        contacts[i] = [contact.x, contact.y, contact.z];
        e[i] = -contact.z - terrain.height_m(contact.x, contact.y);
    }
    e
}

/// Place the vehicle at the north/east/yaw of `pose`, starting Newton from `guess_pose` and
/// `guess` (the previous step's solution).
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
        &mut [None; WHEELS],
    )
}

/// Jacobian `d e / d u` kept between placements (chord method).
pub type PlacementJacobian = SMatrix<f64, 6, 6>;

/// [`place`] reusing the Jacobian of an earlier placement (the chord method: between two 5 ms
/// steps the configuration barely changes) and the terrain normals under the axles
/// ([`NormalCache`]). The Jacobian is recomputed by finite differences
/// when there is none or when an iteration reduces the residual by less than 4x; the solution
/// is the same (to the 1e-9 m tolerance), only cheaper.
#[allow(clippy::too_many_arguments)]
pub fn place_cached(
    geometry: &dyn VehicleGeometry,
    terrain: &dyn TerrainSurface,
    pose: &BodyPose,
    guess: &Suspension,
    steer_rad: &[f64; WHEELS],
    limits: &JointLimits,
    cache: &mut Option<PlacementJacobian>,
    normals: &mut NormalCache,
) -> Placement {
    let mut u = Unknowns::new(
        pose.pos_m[2],
        pose.roll_rad,
        pose.pitch_rad,
        guess.rocker_rad,
        guess.bogie_rad[0],
        guess.bogie_rad[1],
    );
    let mut contacts = [[0.0; 3]; WHEELS];
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
    for _ in 0..40 {
        iterations += 1;
        let e = residuals(
            geometry,
            terrain,
            pose,
            &u,
            steer_rad,
            &mut contacts,
            normals,
        );
        let size = e.amax();
        if size < 1e-9 {
            break;
        }
        let stale = size > 0.25 * previous;
        previous = size;
        let mut jac = match cache {
            Some(j) if !stale => *j,
            _ => {
                let mut j = PlacementJacobian::zeros();
                let mut scratch = [[0.0; 3]; WHEELS];
                for k in 0..6 {
                    let mut up = u;
                    up[k] += h;
                    let ep = residuals(
                        geometry,
                        terrain,
                        pose,
                        &up,
                        steer_rad,
                        &mut scratch,
                        normals,
                    );
                    j.set_column(k, &((ep - e) / h));
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
    let mut e = residuals(
        geometry,
        terrain,
        pose,
        &u,
        steer_rad,
        &mut contacts,
        normals,
    );
    let at_limit = free.iter().any(|f| !f);
    if at_limit {
        // Raise the body until no wheel penetrates (twice: the contacts move a little).
        for _ in 0..3 {
            let lowest = e.min();
            if lowest < 0.0 {
                u[0] += lowest;
            }
            e = residuals(
                geometry,
                terrain,
                pose,
                &u,
                steer_rad,
                &mut contacts,
                normals,
            );
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
        contacts_w: contacts,
        clearance_m: clearance,
        iterations,
        at_limit,
    }
}
