//! Quasi-static force model of the rocker-bogie: which wheels roll, which slip, and which
//! contact lets go, decided by a force balance instead of an equal-weight compromise.
//!
//! **Unknowns** are those of the rolling solve ([`super::rolling`]): the generalised velocity
//! `x = [v; w; q_dot]` (body velocity and rate in `R`, rocker and bogie rates). A wheel may
//! touch the terrain at more than one point (on the ground and against a step face): every
//! contact `c` of wheel `i` has the three rows of [`contact_rows`], normal `a_n`, rolling
//! tangent `a_t` and lateral `a_l`, which give the velocity of the wheel's material contact
//! point before its own spin; its **slip velocity** beyond what the soil's slip model
//! ([`crate::soil::per_wheel_slip`], [`crate::soil::lumped_slip`]) already gives is
//! `u_c = (a_t x - b_t,i, a_l x - b_l,i)`, with `b_t,i` the wheel's ground speed (its rim speed
//! `r_i theta_dot_i` less the soil slip) and `b_l,i` its sideways slip velocity.
//!
//! **Contact forces.** Each contact carries a normal force `N_c >= 0` along its normal and a
//! friction force `F_c` in its tangent plane, bounded by Coulomb's cone `|F_c| <= mu N_c`. Below
//! the bound the contact creeps: `F_c = -k u_c` (the linear start of the Janosi-Hanamoto shear
//! curve, see [`creep_stiffness`]); at the bound it slides, `F_c = -mu N_c u_c / |u_c|`. The
//! normal rows are stiff penalties (`N_c = -k NORMAL_WEIGHT^2 a_n x`, weight 1000 as in the
//! rolling solve: the wheel neither sinks nor lifts while the contact is active).
//!
//! **Balance.** Quasi-static equilibrium of the linkage (body, rockers, bogies; massless links,
//! frictionless pivots, an ideal differential; the motors hold the wheel spins): by virtual work
//! along every generalised velocity,
//!
//! `sum_c (N_c a_n,c + F_t,c a_t,c + F_l,c a_l,c) + G = 0`,
//!
//! with `G` the generalised force of the weight `W` at the centre of mass `p_cm` (body fixed):
//! `G = W [g; p_cm x g; 0]`, `g` the unit gravity direction in `R`. The soil's slip model
//! already accounts for the weight's component along the body's `x` and `y` axes (it computes
//! the slip of the traction that balances the slope from them), so `G` keeps only the body-`z`
//! component of the force (and the full moment): the force model adds the work of lifting the
//! body along its own `z` (climbing a step), not the slope a second time. On a plane the free
//! motions (forward, sideways, yaw) do no work against this `G`, so there the model is the
//! rolling solve's least squares exactly.
//!
//! This balance is the stationarity condition of
//! `J(x) = sum_c (k/2 NORMAL_WEIGHT^2 (a_n x)^2 + rho_c(u_c)) - G . x`, with `rho_c` Huber's
//! function (quadratic `k/2 |u|^2` up to `|u| = mu N_c / k`, linear beyond): the principle of
//! minimum dissipation of quasi-static wheeled vehicles with Coulomb friction (Alexander &
//! Maddocks, "On the kinematics of wheeled mobile robots", IJRR 8(5), 1989), with the soil's
//! creep below the friction bound. It is solved by iteratively reweighted least squares with a
//! fixed number of passes ([`ITERATIONS`]): each pass is the rolling solve's weighted least
//! squares with the weight of a sliding contact lowered to `mu N_c / (k |u_c|)` (so its friction
//! is exactly at the cone), `N_c` from the previous pass.
//!
//! **Unilateral contacts.** A contact whose normal force comes out negative (it would have to
//! pull) is released: the wheel leaves that surface (one contact per pass, the most negative).
//! A released contact whose wheel would move into its surface is taken back. So a wheel
//! pressed against a step face by the push of the others is lifted off the ground when the
//! friction at the face (`mu N_face`, upwards while the wheel turns against the face) carries
//! its share of the weight: the classic climbing condition of a rocker-bogie wheel at a step
//! (Lindemann & Voorhees, "Mars Exploration Rover mobility assembly design, test and
//! performance", IEEE SMC 2005; Iagnemma & Dubowsky, *Mobile Robots in Rough Terrain*,
//! Springer 2004, quasi-static force analysis).

use super::geometry::{TruthGeometry, WheelPose, WHEELS};
use super::rolling::{contact_rows, RollingContact, Row, Twist, LATERAL_WEIGHT, NORMAL_WEIGHT};
use nalgebra::{SMatrix, SVector, Vector3};

