//! Rocky 8 geometry as the simulator needs it: axle centres of the six wheels in the rover
//! frame `R` as functions of the rocker and bogie angles.
//!
//! The simulator talks to the geometry only through [`VehicleGeometry`], so the source of the
//! numbers can be switched in one place. [`DhGeometry`] is the simulator's reading of H04
//! Appendix A, Table 2 (standard Denavit-Hartenberg: `T = Rz(gamma) Tz(d) Tx(a) Rx(alpha)`).
//!
//! Link pitch (H04 Table 2): the right rocker turns by `+beta`, the left by `-beta` (the
//! differential); the right bogie wheels by `beta + rho1`, the left by `-beta + rho2`. A
//! positive link angle lifts the front of the link (rotation about `+y_R`).

use nalgebra::{Matrix4, Vector3};

/// Wheel count.
pub const WHEELS: usize = 6;

/// What the simulator needs from a vehicle geometry.
pub trait VehicleGeometry {
    /// Wheel radius, m.
    fn wheel_radius_m(&self) -> f64;
    /// Axle centres (wheel centres) in `R`, m, for rocker `beta` and bogies `[rho1, rho2]`, rad.
    fn axle_centres(&self, rocker_rad: f64, bogie_rad: [f64; 2]) -> [[f64; 3]; WHEELS];
}

/// Pitch of the link carrying each wheel, about `+y_R` (positive lifts the front), rad.
pub fn link_pitch(rocker_rad: f64, bogie_rad: [f64; 2]) -> [f64; WHEELS] {
    let (b, r1, r2) = (rocker_rad, bogie_rad[0], bogie_rad[1]);
    [b + r1, -b + r2, b + r1, -b + r2, b, -b]
}

/// One D-H row: `gamma` offset (added to the joint variable), `d`, `a`, `alpha`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DhRow {
    /// Constant part of the joint angle, rad.
    pub gamma_rad: f64,
    /// Offset along the previous `z`, m.
    pub d_m: f64,
    /// Length along the new `x`, m.
    pub a_m: f64,
    /// Twist about the new `x`, rad.
    pub alpha_rad: f64,
}

const fn row(gamma_rad: f64, d_m: f64, a_m: f64, alpha_rad: f64) -> DhRow {
    DhRow {
        gamma_rad,
        d_m,
        a_m,
        alpha_rad,
    }
}

const HALF_PI: f64 = core::f64::consts::FRAC_PI_2;
const PI: f64 = core::f64::consts::PI;

/// Rocky 8 D-H data, H04 Appendix A Table 2 (the simulator's own reading).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DhGeometry {
    /// Rover frame to rocker (differential) frame `D`.
    pub d: DhRow,
    /// `D` to the right bogie `rho1` (joint variable `beta`).
    pub rho1: DhRow,
    /// `D` to the left bogie `rho2` (joint variable `-beta`).
    pub rho2: DhRow,
    /// Steering frames `S1..S6` (joint variable: bogie angle for 1-4, `+-beta` for 5-6).
    pub steer: [DhRow; WHEELS],
    /// Axle frames `A1..A6` (joint variable: steering angle; only `d` matters for the centre).
    pub axle: [DhRow; WHEELS],
    /// Wheel radius, m.
    pub wheel_radius_m: f64,
}

/// Wheel radius assumed by [`DhGeometry::rocky8`], m. H04 Table 2 writes the radius as a
/// placeholder (1.000); 0.1 m is the simulator's assumption for a Rocky 8 class wheel.
pub const ROCKY8_WHEEL_RADIUS_M: f64 = 0.1;

impl DhGeometry {
    /// H04 Table 2 values.
    pub fn rocky8() -> Self {
        Self {
            d: row(0.0, -0.2022, -0.1420, -HALF_PI),
            rho1: row(-0.2698, 0.3111, 0.2812, 0.0),
            rho2: row(-0.2698, -0.3111, 0.2812, 0.0),
            steer: [
                row(0.2698, 0.0, 0.2644, -HALF_PI),
                row(0.2698, 0.0, 0.2644, -HALF_PI),
                row(-2.872, 0.0, 0.1285, HALF_PI),
                row(-2.872, 0.0, 0.1285, HALF_PI),
                row(PI, 0.3111, 0.2121, HALF_PI),
                row(PI, -0.3111, 0.2121, HALF_PI),
            ],
            axle: [
                row(0.0, -0.1273, 0.0, -HALF_PI),
                row(0.0, -0.1273, 0.0, -HALF_PI),
                row(0.0, -0.1273, 0.0, HALF_PI),
                row(0.0, -0.1273, 0.0, HALF_PI),
                row(0.0, -0.2022, 0.0, HALF_PI),
                row(0.0, -0.2022, 0.0, HALF_PI),
            ],
            wheel_radius_m: ROCKY8_WHEEL_RADIUS_M,
        }
    }

