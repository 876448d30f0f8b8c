//! # Stereo rectification of the raw hazcam pair (RECT-1 to RECT-7)
//!
//! The hazcams are ~80 deg wide-angle lenses; the camera delivers the raw images with their
//! [`LensCalibration`] (Brown-Conrady radial-tangential model, equations in
//! [`rover_hal::RawCamera`]). Visual odometry (H04 sec. 2) and the hazard mapper work on the
//! rectified pinhole pair of [`StereoCalibration`]. This module maps each raw pair into that
//! geometry.
//!
//! ## Map (built once, [`Rectifier::build`])
//! For every node of a lattice every [`LATTICE_STEP_PX`] = 8 rectified pixels
//! (`x = 0, 8, ..., 640`, `y = 0, 8, ..., 480`: 81 x 61 nodes per camera), the rectified ray
//! `v_K = ((x - cx) / fx, (y - cy) / fy, 1)` is rotated into the raw camera
//! (`v_A = R_AK v_K`), distorted and projected with the raw intrinsics; the raw position is
//! stored in fixed point ([`MapNode`], 1/256 px, `i32`). Each node is checked: finite, in
//! front of the camera, the lens locally one-to-one there (Jacobian determinant of the
//! distortion above [`MIN_JACOBIAN_DET`]), the point found again by the bounded inverse
//! ([`undistort`]: at most [`UNDISTORT_ITERATIONS`] Newton steps; non-convergence is an
//! error) within [`ROUND_TRIP_TOL_PX`], and inside the raw image with room for the bilinear
//! 2 x 2 neighbourhood. Any failure refuses the whole map ([`RectifyError`]): the flight
//! software then runs no visual odometry and no hazard map on the pair. In particular a map
//! whose rectified field is not covered by the raw image is refused: neither VO nor the
//! mapper has a validity mask, and a black border would give corners on the field's edge.
//! The nominal Rocky 8 lens covers the field with at least 8 px to spare.
//!
//! ## Per pixel ([`rectify_row`])
//! The raw position of rectified pixel `(x, y)` is the bilinear interpolation of its cell's
//! four nodes, in integers: along the column `L = P(i, j) (8 - b) + P(i, j + 1) b`,
//! `R = P(i + 1, j) (8 - b) + P(i + 1, j + 1) b` (`b = y mod 8`), then along the row
//! `q = L (8 - a) + R a` (`a = x mod 8`, stepped by `R - L`), in 1/16384 px. The pixel value
//! is the bilinear interpolation of the raw image with 8-bit weights, rounded half up:
//! `(I00 (256 - wx)(256 - wy) + I10 wx (256 - wy) + I01 (256 - wx) wy + I11 wx wy + 2^15) >> 16`.
//! Integer arithmetic only, so the host and the rover CPU give the same bytes. A pixel whose
//! raw neighbourhood is outside the image (impossible with a map that passed the checks) is 0.
//! [`rectify_row`] computes these bytes cell by cell (the timing budget): a planned cell whose pixels
//! stay inside the image, within 8 raw columns and 2 raw rows, runs on one window of the raw
//! image with a packed position register and no per-pixel checks; other cells run the checked
//! per-pixel code (`docs/vo.md`, RECT-7).
//!
//! Interpolating the map between nodes 8 px apart costs at most about 0.03 px against the
//! exact lens model for the nominal lens (`rect_2_lattice_error`).
//!
//! ## Work items
//! A pair is rectified by [`Rectifier::step`] in work items of one image row each (left rows
//! first, then right), so it runs in the background work quantum
//! ([`crate::exec::spend_quantum`]) like the VO and the hazard mapper; each item costs
//! [`RectifyConfig::row_cost`] units (of about 10 000 rover-CPU instructions).
//!
//! ## Memory
//! The map (2 x 4 941 nodes x 8 B = 79 056 B) and the two rectified images (2 x 307 200 B)
//! live in the image memory region the platform provides ([`RectifyMemory`]: external RAM on
//! the rover CPU); the [`Rectifier`] itself is a few dozen bytes.

mod kernel;
mod lens;
#[cfg(test)]
mod tests;

