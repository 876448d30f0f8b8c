//! Geometry of one capture: the camera pose, the ground-plane prior (the rover's wheel-contact
//! plane), the grid frame, where a ground point appears in both images, and the visible wedge
//! (V99 sec. 4: "a wedge of the ground plane, with limited downrange radius R and half-angle
//! alpha").

use super::grid::GridFrame;
use super::{
    CameraPose, PerceptionConfig, PerceptionError, Point2, Wedge, CELL_SIZE_M, GRID_ROWS,
    GRID_X_MIN_M, GRID_Y_MIN_M,
};
use crate::kinematics::geometry::WHEEL_RADIUS_M;
use crate::types::{Mat3, Vec3};
use crate::vo::motion::CameraMount;
use crate::vo::stereo::PinholeStereo;
use crate::vo::TEMPLATE_HALF;
use rover_hal::{IMAGE_HEIGHT_PX, IMAGE_WIDTH_PX};

/// Candidate half-angles of the wedge: 10 deg to 60 deg in steps of 2.5 deg.
pub const WEDGE_CANDIDATES: u8 = 21;
/// Radius step of the wedge search, m.
const WEDGE_RANGE_STEP_M: f64 = 0.05;
/// Segments of the wedge's outer arc (the arc is checked on its circumscribed polygon).
const WEDGE_ARC_SEGMENTS: usize = 8;
/// Largest number of radius steps of the wedge search (20 m).
const WEDGE_MAX_STEPS: usize = 400;
/// Pixels kept free at the image border around a sample (template half side plus the
/// sub-pixel refinement's reach).
const BORDER_PX: f64 = (TEMPLATE_HALF + 2) as f64;

/// The geometry of a capture in the world frame `W`: the left camera's pose, the ground-plane
/// prior (the plane `z_R = r` of the rover frame at capture, `r` the wheel radius: the wheels'
/// contact plane), and the grid frame `G` (origin at the camera centre, `x_G` along the rover's
/// heading).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    /// Left camera pose.
    pub pose: CameraPose,
    /// Rotation from `W` to the camera frame `K`.
    pub rot_camera_from_world: Mat3,
    /// The world's down axis `z_W` in `K`.
    pub down_in_camera: Vec3,
    /// Unit normal of the prior plane in `W` (the rover's `z_R`, pointing down).
    pub prior_normal: Vec3,
    /// A point of the prior plane in `W`, m.
    pub prior_point: Vec3,
    /// Distance of the left camera centre from the prior plane, m.
    pub camera_height_m: f64,
    /// The grid frame.
    pub frame: GridFrame,
    camera: PinholeStereo,
}

impl Footprint {
    /// The geometry of a capture at `pose` with the camera `mount` and intrinsics `camera`.
    /// Errors: [`PerceptionError::InvalidPose`] (non-finite, or not a rotation);
    /// [`PerceptionError::PoseOutOfRange`] when the rover's forward axis is more than 60 deg
    /// from level (no heading), its contact plane more than 60 deg from level, or the camera
    /// not above the plane by more than `config.max_height_above_m`.
    pub fn new(
        pose: &CameraPose,
        mount: &CameraMount,
        camera: PinholeStereo,
        config: &PerceptionConfig,
    ) -> Result<Self, PerceptionError> {
        if !pose.is_valid() {
            return Err(PerceptionError::InvalidPose);
        }
        let rot_wk = pose.rot_world_from_camera;
        let rot_wr = rot_wk * mount.rot_rover_from_camera.transpose();
        let forward = rot_wr * Vec3::x();
        let normal = rot_wr * Vec3::z();
        // cos 60 deg.
        let limit = 0.5;
        if !(libm::hypot(forward.x, forward.y) >= limit && normal.z >= limit) {
            return Err(PerceptionError::PoseOutOfRange);
        }
        let rover_origin = pose.position_world_m - rot_wr * mount.pos_camera_in_rover_m;
        let prior_point = rover_origin + normal * WHEEL_RADIUS_M;
        let camera_height_m = normal.dot(&(prior_point - pose.position_world_m));
        if !(camera_height_m > config.max_height_above_m) {
            return Err(PerceptionError::PoseOutOfRange);
        }
        let c = pose.position_world_m;
        let rot_camera_from_world = rot_wk.transpose();
        Ok(Self {
            pose: *pose,
            rot_camera_from_world,
            down_in_camera: rot_camera_from_world * Vec3::z(),
            prior_normal: normal,
            prior_point,
            camera_height_m,
            frame: GridFrame::new([c.x, c.y, c.z], libm::atan2(forward.y, forward.x)),
            camera,
        })
    }

    /// A placeholder (zero camera and rotations): the compile-time value of a statically
    /// allocated hazard mapper before its initialisation writes [`Self::level`]'s.
    pub const EMPTY: Self = Self {
        pose: CameraPose {
            rot_world_from_camera: crate::types::zero_matrix::<3, 3>(),
            position_world_m: crate::types::VEC3_ZERO,
        },
        rot_camera_from_world: crate::types::zero_matrix::<3, 3>(),
        down_in_camera: crate::types::VEC3_ZERO,
        prior_normal: crate::types::VEC3_ZERO,
        prior_point: crate::types::VEC3_ZERO,
        camera_height_m: 0.0,
        frame: GridFrame {
            origin_world_m: [0.0; 3],
            heading_rad: 0.0,
            heading_cos: 0.0,
            heading_sin: 0.0,
        },
        camera: PinholeStereo {
            fx_px: 0.0,
            fy_px: 0.0,
            cx_px: 0.0,
            cy_px: 0.0,
            baseline_m: 0.0,
        },
    };

