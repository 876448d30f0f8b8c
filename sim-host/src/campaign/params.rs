//! The scenario parameters a campaign can disperse, by name (`soil.friction_angle_deg`,
//! `terrain.slope_deg`, `sensors.imu.gyro_noise_rad_s`, `start.north_m`, ...). Each name maps
//! to one `f64` of a [`Scenario`]; a soil parameter first turns a preset soil into its explicit
//! parameters (the preset's values, so an undispersed field keeps the preset's value).

use crate::scenario::{Scenario, SlipModelKind, SoilSpec};
use crate::soil::per_wheel_slip::SoilParams;
use crate::terrain::BaseShape;

/// Accessor of one parameter.
pub type Accessor = fn(&mut Scenario) -> anyhow::Result<&mut f64>;

/// A dispersible parameter.
#[derive(Clone, Copy)]
pub struct Param {
    /// Name used in campaign specs.
    pub name: &'static str,
    /// Unit.
    pub unit: &'static str,
    /// What it is.
    pub doc: &'static str,
    /// The value in a scenario.
    pub get: Accessor,
}

impl std::fmt::Debug for Param {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Param").field("name", &self.name).finish()
    }
}

/// The explicit rigid-wheel soil parameters of `soil` (inverse of `SoilParams::soil`).
pub fn soil_params(soil: &crate::soil::terramechanics::Soil) -> SoilParams {
    SoilParams {
        n: soil.n,
        k_c: soil.k_c,
        k_phi: soil.k_phi,
        cohesion_pa: soil.cohesion_pa,
        friction_angle_deg: soil.phi_rad.to_degrees(),
        shear_modulus_m: soil.shear_k_m,
        lateral_shear_modulus_m: Some(soil.shear_k_y_m),
        shear_modulus_slope_m_per_rad: soil.shear_k_slope_m_per_rad,
        lateral_shear_modulus_slope_m_per_rad: soil.shear_k_y_slope_m_per_rad,
        theta_m_a0: Some(soil.theta_m_a0),
        theta_m_a1: Some(soil.theta_m_a1),
        exit_sinkage_ratio: soil.exit_sinkage_ratio,
    }
}

/// The scenario's rigid-wheel soil as explicit parameters (a preset is replaced by its values).
fn bekker(s: &mut Scenario) -> anyhow::Result<&mut SoilParams> {
    anyhow::ensure!(
        s.slip_model == SlipModelKind::Terramechanics,
        "a rigid-wheel soil parameter, but the scenario runs the lumped slip model (use \
         soil_lumped.*)"
    );
    if !matches!(s.soil, SoilSpec::Bekker(_)) {
        s.soil = SoilSpec::Bekker(soil_params(&s.soil.bekker()?));
    }
    match &mut s.soil {
        SoilSpec::Bekker(p) => {
            // The defaults `SoilParams::soil` would apply, made explicit so a dispersion of
            // them starts from the value the simulator uses.
            p.lateral_shear_modulus_m.get_or_insert(p.shear_modulus_m);
            p.theta_m_a0
                .get_or_insert(crate::soil::terramechanics::WONG_REECE_SAND_A0);
            p.theta_m_a1
                .get_or_insert(crate::soil::terramechanics::WONG_REECE_SAND_A1);
            Ok(p)
        }
        _ => anyhow::bail!("soil is not a rigid-wheel soil"),
    }
}

/// The scenario's lumped soil as explicit parameters.
fn lumped(s: &mut Scenario) -> anyhow::Result<&mut crate::soil::lumped_slip::LumpedSoil> {
    anyhow::ensure!(
        s.slip_model == SlipModelKind::Lumped,
        "a lumped soil parameter, but the scenario runs the terramechanics slip model (use soil.*)"
    );
    if !matches!(s.soil, SoilSpec::Lumped(_)) {
        s.soil = SoilSpec::Lumped(s.soil.lumped()?);
    }
    match &mut s.soil {
        SoilSpec::Lumped(p) => Ok(p),
        _ => anyhow::bail!("soil is not a lumped soil"),
    }
}

fn plane(s: &mut Scenario) -> anyhow::Result<(&mut f64, &mut f64)> {
    match &mut s.terrain.base {
        BaseShape::Plane {
            slope_deg,
            downhill_azimuth_deg,
        } => Ok((slope_deg, downhill_azimuth_deg)),
        other => anyhow::bail!("terrain.slope_deg needs a plane terrain, not {other:?}"),
    }
}