/// Passes of the reweighted least squares (each one 9x9 Cholesky solve).
pub const ITERATIONS: usize = 24;
/// Rim speed under which the creep stiffness is evaluated at this speed instead, m/s (a
/// stationary rover would otherwise have an infinitely stiff creep).
pub const CREEP_SPEED_FLOOR_M_S: f64 = 0.01;
/// Speed away from its surface above which a contact carries no load in the next pass, m/s.
const SEPARATION_TOLERANCE_M_S: f64 = 1e-7;
/// The passes stop early when no weight changes by more than this fraction and no contact is
/// taken or released.
const SETTLED_WEIGHT: f64 = 1e-3;
/// Smallest relative weight of a sliding contact (keeps the normal equations defined).
const MIN_WEIGHT: f64 = 1e-6;

/// Friction of the wheel-terrain contacts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Friction {
    /// Coulomb coefficient `mu = tan(phi)` of the soil (its friction angle).
    pub mu: f64,
    /// Slip ratio at which the linearised creep reaches the friction bound: `2 K / L` of the
    /// Janosi-Hanamoto law (see [`creep_stiffness`]).
    pub creep_slip: f64,
}

/// The weight and where it acts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weight {
    /// Weight, N.
    pub weight_n: f64,
    /// Centre of mass in `R`, m.
    pub centre_of_mass_m: Vector3<f64>,
    /// Unit gravity direction in `R`.
    pub gravity_r: Vector3<f64>,
}

/// One contact of a wheel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceContact {
    /// Wheel index (0..6).
    pub wheel: usize,
    /// Contact frame and whether it touches.
    pub contact: RollingContact,
}

/// The solution of the quasi-static model.
#[derive(Debug, Clone, PartialEq)]
pub struct QuasiStatic {
    /// Body twist and suspension rates.
    pub twist: Twist,
    /// Normal force of each contact (input order), N (0 when released or not touching).
    pub normal_n: Vec<f64>,
    /// Friction force of each contact `[tangent, lateral]`, N.
    pub friction_n: Vec<[f64; 2]>,
    /// Whether each contact carries load at the end.
    pub active: Vec<bool>,
    /// Whether each contact slides (its friction at the Coulomb bound).
    pub sliding: Vec<bool>,
    /// Normal load of each wheel (sum over its contacts), N.
    pub wheel_load_n: [f64; WHEELS],
    /// Creep stiffness used, N/(m/s).
    pub creep_stiffness: f64,
}

/// Creep stiffness `k`, N/(m/s): the Janosi-Hanamoto traction `F = F_max (1 - K/(sL)(1 -
/// exp(-sL/K)))` (Wong, *Theory of Ground Vehicles*, ch. 2) starts as `F_max s L / (2 K)`, so a
/// slip velocity `u` at rim speed `V` (slip ratio `u / V`) gives `F = F_max u / (s* V)` with
/// `s* = 2 K / L`. With `F_max = mu W / 6` (the mean wheel load; one stiffness for every
/// contact, so that below the friction bound the model is the rolling solve's equal-weight
/// least squares) and `V` the mean rim speed of the wheels on the ground (at least
/// [`CREEP_SPEED_FLOOR_M_S`]).
pub fn creep_stiffness(friction: &Friction, weight_n: f64, rim_speed_m_s: f64) -> f64 {
    let v = rim_speed_m_s.abs().max(CREEP_SPEED_FLOOR_M_S);
    friction.mu * weight_n / WHEELS as f64 / (friction.creep_slip.max(1e-3) * v)
}

/// The contacts' rows and the per-wheel drive of one quasi-static solve.
struct Problem<'a> {
    contacts: &'a [ForceContact],
    /// `[normal, tangent, lateral]` rows of each contact.
    rows: Vec<[Row; 3]>,
    ground_speed: &'a [f64; WHEELS],
    lateral: &'a [f64; WHEELS],
    /// The weight's row of the normal equations.
    gravity: Row,
    /// Creep stiffness, N/(m/s).
    k: f64,
}

/// The state of the reweighting passes.
struct Passes {
    /// Creep weight of each contact (1: creeping; below: sliding at the Coulomb bound).
    w: Vec<f64>,
    /// Normal force of each contact, N.
    normal: Vec<f64>,
    /// Slip velocity of each contact `[tangent, lateral]`, m/s.
    slip: Vec<[f64; 2]>,
    sliding: Vec<bool>,
    /// Relaxed normal force of each contact's friction bound, N.
    bound_n: Vec<f64>,
    first: bool,
}

