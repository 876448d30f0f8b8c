//! Diagnostic: the flight contact-angle odometry (`fsw::kinematics::contact`, V99 sec. 6) fed
//! with the simulator's joint readings and the true body rotation of each 50 ms step, printed
//! against the truth's contact angles, with the 3D path length of the estimate, of eq. 15
//! (contacts under the axles) and of the truth. The rover drives straight at 1 rad/s, without
//! the flight software.
//!
//! ```sh
//! cargo run --release -p sim-host --example contact_diag -- scenarios/undulating.toml [nogyro]
//! ```
use fsw::kinematics::{KinematicOdometry, OdometryConfig, ROCKY8};
use nalgebra::Vector3;
use rover_hal::MobilityCommand;
use sim_host::scenario::Scenario;
use sim_host::world::World;

fn main() -> anyhow::Result<()> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or("/tmp/und-perfect.toml".into());
    let gyro_on = std::env::args().nth(2).is_none_or(|s| s != "nogyro");
    let sc = Scenario::load(std::path::Path::new(&path))?;
    let mut w = World::new(&sc, 1)?;
    w.command = MobilityCommand {
        steer_angle_rad: [0.0; 6],
        wheel_rate_rad_s: [1.0; 6],
    };
    for _ in 0..400 {
        w.step();
    }
    let cfg = OdometryConfig {
        contact_angles: true,
        ..OdometryConfig::default()
    };
    let mut odo = KinematicOdometry::new(ROCKY8, cfg);
    let mut plain = KinematicOdometry::new(ROCKY8, OdometryConfig::default());
    odo.start(&w.joints).unwrap();
    plain.start(&w.joints).unwrap();
    let p0 = w.truth.pose;
    let mut rot_prev = w.truth.pose.rot_w_from_r();
    let mut est_len = 0.0;
    let mut plain_len = 0.0;
    let mut true_len = 0.0;
    let mut prev_pos = Vector3::from(p0.pos_m);
    for k in 0..2000 {
        for _ in 0..10 {
            w.step();
        }
        let rot = w.truth.pose.rot_w_from_r();
        let g = (rot_prev.inverse() * rot).scaled_axis();
        rot_prev = rot;
        let gyro = gyro_on.then(|| fsw::types::Vec3::new(g.x, g.y, g.z));
        odo.update_with_gyro(&w.joints, gyro).unwrap();
        plain.update(&w.joints).unwrap();
        let rp = odo.take().unwrap();
        let rq = plain.take().unwrap();
        let pos = Vector3::from(w.truth.pose.pos_m);
        let d = pos - prev_pos;
        prev_pos = pos;
        let dt = (rot.inverse() * d).norm(); // not exact frame but length
        let le = rp.trans_0_1_m.norm();
        let lp = rq.trans_0_1_m.norm();
        est_len += le;
        plain_len += lp;
        true_len += dt;
        if k % 100 == 0 {
            let ta = w
                .truth
                .contact_angle_rad
                .map(|a| (a.to_degrees() * 10.0).round() / 10.0);
            let ea = odo
                .contact_angles_rad()
                .map(|a| (a.to_degrees() * 10.0).round() / 10.0);
            println!("k {k} x {:.2} pitch {:.1} truth {:?} est {:?} step true {:.5} est {:.5} plain {:.5}", w.truth.pose.pos_m[0], w.truth.pose.pitch_rad.to_degrees(), ta, ea, dt, le, lp);
        }
        if w.truth.pose.pos_m[0] > 11.0 {
            break;
        }
    }
    println!(
        "3D length true {true_len:.4} est {est_len:.4} ({:.2} %) plain {plain_len:.4} ({:.2} %)",
        100.0 * (est_len - true_len) / true_len,
        100.0 * (plain_len - true_len) / true_len
    );
    Ok(())
}
