//! Steering and drive motors: saturation, first-order lag and a rate limit.

use serde::Deserialize;

/// One motor channel: the output follows the saturated command through a first-order lag of
/// time constant `lag_s`, and never changes faster than `rate_limit` per second.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct MotorParams {
    /// Largest commanded magnitude (rad for steering, rad/s for drive).
    pub saturation: f64,
    /// Largest rate of change of the output (rad/s for steering, rad/s^2 for drive).
    pub rate_limit: f64,
    /// Time constant of the first-order lag, s.
    pub lag_s: f64,
}

impl MotorParams {
    /// Rocky 8 class steering motor (simulator assumption): +-100 deg, 1.5 rad/s, 50 ms lag.
    pub fn steering() -> Self {
        Self {
            saturation: 100f64.to_radians(),
            rate_limit: 1.5,
            lag_s: 0.05,
        }
    }
    /// Rocky 8 class drive motor (simulator assumption): 3 rad/s (0.3 m/s at 0.1 m radius),
    /// 2 rad/s^2, 100 ms lag.
    pub fn drive() -> Self {
        Self {
            saturation: 3.0,
            rate_limit: 2.0,
            lag_s: 0.1,
        }
    }

    /// Advance `output` by `dt_s` towards `command`.
    pub fn step(&self, output: f64, command: f64, dt_s: f64) -> f64 {
        let target = command.clamp(-self.saturation, self.saturation);
        let rate = if self.lag_s > 0.0 {
            (target - output) / self.lag_s.max(dt_s)
        } else {
            (target - output) / dt_s
        };
        output + rate.clamp(-self.rate_limit, self.rate_limit) * dt_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SIM-4: a motor saturates its command, respects its rate limit and settles with its lag.
    #[test]
    fn sim_4_saturation_rate_limit_lag() {
        let m = MotorParams {
            saturation: 1.0,
            rate_limit: 2.0,
            lag_s: 0.1,
        };
        let dt = 0.005;
        let mut x = 0.0;
        let mut prev = 0.0;
        for _ in 0..400 {
            x = m.step(x, 5.0, dt);
            assert!((x - prev) / dt <= 2.0 + 1e-12);
            prev = x;
        }
        assert!((x - 1.0).abs() < 1e-6, "settles at the saturation, got {x}");
        // Small step: pure first-order lag (rate limit inactive): 63 % after one time constant.
        let mut y = 0.0;
        for _ in 0..20 {
            y = m.step(y, 0.1, dt);
        }
        assert!((y / 0.1 - 0.64).abs() < 0.02, "{y}");
    }
}
