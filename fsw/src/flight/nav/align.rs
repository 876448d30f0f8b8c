//! # Aligner: alignment at rest
//!
//! Tilt tilt from the averaged specific force, gyro bias from the averaged rate
//! (eq. 26 with v = 0), heading from the sun sensor (RB sec. 5.1: the sun's direction in the
//! levelled rover frame against its ephemeris direction in `N`), and the start of the EKF with
//! the covariance of those estimates.
//!
//! The alignment ends when [`AlignConfig::samples`] IMU samples are averaged and at least
//! one sun reading was taken. Without a sun reading for [`AlignConfig::sun_wait_samples`]
//! more samples (sun out of view, sensor failed, no ephemeris) the heading of the plan
//! ([`AlignConfig::initial_yaw_rad`], 1-sigma [`AlignConfig::initial_yaw_sigma_rad`]) is used and
//! [`AlignCounters::heading_from_plan`] counts it.

use super::filter::NavFilter;
use super::PoseEstimate;
use crate::estimation::{CoreCov, EkfConfig, NominalState};
use crate::types::{Quat, Vec3};
use rover_hal::{ImuSample, SunReading};

/// Settings of the alignment and of the drive's start (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlignConfig {
    /// Start position of the rover reference point in `N` (north, east, down), m, from the
    /// ground's localisation (the drive plan), not measured on board.
    pub initial_position_n_m: [f64; 3],
    /// Start heading of the plan (yaw from north, positive towards east), rad: used only when
    /// the alignment gets no sun heading (see [`AlignCounters::heading_from_plan`]).
    pub initial_yaw_rad: f64,
    /// 1-sigma uncertainty of the plan's start heading, rad.
    pub initial_yaw_sigma_rad: f64,
    /// 1-sigma uncertainty of the start position, m per axis.
    pub initial_position_sigma_m: f64,
    /// IMU samples averaged at rest before the EKF starts (tilt and gyro bias alignment).
    pub samples: u32,
    /// Largest standard deviation of any gyro axis over the alignment, rad/s (the rover must be
    /// at rest; a larger dispersion restarts the alignment).
    pub max_gyro_std_rad_s: f64,
    /// Largest standard deviation of any accelerometer axis over the alignment, m/s^2.
    pub max_accel_std_m_s2: f64,
    /// IMU samples the alignment waits beyond `samples` for a sun reading (heading) before it
    /// starts with the plan's heading [`Self::initial_yaw_rad`].
    pub sun_wait_samples: u32,
    /// Initial 1-sigma of the accelerometer bias, m/s^2 (also the tilt's 1-sigma over gravity).
    pub accel_bias_sigma_m_s2: f64,
}

/// Counters of the alignment (telemetry, [`super::NavCounters`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AlignCounters {
    /// Alignments restarted because the IMU samples were not those of a rover at rest.
    pub align_restarts: u32,
    /// Alignments whose heading came from the sun sensor.
    pub heading_from_sun: u32,
    /// Alignments that took the plan's heading (no usable sun reading in time).
    pub heading_from_plan: u32,
}

/// The aligned start: the pose the filter started at, the gyro bias, and the time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aligned {
    /// Aligned pose (`N`).
    pub pose: PoseEstimate,
    /// Gyro bias estimate, rad/s (`R`).
    pub b_g: Vec3,
    /// Time of the sample that ended the alignment, us.
    pub t_us: u64,
}

/// The alignment component: its settings, the sums of the samples at rest, counters.
#[derive(Debug, Clone, Copy)]
pub struct Aligner {
    config: AlignConfig,
    sums: Alignment,
    counters: AlignCounters,
}

/// Sums of the stationary IMU samples during alignment.
#[derive(Debug, Clone, Copy, Default)]
struct Alignment {
    count: u32,
    gyro: [f64; 3],
    accel: [f64; 3],
    /// Sums of squares of the samples (dispersion test).
    gyro_sq: [f64; 3],
    accel_sq: [f64; 3],
    /// Sum of the unit sun vectors read in `R` during the alignment.
    sun: [f64; 3],
    /// Sun readings summed.
    sun_count: u32,
    /// Time of the last sun reading summed, us (the ephemeris is evaluated there).
    sun_t_us: u64,
}

impl Alignment {
    /// No samples yet (as [`Default`], usable in a `const`).
    const EMPTY: Self = Self {
        count: 0,
        gyro: [0.0; 3],
        accel: [0.0; 3],
        gyro_sq: [0.0; 3],
        accel_sq: [0.0; 3],
        sun: [0.0; 3],
        sun_count: 0,
        sun_t_us: 0,
    };
}

impl Alignment {
    /// Adds one sun reading in `R` (unit vector, finite; others are ignored).
    fn add_sun(&mut self, reading: &SunReading) {
        let s = reading.sun_dir_rover;
        let norm = crate::linalg::sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
        let unit = libm::fabs(norm - 1.0) < 0.01;
        if !reading.sun_in_view || !unit {
            return;
        }
        for (acc, v) in self.sun.iter_mut().zip(s.iter()) {
            *acc += v;
        }
        self.sun_count = self.sun_count.saturating_add(1);
        self.sun_t_us = reading.t_us;
    }
}