    /// A placeholder: camera at the origin looking down `z_W`, prior 1 m below (used before
    /// the first capture).
    pub fn level(camera: PinholeStereo) -> Self {
        Self {
            pose: CameraPose {
                rot_world_from_camera: Mat3::identity(),
                position_world_m: Vec3::zeros(),
            },
            rot_camera_from_world: Mat3::identity(),
            down_in_camera: Vec3::z(),
            prior_normal: Vec3::z(),
            prior_point: Vec3::z(),
            camera_height_m: 1.0,
            frame: GridFrame::new([0.0; 3], 0.0),
            camera,
        }
    }

    /// The world point (m) of the prior plane below (or above) grid point `g` (`[x_G, y_G]`,
    /// m).
    pub fn prior_below(&self, g: Point2) -> Vec3 {
        let [x, y] = self.frame.to_world_xy(g);
        let (n, p) = (&self.prior_normal, &self.prior_point);
        // n . (q - p) = 0 with n.z >= 0.5 (checked by `new`; 1 for `level`).
        let z = p.z - (n.x * (x - p.x) + n.y * (y - p.y)) / n.z;
        Vec3::new(x, y, z)
    }

    /// Where the prior's point below grid point `g` appears: `(x, y, disparity)` in the left
    /// image (pixels), when it is in front of the cameras and a template around it fits in both
    /// images.
    pub fn in_view(&self, g: Point2) -> Option<(f64, f64, f64)> {
        let p = self.rot_camera_from_world * (self.prior_below(g) - self.pose.position_world_m);
        if !(p.z > 0.05) {
            return None;
        }
        let (x, y) = self.camera.project_left(&p)?;
        let disparity = self.camera.fx_px * self.camera.baseline_m / p.z;
        let (x_max, y_max) = (
            (IMAGE_WIDTH_PX - 1) as f64 - BORDER_PX,
            (IMAGE_HEIGHT_PX - 1) as f64 - BORDER_PX,
        );
        let inside = x <= x_max
            && x - disparity >= BORDER_PX
            && (BORDER_PX..=y_max).contains(&y)
            && disparity.is_finite();
        inside.then_some((x, y, disparity))
    }

    /// True when grid point `g` lies in the grid and both cameras see its prior point.
    pub fn visible(&self, g: Point2) -> bool {
        let x_max = GRID_X_MIN_M + GRID_ROWS as f64 * CELL_SIZE_M;
        let in_grid =
            g[0] >= GRID_X_MIN_M && g[0] <= x_max && g[1] >= GRID_Y_MIN_M && g[1] <= -GRID_Y_MIN_M;
        in_grid && self.in_view(g).is_some()
    }

    /// Wedge candidate `candidate` (`0..WEDGE_CANDIDATES`): half-angle
    /// `alpha = 10 deg + 2.5 deg x candidate` about the grid's heading, apex at the camera's nadir; the largest outer
    /// radius `R` (0.05 m steps, at most `max_range_m`) whose arc is visible (checked on the
    /// arc's circumscribed polygon: its ends and 8 tangent-line corners), then the smallest
    /// inner radius whose chord ends are visible. The visible footprint (the prior-plane points
    /// that project inside both images, within the grid) is an intersection of half-planes,
    /// hence convex, so it contains the convex hull of these points and with it the sector.
    /// Returns the wedge in `W` and its area `alpha (R^2 - r^2)` (m^2), `None` when no sector
    /// of this half-angle is visible.
    pub fn wedge_candidate(&self, candidate: u8, max_range_m: f64) -> Option<(f64, Wedge)> {
        let deg = core::f64::consts::PI / 180.0;
        let alpha = (10.0 + 2.5 * f64::from(candidate)) * deg;
        let at = |r: f64, a: f64| -> Point2 {
            let (s, c) = libm::sincos(a);
            [r * c, r * s]
        };
        let steps = if max_range_m > 0.0 {
            (libm::floor(max_range_m / WEDGE_RANGE_STEP_M) as usize).min(WEDGE_MAX_STEPS)
        } else {
            0
        };
        let delta = 2.0 * alpha / WEDGE_ARC_SEGMENTS as f64;
        let sag = 1.0 / libm::cos(delta / 2.0);
        let outer = (1..=steps)
            .rev()
            .map(|k| k as f64 * WEDGE_RANGE_STEP_M)
            .find(|&r| {
                self.visible(at(r, -alpha))
                    && self.visible(at(r, alpha))
                    && (0..WEDGE_ARC_SEGMENTS).all(|m| {
                        let a = -alpha + (m as f64 + 0.5) * delta;
                        self.visible(at(r * sag, a))
                    })
            })?;
        let inner = (0..steps)
            .map(|k| k as f64 * WEDGE_RANGE_STEP_M)
            .take_while(|&r| r < outer)
            .find(|&r| self.visible(at(r, -alpha)) && self.visible(at(r, alpha)))?;
        let wedge = Wedge {
            apex_m: self.frame.to_world_xy([0.0, 0.0]),
            heading_rad: self.frame.heading_rad,
            half_angle_rad: alpha,
            min_range_m: inner,
            max_range_m: outer,
        };
        Some((alpha * (outer * outer - inner * inner), wedge))
    }
}
