//! Scenario files (TOML): terrain, soil, path, duration, sensor rates and noise, seed, faults.
//! The format is documented in `docs/simulator.md`.

use crate::sensors::encoders::EncoderParams;
use crate::sensors::faults::FaultSpec;
use crate::sensors::hazcam::CameraTolerances;
use crate::sensors::hazcam_lens::LensTolerances;
use crate::sensors::imu::ImuParams;
use crate::sensors::sun::SunParams;
use crate::soil::lumped_slip::LumpedSoil;
use crate::soil::per_wheel_slip::SoilParams;
use crate::soil::terramechanics::Soil;
use crate::terrain::TerrainSpec;
use serde::Deserialize;
use std::path::Path;

/// Soil: a preset name (`"loose_sand"`, `"firm_soil"`, and for the terramechanics model also
/// `"mars_simulant"` and `"wong_dry_sand"`) or explicit parameters of either model. For the
/// terramechanics model `loose_sand` is the lunar regolith simulant of Ishigami et al. (2007),
/// measured with a small rover wheel; `firm_soil` Wong's sandy loam; `mars_simulant` the DLR
/// Mars soil simulant; `wong_dry_sand` Wong's dry sand (the `loose_sand` of earlier versions)
/// (`docs/terramechanics.md`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum SoilSpec {
    /// A named preset.
    Preset(String),
    /// Explicit parameters of the lumped model.
    Lumped(LumpedSoil),
    /// Explicit Bekker and shear parameters (terramechanics model).
    Bekker(SoilParams),
}

/// Which slip model the truth uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum SlipModelKind {
    /// One slip ratio and angle for the vehicle from the slopes ([`crate::soil::lumped_slip`]).
    Lumped,
    /// Per-wheel slip from loads and rigid-wheel (Wong-Reece) terramechanics ([`crate::soil::per_wheel_slip`]);
    /// the default.
    #[default]
    Terramechanics,
}

impl SoilSpec {
    /// The soil of the lumped model.
    pub fn lumped(&self) -> anyhow::Result<LumpedSoil> {
        match self {
            SoilSpec::Preset(name) => match name.as_str() {
                "loose_sand" => Ok(LumpedSoil::loose_sand()),
                "firm_soil" => Ok(LumpedSoil::firm_soil()),
                other => anyhow::bail!(
                    "unknown soil preset {other:?} for the lumped model (loose_sand, firm_soil)"
                ),
            },
            SoilSpec::Lumped(p) => Ok(*p),
            SoilSpec::Bekker(_) => {
                anyhow::bail!("Bekker soil parameters need slip_model = \"terramechanics\"")
            }
        }
    }

    /// The soil of the terramechanics model.
    pub fn bekker(&self) -> anyhow::Result<Soil> {
        match self {
            SoilSpec::Preset(name) => match name.as_str() {
                "loose_sand" => Ok(Soil::ishigami_regolith_simulant()),
                "firm_soil" => Ok(Soil::sandy_loam()),
                "mars_simulant" => Ok(Soil::mars_dlr_simulant()),
                "wong_dry_sand" => Ok(Soil::dry_sand()),
                other => anyhow::bail!(
                    "unknown soil preset {other:?} (loose_sand, firm_soil, mars_simulant, \
                     wong_dry_sand)"
                ),
            },
            SoilSpec::Bekker(p) => Ok(p.soil()),
            SoilSpec::Lumped(_) => {
                anyhow::bail!("lumped soil parameters need slip_model = \"lumped\"")
            }
        }
    }
}

/// Where and when the traverse happens (the `[site]` table): the sun's motion in the
/// simulator follows from it ([`crate::sensors::sun`]). The flight software is given the same
/// site and date as mission inputs and computes the sun with its own code and clock.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default)]
pub struct Site {
    /// Latitude, degrees (north positive).
    pub latitude_deg: f64,
    /// Areocentric solar longitude `Ls` (the season), degrees; constant over a run.
    pub solar_longitude_deg: f64,
    /// Local true solar time at simulation time 0, hours (0-24, noon at 12).
    pub local_solar_time_h: f64,
}

impl Default for Site {
    /// Gusev crater (14.6 deg S) at the northern spring equinox (`Ls` 0), starting at 09:00
    /// local true solar time: the sun climbs from 43.2 deg to 52.2 deg elevation over the
    /// longest scenario (2400 s), 76-70 deg azimuth (east-north-east).
    fn default() -> Self {
        Self {
            latitude_deg: -14.6,
            solar_longitude_deg: 0.0,
            local_solar_time_h: 9.0,
        }
    }
}

