//! Vehicle odometry: forward kinematics (eq. 15) integrated over an interval into a
//! [`RelativePose`] with a covariance propagated from encoder noise (the measurement the EKF
//! gates with a 5-dof Mahalanobis test, H04 sec. 4, eq. 46).
//!
//! Each pair of successive joint readings gives joint increments (drive angles, rocker and
//! bogie angles); eq. 15 is linear in the rates, so the same least squares applied to the
//! increments at the mid-point configuration gives the body displacement of the step
//! `[dp (m); dphi (rad)]` in the rover frame at the step start. Steps compose as
//! `T_0,k+1 = T_0,k * exp(step)`. The covariance over `[delta_theta; delta_p]` (perturbation
//! in `R0`, the [`RelativePose`] convention) propagates as `P' = F P F^T + G Q G^T` with
//! `F = [[I, 0], [-[R dp]x, I]]`, `G = diag(R, R)` and `Q` the step covariance from the
//! encoder noise mapped through the least squares.
//!
//! With [`OdometryConfig::contact_angles`] the step comes from the contact-angle estimator
//! ([`super::contact`], V99 sec. 6): the body displacement and the six contact angles are
//! solved jointly (optionally with the gyro's rotation increment,
//! [`KinematicOdometry::update_with_gyro`]); the angles carry over from step to step and the covariance is the same
//! encoder-noise map evaluated at the solved angles (contact points `c_i(delta_i)`, drive
//! columns `r t_i(delta_i)`; the angles themselves are treated as known there).

use super::contact::{contact_jacobians, contact_step_frames, ContactConfig};
use super::forward::{contact_velocities, ContactLeastSquares};
use super::geometry::{check_suspension, wheel_frames_trusted, RoverGeometry};
use super::jacobian::WheelJacobian;
use super::{KinematicsError, SuspensionRates, SuspensionState};
use crate::types::{Mat3, Mat6, Quat, RelativePose, Vec3, Vec6};
use rover_hal::{JointState, WHEEL_COUNT};

/// Noise model of the vehicle odometry (standard deviations per joint-reading step).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryConfig {
    /// Noise of each drive-angle increment, rad (quantisation and read noise).
    pub drive_increment_noise_rad: f64,
    /// Additional drive noise proportional to the increment (model error of the no-slip,
    /// fixed-contact assumptions), dimensionless fraction of `|delta_theta|`.
    pub drive_fraction: f64,
    /// Noise of the steering angle, rad.
    pub steer_noise_rad: f64,
    /// Noise of each rocker or bogie angle increment, rad.
    pub suspension_increment_noise_rad: f64,
    /// Uncertainty of the effective wheel radius common to all wheels (manufacturing, tyre and
    /// grouser wear, sinkage on firm ground), 1-sigma fraction of the radius. A systematic
    /// scale: one perturbation of all wheels' rolling travel together.
    pub radius_scale_sigma: f64,
    /// Uncertainty of each wheel's own radius relative to the others (manufacturing, wear),
    /// 1-sigma fraction: one perturbation per wheel of its rolling travel, so that unequal
    /// radii (a systematic yaw rate, Borenstein & Feng 1996) are inside the model.
    pub wheel_radius_sigma: f64,
    /// Model error of the fixed-contact assumption while the suspension articulates: each
    /// wheel's contact velocity is uncertain along its rolling, lateral and normal directions by this
    /// fraction of the wheel's displacement relative to the body from the rocker/bogie
    /// increments averaged over the last [`ARTICULATION_WINDOW`] steps (a wheel climbing or
    /// descending relative to the body rolls on a contact point away from below its axle, V99
    /// sec. 6, which eq. 15 does not model).
    pub articulation_fraction: f64,
    /// Components of `[delta_theta; delta_p]` reported as observed. Default: all but the
    /// vertical translation `delta_p_z` (H04: 5 of 6 DOF; the vertical motion of the contacts
    /// is assumed, not measured, see `docs/kinematics.md`).
    pub observed: [bool; 6],
    /// Estimate the wheel/terrain contact angles with the body displacement (V99 sec. 6,
    /// [`super::contact`]). Default `false`: the contacts are assumed below the axles (eq. 15).
    pub contact_angles: bool,
    /// Also run the contact-angle estimator as a diagnostic: its translation is available from
    /// [`KinematicOdometry::contact_translation_m`] (the navigator's 3D kinematic dead
    /// reckoning) while the relative pose stays eq. 15. Ignored with `contact_angles`.
    pub contact_translation: bool,
    /// Tuning of the contact-angle estimator (used with `contact_angles` or
    /// `contact_translation`).
    pub contact: ContactConfig,
}

