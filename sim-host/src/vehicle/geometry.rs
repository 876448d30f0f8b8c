//! The truth vehicle's geometry: a Rocky 8 class rocker-bogie written as a side-view linkage,
//! independently of the flight code's D-H model (`fsw::kinematics`, H04 Table 2).
//!
//! Only published dimensions are shared with the flight side (H04 Appendix A Table 2 evaluated
//! at zero joint angles; see `docs/kinematics.md`): wheel radius 0.10 m, track 0.6222 m, axles
//! at `x` = 0.3930 (front), 0.0005 (middle), -0.3541 (rear) m at axle height `z = 0`, the
//! rocker pivot at (-0.1420, -0.2022) m and the bogie pivot at (0.1291, -0.1273) m in the
//! side plane `(x, z)` of each side. The simulator never reads the flight geometry.
//!
//! Model: each side is a planar linkage in the plane `y = +-track/2` of `R` (x forward, y
//! right, z down). The rocker of the right side turns about the lateral axis `+y_R` through its
//! pivot by `+beta`, the left by `-beta` (the differential). A bogie turns about the lateral
//! axis through its pivot by its own angle `rho` relative to its rocker. The rear wheels hang on
//! the rockers, the front and middle wheels on the bogies. Steering axes are the links' `z`
//! axes through the axle centres (so the axle centre does not move with steering); a positive
//! steering angle turns the wheel to the right (about `+z_R`). A positive rotation about `+y_R`
//! lifts the points ahead of the pivot (`z` down). The angle conventions are those the joint
//! encoders report; the test `sim_2_truth_geometry_matches_flight_convention`
//! (`sim-host/tests/truth_convention.rs`) checks them against the flight model (a test may read
//! it; the simulation never does).

use nalgebra::{Matrix3, Rotation3, Vector3};

/// Wheel count.
pub const WHEELS: usize = 6;

/// One wheel at the current joint angles, in the rover frame `R`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelPose {
    /// Axle centre (wheel centre), m.
    pub axle_m: Vector3<f64>,
    /// Unit spin axis (normal of the wheel plane), pointing to the rover's right when the wheel
    /// is not steered.
    pub spin_axis: Vector3<f64>,
    /// Unit rolling direction (a positive wheel rate moves the rover along it on level ground).
    pub rolling_dir: Vector3<f64>,
}

/// What the simulator needs from a vehicle geometry.
pub trait VehicleGeometry {
    /// Radius of wheel `i` (0..6, the order of [`VehicleGeometry::wheels`]), m.
    fn wheel_radius_m(&self, i: usize) -> f64;
    /// The six wheels in `R` for rocker `beta`, bogies `[rho1, rho2]` and steering angles, rad.
    /// `None` if an angle is not finite.
    fn wheels(
        &self,
        rocker_rad: f64,
        bogie_rad: [f64; 2],
        steer_rad: &[f64; WHEELS],
    ) -> Option<[WheelPose; WHEELS]>;
}

/// Side of wheel `i` (0 right for wheels 1, 3, 5; 1 left for 2, 4, 6).
pub fn side(i: usize) -> usize {
    i % 2
}

/// Whether wheel `i` hangs on a bogie (front and middle wheels).
pub fn on_bogie(i: usize) -> bool {
    i < 4
}

/// Rocky 8 as the simulator's truth vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthGeometry {
    /// Radius of each wheel (1..6 as `axle_m`), m: the published 0.10 m for all six at the
    /// published dimensions; the per-seed errors make them differ (manufacturing, wear).
    pub wheel_radius_m: [f64; WHEELS],
    /// Rocker pivots `[right, left]` in `R` at zero joint angles, m.
    pub rocker_pivot_m: [Vector3<f64>; 2],
    /// Bogie pivots `[right, left]` in `R` at zero joint angles, m.
    pub bogie_pivot_m: [Vector3<f64>; 2],
    /// Axle centres of wheels 1..6 in `R` at zero joint angles, m.
    pub axle_m: [Vector3<f64>; WHEELS],
}

/// Rotation about the lateral axis `+y_R` by `a` (positive lifts points ahead of the axis).
fn rot_y(a: f64) -> Matrix3<f64> {
    *Rotation3::from_axis_angle(&Vector3::y_axis(), a).matrix()
}

/// Cross product with `+y_R`: the velocity of a point at `d` from a lateral axis turning at a
/// unit rate.
fn y_cross(d: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(d.z, 0.0, -d.x)
}

