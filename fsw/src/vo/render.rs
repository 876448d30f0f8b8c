//! Test-only renderer: a textured ground plane seen by the Rocky 8 hazcam pair (pinhole model,
//! 2x2 supersampling), and the synthetic 3D scenes for the motion tests.

use super::motion::CameraMount;
use crate::types::{Mat3, Quat, Vec3};
use rover_hal::{StereoCalibration, IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX};
use std::vec::Vec;

/// Rocky 8 hazcam calibration ([`super::rocky8_hazcam`]).
pub fn hazcam() -> StereoCalibration {
    super::rocky8_hazcam()
}

/// A rover pose in the world frame (the rover frame at the first image): `v_W = rot v_R + pos`.
#[derive(Debug, Clone, Copy)]
pub struct RoverPose {
    /// Rotation from `R` to the world.
    pub rot: Mat3,
    /// Rover origin in the world, m.
    pub pos: Vec3,
}

impl RoverPose {
    /// Pose from yaw, pitch, roll (rad, z-y-x) and a position.
    pub fn new(yaw: f64, pitch: f64, roll: f64, pos: Vec3) -> Self {
        let q = Quat::from_euler_angles(roll, pitch, yaw);
        Self {
            rot: q.to_rotation_matrix().into_inner(),
            pos,
        }
    }

    /// Relative pose from `self` (time 0) to `other` (time 1): `(rot_0_1, trans_0_1_m)`.
    pub fn relative_to(&self, other: &RoverPose) -> (Mat3, Vec3) {
        (
            self.rot.transpose() * other.rot,
            self.rot.transpose() * (other.pos - self.pos),
        )
    }
}

fn hash(ix: i64, iy: i64, salt: u64) -> f64 {
    let mut h = (ix as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
        ^ (iy as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
        ^ salt.wrapping_mul(0x1656_67b1_9e37_79f9);
    h ^= h >> 29;
    h = h.wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h ^= h >> 32;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Value noise with smooth interpolation, cell `scale` metres, values 0..1.
fn value_noise(x: f64, y: f64, scale: f64, salt: u64) -> f64 {
    let (gx, gy) = (x / scale, y / scale);
    let (x0, y0) = (gx.floor(), gy.floor());
    let (fx, fy) = (gx - x0, gy - y0);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let (ix, iy) = (x0 as i64, y0 as i64);
    let a = hash(ix, iy, salt);
    let b = hash(ix + 1, iy, salt);
    let c = hash(ix, iy + 1, salt);
    let d = hash(ix + 1, iy + 1, salt);
    let top = a + sx * (b - a);
    let bottom = c + sx * (d - c);
    top + sy * (bottom - top)
}

/// Albedo of the ground at world `(x, y)`, grey levels.
pub fn ground_texture(x: f64, y: f64) -> f64 {
    let v = 0.5 * value_noise(x, y, 0.03, 1)
        + 0.3 * value_noise(x, y, 0.09, 2)
        + 0.2 * value_noise(x, y, 0.25, 3);
    30.0 + 200.0 * v
}

/// Renders the left and right images of the ground plane `z_W = 0` (the rover stands on it at
/// the first pose) from the rover pose `pose`.
pub fn render_pair(cal: &StereoCalibration, pose: &RoverPose) -> (Vec<u8>, Vec<u8>) {
    let mount = CameraMount::from_calibration(cal).unwrap();
    let rot_wk = pose.rot * mount.rot_rover_from_camera;
    let centre_left = pose.rot * mount.pos_camera_in_rover_m + pose.pos;
    let centre_right = centre_left + rot_wk * Vec3::new(cal.baseline_m, 0.0, 0.0);
    let render = |centre: Vec3| {
        let mut img = vec![0u8; IMAGE_PIXELS];
        for y in 0..IMAGE_HEIGHT_PX {
            for x in 0..IMAGE_WIDTH_PX {
                let mut sum = 0.0;
                for (ox, oy) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                    let ray_k = Vec3::new(
                        (x as f64 + ox - cal.cx_px) / cal.fx_px,
                        (y as f64 + oy - cal.cy_px) / cal.fy_px,
                        1.0,
                    );
                    let ray = rot_wk * ray_k;
                    let value = if ray.z > 1e-6 {
                        let t = -centre.z / ray.z;
                        let p = centre + ray * t;
                        ground_texture(p.x, p.y)
                    } else {
                        90.0 // sky
                    };
                    sum += value;
                }
                img[y * IMAGE_WIDTH_PX + x] = (sum / 4.0).round().clamp(0.0, 255.0) as u8;
            }
        }
        img
    };
    (render(centre_left), render(centre_right))
}
