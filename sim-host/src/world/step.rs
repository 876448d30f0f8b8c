//! [`World::step`]: one minor frame of the truth, in the order of the motion model of the
//! module documentation ([`crate::world`]): motors, contacts, soil slip, the quasi-static body
//! twist (with its plausibility, cap and inertia bounds), wheels lifted onto faces, integration
//! and placement, the truth's bookkeeping (scrub, energy), and the sensors.

use super::{Slip, World, FRAME_US, MARS_GRAVITY_M_S2};
use crate::sensors::faults::{FaultDevice, FaultKind};
use crate::soil::per_wheel_slip::{centre_of_mass, SlipState, WheelGround, WheelSlip};
use crate::soil::terramechanics::ROCKY8_MASS_KG;
use crate::surface::TerrainSurface;
use crate::vehicle::contact::{face_contact, ground_contact_below, WheelContact, EDGE_PROBE_M};
use crate::vehicle::forces::{solve_quasi_static, ForceContact, QuasiStatic, Weight};
use crate::vehicle::geometry::{VehicleGeometry, WheelPose, WHEELS};
use crate::vehicle::placement::{place_cached, BodyPose, Placement, Suspension, LIFTED_ANGLE_RAD};
use crate::vehicle::rolling::{RollingContact, Twist, CONTACT_TOLERANCE_M};
use nalgebra::{Rotation3, Vector3};

/// Two contacts of one wheel are distinct when their normals differ by more than about 10 deg
/// (cosine below this).
const DISTINCT_COS: f64 = 0.985;
/// A wheel whose contact is more than this off the vertical below its axle (on an edge or a
/// face) is also searched for the ground below, up to this much short of that contact, rad.
const BELOW_ANGLE_RAD: f64 = 0.35;

/// The state of the vehicle at the start of a step, fixed over the step.
struct StepStart {
    /// The step, s.
    dt: f64,
    /// The wheels in `R` at the start configuration (with the step's steering).
    wheels: [WheelPose; WHEELS],
    /// Body pose.
    pose0: BodyPose,
    /// `R` to `W`, and its inverse.
    rot: Rotation3<f64>,
    rot_inv: Rotation3<f64>,
    /// Suspension.
    s0: Suspension,
    /// The placement's contact of each wheel as a rolling contact (in `R`).
    contacts: [RollingContact; WHEELS],
}

/// What the wheels drive over the step, after the soil's slip.
struct WheelDrive {
    /// Per-wheel slip (after the slip-override fault).
    wheel_slip: [WheelSlip; WHEELS],
    /// The vehicle's slip (after the slip-override fault).
    slip: SlipState,
    /// Ground speed along the rolling tangent, m/s.
    ground_speed: [f64; WHEELS],
    /// Ground speed over rim speed (1 for a wheel at rest).
    slip_factor: [f64; WHEELS],
    /// Lateral (slip-angle) speed, m/s.
    lateral: [f64; WHEELS],
    /// Largest `|rim speed|` of the six wheels, m/s: the bound of a plausible twist.
    max_rim: f64,
}

/// Every contact of every wheel for the force model, and the same contacts in `W` (for the
/// placement), in the same order.
struct AllContacts {
    force: Vec<ForceContact>,
    world: Vec<WheelContact>,
}

