//! The simulator's own model of the Rocky 8 hazard cameras, written from the published figures
//! (REFERENCE.md; H04, H05) without reading the flight code: the nominal stereo head (what a
//! ground calibration file of the rover would say) and the per-unit manufacturing and
//! calibration errors of the real head, which the flight software does not know.
//!
//! # Nominal head
//! 640 x 480 pixels, field of view 79.5 x 64.0 deg (horizontal x vertical), so
//! `fx = 320 / tan(39.75 deg)` and `fy = 240 / tan(32.0 deg)`, principal point at the image
//! centre `(319.5, 239.5)` (pixel centres at integers), baseline 8.4 cm, the optical axis pitched
//! 45 deg down from the rover's forward axis, the left optical centre 0.2 m ahead of and 0.6 m
//! above the rover reference point on the rover's centre line. Frames as in
//! [`rover_hal::StereoCalibration`]: rover `R` x forward, y right, z down; camera `K` x right,
//! y down, z along the optical axis.
//!
//! # Errors of the real head (1-sigma, per seed)
//! The rendered pair stays a rectified pinhole pair (the renderer draws one intrinsic model for
//! both cameras), so the errors are those left after a ground calibration and rectification:
//!
//! | quantity | 1-sigma | source |
//! |---|---|---|
//! | focal lengths `fx`, `fy` (independent) | 0.2 % | simulator assumption (a calibrated head's focal uncertainty is typically 0.1-0.5 %; Bouguet's toolbox reports its 3-sigma uncertainties, a few tenths of a percent for a well-covered target) |
//! | principal point `cx`, `cy` | 0.5 px | simulator assumption (same class as above) |
//! | baseline | 0.2 mm | simulator assumption (0.24 % of 8.4 cm) |
//! | mounting angles of the head (roll, pitch, yaw about `x_R`, `y_R`, `z_R`) | 0.1 deg | simulator assumption (camera-to-body alignment after a fiducial survey) |
//! | mounting position of the head (per axis of `R`) | 2 mm | simulator assumption, the same figure as the vehicle dimension errors and the total-station accuracy of H04 (2 mm) |
//!
//! With the wide-angle lenses ([`super::hazcam_lens`], the default) the focal-length and
//! principal-point errors move to the two raw cameras (alike), and each camera's lens gets its
//! own distortion-coefficient errors; the flight software rectifies with the nominal lenses.
//! Not modelled: a relative rotation between the raw cameras.

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rover_hal::StereoCalibration;
use serde::Deserialize;

/// Image width, pixels.
pub const WIDTH_PX: f64 = 640.0;
/// Image height, pixels.
pub const HEIGHT_PX: f64 = 480.0;
/// Horizontal field of view, degrees.
pub const HFOV_DEG: f64 = 79.5;
/// Vertical field of view, degrees.
pub const VFOV_DEG: f64 = 64.0;
/// Stereo baseline, m.
pub const BASELINE_M: f64 = 0.084;
/// Pitch of the optical axis below the rover's forward axis, degrees.
pub const PITCH_DOWN_DEG: f64 = 45.0;
/// Left optical centre ahead of the rover reference point, m.
pub const AHEAD_M: f64 = 0.2;
/// Left optical centre above the rover reference point, m.
pub const ABOVE_M: f64 = 0.6;

/// The nominal Rocky 8 hazcam head (what the ground calibration file says).
pub fn nominal_hazcam() -> StereoCalibration {
    let fx = 0.5 * WIDTH_PX / (0.5 * HFOV_DEG).to_radians().tan();
    let fy = 0.5 * HEIGHT_PX / (0.5 * VFOV_DEG).to_radians().tan();
    // Columns of R_RK are the camera axes in R: x_K = right (+y_R); z_K = forward and pitched
    // down (+x_R cos p + z_R sin p); y_K = z_K x x_K.
    let (s, c) = PITCH_DOWN_DEG.to_radians().sin_cos();
    let x_k = Vector3::new(0.0, 1.0, 0.0);
    let z_k = Vector3::new(c, 0.0, s);
    let y_k = z_k.cross(&x_k);
    let r = Matrix3::from_columns(&[x_k, y_k, z_k]);
    StereoCalibration {
        fx_px: fx,
        fy_px: fy,
        cx_px: 0.5 * (WIDTH_PX - 1.0),
        cy_px: 0.5 * (HEIGHT_PX - 1.0),
        baseline_m: BASELINE_M,
        rot_rover_from_camera: rows(&r),
        pos_camera_in_rover_m: [AHEAD_M, 0.0, -ABOVE_M],
    }
}

fn rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]])
}