impl TruthGeometry {
    /// Rocky 8 at its published dimensions (H04 Appendix A Table 2 at zero joint angles).
    pub fn rocky8() -> Self {
        let half_track = 0.3111;
        let both = |x: f64, z: f64| {
            [
                Vector3::new(x, half_track, z),
                Vector3::new(x, -half_track, z),
            ]
        };
        let axle = |x: f64, i: usize| {
            let y = if side(i) == 0 {
                half_track
            } else {
                -half_track
            };
            Vector3::new(x, y, 0.0)
        };
        Self {
            wheel_radius_m: [0.10; WHEELS],
            rocker_pivot_m: both(-0.1420, -0.2022),
            bogie_pivot_m: both(0.1291, -0.1273),
            axle_m: [
                axle(0.3930, 0),
                axle(0.3930, 1),
                axle(0.0005, 2),
                axle(0.0005, 3),
                axle(-0.3541, 4),
                axle(-0.3541, 5),
            ],
        }
    }

    /// This geometry with every published length shifted by `delta(k)` metres (`k` counts the
    /// lengths: pivot and axle coordinates in `x` and `z`, the half track of each axle, the
    /// wheel radius, one `delta` common to all six wheels): the per-seed manufacturing errors of
    /// the truth vehicle. The wheels' individual radius errors are
    /// [`TruthGeometry::with_wheel_radius_errors`].
    pub fn perturbed(&self, mut delta: impl FnMut(usize) -> f64) -> Self {
        let mut g = *self;
        let mut k = 0;
        let mut bump = |v: &mut Vector3<f64>, lateral: bool| {
            v.x += delta(k);
            v.z += delta(k + 1);
            k += 2;
            if lateral {
                v.y += delta(k).copysign(v.y);
                k += 1;
            }
        };
        for p in g
            .rocker_pivot_m
            .iter_mut()
            .chain(g.bogie_pivot_m.iter_mut())
        {
            bump(p, false);
        }
        for a in g.axle_m.iter_mut() {
            bump(a, true);
        }
        let common = delta(k);
        for r in g.wheel_radius_m.iter_mut() {
            *r += common;
        }
        g
    }

    /// This geometry with the radius of wheel `i` shifted by `delta(i)` metres (`i` = 0..6 in
    /// wheel order): the wheels' individual radius errors (manufacturing, wear), on top of the
    /// common one of [`TruthGeometry::perturbed`].
    pub fn with_wheel_radius_errors(&self, mut delta: impl FnMut(usize) -> f64) -> Self {
        let mut g = *self;
        for (i, r) in g.wheel_radius_m.iter_mut().enumerate() {
            *r += delta(i);
        }
        g
    }

    /// Mean of the six wheel radii, m.
    pub fn mean_wheel_radius_m(&self) -> f64 {
        self.wheel_radius_m.iter().sum::<f64>() / WHEELS as f64
    }

    /// Side-plane rotation of the rocker of side `s` (`+beta` right, `-beta` left).
    fn rocker_rot(s: usize, rocker_rad: f64) -> Matrix3<f64> {
        rot_y(if s == 0 { rocker_rad } else { -rocker_rad })
    }

    /// Current bogie pivot of side `s` in `R`, m.
    pub fn bogie_pivot(&self, s: usize, rocker_rad: f64) -> Vector3<f64> {
        let r = Self::rocker_rot(s, rocker_rad);
        self.rocker_pivot_m[s] + r * (self.bogie_pivot_m[s] - self.rocker_pivot_m[s])
    }

    /// Current rocker pivot of side `s` in `R`, m (fixed to the body).
    pub fn rocker_pivot(&self, s: usize) -> Vector3<f64> {
        self.rocker_pivot_m[s]
    }

    /// Rotation of the link that carries wheel `i` (rocker for rear wheels, bogie otherwise).
    fn link_rot(i: usize, rocker_rad: f64, bogie_rad: [f64; 2]) -> Matrix3<f64> {
        let s = side(i);
        let beta = if s == 0 { rocker_rad } else { -rocker_rad };
        if on_bogie(i) {
            rot_y(beta + bogie_rad[s])
        } else {
            rot_y(beta)
        }
    }

    /// Axle centre of wheel `i` in `R`, m.
    pub fn axle(&self, i: usize, rocker_rad: f64, bogie_rad: [f64; 2]) -> Vector3<f64> {
        let s = side(i);
        let rocker = Self::rocker_rot(s, rocker_rad);
        let p0 = self.rocker_pivot_m[s];
        if on_bogie(i) {
            let b0 = self.bogie_pivot_m[s];
            let link = Self::link_rot(i, rocker_rad, bogie_rad);
            p0 + rocker * (b0 - p0) + link * (self.axle_m[i] - b0)
        } else {
            p0 + rocker * (self.axle_m[i] - p0)
        }
    }

