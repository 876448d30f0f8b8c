//! # Error-state EKF (H04 sec. 4 and App. B; H05 sec. IV; RB sec. 5)
//!
//! The indirect (error-state) extended Kalman filter that merges the IMU with relative-pose
//! measurements from visual and vehicle odometry by stochastic cloning, gates the kinematic
//! measurements with the Mahalanobis test that detects slip, and takes absolute attitude from the
//! sun sensor and zero-velocity updates at stops. Files by concern, in the manner of PX4 EKF2:
//!
//! | file | content | seed |
//! |---|---|---|
//! | [`state`] | nominal state, error-state layout, covariance type, error injection, health | H04 sec. 4 |
//! | `propagate` | IMU integration and covariance propagation, [`Ekf::propagate`] | H04 eq. 26-27, 50-51 |
//! | `clone` | the fixed clone window, [`Ekf::clone_at`], [`Ekf::release`] | H04 eq. 41 (stochastic cloning) |
//! | `fusion` | the shared measurement update (Cholesky downdate) | H04 eq. 52-56 |
//! | `relative_pose` | [`Ekf::gate_relative_pose`], [`Ekf::update_relative_pose`] | H04 eq. 28-45 |
//! | [`gate`] | chi-square table and [`gate::GateDecision`] | H04 eq. 46 |
//! | `sun_sensor` | [`Ekf::update_sun`], sequential scalar updates | RB eq. 16-21 |
//! | `zupt` | [`Ekf::update_zero_velocity`], [`Ekf::update_zero_rate`] | bias observability at stops |
//!
//! ## Frames and conventions
//! - Navigation frame `N`: x north, y east, z down, fixed to the terrain; Mars gravity is
//!   `+3.711 m/s^2` along `+z` ([`EkfConfig::gravity_n_m_s2`]). Planet rotation (7.088e-5 rad/s)
//!   is ignored: `N` is treated as inertial (at rover speeds the Coriolis term is below 1e-5
//!   m/s^2; the rotation rate itself is absorbed by the gyro-bias state only while the heading is
//!   constant, so a long static alignment should subtract it before calling the filter).
//! - Attitude: unit quaternion `q_nr` rotating rover-frame vectors into `N`
//!   (`v_N = C(q_nr) v_R`).
//! - Error state (15, H04 sec. 4): `[dtheta, db_g, dv, db_a, dp]` where the attitude error is a
//!   rotation vector in the rover frame, `C_true = C_hat * exp([dtheta]x)` (H04: `q = dq (x) q_hat`
//!   with the JPL global-to-body quaternion, the same perturbation), and every other error is
//!   `true - estimate`.
//! - IMU (see [`rover_hal::ImuSample`]): gyro = angular rate in `R`; accelerometer = specific
//!   force in `R`, `[0, 0, -3.711]` at rest on level ground.
//! - Time: microseconds since boot; the state carries the time of the last IMU sample.
//!
//! See `docs/estimation.md` for the discretization, cloning, gate and the equation-to-function
//! map.

pub mod absolute_pose;
mod clone;
pub mod ephemeris;
mod fusion;
pub mod gate;
mod propagate;
mod relative_pose;
pub mod replay;
pub mod state;
mod sun_sensor;
mod zupt;

#[cfg(test)]
mod tests;

pub use clone::CloneHandle;
pub use gate::{GateDecision, CHI2_95, CHI2_999};
pub use propagate::PropagationStep;
pub use relative_pose::KeptRelativePose;
pub use replay::{Recorder, ReplayProgress};
pub use state::{CoreCov, Cov, NominalState, CLONE_DIM, CORE_DIM, DIM, MAX_CLONES};
pub use sun_sensor::SunUpdate;

use crate::types::Vec3;
use clone::CloneSlot;
use state::ImuHold;

/// Mars surface gravity, m/s^2 (H04; REFERENCE.md).
pub const MARS_GRAVITY_M_S2: f64 = 3.711;

