//! The simulator's model of the hazcams' wide-angle lenses, written from the published
//! Brown-Conrady radial-tangential model (Brown 1966, "Decentering distortion of lenses";
//! the form of OpenCV and of Bouguet's calibration toolbox), not from the flight code.
//!
//! # Why radial-tangential and not CAHVOR
//! Both describe a lens of ~80 deg well. The radial-tangential model is the one published
//! calibrations of comparable machine-vision cameras come in (so its coefficients can be cited
//! as they are), it is the model of the common calibration tools, and its inverse is a small
//! fixed-size Newton iteration. CAHVOR (Gennery; MER, MSL cameras) would need the coefficients
//! of a JPL calibration, which the project does not have for Rocky 8.
//!
//! # Nominal lenses (what the rover's ground calibration file says)
//! No published Rocky 8 hazcam lens calibration was found. The nominal raw cameras are those
//! of a published calibration of a ~80 deg wide-angle machine-vision stereo head: the EuRoC
//! MAV dataset's stereo pair (Burri et al. 2016, "The EuRoC micro aerial vehicle datasets",
//! IJRR 35(10); `cam0/sensor.yaml`, `cam1/sensor.yaml`: MT9V034 global-shutter sensors,
//! 752 x 480 pixels, Kalibr radial-tangential calibration):
//!
//! | camera | fu, fv (px) | cu, cv (px) | k1 | k2 | p1 | p2 |
//! |---|---|---|---|---|---|---|
//! | cam0 (left) | 458.654, 457.296 | 367.215, 248.375 | -0.28340811 | 0.07395907 | 0.00019359 | 1.76187114e-05 |
//! | cam1 (right) | 457.587, 456.134 | 379.999, 255.238 | -0.28368365 | 0.07451284 | -0.00010473 | -3.555907e-05 |
//!
//! Its horizontal field by `fu` (`2 atan(376 / 458.65)` = 78.7 deg) is that of the Rocky 8
//! hazcams (79.5 deg). The lens is carried over to the hazcams' 640-pixel-wide sensor at the
//! same field per pixel across: focal lengths and the principal points' offsets from the
//! image centre scaled by 640 / 752 (the distortion coefficients act on normalized
//! coordinates and stay as published; `k3 = 0` as in the publication). Each camera keeps its
//! own coefficients and intrinsics. The raw cameras are aligned with the rectified frame
//! (`R_AK = I`; EuRoC's relative rotation of 0.2 deg is left out: the rendered head keeps its
//! parallel cameras). With this lens the raw field is wider than the rectified one (barrel
//! distortion): the rectified 640 x 480 pinhole image of [`super::hazcam`] lies inside
//! both raw images with at least 8 px to spare (the right camera's bottom edge), and the raw corners see about 54 deg off axis.
//!
//! # Per-unit errors (the real lens against its calibration)
//! - The head's focal-length and principal-point errors of [`super::hazcam`]
//!   (0.2 %, 0.5 px 1-sigma) apply to both raw cameras alike (as they did to the rectified pair).
//! - Each camera's distortion coefficients get their own error: each of `k1, k2, k3, p1, p2`
//!   with the 1-sigma that moves the corner of the rectified field by
//!   [`LensTolerances::distortion_px`] (default 0.15 px) on its own. The corner then moves by
//!   about 0.34 px (1-sigma) and the field by 0.10 px RMS (`lens_errors_have_the_stated_size`):
//!   the residual of a good calibration (reprojection residuals of 0.1-0.3 px; a simulator
//!   assumption in that range, not a published figure of these cameras).

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rover_hal::{LensCalibration, RawCamera, StereoCalibration};
use serde::Deserialize;

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// Published EuRoC image width, px.
const EUROC_WIDTH_PX: f64 = 752.0;
/// Published EuRoC image height, px.
const EUROC_HEIGHT_PX: f64 = 480.0;

/// One EuRoC camera carried over to the 640 x 480 sensor (module doc).
fn euroc_scaled(f: [f64; 2], c: [f64; 2], d: [f64; 4]) -> RawCamera {
    let s = super::hazcam::WIDTH_PX / EUROC_WIDTH_PX;
    let centre = |n: f64| 0.5 * (n - 1.0);
    RawCamera {
        fx_px: f[0] * s,
        fy_px: f[1] * s,
        cx_px: centre(super::hazcam::WIDTH_PX) + s * (c[0] - centre(EUROC_WIDTH_PX)),
        cy_px: centre(super::hazcam::HEIGHT_PX) + s * (c[1] - centre(EUROC_HEIGHT_PX)),
        k1: d[0],
        k2: d[1],
        k3: 0.0,
        p1: d[2],
        p2: d[3],
        rot_raw_from_rect: IDENTITY,
    }
}