impl Site {
    /// Local true solar time `t_s` seconds after simulation time 0, hours (not wrapped).
    pub fn local_solar_time_at_h(&self, t_s: f64) -> f64 {
        self.local_solar_time_h + 24.0 * t_s / crate::sensors::sun::SOL_S
    }

    /// Unit vector towards the sun in `W` (x north, y east, z down) at simulation time `t_s`.
    pub fn sun_w(&self, t_s: f64) -> nalgebra::Vector3<f64> {
        crate::sensors::sun::sun_direction_w(
            self.latitude_deg,
            self.solar_longitude_deg,
            self.local_solar_time_at_h(t_s),
        )
    }
}

/// Sensor rates and noise.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default)]
pub struct SensorSpec {
    /// IMU noise (the IMU runs at the 200 Hz minor-frame rate).
    pub imu: ImuParams,
    /// Encoder noise and quantisation.
    pub encoders: EncoderParams,
    /// Joint-encoder sample rate, Hz (must divide 200).
    pub encoder_hz: u32,
    /// Sun sensor (the sun itself follows from the scenario's [`Site`]).
    pub sun: SunParams,
    /// Sun-sensor sample rate, Hz (must divide 200).
    pub sun_hz: u32,
    /// Polls of the camera between trigger and completion.
    pub camera_latency_polls: u32,
    /// Per-seed error of each vehicle dimension seen by the simulator, m (1-sigma); the flight
    /// code keeps the nominal geometry.
    pub dimension_error_m: f64,
    /// Per-seed error of each wheel's radius on its own, m (1-sigma), on top of the common
    /// radius error of `dimension_error_m` (which shifts all six radii together): wheels differ
    /// by manufacturing and wear. Default 0.5 mm, a simulator assumption (no published Rocky 8
    /// figure found; Borenstein & Feng 1996 name unequal wheel diameters a dominant systematic
    /// odometry error, without a tolerance for machined rover wheels).
    pub wheel_radius_error_m: f64,
    /// Per-seed calibration errors of the hazcam head (the flight software is given the
    /// nominal calibration; the images are rendered with the true one). `false`: the true head
    /// is the nominal one.
    pub camera_calibration_errors: bool,
    /// 1-sigma tolerances of those errors.
    pub camera_tolerances: CameraTolerances,
    /// Ideal lenses: the cameras deliver the rectified pinhole pair directly (the model before
    /// the wide-angle lenses, for comparison). Default `false`: raw images through the
    /// wide-angle lens model (`sensors::hazcam_lens`), rectified by the flight software.
    pub ideal_lens: bool,
    /// 1-sigma tolerance of the lens calibration (per camera).
    pub lens_tolerances: LensTolerances,
}

impl Default for SensorSpec {
    fn default() -> Self {
        Self {
            imu: ImuParams::default(),
            encoders: EncoderParams::default(),
            encoder_hz: 200,
            sun: SunParams::default(),
            sun_hz: 200,
            camera_latency_polls: 3,
            dimension_error_m: 0.002,
            wheel_radius_error_m: 0.0005,
            camera_calibration_errors: true,
            camera_tolerances: CameraTolerances::default(),
            ideal_lens: false,
            lens_tolerances: LensTolerances::default(),
        }
    }
}

/// What the ground commands the rover to do with the waypoints.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NavigationKind {
    /// Follow the waypoints as a path (no hazard avoidance).
    #[default]
    Path,
    /// "Go to (x, y)": the last waypoint is the goal; the flight software maps hazards from
    /// the hazcams and plans round them with RoverBug (V99 sec. 4).
    Roverbug,
}

/// How the simulator's reference driver steers (until the flight software commands the motors).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriverMode {
    /// Carrot following on the TRUE position: perfect slip compensation.
    TruthCarrot,
    /// Heading hold along each segment on the true heading, segment length measured by wheel
    /// odometry: no slip compensation (the rover drifts downhill).
    OpenLoop,
}