/// 1-sigma tolerances of the real head against its calibration (see the module table).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default)]
pub struct CameraTolerances {
    /// Relative focal-length error, each of `fx` and `fy` (0.002 = 0.2 %).
    pub focal_rel: f64,
    /// Principal point, each of `cx` and `cy`, pixels.
    pub principal_point_px: f64,
    /// Baseline, m.
    pub baseline_m: f64,
    /// Mounting angles of the head (roll, pitch, yaw about the rover axes), degrees.
    pub mount_angle_deg: f64,
    /// Mounting position of the head, each axis of `R`, m.
    pub mount_position_m: f64,
}

impl Default for CameraTolerances {
    fn default() -> Self {
        Self {
            focal_rel: 0.002,
            principal_point_px: 0.5,
            baseline_m: 0.0002,
            mount_angle_deg: 0.1,
            mount_position_m: 0.002,
        }
    }
}

/// The errors of one head (true minus nominal).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CameraErrors {
    /// Relative errors of `fx`, `fy`.
    pub focal_rel: [f64; 2],
    /// Errors of `cx`, `cy`, pixels.
    pub principal_point_px: [f64; 2],
    /// Baseline error, m.
    pub baseline_m: f64,
    /// Small rotation of the head about `x_R`, `y_R`, `z_R` (roll, pitch, yaw), rad.
    pub mount_angle_rad: [f64; 3],
    /// Offset of the head along `x_R`, `y_R`, `z_R`, m.
    pub mount_position_m: [f64; 3],
}

impl CameraErrors {
    /// Draw one head's errors with the 1-sigma `tol` from `rng` (always 13 draws, in a fixed
    /// order, so the stream stays aligned whatever the tolerances).
    pub fn draw(tol: &CameraTolerances, rng: &mut ChaCha8Rng) -> Self {
        let mut n = || -> f64 { rng.sample(StandardNormal) };
        let focal_rel = [tol.focal_rel * n(), tol.focal_rel * n()];
        let principal_point_px = [tol.principal_point_px * n(), tol.principal_point_px * n()];
        let baseline_m = tol.baseline_m * n();
        let a = tol.mount_angle_deg.to_radians();
        let mount_angle_rad = [a * n(), a * n(), a * n()];
        let p = tol.mount_position_m;
        let mount_position_m = [p * n(), p * n(), p * n()];
        Self {
            focal_rel,
            principal_point_px,
            baseline_m,
            mount_angle_rad,
            mount_position_m,
        }
    }

    /// The true head: `nominal` with these errors. The head turns about its left optical
    /// centre by `R_x(roll) R_y(pitch) R_z(yaw)` (rover axes): `R_RK' = R_err R_RK`.
    pub fn apply(&self, nominal: &StereoCalibration) -> StereoCalibration {
        let [roll, pitch, yaw] = self.mount_angle_rad;
        let r_err = Rotation3::from_axis_angle(&Vector3::x_axis(), roll)
            * Rotation3::from_axis_angle(&Vector3::y_axis(), pitch)
            * Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
        let r_nom = Matrix3::from_fn(|i, j| nominal.rot_rover_from_camera[i][j]);
        let r = r_err.matrix() * r_nom;
        let t = nominal.pos_camera_in_rover_m;
        let d = self.mount_position_m;
        StereoCalibration {
            fx_px: nominal.fx_px * (1.0 + self.focal_rel[0]),
            fy_px: nominal.fy_px * (1.0 + self.focal_rel[1]),
            cx_px: nominal.cx_px + self.principal_point_px[0],
            cy_px: nominal.cy_px + self.principal_point_px[1],
            baseline_m: nominal.baseline_m + self.baseline_m,
            rot_rover_from_camera: rows(&r),
            pos_camera_in_rover_m: [t[0] + d[0], t[1] + d[1], t[2] + d[2]],
        }
    }
}

/// The simulated head: the nominal calibration the flight software is given and the true one
/// the renderer draws with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HazcamModel {
    /// What the ground calibration file says (returned by the HAL's `calibration()`): the
    /// rectified pair the flight software works in.
    pub nominal: StereoCalibration,
    /// The real head (used to render). With lenses, only its mounting and baseline are drawn
    /// from: its focal-length and principal-point errors are in the true raw cameras.
    pub truth: StereoCalibration,
    /// Truth minus nominal.
    pub errors: CameraErrors,
    /// The raw cameras' lenses ([`super::hazcam_lens`]); `None`: ideal lenses, the camera delivers the
    /// rectified pinhole pair (the model before the lenses, kept for comparison).
    pub lens: Option<super::hazcam_lens::LensModel>,
}

