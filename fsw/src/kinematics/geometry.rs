//! Rover geometry as Denavit-Hartenberg data (H04 Appendix A, Table 2) and the per-wheel
//! homogeneous transforms of eq. 12.
//!
//! Convention (checked numerically in the tests): standard D-H, one row maps frame `i-1` to
//! frame `i` by `Rz(gamma) * Tz(d) * Tx(a) * Rx(alpha)`; a joint variable in `gamma` rotates about
//! the `z` axis of frame `i-1`. The base frame of the table is the rover frame `R` itself
//! (x forward, y right, z down): with this reading the right bogie lies at `+y`, the steering axes
//! are vertical, every axle lies at `z = 0` of `R` and the contact points fall below the axles.

use super::{KinematicsError, SuspensionState};
use crate::types::{Mat3, Vec3};
use rover_hal::WHEEL_COUNT;

/// Which measured joint variable enters a D-H row's `gamma` (`gamma = offset + sign * variable`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointVariable {
    /// Constant row (no joint).
    Fixed,
    /// Rocker (differential) angle `beta`.
    Rocker,
    /// Right bogie angle `rho_1`.
    RightBogie,
    /// Left bogie angle `rho_2`.
    LeftBogie,
    /// This wheel's steering angle `psi_i`.
    Steer,
}

/// One D-H row (H04 Table 2 columns `gamma, d, a, alpha`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DhRow {
    /// Constant part of the joint angle `gamma`, rad.
    pub gamma_offset_rad: f64,
    /// The joint variable in `gamma`.
    pub joint: JointVariable,
    /// Sign of the joint variable in `gamma` (+1 or -1).
    pub joint_sign: f64,
    /// Offset `d` along the previous `z` axis, m.
    pub d_m: f64,
    /// Length `a` along the new `x` axis, m.
    pub a_m: f64,
    /// Twist `alpha` about the new `x` axis, rad.
    pub alpha_rad: f64,
    /// `[sin, cos]` of `gamma_offset_rad`, computed by [`DhRow::new`].
    gamma_offset_sin_cos: [f64; 2],
    /// `[sin, cos]` of `alpha_rad`, computed by [`DhRow::new`].
    alpha_sin_cos: [f64; 2],
}

impl DhRow {
    /// A row `gamma = gamma_offset_rad + joint_sign * joint` (`joint_sign` is +1 or -1; any
    /// negative value counts as -1), `d`, `a`, `alpha`. The sines and cosines of the constant
    /// angles are computed here, at compile time for a `const` table.
    pub const fn new(
        gamma_offset_rad: f64,
        joint: JointVariable,
        joint_sign: f64,
        d_m: f64,
        a_m: f64,
        alpha_rad: f64,
    ) -> Self {
        DhRow {
            gamma_offset_rad,
            joint,
            joint_sign: if joint_sign < 0.0 { -1.0 } else { 1.0 },
            d_m,
            a_m,
            alpha_rad,
            gamma_offset_sin_cos: const_sin_cos(gamma_offset_rad),
            alpha_sin_cos: const_sin_cos(alpha_rad),
        }
    }
}

/// `[sin x, cos x]` in a `const` context: exact at 0, +-pi/2 and pi, otherwise a Taylor series
/// (30 terms) after reduction to `[-pi, pi]`, accurate to a few ulp. Used only for the constant
/// angles of a D-H table; non-finite or huge angles give `[NaN, NaN]`.
const fn const_sin_cos(x: f64) -> [f64; 2] {
    if x == 0.0 {
        return [0.0, 1.0];
    } else if x == HALF_PI {
        return [1.0, 0.0];
    } else if x == -HALF_PI {
        return [-1.0, 0.0];
    } else if x == PI || x == -PI {
        return [0.0, -1.0];
    }
    if !(x.is_finite()) || x > 64.0 || x < -64.0 {
        return [f64::NAN, f64::NAN];
    }
    let two_pi = 2.0 * PI;
    let mut r = x;
    let mut n = 0;
    while n < 12 && r > PI {
        r -= two_pi;
        n += 1;
    }
    while n < 24 && r < -PI {
        r += two_pi;
        n += 1;
    }
    let r2 = r * r;
    let (mut sin, mut cos) = (r, 1.0);
    let (mut sin_term, mut cos_term) = (r, 1.0);
    let mut k = 1.0;
    while k < 30.0 {
        sin_term *= -r2 / ((2.0 * k) * (2.0 * k + 1.0));
        cos_term *= -r2 / ((2.0 * k - 1.0) * (2.0 * k));
        sin += sin_term;
        cos += cos_term;
        k += 1.0;
    }
    [sin, cos]
}