pub use kernel::rectify_row;
use lens::{check_camera, map_node};
pub use lens::{distort, undistort};
#[cfg(test)]
use rover_hal::RawCamera;
use rover_hal::{
    LensCalibration, StereoCalibration, StereoFrame, IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX,
};

/// Lattice step of the map, rectified pixels.
pub const LATTICE_STEP_PX: usize = 8;
/// Lattice nodes per row (`x = 0, 8, ..., 640`).
pub const LATTICE_COLS: usize = IMAGE_WIDTH_PX / LATTICE_STEP_PX + 1;
/// Lattice rows (`y = 0, 8, ..., 480`).
pub const LATTICE_ROWS: usize = IMAGE_HEIGHT_PX / LATTICE_STEP_PX + 1;
/// Lattice nodes of one camera.
pub const LATTICE_NODES: usize = LATTICE_COLS * LATTICE_ROWS;
/// Map nodes of the pair (left camera first).
pub const MAP_NODES: usize = 2 * LATTICE_NODES;
/// Fractional bits of a [`MapNode`] coordinate (1/256 px).
pub const NODE_FRAC_BITS: u32 = 8;
/// Newton iterations of [`undistort`] (fixed bound).
pub const UNDISTORT_ITERATIONS: usize = 20;
/// Largest distance between a lattice point and the inverse of its raw position, px.
pub const ROUND_TRIP_TOL_PX: f64 = 0.01;
/// Smallest Jacobian determinant of the distortion (normalized coordinates) accepted at a node:
/// below it the lens folds or nearly folds the field there.
pub const MIN_JACOBIAN_DET: f64 = 0.05;
/// Largest absolute coordinate accepted anywhere in the lens model (normalized units), so
/// that the fixed-point conversion cannot overflow.
const MAX_NORMALIZED: f64 = 1.0e3;

const W: usize = IMAGE_WIDTH_PX;
const H: usize = IMAGE_HEIGHT_PX;
/// Bits of the row interpolation (8 x 8 = 64 = 2^6).
const CELL_BITS: u32 = 6;
/// Fractional bits of the per-pixel raw position `q` (node bits + cell bits).
const Q_FRAC_BITS: u32 = NODE_FRAC_BITS + CELL_BITS;

/// Raw position of a lattice node, 1/256 px (pixel centres at integers).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MapNode {
    /// Raw column, 1/256 px.
    pub u: i32,
    /// Raw row, 1/256 px.
    pub v: i32,
}

/// Why a map could not be built or a pair not rectified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RectifyError {
    /// A calibration value is non-finite, a focal length not positive, a coefficient absurd
    /// (`|k|, |p| > 100`), or a rotation not orthonormal.
    BadCalibration,
    /// A lattice ray is behind the raw camera or its distortion is not finite.
    BadRay,
    /// The lens folds the field at a node (Jacobian determinant below [`MIN_JACOBIAN_DET`]).
    Folded,
    /// The bounded inverse did not converge or did not find the node again.
    NotConverged,
    /// A node falls outside the raw image (the rectified field is not covered).
    FieldNotCovered,
    /// The image memory is too small (map or image buffers).
    Memory,
    /// No valid map (build failed or not built).
    NoMap,
    /// A raw image is not `IMAGE_PIXELS` bytes.
    ImageSize,
    /// A pair is being rectified already.
    Busy,
    /// [`Rectifier::step`] without a pair started.
    NotStarted,
    /// The frame given to [`Rectifier::step`] is not the one started.
    FrameChanged,
}

/// Figures of a built map.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MapStats {
    /// Largest round-trip error over the nodes, px.
    pub max_round_trip_px: f64,
    /// Largest Newton iteration count of the inverse.
    pub max_iterations: u32,
    /// Smallest distance of a node from the raw image border, px.
    pub min_margin_px: f64,
    /// Smallest Jacobian determinant of the distortion at a node.
    pub min_jacobian_det: f64,
}

/// The image memory of the rectification: the map and the two rectified images. The platform
/// provides it (external RAM on the rover CPU, the heap on the host).
pub trait RectifyMemory {
    /// The map and the two output images, for writing.
    fn parts(&mut self) -> (&mut [MapNode], &mut [u8], &mut [u8]);
    /// The two rectified images.
    fn images(&self) -> (&[u8], &[u8]);
}