/// Heading (rad) and its 1-sigma (rad) from the averaged sun vector `s_r` (`R`), the tilt
/// `(roll, pitch)` with 1-sigma `tilt_sigma` (rad) and the ephemeris direction `s_n`: with
/// `v = R_y(pitch) R_x(roll) s_R` the sun in the levelled frame, `yaw = az(s_N) - az(v)`,
/// `az(u) = atan2(u_y, u_x)`; variance `(sigma_sun^2 / n) / cos^2(el) + sigma_tilt^2 tan^2(el)`
/// for a sun at elevation `el`. `None` when the sun is within 5 deg of the zenith (no azimuth).
fn sun_heading(
    s_r: Vec3,
    roll: f64,
    pitch: f64,
    tilt_sigma: f64,
    s_n: Vec3,
    sun_sigma_rad: f64,
    n: u32,
) -> Option<(f64, f64)> {
    let v = Quat::from_euler_angles(roll, pitch, 0.0) * s_r.normalize();
    let horizontal = crate::linalg::sqrt(v.x * v.x + v.y * v.y);
    let horizontal_n = crate::linalg::sqrt(s_n.x * s_n.x + s_n.y * s_n.y);
    let min = libm::sin(5.0_f64.to_radians());
    if !(horizontal > min && horizontal_n > min) {
        return None;
    }
    let yaw = crate::guidance::wrap_pi(libm::atan2(s_n.y, s_n.x) - libm::atan2(v.y, v.x));
    let tan_el = libm::fabs(v.z) / horizontal;
    let var = sun_sigma_rad * sun_sigma_rad / f64::from(n.max(1)) / (horizontal * horizontal)
        + tilt_sigma * tilt_sigma * tan_el * tan_el;
    let sigma = crate::linalg::sqrt(var).max(1.0e-3);
    (yaw.is_finite() && sigma.is_finite()).then_some((yaw, sigma))
}

impl Aligner {
    /// Placeholder (the compile-time value of a static navigator before its initialisation).
    pub const EMPTY: Self = Self {
        config: AlignConfig {
            initial_position_n_m: [0.0; 3],
            initial_yaw_rad: 0.0,
            initial_yaw_sigma_rad: 0.0,
            initial_position_sigma_m: 0.0,
            samples: 0,
            max_gyro_std_rad_s: 0.0,
            max_accel_std_m_s2: 0.0,
            sun_wait_samples: 0,
            accel_bias_sigma_m_s2: 0.0,
        },
        sums: Alignment::EMPTY,
        counters: AlignCounters {
            align_restarts: 0,
            heading_from_sun: 0,
            heading_from_plan: 0,
        },
    };

    /// A new alignment with `config`: no samples, counters zero.
    pub fn new(config: AlignConfig) -> Self {
        Self {
            config,
            sums: Alignment::EMPTY,
            counters: AlignCounters::default(),
        }
    }

    /// The settings (the drive's start pose among them).
    pub fn config(&self) -> &AlignConfig {
        &self.config
    }

    /// Counters.
    pub fn counters(&self) -> AlignCounters {
        self.counters
    }

    /// The plan's start pose (`N`): the navigation pose before the alignment ends.
    pub fn start_pose(&self) -> PoseEstimate {
        PoseEstimate {
            p_n: Vec3::from(self.config.initial_position_n_m),
            q_nr: Quat::from_euler_angles(0.0, 0.0, self.config.initial_yaw_rad),
        }
    }

    /// RG4 while aligning: a checked sun reading in `R`, summed for the heading (unit vectors
    /// in view only).
    pub fn sun(&mut self, reading: &SunReading) {
        self.sums.add_sun(reading);
    }