/// What a wheel's steering frame `S_i` hangs from (eq. 12 and its rear-wheel exception).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WheelMount {
    /// `S_i` follows the right bogie frame `rho_1`.
    RightBogie,
    /// `S_i` follows the left bogie frame `rho_2`.
    LeftBogie,
    /// `S_i` follows the rocker frame `D` directly (rear wheels).
    Rocker,
}

/// The D-H rows of one wheel: `S_i`, `A_i`, `C_i` (the `M_i` row is `Tz(-r)` at the contact,
/// see [`RoverGeometry::wheel_radius_m`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelChain {
    /// Parent of the steering frame.
    pub mount: WheelMount,
    /// Row `S_i` (steering frame).
    pub steer: DhRow,
    /// Row `A_i` (axle frame; carries the steering angle).
    pub axle: DhRow,
    /// Row `C_i` (contact frame).
    pub contact: DhRow,
}

/// Joint and actuator limits of a rover.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimits {
    /// Largest accepted `|beta|`, rad.
    pub rocker_rad: f64,
    /// Largest accepted `|rho_1|`, `|rho_2|`, rad.
    pub bogie_rad: f64,
    /// Steering range `[-steer_rad, +steer_rad]`, rad.
    pub steer_rad: f64,
    /// Largest wheel rate the drive motors deliver, rad/s.
    pub wheel_rate_rad_s: f64,
}

/// A rocker-bogie rover: D-H table (H04 Table 2), wheel radius and limits. Another rover of this
/// class is a new value of this type, not new code.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoverGeometry {
    /// Row `D`: rover frame `R` to rocker (differential) frame `D` (constant).
    pub rocker: DhRow,
    /// Rows `rho_1` (right) and `rho_2` (left): `D` to the bogie frames.
    pub bogies: [DhRow; 2],
    /// Rows `S_i, A_i, C_i` per wheel, index `wheel - 1`.
    pub wheels: [WheelChain; WHEEL_COUNT],
    /// Wheel radius `r`, m: Table 2's `M_i` rows carry `d = -r` and `a = -r * theta_i`.
    pub wheel_radius_m: f64,
    /// Joint and actuator limits.
    pub limits: JointLimits,
}

const PI: f64 = core::f64::consts::PI;
const HALF_PI: f64 = core::f64::consts::FRAC_PI_2;

const fn row(
    gamma_offset_rad: f64,
    joint: JointVariable,
    joint_sign: f64,
    d_m: f64,
    a_m: f64,
    alpha_rad: f64,
) -> DhRow {
    DhRow::new(gamma_offset_rad, joint, joint_sign, d_m, a_m, alpha_rad)
}

/// Rocky 8 wheel radius, m. H04 Table 2 leaves it as `-1.000` in the `M_i` rows; 0.10 m is the
/// documented assumption for Rocky 8's ~20 cm wheels (see `docs/kinematics.md`).
pub const WHEEL_RADIUS_M: f64 = 0.10;

