//! Types shared by the flight modules, named after the math (nalgebra, statically sized).
//!
//! Frames (see [`rover_hal`]): rover frame `R` x forward, y right, z down; navigation frame `N`
//! x north, y east, z down; camera frame `K` x right, y down, z along the optical axis.

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3, Vector6};

/// 3-vector, f64.
pub type Vec3 = Vector3<f64>;
/// 6-vector, f64.
pub type Vec6 = Vector6<f64>;
/// 3x3 matrix, f64.
pub type Mat3 = Matrix3<f64>;
/// 6x6 matrix, f64.
pub type Mat6 = Matrix6<f64>;
/// Unit quaternion, f64.
pub type Quat = UnitQuaternion<f64>;

/// The zero 3-vector as a `const` (`Vec3::zeros()`, for compile-time initialisers).
pub const VEC3_ZERO: Vec3 = Vec3::new(0.0, 0.0, 0.0);
/// The identity rotation as a `const` (`Quat::identity()`: `w = 1`, for compile-time
/// initialisers).
pub const QUAT_IDENTITY: Quat = Quat::new_unchecked(nalgebra::Quaternion {
    coords: nalgebra::Vector4::new(0.0, 0.0, 0.0, 1.0),
});

/// The zero `R x C` matrix as a `const` (`SMatrix::zeros()`, for compile-time initialisers).
pub const fn zero_matrix<const R: usize, const C: usize>() -> nalgebra::SMatrix<f64, R, C> {
    nalgebra::SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; R]; C]))
}

/// A relative pose of the rover between two times `t0` and `t1`, with its covariance: the
/// measurement that vehicle odometry (H04 sec. 3-4) and visual odometry (H04 sec. 2) hand to the
/// estimator (H04 eq. 28-45).
///
/// `R0` and `R1` are the rover frame at `t0` and at `t1`.
/// - `rot_0_1` rotates vectors from `R1` into `R0` (`v_R0 = rot_0_1 * v_R1`);
/// - `trans_0_1_m` is the position of the origin of `R1` expressed in `R0`, metres;
/// - `covariance` is over the error vector `[delta_theta; delta_p]` (rad, m), with the true
///   rotation `exp([delta_theta]x) * rot_0_1` (perturbation expressed in `R0`) and the true
///   translation `trans_0_1_m + delta_p`;
/// - `observed[k]` is false for an error component the sensor does not observe (its rows and
///   columns are then ignored by the estimator; H04: the kinematics observe 5 of 6 DOF).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativePose {
    /// Start time of the interval, microseconds since boot.
    pub t0_us: u64,
    /// End time of the interval, microseconds since boot.
    pub t1_us: u64,
    /// Rotation from `R1` to `R0`.
    pub rot_0_1: Quat,
    /// Origin of `R1` in `R0`, m.
    pub trans_0_1_m: Vec3,
    /// Covariance of `[delta_theta (rad); delta_p (m)]`.
    pub covariance: Mat6,
    /// Which of the six error components are observed.
    pub observed: [bool; 6],
}