/// A scenario.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct Scenario {
    /// Name (used in outputs).
    pub name: String,
    /// One-line description.
    #[serde(default)]
    pub description: String,
    /// Random seed (terrain, slip, sensor noise, dimension errors).
    #[serde(default)]
    pub seed: u64,
    /// Seed of the terrain (roughness, rock field) when it differs from [`Scenario::seed`]
    /// (campaigns that keep one terrain while the other draws vary). Default: `seed`.
    #[serde(default)]
    pub terrain_seed: Option<u64>,
    /// Seed of the per-unit calibration and manufacturing errors (vehicle dimensions, wheel
    /// radii, hazcam head, IMU scale factors and misalignments: `world::Streams` 5-8) when it
    /// differs from [`Scenario::seed`]: one rover unit over many drives. Default: `seed`.
    #[serde(default)]
    pub calibration_seed: Option<u64>,
    /// Offset of the true start pose from the planned one (the first waypoint, facing the
    /// second): the rover's localisation error before the drive. The flight software is given
    /// the planned pose ([`crate::closed_loop::Mission::plan`]); the truth starts offset. Default 0.
    #[serde(default)]
    pub start_offset: StartOffset,
    /// Longest simulated time, s.
    pub duration_s: f64,
    /// Driving speed, m/s.
    #[serde(default = "default_speed")]
    pub speed_m_s: f64,
    /// Distance from the last waypoint that counts as reaching the goal, m.
    #[serde(default = "default_goal")]
    pub goal_tolerance_m: f64,
    /// Slip limit of the drive (mission input of the flight's fault protection, MER style:
    /// the ground sets it per terrain), fraction; default 0.4 (MER).
    #[serde(default = "default_slip_limit")]
    pub slip_limit: f64,
    /// Largest horizontal position sigma the ground accepts before fault protection stops the
    /// drive (mission input), m; default 1.
    #[serde(default = "default_max_sigma")]
    pub max_position_sigma_m: f64,
    /// Waypoints `[north, east]`, m; the rover starts at the first, facing the second.
    pub waypoints: Vec<[f64; 2]>,
    /// What the ground commands: follow the waypoints as a path (`path`, the default), or go
    /// to the last waypoint avoiding the hazards the rover sees (`roverbug`, V99 sec. 4: the
    /// flight software's hazard map and RoverBug planner; the path of `path` is the special
    /// case of a world without obstacles).
    #[serde(default)]
    pub navigation: NavigationKind,
    /// Reference driver mode (default: carrot on truth, i.e. with slip compensation).
    #[serde(default = "default_driver")]
    pub driver: DriverMode,
    /// Slip model on/off.
    #[serde(default = "default_true")]
    pub slip: bool,
    /// Which slip model the truth uses (default: terramechanics).
    #[serde(default)]
    pub slip_model: SlipModelKind,
    /// Terrain.
    pub terrain: TerrainSpec,
    /// Soil.
    pub soil: SoilSpec,
    /// Site, season and time of day (the sun's motion).
    #[serde(default)]
    pub site: Site,
    /// Sensors.
    #[serde(default)]
    pub sensors: SensorSpec,
    /// Injected faults.
    #[serde(default)]
    pub faults: Vec<FaultSpec>,
    /// Height from which a rock or placed obstacle is a hazard to the truth vehicle, m
    /// (the simulator's own collision check, [`crate::hazards`]); default
    /// [`crate::hazards::DEFAULT_HAZARD_HEIGHT_M`].
    #[serde(default = "default_hazard_height")]
    pub hazard_height_m: f64,
    /// The day's science targets for the flight software's sequencer (V99 sec. 3),
    /// uplinked after the start. Needs `navigation = "roverbug"`.
    #[serde(default)]
    pub mission: Option<MissionSpec>,
}

/// The ground's targets and budget for a run.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MissionSpec {
    /// Energy the plan may use from the uplink on, J.
    pub energy_budget_j: f64,
    /// The plan must end by this time, s since the start (default: the scenario's duration).
    #[serde(default)]
    pub end_s: Option<f64>,
    /// The targets (at most `fsw::sequencer::MAX_TARGETS`), in `W`.
    pub targets: Vec<TargetSpec>,
}

/// One science target.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSpec {
    /// North, m (`W`).
    pub x_m: f64,
    /// East, m (`W`).
    pub y_m: f64,
    /// Priority (higher is dropped last).
    #[serde(default = "default_priority")]
    pub priority: u8,
    /// Science time at the target, s.
    #[serde(default = "default_dwell")]
    pub dwell_s: f64,
    /// The dwell may start from, s.
    #[serde(default)]
    pub window_open_s: f64,
    /// The dwell must start by, s (default: no limit).
    #[serde(default)]
    pub window_close_s: Option<f64>,
    /// Instrument energy above the idle power during the dwell, J (the simulator does not
    /// draw it: its energy model has no instruments).
    #[serde(default)]
    pub dwell_energy_j: f64,
}

fn default_priority() -> u8 {
    1
}
fn default_dwell() -> f64 {
    60.0
}

impl MissionSpec {
    /// The flight software's targets.
    pub fn targets(&self) -> Vec<fsw::sequencer::Target> {
        self.targets
            .iter()
            .map(|t| fsw::sequencer::Target {
                position_m: [t.x_m, t.y_m],
                priority: t.priority,
                window_open_s: t.window_open_s,
                window_close_s: t.window_close_s.unwrap_or(1.0e9),
                dwell_s: t.dwell_s,
                dwell_energy_j: t.dwell_energy_j,
            })
            .collect()
    }
}

