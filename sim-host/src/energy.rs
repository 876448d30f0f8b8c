//! The simulator's truth energy model: the electrical power the rover draws from its battery,
//! and the energy it has used, integrated along the truth state every simulation step. It is
//! the simulator's own model, independent of the flight software (no flight parameter, no
//! `fsw::sequencer` resource model); the flight software sees it only through the power
//! subsystem device ([`crate::devices::world::WorldPower`]).
//!
//! **Model.** Electrical power drawn from the battery:
//!
//! `P = P_awake + max(0, F v_rim) / eta`, `F = m g (sin(theta_up) + c_rr)`
//!
//! - `theta_up`: the truth pitch of the body along its direction of travel (positive uphill),
//!   from gravity in the body frame ([`drive_state`]);
//! - `v_rim`: the mean `|rim speed|` of the six truth drive motors, `|r_i w_i|` with each wheel's
//!   true radius: a slipping wheel turns faster than the rover moves and costs energy for the
//!   ground it does not cover; turning in place counts through the rim speeds too;
//! - `m` = [`ROCKY8_MASS_KG`], `g` = [`MARS_GRAVITY`];
//! - `c_rr`: the rolling resistance of the run's soil ([`rolling_resistance`]);
//! - `eta`: motor times gearhead efficiency ([`DRIVE_EFFICIENCY`]);
//! - `P_awake`: everything else the rover draws while awake and driving (avionics, cameras,
//!   heaters, motor controllers at rest) ([`AWAKE_POWER_W`]).
//!
//! Downhill (`F v_rim < 0`) nothing is recovered: the motors brake, they do not charge the
//! battery. A charging source is not modelled, so the energy used never decreases.
//!
//! **Constants and sources.**
//! - [`MOTOR_MAX_EFFICIENCY`] 0.85: maxon RE 25 (25 mm, graphite brushes, 20 W, 24 V, part
//!   number 118752), "max. efficiency 85 %" (maxon catalogue / product data sheet).
//! - [`GEARHEAD_MAX_EFFICIENCY`] 0.70: maxon GP 32 A planetary gearhead, 3 stages (86:1, part
//!   number 166167), "max. efficiency 70 %" (maxon catalogue / product data sheet). A 3-stage
//!   planetary is the class of reduction a 0.1 m wheel at 3 rad/s needs from a motor near
//!   8,000 rpm; the Mars Exploration Rovers carried maxon motors (78 of them, marsnews.com,
//!   "Motors bring Mars mission to life", 2003). Rocky 8's own drivetrain figures are not
//!   published in the sources we have: this is a catalogue drivetrain of its class.
//! - [`MER_DRIVE_POWER_W`] 100 W, [`MER_MASS_KG`] 174 kg: NASA, "Mars Exploration Rover - Rover
//!   Energy" (mars.nasa.gov/mer/mission/rover/energy/): "The rover needs about 100 watts ... to
//!   drive"; the rover's mass 174 kg (NASA MER mission facts). [`MER_DRIVE_SPEED_M_S`]
//!   0.05 m/s: MER's top speed on flat hard ground (NASA MER "Rover Wheels"/mobility pages:
//!   5 cm per second).
//! - [`AWAKE_POWER_W`]: **derived, not published.** No published split of MER's 100 W between
//!   avionics and motors was found (NASA's energy page gives the total only). `P_awake` is set
//!   so that this model gives 100 W for a MER-class drive: [`MER_MASS_KG`] on level firm
//!   ground ([`MER_CALIBRATION_ROLLING_RESISTANCE`], the firm-soil preset's 0.03) at
//!   [`MER_DRIVE_SPEED_M_S`] without slip: `P_awake = 100 - m_MER g c_rr v / eta` = 98.37 W.
//!   The limitation: the motor term of a level drive is then about 1.6 % of the total, which
//!   is what the model says (a 174 kg rover at 5 cm/s against 3 % rolling resistance needs
//!   0.97 W at the wheels), not a measured split; if MER's 100 W already included a larger
//!   motor share, `P_awake` is too high by that share.

use crate::soil::lumped_slip::LumpedSoil;
use crate::soil::terramechanics::{Wheel, MARS_GRAVITY, ROCKY8_MASS_KG};
use crate::vehicle::geometry::WHEELS;
use crate::world::{Slip, Truth};
use nalgebra::Vector3;

