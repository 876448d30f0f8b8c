//! Rocky 8 geometry as the simulator needs it, taken from the flight code's kinematic data
//! ([`fsw::kinematics::ROCKY8`], H04 Appendix A Table 2): one source of truth.
//!
//! The simulator talks to the geometry only through [`VehicleGeometry`]; it is implemented for
//! the flight code's [`RoverGeometry`]. The simulator's truth vehicle is that geometry with
//! per-seed dimension errors of a few millimetres ([`perturbed`]), so the flight model is not
//! perfect.
//!
//! Sign conventions follow `fsw::kinematics`: a positive steering angle turns the wheel to the
//! right (about `+z_R`); a positive wheel rate rolls the wheel along its rolling direction.

use fsw::kinematics::geometry::{wheel_frames, DhRow};
use fsw::kinematics::{RoverGeometry, SuspensionState, ROCKY8};
use nalgebra::Vector3;

/// Wheel count.
pub const WHEELS: usize = 6;

/// One wheel at the current joint angles, in the rover frame `R`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelPose {
    /// Axle centre (wheel centre), m.
    pub axle_m: Vector3<f64>,
    /// Unit spin axis (normal of the wheel plane).
    pub spin_axis: Vector3<f64>,
    /// Unit rolling direction (a positive wheel rate moves the contact point backwards, so the
    /// rover along this direction).
    pub rolling_dir: Vector3<f64>,
}

/// What the simulator needs from a vehicle geometry.
pub trait VehicleGeometry {
    /// Wheel radius, m.
    fn wheel_radius_m(&self) -> f64;
    /// The six wheels in `R` for rocker `beta`, bogies `[rho1, rho2]` and steering angles, rad.
    /// `None` if the angles are outside the geometry's limits.
    fn wheels(
        &self,
        rocker_rad: f64,
        bogie_rad: [f64; 2],
        steer_rad: &[f64; WHEELS],
    ) -> Option<[WheelPose; WHEELS]>;
}

impl VehicleGeometry for RoverGeometry {
    fn wheel_radius_m(&self) -> f64 {
        self.wheel_radius_m
    }

    /// Eq. 12 (H04) through [`wheel_frames`]: the axle centre is the origin of `C_i` (Table 2
    /// rows `C_i` have `d = a = 0`); the wheel plane holds `x_Ci` (rolling) and `z_Ci`.
    fn wheels(
        &self,
        rocker_rad: f64,
        bogie_rad: [f64; 2],
        steer_rad: &[f64; WHEELS],
    ) -> Option<[WheelPose; WHEELS]> {
        let state = SuspensionState {
            rocker_rad,
            bogie_rad,
            steer_rad: *steer_rad,
        };
        let frames = wheel_frames(self, &state).ok()?;
        Some(frames.map(|f| {
            let x = f.contact.x_axis();
            let z = f.contact.z_axis();
            WheelPose {
                axle_m: f.contact.pos,
                spin_axis: z.cross(&x).normalize(),
                rolling_dir: x,
            }
        }))
    }
}

/// The flight code's Rocky 8 geometry.
pub fn rocky8() -> RoverGeometry {
    ROCKY8
}

/// `geometry` with every non-zero D-H length (`d`, `a`) and the wheel radius shifted by
/// `delta(k)` metres (`k` counts the lengths): the per-seed dimension errors of the truth
/// vehicle.
pub fn perturbed(geometry: &RoverGeometry, mut delta: impl FnMut(usize) -> f64) -> RoverGeometry {
    let mut g = *geometry;
    let mut k = 0;
    let mut bump = |row: &mut DhRow| {
        for v in [&mut row.d_m, &mut row.a_m] {
            if *v != 0.0 {
                *v += delta(k);
                k += 1;
            }
        }
    };
    bump(&mut g.rocker);
    for b in &mut g.bogies {
        bump(b);
    }
    for w in &mut g.wheels {
        bump(&mut w.steer);
        bump(&mut w.axle);
    }
    g.wheel_radius_m += delta(k);
    g
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SIM-2: the flight geometry puts all six axles at `z = 0` with zero joint angles, right
    /// wheels at `+y`, front wheels ahead, rolling directions forward; a positive rocker angle
    /// lifts the right front wheel; a positive steering angle turns the wheel right; the
    /// per-seed dimension errors change the lengths by the drawn amounts.
    #[test]
    fn sim_2_flight_geometry_layout() {
        let g = rocky8();
        let w = g.wheels(0.0, [0.0, 0.0], &[0.0; 6]).unwrap();
        for (i, p) in w.iter().enumerate() {
            assert!(p.axle_m.z.abs() < 1e-3, "wheel {} z {}", i + 1, p.axle_m.z);
            assert!((p.axle_m.y.abs() - 0.3111).abs() < 1e-9);
            assert_eq!(
                p.axle_m.y > 0.0,
                i % 2 == 0,
                "right wheels are odd-numbered"
            );
            assert!((p.rolling_dir - Vector3::x()).norm() < 1e-3);
            assert!(p.spin_axis.y.abs() > 0.999);
        }
        assert!(w[0].axle_m.x > w[2].axle_m.x && w[2].axle_m.x > w[4].axle_m.x);
        let lifted = g.wheels(0.1, [0.0, 0.0], &[0.0; 6]).unwrap();
        assert!(
            lifted[0].axle_m.z < w[0].axle_m.z,
            "beta > 0 lifts the right front"
        );
        assert!(
            lifted[1].axle_m.z > w[1].axle_m.z,
            "and lowers the left front"
        );
        let steered = g.wheels(0.0, [0.0, 0.0], &[0.3; 6]).unwrap();
        assert!(
            steered[0].rolling_dir.y > 0.29,
            "positive steering turns right"
        );
        let p = perturbed(&g, |_| 0.002);
        let wp = p.wheels(0.0, [0.0, 0.0], &[0.0; 6]).unwrap();
        assert!((p.wheel_radius_m - g.wheel_radius_m - 0.002).abs() < 1e-12);
        assert!((wp[0].axle_m - w[0].axle_m).norm() > 1e-3);
        assert!(g.wheels(5.0, [0.0, 0.0], &[0.0; 6]).is_none());
    }
}
