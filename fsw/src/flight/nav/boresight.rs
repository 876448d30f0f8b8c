//! Online estimate of the VO translation boresight in yaw.
//!
//! VO (H04 sec. 2-3, eq. 11) measures the camera's motion and turns it into the rover frame `R`
//! with the nominal camera-to-rover rotation of the ground calibration. A mounting error of the
//! real head (and a principal-point error, which tilts every viewing ray the same way) rotates
//! the translation VO reports: a rover driving straight along `x_R` is reported as moving at a
//! small angle `a` to it, i.e. crabbing by `a` with no slip at all. The VO covariance (the ML
//! fit) does not contain this systematic error. The kinematic odometry says the opposite (no
//! lateral motion on firm ground), the IMU and the sun say nothing about it, and the filter
//! reconciles the two by rotating its heading a little at every VO update: the heading and the
//! velocity chase each other, the filter reads the steady rotation as a gyro `z` bias, and the
//! heading then drifts away from the sun. Measured on `flat-firm --no-slip`, seed 9: VO's
//! lateral translation error -3.4e-4 m per 0.1 m step (-0.19 deg, 1.7 of its own sigma) against
//! the truth, gyro `z` bias learnt 2.5e-4 rad/s (true below 1e-4), heading error -1.1 deg at
//! 200 s; with the simulator's camera errors switched off the same run learns no such bias.
//!
//! The boresight is observable from the two sensors themselves: over a capture interval in
//! which every kinematic interval was accepted by the slip gate on level ground (no crab: the
//! wheels' lateral constraint holds), the angle between VO's horizontal translation and the
//! wheels' (chained with the gyro rotations, in the rover frame of the first capture) is the
//! boresight plus noise. Its running mean (gain `1/n`, then `1/window`) is removed from each VO
//! translation (and its covariance rotated) before the VO gate and the fusion. The estimate is
//! bounded to [`BoresightConfig::max_angle_rad`] (ten times the mounting tolerance), and a
//! sample further than [`BoresightConfig::max_sample_rad`] from it is ignored (a VO outlier, an
//! undetected skid).
//!
//! Only the yaw is estimated: a pitch error of the head tilts VO's translation too, but the
//! filter's pitch is held by the accelerometer (gravity) and nothing in the kinematics pins the
//! rover's vertical motion (the kinematic `z` translation is not fused while VO is alive).

use crate::types::{Mat3, Mat6, Quat, RelativePose, Vec3};

/// Settings of the boresight estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoresightConfig {
    /// Estimate and apply the boresight (false: VO translations are fused as VO reports them).
    pub enabled: bool,
    /// Samples after which the running mean turns into exponential smoothing with gain
    /// `1/window`.
    pub window: u32,
    /// Shortest horizontal travel of a capture interval, by the wheels and by VO, m.
    pub min_step_m: f64,
    /// Largest `|sin|` of the cross slope (from the EKF attitude) at which an interval counts:
    /// a rover crabs on a cross slope.
    pub max_cross_slope: f64,
    /// Largest roll and pitch change of one kinematic interval (from its rotation), rad: on
    /// rough ground the wheels' direction over a capture interval is no clean reference (the
    /// contacts move under the axles as the suspension articulates), and learning there made
    /// the estimate wrong (`rough-kinematics`: EKF error 0.17 % before the boresight, 0.87 %
    /// learning on every interval).
    pub max_tilt_step_rad: f64,
    /// Bound of the estimate, rad.
    pub max_angle_rad: f64,
    /// Largest difference between a sample and the estimate, rad (larger: ignored).
    pub max_sample_rad: f64,
    /// Samples the estimate needs before it is applied: one sample is the angle between two
    /// noisy 0.1 m translations (about 2-3 mrad of noise each, the size of the boresight
    /// itself), so a mean of a few is noise (`rough-kinematics`, where the smoothness test lets
    /// few intervals through: 5.2 mrad learnt from 2 samples, EKF 0.15 -> 0.51 %).
    pub min_samples: u32,
}

impl Default for BoresightConfig {
    /// On (why: note 0018). Window 50 samples (about 50 s at one VO pose per 10 cm), 5 cm
    /// minimum travel, cross slope below 3 deg, roll and pitch under 2 mrad per kinematic
    /// interval, bound 1 deg (ten times the 0.1 deg mounting tolerance class of a surveyed
    /// head), samples within 1 deg of the estimate.
    fn default() -> Self {
        Self {
            enabled: true,
            window: 50,
            min_step_m: 0.05,
            max_cross_slope: 0.052,
            max_tilt_step_rad: 0.002,
            max_angle_rad: 0.017_5,
            max_sample_rad: 0.017_5,
            min_samples: 10,
        }
    }
}

/// The kinematic motion chained since a capture, in the rover frame at the capture.
#[derive(Debug, Clone, Copy, PartialEq)]
struct KinTrack {
    /// Capture time the track starts at, us.
    t0_us: u64,
    /// Rotation from the current interval end to the start frame.
    rot: Quat,
    /// Translation in the start frame, m.
    trans: Vec3,
    /// Every interval of the track was fused by the gate on level ground.
    clean: bool,
}