fn rocks(s: &mut Scenario) -> anyhow::Result<&mut crate::terrain::RockField> {
    s.terrain
        .rocks
        .as_mut()
        .ok_or_else(|| anyhow::anyhow!("the scenario has no rock field"))
}

macro_rules! p {
    ($name:literal, $unit:literal, $doc:literal, $s:ident => $body:expr) => {
        Param {
            name: $name,
            unit: $unit,
            doc: $doc,
            get: |$s: &mut Scenario| -> anyhow::Result<&mut f64> { Ok($body) },
        }
    };
}

/// Every dispersible parameter (rustfmt leaves the table alone: `s => body` is not Rust
/// syntax, so it stays one parameter a line).
pub const PARAMS: &[Param] = &[
    // Rigid-wheel soil (terramechanics slip model; `docs/terramechanics.md`).
    p!("soil.n", "-", "Bekker sinkage exponent", s => &mut bekker(s)?.n),
    p!("soil.k_c", "N/m^(n+1)", "Bekker cohesive modulus", s => &mut bekker(s)?.k_c),
    p!("soil.k_phi", "N/m^(n+2)", "Bekker frictional modulus", s => &mut bekker(s)?.k_phi),
    p!("soil.cohesion_pa", "Pa", "cohesion", s => &mut bekker(s)?.cohesion_pa),
    p!("soil.friction_angle_deg", "deg", "internal friction angle", s => &mut bekker(s)?.friction_angle_deg),
    p!("soil.shear_modulus_m", "m", "shear deformation modulus K_x at zero slip angle", s => &mut bekker(s)?.shear_modulus_m),
    p!("soil.lateral_shear_modulus_m", "m", "lateral shear deformation modulus K_y", s => bekker(s)?.lateral_shear_modulus_m.get_or_insert(f64::NAN)),
    p!("soil.exit_sinkage_ratio", "-", "rear-to-front sinkage ratio (exit angle)", s => &mut bekker(s)?.exit_sinkage_ratio),
    p!("soil.theta_m_a0", "-", "Wong-Reece a0 of the maximum-stress angle", s => bekker(s)?.theta_m_a0.get_or_insert(f64::NAN)),
    p!("soil.theta_m_a1", "-", "Wong-Reece a1 of the maximum-stress angle", s => bekker(s)?.theta_m_a1.get_or_insert(f64::NAN)),
    // Lumped soil (lumped slip model).
    p!("soil_lumped.cohesion_term", "-", "c A / W", s => &mut lumped(s)?.cohesion_term),
    p!("soil_lumped.friction_angle_deg", "deg", "internal friction angle", s => &mut lumped(s)?.friction_angle_deg),
    p!("soil_lumped.shear_modulus_ratio", "-", "K / L", s => &mut lumped(s)?.shear_modulus_ratio),
    p!("soil_lumped.rolling_resistance", "-", "rolling-resistance coefficient", s => &mut lumped(s)?.rolling_resistance),
    p!("soil_lumped.lateral_constant", "-", "lateral slip-angle constant", s => &mut lumped(s)?.lateral_constant),
    p!("soil_lumped.noise", "-", "slip perturbation sigma", s => &mut lumped(s)?.noise),
    // Terrain.
    p!("terrain.slope_deg", "deg", "slope of a plane terrain", s => plane(s)?.0),
    p!("terrain.downhill_azimuth_deg", "deg", "downhill azimuth of a plane terrain", s => plane(s)?.1),
    p!("terrain.roughness_m", "m", "amplitude of the rough-terrain noise", s => &mut s.terrain.roughness_m),
    p!("terrain.roughness_wavelength_m", "m", "longest roughness wavelength", s => &mut s.terrain.roughness_wavelength_m),
    p!("terrain.rocks.density_per_m2", "1/m^2", "rock density", s => &mut rocks(s)?.density_per_m2),
    p!("terrain.rocks.max_height_m", "m", "largest rock height", s => &mut rocks(s)?.max_height_m),
    p!("terrain.rocks.abundance_k", "-", "rock area fraction k of the Golombek-Rapp model (0: power law)", s => &mut rocks(s)?.abundance_k),
    // Start pose: the true start minus the planned one (`Scenario::start_offset`).
    p!("start.north_m", "m", "true start north of the planned start", s => &mut s.start_offset.north_m),
    p!("start.east_m", "m", "true start east of the planned start", s => &mut s.start_offset.east_m),
    p!("start.yaw_deg", "deg", "true start heading minus the planned heading", s => &mut s.start_offset.yaw_deg),
    // Drive and site.
    p!("speed_m_s", "m/s", "driving speed", s => &mut s.speed_m_s),
    p!("site.local_solar_time_h", "h", "local true solar time at t = 0", s => &mut s.site.local_solar_time_h),
    // IMU noise and calibration (1-sigma values of the draws; `docs/simulator.md`).
    p!("sensors.imu.gyro_noise_rad_s", "rad/s", "gyro white noise per sample", s => &mut s.sensors.imu.gyro_noise_rad_s),
    p!("sensors.imu.gyro_bias_rad_s", "rad/s", "gyro turn-on bias", s => &mut s.sensors.imu.gyro_bias_rad_s),
    p!("sensors.imu.gyro_bias_walk_rad_s_sqrt_s", "rad/s/sqrt(s)", "gyro bias walk", s => &mut s.sensors.imu.gyro_bias_walk_rad_s_sqrt_s),
    p!("sensors.imu.accel_noise_m_s2", "m/s^2", "accelerometer white noise per sample", s => &mut s.sensors.imu.accel_noise_m_s2),
    p!("sensors.imu.accel_bias_m_s2", "m/s^2", "accelerometer turn-on bias", s => &mut s.sensors.imu.accel_bias_m_s2),
    p!("sensors.imu.accel_bias_walk_m_s2_sqrt_s", "m/s^2/sqrt(s)", "accelerometer bias walk", s => &mut s.sensors.imu.accel_bias_walk_m_s2_sqrt_s),
    p!("sensors.imu.gyro_scale_rel", "-", "gyro scale-factor error sigma", s => &mut s.sensors.imu.gyro_scale_rel),
    p!("sensors.imu.gyro_misalignment_deg", "deg", "gyro misalignment sigma", s => &mut s.sensors.imu.gyro_misalignment_deg),
    p!("sensors.imu.accel_scale_rel", "-", "accelerometer scale-factor error sigma", s => &mut s.sensors.imu.accel_scale_rel),
    p!("sensors.imu.accel_misalignment_deg", "deg", "accelerometer misalignment sigma", s => &mut s.sensors.imu.accel_misalignment_deg),
    // Encoders and sun sensor.
    p!("sensors.encoders.angle_noise_rad", "rad", "steering and suspension angle noise", s => &mut s.sensors.encoders.angle_noise_rad),
    p!("sensors.encoders.rate_noise_rad_s", "rad/s", "drive rate noise", s => &mut s.sensors.encoders.rate_noise_rad_s),
    p!("sensors.sun.noise_rad", "rad", "sun sensor noise per axis", s => &mut s.sensors.sun.noise_rad),
    // Manufacturing and hazcam calibration error sigmas.
    p!("sensors.dimension_error_m", "m", "vehicle dimension error sigma", s => &mut s.sensors.dimension_error_m),
    p!("sensors.wheel_radius_error_m", "m", "per-wheel radius error sigma", s => &mut s.sensors.wheel_radius_error_m),
    p!("sensors.camera_tolerances.focal_rel", "-", "focal-length error sigma", s => &mut s.sensors.camera_tolerances.focal_rel),
    p!("sensors.camera_tolerances.principal_point_px", "px", "principal point sigma", s => &mut s.sensors.camera_tolerances.principal_point_px),
    p!("sensors.camera_tolerances.baseline_m", "m", "baseline error sigma", s => &mut s.sensors.camera_tolerances.baseline_m),
    p!("sensors.camera_tolerances.mount_angle_deg", "deg", "head mounting angle sigma", s => &mut s.sensors.camera_tolerances.mount_angle_deg),
    p!("sensors.camera_tolerances.mount_position_m", "m", "head mounting position sigma", s => &mut s.sensors.camera_tolerances.mount_position_m),
];

/// The parameter called `name`.
pub fn find(name: &str) -> anyhow::Result<&'static Param> {
    PARAMS.iter().find(|p| p.name == name).ok_or_else(|| {
        let names: Vec<&str> = PARAMS.iter().map(|p| p.name).collect();
        anyhow::anyhow!("unknown parameter {name:?}; known: {}", names.join(", "))
    })
}

/// Set `name` to `value` in `scenario`.
pub fn set(scenario: &mut Scenario, name: &str, value: f64) -> anyhow::Result<()> {
    *(find(name)?.get)(scenario)? = value;
    Ok(())
}

/// The value of `name` in `scenario` (a preset soil is made explicit first).
pub fn get(scenario: &mut Scenario, name: &str) -> anyhow::Result<f64> {
    Ok(*(find(name)?.get)(scenario)?)
}