    /// Derivatives of the axle centre of wheel `i` in `R` with respect to `[beta, rho1, rho2]`
    /// (columns), m/rad: rotation about the lateral axes through the rocker and bogie pivots.
    pub fn axle_jacobian(&self, i: usize, rocker_rad: f64, bogie_rad: [f64; 2]) -> Matrix3<f64> {
        let s = side(i);
        let a = self.axle(i, rocker_rad, bogie_rad);
        let sign = if s == 0 { 1.0 } else { -1.0 };
        let d_beta = y_cross(&(a - self.rocker_pivot_m[s])) * sign;
        let mut j = Matrix3::zeros();
        j.set_column(0, &d_beta);
        if on_bogie(i) {
            let d_rho = y_cross(&(a - self.bogie_pivot(s, rocker_rad)));
            j.set_column(1 + s, &d_rho);
        }
        j
    }
}

impl VehicleGeometry for TruthGeometry {
    fn wheel_radius_m(&self, i: usize) -> f64 {
        self.wheel_radius_m[i]
    }

    fn wheels(
        &self,
        rocker_rad: f64,
        bogie_rad: [f64; 2],
        steer_rad: &[f64; WHEELS],
    ) -> Option<[WheelPose; WHEELS]> {
        let finite = rocker_rad.is_finite()
            && bogie_rad.iter().all(|b| b.is_finite())
            && steer_rad.iter().all(|s| s.is_finite());
        if !finite {
            return None;
        }
        Some(std::array::from_fn(|i| {
            let link = Self::link_rot(i, rocker_rad, bogie_rad);
            let (sin, cos) = steer_rad[i].sin_cos();
            WheelPose {
                axle_m: self.axle(i, rocker_rad, bogie_rad),
                rolling_dir: link * Vector3::new(cos, sin, 0.0),
                spin_axis: link * Vector3::new(-sin, cos, 0.0),
            }
        }))
    }
}

/// Rocky 8 as the truth vehicle at its published dimensions.
pub fn rocky8() -> TruthGeometry {
    TruthGeometry::rocky8()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SIM-2: zero joint angles put all six axles at `z = 0`, right wheels at `+y`, front
    /// wheels ahead, rolling directions forward; a positive rocker angle lifts the right front
    /// wheel and lowers the left front; a positive steering angle turns the wheel right; the
    /// per-seed dimension errors change the lengths by the drawn amounts (the common radius
    /// error all six radii, a per-wheel error its own wheel's only); the analytic suspension
    /// Jacobian equals finite differences.
    #[test]
    fn sim_2_truth_geometry_layout() {
        let g = rocky8();
        let w = g.wheels(0.0, [0.0, 0.0], &[0.0; 6]).unwrap();
        for (i, p) in w.iter().enumerate() {
            assert!(p.axle_m.z.abs() < 1e-12, "wheel {} z {}", i + 1, p.axle_m.z);
            assert!((p.axle_m.y.abs() - 0.3111).abs() < 1e-9);
            assert_eq!(
                p.axle_m.y > 0.0,
                i % 2 == 0,
                "right wheels are odd-numbered"
            );
            assert!((p.rolling_dir - Vector3::x()).norm() < 1e-12);
            assert!((p.spin_axis - Vector3::y()).norm() < 1e-12);
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
        let p = g.perturbed(|_| 0.002);
        for i in 0..WHEELS {
            assert!((p.wheel_radius_m[i] - g.wheel_radius_m[i] - 0.002).abs() < 1e-12);
        }
        let q = g.with_wheel_radius_errors(|i| 1e-4 * i as f64);
        for i in 0..WHEELS {
            assert!((q.wheel_radius_m(i) - 0.10 - 1e-4 * i as f64).abs() < 1e-15);
        }
        assert_eq!(q.axle_m, g.axle_m);
        assert!((q.mean_wheel_radius_m() - 0.10025).abs() < 1e-12);
        let wp = p.wheels(0.0, [0.0, 0.0], &[0.0; 6]).unwrap();
        assert!((wp[0].axle_m - w[0].axle_m).norm() > 1e-3);
        assert!(g.wheels(f64::NAN, [0.0, 0.0], &[0.0; 6]).is_none());
        let (beta, rho) = (0.13, [-0.21, 0.17]);
        for i in 0..WHEELS {
            let j = g.axle_jacobian(i, beta, rho);
            let h = 1e-7;
            let base = g.axle(i, beta, rho);
            let fd = [
                (g.axle(i, beta + h, rho) - base) / h,
                (g.axle(i, beta, [rho[0] + h, rho[1]]) - base) / h,
                (g.axle(i, beta, [rho[0], rho[1] + h]) - base) / h,
            ];
            for (k, col) in fd.iter().enumerate() {
                assert!((j.column(k) - col).norm() < 1e-6, "wheel {i} column {k}");
            }
        }
    }
}