/// The nominal lenses of the hazcam head (module doc: EuRoC cam0 / cam1 on the 640 x 480
/// sensor).
pub fn nominal_lens() -> LensCalibration {
    LensCalibration {
        left: euroc_scaled(
            [458.654, 457.296],
            [367.215, 248.375],
            [-0.283_408_11, 0.073_959_07, 0.000_193_59, 1.761_871_14e-05],
        ),
        right: euroc_scaled(
            [457.587, 456.134],
            [379.999, 255.238],
            [-0.283_683_65, 0.074_512_84, -0.000_104_73, -3.555_907e-05],
        ),
    }
}

/// Distorted normalized coordinates of the undistorted normalized point `(x, y)` (module
/// doc; `RawCamera` documents the equations).
pub fn distort(c: &RawCamera, x: f64, y: f64) -> [f64; 2] {
    let r2 = x * x + y * y;
    let g = 1.0 + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3));
    [
        x * g + 2.0 * c.p1 * x * y + c.p2 * (r2 + 2.0 * x * x),
        y * g + c.p1 * (r2 + 2.0 * y * y) + 2.0 * c.p2 * x * y,
    ]
}

/// Jacobian of [`distort`] with respect to `(x, y)`, rows `x_d`, `y_d`.
fn distort_jacobian(c: &RawCamera, x: f64, y: f64) -> [[f64; 2]; 2] {
    let r2 = x * x + y * y;
    let g = 1.0 + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3));
    // dg/d(r^2)
    let dg = c.k1 + r2 * (2.0 * c.k2 + 3.0 * r2 * c.k3);
    [
        [
            g + 2.0 * x * x * dg + 2.0 * c.p1 * y + 6.0 * c.p2 * x,
            2.0 * x * y * dg + 2.0 * c.p1 * x + 2.0 * c.p2 * y,
        ],
        [
            2.0 * x * y * dg + 2.0 * c.p1 * x + 2.0 * c.p2 * y,
            g + 2.0 * y * y * dg + 6.0 * c.p1 * y + 2.0 * c.p2 * x,
        ],
    ]
}

/// Undistorted normalized coordinates of the distorted normalized point `(xd, yd)`: Newton's
/// method from `(xd, yd)` (at most 50 iterations, to 1e-14), `None` if it does not converge
/// or the Jacobian is singular (outside the lens's monotonic field).
pub fn undistort(c: &RawCamera, xd: f64, yd: f64) -> Option<[f64; 2]> {
    let (mut x, mut y) = (xd, yd);
    for _ in 0..50 {
        let [fx, fy] = distort(c, x, y);
        let (ex, ey) = (fx - xd, fy - yd);
        if ex.abs().max(ey.abs()) < 1e-14 {
            return Some([x, y]);
        }
        let j = distort_jacobian(c, x, y);
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !det.is_finite() || det <= 1e-9 {
            return None;
        }
        x -= (j[1][1] * ex - j[0][1] * ey) / det;
        y -= (j[0][0] * ey - j[1][0] * ex) / det;
    }
    let [fx, fy] = distort(c, x, y);
    ((fx - xd).abs().max((fy - yd).abs()) < 1e-12).then_some([x, y])
}

/// Raw pixel of the ray `v` (rectified frame of that camera), `None` behind the camera.
pub fn project(c: &RawCamera, v: [f64; 3]) -> Option<[f64; 2]> {
    let a = mat_vec(&c.rot_raw_from_rect, v);
    if a[2] <= 1e-9 {
        return None;
    }
    let [xd, yd] = distort(c, a[0] / a[2], a[1] / a[2]);
    Some([c.cx_px + c.fx_px * xd, c.cy_px + c.fy_px * yd])
}

/// Ray (rectified frame of that camera, `z = 1` in the raw frame before the rotation) of the
/// raw pixel `(u, v)`, `None` where the lens model cannot be inverted.
pub fn ray(c: &RawCamera, u: f64, v: f64) -> Option<[f64; 3]> {
    let [x, y] = undistort(c, (u - c.cx_px) / c.fx_px, (v - c.cy_px) / c.fy_px)?;
    // v_K = R_AK^T v_A.
    let r = &c.rot_raw_from_rect;
    Some([0, 1, 2].map(|j| r[0][j] * x + r[1][j] * y + r[2][j]))
}

fn mat_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

/// 1-sigma tolerance of the lens calibration (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default)]
pub struct LensTolerances {
    /// Image displacement at the corner of the rectified field caused by the 1-sigma error of
    /// each distortion coefficient alone, px.
    pub distortion_px: f64,
}

