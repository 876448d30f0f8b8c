//! The flight configuration of every scenario is the nominal flight
//! profile plus the mission plan, and nothing else: no simulator parameter (IMU noise, sun
//! sensor noise, dimension or calibration errors), no truth (start pose, terrain roughness)
//! and no seed leaks into it.

use fsw::estimation::ephemeris::SunEphemeris;
use fsw::estimation::EkfConfig;
use fsw::flight::FswConfig;
use sim_host::closed_loop::{flight_config, DriveOptions};
use sim_host::scenario::Scenario;
use sim_host::world::World;

fn scenarios() -> Vec<Scenario> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios");
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .expect("scenarios directory")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    paths.sort();
    paths
        .iter()
        .map(|p| Scenario::load(p).expect("scenario parses"))
        .collect()
}

#[test]
fn flight_configuration_is_the_nominal_profile_plus_the_plan() {
    let all = scenarios();
    assert!(all.len() >= 10, "found {} scenarios", all.len());
    for scenario in &all {
        let options = DriveOptions::default();
        let config = flight_config(scenario, options);
        // The plan, computed here from the scenario's waypoints and site only.
        let [a, b] = [scenario.waypoints[0], scenario.waypoints[1]];
        let yaw = (b[1] - a[1]).atan2(b[0] - a[0]);
        let start = config.nav.align.initial_position_n_m;
        assert_eq!([start[0], start[1]], a, "{}: planned start", scenario.name);
        let mut expected = FswConfig::rocky8(start, yaw);
        let site = &scenario.site;
        expected.nav.filter.ekf.sun = Some(SunEphemeris::from_site(
            site.latitude_deg,
            site.solar_longitude_deg,
            site.local_solar_time_h,
        ));
        expected.nav.drive.protection.arrival_tolerance_m = scenario.goal_tolerance_m;
        expected.nav.drive.protection.slip_limit = scenario.slip_limit;
        expected.nav.drive.protection.max_position_sigma_m = scenario.max_position_sigma_m;
        expected.nav.goal.hazard_avoidance =
            scenario.navigation == sim_host::scenario::NavigationKind::Roverbug;
        expected.nav.drive.guidance.cruise_speed_m_s = scenario
            .speed_m_s
            .min(expected.nav.drive.guidance.max_wheel_speed_m_s);
        assert_eq!(config, expected, "{}", scenario.name);
        // The filter's IMU model is the nominal profile's, whatever the simulator's IMU is.
        assert_eq!(
            config.nav.filter.ekf.imu_noise,
            EkfConfig::default().imu_noise
        );
        for seed in [1, 2, 3, 7, 1234] {
            let mut seeded = scenario.clone();
            seeded.seed = seed;
            assert_eq!(
                flight_config(&seeded, options),
                config,
                "{} seed {seed}",
                scenario.name
            );
            // The truth start differs from the plan (terrain roughness, suspension settling),
            // so a leak of the truth pose would show here.
            let world = World::new(&seeded, seed).expect("world");
            let truth = world.truth.pose.pos_m;
            assert!(
                (truth[2] - start[2]).abs() > 0.0 || truth[0] != start[0] || truth[1] != start[1],
                "{}: plan equals truth exactly",
                scenario.name
            );
        }
    }
}