/// Mean rim speed of the wheels on the ground, m/s.
fn mean_rim_speed(
    contacts: &[ForceContact],
    ground_speed: &[f64; WHEELS],
    slip_factor: &[f64; WHEELS],
) -> f64 {
    let mut on_ground = [false; WHEELS];
    for c in contacts.iter().filter(|c| c.contact.touching) {
        on_ground[c.wheel] = true;
    }
    let count = on_ground.iter().filter(|g| **g).count();
    (0..WHEELS)
        .filter(|i| on_ground[*i])
        .map(|i| (ground_speed[i] / slip_factor[i].max(1e-6)).abs())
        .sum::<f64>()
        / count.max(1) as f64
}

/// The weight's generalised force: its normal component and its moment about the reference
/// point.
fn gravity_row(weight: &Weight) -> Row {
    let g = weight.gravity_r.normalize();
    let moment = weight.centre_of_mass_m.cross(&g);
    Row::from_column_slice(&[
        0.0,
        0.0,
        g.z * weight.weight_n,
        moment.x * weight.weight_n,
        moment.y * weight.weight_n,
        moment.z * weight.weight_n,
        0.0,
        0.0,
        0.0,
    ])
}

#[allow(clippy::needless_range_loop)] // parallel arrays per contact
impl Problem<'_> {
    /// The weighted normal equations of the active contacts, `None` when fewer than three
    /// wheels carry load.
    fn normal_equations(
        &self,
        active: &[bool],
        w: &[f64],
    ) -> Option<(SMatrix<f64, 9, 9>, SVector<f64, 9>)> {
        let mut wheel_active = [false; WHEELS];
        let mut ata = SMatrix::<f64, 9, 9>::identity() * 1e-9;
        let mut atb = self.gravity / self.k;
        for c in 0..self.contacts.len() {
            if !active[c] {
                continue;
            }
            let i = self.contacts[c].wheel;
            wheel_active[i] = true;
            let [a_n, a_t, a_l] = &self.rows[c];
            let lw2 = LATERAL_WEIGHT * LATERAL_WEIGHT;
            ata += a_n * a_n.transpose() * (NORMAL_WEIGHT * NORMAL_WEIGHT)
                + (a_t * a_t.transpose() + a_l * a_l.transpose() * lw2) * w[c];
            atb += (a_t * self.ground_speed[i] + a_l * (self.lateral[i] * lw2)) * w[c];
        }
        (wheel_active.iter().filter(|a| **a).count() >= 3).then_some((ata, atb))
    }

    /// Normal forces and slip velocities of the pass with solution `x`.
    fn forces_of(&self, x: &SVector<f64, 9>, active: &[bool], passes: &mut Passes) {
        let normal_k = self.k * NORMAL_WEIGHT * NORMAL_WEIGHT;
        for c in 0..self.contacts.len() {
            let i = self.contacts[c].wheel;
            let [a_n, a_t, a_l] = &self.rows[c];
            passes.slip[c] = [
                a_t.dot(x) - self.ground_speed[i],
                a_l.dot(x) - self.lateral[i],
            ];
            passes.normal[c] = if active[c] {
                -normal_k * a_n.dot(x)
            } else {
                0.0
            };
        }
    }
}

#[allow(clippy::needless_range_loop)] // parallel arrays per contact
impl Passes {
    /// Reweight: a contact whose creep force would exceed mu N slides at mu N. The normal
    /// force of the bound is relaxed (half the previous bound, half this pass's force) so the
    /// coupling of the bounds and the normal forces settles instead of oscillating. Returns
    /// whether no weight changed by more than [`SETTLED_WEIGHT`].
    fn reweight(&mut self, active: &[bool], k: f64, mu: f64) -> bool {
        let mut settled = true;
        for c in 0..self.w.len() {
            let slip = self.slip[c];
            let u = (slip[0] * slip[0] + slip[1] * slip[1]).sqrt();
            let previous_w = self.w[c];
            self.bound_n[c] = if self.first {
                self.normal[c].max(0.0)
            } else {
                0.5 * (self.bound_n[c] + self.normal[c].max(0.0))
            };
            let bound = mu * self.bound_n[c];
            self.sliding[c] = active[c] && k * u > bound;
            self.w[c] = if self.sliding[c] {
                (bound / (k * u)).max(MIN_WEIGHT)
            } else {
                1.0
            };
            settled &= (self.w[c] - previous_w).abs() <= SETTLED_WEIGHT * previous_w;
        }
        self.first = false;
        settled
    }
}