impl Default for LensTolerances {
    fn default() -> Self {
        Self {
            distortion_px: 0.15,
        }
    }
}

/// Normalized coordinates of the rectified field's corner (where the coefficient errors are
/// scaled), for the rectified head `rect`.
fn field_corner(rect: &StereoCalibration) -> [f64; 2] {
    [rect.cx_px / rect.fx_px, rect.cy_px / rect.fy_px]
}

/// Displacement of the corner `(x, y)` (px, with focal length `f`) per unit of each of
/// `k1, k2, k3, p1, p2`.
fn coefficient_sensitivity(f: f64, x: f64, y: f64) -> [f64; 5] {
    let r2 = x * x + y * y;
    let r = r2.sqrt();
    let tangential_p1 = (2.0 * x * y).hypot(r2 + 2.0 * y * y);
    let tangential_p2 = (r2 + 2.0 * x * x).hypot(2.0 * x * y);
    [
        f * r * r2,
        f * r * r2 * r2,
        f * r * r2 * r2 * r2,
        f * tangential_p1,
        f * tangential_p2,
    ]
}

/// The true lenses of one head: `nominal` with the head's common focal-length and
/// principal-point errors (`focal_rel`, `principal_px`, true minus nominal) and per-camera
/// distortion errors drawn from `rng` with `tol` (always 10 draws, left then right, `k1, k2,
/// k3, p1, p2`). `rect` gives the rectified field whose corner scales the errors.
pub fn draw_truth(
    nominal: &LensCalibration,
    rect: &StereoCalibration,
    focal_rel: [f64; 2],
    principal_px: [f64; 2],
    tol: &LensTolerances,
    rng: &mut ChaCha8Rng,
) -> LensCalibration {
    let [x, y] = field_corner(rect);
    let mut one = |c: &RawCamera| {
        let s = coefficient_sensitivity(c.fx_px, x, y);
        let mut e = [0.0; 5];
        for (ei, si) in e.iter_mut().zip(s) {
            let n: f64 = rng.sample(StandardNormal);
            *ei = tol.distortion_px / si * n;
        }
        RawCamera {
            fx_px: c.fx_px * (1.0 + focal_rel[0]),
            fy_px: c.fy_px * (1.0 + focal_rel[1]),
            cx_px: c.cx_px + principal_px[0],
            cy_px: c.cy_px + principal_px[1],
            k1: c.k1 + e[0],
            k2: c.k2 + e[1],
            k3: c.k3 + e[2],
            p1: c.p1 + e[3],
            p2: c.p2 + e[4],
            rot_raw_from_rect: c.rot_raw_from_rect,
        }
    };
    let left = one(&nominal.left);
    let right = one(&nominal.right);
    LensCalibration { left, right }
}

/// The lenses of the simulated head: the calibration file's and the real ones.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LensModel {
    /// What the ground calibration file says (returned by the HAL's `lens_calibration()`).
    pub nominal: LensCalibration,
    /// The real lenses (used to render the raw images).
    pub truth: LensCalibration,
}

/// Largest distance between a rectified pixel's position in the raw image under `a` and
/// under `b`, over a grid of the rectified field `rect` (every `step` px), and the RMS, px:
/// the image error a rectification with `a` makes when the lens is `b`.
pub fn field_displacement(
    a: &RawCamera,
    b: &RawCamera,
    rect: &StereoCalibration,
    step: usize,
) -> (f64, f64) {
    let (mut worst, mut sum2, mut n) = (0.0f64, 0.0, 0usize);
    for j in (0..rover_hal::IMAGE_HEIGHT_PX).step_by(step.max(1)) {
        for i in (0..rover_hal::IMAGE_WIDTH_PX).step_by(step.max(1)) {
            let v = [
                (i as f64 - rect.cx_px) / rect.fx_px,
                (j as f64 - rect.cy_px) / rect.fy_px,
                1.0,
            ];
            if let (Some(p), Some(q)) = (project(a, v), project(b, v)) {
                let d = (p[0] - q[0]).hypot(p[1] - q[1]);
                worst = worst.max(d);
                sum2 += d * d;
                n += 1;
            }
        }
    }
    (worst, (sum2 / n.max(1) as f64).sqrt())
}