impl Default for OdometryConfig {
    /// The calibrated flight profile (`docs/kinematics.md`, "Noise model and its
    /// calibration"). The sensor terms start from the encoders' data (a 4096-count drive
    /// encoder: quantisation 1.53 mrad, 0.63 mrad per increment; 1 mrad steering readings;
    /// 12-bit rocker/bogie potentiometers with 1 mrad noise: 1.55 mrad per increment), the
    /// systematic terms from the wheel tolerance (2 % effective radius) and the articulation
    /// model error; all five noise terms were then scaled by one factor, 0.85, so that the gate's
    /// false-alarm rate without slip is near its 5 % design on firm flat ground while staying
    /// under 10 % on firm rough ground (calibration seeds 11-12, not the SIL seeds).
    fn default() -> Self {
        const CALIBRATION: f64 = 0.85;
        OdometryConfig {
            drive_increment_noise_rad: 0.63e-3 * CALIBRATION,
            drive_fraction: 0.005 * CALIBRATION,
            steer_noise_rad: 1.0e-3 * CALIBRATION,
            suspension_increment_noise_rad: 1.55e-3 * CALIBRATION,
            radius_scale_sigma: 0.02 * CALIBRATION,
            wheel_radius_sigma: 0.005 * CALIBRATION,
            articulation_fraction: 1.5,
            observed: [true, true, true, true, true, false],
            contact_angles: false,
            contact_translation: false,
            contact: ContactConfig::default(),
        }
    }
}

/// Joint steps over which the suspension's articulation rate is averaged for the
/// [`OdometryConfig::articulation_fraction`] model error (1 s at the 20 Hz RG2 rate: long enough
/// that the potentiometer noise of two readings is small against the terrain's articulation,
/// short enough to follow the terrain).
pub const ARTICULATION_WINDOW: usize = 20;

/// Largest gap between two joint readings kept in the articulation window, us.
const ARTICULATION_MAX_GAP_US: u64 = 500_000;

/// The last [`ARTICULATION_WINDOW`]` + 1` suspension readings `[rocker, bogie 1, bogie 2]`
/// (rad), a ring.
#[derive(Debug, Clone, Copy)]
struct SuspensionWindow {
    angles: [[f64; 3]; ARTICULATION_WINDOW + 1],
    head: usize,
    len: usize,
    last_t_us: u64,
}

impl SuspensionWindow {
    const fn new() -> Self {
        Self {
            angles: [[0.0; 3]; ARTICULATION_WINDOW + 1],
            head: 0,
            len: 0,
            last_t_us: 0,
        }
    }

    /// Adds a reading (finite, checked by the caller); a gap or time going backwards restarts
    /// the window.
    fn push(&mut self, j: &JointState) {
        let continuous = self.len > 0
            && j.t_us > self.last_t_us
            && j.t_us - self.last_t_us <= ARTICULATION_MAX_GAP_US;
        if !continuous {
            self.len = 0;
        }
        let n = ARTICULATION_WINDOW + 1;
        self.head = (self.head + 1) % n;
        if let Some(slot) = self.angles.get_mut(self.head) {
            *slot = [j.rocker_rad, j.bogie_rad[0], j.bogie_rad[1]];
        }
        self.len = (self.len + 1).min(n);
        self.last_t_us = j.t_us;
    }

    /// Mean suspension increment per joint step over the window (rad per step), or `None`
    /// before the window holds two readings.
    fn mean_increment(&self) -> Option<SuspensionRates> {
        if self.len < 2 {
            return None;
        }
        let n = ARTICULATION_WINDOW + 1;
        let oldest = (self.head + n + 1 - self.len) % n;
        let (new, old) = (self.angles.get(self.head)?, self.angles.get(oldest)?);
        let steps = (self.len - 1) as f64;
        Some(SuspensionRates {
            rocker_rad_s: (new[0] - old[0]) / steps,
            bogie_rad_s: [(new[1] - old[1]) / steps, (new[2] - old[2]) / steps],
        })
    }
}

/// Integrates forward kinematics over an interval (vehicle odometry, H04 sec. 3-4).
#[derive(Debug, Clone)]
pub struct KinematicOdometry {
    geometry: RoverGeometry,
    config: OdometryConfig,
    last: Option<JointState>,
    t0_us: u64,
    rot_0_k: Quat,
    trans_0_k_m: Vec3,
    covariance: Mat6,
    contact_rad: [f64; WHEEL_COUNT],
    window_rad: [f64; WHEEL_COUNT],
    window: SuspensionWindow,
    contact_trans_0_k_m: Vec3,
    axles_m: [Vec3; WHEEL_COUNT],
    angle_window: Option<AngleWindow>,
}

/// The joint readings since the last contact-angle update ([`ContactConfig::window_travel_m`]).
#[derive(Debug, Clone, Copy)]
struct AngleWindow {
    /// Reading at the window's start.
    start: JointState,
    /// Time of the last reading added, us.
    last_t_us: u64,
    /// Sum of the steps' gyro rotation increments, rad, `R` (`None` if a step had none).
    gyro_rad: Option<Vec3>,
    /// Wheels valid in every step of the window.
    valid: [bool; WHEEL_COUNT],
}

impl AngleWindow {
    fn new(start: &JointState) -> Self {
        AngleWindow {
            start: *start,
            last_t_us: start.t_us,
            gyro_rad: Some(Vec3::zeros()),
            valid: [true; WHEEL_COUNT],
        }
    }
}