// Steering rows of the bogie wheels: front (S1, S2) and middle (S3, S4).
const fn bogie_wheel(mount: WheelMount, front: bool) -> WheelChain {
    use JointVariable::*;
    let bogie = match mount {
        WheelMount::LeftBogie => LeftBogie,
        _ => RightBogie,
    };
    if front {
        WheelChain {
            mount,
            steer: row(0.2698, bogie, 1.0, 0.0, 0.2644, -HALF_PI),
            axle: row(0.0, Steer, -1.0, -0.1273, 0.0, -HALF_PI),
            contact: row(0.0, Fixed, 1.0, 0.0, 0.0, HALF_PI),
        }
    } else {
        WheelChain {
            mount,
            // Table 2 prints -2.872 = -(pi - 0.2698) rounded; the exact value keeps the middle
            // steering axes vertical on level ground.
            steer: row(0.2698 - PI, bogie, 1.0, 0.0, 0.1285, HALF_PI),
            axle: row(0.0, Steer, -1.0, -0.1273, 0.0, HALF_PI),
            contact: row(PI, Fixed, 1.0, 0.0, 0.0, HALF_PI),
        }
    }
}

// Rear wheels (S5 right, S6 left) hang from the rocker frame D directly.
const fn rear_wheel(sign: f64) -> WheelChain {
    use JointVariable::*;
    WheelChain {
        mount: WheelMount::Rocker,
        steer: row(PI, Rocker, sign, sign * 0.3111, 0.2121, HALF_PI),
        axle: row(0.0, Steer, -1.0, -0.2022, 0.0, HALF_PI),
        contact: row(PI, Fixed, 1.0, 0.0, 0.0, HALF_PI),
    }
}

/// Rocky 8 (H04 Appendix A, Table 2), base frame `R` (x forward, y right, z down).
///
/// Deviations from the printed table, all documented in `docs/kinematics.md`: `S_3, S_4` use
/// `rho + 0.2698 - pi` for the printed `rho - 2.872` (its 4-digit rounding); the steering
/// angle enters the `A_i` rows with sign -1 so that a positive `psi_i` turns the wheel to the
/// right (about `+z_R`, like positive yaw, and as eq. 22 requires for a crab to the right),
/// because Table 2's steering axes `z_Si` point up; `M_i` carries the wheel radius
/// [`WHEEL_RADIUS_M`] in place of `-1.000`. Limits are assumptions (no source gives them):
/// rocker +-0.6 rad, bogies +-1.0 rad, steering +-1.75 rad, wheel rate 2.0 rad/s.
pub const ROCKY8: RoverGeometry = {
    use JointVariable::*;
    RoverGeometry {
        rocker: row(0.0, Fixed, 1.0, -0.2022, -0.1420, -HALF_PI),
        bogies: [
            row(-0.2698, Rocker, 1.0, 0.3111, 0.2812, 0.0),
            row(-0.2698, Rocker, -1.0, -0.3111, 0.2812, 0.0),
        ],
        wheels: [
            bogie_wheel(WheelMount::RightBogie, true),
            bogie_wheel(WheelMount::LeftBogie, true),
            bogie_wheel(WheelMount::RightBogie, false),
            bogie_wheel(WheelMount::LeftBogie, false),
            rear_wheel(1.0),
            rear_wheel(-1.0),
        ],
        wheel_radius_m: WHEEL_RADIUS_M,
        limits: JointLimits {
            rocker_rad: 0.6,
            bogie_rad: 1.0,
            steer_rad: 1.75,
            wheel_rate_rad_s: 2.0,
        },
    }
};

/// `(sin, cos)` with exact values at the right angles of the D-H tables (0, +-pi/2, pi), which
/// also saves the transcendental calls for the constant twists.
fn sin_cos(angle: f64) -> (f64, f64) {
    if angle == 0.0 {
        (0.0, 1.0)
    } else if angle == HALF_PI {
        (1.0, 0.0)
    } else if angle == -HALF_PI {
        (-1.0, 0.0)
    } else if angle == PI {
        (0.0, -1.0)
    } else {
        libm::sincos(angle)
    }
}

/// A rigid transform `T_b^a` (frame `b` expressed in frame `a`): `p_a = rot * p_b + pos`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Rotation, columns are the axes of `b` in `a`.
    pub rot: Mat3,
    /// Origin of `b` in `a`, m.
    pub pos: Vec3,
}