impl World {
    /// Advance the world by one minor frame.
    pub fn step(&mut self) {
        let dt = FRAME_US as f64 * 1e-6;
        self.step_motors(dt);
        // Contacts of the last placement, in R, with the current steering.
        self.update_wheels();
        let Some(wheels) = self.wheels else {
            return;
        };
        let pose0 = self.truth.pose;
        let rot = pose0.rot_w_from_r();
        let rot_inv = rot.inverse();
        let contacts: [RollingContact; WHEELS] = std::array::from_fn(|i| {
            RollingContact::new(
                self.truth.clearance_m[i] < CONTACT_TOLERANCE_M,
                rot_inv * self.contacts[i].normal_w,
                wheels[i].spin_axis,
            )
        });
        let start = StepStart {
            dt,
            wheels,
            pose0,
            rot,
            rot_inv,
            s0: self.truth.suspension,
            contacts,
        };
        let all = self.all_contacts(&start);
        let gravity_r = rot_inv * Vector3::z();
        let drive = self.wheel_drive(&start, &gravity_r);
        let s0 = start.s0;
        let quasi = solve_quasi_static(
            &self.geometry,
            &wheels,
            s0.rocker_rad,
            s0.bogie_rad,
            &all.force,
            &drive.ground_speed,
            &drive.slip_factor,
            &drive.lateral,
            &self.friction,
            &Weight {
                weight_n: ROCKY8_MASS_KG * MARS_GRAVITY_M_S2,
                centre_of_mass_m: centre_of_mass(),
                gravity_r,
            },
        );
        let twist = self.plausible_twist(&start, &drive, &quasi);
        let twist = self.bounded_twist(&start, &drive, twist);
        let lifted = self.lift_onto_faces(&all, &quasi);
        let placed = self.integrate_and_place(&start, &twist, &lifted);
        self.update_truth(&start, &drive, &placed, &twist, all, quasi);
        self.account_scrub(
            &wheels,
            &contacts,
            &s0,
            &pose0,
            &drive.ground_speed,
            &drive.slip_factor,
            dt,
        );
        self.update_wheels();
        // Energy: the power of this step's truth state (motor rates, pitch, motion) over it.
        let (theta_up, rim_speed) =
            crate::energy::drive_state(&self.truth, &self.geometry.wheel_radius_m);
        self.energy.step(theta_up, rim_speed, dt);
        self.sample_sensors(&start);
    }

    /// Motors follow the command over `dt`; a stalled motor does not turn its wheel.
    fn step_motors(&mut self, dt: f64) {
        let t = &mut self.truth;
        for i in 0..WHEELS {
            t.steer_rad[i] =
                self.steer_motor
                    .step(t.steer_rad[i], self.command.steer_angle_rad[i], dt);
            t.wheel_rate_rad_s[i] =
                self.drive_motor
                    .step(t.wheel_rate_rad_s[i], self.command.wheel_rate_rad_s[i], dt);
            // A stalled motor does not turn its wheel whatever the command (the vehicle drags
            // the wheel: its rim speed is zero in the rolling solve below).
            if self
                .faults
                .active_wheel(FaultDevice::Motors, FaultKind::Stall, t.t_us, i)
                .is_some()
            {
                t.wheel_rate_rad_s[i] = 0.0;
            }
            t.wheel_angle_rad[i] += t.wheel_rate_rad_s[i] * dt;
        }
    }

    /// Every contact of every wheel for the force model: the placement's contact, and on
    /// terrain with vertical faces also a step face within the edge probe (ahead or behind)
    /// and the ground below a wheel whose contact is on a face or edge (a wheel standing on
    /// the ground and pressed against a face touches both).
    fn all_contacts(&self, start: &StepStart) -> AllContacts {
        let (rot, rot_inv, wheels) = (&start.rot, &start.rot_inv, &start.wheels);
        let p0 = Vector3::from(start.pose0.pos_m);
        let mut all_contacts: Vec<ForceContact> = Vec::with_capacity(3 * WHEELS);
        // The same contacts in `W` (for the placement).
        let mut world_contacts: Vec<WheelContact> = Vec::with_capacity(3 * WHEELS);
        for i in 0..WHEELS {
            all_contacts.push(ForceContact {
                wheel: i,
                contact: start.contacts[i],
            });
            world_contacts.push(self.contacts[i]);
            if !self.terrain.has_edges() {
                continue;
            }
            let c = p0 + rot * wheels[i].axle_m;
            let spin = rot * wheels[i].spin_axis;
            let r_wheel = self.geometry.wheel_radius_m(i);
            let primary = self.contacts[i];
            let mut extra = |k: &WheelContact| {
                let distinct = all_contacts
                    .iter()
                    .filter(|f| f.wheel == i)
                    .all(|f| f.contact.normal.dot(&(rot_inv * k.normal_w)) < DISTINCT_COS);
                if distinct {
                    world_contacts.push(*k);
                    all_contacts.push(ForceContact {
                        wheel: i,
                        contact: RollingContact::new(
                            true,
                            rot_inv * k.normal_w,
                            wheels[i].spin_axis,
                        ),
                    });
                }
            };
            for direction in [1.0, -1.0] {
                if let Some(k) = face_contact(&self.terrain, &c, &spin, r_wheel, direction) {
                    if k.clearance_m < EDGE_PROBE_M {
                        extra(&k);
                    }
                }
            }
            if primary.angle_rad.abs() > BELOW_ANGLE_RAD {
                let below = ground_contact_below(
                    &self.terrain,
                    &c,
                    &spin,
                    r_wheel,
                    primary.angle_rad.abs() - BELOW_ANGLE_RAD,
                );
                if below.clearance_m < CONTACT_TOLERANCE_M {
                    extra(&below);
                }
            }
        }
        AllContacts {
            force: all_contacts,
            world: world_contacts,
        }
    }