/// [`RectifyMemory`] over any owned or borrowed buffers: `map` needs [`MAP_NODES`] nodes,
/// `left` and `right` [`IMAGE_PIXELS`] bytes each (smaller buffers make
/// [`Rectifier::build`] fail with [`RectifyError::Memory`]; empty ones suit a platform whose
/// camera delivers rectified images).
#[derive(Debug)]
pub struct ImageMemory<M, B> {
    /// Map nodes.
    pub map: M,
    /// Left rectified image.
    pub left: B,
    /// Right rectified image.
    pub right: B,
}

impl<M, B> RectifyMemory for ImageMemory<M, B>
where
    M: AsMut<[MapNode]>,
    B: AsRef<[u8]> + AsMut<[u8]>,
{
    fn parts(&mut self) -> (&mut [MapNode], &mut [u8], &mut [u8]) {
        (self.map.as_mut(), self.left.as_mut(), self.right.as_mut())
    }
    fn images(&self) -> (&[u8], &[u8]) {
        (self.left.as_ref(), self.right.as_ref())
    }
}

/// Settings of the rectification work.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RectifyConfig {
    /// Cost of one row item, units of about 10 000 rover-CPU instructions.
    pub row_cost: u16,
}

impl Default for RectifyConfig {
    fn default() -> Self {
        Self { row_cost: 4 }
    }
}

/// Progress of [`Rectifier::step`] ([`crate::exec::Progress`]: rows remain, or the pair is
/// rectified (`Ok`) or abandoned).
pub type RectifyProgress = crate::exec::Progress<Result<(), RectifyError>>;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Idle,
    /// Next row `row` of image `camera` (0 left, 1 right).
    Rows {
        camera: u8,
        row: u16,
    },
}

/// The rectification state: validity of the map, the pair in progress.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rectifier {
    config: RectifyConfig,
    map_valid: bool,
    stats: MapStats,
    phase: Phase,
    frame_t_us: u64,
    frame_sequence: u32,
    items: u32,
}

impl crate::exec::FrameJob for Rectifier {
    type Error = RectifyError;
    const NOT_STARTED: RectifyError = RectifyError::NotStarted;
    const FRAME_CHANGED: RectifyError = RectifyError::FrameChanged;

    fn running(&self) -> bool {
        self.phase != Phase::Idle
    }

    fn frame(&self) -> crate::exec::FrameKey {
        crate::exec::FrameKey {
            capture_t_us: self.frame_t_us,
            sequence: self.frame_sequence,
        }
    }

    fn stop(&mut self) {
        self.phase = Phase::Idle;
    }

    fn items(&self) -> u32 {
        self.items
    }
}

impl Rectifier {
    /// A rectifier without a map.
    pub const fn new(config: RectifyConfig) -> Self {
        Self {
            config,
            map_valid: false,
            stats: MapStats {
                max_round_trip_px: 0.0,
                max_iterations: 0,
                min_margin_px: 0.0,
                min_jacobian_det: 0.0,
            },
            phase: Phase::Idle,
            frame_t_us: 0,
            frame_sequence: 0,
            items: 0,
        }
    }

    /// Builds the map of `lens` into `rect`'s geometry in `memory` (module doc; about
    /// 10 000 node evaluations, once at initialisation). On error the map is invalid and
    /// [`Self::start`] refuses every pair.
    pub fn build(
        &mut self,
        lens: &LensCalibration,
        rect: &StereoCalibration,
        memory: &mut impl RectifyMemory,
    ) -> Result<MapStats, RectifyError> {
        self.map_valid = false;
        self.phase = Phase::Idle;
        let (map, left, right) = memory.parts();
        if map.len() < MAP_NODES || left.len() < IMAGE_PIXELS || right.len() < IMAGE_PIXELS {
            return Err(RectifyError::Memory);
        }
        check_rect(rect)?;
        let mut stats = MapStats {
            max_round_trip_px: 0.0,
            max_iterations: 0,
            min_margin_px: f64::INFINITY,
            min_jacobian_det: f64::INFINITY,
        };
        for (camera, nodes) in [&lens.left, &lens.right]
            .into_iter()
            .zip(map.chunks_exact_mut(LATTICE_NODES))
        {
            check_camera(camera)?;
            for (n, node) in nodes.iter_mut().enumerate() {
                let x = ((n % LATTICE_COLS) * LATTICE_STEP_PX) as f64;
                let y = ((n / LATTICE_COLS) * LATTICE_STEP_PX) as f64;
                let ray = [
                    (x - rect.cx_px) / rect.fx_px,
                    (y - rect.cy_px) / rect.fy_px,
                    1.0,
                ];
                *node = map_node(camera, ray, &mut stats)?;
            }
        }
        self.stats = stats;
        self.map_valid = true;
        Ok(stats)
    }