/// Maximum efficiency of the drive motor, maxon RE 25 (118752): 85 %.
pub const MOTOR_MAX_EFFICIENCY: f64 = 0.85;
/// Maximum efficiency of the gearhead, maxon GP 32 A, 3 stages (166167): 70 %.
pub const GEARHEAD_MAX_EFFICIENCY: f64 = 0.70;
/// Drivetrain efficiency `eta` from the battery to the wheel rim: motor times gearhead.
pub const DRIVE_EFFICIENCY: f64 = MOTOR_MAX_EFFICIENCY * GEARHEAD_MAX_EFFICIENCY;

/// MER's power to drive, W (NASA, "Mars Exploration Rover - Rover Energy").
pub const MER_DRIVE_POWER_W: f64 = 100.0;
/// MER's mass, kg (NASA MER mission facts).
pub const MER_MASS_KG: f64 = 174.0;
/// MER's drive speed of the calibration: its 5 cm/s on flat hard ground, m/s.
pub const MER_DRIVE_SPEED_M_S: f64 = 0.05;
/// Rolling resistance of the calibration's level firm ground: the lumped firm-soil preset's
/// `rolling_resistance` ([`LumpedSoil::firm_soil`]).
pub const MER_CALIBRATION_ROLLING_RESISTANCE: f64 = 0.03;

/// Power drawn while awake apart from the drive motors' mechanical work, W: derived so that a
/// MER-class drive (level firm ground, 5 cm/s, no slip) draws [`MER_DRIVE_POWER_W`] (see the
/// module doc: a calibration, not a published split).
pub const AWAKE_POWER_W: f64 = MER_DRIVE_POWER_W
    - MER_MASS_KG * MARS_GRAVITY * MER_CALIBRATION_ROLLING_RESISTANCE * MER_DRIVE_SPEED_M_S
        / DRIVE_EFFICIENCY;

/// The parameters of the power model of one vehicle on one soil.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyModel {
    /// Vehicle mass `m`, kg.
    pub mass_kg: f64,
    /// Gravity `g`, m/s^2.
    pub gravity_m_s2: f64,
    /// Rolling-resistance coefficient `c_rr` of the soil (dimensionless).
    pub rolling_resistance: f64,
    /// Drivetrain efficiency `eta` (battery to wheel rim).
    pub efficiency: f64,
    /// Power drawn while awake apart from the drive's mechanical work, W.
    pub awake_power_w: f64,
}

impl EnergyModel {
    /// Rocky 8 ([`ROCKY8_MASS_KG`], Mars gravity, the catalogue drivetrain, [`AWAKE_POWER_W`])
    /// on a soil of rolling resistance `rolling_resistance`.
    pub fn rocky8(rolling_resistance: f64) -> Self {
        Self {
            mass_kg: ROCKY8_MASS_KG,
            gravity_m_s2: MARS_GRAVITY,
            rolling_resistance,
            efficiency: DRIVE_EFFICIENCY,
            awake_power_w: AWAKE_POWER_W,
        }
    }

    /// Rocky 8 on the soil of a run's slip model ([`rolling_resistance`]).
    pub fn for_slip(slip: &Slip) -> Self {
        Self::rocky8(rolling_resistance(slip))
    }

    /// The MER-class vehicle of the calibration: [`MER_MASS_KG`] on level firm ground.
    pub fn mer_calibration() -> Self {
        Self {
            mass_kg: MER_MASS_KG,
            ..Self::rocky8(MER_CALIBRATION_ROLLING_RESISTANCE)
        }
    }

    /// Resistance force along the motion `F = m g (sin(theta_up) + c_rr)`, N, at the pitch
    /// `theta_up_rad` along the direction of travel (positive uphill).
    pub fn resistance_n(&self, theta_up_rad: f64) -> f64 {
        self.mass_kg * self.gravity_m_s2 * (theta_up_rad.sin() + self.rolling_resistance)
    }

    /// Electrical power `P = P_awake + max(0, F v_rim) / eta`, W, at the pitch `theta_up_rad`
    /// along the direction of travel and the mean rim speed `rim_speed_m_s` (m/s, >= 0).
    pub fn power_w(&self, theta_up_rad: f64, rim_speed_m_s: f64) -> f64 {
        let mechanical = (self.resistance_n(theta_up_rad) * rim_speed_m_s).max(0.0);
        self.awake_power_w + mechanical / self.efficiency
    }
}