/// A completed track between two captures.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Segment {
    t0_us: u64,
    t1_us: u64,
    trans: Vec3,
}

/// The running boresight estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Boresight {
    /// Current estimate: the angle (rad, about `z_R`, positive from `x_R` towards `y_R`) by
    /// which VO's translation is rotated from the rover's true motion.
    pub yaw_rad: f64,
    /// Samples taken into the estimate.
    pub updates: u32,
    track: Option<KinTrack>,
    segment: Option<Segment>,
}

impl Default for Boresight {
    fn default() -> Self {
        Self::new()
    }
}

/// Signed angle (rad) from `a` to `b` in the `x, y` plane; `None` when either is shorter than
/// `min` or not finite.
fn planar_angle(a: &Vec3, b: &Vec3, min: f64) -> Option<f64> {
    let (na, nb) = (
        crate::linalg::sqrt(a.x * a.x + a.y * a.y),
        crate::linalg::sqrt(b.x * b.x + b.y * b.y),
    );
    if !(na >= min && nb >= min && na.is_finite() && nb.is_finite()) {
        return None;
    }
    let cross = a.x * b.y - a.y * b.x;
    let dot = a.x * b.x + a.y * b.y;
    let angle = libm::atan2(cross, dot);
    angle.is_finite().then_some(angle)
}

impl Boresight {
    /// No estimate yet (zero).
    pub const fn new() -> Self {
        Self {
            yaw_rad: 0.0,
            updates: 0,
            track: None,
            segment: None,
        }
    }

    /// A capture at `t_us`: the track since the previous capture becomes the segment a VO pose
    /// between the two captures is compared with, and a new track starts.
    pub fn capture(&mut self, t_us: u64) {
        self.segment = self.track.filter(|t| t.clean).map(|t| Segment {
            t0_us: t.t0_us,
            t1_us: t_us,
            trans: t.trans,
        });
        self.track = Some(KinTrack {
            t0_us: t_us,
            rot: Quat::identity(),
            trans: Vec3::zeros(),
            clean: true,
        });
    }

    /// One kinematic interval `rp` (rotation and translation of the wheels, the radius scale
    /// applied); `usable`: fused by the gate (no slip detected) with VO alive. `cross_slope`:
    /// `|sin|` of the cross slope from the EKF attitude.
    pub fn kinematic(
        &mut self,
        c: &BoresightConfig,
        rp: &RelativePose,
        usable: bool,
        cross_slope: f64,
    ) {
        let Some(t) = self.track.as_mut() else {
            return;
        };
        let level = cross_slope.is_finite() && cross_slope <= c.max_cross_slope;
        let finite = rp.trans_0_1_m.iter().all(|v| v.is_finite())
            && rp.rot_0_1.coords.iter().all(|v| v.is_finite());
        let tilt = rp.rot_0_1.scaled_axis();
        let smooth = crate::linalg::sqrt(tilt.x * tilt.x + tilt.y * tilt.y) <= c.max_tilt_step_rad;
        if !(usable && level && finite && smooth) {
            t.clean = false;
            return;
        }
        t.trans += t.rot.transform_vector(&rp.trans_0_1_m);
        t.rot *= rp.rot_0_1;
    }

    /// The kinematic track was broken (an odometry error, an interval restarted): the
    /// current capture interval cannot be compared.
    pub fn interrupt(&mut self) {
        if let Some(t) = self.track.as_mut() {
            t.clean = false;
        }
    }

    /// `vo` with the estimated boresight removed from its translation (rotated by `-yaw_rad`
    /// about `z_R`, covariance rotated alike). Unchanged when disabled or learnt from fewer
    /// than [`BoresightConfig::min_samples`] samples.
    pub fn correct(&self, c: &BoresightConfig, vo: &RelativePose) -> RelativePose {
        if !c.enabled || self.yaw_rad == 0.0 || self.updates < c.min_samples {
            return *vo;
        }
        let r: Mat3 = *Quat::from_axis_angle(&Vec3::z_axis(), -self.yaw_rad)
            .to_rotation_matrix()
            .matrix();
        let mut t = Mat6::identity();
        t.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        let mut out = *vo;
        out.trans_0_1_m = r * vo.trans_0_1_m;
        out.covariance = t * vo.covariance * t.transpose();
        out
    }

