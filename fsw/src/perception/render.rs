//! Test-only ray caster of the hazcam pair over analytic scenes: level ground `z_W = 0` (z
//! down), optionally a ramp rising from `x_W = x0`, hemispherical rocks and rectangular blocks,
//! all textured with the visual odometry's procedural albedo ([`crate::vo::render`]) mapped
//! through `(x + 0.83 z, y - 0.57 z)` so that vertical faces are textured too. Pinhole model,
//! 2x2 supersampling, no shading.

use super::CameraPose;
use crate::types::Vec3;
use crate::vo::render::ground_texture;
use rover_hal::{StereoCalibration, IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX};
use std::vec::Vec;

/// A solid standing on the level ground.
#[derive(Debug, Clone, Copy)]
pub enum Solid {
    /// Hemisphere of `radius` m centred on the ground at `centre` `[x, y]` (m).
    Hemisphere { centre: [f64; 2], radius: f64 },
    /// Box over `[min, max]` in `x, y` (m), `height` m tall.
    Block {
        min: [f64; 2],
        max: [f64; 2],
        height: f64,
    },
}

/// An analytic scene in the world frame (x north, y east, z down; the level ground at z = 0).
#[derive(Debug, Clone, Default)]
pub struct Scene {
    /// Ramp: `(x0, slope)`: for `x >= x0` the ground is `z = -(x - x0) tan(slope)`.
    pub ramp: Option<(f64, f64)>,
    /// Solids on the level ground.
    pub solids: Vec<Solid>,
}

impl Scene {
    /// Height (up, m) of the ground without solids at `(x, y)`.
    pub fn ground_height(&self, x: f64, _y: f64) -> f64 {
        match self.ramp {
            Some((x0, slope)) if x >= x0 => (x - x0) * slope.tan(),
            _ => 0.0,
        }
    }

    /// Height (up, m) of the scene's top surface at `(x, y)`.
    pub fn height(&self, x: f64, y: f64) -> f64 {
        let mut h = self.ground_height(x, y);
        for s in &self.solids {
            match *s {
                Solid::Hemisphere { centre, radius } => {
                    let d2 = (x - centre[0]).powi(2) + (y - centre[1]).powi(2);
                    if d2 < radius * radius {
                        h = h.max((radius * radius - d2).sqrt());
                    }
                }
                Solid::Block { min, max, height } => {
                    if x >= min[0] && x <= max[0] && y >= min[1] && y <= max[1] {
                        h = h.max(height);
                    }
                }
            }
        }
        h
    }

    /// Nearest intersection of the ray `o + t d` (t > 0) with the scene.
    pub fn hit(&self, o: Vec3, d: Vec3) -> Option<Vec3> {
        let mut best = f64::INFINITY;
        let mut consider = |t: f64| {
            if t > 1e-9 && t < best {
                best = t;
            }
        };
        // Level ground (where no ramp).
        if d.z > 1e-12 {
            let t = -o.z / d.z;
            let x = o.x + t * d.x;
            if self.ramp.is_none_or(|(x0, _)| x < x0) {
                consider(t);
            }
        }
        if let Some((x0, slope)) = self.ramp {
            let k = slope.tan();
            let denominator = d.z + d.x * k;
            if denominator.abs() > 1e-12 {
                let t = -(o.z + (o.x - x0) * k) / denominator;
                if o.x + t * d.x >= x0 {
                    consider(t);
                }
            }
        }
        for s in &self.solids {
            match *s {
                Solid::Hemisphere { centre, radius } => {
                    let c = Vec3::new(centre[0], centre[1], 0.0);
                    let oc = o - c;
                    let (a, b, cc) = (d.dot(&d), 2.0 * d.dot(&oc), oc.dot(&oc) - radius * radius);
                    let disc = b * b - 4.0 * a * cc;
                    if disc >= 0.0 {
                        let t = (-b - disc.sqrt()) / (2.0 * a);
                        if (o + d * t).z <= 1e-9 {
                            consider(t);
                        }
                    }
                }
                Solid::Block { min, max, height } => {
                    let lo = [min[0], min[1], -height];
                    let hi = [max[0], max[1], 0.0];
                    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
                    let mut missed = false;
                    for axis in 0..3 {
                        if d[axis].abs() < 1e-15 {
                            if o[axis] < lo[axis] || o[axis] > hi[axis] {
                                missed = true;
                            }
                            continue;
                        }
                        let ta = (lo[axis] - o[axis]) / d[axis];
                        let tb = (hi[axis] - o[axis]) / d[axis];
                        t0 = t0.max(ta.min(tb));
                        t1 = t1.min(ta.max(tb));
                    }
                    if !missed && t0 <= t1 {
                        consider(t0);
                    }
                }
            }
        }
        best.is_finite().then(|| o + d * best)
    }
}

/// Grey level of the scene surface at world point `p`.
fn albedo(p: &Vec3) -> f64 {
    ground_texture(p.x + 0.83 * p.z, p.y - 0.57 * p.z)
}

/// Renders the left and right images of `scene` seen from the left camera at `pose` with
/// calibration `cal` (the right camera at `+baseline` along `x_K`).
pub fn render(scene: &Scene, pose: &CameraPose, cal: &StereoCalibration) -> (Vec<u8>, Vec<u8>) {
    let rot = pose.rot_world_from_camera;
    let left_centre = pose.position_world_m;
    let right_centre = left_centre + rot * Vec3::new(cal.baseline_m, 0.0, 0.0);
    let draw = |centre: Vec3| {
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
                    sum += match scene.hit(centre, rot * ray_k) {
                        Some(p) => albedo(&p),
                        None => 90.0, // sky
                    };
                }
                img[y * IMAGE_WIDTH_PX + x] = (sum / 4.0).round().clamp(0.0, 255.0) as u8;
            }
        }
        img
    };
    (draw(left_centre), draw(right_centre))
}