    /// True when a valid map was built.
    pub fn has_map(&self) -> bool {
        self.map_valid
    }

    /// Figures of the map (zero before a build).
    pub fn map_stats(&self) -> MapStats {
        self.stats
    }

    /// True while a pair is being rectified.
    pub fn is_busy(&self) -> bool {
        self.phase != Phase::Idle
    }

    /// Starts rectifying the raw pair `frame` (its images must stay unchanged until the last
    /// [`Self::step`]).
    pub fn start(&mut self, frame: &StereoFrame) -> Result<(), RectifyError> {
        if !self.map_valid {
            return Err(RectifyError::NoMap);
        }
        if self.phase != Phase::Idle {
            return Err(RectifyError::Busy);
        }
        if frame.left.len() != IMAGE_PIXELS || frame.right.len() != IMAGE_PIXELS {
            return Err(RectifyError::ImageSize);
        }
        self.frame_t_us = frame.capture_t_us;
        self.frame_sequence = frame.sequence;
        self.items = 0;
        self.phase = Phase::Rows { camera: 0, row: 0 };
        Ok(())
    }

    /// Abandons the pair in progress.
    pub fn reset(&mut self) {
        self.phase = Phase::Idle;
    }

    /// Rectifies rows of the started pair until their costs reach `quantum` units (at least
    /// one row; [`crate::exec::spend_quantum`]). `frame` must be the started pair.
    pub fn step(
        &mut self,
        frame: &StereoFrame,
        memory: &mut impl RectifyMemory,
        quantum: u32,
    ) -> RectifyProgress {
        let cost = self.config.row_cost;
        crate::exec::step_frame_job(
            self,
            frame,
            quantum,
            || Some(memory.parts()),
            |r, (map, left, right)| {
                let Phase::Rows { camera, row } = r.phase else {
                    return (cost, Some(Err(RectifyError::NotStarted)));
                };
                let (raw, out) = if camera == 0 {
                    (frame.left, &mut **left)
                } else {
                    (frame.right, &mut **right)
                };
                let nodes = map
                    .get(usize::from(camera) * LATTICE_NODES..)
                    .and_then(|m| m.get(..LATTICE_NODES));
                let start = usize::from(row) * W;
                let (Some(nodes), Some(out_row)) = (nodes, out.get_mut(start..start + W)) else {
                    return (cost, Some(Err(RectifyError::Memory)));
                };
                rectify_row(nodes, usize::from(row), raw, out_row);
                r.items = r.items.saturating_add(1);
                let next = if usize::from(row) + 1 < H {
                    Phase::Rows {
                        camera,
                        row: row + 1,
                    }
                } else if camera == 0 {
                    Phase::Rows { camera: 1, row: 0 }
                } else {
                    Phase::Idle
                };
                r.phase = next;
                (cost, (next == Phase::Idle).then_some(Ok(())))
            },
        )
    }

    /// Row items of one pair.
    pub const ITEMS_PER_PAIR: u32 = 2 * H as u32;
}

/// Checks the rectified calibration's intrinsics.
fn check_rect(rect: &StereoCalibration) -> Result<(), RectifyError> {
    let ok = [rect.fx_px, rect.fy_px]
        .iter()
        .all(|f| f.is_finite() && *f > 1.0 && *f < 1.0e5)
        && [rect.cx_px, rect.cy_px]
            .iter()
            .all(|c| c.is_finite() && c.abs() < 1.0e5);
    if ok {
        Ok(())
    } else {
        Err(RectifyError::BadCalibration)
    }
}
