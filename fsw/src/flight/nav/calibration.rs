//! # Calibration: what the kinematics and VO teach each other over capture intervals
//!
//! Two estimates are learnt by comparing the wheels' motion with VO's over the same capture
//! interval, when every kinematic interval in it was fused by the slip gate with VO alive (a
//! "clean" interval):
//!
//! - the **VO translation boresight** ([`Boresight`]): the yaw by which VO's translation is
//!   rotated from the rover's true motion, removed from each VO pose before anything uses it;
//! - the **dead reckoning's wheel-radius scale** ([`CaptureScale`]): the ratio of VO's
//!   translation length to the 3D kinematic dead reckoning's (the contact-angle steps), which
//!   scales the dead reckoning's steps ([`CalibrationConfig::dr_scale`]).
//!
//! [`super::KinAiding`] feeds the kinematic intervals ([`Calibration::kinematic`],
//! [`Calibration::interrupt`]); [`super::VoAiding`] marks the captures
//! ([`Calibration::capture`]), corrects its poses ([`Calibration::correct`]) and teaches both
//! from the poses its gate accepted ([`Calibration::learn`]). Why two radius scales:
//! note 0021.

use super::boresight::{Boresight, BoresightConfig};
use super::radius::{CaptureScale, RadiusScaleConfig};
use crate::types::{RelativePose, Vec3};

/// Settings of the calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationConfig {
    /// The VO translation boresight estimate.
    pub boresight: BoresightConfig,
    /// Scale the 3D kinematic dead reckoning's steps by their own effective wheel-radius scale,
    /// learnt from VO (module doc). Without VO the scale stays 1.
    pub dr_scale: bool,
    /// Windows, gain and bounds of the dead reckoning's scale (1 m windows, within 4 %).
    pub dr_scale_estimate: RadiusScaleConfig,
}

/// The calibration component.
#[derive(Debug, Clone, Copy)]
pub struct Calibration {
    config: CalibrationConfig,
    boresight: Boresight,
    dr_scale: CaptureScale,
}

impl Calibration {
    /// Placeholder (the compile-time value of a static navigator before its initialisation).
    pub const EMPTY: Self = Self {
        config: CalibrationConfig {
            boresight: BoresightConfig {
                enabled: false,
                window: 0,
                min_step_m: 0.0,
                max_cross_slope: 0.0,
                max_tilt_step_rad: 0.0,
                max_angle_rad: 0.0,
                max_sample_rad: 0.0,
                min_samples: 0,
            },
            dr_scale: false,
            dr_scale_estimate: RadiusScaleConfig {
                window_m: 0.0,
                gain: 0.0,
                max_deviation: 0.0,
                vo_recent_cycles: 0,
            },
        },
        boresight: Boresight::new(),
        dr_scale: CaptureScale::new(),
    };

    /// Nothing learnt yet, with `config`.
    pub fn new(config: CalibrationConfig) -> Self {
        Self {
            config,
            boresight: Boresight::new(),
            dr_scale: CaptureScale::new(),
        }
    }

    /// A stereo capture at `t_us` closes the capture interval of both estimates.
    pub fn capture(&mut self, t_us: u64) {
        self.boresight.capture(t_us);
        self.dr_scale.capture(t_us);
    }

    /// The kinematic odometry was interrupted (an odometry error, an interval restarted): the
    /// current capture interval cannot be compared.
    pub fn interrupt(&mut self) {
        self.boresight.interrupt();
        self.dr_scale.interrupt();
    }

    /// One kinematic interval `rp` (the radius scale applied); `usable`: fused by the gate as
    /// slip-free with VO alive; `cross_slope`: `|sin|` of the cross slope; `dr_step_n_m`: the
    /// dead reckoning's unscaled step in `N` (m), `None` when unknown (spoils the interval).
    pub fn kinematic(
        &mut self,
        rp: &RelativePose,
        usable: bool,
        cross_slope: f64,
        dr_step_n_m: Option<Vec3>,
    ) {
        self.boresight
            .kinematic(&self.config.boresight, rp, usable, cross_slope);
        match dr_step_n_m {
            Some(k) => self.dr_scale.kinematic(&[k.x, k.y, k.z], usable),
            None => self.dr_scale.interrupt(),
        }
    }

    /// A raw VO pose with the estimated boresight removed ([`Boresight::correct`]).
    pub fn correct(&self, raw: &RelativePose) -> RelativePose {
        self.boresight.correct(&self.config.boresight, raw)
    }

    /// A VO pose the VO gate accepted teaches the boresight (from its `raw` translation) and
    /// the dead reckoning's scale (from the `corrected` one) when the wheels' motion over the
    /// same capture interval is clean.
    pub fn learn(&mut self, raw: &RelativePose, corrected: &RelativePose) {
        self.boresight.learn(&self.config.boresight, raw);
        let t = corrected.trans_0_1_m;
        self.dr_scale.learn(
            &self.config.dr_scale_estimate,
            corrected.t0_us,
            corrected.t1_us,
            &[t.x, t.y, t.z],
        );
    }

    /// The scale applied to the dead reckoning's steps (1 when [`CalibrationConfig::dr_scale`]
    /// is off) and the windows it was learnt from.
    pub fn dr_scale(&self) -> (f64, u32) {
        if self.config.dr_scale {
            (self.dr_scale.scale.scale, self.dr_scale.scale.updates)
        } else {
            (1.0, 0)
        }
    }

    /// The boresight removed from each VO pose (rad about `z_R`, positive from `x_R` towards
    /// `y_R`) and the samples it was learnt from.
    pub fn boresight(&self) -> (f64, u32) {
        (self.boresight.yaw_rad, self.boresight.updates)
    }
}