    /// RG1 while aligning: one checked IMU sample of the rover at rest. When the alignment is
    /// complete (module doc) the filter is started at the aligned state with the covariance of
    /// the estimates, and the aligned start is returned; a dispersion beyond the limits
    /// restarts the alignment (counted); a filter that refuses the start is reported to it
    /// ([`NavFilter::error`]) and the alignment restarts.
    pub fn add_imu(&mut self, s: &ImuSample, filter: &mut NavFilter) -> Option<Aligned> {
        let ekf: EkfConfig = *filter.ekf_config();
        let a = &mut self.sums;
        a.count = a.count.saturating_add(1);
        for k in 0..3 {
            a.gyro[k] += s.gyro_rad_s[k];
            a.accel[k] += s.accel_m_s2[k];
            a.gyro_sq[k] += s.gyro_rad_s[k] * s.gyro_rad_s[k];
            a.accel_sq[k] += s.accel_m_s2[k] * s.accel_m_s2[k];
        }
        let sun_wait_over = a.count
            >= self
                .config
                .samples
                .saturating_add(self.config.sun_wait_samples);
        if a.count < self.config.samples || (a.sun_count == 0 && !sun_wait_over) {
            return None;
        }
        let n = f64::from(a.count);
        // Dispersion test (FP-5): a rover that moved, a shock or a spike within the sensor's
        // range would be averaged into the attitude and the gyro bias; restart instead.
        let std = |sum: &[f64; 3], sq: &[f64; 3]| {
            (0..3).fold(0.0_f64, |m, k| {
                let mean = sum[k] / n;
                m.max(crate::linalg::sqrt((sq[k] / n - mean * mean).max(0.0)))
            })
        };
        let (gyro_std, accel_std) = (std(&a.gyro, &a.gyro_sq), std(&a.accel, &a.accel_sq));
        let c = &self.config;
        let steady = gyro_std <= c.max_gyro_std_rad_s && accel_std <= c.max_accel_std_m_s2;
        if !steady {
            self.sums = Alignment::default();
            self.counters.align_restarts = self.counters.align_restarts.saturating_add(1);
            return None;
        }
        let f = Vec3::new(a.accel[0] / n, a.accel[1] / n, a.accel[2] / n);
        let g = f.norm();
        if !(g.is_finite() && g > 0.1) {
            // No usable gravity reference: start again.
            self.sums = Alignment::default();
            return None;
        }
        // At rest f = -C' g_N: the rover-frame down axis is -f / |f| (eq. 26 with v = 0).
        let pitch = libm::asin((f.x / g).clamp(-1.0, 1.0));
        let roll = libm::atan2(-f.y, -f.z);
        let c = &self.config;
        let tilt_sigma = c.accel_bias_sigma_m_s2 / g;
        let sun = match (a.sun_count, ekf.sun.and_then(|e| e.sun_dir_n(a.sun_t_us))) {
            (k, Some(s_n)) if k > 0 => sun_heading(
                Vec3::new(a.sun[0], a.sun[1], a.sun[2]),
                roll,
                pitch,
                tilt_sigma,
                s_n,
                ekf.sun_sigma_rad,
                k,
            ),
            _ => None,
        };
        let (yaw, yaw_sigma) = match sun {
            Some(h) => {
                self.counters.heading_from_sun = self.counters.heading_from_sun.saturating_add(1);
                h
            }
            None if sun_wait_over => {
                self.counters.heading_from_plan = self.counters.heading_from_plan.saturating_add(1);
                (c.initial_yaw_rad, c.initial_yaw_sigma_rad)
            }
            // A sun reading without an azimuth (zenith) or ephemeris: keep waiting for the
            // timeout.
            None => return None,
        };
        let q = Quat::from_euler_angles(roll, pitch, yaw);
        let x0 = NominalState {
            t_us: s.t_us,
            q_nr: q,
            b_g: Vec3::new(a.gyro[0] / n, a.gyro[1] / n, a.gyro[2] / n),
            v_n: Vec3::zeros(),
            b_a: Vec3::zeros(),
            p_n: Vec3::from(self.config.initial_position_n_m),
        };
        let p0 = start_covariance(c, &ekf, tilt_sigma, yaw_sigma, n);
        match filter.start(x0, &p0) {
            Ok(()) => Some(Aligned {
                pose: PoseEstimate {
                    p_n: x0.p_n,
                    q_nr: x0.q_nr,
                },
                b_g: x0.b_g,
                t_us: s.t_us,
            }),
            Err(e) => {
                self.sums = Alignment::default();
                filter.error(e);
                None
            }
        }
    }
}

/// The core covariance the filter starts with (diagonal): tilt `tilt_sigma` and heading
/// `yaw_sigma` (rad), the gyro bias from the average of `n` samples at 200 Hz, the velocity of a
/// rover at rest (the zero-velocity update's sigma), the accelerometer bias and start position
/// of `c`.
fn start_covariance(
    c: &AlignConfig,
    ekf: &EkfConfig,
    tilt_sigma: f64,
    yaw_sigma: f64,
    n: f64,
) -> CoreCov {
    let gyro_avg_sigma = ekf.imu_noise.gyro_rad_s_sqrt_hz * crate::linalg::sqrt(200.0 / n) + 1.0e-6;
    let mut p0 = CoreCov::zeros();
    let diag = [
        tilt_sigma,
        tilt_sigma,
        yaw_sigma,
        gyro_avg_sigma,
        gyro_avg_sigma,
        gyro_avg_sigma,
        ekf.zupt_sigma_m_s,
        ekf.zupt_sigma_m_s,
        ekf.zupt_sigma_m_s,
        c.accel_bias_sigma_m_s2,
        c.accel_bias_sigma_m_s2,
        c.accel_bias_sigma_m_s2,
        c.initial_position_sigma_m,
        c.initial_position_sigma_m,
        c.initial_position_sigma_m,
    ];
    for (i, s) in diag.iter().enumerate() {
        p0[(i, i)] = s * s;
    }
    p0
}