impl Frame {
    /// The identity transform.
    pub fn identity() -> Self {
        Frame {
            rot: Mat3::identity(),
            pos: Vec3::zeros(),
        }
    }

    /// Standard D-H transform `Rz(gamma) Tz(d) Tx(a) Rx(alpha)`.
    pub fn from_dh(gamma_rad: f64, d_m: f64, a_m: f64, alpha_rad: f64) -> Self {
        let (sg, cg) = sin_cos(gamma_rad);
        let (sa, ca) = sin_cos(alpha_rad);
        Self::from_sin_cos(sg, cg, d_m, a_m, sa, ca)
    }

    /// [`Frame::from_dh`] from the sines and cosines of `gamma` and `alpha`.
    pub fn from_sin_cos(sg: f64, cg: f64, d_m: f64, a_m: f64, sa: f64, ca: f64) -> Self {
        Frame {
            rot: Mat3::new(cg, -sg * ca, sg * sa, sg, cg * ca, -cg * sa, 0.0, sa, ca),
            pos: Vec3::new(a_m * cg, a_m * sg, d_m),
        }
    }

    /// Composition `self * next` (`T_c^a = T_b^a * T_c^b`).
    pub fn then(&self, next: &Frame) -> Frame {
        Frame {
            rot: self.rot * next.rot,
            pos: self.pos + self.rot * next.pos,
        }
    }

    /// The `z` axis of this frame.
    pub fn z_axis(&self) -> Vec3 {
        self.rot.column(2).into_owned()
    }

    /// The `x` axis of this frame.
    pub fn x_axis(&self) -> Vec3 {
        self.rot.column(0).into_owned()
    }
}

/// `[sin, cos]` of the joint values entering one wheel's chain (computed once per call).
#[derive(Debug, Clone, Copy)]
struct ChainJoints {
    rocker: [f64; 2],
    bogies: [[f64; 2]; 2],
    steer: [f64; 2],
}

impl DhRow {
    fn variable(&self, q: &ChainJoints) -> [f64; 2] {
        match self.joint {
            JointVariable::Fixed => [0.0, 1.0],
            JointVariable::Rocker => q.rocker,
            JointVariable::RightBogie => q.bogies[0],
            JointVariable::LeftBogie => q.bogies[1],
            JointVariable::Steer => q.steer,
        }
    }

    /// `Rz(offset + sign * q) Tz(d) Tx(a) Rx(alpha)` by the angle-sum identities (no
    /// transcendental call).
    fn frame(&self, q: &ChainJoints) -> Frame {
        let [sq, cq] = self.variable(q);
        let sq = self.joint_sign * sq;
        let [so, co] = self.gamma_offset_sin_cos;
        let (sg, cg) = (so * cq + co * sq, co * cq - so * sq);
        let [sa, ca] = self.alpha_sin_cos;
        Frame::from_sin_cos(sg, cg, self.d_m, self.a_m, sa, ca)
    }
}

/// The transforms and joint axes of one wheel at the current joint angles (eq. 12).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelFrames {
    /// `T_Ci^R`: contact frame in the rover frame.
    pub contact: Frame,
    /// Contact point (origin of `M_i`, `r` below the axle along `-z_Ci`) in `R`, m.
    pub contact_point_m: Vec3,
    /// Unit rolling direction `x_Ci` in `R` (positive `theta_i` moves the rover along it).
    pub rolling_dir: Vec3,
    /// Unit steering axis in `R` about which a positive `psi_i` turns the wheel (right-hand
    /// rule; points down when the rover is level).
    pub steer_axis: Vec3,
    /// `d p_contact / d beta` in `R`, m/rad.
    pub d_contact_d_rocker: Vec3,
    /// `d p_contact / d rho` of the wheel's bogie in `R`, m/rad (zero for the rear wheels).
    pub d_contact_d_bogie: Vec3,
    /// Index of the bogie angle this wheel depends on (`None` for the rear wheels).
    pub bogie: Option<usize>,
    /// Unit axis `k_beta` in `R` of the rocker joint as it moves this wheel, signed so that any
    /// point `q` fixed to the wheel's chain moves by `dq/dbeta = k_beta x (q - o)` (`o` on the
    /// axis); `d_contact_d_rocker = k_beta x (p_contact - o)`. Used by the contact-angle
    /// estimator ([`super::contact`]) to move the Jacobian columns to another contact point.
    pub rocker_axis: Vec3,
    /// Unit axis `k_rho` in `R` of this wheel's bogie joint, same convention as
    /// [`Self::rocker_axis`] (zero for the rear wheels).
    pub bogie_axis: Vec3,
}

