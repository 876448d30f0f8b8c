#![allow(clippy::needless_range_loop)] // wheel loops index several parallel arrays
//! The simulated world: terrain, vehicle truth state, motors, slip and the sensor models. One
//! [`World::step`] advances everything by one minor frame (5 ms) and refreshes the readings the
//! HAL devices hand to the flight software.
//!
//! Motion model per step: motors follow the command; each wheel's soil slip comes from its
//! contact and load ([`crate::soil::per_wheel_slip`], [`crate::soil::lumped_slip`]); the quasi-static force model
//! ([`crate::vehicle::forces`]) gives the body twist and the suspension rates from every contact
//! of every wheel (on terrain with vertical faces a wheel may touch the ground and a face): a
//! contact rolls while its friction stays inside Coulomb's cone and slides at the cone
//! otherwise, and a contact that would have to pull lets go (a wheel pushed against a face is
//! lifted off the ground by the friction at the face); the body pose and the suspension are
//! integrated over the step (`R_WR <- R_WR exp(w dt)`, `p <- p + R_WR v dt`); then the
//! placement solver projects the vehicle back onto the terrain (height, roll, pitch, rocker and
//! bogies at the integrated north, east and yaw: the holonomic constraint), a lifted wheel on its
//! face contact.

use crate::scenario::SlipModelKind;
use crate::scenario::{Scenario, Site};
use crate::sensors::encoders::EncoderParams;
use crate::sensors::faults::{FaultDevice, FaultKind, Faults};
use crate::sensors::hazcam::HazcamModel;
use crate::sensors::imu::ImuModel;
use crate::sensors::sun::SunParams;
use crate::soil::lumped_slip::LumpedSlip;
use crate::soil::per_wheel_slip::centre_of_mass;
use crate::soil::per_wheel_slip::{SlipModel, SlipState, WheelGround, WheelSlip};
use crate::soil::terramechanics::{Wheel, ROCKY8_MASS_KG};
use crate::surface::TerrainSurface;
use crate::terrain::Terrain;
use crate::vehicle::contact::{face_contact, ground_contact_below, WheelContact, EDGE_PROBE_M};
use crate::vehicle::forces::{solve_quasi_static, ForceContact, Friction, QuasiStatic, Weight};
use crate::vehicle::geometry::{rocky8, TruthGeometry, VehicleGeometry, WheelPose, WHEELS};
use crate::vehicle::motors::MotorParams;
use crate::vehicle::placement::{
    place, place_cached, BodyPose, JointLimits, Placement, PlacementJacobian, Suspension,
    LIFTED_ANGLE_RAD,
};
use crate::vehicle::rolling::{RollingContact, CONTACT_TOLERANCE_M};
use nalgebra::{Rotation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rover_hal::{ImuSample, JointState, MobilityCommand, SunReading};

/// Mars gravity, m/s^2 (REFERENCE.md).
pub const MARS_GRAVITY_M_S2: f64 = 3.711;
/// Minor frame, microseconds (200 Hz).
pub const FRAME_US: u64 = 5_000;

/// Independent random streams, one per consumer, so that adding draws in one model does not
/// change the others.
#[derive(Debug, Clone)]
pub struct Streams {
    /// Slip.
    pub slip: ChaCha8Rng,
    /// IMU.
    pub imu: ChaCha8Rng,
    /// Encoders.
    pub encoders: ChaCha8Rng,
    /// Sun sensor.
    pub sun: ChaCha8Rng,
    /// Geometry dimension errors.
    pub geometry: ChaCha8Rng,
    /// Calibration errors of the hazcam head.
    pub camera: ChaCha8Rng,
    /// Scale-factor and misalignment errors of the IMU.
    pub imu_calibration: ChaCha8Rng,
    /// The wheels' individual radius errors.
    pub wheel_radius: ChaCha8Rng,
}

impl Streams {
    /// Streams for `seed`.
    pub fn new(seed: u64) -> Self {
        let s = |k: u64| {
            let mut r = ChaCha8Rng::seed_from_u64(seed);
            r.set_stream(k);
            r
        };
        Self {
            slip: s(1),
            imu: s(2),
            encoders: s(3),
            sun: s(4),
            geometry: s(5),
            camera: s(6),
            imu_calibration: s(7),
            wheel_radius: s(8),
        }
    }
}

/// Truth of the vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Truth {
    /// Time, microseconds since boot.
    pub t_us: u64,
    /// Body pose in `W`.
    pub pose: BodyPose,
    /// Suspension.
    pub suspension: Suspension,
    /// Actual steering angles, rad (positive turns the wheel right, as in `fsw::kinematics`).
    pub steer_rad: [f64; WHEELS],
    /// Actual wheel rates, rad/s.
    pub wheel_rate_rad_s: [f64; WHEELS],
    /// Wheel angles, rad.
    pub wheel_angle_rad: [f64; WHEELS],
    /// Slip over the last step.
    pub slip: crate::soil::per_wheel_slip::SlipState,
    /// Ground velocity of the body in `R` over the last step `[vx, vy]`, m/s.
    pub velocity_r_m_s: [f64; 2],
    /// Horizontal distance travelled, m.
    pub distance_m: f64,
    /// Clearance of each wheel (0 on the ground), m.
    pub clearance_m: [f64; WHEELS],
    /// Contact angle of each wheel in its wheel plane, rad (0 below the axle, positive ahead).
    pub contact_angle_rad: [f64; WHEELS],
    /// Longitudinal slip ratio of each wheel over the last step.
    pub wheel_slip_ratio: [f64; WHEELS],
    /// Normal load of each wheel over the last step from the quasi-static force model (the sum
    /// over its contacts, a step face included), N.
    pub wheel_load_n: [f64; WHEELS],
    /// Suspension rates `[beta, rho1, rho2]` over the last step, rad/s.
    pub suspension_rate_rad_s: [f64; 3],
}

