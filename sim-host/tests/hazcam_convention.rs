//! SIM-18: the simulator's nominal hazcam head (`sim_host::sensors::hazcam`, written from
//! the published figures) is the calibration the flight software is built around. This test is
//! the only place where simulator code reads the flight camera model; the simulation never does.

use sim_host::devices::hazcam_calibration;
use sim_host::sensors::hazcam::nominal_hazcam;

/// SIM-18: every field of the simulator's nominal head equals `fsw::vo::rocky8_hazcam()` to
/// 1e-9, and the HAL devices' nominal calibration is the simulator's own.
#[test]
fn sim_18_nominal_head_agrees_with_flight_model() {
    let ours = nominal_hazcam();
    let flight = fsw::vo::rocky8_hazcam();
    let close = |a: f64, b: f64, what: &str| {
        assert!((a - b).abs() < 1e-9, "{what}: simulator {a} flight {b}");
    };
    close(ours.fx_px, flight.fx_px, "fx");
    close(ours.fy_px, flight.fy_px, "fy");
    close(ours.cx_px, flight.cx_px, "cx");
    close(ours.cy_px, flight.cy_px, "cy");
    close(ours.baseline_m, flight.baseline_m, "baseline");
    for i in 0..3 {
        close(
            ours.pos_camera_in_rover_m[i],
            flight.pos_camera_in_rover_m[i],
            "position",
        );
        for j in 0..3 {
            close(
                ours.rot_rover_from_camera[i][j],
                flight.rot_rover_from_camera[i][j],
                "rotation",
            );
        }
    }
    assert_eq!(hazcam_calibration(), ours);
}