/// Frames shared by several wheels: `T_D^R` and `T_rho1^R`, `T_rho2^R`.
#[derive(Debug, Clone, Copy)]
struct SharedFrames {
    rocker: Frame,
    bogies: [Frame; 2],
}

/// Checks a suspension state against the geometry's limits.
pub(crate) fn check_suspension(
    geometry: &RoverGeometry,
    s: &SuspensionState,
) -> Result<(), KinematicsError> {
    let all = [s.rocker_rad, s.bogie_rad[0], s.bogie_rad[1]];
    if all.iter().chain(s.steer_rad.iter()).any(|v| !v.is_finite()) {
        return Err(KinematicsError::NonFinite);
    }
    if libm::fabs(s.rocker_rad) > geometry.limits.rocker_rad {
        return Err(KinematicsError::JointOutOfRange);
    }
    if s.bogie_rad
        .iter()
        .any(|b| libm::fabs(*b) > geometry.limits.bogie_rad)
    {
        return Err(KinematicsError::JointOutOfRange);
    }
    if s.steer_rad
        .iter()
        .any(|p| libm::fabs(*p) > geometry.limits.steer_rad)
    {
        return Err(KinematicsError::JointOutOfRange);
    }
    Ok(())
}

/// Derivative of a point carried by a revolute D-H joint: the joint turns about the `z` axis
/// of the frame before its row, with the row's sign.
fn revolute_rate(parent: &Frame, sign: f64, point: &Vec3) -> Vec3 {
    parent.z_axis().cross(&(point - parent.pos)) * sign
}

/// Eq. 12 (H04): `T_Ci^R = T_D^R T_rho^D T_Si^rho T_Ai^Si T_Ci^Ai` (rear wheels: `T_D^R T_Si^D`
/// ...), the contact point `T_Mi^R` origin (`M_i` row at `xi = theta = 0`: `Tz(-r)`), and the
/// joint axes needed by the wheel Jacobians (eq. 13-14). Angles are not range-checked here (see
/// [`wheel_frames`]).
fn wheel_frames_unchecked(
    geometry: &RoverGeometry,
    shared: &SharedFrames,
    chain: &WheelChain,
    q: &ChainJoints,
) -> WheelFrames {
    let frame_d = shared.rocker;
    // Frame whose z axis the rocker joint turns about, with the sign of beta in that row.
    let (rocker_sign, frame_before_steer, bogie) = match chain.mount {
        WheelMount::RightBogie => (geometry.bogies[0].joint_sign, shared.bogies[0], Some(0)),
        WheelMount::LeftBogie => (geometry.bogies[1].joint_sign, shared.bogies[1], Some(1)),
        WheelMount::Rocker => (chain.steer.joint_sign, frame_d, None),
    };
    let frame_s = frame_before_steer.then(&chain.steer.frame(q));
    let frame_a = frame_s.then(&chain.axle.frame(q));
    let contact = frame_a.then(&chain.contact.frame(q));
    let contact_point_m = contact.pos - contact.z_axis() * geometry.wheel_radius_m;
    let d_contact_d_rocker = revolute_rate(&frame_d, rocker_sign, &contact_point_m);
    let (d_contact_d_bogie, bogie_axis) = match bogie {
        Some(_) => (
            revolute_rate(
                &frame_before_steer,
                chain.steer.joint_sign,
                &contact_point_m,
            ),
            frame_before_steer.z_axis() * chain.steer.joint_sign,
        ),
        None => (Vec3::zeros(), Vec3::zeros()),
    };
    WheelFrames {
        contact,
        contact_point_m,
        rolling_dir: contact.x_axis(),
        steer_axis: frame_s.z_axis() * chain.axle.joint_sign,
        d_contact_d_rocker,
        d_contact_d_bogie,
        bogie,
        rocker_axis: frame_d.z_axis() * rocker_sign,
        bogie_axis,
    }
}

