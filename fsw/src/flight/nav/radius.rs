//! Online estimate of the effective wheel-radius scale (an estimated scale state): the ratio of the EKF's travel to the wheels' travel over intervals the gate
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

/// The effective wheel-radius scale of the 3D kinematic dead reckoning
/// ([`super::NavConfig::kin3d_radius_scale`]), learnt from VO directly: over a capture interval
/// in which every kinematic interval was accepted by the slip gate with VO alive (the same
/// "clean" test as the boresight, `boresight.rs`), the length of VO's translation between the
/// two captures against the length of the dead reckoning's (the contact-angle steps, unscaled,
/// summed as vectors in `N`). The pairs feed a [`RadiusScale`] (1 m windows of dead-reckoning
/// travel, gain 0.3, within 4 % of 1). VO measures the true motion (0.2-0.5 % of distance in the
/// SIL) where the EKF's own travel over an interval mostly repeats the kinematics it fused
/// before, so the EKF is not the reference here.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureScale {
    /// The running scale (VO over dead-reckoning length).
    pub scale: RadiusScale,
    track: Option<(u64, [f64; 3], bool)>,
    segment: Option<(u64, u64, [f64; 3])>,
}

impl CaptureScale {
    /// Nominal radius (scale 1), no capture yet.
    pub const fn new() -> Self {
        Self {
            scale: RadiusScale::new(),
            track: None,
            segment: None,
        }
    }

    /// A capture at `t_us`: the track since the previous capture, if clean, becomes the segment
    /// a VO pose between the two captures is compared with; a new track starts.
    pub fn capture(&mut self, t_us: u64) {
        self.segment = self
            .track
            .filter(|t| t.2)
            .map(|(t0, sum, _)| (t0, t_us, sum));
        self.track = Some((t_us, [0.0; 3], true));
    }

    /// One kinematic interval: the dead reckoning's unscaled step `step_n_m` (m, `N`);
    /// `usable`: fused by the slip gate with VO alive. Anything else (or a non-finite step)
    /// spoils the current capture interval.
    pub fn kinematic(&mut self, step_n_m: &[f64; 3], usable: bool) {
        let Some(t) = self.track.as_mut() else {
            return;
        };
        if !(usable && step_n_m.iter().all(|v| v.is_finite())) {
            t.2 = false;
            return;
        }
        for (s, d) in t.1.iter_mut().zip(step_n_m.iter()) {
            *s += d;
        }
    }

    /// The odometry was interrupted: the current capture interval cannot be compared.
    pub fn interrupt(&mut self) {
        if let Some(t) = self.track.as_mut() {
            t.2 = false;
        }
    }

    /// Learn from a VO translation `vo_trans_m` (any frame: only its length counts) between the
    /// captures at `t0_us` and `t1_us`, when they are exactly the last clean segment. Returns
    /// true when the pair was taken.
    pub fn learn(
        &mut self,
        c: &RadiusScaleConfig,
        t0_us: u64,
        t1_us: u64,
        vo_trans_m: &[f64; 3],
    ) -> bool {
        let Some((_, _, kin)) = self.segment.filter(|s| s.0 == t0_us && s.1 == t1_us) else {
            return false;
        };
        self.segment = None;
        let norm = |v: &[f64; 3]| crate::linalg::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        let (k, v) = (norm(&kin), norm(vo_trans_m));
        if !(k > 0.0 && v.is_finite()) {
            return false;
        }
        self.scale.add(c, k, v, true);
        true
    }
}

impl Default for CaptureScale {
    fn default() -> Self {
        Self::new()
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

    /// KIN-14: the dead reckoning's scale from VO. Wheels 2 % smaller than nominal: VO moves
    /// 0.98 of the dead reckoning's clean 0.25 m capture intervals (0.4 % noise on VO's
    /// length); the scale reaches 0.98 within 0.2 %. A spoilt interval, a pose that does not
    /// span the last segment, a non-finite step change nothing; the bound holds.
    #[test]
    fn kin_14_capture_scale_learns_from_vo() {
        let c = RadiusScaleConfig::default();
        let mut s = CaptureScale::new();
        let mut t = 0u64;
        s.capture(t);
        for i in 0..200u64 {
            for _ in 0..25 {
                s.kinematic(&[0.006, 0.008, 0.0], true);
            }
            let t1 = t + 2_500_000;
            s.capture(t1);
            let noise = if i % 2 == 0 { 1.004 } else { 0.996 };
            assert!(s.learn(&c, t, t1, &[0.0, 0.0, 0.25 * 0.98 * noise]));
            t = t1;
        }
        assert!((s.scale.scale - 0.98).abs() < 2e-3, "{}", s.scale.scale);
        let before = s;
        // A spoilt interval: no segment.
        s.kinematic(&[0.01, 0.0, 0.0], false);
        s.kinematic(&[0.01, 0.0, 0.0], true);
        s.capture(t + 1);
        assert!(!s.learn(&c, t, t + 1, &[0.5, 0.0, 0.0]));
        // A clean one, but the pose spans other captures.
        s.kinematic(&[0.25, 0.0, 0.0], true);
        s.capture(t + 2);
        assert!(!s.learn(&c, t, t + 2, &[0.5, 0.0, 0.0]));
        // Interrupted; non-finite.
        s.kinematic(&[0.25, 0.0, 0.0], true);
        s.interrupt();
        s.capture(t + 3);
        assert!(!s.learn(&c, t + 2, t + 3, &[0.5, 0.0, 0.0]));
        s.kinematic(&[f64::NAN, 0.0, 0.0], true);
        s.capture(t + 4);
        assert!(!s.learn(&c, t + 3, t + 4, &[0.5, 0.0, 0.0]));
        assert_eq!(s.scale, before.scale);
        // 30 % slip cannot teach more than the bound.
        for k in 4..104 {
            s.kinematic(&[0.25, 0.0, 0.0], true);
            s.capture(t + k + 1);
            s.learn(&c, t + k, t + k + 1, &[0.175, 0.0, 0.0]);
        }
        assert!((s.scale.scale - (1.0 - c.max_deviation)).abs() < 1e-12);
    }
}