/// The slip model of a run.
#[derive(Debug, Clone)]
pub enum Slip {
    /// Vehicle-level slip from the slopes.
    Lumped(LumpedSlip),
    /// Per-wheel terramechanics.
    Terramechanics(SlipModel),
}

/// The world.
pub struct World {
    /// Terrain.
    pub terrain: Terrain,
    /// The simulator's (true) vehicle geometry: Rocky 8's published dimensions with the
    /// per-seed dimension errors and the wheels' individual radius errors.
    pub geometry: TruthGeometry,
    /// Joint limits.
    pub limits: JointLimits,
    /// Truth state.
    pub truth: Truth,
    /// Motor command the motors follow (from the reference driver or the flight software).
    pub command: MobilityCommand,
    /// Last command the flight software sent through `Mobility::command` (`None`: none yet).
    pub flight_command: Option<MobilityCommand>,
    steer_motor: MotorParams,
    drive_motor: MotorParams,
    slip: Slip,
    /// Friction of the wheel contacts (force model), from the soil.
    pub friction: Friction,
    /// The contacts and the force model's solution of the last step (diagnostics).
    pub forces: Option<(Vec<ForceContact>, QuasiStatic)>,
    imu: ImuModel,
    /// Encoder model.
    pub encoders: EncoderParams,
    /// Sun sensor model.
    pub sun: SunParams,
    /// Site, season and time of day: the sun's motion.
    pub site: Site,
    /// The hazcam head: the nominal calibration (given to the flight software) and the true
    /// one with this seed's errors (used to render).
    pub hazcam: HazcamModel,
    /// Faults.
    pub faults: Faults,
    /// The truth energy model and the battery energy used so far ([`crate::energy`]),
    /// integrated every step.
    pub energy: crate::energy::EnergyMeter,
    /// Host nanoseconds spent inside simulated devices doing the simulator's own work (image
    /// rendering), subtracted from the execution counter so that the flight software's timing
    /// figures measure flight code, not the simulator.
    pub sim_overhead_ns: std::cell::Cell<u64>,
    /// Random streams.
    pub streams: Streams,
    encoder_every: u64,
    sun_every: u64,
    prev_velocity_w: Vector3<f64>,
    /// Linear and angular velocity of the body of the last step in `W` (the inertia bound).
    prev_twist_w: Option<(Vector3<f64>, Vector3<f64>)>,
    jacobian: Option<PlacementJacobian>,
    contacts: [WheelContact; WHEELS],
    wheels: Option<[WheelPose; WHEELS]>,
    /// Latest IMU sample (before faults).
    pub imu_sample: ImuSample,
    /// Latest joint reading (before faults).
    pub joints: JointState,
    /// Latest sun reading (before faults).
    pub sun_reading: SunReading,
    /// Steps taken.
    pub steps: u64,
    /// Newton iterations of the placement solver, summed over all steps (diagnostics).
    pub placement_iterations: u64,
    /// Steps whose quasi-static twist was implausible (faster than the wheels can drive the
    /// rover) and that fell back to the kinematic least squares (diagnostics; 0 on every
    /// scenario but a dense rock field).
    pub force_fallbacks: u64,
    /// Steps whose quasi-static twist changed the body's velocity faster than the contact
    /// forces and gravity can accelerate it, and was limited to that (see `step`).
    pub inertia_limits: u64,
    /// Steps whose twist (after the kinematic fallback) exceeded the plausible bounds of a
    /// quasi-static rover and was scaled down to them.
    pub twist_caps: u64,
    /// Scrub of the wheels on the ground, m, summed over wheels and steps: the difference
    /// between the ground speed each wheel drives (its rim speed after its own slip) and the
    /// speed at which its contact point actually moved along its rolling tangent over the step
    /// (body, suspension and link rotation after the placement), times the step. Where the
    /// commanded wheel rates do not fit the terrain, the quasi-static contacts slide: motion
    /// that no odometry can see. Diagnostics (`truth_scrub` in `summary.json`).
    pub scrub_m: f64,
    /// The same with sign, m: ground travel driven less the travel the contact points made
    /// (positive: the wheels turned more than the rover moved, so odometry runs long).
    pub scrub_net_m: f64,
    /// Ground travel the wheels on the ground drove, m (the sum of `|ground speed| dt`): the
    /// reference of [`Self::scrub_m`].
    pub driven_m: f64,
    /// Averaged wheel odometry, m: the mean increment of the six drive encoders (as read)
    /// times the nominal wheel radius (0.10 m, published: what the flight software knows, not
    /// the wheels' true radii) times the cosine of the true pitch;
    /// the pitch-compensated baseline of V99 sec. 6 (diagnostics, not seen by the flight
    /// software).
    pub wheel_average_m: f64,
}

