//! Online estimate of the effective wheel-radius scale (issue 14 item 3, "estimated scale
//! states"): the ratio of the EKF's travel to the wheels' travel over intervals the gate
//! accepted while VO anchors the EKF. On firm ground that is the wheels' effective radius over
//! the nominal one (manufacturing, wear, sinkage); the kinematic translation is multiplied by
//! it before the gate and the fusion, so that a systematic radius error is not read as slip.
//!
//! Undetected slip also enters the ratio, so the scale is bounded to
//! [`RadiusScaleConfig::max_deviation`] around 1 (the wheels' radius tolerance): slip beyond
//! that stays visible to the gate.

/// Settings of the radius-scale estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadiusScaleConfig {
    /// Wheel travel per update of the estimate, m.
    pub window_m: f64,
    /// Gain of each update (exponential smoothing over windows).
    pub gain: f64,
    /// Largest deviation of the scale from 1 (the radius tolerance), fraction.
    pub max_deviation: f64,
    /// An interval counts only if a VO update was fused within this many RG2 cycles.
    pub vo_recent_cycles: u32,
}

impl Default for RadiusScaleConfig {
    /// 1 m windows, gain 0.3, within 4 % of nominal (twice the 2 % radius tolerance), VO fused
    /// within the last 2 s.
    fn default() -> Self {
        Self {
            window_m: 1.0,
            gain: 0.3,
            max_deviation: 0.04,
            vo_recent_cycles: 40,
        }
    }
}

/// The running estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadiusScale {
    /// Current scale (effective radius over nominal).
    pub scale: f64,
    wheel_m: f64,
    ekf_m: f64,
    /// Windows completed.
    pub updates: u32,
}

impl RadiusScale {
    /// Nominal radius (scale 1).
    pub const fn new() -> Self {
        Self {
            scale: 1.0,
            wheel_m: 0.0,
            ekf_m: 0.0,
            updates: 0,
        }
    }

    /// One kinematic interval: `wheel_m` of nominal wheel travel, `ekf_m` of EKF travel; used
    /// only when `usable` (accepted by the gate, VO recent).
    pub fn add(&mut self, c: &RadiusScaleConfig, wheel_m: f64, ekf_m: f64, usable: bool) {
        if !(usable && wheel_m.is_finite() && ekf_m.is_finite() && wheel_m > 0.0) {
            return;
        }
        self.wheel_m += wheel_m;
        self.ekf_m += ekf_m;
        if self.wheel_m < c.window_m {
            return;
        }
        let ratio = self.ekf_m / self.wheel_m;
        self.wheel_m = 0.0;
        self.ekf_m = 0.0;
        let next = self.scale + c.gain * (ratio - self.scale);
        if next.is_finite() {
            self.scale = crate::linalg::clamp(next, 1.0 - c.max_deviation, 1.0 + c.max_deviation);
            self.updates = self.updates.saturating_add(1);
        }
    }
}

impl Default for RadiusScale {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kin_11_radius_scale_converges_and_is_bounded() {
        let c = RadiusScaleConfig::default();
        let mut r = RadiusScale::new();
        // Wheels 2.2 % smaller than nominal: the EKF moves 0.978 of the wheel travel.
        for _ in 0..2_000 {
            r.add(&c, 0.005, 0.005 * 0.978, true);
        }
        assert!((r.scale - 0.978).abs() < 1e-3, "{}", r.scale);
        // Unusable intervals change nothing.
        let before = r;
        for _ in 0..2_000 {
            r.add(&c, 0.005, 0.0, false);
        }
        assert_eq!(r, before);
        // 30 % slip cannot teach more than the bound.
        for _ in 0..4_000 {
            r.add(&c, 0.005, 0.0035, true);
        }
        assert!((r.scale - (1.0 - c.max_deviation)).abs() < 1e-12);
    }
}