/// Solve the quasi-static model. `wheels` are the wheel poses in `R` at `rocker_rad`,
/// `bogie_rad`; `contacts` every contact of every wheel (a wheel may have several);
/// `ground_speed`, `slip_factor`, `lateral` per wheel as in
/// [`super::rolling::solve_rolling`].
#[allow(clippy::too_many_arguments)]
pub fn solve_quasi_static(
    geometry: &TruthGeometry,
    wheels: &[WheelPose; WHEELS],
    rocker_rad: f64,
    bogie_rad: [f64; 2],
    contacts: &[ForceContact],
    ground_speed: &[f64; WHEELS],
    slip_factor: &[f64; WHEELS],
    lateral: &[f64; WHEELS],
    friction: &Friction,
    weight: &Weight,
) -> QuasiStatic {
    let n = contacts.len();
    let rows: Vec<[Row; 3]> = contacts
        .iter()
        .map(|c| {
            contact_rows(
                geometry,
                wheels,
                rocker_rad,
                bogie_rad,
                c.wheel,
                &c.contact,
                slip_factor[c.wheel],
            )
        })
        .collect();
    let mut active: Vec<bool> = contacts.iter().map(|c| c.contact.touching).collect();
    let rim = mean_rim_speed(contacts, ground_speed, slip_factor);
    let k = creep_stiffness(friction, weight.weight_n, rim);
    let problem = Problem {
        contacts,
        rows,
        ground_speed,
        lateral,
        gravity: gravity_row(weight),
        k,
    };
    let mut passes = Passes {
        w: vec![1.0; n],
        normal: vec![0.0; n],
        slip: vec![[0.0; 2]; n],
        sliding: vec![false; n],
        bound_n: vec![0.0; n],
        first: true,
    };
    let mut x = SVector::<f64, 9>::zeros();
    let mut solved = false;
    // Weights and active set of the last solve (the result).
    let mut w_solved = passes.w.clone();
    let mut active_solved = active.clone();
    for _ in 0..ITERATIONS {
        let Some(sol) = problem
            .normal_equations(&active, &passes.w)
            .and_then(|(ata, atb)| ata.cholesky().map(|ch| ch.solve(&atb)))
        else {
            solved = false;
            break;
        };
        x = sol;
        solved = true;
        w_solved.clone_from(&passes.w);
        active_solved.clone_from(&active);
        problem.forces_of(&x, &active, &mut passes);
        let mut settled = passes.reweight(&active, k, friction.mu);
        // Unilateral contacts (the semi-smooth Newton step of a one-sided penalty): a contact
        // carries load in the next pass when its wheel does not leave it in this one.
        for c in 0..n {
            let now = contacts[c].contact.touching
                && problem.rows[c][0].dot(&x) <= SEPARATION_TOLERANCE_M_S;
            settled &= now == active[c];
            active[c] = now;
        }
        // Nothing changed: this pass is the solution (on smooth ground without a sliding wheel,
        // the first pass, the rolling solve's least squares).
        if settled {
            break;
        }
    }
    solution(contacts, passes, &x, solved, &w_solved, active_solved, k)
}