/// Nominal wheel radius of the averaged wheel odometry, m (the published Rocky 8 figure).
const NOMINAL_WHEEL_RADIUS_M: f64 = 0.10;

/// Two contacts of one wheel are distinct when their normals differ by more than about 10 deg
/// (cosine below this).
const DISTINCT_COS: f64 = 0.985;
/// A wheel whose contact is more than this off the vertical below its axle (on an edge or a
/// face) is also searched for the ground below, up to this much short of that contact, rad.
const BELOW_ANGLE_RAD: f64 = 0.35;

/// Friction of the wheel contacts for the force model, from the soil of the slip model:
/// Coulomb `mu = tan(phi)` of the soil's friction angle (Wong, *Theory of Ground Vehicles*,
/// Table 2.3, as the soil presets give it) and the creep slip `2 K / L` of the Janosi-Hanamoto
/// law (`K / L` of the lumped soil; for the terramechanics soil `K` over the contact length of
/// a Rocky 8 wheel under a sixth of the weight). After the per-seed draw.
fn friction_of(slip: &Slip) -> Friction {
    match slip {
        Slip::Lumped(m) => {
            let soil = m.soil();
            Friction {
                mu: soil.friction_angle_deg.to_radians().tan(),
                creep_slip: 2.0 * soil.shear_modulus_ratio,
            }
        }
        Slip::Terramechanics(m) => {
            let soil = m.soil();
            let load = ROCKY8_MASS_KG * MARS_GRAVITY_M_S2 / WHEELS as f64;
            // Contact length of the rigid wheel at free rolling: the chord from the entry
            // angle to the exit angle (exit sinkage `lambda` times the entry sinkage).
            let wheel = Wheel::rocky8();
            let entry = crate::soil::rigid_wheel::wheel_forces(soil, &wheel, load, 0.0, 0.0)
                .entry_angle_rad;
            let exit = (1.0 - soil.exit_sinkage_ratio * (1.0 - entry.cos()))
                .clamp(-1.0, 1.0)
                .acos();
            let length = wheel.radius_m * (entry.sin() + exit.sin());
            Friction {
                mu: soil.phi_rad.tan(),
                creep_slip: if length > 0.0 {
                    (2.0 * soil.shear_k_m / length).min(1.0)
                } else {
                    1.0
                },
            }
        }
    }
}

