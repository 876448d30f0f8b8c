//! The flight software's configuration of a run, as the ground makes it from the scenario: the
//! nominal flight profile with the mission inputs ([`Mission::plan`]) and the drive options
//! ([`DriveOptions`]). Nothing comes from the simulator's truth, parameters or seed.

use crate::scenario::Scenario;
use fsw::flight::FswConfig;

/// What the ground chooses for a drive besides the scenario: slip compensation and VO.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriveOptions {
    /// Slip compensation on (H05) or off (wheel and IMU odometry only).
    pub slip_compensation: bool,
    /// Visual odometry on; off: the EKF gets IMU, sun and kinematics only.
    pub vo_enabled: bool,
}

impl Default for DriveOptions {
    fn default() -> Self {
        Self {
            slip_compensation: true,
            vo_enabled: true,
        }
    }
}

/// The mission inputs of a drive as the ground plans it from the scenario, never from the
/// simulator's truth or seed: the start pose of the plan (first waypoint, heading towards the
/// second, height from the smooth terrain model plus the nominal height of the rover
/// reference point), the site and time for the sun ephemeris, the cruise speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mission {
    /// Planned start position, m, `N` (north, east, down).
    pub start_n_m: [f64; 3],
    /// Planned start heading, rad.
    pub start_yaw_rad: f64,
    /// Sun ephemeris of the site and time.
    pub sun: fsw::estimation::ephemeris::SunEphemeris,
    /// Cruise speed, m/s.
    pub cruise_speed_m_s: f64,
    /// Distance from the goal that counts as arriving, m (the arrival must be supported by the
    /// estimate to this tolerance, `ProtectionConfig::arrival_tolerance_m`).
    pub goal_tolerance_m: f64,
    /// Slip limit of the drive (fault protection), fraction.
    pub slip_limit: f64,
    /// Largest horizontal position sigma the ground accepts for the drive (fault protection), m.
    pub max_position_sigma_m: f64,
    /// "Go to the last waypoint, avoiding hazards" (RoverBug, V99 sec. 4) instead of "follow
    /// the waypoints".
    pub goal_directed: bool,
}

impl Mission {
    /// The plan of `scenario`.
    pub fn plan(scenario: &Scenario) -> Self {
        let [start, next] = [scenario.waypoints[0], scenario.waypoints[1]];
        // The ground's terrain model: the base shape without roughness, rocks or obstacles.
        let mut smooth = scenario.terrain.clone();
        smooth.roughness_m = 0.0;
        smooth.rocks = None;
        smooth.obstacles.clear();
        let ground = crate::surface::TerrainSurface::height_m(
            &crate::terrain::Terrain::new(smooth, 0, &scenario.waypoints),
            start[0],
            start[1],
        );
        // Nominal height of the reference point above the wheel contacts (flight geometry).
        let reference_height = fsw::kinematics::wheel_contact_points(
            &fsw::kinematics::ROCKY8,
            &fsw::kinematics::SuspensionState::default(),
        )
        .map(|c| c.iter().map(|p| p.z).sum::<f64>() / c.len() as f64)
        .unwrap_or(0.0);
        let site = &scenario.site;
        Self {
            start_n_m: [start[0], start[1], -(ground + reference_height)],
            start_yaw_rad: (next[1] - start[1]).atan2(next[0] - start[0]),
            sun: fsw::estimation::ephemeris::SunEphemeris::from_site(
                site.latitude_deg,
                site.solar_longitude_deg,
                site.local_solar_time_h,
            ),
            cruise_speed_m_s: scenario.speed_m_s,
            goal_tolerance_m: scenario.goal_tolerance_m,
            slip_limit: scenario.slip_limit,
            max_position_sigma_m: scenario.max_position_sigma_m,
            goal_directed: scenario.navigation == crate::scenario::NavigationKind::Roverbug,
        }
    }
}

/// The flight software's configuration for `scenario`: the nominal flight profile
/// ([`FswConfig::rocky8`]: datasheet-class IMU densities, nominal geometry and calibration,
/// calibrated odometry noise) with the mission inputs of [`Mission::plan`] and the drive
/// options. Nothing comes from the simulator's truth, parameters or seed
/// (`sim-host/tests/flight_profile.rs` checks it for every scenario and several seeds).
pub fn flight_config(scenario: &Scenario, options: DriveOptions) -> FswConfig {
    let mission = Mission::plan(scenario);
    let mut config = FswConfig::rocky8(mission.start_n_m, mission.start_yaw_rad);
    let nav = &mut config.nav;
    nav.filter.ekf.sun = Some(mission.sun);
    nav.drive.guidance.cruise_speed_m_s = mission
        .cruise_speed_m_s
        .min(nav.drive.guidance.max_wheel_speed_m_s);
    nav.drive.slip_compensation = options.slip_compensation;
    nav.vo.enabled = options.vo_enabled;
    nav.drive.protection.arrival_tolerance_m = mission.goal_tolerance_m;
    nav.drive.protection.slip_limit = mission.slip_limit;
    nav.drive.protection.max_position_sigma_m = mission.max_position_sigma_m;
    nav.goal.hazard_avoidance = mission.goal_directed;
    config
}