fn skew(v: &Vec3) -> Mat3 {
    Mat3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The body step of one joint step `[dp; dphi]`, the wheel Jacobians and the least squares it
/// was solved with, and the contact angles (rad) it used.
type ContactParts = (
    Vec6,
    [WheelJacobian; WHEEL_COUNT],
    ContactLeastSquares,
    [f64; WHEEL_COUNT],
);

/// The suspension and steering state halfway between readings `a` and `b` (steering 0 for the
/// wheels not `valid`), rad: the configuration a step's increments are linearised at.
fn mid_state(a: &JointState, b: &JointState, valid: &[bool; WHEEL_COUNT]) -> SuspensionState {
    let mid = |x: f64, y: f64| 0.5 * (x + y);
    SuspensionState {
        rocker_rad: mid(a.rocker_rad, b.rocker_rad),
        bogie_rad: [
            mid(a.bogie_rad[0], b.bogie_rad[0]),
            mid(a.bogie_rad[1], b.bogie_rad[1]),
        ],
        steer_rad: core::array::from_fn(|i| {
            let ok = valid.get(i).copied().unwrap_or(false);
            match (a.steer_angle_rad.get(i), b.steer_angle_rad.get(i)) {
                (Some(x), Some(y)) if ok => mid(*x, *y),
                _ => 0.0,
            }
        }),
    }
}

/// The rocker and bogie increments from reading `a` to reading `b`, rad (in the fields named
/// `_rad_s`).
fn suspension_increments(a: &JointState, b: &JointState) -> SuspensionRates {
    SuspensionRates {
        rocker_rad_s: b.rocker_rad - a.rocker_rad,
        bogie_rad_s: [
            b.bogie_rad[0] - a.bogie_rad[0],
            b.bogie_rad[1] - a.bogie_rad[1],
        ],
    }
}

fn finite_reading(j: &JointState) -> bool {
    let angles = [j.rocker_rad, j.bogie_rad[0], j.bogie_rad[1]];
    let wheels_ok = j
        .drive_angle_rad
        .iter()
        .zip(j.steer_angle_rad.iter())
        .zip(j.wheel_valid.iter())
        .all(|((d, s), ok)| !*ok || (d.is_finite() && s.is_finite()));
    wheels_ok && angles.iter().all(|a| a.is_finite())
}

impl KinematicOdometry {
    /// A new integrator; call [`Self::start`] before [`Self::update`].
    pub const fn new(geometry: RoverGeometry, config: OdometryConfig) -> Self {
        KinematicOdometry {
            geometry,
            config,
            last: None,
            t0_us: 0,
            rot_0_k: crate::types::QUAT_IDENTITY,
            trans_0_k_m: crate::types::VEC3_ZERO,
            covariance: crate::types::zero_matrix::<6, 6>(),
            contact_rad: [0.0; WHEEL_COUNT],
            window_rad: [0.0; WHEEL_COUNT],
            window: SuspensionWindow::new(),
            contact_trans_0_k_m: crate::types::VEC3_ZERO,
            axles_m: [crate::types::VEC3_ZERO; WHEEL_COUNT],
            angle_window: None,
        }
    }

    /// Current contact-angle estimates `delta_i`, rad, index `wheel - 1` (in each wheel plane,
    /// positive = contact ahead of the axle; V99 sec. 6). All zero unless
    /// [`OdometryConfig::contact_angles`] or [`OdometryConfig::contact_translation`] is set. They
    /// persist across intervals ([`Self::start`]).
    pub fn contact_angles_rad(&self) -> [f64; WHEEL_COUNT] {
        self.contact_rad
    }

    /// The contact angles estimated over windows of travel
    /// ([`ContactConfig::window_travel_m`]), rad, index `wheel - 1`, same convention as
    /// [`Self::contact_angles_rad`]: less noisy and lagging by up to one window, for the
    /// rough-terrain inverse kinematics. Equal to [`Self::contact_angles_rad`] when the
    /// window distance is 0.
    pub fn windowed_contact_angles_rad(&self) -> [f64; WHEEL_COUNT] {
        self.window_rad
    }

    /// Axle centres (origins of the contact frames `C_i`, m, `R`, index `wheel - 1`) at the
    /// suspension state of the last applied step (the mean of its two readings; H04 Table 1,
    /// eq. 12). All zero before the first step. For the track memory of the 3D kinematic dead
    /// reckoning ([`super::track`]).
    pub fn axle_centres_m(&self) -> [Vec3; WHEEL_COUNT] {
        self.axles_m
    }

    /// Reset the contact-angle estimates to 0 (contacts below the axles).
    pub fn reset_contact_angles(&mut self) {
        self.contact_rad = [0.0; WHEEL_COUNT];
        self.window_rad = [0.0; WHEEL_COUNT];
        self.angle_window = None;
    }

    /// Start a new interval at the reading `joints` (time `t0 = joints.t_us`). Errors: the
    /// reading is non-finite or its suspension encoders are invalid (the interval stays
    /// unstarted).
    pub fn start(&mut self, joints: &JointState) -> Result<(), KinematicsError> {
        self.last = None;
        if !joints.suspension_valid {
            return Err(KinematicsError::SuspensionInvalid);
        }
        if !finite_reading(joints) {
            return Err(KinematicsError::NonFinite);
        }
        self.last = Some(*joints);
        if self.window.last_t_us != joints.t_us {
            self.window.push(joints);
        }
        self.t0_us = joints.t_us;
        self.rot_0_k = Quat::identity();
        self.trans_0_k_m = Vec3::zeros();
        self.contact_trans_0_k_m = Vec3::zeros();
        self.covariance = Mat6::zeros();
        Ok(())
    }

    /// Add the step from the previous reading to `joints`. A wheel invalid in either reading is
    /// dropped for this step. On error the step is not applied; errors other than
    /// [`KinematicsError::TimeNotAdvancing`] also end the interval (call [`Self::start`]).
    pub fn update(&mut self, joints: &JointState) -> Result<(), KinematicsError> {
        self.update_with_gyro(joints, None)
    }

    /// [`Self::update`] with the body rotation increment measured by the gyro over the same
    /// step, `gyro_rad` (rad, rotation vector in `R` at the step start). It is used only with
    /// [`OdometryConfig::contact_angles`] (then the rotation of the step is the gyro's and the
    /// kinematics solve the translation and the contact angles); otherwise it is ignored and
    /// the step is exactly [`Self::update`]'s. A non-finite gyro value is an error
    /// ([`KinematicsError::NonFinite`], ends the interval) when it is used.
    pub fn update_with_gyro(
        &mut self,
        joints: &JointState,
        gyro_rad: Option<Vec3>,
    ) -> Result<(), KinematicsError> {
        let prev = self.last.ok_or(KinematicsError::NotStarted)?;
        if joints.t_us <= prev.t_us {
            return Err(KinematicsError::TimeNotAdvancing);
        }
        let result = self.step(&prev, joints, gyro_rad);
        self.last = match result {
            Ok(()) => Some(*joints),
            Err(_) => {
                self.angle_window = None;
                None
            }
        };
        result
    }

    fn step(
        &mut self,
        prev: &JointState,
        cur: &JointState,
        gyro_rad: Option<Vec3>,
    ) -> Result<(), KinematicsError> {
        if !(prev.suspension_valid && cur.suspension_valid) {
            return Err(KinematicsError::SuspensionInvalid);
        }
        if !finite_reading(cur) {
            return Err(KinematicsError::NonFinite);
        }
        let valid: [bool; WHEEL_COUNT] =
            core::array::from_fn(|i| prev.wheel_valid[i] && cur.wheel_valid[i]);
        let state = mid_state(prev, cur, &valid);
        check_suspension(&self.geometry, &state)?;
        let increments = suspension_increments(prev, cur);
        let drive: [f64; WHEEL_COUNT] = core::array::from_fn(|i| {
            if valid[i] {
                cur.drive_angle_rad[i] - prev.drive_angle_rad[i]
            } else {
                0.0
            }
        });
        let frames = wheel_frames_trusted(&self.geometry, &state);
        let radius = self.geometry.wheel_radius_m;
        let use_contacts = self.config.contact_angles || self.config.contact_translation;
        // The contact-angle step (V99 sec. 6): the measurement with `contact_angles`, the
        // diagnostic translation with `contact_translation` (then a failure only skips it).
        let contact = if use_contacts {
            match self.contact_solution(&frames, &increments, &drive, &valid, gyro_rad) {
                Ok(c) => Some(c),
                Err(e) if self.config.contact_angles => return Err(e),
                Err(_) => None,
            }
        } else {
            None
        };
        // The smoothed angles over windows of travel (for the inverse kinematics).
        let windowed = (use_contacts && self.config.contact.window_travel_m > 0.0)
            .then(|| self.window_angles(prev, cur, &valid, gyro_rad));
        // Borrowed from the contact solution when it is the measurement (copying its Jacobians
        // and least squares costs about 1,000 instructions per step on the rover CPU).
        let fallback;
        let (step, jacobians, lsq) = match (&contact, self.config.contact_angles) {
            (Some((step, jacobians, lsq, _)), true) => (*step, jacobians, lsq),
            _ => {
                let jacobians = frames.map(|f| WheelJacobian::from_frames(&f, radius));
                let points = frames.map(|f| f.contact_point_m);
                let lsq = ContactLeastSquares::new(&points, &valid)?;
                let step = lsq.solve(&contact_velocities(&jacobians, &increments, &drive));
                fallback = (jacobians, lsq);
                (step, &fallback.0, &fallback.1)
            }
        };
        if step.iter().any(|x| !x.is_finite()) {
            return Err(KinematicsError::NonFinite);
        }
        self.window.push(cur);
        let articulation = self.window.mean_increment().unwrap_or(increments);
        let q = self.step_covariance(lsq, jacobians, &frames, &drive, &articulation, &valid);
        if let Some((c_step, _, _, _)) = &contact {
            if self.config.contact_translation && c_step.iter().all(|x| x.is_finite()) {
                // The contact-angle translation in the interval's start frame, rotated like the
                // measurement's own step.
                let rot = self.rot_0_k.to_rotation_matrix().into_inner();
                let half = Quat::from_scaled_axis(Vec3::new(step[3], step[4], step[5]) * 0.5);
                self.contact_trans_0_k_m +=
                    rot * (half * Vec3::new(c_step[0], c_step[1], c_step[2]));
            }
        }
        self.compose(&step, &q);
        self.axles_m = frames.map(|f| f.contact.pos);
        if let Some((_, _, _, angles)) = contact {
            self.contact_rad = angles;
        }
        match windowed {
            Some((angles, window)) => {
                self.window_rad = angles;
                self.angle_window = Some(window);
            }
            None => self.window_rad = self.contact_rad,
        }
        Ok(())
    }

    /// The windowed contact angles ([`Self::windowed_contact_angles_rad`]) after the step
    /// `prev` -> `cur`: the step joins the current window (a new one starts
    /// at `prev` if the last did not end there); once the valid wheels' mean rim travel over the
    /// window reaches the window distance, the angles are estimated from the window's joint
    /// increments at its mid-point configuration (its own wheel frames: the step's frames
    /// instead, half a window of articulation away, would save 0.8 KB of the deepest stack path
    /// but the estimate is then linearised off its data), with the sum of its gyro increments
    /// ([`contact_step_frames`], V99 sec. 6) and the current windowed angles as the prior, taken
    /// relative to their mean (`ContactConfig::zero_mean`), and a new window starts at `cur`.
    /// A window whose estimate fails (fewer than three wheels valid throughout, a singular
    /// system) is dropped and the angles hold. Returns the angles and the window to keep.
    fn window_angles(
        &self,
        prev: &JointState,
        cur: &JointState,
        valid: &[bool; WHEEL_COUNT],
        gyro_rad: Option<Vec3>,
    ) -> ([f64; WHEEL_COUNT], AngleWindow) {
        let mut window = match self.angle_window {
            Some(w) if w.last_t_us == prev.t_us => w,
            _ => AngleWindow::new(prev),
        };
        window.last_t_us = cur.t_us;
        window.gyro_rad = match (window.gyro_rad, gyro_rad) {
            (Some(a), Some(b)) => Some(a + b),
            _ => None,
        };
        for (w, v) in window.valid.iter_mut().zip(valid.iter()) {
            *w = *w && *v;
        }
        let start = &window.start;
        let drive: [f64; WHEEL_COUNT] = core::array::from_fn(|i| {
            let ok = window.valid.get(i).copied().unwrap_or(false);
            match (cur.drive_angle_rad.get(i), start.drive_angle_rad.get(i)) {
                (Some(c), Some(s)) if ok => c - s,
                _ => 0.0,
            }
        });
        let radius = self.geometry.wheel_radius_m;
        let (mut travel, mut n) = (0.0, 0.0);
        for (d, ok) in drive.iter().zip(window.valid.iter()) {
            if *ok {
                travel += libm::fabs(radius * d);
                n += 1.0;
            }
        }
        if n < 1.0 || travel / n < self.config.contact.window_travel_m {
            return (self.window_rad, window);
        }
        let state = mid_state(start, cur, &window.valid);
        let increments = suspension_increments(start, cur);
        let next = AngleWindow::new(cur);
        if check_suspension(&self.geometry, &state).is_err() {
            return (self.window_rad, next);
        }
        let frames = wheel_frames_trusted(&self.geometry, &state);
        match contact_step_frames(
            &self.geometry,
            &frames,
            &increments,
            &drive,
            &window.valid,
            window.gyro_rad,
            &self.window_rad,
            &self.config.contact,
            false,
        ) {
            Ok(sol) => (self.zero_mean(sol.contact_angles_rad, &window.valid), next),
            Err(_) => (self.window_rad, next),
        }
    }

    /// `angles` relative to their mean over the valid wheels with
    /// [`ContactConfig::zero_mean`], else unchanged.
    fn zero_mean(
        &self,
        mut angles: [f64; WHEEL_COUNT],
        valid: &[bool; WHEEL_COUNT],
    ) -> [f64; WHEEL_COUNT] {
        let (mut sum, mut n) = (0.0, 0.0);
        for (a, v) in angles.iter().zip(valid.iter()) {
            if *v {
                sum += a;
                n += 1.0;
            }
        }
        if self.config.contact.zero_mean && n > 0.0 {
            let mean = sum / n;
            for a in angles.iter_mut() {
                *a -= mean;
            }
        }
        angles
    }

    /// The body step `[dp; dphi]` of one joint step as the eq. 15 least squares along the
    /// contact tangents at `angles` (rad), with its Jacobians and least squares; returns the
    /// angles with them.
    fn step_along(
        &self,
        frames: &[super::geometry::WheelFrames; WHEEL_COUNT],
        increments: &SuspensionRates,
        drive: &[f64; WHEEL_COUNT],
        valid: &[bool; WHEEL_COUNT],
        angles: [f64; WHEEL_COUNT],
    ) -> Result<ContactParts, KinematicsError> {
        let jacobians = contact_jacobians(frames, self.geometry.wheel_radius_m, &angles);
        let lsq = ContactLeastSquares::new(&jacobians.map(|j| j.contact_point_m), valid)?;
        let step = lsq.solve(&contact_velocities(&jacobians, increments, drive));
        Ok((step, jacobians, lsq, angles))
    }

    /// The contact-angle body step of one joint step (V99 sec. 6, [`super::contact`]): the
    /// angles are estimated with the gyro rotation, taken relative to their mean
    /// (`ContactConfig::zero_mean`), and the body step is the eq. 15 least squares along the
    /// resulting contact tangents. Returns the step `[dp; dphi]`, the Jacobians, the least
    /// squares and the angles.
    fn contact_solution(
        &self,
        frames: &[super::geometry::WheelFrames; WHEEL_COUNT],
        increments: &SuspensionRates,
        drive: &[f64; WHEEL_COUNT],
        valid: &[bool; WHEEL_COUNT],
        gyro_rad: Option<Vec3>,
    ) -> Result<ContactParts, KinematicsError> {
        let sol = contact_step_frames(
            &self.geometry,
            frames,
            increments,
            drive,
            valid,
            gyro_rad,
            &self.contact_rad,
            &self.config.contact,
            false,
        )?;
        // The common mode of the angles (all tangents tilted alike) is the direction of the
        // body's motion in its own x-z plane, which the wheels barely observe (the same rim
        // travels fit a body moving along x or climbing along a tilted x): with
        // `ContactConfig::zero_mean` the angles are taken relative to their mean over the
        // valid wheels, and the body step is the eq. 15 least squares along the resulting
        // contact tangents.
        let angles = self.zero_mean(sol.contact_angles_rad, valid);
        let (step, jacobians, lsq, angles) =
            self.step_along(frames, increments, drive, valid, angles)?;
        let step = if self.config.contact.zero_mean {
            step
        } else {
            sol.body_step
        };
        Ok((step, jacobians, lsq, angles))
    }

    /// Translation of the current interval from the contact-angle step (m, `R` at the interval
    /// start), accumulated with [`OdometryConfig::contact_translation`]; the measurement's own
    /// translation otherwise. A diagnostic for the 3D kinematic dead reckoning: the
    /// measurement fused by the EKF stays eq. 15 unless [`OdometryConfig::contact_angles`].
    pub fn contact_translation_m(&self) -> Vec3 {
        if self.config.contact_translation && !self.config.contact_angles {
            self.contact_trans_0_k_m
        } else {
            self.trans_0_k_m
        }
    }

    /// Covariance of the step `[dphi; dp]` (in the step-start frame) from the encoder noise.
    fn step_covariance(
        &self,
        lsq: &ContactLeastSquares,
        jacobians: &[WheelJacobian; WHEEL_COUNT],
        frames: &[super::geometry::WheelFrames; WHEEL_COUNT],
        drive: &[f64; WHEEL_COUNT],
        articulation_rate: &SuspensionRates,
        valid: &[bool; WHEEL_COUNT],
    ) -> Mat6 {
        let c = &self.config;
        let mut q = Mat6::zeros();
        // The patterns that perturb one wheel only: the step is `M_i b_i` (`wheel_map`), so
        // their sum `sum sigma^2 (M_i b)(M_i b)'` is `M_i S_i M_i'` with the wheel's 3x3
        // `S_i = sum sigma^2 b b'` (one 6x3 map per wheel instead of one solve and one 6x6
        // outer product per pattern).
        let articulation = contact_velocities(jacobians, articulation_rate, &[0.0; WHEEL_COUNT]);
        let mut travels = [Vec3::zeros(); WHEEL_COUNT];
        for i in 0..WHEEL_COUNT {
            if !valid[i] {
                continue;
            }
            let drive_dir = jacobians[i].drive;
            let travel = drive_dir * drive[i];
            travels[i] = travel;
            // Drive encoder increment.
            let sigma = c.drive_increment_noise_rad + c.drive_fraction * libm::fabs(drive[i]);
            let mut s_i = drive_dir * drive_dir.transpose() * (sigma * sigma);
            // Steering error turns the rolling direction about the steering axis.
            let turned = frames[i].steer_axis.cross(&drive_dir) * drive[i];
            s_i += turned * turned.transpose() * (c.steer_noise_rad * c.steer_noise_rad);
            // The wheel's own radius.
            s_i += travel * travel.transpose() * (c.wheel_radius_sigma * c.wheel_radius_sigma);
            // Articulation: the wheel's mean displacement per step relative to the body from
            // the suspension, over the articulation window, along, across and normal to its
            // rolling direction.
            let moved = crate::linalg::norm(&articulation[i]);
            let n = crate::linalg::norm(&drive_dir);
            if moved > 0.0 && n > 0.0 {
                let along = drive_dir / n;
                let lateral = frames[i].steer_axis.cross(&along);
                let normal = along.cross(&lateral);
                let sigma = c.articulation_fraction * moved;
                s_i += (along * along.transpose()
                    + lateral * lateral.transpose()
                    + normal * normal.transpose())
                    * (sigma * sigma);
            }
            let m = lsq.wheel_map(i);
            // `M_i S_i M_i'` is symmetric: its upper triangle only, mirrored.
            let ms = m * s_i;
            for r in 0..6 {
                for c in r..6 {
                    let mut v = 0.0;
                    for k in 0..3 {
                        v += ms[(r, k)] * m[(c, k)];
                    }
                    q[(r, c)] += v;
                    if c != r {
                        q[(c, r)] += v;
                    }
                }
            }
        }
        // Sensitivity column of the step for one contact-velocity pattern that perturbs several
        // wheels; the outer product's upper triangle, mirrored.
        let mut add = |b: &[Vec3; WHEEL_COUNT], sigma: f64| {
            let t = lsq.solve(b);
            let col = [t[3], t[4], t[5], t[0], t[1], t[2]];
            let s2 = sigma * sigma;
            for r in 0..6 {
                let cr = col[r] * s2;
                for c in r..6 {
                    let v = cr * col[c];
                    q[(r, c)] += v;
                    if c != r {
                        q[(c, r)] += v;
                    }
                }
            }
        };
        // Common radius scale: all wheels' rolling travel together.
        add(&travels, c.radius_scale_sigma);
        for k in 0..3 {
            let unit = SuspensionRates {
                rocker_rad_s: if k == 0 { 1.0 } else { 0.0 },
                bogie_rad_s: [
                    if k == 1 { 1.0 } else { 0.0 },
                    if k == 2 { 1.0 } else { 0.0 },
                ],
            };
            let b = contact_velocities(jacobians, &unit, &[0.0; WHEEL_COUNT]);
            let masked: [Vec3; WHEEL_COUNT] =
                core::array::from_fn(|i| if valid[i] { b[i] } else { Vec3::zeros() });
            add(&masked, c.suspension_increment_noise_rad);
        }
        q
    }

    fn compose(&mut self, step: &Vec6, q: &Mat6) {
        let dp = Vec3::new(step[0], step[1], step[2]);
        let dphi = Vec3::new(step[3], step[4], step[5]);
        let rot = self.rot_0_k.to_rotation_matrix().into_inner();
        // Mid-step rotation for the translation (second order in the step).
        let half = Quat::from_scaled_axis(dphi * 0.5);
        let dp_0 = rot * (half * dp);
        // `P <- F P F' + G Q G'` with `F = [[I, 0], [S, I]]`, `S = -[dp_0]x`, and
        // `G = diag(C, C)`, by 3x3 blocks (`P = [[A, B], [B', D]]`): `F P F'` is
        // `[[A, A S' + B], [S A + B', S A S' + S B + B' S' + D]]`.
        let s = -skew(&dp_0);
        let p = &self.covariance;
        let (a, b, d) = (block3(p, 0, 0), block3(p, 0, 3), block3(p, 3, 3));
        let sa = s * a;
        let sb = s * b;
        let top_right = sa.transpose() + b;
        let bottom = sa * s.transpose() + sb + sb.transpose() + d;
        let block = |r: usize, c: usize| block3(q, r, c);
        let rt = rot.transpose();
        let mut out = Mat6::zeros();
        out.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(a + rot * block(0, 0) * rt));
        out.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(top_right + rot * block(0, 3) * rt));
        out.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(top_right.transpose() + rot * block(3, 0) * rt));
        out.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(bottom + rot * block(3, 3) * rt));
        self.covariance = out;
        self.trans_0_k_m += dp_0;
        self.rot_0_k *= Quat::from_scaled_axis(dphi);
    }

    /// The relative pose from the interval start to the last reading (see [`RelativePose`]
    /// for the convention; unobserved components per [`OdometryConfig::observed`]).
    /// Error: [`KinematicsError::NotStarted`] when no interval is running.
    pub fn relative_pose(&self) -> Result<RelativePose, KinematicsError> {
        let last = self.last.ok_or(KinematicsError::NotStarted)?;
        Ok(RelativePose {
            t0_us: self.t0_us,
            t1_us: last.t_us,
            rot_0_1: self.rot_0_k,
            trans_0_1_m: self.trans_0_k_m,
            covariance: self.covariance,
            observed: self.config.observed,
        })
    }

    /// [`Self::relative_pose`], then start a new interval at the last reading.
    pub fn take(&mut self) -> Result<RelativePose, KinematicsError> {
        let pose = self.relative_pose()?;
        let last = self.last.ok_or(KinematicsError::NotStarted)?;
        self.start(&last)?;
        Ok(pose)
    }
}

