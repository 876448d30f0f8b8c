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
use crate::sensors::faults::Faults;
use crate::sensors::hazcam::HazcamModel;
use crate::sensors::imu::ImuModel;
use crate::sensors::sun::SunParams;
use crate::soil::lumped_slip::LumpedSlip;
use crate::soil::per_wheel_slip::SlipModel;
use crate::soil::terramechanics::{Wheel, ROCKY8_MASS_KG};
use crate::surface::TerrainSurface;
use crate::terrain::Terrain;
use crate::vehicle::contact::WheelContact;
use crate::vehicle::forces::{ForceContact, Friction, QuasiStatic};
use crate::vehicle::geometry::{rocky8, TruthGeometry, VehicleGeometry, WheelPose, WHEELS};
use crate::vehicle::motors::MotorParams;
use crate::vehicle::placement::{
    place, BodyPose, JointLimits, Placement, PlacementJacobian, Suspension,
};
use crate::vehicle::rolling::RollingContact;
use nalgebra::Vector3;
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

impl Streams {
    /// Streams for `seed`; with `unit` (a rover unit's calibration seed) its calibration and
    /// manufacturing errors come from that seed instead.
    fn for_unit(seed: u64, unit: Option<u64>) -> Self {
        let mut streams = Streams::new(seed);
        if let Some(unit) = unit {
            // One rover unit: its calibration and manufacturing errors from their own seed.
            let cal = Streams::new(unit);
            streams.geometry = cal.geometry;
            streams.camera = cal.camera;
            streams.imu_calibration = cal.imu_calibration;
            streams.wheel_radius = cal.wheel_radius;
        }
        streams
    }
}

/// The truth vehicle geometry: Rocky 8's published dimensions with this seed's dimension
/// errors and the wheels' individual radius errors (each from its own stream).
fn truth_geometry(scenario: &Scenario, streams: &mut Streams) -> TruthGeometry {
    let sigma = scenario.sensors.dimension_error_m;
    let sigma_wheel = scenario.sensors.wheel_radius_error_m;
    rocky8()
        .perturbed(|_| {
            let n: f64 = StandardNormal.sample(&mut streams.geometry);
            sigma * n
        })
        .with_wheel_radius_errors(|_| {
            let n: f64 = StandardNormal.sample(&mut streams.wheel_radius);
            sigma_wheel * n
        })
}

/// The slip model of `scenario` with the per-seed soil draw.
fn slip_of(
    scenario: &Scenario,
    geometry: &TruthGeometry,
    streams: &mut Streams,
) -> anyhow::Result<Slip> {
    Ok(match scenario.slip_model {
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
    })
}

/// The start placement: the planned start plus the scenario's start offset (0 by default),
/// each wheel set on the ground.
fn start_placement(
    scenario: &Scenario,
    terrain: &Terrain,
    geometry: &TruthGeometry,
    limits: &JointLimits,
) -> Placement {
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
    let steer = [0.0; WHEELS];
    place(
        geometry,
        terrain,
        &pose,
        &Suspension::default(),
        &steer,
        limits,
    )
}

impl World {
    /// Build the world of `scenario` for `seed`.
    pub fn new(scenario: &Scenario, seed: u64) -> anyhow::Result<Self> {
        let mut streams = Streams::for_unit(seed, scenario.calibration_seed);
        let terrain = Terrain::new(
            scenario.terrain.clone(),
            scenario.terrain_seed.unwrap_or(seed),
            &scenario.waypoints,
        );
        let geometry = truth_geometry(scenario, &mut streams);
        let slip = slip_of(scenario, &geometry, &mut streams)?;
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
        let limits = JointLimits::rocky8();
        let p = start_placement(scenario, &terrain, &geometry, &limits);
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

/// Wrap an angle to `(-pi, pi]`.
pub fn wrap_pi(a: f64) -> f64 {
    let w = (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    if w <= -std::f64::consts::PI {
        w + std::f64::consts::TAU
    } else {
        w
    }
}

mod step;
#[cfg(test)]
mod tests;