/// The result of the last solve `x` (zero twist when no solve succeeded) with the weights
/// `w` and active set `active` it was made with.
fn solution(
    contacts: &[ForceContact],
    passes: Passes,
    x: &SVector<f64, 9>,
    solved: bool,
    w: &[f64],
    active: Vec<bool>,
    k: f64,
) -> QuasiStatic {
    let n = contacts.len();
    let Passes {
        mut normal,
        slip,
        mut sliding,
        ..
    } = passes;
    let mut wheel_load_n = [0.0; WHEELS];
    let mut friction_n = vec![[0.0; 2]; n];
    for c in 0..n {
        let u = (slip[c][0] * slip[c][0] + slip[c][1] * slip[c][1]).sqrt();
        sliding[c] = w[c] < 1.0 && u > 0.0;
        if !active[c] || !solved {
            normal[c] = 0.0;
            sliding[c] = false;
            continue;
        }
        normal[c] = normal[c].max(0.0);
        wheel_load_n[contacts[c].wheel] += normal[c];
        friction_n[c] = [-k * w[c] * slip[c][0], -k * w[c] * slip[c][1]];
    }
    let touching = (0..WHEELS)
        .filter(|i| (0..n).any(|c| active[c] && contacts[c].wheel == *i))
        .count();
    let twist = if solved {
        Twist {
            v: Vector3::new(x[0], x[1], x[2]),
            w: Vector3::new(x[3], x[4], x[5]),
            suspension_rad_s: [x[6], x[7], x[8]],
            contacts: touching,
        }
    } else {
        Twist {
            v: Vector3::zeros(),
            w: Vector3::zeros(),
            suspension_rad_s: [0.0; 3],
            contacts: touching,
        }
    };
    QuasiStatic {
        twist,
        normal_n: normal,
        friction_n,
        active,
        sliding,
        wheel_load_n,
        creep_stiffness: k,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vehicle::geometry::{rocky8, VehicleGeometry};
    use crate::vehicle::rolling::solve_rolling;

    const WEIGHT_N: f64 = 150.0 * 3.711;

    fn weight() -> Weight {
        Weight {
            weight_n: WEIGHT_N,
            centre_of_mass_m: Vector3::new(0.0, 0.0, -0.25),
            gravity_r: Vector3::z(),
        }
    }

    fn on_ground(wheels: &[WheelPose; WHEELS]) -> Vec<ForceContact> {
        (0..WHEELS)
            .map(|i| ForceContact {
                wheel: i,
                contact: RollingContact::new(true, -Vector3::z(), wheels[i].spin_axis),
            })
            .collect()
    }

    /// SIM-27: on level ground with every wheel able to roll (right wheels 1 % larger, so the
    /// rolling rows conflict a little), the force model is the rolling solve's least squares
    /// (the creep regime, the weight does no work), and its loads carry the weight.
    #[test]
    fn sim_27_level_ground_is_the_rolling_solve() {
        let mut g = rocky8();
        for i in [0, 2, 4] {
            g.wheel_radius_m[i] = 0.101;
        }
        let w = g.wheels(0.0, [0.0; 2], &[0.0; WHEELS]).unwrap();
        let speed: [f64; WHEELS] = std::array::from_fn(|i| g.wheel_radius_m(i) * 1.0);
        let friction = Friction {
            mu: 0.7,
            creep_slip: 0.2,
        };
        let contacts = on_ground(&w);
        let q = solve_quasi_static(
            &g,
            &w,
            0.0,
            [0.0; 2],
            &contacts,
            &speed,
            &[1.0; WHEELS],
            &[0.0; WHEELS],
            &friction,
            &weight(),
        );
        let rolling = solve_rolling(
            &g,
            &w,
            0.0,
            [0.0; 2],
            &contacts
                .iter()
                .map(|c| c.contact)
                .collect::<Vec<_>>()
                .try_into()
                .unwrap(),
            &speed,
            &[1.0; WHEELS],
            &[0.0; WHEELS],
        );
        assert!((q.twist.v - rolling.v).norm() < 1e-7, "{q:?} {rolling:?}");
        assert!((q.twist.w - rolling.w).norm() < 1e-7, "{q:?} {rolling:?}");
        let total: f64 = q.wheel_load_n.iter().sum();
        assert!((total - WEIGHT_N).abs() < 1e-3 * WEIGHT_N, "{total}");
        assert!(q.sliding.iter().all(|s| !s));
    }

    /// SIM-27: the right front wheel pressed against a step face (a second contact with a
    /// horizontal normal) while all wheels turn at 0.08 m/s: every contact's friction stays in
    /// its Coulomb cone (within 2 % and 1 mN, the relaxation of the bounds), no normal force pulls,
    /// and the wheel is lifted off the ground with a high friction
    /// coefficient (its ground contact carries nothing) but not with a low one.
    #[test]
    fn sim_27_wheel_at_a_face_is_lifted_by_friction() {
        let g = rocky8();
        let w = g.wheels(0.0, [0.0; 2], &[0.0; WHEELS]).unwrap();
        let mut contacts = on_ground(&w);
        contacts.push(ForceContact {
            wheel: 0,
            contact: RollingContact::new(true, -Vector3::x(), w[0].spin_axis),
        });
        let speed = [0.08; WHEELS];
        let mut released = Vec::new();
        for mu in [1.0, 0.2] {
            let friction = Friction {
                mu,
                creep_slip: 0.2,
            };
            let q = solve_quasi_static(
                &g,
                &w,
                0.0,
                [0.0; 2],
                &contacts,
                &speed,
                &[1.0; WHEELS],
                &[0.0; WHEELS],
                &friction,
                &weight(),
            );
            for c in 0..contacts.len() {
                let f = q.friction_n[c];
                let size = (f[0] * f[0] + f[1] * f[1]).sqrt();
                assert!(q.normal_n[c] >= 0.0);
                assert!(
                    size <= 1.02 * mu * q.normal_n[c] + 1e-3,
                    "mu {mu} contact {c} {q:?}"
                );
            }
            assert!(q.normal_n[6] > 0.0, "pressed against the face: {q:?}");
            released.push(q.normal_n[0] < 1e-3);
        }
        assert_eq!(released, [true, false]);
    }
}