/// Rolling-resistance coefficient `c_rr` of a run's soil: the lumped model's
/// `rolling_resistance` (after the run's per-seed draw); for the terramechanics soils the
/// rigid wheel's resistance at zero slip, `-DP(s = 0) / W`, under the level-ground wheel load
/// `W = m g / 6` ([`crate::soil::rigid_wheel::wheel_forces`] on the Rocky 8 wheel), not below 0 (a
/// soil whose stress distribution gives a net pull at zero slip has no rolling resistance in
/// this model).
pub fn rolling_resistance(slip: &Slip) -> f64 {
    match slip {
        Slip::Lumped(m) => m.soil().rolling_resistance.max(0.0),
        Slip::Terramechanics(m) => {
            let load = ROCKY8_MASS_KG * MARS_GRAVITY / WHEELS as f64;
            let f =
                crate::soil::rigid_wheel::wheel_forces(m.soil(), &Wheel::rocky8(), load, 0.0, 0.0);
            (-f.drawbar_pull_n / load).max(0.0)
        }
    }
}

/// The lumped firm-soil preset's rolling resistance (the calibration's ground, for the tests
/// and the docs).
pub fn firm_soil_rolling_resistance() -> f64 {
    LumpedSoil::firm_soil().rolling_resistance
}

/// The drive state of the power model from the truth: `(theta_up, v_rim)`. `theta_up` is the
/// body's pitch along its direction of travel, rad, positive uphill: `asin(-g_x d)` with `g_x`
/// the body-`x` component of the unit gravity vector in `R` (z down) and `d` = +1 when the
/// body moves (or, standing, its wheels turn) forwards, -1 backwards. `v_rim` is the mean
/// `|r_i w_i|` of the six drive motors with each wheel's true radius `radii_m`, m/s.
pub fn drive_state(truth: &Truth, radii_m: &[f64; WHEELS]) -> (f64, f64) {
    let rot = truth.pose.rot_w_from_r();
    let gravity_r = rot.inverse() * Vector3::z();
    let rims: [f64; WHEELS] = std::array::from_fn(|i| radii_m[i] * truth.wheel_rate_rad_s[i]);
    let v_rim = rims.iter().map(|r| r.abs()).sum::<f64>() / WHEELS as f64;
    let forward = truth.velocity_r_m_s[0];
    let signed_rim: f64 = rims.iter().sum();
    let direction = if forward.abs() > 1e-6 {
        forward.signum()
    } else if signed_rim < 0.0 {
        -1.0
    } else {
        1.0
    };
    let theta_up = (-gravity_r.x * direction).clamp(-1.0, 1.0).asin();
    (theta_up, v_rim)
}

/// The battery energy used since boot, integrated per simulation step: each step adds the power
/// of its truth state times the step (exact for a constant power).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyMeter {
    /// The power model.
    pub model: EnergyModel,
    energy_j: f64,
    power_w: f64,
    elapsed_s: f64,
}

impl EnergyMeter {
    /// No energy used yet; the power is the awake power until the first step.
    pub fn new(model: EnergyModel) -> Self {
        Self {
            model,
            energy_j: 0.0,
            power_w: model.awake_power_w,
            elapsed_s: 0.0,
        }
    }

    /// One step of `dt_s` at pitch `theta_up_rad` and mean rim speed `rim_speed_m_s`.
    pub fn step(&mut self, theta_up_rad: f64, rim_speed_m_s: f64, dt_s: f64) {
        let p = self.model.power_w(theta_up_rad, rim_speed_m_s);
        self.integrate(p, dt_s);
    }

    /// Add `power_w` over `dt_s` (a step of the power model, or a test's constant power).
    pub fn integrate(&mut self, power_w: f64, dt_s: f64) {
        self.energy_j += power_w * dt_s;
        self.elapsed_s += dt_s;
        self.power_w = power_w;
    }

    /// Energy used since boot, J.
    pub fn energy_j(&self) -> f64 {
        self.energy_j
    }

    /// Power of the last step, W.
    pub fn power_w(&self) -> f64 {
        self.power_w
    }

    /// Time integrated, s.
    pub fn elapsed_s(&self) -> f64 {
        self.elapsed_s
    }