/// The 3x3 block of `m` at row `r0`, column `c0` (NaN outside `m`; built element-wise, without
/// the view's `into_owned`, whose length assertion the optimiser keeps: no panic path).
fn block3(m: &Mat6, r0: usize, c0: usize) -> Mat3 {
    Mat3::from_fn(|r, c| m.get((r0 + r, c0 + c)).copied().unwrap_or(f64::NAN))
}

#[cfg(test)]
mod covariance_tests {
    use super::super::contact::contact_jacobians;
    use super::super::geometry::{wheel_frames_trusted, ROCKY8};
    use super::*;

    /// The per-pattern sum the per-wheel maps replace: one least-squares solve and one outer
    /// product per perturbation pattern (the definition of the step covariance).
    fn reference(
        c: &OdometryConfig,
        lsq: &ContactLeastSquares,
        jac: &[WheelJacobian; WHEEL_COUNT],
        frames: &[super::super::geometry::WheelFrames; WHEEL_COUNT],
        drive: &[f64; WHEEL_COUNT],
        rates: &SuspensionRates,
        valid: &[bool; WHEEL_COUNT],
    ) -> Mat6 {
        let mut q = Mat6::zeros();
        let mut add = |b: &[Vec3; WHEEL_COUNT], sigma: f64| {
            let t = lsq.solve(b);
            let col = Vec6::new(t[3], t[4], t[5], t[0], t[1], t[2]);
            q += col * col.transpose() * (sigma * sigma);
        };
        let articulation = contact_velocities(jac, rates, &[0.0; WHEEL_COUNT]);
        let mut travels = [Vec3::zeros(); WHEEL_COUNT];
        for i in 0..WHEEL_COUNT {
            if !valid[i] {
                continue;
            }
            let one = |v: Vec3| {
                let mut b = [Vec3::zeros(); WHEEL_COUNT];
                b[i] = v;
                b
            };
            travels[i] = jac[i].drive * drive[i];
            add(
                &one(jac[i].drive),
                c.drive_increment_noise_rad + c.drive_fraction * drive[i].abs(),
            );
            add(
                &one(frames[i].steer_axis.cross(&jac[i].drive) * drive[i]),
                c.steer_noise_rad,
            );
            add(&one(travels[i]), c.wheel_radius_sigma);
            let moved = crate::linalg::norm(&articulation[i]);
            // nalgebra's `normalize`: the vector over its norm.
            let along = jac[i].drive / crate::linalg::norm(&jac[i].drive);
            let lateral = frames[i].steer_axis.cross(&along);
            for v in [along, lateral, along.cross(&lateral)] {
                add(&one(v), c.articulation_fraction * moved);
            }
        }
        add(&travels, c.radius_scale_sigma);
        for k in 0..3 {
            let unit = SuspensionRates {
                rocker_rad_s: f64::from(u8::from(k == 0)),
                bogie_rad_s: [f64::from(u8::from(k == 1)), f64::from(u8::from(k == 2))],
            };
            let b = contact_velocities(jac, &unit, &[0.0; WHEEL_COUNT]);
            let masked: [Vec3; WHEEL_COUNT] =
                core::array::from_fn(|i| if valid[i] { b[i] } else { Vec3::zeros() });
            add(&masked, c.suspension_increment_noise_rad);
        }
        q
    }