    /// The same geometry with every length perturbed by `delta(k)` metres (k counts the
    /// lengths), for per-seed dimension errors.
    pub fn perturbed(&self, mut delta: impl FnMut(usize) -> f64) -> Self {
        let mut g = *self;
        let mut k = 0;
        let mut bump = |v: &mut f64| {
            if *v != 0.0 {
                *v += delta(k);
                k += 1;
            }
        };
        for r in [&mut g.d, &mut g.rho1, &mut g.rho2]
            .into_iter()
            .chain(g.steer.iter_mut())
            .chain(g.axle.iter_mut())
        {
            bump(&mut r.d_m);
            bump(&mut r.a_m);
        }
        g
    }
}

fn dh(r: &DhRow, joint_rad: f64) -> Matrix4<f64> {
    let (sg, cg) = (r.gamma_rad + joint_rad).sin_cos();
    let (sa, ca) = r.alpha_rad.sin_cos();
    Matrix4::new(
        cg,
        -sg * ca,
        sg * sa,
        r.a_m * cg,
        sg,
        cg * ca,
        -cg * sa,
        r.a_m * sg,
        0.0,
        sa,
        ca,
        r.d_m,
        0.0,
        0.0,
        0.0,
        1.0,
    )
}

impl VehicleGeometry for DhGeometry {
    fn wheel_radius_m(&self) -> f64 {
        self.wheel_radius_m
    }

    /// Eq. 12 (H04) chain `T_D^R T_rho^D T_S^rho T_A^S` (rear wheels: `T_D^R T_S^D T_A^S`),
    /// origin of `A_i`.
    fn axle_centres(&self, rocker_rad: f64, bogie_rad: [f64; 2]) -> [[f64; 3]; WHEELS] {
        let t_d = dh(&self.d, 0.0);
        let t_rho = [
            t_d * dh(&self.rho1, rocker_rad),
            t_d * dh(&self.rho2, -rocker_rad),
        ];
        let mut out = [[0.0; 3]; WHEELS];
        for (i, o) in out.iter_mut().enumerate() {
            let t_s = match i {
                0 | 2 => t_rho[0] * dh(&self.steer[i], bogie_rad[0]),
                1 | 3 => t_rho[1] * dh(&self.steer[i], bogie_rad[1]),
                4 => t_d * dh(&self.steer[i], rocker_rad),
                _ => t_d * dh(&self.steer[i], -rocker_rad),
            };
            let t_a = t_s * dh(&self.axle[i], 0.0);
            let p: Vector3<f64> = t_a.fixed_view::<3, 1>(0, 3).into();
            *o = [p.x, p.y, p.z];
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SIM-2: the H04 Table 2 reading puts all six axles at `z = 0` with zero joint angles,
    /// right wheels at `+y`, front wheels ahead, and rotating the rocker lifts the right front.
    #[test]
    fn sim_2_table2_layout() {
        let g = DhGeometry::rocky8();
        let a = g.axle_centres(0.0, [0.0, 0.0]);
        for (i, p) in a.iter().enumerate() {
            assert!(p[2].abs() < 1e-3, "wheel {} z {}", i + 1, p[2]);
            assert!((p[1].abs() - 0.3111).abs() < 1e-9);
            assert_eq!(p[1] > 0.0, i % 2 == 0, "right wheels are odd-numbered");
        }
        assert!(a[0][0] > a[2][0] && a[2][0] > a[4][0]);
        assert!((a[0][0] - a[1][0]).abs() < 1e-12);
        let lifted = g.axle_centres(0.1, [0.0, 0.0]);
        assert!(
            lifted[0][2] < a[0][2],
            "positive beta lifts the right front (z up is -)"
        );
        assert!(lifted[1][2] > a[1][2], "and lowers the left front");
        let bogie = g.axle_centres(0.0, [0.1, 0.0]);
        assert!(bogie[0][2] < a[0][2] && bogie[2][2] > a[2][2]);
    }
}