    /// Mean power since boot, W (the awake power before the first step).
    pub fn mean_power_w(&self) -> f64 {
        if self.elapsed_s > 0.0 {
            self.energy_j / self.elapsed_s
        } else {
            self.model.awake_power_w
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ENERGY-1: a MER-class drive (174 kg, level firm ground, 5 cm/s, no slip) draws the
    /// published 100 W; the calibration's ground is the firm-soil preset.
    #[test]
    fn energy_1_level_drive_gives_the_mer_figure() {
        assert_eq!(
            MER_CALIBRATION_ROLLING_RESISTANCE,
            firm_soil_rolling_resistance()
        );
        let mer = EnergyModel::mer_calibration();
        let p = mer.power_w(0.0, MER_DRIVE_SPEED_M_S);
        assert!((p - 100.0).abs() < 1e-9, "{p} W");
        // The motor share of it, computed here from the figures: 174 kg x 3.711 m/s^2 x 0.03
        // x 0.05 m/s / (0.85 x 0.70).
        let motors = 174.0 * 3.711 * 0.03 * 0.05 / (0.85 * 0.70);
        assert!((p - AWAKE_POWER_W - motors).abs() < 1e-9);
        assert!((AWAKE_POWER_W - 98.372).abs() < 1e-3, "{AWAKE_POWER_W}");
    }

    /// ENERGY-2: 10 deg uphill raises the power by the grade term `m g sin(10 deg) v / eta`,
    /// computed independently here; downhill steep enough to push the rover recovers nothing.
    #[test]
    fn energy_2_uphill_adds_the_grade_term() {
        let model = EnergyModel::rocky8(0.05);
        let v = 0.1;
        let level = model.power_w(0.0, v);
        let up = model.power_w(10f64.to_radians(), v);
        let grade = 150.0 * 3.711 * 0.173_648_177_666_930_33 * 0.1 / 0.595;
        assert!(
            (up - level - grade).abs() < 1e-9,
            "{up} - {level} vs {grade}"
        );
        assert!(grade > 9.0 && grade < 17.0, "{grade}");
        // Downhill 10 deg: sin(-10 deg) + 0.05 < 0, the motors brake, no energy back.
        let down = model.power_w(-10f64.to_radians(), v);
        assert_eq!(down, AWAKE_POWER_W);
        // Slip costs energy: the same ground speed with the wheels turning 30 % faster.
        assert!(model.power_w(0.0, v / 0.7) > level);
    }

    /// ENERGY-3: standing (no rim speed), the rover draws the awake power on any slope.
    #[test]
    fn energy_3_standing_draws_the_awake_power() {
        let model = EnergyModel::rocky8(0.08);
        for pitch in [-0.3, 0.0, 0.2] {
            assert_eq!(model.power_w(pitch, 0.0), AWAKE_POWER_W);
        }
        let meter = EnergyMeter::new(model);
        assert_eq!(meter.power_w(), AWAKE_POWER_W);
        assert_eq!(meter.mean_power_w(), AWAKE_POWER_W);
    }

    /// ENERGY-4: the meter integrates a constant power exactly (to rounding) over 700 s of
    /// 5 ms steps, and its mean power is that power.
    #[test]
    fn energy_4_constant_power_integrates_exactly() {
        let mut meter = EnergyMeter::new(EnergyModel::rocky8(0.03));
        let (p, dt, n) = (123.25, 0.005, 140_000u32);
        for _ in 0..n {
            meter.integrate(p, dt);
        }
        let expected = p * dt * f64::from(n);
        assert!(
            (meter.energy_j() - expected).abs() < 1e-9 * expected,
            "{} vs {expected}",
            meter.energy_j()
        );
        assert!((meter.mean_power_w() - p).abs() < 1e-9 * p);
        assert!((meter.elapsed_s() - 700.0).abs() < 1e-6);
        // The model's steps: a standing rover uses the awake power times the time.
        let mut standing = EnergyMeter::new(EnergyModel::rocky8(0.03));
        for _ in 0..1_000 {
            standing.step(0.1, 0.0, dt);
        }
        assert!((standing.energy_j() - AWAKE_POWER_W * 5.0).abs() < 1e-9);
    }

    /// ENERGY-5: the soils' rolling resistance: the lumped presets' coefficient (after the
    /// per-seed draw), and for the terramechanics soils the rigid wheel's resistance at zero
    /// slip: about 0.14 on the sandy loam; 0 (clamped) on the Ishigami regolith simulant, whose
    /// Wong-Reece stress distribution gives a net pull at zero slip (a limit of the model,
    /// `docs/simulator.md`).
    #[test]
    fn energy_5_rolling_resistance_of_the_soils() {
        use crate::soil::terramechanics::Soil;
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
        let lumped = Slip::Lumped(crate::soil::lumped_slip::LumpedSlip::new(
            LumpedSoil::loose_sand(),
            true,
            &mut rng,
        ));
        let c = rolling_resistance(&lumped);
        assert!((c - 0.08).abs() < 0.08 * 0.3, "{c}");
        let mut terra = |soil: Soil| {
            Slip::Terramechanics(crate::soil::per_wheel_slip::SlipModel::new(
                soil,
                [0.1; WHEELS],
                false,
                &mut rng,
            ))
        };
        let sand = rolling_resistance(&terra(Soil::ishigami_regolith_simulant()));
        let loam = rolling_resistance(&terra(Soil::sandy_loam()));
        std::eprintln!("c_rr: lumped sand {c:.4}, regolith simulant {sand:.4}, loam {loam:.4}");
        assert!(loam > 0.05 && loam < 0.3, "{loam}");
        assert_eq!(sand, 0.0);
    }

    /// ENERGY-6: the world integrates the model along its truth every step and the power
    /// device reports that energy with the mean power since its previous reading: standing,
    /// the awake power; driving straight on level firm ground at 0.1 m/s without slip, the
    /// awake power plus `m g c_rr v / eta` computed here; the scenario's `power` faults
    /// (invalid, dropout) reach the reading.
    #[test]
    fn energy_6_world_and_power_device() {
        use crate::devices::world::WorldPower;
        use crate::sensors::faults::{FaultDevice, FaultKind, FaultSpec};
        use rover_hal::{ErrorKind, Power};
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/flat-firm.toml");
        let mut scenario = crate::scenario::Scenario::load(&path).unwrap();
        scenario.slip = false;
        scenario.terrain.roughness_m = 0.0;
        scenario.terrain.rocks = None;
        scenario.sensors.dimension_error_m = 0.0;
        scenario.sensors.wheel_radius_error_m = 0.0;
        scenario.faults = vec![
            FaultSpec::new(FaultDevice::Power, FaultKind::Invalid, 9.0, 1.0),
            FaultSpec::new(FaultDevice::Power, FaultKind::Dropout, 10.0, 1.0),
        ];
        let world = std::rc::Rc::new(std::cell::RefCell::new(
            crate::world::World::new(&scenario, 1).unwrap(),
        ));
        let mut device = WorldPower::new(world.clone());
        let run = |seconds: f64| {
            for _ in 0..(seconds * 200.0).round() as u32 {
                world.borrow_mut().step();
            }
        };
        // Standing for 1 s.
        run(1.0);
        let standing = device.read().unwrap();
        assert!(standing.valid);
        assert_eq!(standing.t_us, 1_000_000);
        assert!((standing.energy_used_j - AWAKE_POWER_W).abs() < 1e-9);
        assert!((standing.bus_power_w - AWAKE_POWER_W).abs() < 1e-9);
        // Driving straight at 1 rad/s (0.1 m/s rim speed): 3 s to settle, then 5 s measured.
        world.borrow_mut().command.wheel_rate_rad_s = [1.0; WHEELS];
        run(3.0);
        let settled = device.read().unwrap();
        run(5.0);
        let driving = device.read().unwrap();
        let c_rr = world.borrow().energy.model.rolling_resistance;
        assert_eq!(c_rr, rolling_resistance(world.borrow().slip_model()));
        let expected = AWAKE_POWER_W + 150.0 * 3.711 * c_rr * 0.1 / (0.85 * 0.70);
        assert!(
            (driving.bus_power_w - expected).abs() < 1e-6 * expected,
            "{} W vs {expected} W",
            driving.bus_power_w
        );
        let energy = world.borrow().energy.energy_j();
        assert_eq!(driving.energy_used_j, energy);
        assert!(
            (driving.energy_used_j - settled.energy_used_j - 5.0 * driving.bus_power_w).abs()
                < 1e-6
        );
        // Faults: invalid at 9-10 s, dropout at 10-11 s.
        run(0.5);
        assert!(!device.read().unwrap().valid);
        run(1.0);
        assert_eq!(device.read(), Err(ErrorKind::Timeout));
        run(1.0);
        let after = device.read().unwrap();
        assert!(after.valid && after.energy_used_j > driving.energy_used_j);
    }
}