impl World {
    /// Build the world of `scenario` for `seed`.
    pub fn new(scenario: &Scenario, seed: u64) -> anyhow::Result<Self> {
        let mut streams = Streams::new(seed);
        if let Some(unit) = scenario.calibration_seed {
            // One rover unit: its calibration and manufacturing errors from their own seed.
            let cal = Streams::new(unit);
            streams.geometry = cal.geometry;
            streams.camera = cal.camera;
            streams.imu_calibration = cal.imu_calibration;
            streams.wheel_radius = cal.wheel_radius;
        }
        let terrain = Terrain::new(
            scenario.terrain.clone(),
            scenario.terrain_seed.unwrap_or(seed),
            &scenario.waypoints,
        );
        let sigma = scenario.sensors.dimension_error_m;
        let sigma_wheel = scenario.sensors.wheel_radius_error_m;
        let geometry = rocky8()
            .perturbed(|_| {
                let n: f64 = StandardNormal.sample(&mut streams.geometry);
                sigma * n
            })
            .with_wheel_radius_errors(|_| {
                let n: f64 = StandardNormal.sample(&mut streams.wheel_radius);
                sigma_wheel * n
            });
        let slip = match scenario.slip_model {
            SlipModelKind::Lumped => Slip::Lumped(LumpedSlip::new(
                scenario.soil.lumped()?,
                scenario.slip,
                &mut streams.slip,
            )),
            SlipModelKind::Terramechanics => Slip::Terramechanics(SlipModel::new(
                scenario.soil.bekker()?,
                geometry.wheel_radius_m,
                scenario.slip,
                &mut streams.slip,
            )),
        };
        let energy = crate::energy::EnergyMeter::new(crate::energy::EnergyModel::for_slip(&slip));
        let imu = ImuModel::new(
            scenario.sensors.imu,
            &mut streams.imu,
            &mut streams.imu_calibration,
        );
        let hazcam = HazcamModel::new(
            scenario.sensors.camera_calibration_errors,
            &scenario.sensors.camera_tolerances,
            scenario.sensors.ideal_lens,
            &scenario.sensors.lens_tolerances,
            &mut streams.camera,
        );
        let [planned, next] = [scenario.waypoints[0], scenario.waypoints[1]];
        // The true start: the planned one plus the scenario's start offset (0 by default).
        let offset = scenario.start_offset;
        let start = [planned[0] + offset.north_m, planned[1] + offset.east_m];
        let yaw = (next[1] - planned[1]).atan2(next[0] - planned[0]) + offset.yaw_deg.to_radians();
        // Start height for the placement, which then sets each wheel on the ground.
        let r = geometry.mean_wheel_radius_m();
        let pose = BodyPose {
            pos_m: [
                start[0],
                start[1],
                -(terrain.height_m(start[0], start[1]) + r),
            ],
            yaw_rad: yaw,
            pitch_rad: 0.0,
            roll_rad: 0.0,
        };
        let limits = JointLimits::rocky8();
        let steer = [0.0; WHEELS];
        let p = place(
            &geometry,
            &terrain,
            &pose,
            &Suspension::default(),
            &steer,
            &limits,
        );
        let mut world = Self {
            sim_overhead_ns: std::cell::Cell::new(0),
            terrain,
            geometry,
            limits,
            truth: Truth {
                pose: p.pose,
                suspension: p.suspension,
                clearance_m: p.clearance_m,
                contact_angle_rad: p.contacts.map(|c| c.angle_rad),
                ..Truth::default()
            },
            command: MobilityCommand::default(),
            flight_command: None,
            steer_motor: MotorParams::steering(),
            drive_motor: MotorParams::drive(),
            friction: friction_of(&slip),
            forces: None,
            slip,
            imu,
            encoders: scenario.sensors.encoders,
            sun: scenario.sensors.sun,
            site: scenario.site,
            hazcam,
            faults: Faults::new(scenario.faults.clone()),
            energy,
            streams,
            encoder_every: u64::from(200 / scenario.sensors.encoder_hz),
            sun_every: u64::from(200 / scenario.sensors.sun_hz),
            prev_velocity_w: Vector3::zeros(),
            jacobian: None,
            contacts: p.contacts,
            wheels: None,
            imu_sample: ImuSample::default(),
            joints: JointState::default(),
            sun_reading: SunReading::default(),
            steps: 0,
            placement_iterations: 0,
            force_fallbacks: 0,
            inertia_limits: 0,
            twist_caps: 0,
            scrub_m: 0.0,
            scrub_net_m: 0.0,
            driven_m: 0.0,
            prev_twist_w: None,
            wheel_average_m: 0.0,
        };
        world.update_wheels();
        world.sample_imu(Vector3::zeros(), Vector3::zeros(), 0.0);
        world.sample_joints();
        world.sample_sun();
        Ok(world)
    }