    /// KIN-11: the step covariance built from the per-wheel maps (`wheel_map`) equals
    /// the per-pattern definition to 1e-12 relative, with steering, articulation, contact angles
    /// and a missing wheel.
    #[test]
    fn kin_11_step_covariance_per_wheel_maps_equal_the_pattern_sum() {
        let odo = KinematicOdometry::new(ROCKY8, OdometryConfig::default());
        let state = SuspensionState {
            rocker_rad: 0.12,
            bogie_rad: [-0.2, 0.15],
            steer_rad: [0.3, -0.1, 0.0, 0.05, -0.25, 0.4],
        };
        let frames = wheel_frames_trusted(&ROCKY8, &state);
        let angles = [0.2, -0.1, 0.35, 0.0, -0.3, 0.05];
        let jac = contact_jacobians(&frames, ROCKY8.wheel_radius_m, &angles);
        let drive = [0.05, 0.048, 0.06, -0.01, 0.052, 0.0];
        let rates = SuspensionRates {
            rocker_rad_s: 0.004,
            bogie_rad_s: [-0.006, 0.002],
        };
        for valid in [[true; 6], [true, true, false, true, true, true]] {
            let lsq = ContactLeastSquares::new(&jac.map(|j| j.contact_point_m), &valid).unwrap();
            let got = odo.step_covariance(&lsq, &jac, &frames, &drive, &rates, &valid);
            let want = reference(&odo.config, &lsq, &jac, &frames, &drive, &rates, &valid);
            let scale = want.abs().max();
            assert!(scale > 0.0);
            let err = (got - want).abs().max();
            assert!(err <= 1e-12 * scale, "error {err:e} of {scale:e}");
        }
    }
}