/// Continuous-time noise densities of the IMU (H04 eq. 26: `w = [n_r, n_w, n_g, n_u]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuNoise {
    /// Gyro white noise (angle random walk), rad/s/sqrt(Hz) (`n_r`).
    pub gyro_rad_s_sqrt_hz: f64,
    /// Gyro bias random walk, rad/s^2/sqrt(Hz) (`n_w`).
    pub gyro_bias_rad_s2_sqrt_hz: f64,
    /// Accelerometer white noise (velocity random walk), m/s^2/sqrt(Hz) (`n_g`).
    pub accel_m_s2_sqrt_hz: f64,
    /// Accelerometer bias random walk, m/s^3/sqrt(Hz) (`n_u`).
    pub accel_bias_m_s3_sqrt_hz: f64,
}

impl Default for ImuNoise {
    /// A MEMS-grade IMU of the kind flown on rovers (about 0.35 deg/sqrt(h) ARW).
    ///
    /// The gyro bias random walk is the published figure of a MEMS unit of this class: the
    /// ADIS16448 of the EuRoC MAV datasets (Burri et al. 2016, `imu0/sensor.yaml`:
    /// 1.9393e-5 rad/s^2/sqrt(Hz)). With 1e-6 the filter holds its gyro bias as nearly
    /// constant, a bias that wanders turns the attitude during every slip hold (the IMU
    /// coasts), the lateral kinematic residual walks to -2 sigma and the gate's false alarms
    /// on firm flat ground rise to 8.8 % (`docs/estimation.md`, "Gyro bias walk"). The other
    /// three densities are the nominal ones: the EuRoC set's accelerometer figures
    /// (2e-3 and 3e-3) make the estimate worse on the three seeds tried (`flat-firm`, seeds
    /// 1-3: 1.87, 1.72, 1.00 % of distance against 0.75, 1.69, 0.56 %).
    fn default() -> Self {
        Self {
            gyro_rad_s_sqrt_hz: 1.0e-4,
            gyro_bias_rad_s2_sqrt_hz: 1.9393e-5,
            accel_m_s2_sqrt_hz: 1.0e-3,
            accel_bias_m_s3_sqrt_hz: 1.0e-5,
        }
    }
}

/// Filter configuration (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EkfConfig {
    /// IMU noise densities used to build `Q_k` (eq. 27).
    pub imu_noise: ImuNoise,
    /// Gravity in `N`, m/s^2 (`[0, 0, 3.711]` on Mars).
    pub gravity_n_m_s2: Vec3,
    /// Largest IMU sample interval treated as normal, microseconds; a longer one is propagated
    /// with the new sample held over the gap and flagged in [`PropagationStep::gap`].
    pub max_imu_dt_us: u64,
    /// Largest difference between a sun or ZUPT measurement's time stamp and the state time for
    /// the measurement to be applied at the current state, microseconds.
    pub max_measurement_skew_us: u64,
    /// Sun ephemeris of the drive (the sun's direction in `N` at each reading's time);
    /// `None` disables the sun-sensor update.
    pub sun: Option<ephemeris::SunEphemeris>,
    /// Sun-sensor noise, rad, per axis perpendicular to the sun direction (RB sec. 5.1).
    pub sun_sigma_rad: f64,
    /// ZUPT pseudo-measurement noise, m/s per axis.
    pub zupt_sigma_m_s: f64,
    /// Zero-rate pseudo-measurement noise, rad/s per axis (the averaged gyro while stopped).
    pub zero_rate_sigma_rad_s: f64,
    /// Covariance health: largest admissible attitude variance, rad^2.
    pub max_attitude_var_rad2: f64,
    /// Covariance health: largest admissible position variance, m^2.
    pub max_position_var_m2: f64,
}

impl EkfConfig {
    /// A placeholder configuration (every noise, limit and sigma zero, no sun): the value of
    /// statically allocated filters and navigators before their `init` writes the real one.
    pub const EMPTY: Self = Self {
        imu_noise: ImuNoise {
            gyro_rad_s_sqrt_hz: 0.0,
            gyro_bias_rad_s2_sqrt_hz: 0.0,
            accel_m_s2_sqrt_hz: 0.0,
            accel_bias_m_s3_sqrt_hz: 0.0,
        },
        gravity_n_m_s2: crate::types::VEC3_ZERO,
        max_imu_dt_us: 0,
        max_measurement_skew_us: 0,
        sun: None,
        sun_sigma_rad: 0.0,
        zupt_sigma_m_s: 0.0,
        zero_rate_sigma_rad_s: 0.0,
        max_attitude_var_rad2: 0.0,
        max_position_var_m2: 0.0,
    };
}