fn default_hazard_height() -> f64 {
    crate::hazards::DEFAULT_HAZARD_HEIGHT_M
}

/// Offset of the true start pose from the planned one, in `W` (x north, y east, z down).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct StartOffset {
    /// North offset, m.
    pub north_m: f64,
    /// East offset, m.
    pub east_m: f64,
    /// Heading offset, degrees (clockwise from north, as the heading).
    pub yaw_deg: f64,
}

fn default_speed() -> f64 {
    0.1
}
fn default_goal() -> f64 {
    0.3
}
fn default_slip_limit() -> f64 {
    0.4
}
fn default_max_sigma() -> f64 {
    1.0
}
fn default_driver() -> DriverMode {
    DriverMode::TruthCarrot
}
fn default_true() -> bool {
    true
}

impl Scenario {
    /// Parse a scenario from TOML text, checking it.
    pub fn from_toml(text: &str) -> anyhow::Result<Self> {
        let s: Scenario = toml::from_str(text)?;
        s.check()?;
        Ok(s)
    }

    /// Load a scenario file.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
        Self::from_toml(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// Check the values (done by [`Scenario::from_toml`]; call it again after editing a
    /// scenario in code).
    pub fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(self.waypoints.len() >= 2, "need at least two waypoints");
        anyhow::ensure!(
            self.duration_s > 0.0 && self.duration_s.is_finite(),
            "duration_s must be positive"
        );
        anyhow::ensure!(
            self.speed_m_s > 0.0 && self.speed_m_s <= 0.3,
            "speed_m_s must be in (0, 0.3]"
        );
        let site = &self.site;
        anyhow::ensure!(
            (-90.0..=90.0).contains(&site.latitude_deg)
                && site.solar_longitude_deg.is_finite()
                && site.local_solar_time_h.is_finite(),
            "site: latitude_deg in [-90, 90], finite solar_longitude_deg and local_solar_time_h"
        );
        let o = &self.start_offset;
        anyhow::ensure!(
            o.north_m.is_finite() && o.east_m.is_finite() && o.yaw_deg.is_finite(),
            "start_offset must be finite"
        );
        for hz in [self.sensors.encoder_hz, self.sensors.sun_hz] {
            anyhow::ensure!(hz > 0 && 200 % hz == 0, "sensor rates must divide 200 Hz");
        }
        for (k, f) in self.faults.iter().enumerate() {
            f.check()
                .map_err(|e| anyhow::anyhow!("faults[{k}] ({:?} {:?}): {e}", f.device, f.kind))?;
        }
        if let Some(m) = &self.mission {
            anyhow::ensure!(
                self.navigation == NavigationKind::Roverbug,
                "mission targets need navigation = \"roverbug\""
            );
            anyhow::ensure!(
                !m.targets.is_empty() && m.targets.len() <= fsw::sequencer::MAX_TARGETS,
                "mission: 1 to {} targets",
                fsw::sequencer::MAX_TARGETS
            );
            anyhow::ensure!(
                m.energy_budget_j.is_finite() && m.energy_budget_j >= 0.0,
                "mission: energy_budget_j must be finite and non-negative"
            );
        }
        match self.slip_model {
            SlipModelKind::Lumped => self.soil.lumped().map(|_| ())?,
            SlipModelKind::Terramechanics => self.soil.bekker().map(|_| ())?,
        }
        Ok(())
    }

    /// Path length along the waypoints, m.
    pub fn path_length_m(&self) -> f64 {
        self.waypoints
            .windows(2)
            .map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt())
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SIM-10: every scenario file in `scenarios/` parses and passes its checks.
    #[test]
    fn sim_10_scenarios_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios");
        let mut names = Vec::new();
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let s = Scenario::load(&path).unwrap();
                names.push(s.name.clone());
            }
        }
        names.sort();
        for required in [
            "dunes-long",
            "marsyard-25m",
            "rough-kinematics",
            "slope-10-cross",
            "slope-20-cross",
            "step-climb",
            "rock-crawl",
            "rock-field-crawl",
            "fig17-crawl",
            "undulating",
            "flat-firm",
            "rockfield-goal",
            "cul-de-sac",
            "unreachable",
        ] {
            assert!(names.iter().any(|n| n == required), "missing {required}");
        }
        let bad = "name='x'\nduration_s=1\nwaypoints=[[0,0]]\nsoil='loose_sand'\n[terrain]\nbase={kind='flat'}";
        assert!(Scenario::from_toml(bad).is_err());
    }
}
