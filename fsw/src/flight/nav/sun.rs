//! # SunAiding: the sun-sensor heading update (RB sec. 5.1)
//!
//! RG4 hands every checked sun reading with the sun in view to [`SunAiding::update`] once the
//! filter runs (before, the [`super::Aligner`] takes it for the start heading). The update is
//! the EKF's ([`crate::estimation::Ekf::update_sun`], gated). [`SunConfig::streak`] refusals in
//! a row by the sun's gate (the filter's heading drifted beyond its covariance, e.g. kinematic
//! yaw fused while the wheels slip) inflate the heading covariance by the last residual angle
//! (at least 0.01 rad, at most 1 rad) so that the next reading corrects it; counted in
//! [`SunCounters::sun_streaks`].

use super::filter::NavFilter;
use rover_hal::SunReading;

/// Settings of the sun aiding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunConfig {
    /// Sun readings refused by the sun's gate in a row after which the heading covariance is
    /// inflated.
    pub streak: u32,
}

/// Counters of the sun aiding (telemetry, [`super::NavCounters`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SunCounters {
    /// Sun updates applied.
    pub sun_applied: u32,
    /// Sun readings refused (gate, skew, not in view).
    pub sun_refused: u32,
    /// Streaks of sun readings refused by the gate that inflated the heading covariance.
    pub sun_streaks: u32,
}

/// The sun aiding component.
#[derive(Debug, Clone, Copy)]
pub struct SunAiding {
    config: SunConfig,
    /// Sun readings refused by the sun's gate in a row.
    rejections: u32,
    counters: SunCounters,
}

impl SunAiding {
    /// Placeholder (the compile-time value of a static navigator before its initialisation).
    pub const EMPTY: Self = Self {
        config: SunConfig { streak: 0 },
        rejections: 0,
        counters: SunCounters {
            sun_applied: 0,
            sun_refused: 0,
            sun_streaks: 0,
        },
    };

    /// A new sun aiding with `config`.
    pub fn new(config: SunConfig) -> Self {
        Self {
            config,
            rejections: 0,
            counters: SunCounters::default(),
        }
    }

    /// Counters.
    pub fn counters(&self) -> SunCounters {
        self.counters
    }

    /// RG4: one checked sun reading with the sun in view updates the running `filter` (module
    /// doc). Nothing happens while the filter does not run.
    pub fn update(&mut self, reading: &SunReading, filter: &mut NavFilter) {
        let Some(result) = filter.sun(reading) else {
            return;
        };
        match result {
            Ok(u) if u.applied => {
                self.rejections = 0;
                self.counters.sun_applied = self.counters.sun_applied.saturating_add(1)
            }
            Ok(u) => {
                self.counters.sun_refused = self.counters.sun_refused.saturating_add(1);
                self.rejections = self.rejections.saturating_add(1);
                if self.rejections >= self.config.streak {
                    self.rejections = 0;
                    let angle = crate::linalg::sqrt(
                        u.residual[0] * u.residual[0] + u.residual[1] * u.residual[1],
                    );
                    let sigma = if angle.is_finite() {
                        angle.clamp(0.01, 1.0)
                    } else {
                        0.01
                    };
                    self.counters.sun_streaks = self.counters.sun_streaks.saturating_add(1);
                    filter.inflate_heading(sigma);
                }
            }
            Err(_) => self.counters.sun_refused = self.counters.sun_refused.saturating_add(1),
        }
    }
}