    /// Per-wheel slip from the loads and the soil (a wheel's rim speed is its own radius times
    /// its rate), then the slip-override fault, and what each wheel drives over the ground.
    fn wheel_drive(&mut self, start: &StepStart, gravity_r: &Vector3<f64>) -> WheelDrive {
        let (contacts, rot_inv, pose0) = (&start.contacts, &start.rot_inv, &start.pose0);
        let r = self.geometry.wheel_radius_m;
        let ground: [WheelGround; WHEELS] = std::array::from_fn(|i| WheelGround {
            touching: contacts[i].touching,
            point: rot_inv * (self.contacts[i].point_w - Vector3::from(pose0.pos_m)),
            normal: contacts[i].normal,
            tangent: contacts[i].tangent,
            spin: contacts[i].spin,
            rim_speed_m_s: r[i] * self.truth.wheel_rate_rad_s[i],
        });
        let (wheel_slip, slip) = match &mut self.slip {
            Slip::Terramechanics(m) => m.wheel_slips(
                &self.geometry,
                self.truth.suspension.rocker_rad,
                &ground,
                gravity_r,
            ),
            Slip::Lumped(m) => {
                // Slopes along the motion and across the body, from gravity in R.
                let forward: f64 = ground.iter().map(|g| g.rim_speed_m_s).sum();
                let dir = if forward >= 0.0 { 1.0 } else { -1.0 };
                let slope_along = (-gravity_r.x * dir).clamp(-1.0, 1.0).asin();
                let slope_cross = gravity_r.y.clamp(-1.0, 1.0).asin();
                let state = m.step(slope_along, slope_cross, start.dt, &mut self.streams.slip);
                (lumped_wheels(&ground, &state), state)
            }
        };
        let (wheel_slip, slip) = self.override_slip(&ground, wheel_slip, slip);
        let ground_speed = wheel_slip.map(|w| w.ground_speed_m_s);
        let slip_factor: [f64; WHEELS] = std::array::from_fn(|i| {
            let rim = ground[i].rim_speed_m_s;
            if rim.abs() > 1e-9 {
                ground_speed[i] / rim
            } else {
                1.0
            }
        });
        let lateral = wheel_slip.map(|w| w.lateral_m_s);
        let max_rim = ground
            .iter()
            .map(|g| g.rim_speed_m_s.abs())
            .fold(0.0, f64::max);
        WheelDrive {
            wheel_slip,
            slip,
            ground_speed,
            slip_factor,
            lateral,
            max_rim,
        }
    }

