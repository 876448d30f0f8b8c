//! Calls forward (`fk`) or inverse (`ik`) kinematics N times, for instruction counting on the
//! host: `valgrind --tool=callgrind target/release/examples/kin_count fk 2000` minus the same
//! run with `none` gives instructions per call (see `docs/kinematics.md`).
// A host tool, not flight code: the flight crate's lints for panics and docs do not apply.
#![allow(missing_docs, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use fsw::kinematics::*;
use std::hint::black_box;
fn main() {
    let which = std::env::args().nth(1).unwrap_or_default();
    let n: usize = std::env::args()
        .nth(2)
        .map(|s| s.parse().unwrap())
        .unwrap_or(100000);
    let s = SuspensionState {
        rocker_rad: 0.1,
        bogie_rad: [-0.2, 0.15],
        steer_rad: [0.2, 0.25, 0.0, 0.05, -0.2, -0.15],
    };
    let rates = SuspensionRates {
        rocker_rad_s: 0.01,
        bogie_rad_s: [0.02, -0.01],
    };
    let drive = [1.0, 1.1, 0.9, 1.0, 0.95, 1.05];
    let cmd = VehicleCommand {
        x_dot_m_s: 0.08,
        y_dot_m_s: 0.02,
        yaw_rate_rad_s: 0.05,
    };
    let mut acc = 0.0;
    for _ in 0..n {
        match which.as_str() {
            "fk" => {
                acc += forward_kinematics(
                    &ROCKY8,
                    black_box(&s),
                    black_box(&rates),
                    black_box(&drive),
                    &[true; 6],
                )
                .map(|f| f.body_rates[0])
                .unwrap_or(0.0)
            }
            "ik" => {
                acc += inverse_kinematics(&ROCKY8, black_box(&s), black_box(&cmd))
                    .map(|f| f.command.wheel_rate_rad_s[0])
                    .unwrap_or(0.0)
            }
            _ => {}
        }
    }
    println!("{acc}");
}