impl Default for EkfConfig {
    fn default() -> Self {
        Self {
            imu_noise: ImuNoise::default(),
            gravity_n_m_s2: Vec3::new(0.0, 0.0, MARS_GRAVITY_M_S2),
            max_imu_dt_us: 50_000,
            max_measurement_skew_us: 10_000,
            sun: None,
            sun_sigma_rad: 0.01,
            zupt_sigma_m_s: 0.001,
            zero_rate_sigma_rad_s: 1.0e-5,
            max_attitude_var_rad2: 1.0,
            max_position_var_m2: 1.0e8,
        }
    }
}

/// Why the filter refused an input or an operation. The filter state is unchanged unless the
/// variant says otherwise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EstError {
    /// An input contained NaN or an infinity.
    NonFiniteInput,
    /// The IMU sample carried `valid == false`.
    InvalidSample,
    /// The time stamp is not after the state time (a stale or repeated sample).
    TimeNotAdvancing {
        /// Time of the state, us.
        state_t_us: u64,
        /// Time stamp offered, us.
        t_us: u64,
    },
    /// The time stamp is before the state time (time went backwards).
    TimeBackwards {
        /// Time of the state, us.
        state_t_us: u64,
        /// Time stamp offered, us.
        t_us: u64,
    },
    /// A measurement refers to a time with neither a clone nor the current state.
    NoStateAtTime {
        /// The time stamp, us.
        t_us: u64,
    },
    /// Every clone slot is in use.
    CloneWindowFull,
    /// The handle does not name a live clone (released or never issued).
    UnknownClone,
    /// A measurement is malformed (observes nothing, `t0 >= t1`, non-positive variance, a
    /// direction that is not a unit vector).
    InvalidMeasurement,
    /// The sun is not in the sensor's view, or no sun ephemeris is configured.
    SunUnavailable,
    /// The measurement time is too far from the state time ([`EkfConfig::max_measurement_skew_us`]),
    /// or a [`KeptRelativePose`] was offered after the filter changed.
    StaleMeasurement,
    /// The residual covariance `S` is not positive definite; nothing was applied.
    ResidualCovarianceNotPositive,
    /// A covariance diagonal entry is non-finite, negative or above its limit (index in the
    /// full error state). The update that produced it has been applied; the fault is latched
    /// ([`Ekf::fault`]) until [`Ekf::reset`].
    CovarianceUnhealthy {
        /// Index of the first bad diagonal entry (`usize::MAX`: the nominal state is not
        /// finite).
        index: usize,
    },
    /// The filter has a latched covariance fault and refuses to run until reset.
    Faulted,
}

/// The error-state EKF with its clone window (H04 sec. 4). About 9 KB, all inline.
#[derive(Debug, Clone)]
pub struct Ekf {
    pub(crate) config: EkfConfig,
    pub(crate) x: NominalState,
    pub(crate) p: Cov,
    pub(crate) clones: [Option<CloneSlot>; MAX_CLONES],
    pub(crate) next_serial: u32,
    pub(crate) hold: Option<ImuHold>,
    pub(crate) fault: bool,
    /// Changes whenever the state or the covariance may have changed (propagation, update,
    /// clone, release, inflation, reset, copy): a [`KeptRelativePose`] is fused only while
    /// its generation is the filter's.
    pub(crate) generation: u32,
}

impl Ekf {
    /// A filter at the nominal state `x0` with core error covariance `p0` (15x15, order
    /// `[dtheta, db_g, dv, db_a, dp]`, rad, rad/s, m/s, m/s^2, m) and no clones. `p0` is
    /// symmetrized; a non-finite input or a negative diagonal is refused.
    pub fn new(config: EkfConfig, x0: NominalState, p0: &CoreCov) -> Result<Self, EstError> {
        let mut ekf = Self {
            config,
            x: x0,
            p: Cov::zeros(),
            clones: [None; MAX_CLONES],
            next_serial: 0,
            hold: None,
            fault: false,
            generation: 0,
        };
        ekf.reset(x0, p0)?;
        Ok(ekf)
    }