/// Unit ray (rectified frame) of the raw pixel `(u, v)`, as a nalgebra vector.
pub fn unit_ray(c: &RawCamera, u: f64, v: f64) -> Option<Vector3<f64>> {
    ray(c, u, v).map(|r| Vector3::from(r).normalize())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::hazcam::nominal_hazcam;
    use rand::SeedableRng;

    /// SIM-LENS-1: distortion and its inverse round-trip within 0.01 px over the whole raw
    /// field of both nominal cameras and of drawn true ones (every 4th raw pixel, borders
    /// included).
    #[test]
    fn sim_lens_1_distort_undistort_round_trip() {
        let rect = nominal_hazcam();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let truth = draw_truth(
            &nominal_lens(),
            &rect,
            [0.002, -0.002],
            [0.4, -0.3],
            &LensTolerances::default(),
            &mut rng,
        );
        let mut worst: f64 = 0.0;
        for c in [
            nominal_lens().left,
            nominal_lens().right,
            truth.left,
            truth.right,
        ] {
            let mut ius: Vec<usize> = (0..640).step_by(4).collect();
            ius.push(639);
            let mut jvs: Vec<usize> = (0..480).step_by(4).collect();
            jvs.push(479);
            for &j in &jvs {
                for &i in &ius {
                    let (u, v) = (i as f64, j as f64);
                    let r = ray(&c, u, v).expect("invertible over the raw field");
                    let p = project(&c, r).unwrap();
                    let e = (p[0] - u).hypot(p[1] - v);
                    worst = worst.max(e);
                }
            }
        }
        println!("SIM-LENS-1 worst round trip {worst:.2e} px");
        assert!(worst < 0.01, "{worst}");
    }

    /// SIM-LENS-2: the nominal lenses have the published figures carried over to 640 px, an
    /// ~80 deg field, a raw field wider than the rectified one, and the rectified field inside
    /// both raw images with at least 8 px to spare (the right camera's bottom edge).
    #[test]
    fn sim_lens_2_nominal_lens_covers_the_rectified_field() {
        let lens = nominal_lens();
        let rect = nominal_hazcam();
        assert!((lens.left.fx_px - 458.654 * 640.0 / 752.0).abs() < 1e-9);
        assert!((lens.right.cy_px - (239.5 + (255.238 - 239.5) * 640.0 / 752.0)).abs() < 1e-9);
        assert_eq!(lens.left.k1, -0.283_408_11);
        let hfov = 2.0 * (320.0 / lens.left.fx_px).atan().to_degrees();
        assert!((hfov - 78.7).abs() < 0.2, "{hfov}");
        let mut margin = f64::INFINITY;
        for c in [lens.left, lens.right] {
            // The border of the rectified image: left and right columns, top and bottom rows.
            let border = (0..480usize)
                .flat_map(|j| [(0usize, j), (639, j)])
                .chain((0..640usize).flat_map(|i| [(i, 0usize), (i, 479)]));
            for (i, j) in border {
                let v = [
                    (i as f64 - 319.5) / rect.fx_px,
                    (j as f64 - 239.5) / rect.fy_px,
                    1.0,
                ];
                let p = project(&c, v).unwrap();
                margin = margin
                    .min(p[0])
                    .min(639.0 - p[0])
                    .min(p[1])
                    .min(479.0 - p[1]);
            }
            // The raw corner sees further off axis than the rectified corner (about 47 deg).
            let corner = unit_ray(&c, 0.0, 0.0).unwrap();
            let off_axis = corner.z.acos().to_degrees();
            assert!(off_axis > 50.0 && off_axis < 60.0, "{off_axis}");
        }
        println!(
            "SIM-LENS-2 smallest margin of the rectified field in the raw images {margin:.1} px"
        );
        assert!(margin >= 5.0, "{margin}");
    }

    /// SIM-LENS-3: the drawn lens errors have the stated size: each camera's true lens moves
    /// the rectified field by about 0.10 px RMS (corner about 0.34 px), over 200 heads.
    #[test]
    fn lens_errors_have_the_stated_size() {
        let rect = nominal_hazcam();
        let nominal = nominal_lens();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (mut rms2, mut corner2) = (0.0, 0.0);
        let n = 200;
        for _ in 0..n {
            let t = draw_truth(
                &nominal,
                &rect,
                [0.0; 2],
                [0.0; 2],
                &LensTolerances::default(),
                &mut rng,
            );
            let (_, rms) = field_displacement(&nominal.left, &t.left, &rect, 16);
            rms2 += rms * rms;
            let v = [-rect.cx_px / rect.fx_px, -rect.cy_px / rect.fy_px, 1.0];
            let (p, q) = (
                project(&nominal.left, v).unwrap(),
                project(&t.left, v).unwrap(),
            );
            corner2 += (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
        }
        let rms = (rms2 / n as f64).sqrt();
        let corner = (corner2 / n as f64).sqrt();
        println!("SIM-LENS-3 field RMS {rms:.3} px, corner {corner:.3} px");
        assert!(rms > 0.07 && rms < 0.15, "{rms}");
        assert!(corner > 0.25 && corner < 0.45, "{corner}");
    }
}