impl HazcamModel {
    /// The head of one seed: errors drawn from `rng` with `tol` when `enabled`, else none;
    /// wide-angle lenses ([`super::hazcam_lens`]) unless `ideal_lens`, their per-camera errors drawn
    /// with `lens_tol` when `enabled`. The draws are taken in every case (the lens draws after
    /// the head's) so that switching the errors or the lenses off changes nothing else.
    pub fn new(
        enabled: bool,
        tol: &CameraTolerances,
        ideal_lens: bool,
        lens_tol: &super::hazcam_lens::LensTolerances,
        rng: &mut ChaCha8Rng,
    ) -> Self {
        let nominal = nominal_hazcam();
        let drawn = CameraErrors::draw(tol, rng);
        let errors = if enabled {
            drawn
        } else {
            CameraErrors::default()
        };
        let lens_nominal = super::hazcam_lens::nominal_lens();
        let lens_drawn = super::hazcam_lens::draw_truth(
            &lens_nominal,
            &nominal,
            errors.focal_rel,
            errors.principal_point_px,
            lens_tol,
            rng,
        );
        let lens = (!ideal_lens).then_some(super::hazcam_lens::LensModel {
            nominal: lens_nominal,
            truth: if enabled { lens_drawn } else { lens_nominal },
        });
        Self {
            nominal,
            truth: errors.apply(&nominal),
            errors,
            lens,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// SIM-18: the nominal head has the published field of view, baseline and mounting; its
    /// rotation is proper and looks 45 deg down ahead.
    #[test]
    fn sim_18_nominal_head_matches_published_figures() {
        let c = nominal_hazcam();
        let hfov = 2.0 * (320.0 / c.fx_px).atan();
        let vfov = 2.0 * (240.0 / c.fy_px).atan();
        assert!((hfov.to_degrees() - 79.5).abs() < 1e-12);
        assert!((vfov.to_degrees() - 64.0).abs() < 1e-12);
        assert_eq!(c.baseline_m, 0.084);
        let r = Matrix3::from_fn(|i, j| c.rot_rover_from_camera[i][j]);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
        let axis = r.column(2);
        assert!((axis.z.atan2(axis.x).to_degrees() - 45.0).abs() < 1e-12);
        assert!(axis.y.abs() < 1e-15);
        // Right camera to the rover's right.
        assert!((r.column(0) - Vector3::y()).norm() < 1e-15);
    }

    /// SIM-18: per-seed head errors have the stated 1-sigma scatter, the true rotation stays a
    /// rotation, and switching the errors off gives the nominal head.
    #[test]
    fn sim_18_head_errors_scatter_and_switch() {
        let tol = CameraTolerances::default();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let n = 4000;
        let (mut f2, mut b2, mut a2, mut p2, mut c2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for _ in 0..n {
            let m = HazcamModel::new(true, &tol, false, &Default::default(), &mut rng);
            f2 += (m.truth.fx_px / m.nominal.fx_px - 1.0).powi(2);
            c2 += (m.truth.cy_px - m.nominal.cy_px).powi(2);
            b2 += (m.truth.baseline_m - m.nominal.baseline_m).powi(2);
            p2 += (m.truth.pos_camera_in_rover_m[2] - m.nominal.pos_camera_in_rover_m[2]).powi(2);
            let rt = Matrix3::from_fn(|i, j| m.truth.rot_rover_from_camera[i][j]);
            let rn = Matrix3::from_fn(|i, j| m.nominal.rot_rover_from_camera[i][j]);
            assert!((rt.transpose() * rt - Matrix3::identity()).norm() < 1e-12);
            // Pitch of the head: rotation about y_R between the optical axes.
            let (zt, zn) = (rt.column(2), rn.column(2));
            let dp = zt.z.atan2(zt.x) - zn.z.atan2(zn.x);
            a2 += dp * dp;
        }
        let rms = |s: f64| (s / n as f64).sqrt();
        let close = |got: f64, want: f64| (got / want - 1.0).abs() < 0.08;
        assert!(close(rms(f2), tol.focal_rel), "{}", rms(f2));
        assert!(close(rms(c2), tol.principal_point_px), "{}", rms(c2));
        assert!(close(rms(b2), tol.baseline_m), "{}", rms(b2));
        assert!(close(rms(p2), tol.mount_position_m), "{}", rms(p2));
        // The optical-axis elevation changes by the pitch error (and second-order terms).
        assert!(
            close(rms(a2), tol.mount_angle_deg.to_radians()),
            "{}",
            rms(a2)
        );
        let off = HazcamModel::new(false, &tol, false, &Default::default(), &mut rng);
        assert_eq!(off.truth, off.nominal);
        let lens = off.lens.unwrap();
        assert_eq!(lens.truth, lens.nominal);
        assert_eq!(off.nominal, nominal_hazcam());
    }
}
