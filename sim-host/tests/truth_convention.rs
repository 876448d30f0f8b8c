//! SIM-2: the simulator's truth geometry (`sim_host::vehicle::geometry`, written independently
//! of the flight kinematics) means the same by each joint angle as the flight D-H model. This is
//! the only place where simulator code reads the flight geometry: a test, never the simulation.

use fsw::kinematics::geometry::wheel_frames;
use fsw::kinematics::{SuspensionState, ROCKY8};
use nalgebra::Vector3;
use sim_host::vehicle::geometry::{rocky8, VehicleGeometry, WHEELS};

/// SIM-2: the truth geometry reports joint angles in the flight software's convention:
/// at the same rocker, bogie and steering angles the axle centres and rolling directions of
/// the independent side-view model equal those of the flight D-H model (H04 eq. 12) to the
/// 4-digit rounding of Table 2. Only this test reads the flight geometry.
#[test]
fn sim_2_truth_geometry_matches_flight_convention() {
    let g = rocky8();
    for (beta, rho, steer) in [
        (0.0, [0.0, 0.0], 0.0),
        (0.2, [0.0, 0.0], 0.3),
        (-0.15, [0.3, -0.4], -0.5),
        (0.4, [-0.6, 0.5], 1.0),
    ] {
        let state = SuspensionState {
            rocker_rad: beta,
            bogie_rad: rho,
            steer_rad: [steer; 6],
        };
        let frames = wheel_frames(&ROCKY8, &state).unwrap();
        let ours = g.wheels(beta, rho, &[steer; 6]).unwrap();
        for i in 0..WHEELS {
            let f = &frames[i].contact;
            let axle = Vector3::new(f.pos.x, f.pos.y, f.pos.z);
            let x = f.x_axis();
            let roll = Vector3::new(x.x, x.y, x.z);
            assert!(
                (axle - ours[i].axle_m).norm() < 5e-4,
                "wheel {} at {beta} {rho:?}: {axle:?} vs {:?}",
                i + 1,
                ours[i].axle_m
            );
            assert!(
                (roll - ours[i].rolling_dir).norm() < 2e-3,
                "wheel {}",
                i + 1
            );
        }
    }
}