    /// Learn from `vo` (the raw VO pose, accepted by the VO gate) when it spans exactly the last
    /// completed clean segment. Returns true when a sample was taken.
    pub fn learn(&mut self, c: &BoresightConfig, vo: &RelativePose) -> bool {
        if !c.enabled {
            return false;
        }
        let Some(seg) = self
            .segment
            .filter(|s| s.t0_us == vo.t0_us && s.t1_us == vo.t1_us)
        else {
            return false;
        };
        self.segment = None;
        let Some(sample) = planar_angle(&seg.trans, &vo.trans_0_1_m, c.min_step_m) else {
            return false;
        };
        if libm::fabs(sample - self.yaw_rad) > c.max_sample_rad {
            return false;
        }
        let n = self.updates.saturating_add(1).min(c.window.max(1));
        let next = self.yaw_rad + (sample - self.yaw_rad) / f64::from(n);
        if !next.is_finite() {
            return false;
        }
        self.yaw_rad = crate::linalg::clamp(next, -c.max_angle_rad, c.max_angle_rad);
        self.updates = self.updates.saturating_add(1);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(t0: u64, t1: u64, trans: [f64; 3], yaw: f64) -> RelativePose {
        let mut covariance = Mat6::zeros();
        covariance[(3, 3)] = 1e-6;
        covariance[(4, 4)] = 4e-6;
        RelativePose {
            t0_us: t0,
            t1_us: t1,
            rot_0_1: Quat::from_euler_angles(0.0, 0.0, yaw),
            trans_0_1_m: Vec3::from(trans),
            covariance,
            observed: [true; 6],
        }
    }

    /// The estimate converges to the angle between VO's and the wheels' translations over clean
    /// segments, ignores unclean and mismatched ones, and the correction removes it.
    #[test]
    fn boresight_learns_the_vo_translation_angle() {
        let c = BoresightConfig {
            enabled: true,
            ..BoresightConfig::default()
        };
        let mut b = Boresight::new();
        let a = 3.3e-3;
        let mut t = 0u64;
        for k in 0..30u64 {
            b.capture(t);
            // Ten wheel intervals of 1 cm, the rover turning 1 mrad per interval.
            for _ in 0..10 {
                b.kinematic(&c, &pose(0, 1, [0.01, 0.0, 0.0], 1e-3), true, 0.0);
            }
            let t1 = t + 1_000_000;
            // The true motion over the capture interval, in the first frame, and VO's (rotated
            // by the boresight).
            let mut truth = Vec3::zeros();
            let mut q = Quat::identity();
            for _ in 0..10 {
                truth += q.transform_vector(&Vec3::new(0.01, 0.0, 0.0));
                q *= Quat::from_euler_angles(0.0, 0.0, 1e-3);
            }
            let noise = if k % 2 == 0 { 1e-4 } else { -1e-4 };
            let vo_t = Quat::from_euler_angles(0.0, 0.0, a + noise).transform_vector(&truth);
            let vo = pose(t, t1, vo_t.into(), 1e-2);
            b.capture(t1);
            assert!(b.learn(&c, &vo));
            // A second learn on the same segment takes nothing.
            assert!(!b.learn(&c, &vo));
            // Not applied before `min_samples` samples, applied from then on.
            let applied = b.correct(&c, &vo).trans_0_1_m != vo.trans_0_1_m;
            assert_eq!(applied, k + 1 >= u64::from(c.min_samples), "sample {k}");
            t = t1;
        }
        assert!((b.yaw_rad - a).abs() < 2e-5, "{}", b.yaw_rad);
        let raw = pose(0, 1, [0.1 * a.cos(), 0.1 * a.sin(), 0.0], 0.0);
        let fixed = b.correct(&c, &raw);
        assert!(fixed.trans_0_1_m.y.abs() < 1e-5, "{}", fixed.trans_0_1_m);
        // The lateral and forward variances swap through the rotation by a tiny angle only.
        assert!((fixed.covariance[(4, 4)] - 4e-6).abs() < 1e-9);
        // An interval the gate rejected (or on a cross slope) spoils its capture interval.
        let before = b.yaw_rad;
        b.capture(t);
        b.kinematic(&c, &pose(0, 1, [0.1, 0.0, 0.0], 0.0), false, 0.0);
        b.capture(t + 1);
        assert!(!b.learn(&c, &pose(t, t + 1, [0.1, 0.05, 0.0], 0.0)));
        b.kinematic(&c, &pose(0, 1, [0.1, 0.0, 0.0], 0.0), true, 0.1);
        b.capture(t + 2);
        assert!(!b.learn(&c, &pose(t + 1, t + 2, [0.1, 0.05, 0.0], 0.0)));
        // A VO pose between other captures, a too short step, an outlier: ignored.
        b.kinematic(&c, &pose(0, 1, [0.1, 0.0, 0.0], 0.0), true, 0.0);
        b.capture(t + 3);
        assert!(!b.learn(&c, &pose(t + 1, t + 3, [0.1, 0.0, 0.0], 0.0)));
        b.kinematic(&c, &pose(0, 1, [0.1, 0.0, 0.0], 0.0), true, 0.0);
        b.capture(t + 4);
        assert!(!b.learn(&c, &pose(t + 3, t + 4, [0.1, 0.01, 0.0], 0.0)));
        b.kinematic(&c, &pose(0, 1, [0.01, 0.0, 0.0], 0.0), true, 0.0);
        b.capture(t + 5);
        assert!(!b.learn(&c, &pose(t + 4, t + 5, [0.01, 0.0, 0.0], 0.0)));
        assert_eq!(b.yaw_rad, before);
        // Disabled: no correction, no learning.
        let off = BoresightConfig {
            enabled: false,
            ..c
        };
        assert_eq!(b.correct(&off, &raw), raw);
    }
}