    /// Restart at `x0` with core covariance `p0`: drops every clone, the held IMU sample and a
    /// latched fault. Refuses non-finite input or a negative diagonal (state then unchanged).
    pub fn reset(&mut self, x0: NominalState, p0: &CoreCov) -> Result<(), EstError> {
        if !x0.is_finite() || p0.iter().any(|v| !v.is_finite()) {
            return Err(EstError::NonFiniteInput);
        }
        if (0..CORE_DIM).any(|i| p0[(i, i)] < 0.0) {
            return Err(EstError::InvalidMeasurement);
        }
        self.x = x0;
        self.x.q_nr = state::renormalize(&x0.q_nr);
        self.p = Cov::zeros();
        let sym = (p0 + p0.transpose()) * 0.5;
        self.p
            .fixed_view_mut::<CORE_DIM, CORE_DIM>(0, 0)
            .copy_from(&sym);
        self.clones = [None; MAX_CLONES];
        self.hold = None;
        self.fault = false;
        self.touch();
        Ok(())
    }

    /// A new generation: the state or the covariance may change.
    pub(crate) fn touch(&mut self) {
        self.generation = self.generation.wrapping_add(1);
    }

    /// Make this filter a copy of `other`, in place (field by field: no 9 KB temporary on the
    /// stack, unlike `clone_from`).
    pub fn copy_from(&mut self, other: &Ekf) {
        self.config = other.config;
        self.x = other.x;
        self.p.copy_from(&other.p);
        self.clones = other.clones;
        self.next_serial = other.next_serial;
        self.hold = other.hold;
        self.fault = other.fault;
        self.touch();
    }

    /// A placeholder filter (zero configuration, zero state and covariance, no clones): the
    /// compile-time value a statically allocated navigator starts from before
    /// [`Self::init`] writes the real filter in place. Not meant to be run.
    pub const EMPTY: Self = Self {
        config: EkfConfig::EMPTY,
        x: NominalState {
            t_us: 0,
            q_nr: crate::types::QUAT_IDENTITY,
            b_g: crate::types::VEC3_ZERO,
            v_n: crate::types::VEC3_ZERO,
            b_a: crate::types::VEC3_ZERO,
            p_n: crate::types::VEC3_ZERO,
        },
        p: crate::types::zero_matrix::<DIM, DIM>(),
        clones: [None; MAX_CLONES],
        next_serial: 0,
        hold: None,
        fault: false,
        generation: 0,
    };

    /// [`Self::new`] in place: this filter becomes the one `Ekf::new(config, x0, p0)` returns
    /// (every field rewritten, no 9 KB temporary). On error the configuration is set and the
    /// rest is as [`Self::reset`] leaves it on error (unchanged).
    pub fn init(
        &mut self,
        config: EkfConfig,
        x0: NominalState,
        p0: &CoreCov,
    ) -> Result<(), EstError> {
        self.config = config;
        self.next_serial = 0;
        self.reset(x0, p0)
    }

    /// The nominal (estimated) state.
    pub fn state(&self) -> &NominalState {
        &self.x
    }

    /// The full error covariance (core and clone blocks; released clone blocks are zero).
    pub fn covariance(&self) -> &Cov {
        &self.p
    }

    /// The 15x15 covariance of the current error state `[dtheta, db_g, dv, db_a, dp]`.
    pub fn core_covariance(&self) -> CoreCov {
        self.p.fixed_view::<CORE_DIM, CORE_DIM>(0, 0).into_owned()
    }

    /// Time of the state, microseconds since boot.
    pub fn time_us(&self) -> u64 {
        self.x.t_us
    }

    /// The configuration.
    pub fn config(&self) -> &EkfConfig {
        &self.config
    }

    /// True when a covariance health fault is latched (see [`EstError::CovarianceUnhealthy`]).
    pub fn fault(&self) -> bool {
        self.fault
    }

    /// Standard deviation of the heading (rotation about `N`'s z axis), rad: `sqrt(e' P_tt e)`
    /// with `e = C(q_nr)^T z_N` mapping the rover-frame attitude error onto the vertical.
    pub fn heading_sigma_rad(&self) -> f64 {
        let c = self.x.q_nr.to_rotation_matrix().into_inner();
        let e = c.transpose() * Vec3::z();
        let ptt = self.p.fixed_view::<3, 3>(state::I_THETA, state::I_THETA);
        crate::linalg::sqrt((e.transpose() * ptt * e)[(0, 0)].max(0.0))
    }
}