/// Eq. 12 (H04) for all six wheels: contact frames, contact points and joint axes in the rover
/// frame `R` at the given suspension state. Errors: non-finite or out-of-range angles.
pub fn wheel_frames(
    geometry: &RoverGeometry,
    state: &SuspensionState,
) -> Result<[WheelFrames; WHEEL_COUNT], KinematicsError> {
    check_suspension(geometry, state)?;
    Ok(wheel_frames_trusted(geometry, state))
}

/// [`wheel_frames`] for a state already checked by [`check_suspension`].
pub(crate) fn wheel_frames_trusted(
    geometry: &RoverGeometry,
    state: &SuspensionState,
) -> [WheelFrames; WHEEL_COUNT] {
    let sc = |angle: f64| {
        let (s, c) = sin_cos(angle);
        [s, c]
    };
    let q0 = ChainJoints {
        rocker: sc(state.rocker_rad),
        bogies: [sc(state.bogie_rad[0]), sc(state.bogie_rad[1])],
        steer: [0.0, 1.0],
    };
    // `T_D^R` and `T_rho^R` are shared by the wheels.
    let rocker = geometry.rocker.frame(&q0);
    let shared = SharedFrames {
        rocker,
        bogies: [
            rocker.then(&geometry.bogies[0].frame(&q0)),
            rocker.then(&geometry.bogies[1].frame(&q0)),
        ],
    };
    // `w` is only called with `i < WHEEL_COUNT`, the length of both arrays. The array is
    // written element by element into the caller's slot: `core::array::from_fn` builds it on the
    // stack and copies its 1,632 bytes (about 1,220 rover-CPU instructions per call).
    let w = |i: usize| {
        let q = ChainJoints {
            steer: sc(state.steer_rad[i]),
            ..q0
        };
        wheel_frames_unchecked(geometry, &shared, &geometry.wheels[i], &q)
    };
    [w(0), w(1), w(2), w(3), w(4), w(5)]
}

/// Wheel/terrain contact points in the rover frame `R` (x forward, y right, z down), m, from
/// eq. 12 (H04) and the `M_i` row of Table 2 (contact point `r` below the axle along the
/// steering axis). The simulator places the rover on terrain with this function.
/// Errors: non-finite or out-of-range angles ([`KinematicsError`]).
pub fn wheel_contact_points(
    geometry: &RoverGeometry,
    state: &SuspensionState,
) -> Result<[Vec3; WHEEL_COUNT], KinematicsError> {
    let frames = wheel_frames(geometry, state)?;
    Ok(frames.map(|f| f.contact_point_m))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// KIN-1: the compile-time sines and cosines of the table's constant angles agree with libm.
    #[test]
    fn kin_1_const_sin_cos_matches_libm() {
        let mut x = -7.0;
        while x < 7.0 {
            let [s, c] = const_sin_cos(x);
            assert!((s - libm::sin(x)).abs() < 2e-15 && (c - libm::cos(x)).abs() < 2e-15);
            x += 0.0137;
        }
        for x in [0.2698, 0.2698 - PI, PI, -HALF_PI] {
            let [s, c] = const_sin_cos(x);
            assert!((s - libm::sin(x)).abs() < 2e-15 && (c - libm::cos(x)).abs() < 2e-15);
        }
        assert!(const_sin_cos(f64::NAN)[0].is_nan());
    }
}