    /// Slip override (fault `ground`/`slip`): the wheel's ground speed is `1 - value` of its
    /// rim speed whatever the soil (value 1: the wheel spins in place).
    fn override_slip(
        &self,
        ground: &[WheelGround; WHEELS],
        wheel_slip: [WheelSlip; WHEELS],
        slip: SlipState,
    ) -> ([WheelSlip; WHEELS], SlipState) {
        let (mut wheel_slip, mut slip) = (wheel_slip, slip);
        let mut overridden = 0;
        for i in 0..WHEELS {
            if let Some(f) =
                self.faults
                    .active_wheel(FaultDevice::Ground, FaultKind::Slip, self.truth.t_us, i)
            {
                let s = f.value();
                let w = &mut wheel_slip[i];
                w.ground_speed_m_s = (1.0 - s) * ground[i].rim_speed_m_s;
                w.lateral_m_s *= 1.0 - s;
                w.slip_ratio = s;
                overridden += 1;
            }
        }
        if overridden == WHEELS {
            slip.slip_ratio = wheel_slip.iter().map(|w| w.slip_ratio).sum::<f64>() / WHEELS as f64;
        }
        (wheel_slip, slip)
    }

    /// The quasi-static twist, or the kinematic least squares when it is implausible.
    ///
    /// A quasi-static rover cannot move faster than its wheels drive it. When the placement of
    /// the last step did not converge the force balance can become singular and return an
    /// absurd twist (km/s, seen once on a dense rock field); such a step falls back to the
    /// kinematic least squares of all contacts (`solve_rolling`) and is counted.
    fn plausible_twist(
        &mut self,
        start: &StepStart,
        drive: &WheelDrive,
        quasi: &QuasiStatic,
    ) -> Twist {
        let max_rim = drive.max_rim;
        let plausible = |t: &Twist| {
            let finite = t.v.iter().chain(t.w.iter()).all(|x| x.is_finite())
                && t.suspension_rad_s.iter().all(|x| x.is_finite());
            finite
                && t.v.norm() <= 3.0 * max_rim + 0.05
                && t.w.norm() <= 15.0 * max_rim + 0.25
                && t.suspension_rad_s
                    .iter()
                    .all(|x| x.abs() <= 15.0 * max_rim + 0.25)
        };
        if plausible(&quasi.twist) {
            quasi.twist
        } else {
            self.force_fallbacks += 1;
            crate::vehicle::rolling::solve_rolling(
                &self.geometry,
                &start.wheels,
                start.s0.rocker_rad,
                start.s0.bogie_rad,
                &start.contacts,
                &drive.ground_speed,
                &drive.slip_factor,
                &drive.lateral,
            )
        }
    }

    /// The twist within the bounds of a quasi-static rover and of the forces that can act on
    /// it.
    ///
    /// The quasi-static balance has no inertia: where it has no static solution (a wheel
    /// whose contact switches on a steep flank, a rover turning in place on 20 deg sand) it
    /// can return a twist of several m/s for a step or two (on `dunes-long`: up to 6 m/s and an
    /// IMU spike of 1,000 m/s^2). A body's acceleration is bounded by the forces that can act
    /// on it: gravity plus Coulomb friction at the contacts, `|a| <= g (1 + mu)`, and its
    /// angular acceleration by that over the half track. The twist's change per step is
    /// limited to those bounds (counted in `inertia_limits`).
    fn bounded_twist(&mut self, start: &StepStart, drive: &WheelDrive, twist: Twist) -> Twist {
        let (rot, dt, max_rim) = (&start.rot, start.dt, drive.max_rim);
        let mut t = twist;
        // The kinematic fallback has no bound of its own (it follows the contacts, which
        // can be inconsistent after a placement that did not converge): the plausible
        // bounds above cap it.
        let (v_cap, w_cap) = (3.0 * max_rim + 0.05, 15.0 * max_rim + 0.25);
        if t.v.norm() > v_cap || t.w.norm() > w_cap {
            self.twist_caps += 1;
            if t.v.norm() > v_cap {
                t.v *= v_cap / t.v.norm();
            }
            if t.w.norm() > w_cap {
                t.w *= w_cap / t.w.norm();
            }
        }
        let a_max = MARS_GRAVITY_M_S2 * (1.0 + self.friction.mu.max(0.0));
        let alpha_max = a_max / 0.31;
        let v_w = rot * t.v;
        let w_w = rot * t.w;
        if let Some((v0, w0)) = self.prev_twist_w {
            let (dv, dw) = (v_w - v0, w_w - w0);
            let (kv, kw) = (
                (a_max * dt / dv.norm().max(1e-12)).min(1.0),
                (alpha_max * dt / dw.norm().max(1e-12)).min(1.0),
            );
            if kv < 1.0 || kw < 1.0 {
                self.inertia_limits += 1;
                t.v = rot.inverse() * (v0 + dv * kv);
                t.w = rot.inverse() * (w0 + dw * kw);
            }
        }
        self.prev_twist_w = Some((rot * t.v, rot * t.w));
        t
    }