    /// The slip model (soil parameters after the per-seed draw).
    pub fn slip_model(&self) -> &Slip {
        &self.slip
    }

    /// The wheels in `R` at the joint angles of the last placement (`None` outside the
    /// geometry's range, which the placement's stops prevent).
    pub fn wheel_poses(&self) -> Option<[WheelPose; WHEELS]> {
        self.wheels
    }

    fn update_wheels(&mut self) {
        let s = &self.truth.suspension;
        self.wheels = self
            .geometry
            .wheels(s.rocker_rad, s.bogie_rad, &self.truth.steer_rad);
    }

    /// Axle positions in `R` projected on the body's x-y plane, m (the axle centres do not
    /// move with steering).
    pub fn wheel_xy(&self) -> [[f64; 2]; WHEELS] {
        match self.wheels {
            Some(p) => p.map(|w| [w.axle_m.x, w.axle_m.y]),
            None => [[0.0; 2]; WHEELS],
        }
    }

    /// Advance the world by one minor frame.
    pub fn step(&mut self) {
        let dt = FRAME_US as f64 * 1e-6;
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
        // Every contact of every wheel for the force model: the placement's contact, and on
        // terrain with vertical faces also a step face within the edge probe (ahead or behind)
        // and the ground below a wheel whose contact is on a face or edge (a wheel standing on
        // the ground and pressed against a face touches both).
        let p0 = Vector3::from(pose0.pos_m);
        let mut all_contacts: Vec<ForceContact> = Vec::with_capacity(3 * WHEELS);
        // The same contacts in `W` (for the placement).
        let mut world_contacts: Vec<WheelContact> = Vec::with_capacity(3 * WHEELS);
        let mut primary_index = [0; WHEELS];
        for i in 0..WHEELS {
            primary_index[i] = all_contacts.len();
            all_contacts.push(ForceContact {
                wheel: i,
                contact: contacts[i],
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
        // Per-wheel slip from the loads and the soil. A wheel's rim speed is its own radius
        // times its rate.
        let r = self.geometry.wheel_radius_m;
        let ground: [WheelGround; WHEELS] = std::array::from_fn(|i| WheelGround {
            touching: contacts[i].touching,
            point: rot_inv * (self.contacts[i].point_w - Vector3::from(pose0.pos_m)),
            normal: contacts[i].normal,
            tangent: contacts[i].tangent,
            spin: contacts[i].spin,
            rim_speed_m_s: r[i] * self.truth.wheel_rate_rad_s[i],
        });
        let gravity_r = rot_inv * Vector3::z();
        let (wheel_slip, slip) = match &mut self.slip {
            Slip::Terramechanics(m) => m.wheel_slips(
                &self.geometry,
                self.truth.suspension.rocker_rad,
                &ground,
                &gravity_r,
            ),
            Slip::Lumped(m) => {
                // Slopes along the motion and across the body, from gravity in R.
                let forward: f64 = ground.iter().map(|g| g.rim_speed_m_s).sum();
                let dir = if forward >= 0.0 { 1.0 } else { -1.0 };
                let slope_along = (-gravity_r.x * dir).clamp(-1.0, 1.0).asin();
                let slope_cross = gravity_r.y.clamp(-1.0, 1.0).asin();
                let state = m.step(slope_along, slope_cross, dt, &mut self.streams.slip);
                (lumped_wheels(&ground, &state), state)
            }
        };
        // Slip override (fault `ground`/`slip`): the wheel's ground speed is `1 - value` of its
        // rim speed whatever the soil (value 1: the wheel spins in place).
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
        let s0 = self.truth.suspension;
        let quasi = solve_quasi_static(
            &self.geometry,
            &wheels,
            s0.rocker_rad,
            s0.bogie_rad,
            &all_contacts,
            &ground_speed,
            &slip_factor,
            &lateral,
            &self.friction,
            &Weight {
                weight_n: ROCKY8_MASS_KG * MARS_GRAVITY_M_S2,
                centre_of_mass_m: centre_of_mass(),
                gravity_r,
            },
        );
        // A quasi-static rover cannot move faster than its wheels drive it. When the placement
        // of the last step did not converge the force balance can become singular and return an
        // absurd twist (km/s, seen once on a dense rock field); such a step falls back to the
        // kinematic least squares of all contacts (`solve_rolling`) and is counted.
        let max_rim = ground
            .iter()
            .map(|g| g.rim_speed_m_s.abs())
            .fold(0.0, f64::max);
        let plausible = |t: &crate::vehicle::rolling::Twist| {
            let finite = t.v.iter().chain(t.w.iter()).all(|x| x.is_finite())
                && t.suspension_rad_s.iter().all(|x| x.is_finite());
            finite
                && t.v.norm() <= 3.0 * max_rim + 0.05
                && t.w.norm() <= 15.0 * max_rim + 0.25
                && t.suspension_rad_s
                    .iter()
                    .all(|x| x.abs() <= 15.0 * max_rim + 0.25)
        };
        let twist = if plausible(&quasi.twist) {
            quasi.twist
        } else {
            self.force_fallbacks += 1;
            crate::vehicle::rolling::solve_rolling(
                &self.geometry,
                &wheels,
                s0.rocker_rad,
                s0.bogie_rad,
                &contacts,
                &ground_speed,
                &slip_factor,
                &lateral,
            )
        };
        // The quasi-static balance has no inertia: where it has no static solution (a wheel
        // whose contact switches on a steep flank, a rover turning in place on 20 deg sand) it
        // returned a twist of several m/s for a step or two (14 steps of `dunes-long`, up to
        // 6 m/s and an IMU spike of 1,000 m/s^2). A body's acceleration is bounded by the
        // forces that can act on it: gravity plus Coulomb friction at the contacts,
        // `|a| <= g (1 + mu)`, and its angular acceleration by that over the half track. The
        // twist's change per step is limited to those bounds (counted in `inertia_limits`).
        let twist = {
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
        };
        // A wheel the force balance carries on a step face or edge only (no contact near the
        // bottom of its rim carries load: it has been lifted off the ground below) climbs that
        // face: the placement follows the face contact (measured along the rim's normals)
        // instead of setting the wheel back on the ground.
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
        // Integrate the body pose and the suspension over the step.
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
            &lifted,
        );
        self.placement_iterations += u64::from(placed.iterations);
        self.contacts = placed.contacts;
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
        t.wheel_slip_ratio = wheel_slip.map(|w| w.slip_ratio);
        t.wheel_load_n = quasi.wheel_load_n;
        self.forces = Some((all_contacts, quasi));
        t.suspension_rate_rad_s = [
            (placed.suspension.rocker_rad - s0.rocker_rad) / dt,
            (placed.suspension.bogie_rad[0] - s0.bogie_rad[0]) / dt,
            (placed.suspension.bogie_rad[1] - s0.bogie_rad[1]) / dt,
        ];
        t.slip = slip;
        t.velocity_r_m_s = [twist.v.x, twist.v.y];
        t.t_us = t.t_us.saturating_add(FRAME_US);
        self.steps += 1;
        self.account_scrub(
            &wheels,
            &contacts,
            &s0,
            &pose0,
            &ground_speed,
            &slip_factor,
            dt,
        );
        self.update_wheels();
        // Energy: the power of this step's truth state (motor rates, pitch, motion) over it.
        let (theta_up, rim_speed) =
            crate::energy::drive_state(&self.truth, &self.geometry.wheel_radius_m);
        self.energy.step(theta_up, rim_speed, dt);
        // Sensors.
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

    /// Adds the step's scrub to [`Self::scrub_m`] and its driven travel to
    /// [`Self::driven_m`]: for each wheel on the ground at the step's start, the rolling row of
    /// its contact (`contact_rows`, at the start configuration) applied to the motion the step
    /// actually made, less the ground speed it drove.
    #[allow(clippy::too_many_arguments)]
    fn account_scrub(
        &mut self,
        wheels: &[WheelPose; WHEELS],
        contacts: &[RollingContact; WHEELS],
        s0: &Suspension,
        pose0: &BodyPose,
        ground_speed: &[f64; WHEELS],
        slip_factor: &[f64; WHEELS],
        dt: f64,
    ) {
        let rot0 = pose0.rot_w_from_r();
        let rot1 = self.truth.pose.rot_w_from_r();
        let v = rot0.inverse()
            * (Vector3::from(self.truth.pose.pos_m) - Vector3::from(pose0.pos_m))
            / dt;
        let w = nalgebra::UnitQuaternion::from_rotation_matrix(&(rot0.inverse() * rot1))
            .scaled_axis()
            / dt;
        let q = self.truth.suspension_rate_rad_s;
        let x = crate::vehicle::rolling::Row::from_column_slice(&[
            v.x, v.y, v.z, w.x, w.y, w.z, q[0], q[1], q[2],
        ]);
        for i in 0..WHEELS {
            if !contacts[i].touching {
                continue;
            }
            let rows = crate::vehicle::rolling::contact_rows(
                &self.geometry,
                wheels,
                s0.rocker_rad,
                s0.bogie_rad,
                i,
                &contacts[i],
                slip_factor[i],
            );
            let moved = rows[1].dot(&x);
            if moved.is_finite() {
                self.scrub_m += (moved - ground_speed[i]).abs() * dt;
                self.scrub_net_m += (ground_speed[i] - moved) * dt;
                self.driven_m += ground_speed[i].abs() * dt;
            }
        }
    }

    fn sample_imu(&mut self, gyro: Vector3<f64>, specific_force: Vector3<f64>, dt: f64) {
        let f = if self.steps == 0 {
            // At start the rover rests: specific force is minus gravity in R.
            self.truth.pose.rot_w_from_r().inverse() * Vector3::new(0.0, 0.0, -MARS_GRAVITY_M_S2)
        } else {
            specific_force
        };
        let (g, a) = self.imu.sample(
            [gyro.x, gyro.y, gyro.z],
            [f.x, f.y, f.z],
            dt.max(1e-3),
            &mut self.streams.imu,
        );
        self.imu_sample = ImuSample {
            t_us: self.truth.t_us,
            gyro_rad_s: g,
            accel_m_s2: a,
            valid: true,
        };
    }

    fn sample_joints(&mut self) {
        let e = &self.encoders;
        let t = &self.truth;
        let rng = &mut self.streams.encoders;
        let mut j = JointState {
            t_us: t.t_us,
            wheel_valid: [true; WHEELS],
            suspension_valid: true,
            ..JointState::default()
        };
        for i in 0..WHEELS {
            j.drive_angle_rad[i] = e.drive_angle(t.wheel_angle_rad[i]);
            j.drive_rate_rad_s[i] = e.drive_rate(t.wheel_rate_rad_s[i], rng);
            j.steer_angle_rad[i] = e.steer_angle(t.steer_rad[i], rng);
        }
        let mean_increment = (0..WHEELS)
            .map(|i| j.drive_angle_rad[i] - self.joints.drive_angle_rad[i])
            .sum::<f64>()
            / WHEELS as f64;
        if self.steps > 0 {
            self.wheel_average_m +=
                mean_increment * NOMINAL_WHEEL_RADIUS_M * t.pose.pitch_rad.cos();
        }
        j.rocker_rad = e.suspension_angle(t.suspension.rocker_rad, rng);
        j.bogie_rad = [
            e.suspension_angle(t.suspension.bogie_rad[0], rng),
            e.suspension_angle(t.suspension.bogie_rad[1], rng),
        ];
        self.joints = j;
    }

    /// Unit vector towards the sun in `W` at the current truth time.
    pub fn sun_w(&self) -> Vector3<f64> {
        self.site.sun_w(self.truth.t_us as f64 * 1e-6)
    }

    fn sample_sun(&mut self) {
        let rot = self.truth.pose.rot_w_from_r();
        let sun_w = self.sun_w();
        let (v, in_view) = self.sun.measure(&sun_w, &rot, &mut self.streams.sun);
        self.sun_reading = SunReading {
            t_us: self.truth.t_us,
            sun_dir_rover: v,
            sun_in_view: in_view,
        };
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

/// Wrap an angle to `(-pi, pi]`.
pub fn wrap_pi(a: f64) -> f64 {
    let w = (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    if w <= -std::f64::consts::PI {
        w + std::f64::consts::TAU
    } else {
        w
    }
}

#[cfg(test)]
mod tests;