    /// The wheels the force balance carries on a step face or edge only (no contact near the
    /// bottom of its rim carries load: it has been lifted off the ground below): such a wheel
    /// climbs that face, so the placement follows the face contact (measured along the rim's
    /// normals) instead of setting the wheel back on the ground.
    fn lift_onto_faces(&mut self, all: &AllContacts, quasi: &QuasiStatic) -> [bool; WHEELS] {
        let (all_contacts, world_contacts) = (&all.force, &all.world);
        let mut lifted = [false; WHEELS];
        for i in 0..WHEELS {
            let carrying = || {
                (0..all_contacts.len()).filter(|&c| all_contacts[c].wheel == i && quasi.active[c])
            };
            let on_ground =
                carrying().any(|c| world_contacts[c].angle_rad.abs() <= LIFTED_ANGLE_RAD);
            let on_face = carrying()
                .filter(|&c| world_contacts[c].angle_rad.abs() > LIFTED_ANGLE_RAD)
                .max_by(|&a, &b| quasi.normal_n[a].total_cmp(&quasi.normal_n[b]));
            if let (false, Some(c)) = (on_ground, on_face) {
                self.contacts[i] = world_contacts[c];
                self.truth.clearance_m[i] = world_contacts[c].clearance_m.max(0.0);
                lifted[i] = true;
            }
        }
        lifted
    }

    /// Integrate the body pose and the suspension over the step with `twist`, then place the
    /// vehicle on the terrain (the holonomic constraint; `lifted` wheels on their faces).
    fn integrate_and_place(
        &mut self,
        start: &StepStart,
        twist: &Twist,
        lifted: &[bool; WHEELS],
    ) -> Placement {
        let (rot, dt, pose0, s0) = (&start.rot, start.dt, &start.pose0, &start.s0);
        let rot_int = rot * Rotation3::from_scaled_axis(twist.w * dt);
        let v_w = rot * twist.v;
        let (roll, pitch, yaw) = rot_int.euler_angles();
        let pose = BodyPose {
            pos_m: [
                pose0.pos_m[0] + v_w.x * dt,
                pose0.pos_m[1] + v_w.y * dt,
                pose0.pos_m[2] + v_w.z * dt,
            ],
            yaw_rad: yaw,
            pitch_rad: pitch,
            roll_rad: roll,
        };
        let q = twist.suspension_rad_s;
        let guess = Suspension {
            rocker_rad: s0.rocker_rad + q[0] * dt,
            bogie_rad: [s0.bogie_rad[0] + q[1] * dt, s0.bogie_rad[1] + q[2] * dt],
        };
        let placed: Placement = place_cached(
            &self.geometry,
            &self.terrain,
            &pose,
            &guess,
            &self.truth.steer_rad,
            &self.limits,
            &mut self.jacobian,
            Some(&self.contacts),
            true,
            lifted,
        );
        self.placement_iterations += u64::from(placed.iterations);
        self.contacts = placed.contacts;
        placed
    }

    /// The truth after the step: pose, suspension, contacts, slip, loads, rates, time.
    fn update_truth(
        &mut self,
        start: &StepStart,
        drive: &WheelDrive,
        placed: &Placement,
        twist: &Twist,
        all: AllContacts,
        quasi: QuasiStatic,
    ) {
        let (pose0, s0, dt) = (&start.pose0, &start.s0, start.dt);
        let t = &mut self.truth;
        let moved = [
            placed.pose.pos_m[0] - pose0.pos_m[0],
            placed.pose.pos_m[1] - pose0.pos_m[1],
        ];
        t.distance_m += (moved[0] * moved[0] + moved[1] * moved[1]).sqrt();
        t.pose = placed.pose;
        t.suspension = placed.suspension;
        t.clearance_m = placed.clearance_m;
        t.contact_angle_rad = placed.contacts.map(|c| c.angle_rad);
        t.wheel_slip_ratio = drive.wheel_slip.map(|w| w.slip_ratio);
        t.wheel_load_n = quasi.wheel_load_n;
        self.forces = Some((all.force, quasi));
        t.suspension_rate_rad_s = [
            (placed.suspension.rocker_rad - s0.rocker_rad) / dt,
            (placed.suspension.bogie_rad[0] - s0.bogie_rad[0]) / dt,
            (placed.suspension.bogie_rad[1] - s0.bogie_rad[1]) / dt,
        ];
        t.slip = drive.slip;
        t.velocity_r_m_s = [twist.v.x, twist.v.y];
        t.t_us = t.t_us.saturating_add(FRAME_US);
        self.steps += 1;
    }

    /// The sensors after the step: the IMU from the motion over it, the encoders and the sun
    /// sensor at their rates.
    fn sample_sensors(&mut self, start: &StepStart) {
        let (pose0, rot_inv, dt) = (&start.pose0, &start.rot_inv, start.dt);
        let rot1 = self.truth.pose.rot_w_from_r();
        let p0 = Vector3::from(pose0.pos_m);
        let p1 = Vector3::from(self.truth.pose.pos_m);
        let velocity_w = (p1 - p0) / dt;
        let accel_w = (velocity_w - self.prev_velocity_w) / dt;
        self.prev_velocity_w = velocity_w;
        // The rotation over the step as a unit quaternion: `Rotation3::scaled_axis` takes the
        // acos of `(trace - 1) / 2`, which rounding can push above 1 for a rover at rest (NaN).
        let delta = nalgebra::UnitQuaternion::from_rotation_matrix(&(rot_inv * rot1));
        let gyro = delta.scaled_axis() / dt;
        let specific_force = rot1.inverse() * (accel_w - Vector3::new(0.0, 0.0, MARS_GRAVITY_M_S2));
        self.sample_imu(gyro, specific_force, dt);
        if self.steps % self.encoder_every == 0 {
            self.sample_joints();
        }
        if self.steps % self.sun_every == 0 {
            self.sample_sun();
        }
    }
}

/// Every wheel on the ground gets the vehicle's slip ratio and slip angle (the lumped model):
/// the axle moves at `(1 - s)` times its rim speed (`1 - max(s, 0)` backwards) and sideways at
/// `tan(alpha)` times that, towards the rover's right for a positive angle.
fn lumped_wheels(ground: &[WheelGround; WHEELS], state: &SlipState) -> [WheelSlip; WHEELS] {
    std::array::from_fn(|i| {
        let g = &ground[i];
        let rim = g.rim_speed_m_s;
        let s = state.slip_ratio;
        let speed = if rim >= 0.0 {
            (1.0 - s) * rim
        } else {
            (1.0 - s.max(0.0)) * rim
        };
        WheelSlip {
            load_n: 0.0,
            slip_ratio: s,
            slip_angle_rad: state.slip_angle_rad,
            saturated: false,
            ground_speed_m_s: speed,
            lateral_m_s: speed.abs() * state.slip_angle_rad.tan() * g.spin.y.signum(),
        }
    })
}
