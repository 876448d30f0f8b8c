//! # Stereo rectification of the raw hazcam pair (issue 15 item 4)
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
//! [`rectify_row`] computes these bytes cell by cell (issue 18): a planned cell whose pixels
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

#[cfg(test)]
mod tests;

use rover_hal::{
    LensCalibration, RawCamera, StereoCalibration, StereoFrame, IMAGE_HEIGHT_PX, IMAGE_PIXELS,
    IMAGE_WIDTH_PX,
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

/// Checks one raw camera: finite values, positive focal lengths, coefficients within +-100,
/// an orthonormal rotation.
fn check_camera(c: &RawCamera) -> Result<(), RectifyError> {
    let intrinsics = [c.fx_px, c.fy_px]
        .iter()
        .all(|f| f.is_finite() && *f > 1.0 && *f < 1.0e5)
        && [c.cx_px, c.cy_px]
            .iter()
            .all(|v| v.is_finite() && v.abs() < 1.0e5);
    let coefficients = [c.k1, c.k2, c.k3, c.p1, c.p2]
        .iter()
        .all(|k| k.is_finite() && k.abs() <= 100.0);
    let r = &c.rot_raw_from_rect;
    let mut orthonormal = r.iter().flatten().all(|v| v.is_finite());
    for i in 0..3 {
        for j in 0..3 {
            let dot = r[0][i] * r[0][j] + r[1][i] * r[1][j] + r[2][i] * r[2][j];
            let want = if i == j { 1.0 } else { 0.0 };
            orthonormal &= libm::fabs(dot - want) < 1e-6;
        }
    }
    if intrinsics && coefficients && orthonormal {
        Ok(())
    } else {
        Err(RectifyError::BadCalibration)
    }
}

/// Raw position of the rectified ray `ray` (module doc), with the node checks; updates `stats`.
fn map_node(c: &RawCamera, ray: [f64; 3], stats: &mut MapStats) -> Result<MapNode, RectifyError> {
    let r = &c.rot_raw_from_rect;
    let a = [0, 1, 2].map(|i| r[i][0] * ray[0] + r[i][1] * ray[1] + r[i][2] * ray[2]);
    if a[2].is_nan() || a[2] <= 1e-6 {
        return Err(RectifyError::BadRay);
    }
    let (x, y) = (a[0] / a[2], a[1] / a[2]);
    let [xd, yd] = distort(c, x, y);
    if !(xd.is_finite() && yd.is_finite()) || libm::fabs(xd).max(libm::fabs(yd)) > MAX_NORMALIZED {
        return Err(RectifyError::BadRay);
    }
    let det = jacobian_det(c, x, y);
    if det.is_nan() || det < MIN_JACOBIAN_DET {
        return Err(RectifyError::Folded);
    }
    stats.min_jacobian_det = stats.min_jacobian_det.min(det);
    let (back, iterations) = undistort(c, xd, yd).ok_or(RectifyError::NotConverged)?;
    let round_trip = libm::hypot((back[0] - x) * c.fx_px, (back[1] - y) * c.fy_px);
    if round_trip.is_nan() || round_trip > ROUND_TRIP_TOL_PX {
        return Err(RectifyError::NotConverged);
    }
    stats.max_round_trip_px = stats.max_round_trip_px.max(round_trip);
    stats.max_iterations = stats.max_iterations.max(iterations);
    let u = c.cx_px + c.fx_px * xd;
    let v = c.cy_px + c.fy_px * yd;
    // Room for the bilinear neighbourhood: 0 <= u < W - 1, 0 <= v < H - 1.
    let margin = u.min((W - 1) as f64 - u).min(v).min((H - 1) as f64 - v);
    if margin.is_nan() || margin <= 1.0 / 256.0 {
        return Err(RectifyError::FieldNotCovered);
    }
    stats.min_margin_px = stats.min_margin_px.min(margin);
    let scale = f64::from(1u32 << NODE_FRAC_BITS);
    // In range: 0 < u < 639, 0 < v < 479 (checked above), so the products fit an i32.
    Ok(MapNode {
        u: libm::floor(u * scale) as i32,
        v: libm::floor(v * scale) as i32,
    })
}

/// Brown-Conrady distortion of the normalized point `(x, y)` ([`RawCamera`] equations).
pub fn distort(c: &RawCamera, x: f64, y: f64) -> [f64; 2] {
    let r2 = x * x + y * y;
    let g = 1.0 + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3));
    [
        x * g + 2.0 * c.p1 * x * y + c.p2 * (r2 + 2.0 * x * x),
        y * g + c.p1 * (r2 + 2.0 * y * y) + 2.0 * c.p2 * x * y,
    ]
}

/// Jacobian of [`distort`] (rows `x_d`, `y_d`; columns `x`, `y`).
fn jacobian(c: &RawCamera, x: f64, y: f64) -> [[f64; 2]; 2] {
    let r2 = x * x + y * y;
    let g = 1.0 + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3));
    let dg = c.k1 + r2 * (2.0 * c.k2 + 3.0 * r2 * c.k3);
    let cross = 2.0 * x * y * dg + 2.0 * c.p1 * x + 2.0 * c.p2 * y;
    [
        [
            g + 2.0 * x * x * dg + 2.0 * c.p1 * y + 6.0 * c.p2 * x,
            cross,
        ],
        [
            cross,
            g + 2.0 * y * y * dg + 6.0 * c.p1 * y + 2.0 * c.p2 * x,
        ],
    ]
}

fn jacobian_det(c: &RawCamera, x: f64, y: f64) -> f64 {
    let j = jacobian(c, x, y);
    j[0][0] * j[1][1] - j[0][1] * j[1][0]
}

/// Undistorted normalized point of the distorted normalized point `(xd, yd)`: Newton's
/// method from `(xd, yd)`, at most [`UNDISTORT_ITERATIONS`] steps, converged when the
/// residual is below 1e-12 (about 4e-10 px at the hazcam's focal length). Returns the point
/// and the steps taken; `None` when it does not converge, a step meets a (nearly) singular
/// Jacobian, or a value is not finite.
pub fn undistort(c: &RawCamera, xd: f64, yd: f64) -> Option<([f64; 2], u32)> {
    if !(xd.is_finite() && yd.is_finite()) {
        return None;
    }
    let (mut x, mut y) = (xd, yd);
    for k in 0..UNDISTORT_ITERATIONS {
        let [fx, fy] = distort(c, x, y);
        let (ex, ey) = (fx - xd, fy - yd);
        if !(ex.is_finite() && ey.is_finite()) {
            return None;
        }
        if libm::fabs(ex).max(libm::fabs(ey)) < 1e-12 {
            return Some(([x, y], k as u32));
        }
        let j = jacobian(c, x, y);
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if det.is_nan() || libm::fabs(det) <= 1e-9 {
            return None;
        }
        x -= (j[1][1] * ex - j[0][1] * ey) / det;
        y -= (j[0][0] * ey - j[1][0] * ex) / det;
        if libm::fabs(x).max(libm::fabs(y)) > MAX_NORMALIZED {
            return None;
        }
    }
    None
}

/// Fractional bits of a column-interpolated node (1/256 px x 8 = 1/2048 px).
const NODE_BITS: u32 = Q_FRAC_BITS - 3;
/// Bytes of a fast cell's window of the raw image: from one byte before the cell's first raw
/// pixel (so that every load of [`packed_cell`] has a nonzero offset from one address, one
/// instruction less per pixel on the rover CPU), the 2 x 2 neighbourhoods at `x_rel <= 7`,
/// `y_rel <= 1` from that pixel.
const WINDOW_LEN: usize = 1 + 7 + W + W + 2;

/// Rectifies row `row` of one image: `nodes` is that camera's lattice ([`LATTICE_NODES`]),
/// `raw` the raw image ([`IMAGE_PIXELS`] bytes), `out` the rectified row ([`IMAGE_WIDTH_PX`]
/// bytes). Pixels whose raw neighbourhood is outside `raw` (or whose nodes are missing) get 0.
///
/// The same bytes as the per-pixel formula of the module doc for every input (RECT-7),
/// computed cell by cell (issue 18). Along a cell the raw position is affine, between the
/// cell's two column-interpolated nodes. A cell whose pixels all have their 2 x 2
/// neighbourhood inside the raw image and stay within 8 raw columns and 2 raw rows of its first
/// pixel is planned ([`plan_cell`]) and then run on one window of the raw image with a single
/// packed position register ([`packed_cell`]); any other cell takes the checked per-pixel
/// path.
pub fn rectify_row(nodes: &[MapNode], row: usize, raw: &[u8], out: &mut [u8]) {
    let j = row / LATTICE_STEP_PX;
    let b = (row % LATTICE_STEP_PX) as i32;
    let lattice_row = |jj: usize| nodes.get(jj * LATTICE_COLS..(jj + 1) * LATTICE_COLS);
    let (Some(upper), Some(lower)) = (lattice_row(j), lattice_row(j + 1)) else {
        out.fill(0);
        return;
    };
    // The two lattice rows as one array (upper row, then lower row), the raw image and the
    // output row as arrays.
    let pair: Option<&[MapNode; 2 * LATTICE_COLS]> = nodes
        .get(j * LATTICE_COLS..(j + 2) * LATTICE_COLS)
        .and_then(|s| s.try_into().ok());
    let image: Option<&[u8; IMAGE_PIXELS]> =
        raw.get(..IMAGE_PIXELS).and_then(|s| s.try_into().ok());
    let (Some(image), Some(pair), true) = (image, pair, out.len() == W) else {
        // An output row other than W pixels, or a raw image too short: every cell on the
        // checked path.
        checked_cells(upper, lower, b, raw, out);
        return;
    };
    let Ok(row_out) = <&mut [u8; W]>::try_from(out) else {
        return;
    };
    let nodes: [(i32, i32); LATTICE_COLS] =
        core::array::from_fn(|i| match (pair.get(i), pair.get(LATTICE_COLS + i)) {
            (Some(p0), Some(p1)) => column(p0, p1, b),
            _ => (-1, -1),
        });
    run_row(image, &nodes, row_out);
}

/// The cells of a row between the column-interpolated `nodes`: planned ([`plan_cell`]) and run
/// on their window ([`packed_cell`]), or on the checked path.
#[inline(never)]
fn run_row(image: &[u8; IMAGE_PIXELS], nodes: &[(i32, i32); LATTICE_COLS], out: &mut [u8; W]) {
    // The rounding term 2^15 of the formula, opaque to the optimiser so that it stays in a
    // register and folds into the last multiply-accumulate (one instruction less per pixel).
    let rounding = core::hint::black_box(1 << 15);
    for (cell, out_cell) in out.chunks_exact_mut(LATTICE_STEP_PX).enumerate() {
        let (Some(&left), Some(&right)) = (nodes.get(cell), nodes.get(cell + 1)) else {
            continue;
        };
        let fast = plan_cell(left, right).and_then(|plan| Some((plan, plan.window(image)?)));
        match (fast, <&mut [u8; LATTICE_STEP_PX]>::try_from(&mut *out_cell)) {
            (Some((plan, (window, false))), Ok(cell_out)) => {
                packed_cell::<false>(window, cell_out, plan.a, plan.d, rounding)
            }
            (Some((plan, (window, true))), Ok(cell_out)) => {
                packed_cell::<true>(window, cell_out, plan.a, plan.d, rounding)
            }
            // The raw image's first IMAGE_PIXELS bytes are all the checked path can read.
            _ => checked_cell(image, out_cell, left, right),
        }
    }
}

/// Column interpolation of the nodes `p0` (upper) and `p1` (lower) at row fraction `b`
/// (1/2048 px; wrapping like the i32 arithmetic of the module doc's formula in the flight
/// build).
#[inline(always)]
fn column(p0: &MapNode, p1: &MapNode, b: i32) -> (i32, i32) {
    let c0 = LATTICE_STEP_PX as i32 - b;
    (
        p0.u.wrapping_mul(c0).wrapping_add(p1.u.wrapping_mul(b)),
        p0.v.wrapping_mul(c0).wrapping_add(p1.v.wrapping_mul(b)),
    )
}

/// A planned fast cell of [`rectify_row`]: `a`, `d` of [`packed_cell`] and the offset of its
/// first raw pixel in the raw image (bit 31: the cell touches two raw rows).
#[derive(Clone, Copy)]
struct CellPlan {
    a: u32,
    d: u32,
    offset: u32,
}

impl CellPlan {
    /// Bit of `offset` marking a cell on two raw rows.
    const TWO_ROWS: u32 = 1 << 31;

    /// The cell's window of `image` ([`WINDOW_LEN`]) and whether it touches two rows; `None`
    /// for a window that would start before the image (a cell at the first pixel) or reach
    /// past its end (next to the last rows): such cells are left to the checked path.
    #[inline(always)]
    fn window(self, image: &[u8; IMAGE_PIXELS]) -> Option<(&[u8; WINDOW_LEN], bool)> {
        let offset = ((self.offset & !Self::TWO_ROWS) as usize).checked_sub(1)?;
        let window = image.get(offset..offset + WINDOW_LEN)?.try_into().ok()?;
        Some((window, self.offset & Self::TWO_ROWS != 0))
    }
}

/// The plan of the cell between the column-interpolated nodes `(lu, lv)` and `(ru, rv)`
/// (1/2048 px) for [`packed_cell`]; `None` when a pixel of the cell has no room for its
/// 2 x 2 neighbourhood in the image, or the cell's pixels leave 8 raw columns or 2 raw rows
/// from its first one. Each condition is "a value below 2^k"; they are tested together on the
/// OR of the values shifted right by their k.
#[inline(always)]
fn plan_cell((lu, lv): (i32, i32), (ru, rv): (i32, i32)) -> Option<CellPlan> {
    let (lu, lv, ru, rv) = (lu as u32, lv as u32, ru as u32, rv as u32);
    // Both columns and rows in 0..1024 px: the steps below cannot overflow.
    let nodes_out = (lu | ru | lv | rv) >> (NODE_BITS + 10);
    let (du, dv) = (ru.wrapping_sub(lu), rv.wrapping_sub(lv));
    // First pixel's column x0 and its fraction (1/16384 px); the last pixel's column
    // relative to x0 must stay below 8 (its field in the packed position).
    let x0 = lu >> NODE_BITS;
    let qu_frac = (lu & ((1 << NODE_BITS) - 1)) << 3;
    let last = qu_frac.wrapping_add(du.wrapping_mul(LATTICE_STEP_PX as u32 - 1));
    // The rightmost pixel column (x0, or x0 + last / 2^14 when the row runs right) must have
    // its right neighbour in the image: x <= W - 2, i.e. x + (1024 - (W - 1)) < 1024.
    let x_max = x0 + (last >> Q_FRAC_BITS) + (1024 - (W as u32 - 1));
    // The upper of the cell's (at most two) raw rows, from the rows of both nodes; the rows of
    // both nodes relative to it (so of every pixel between them) must lie in 0..2 px, and the
    // lower row must have its lower neighbour in the image: y_base + 1 <= H - 2.
    let (y0, y8) = (lv >> NODE_BITS, rv >> NODE_BITS);
    let dy = y8.wrapping_sub(y0) as i32;
    let y_base = y0.wrapping_add((dy >> 1) as u32);
    let v0 = (lv << 3).wrapping_sub(y_base << Q_FRAC_BITS);
    let v8 = (rv << 3).wrapping_sub(y_base << Q_FRAC_BITS);
    let y_max = y_base + 1 + (1024 - (H as u32 - 1));
    let out = nodes_out
        | (last >> (Q_FRAC_BITS + 3))
        | ((x_max | y_max) >> 10)
        | ((v0 | v8) >> (Q_FRAC_BITS + 1));
    if out != 0 {
        return None;
    }
    let offset = y_base * W as u32 + x0;
    Some(CellPlan {
        a: (qu_frac << 15) | v0,
        d: (du << 15).wrapping_add(dv),
        // dy is -1, 0 or 1 here: bit 31 set exactly when the cell touches two rows.
        offset: offset | (dy as u32) << 31,
    })
}

/// One fast cell ([`rectify_row`]): `a` packs the first pixel's raw position relative to the
/// window's first pixel `(x0, y_base)`: bits 15..31 the column `qu - x0 2^14` (1/16384 px,
/// below 8 px), bits 0..14 the row `qv - y_base 2^14` (below 2 px); `d` packs the per-pixel
/// step the same way. Every position of the cell stays inside both fields (checked by the
/// caller), so `a + k d` is exactly the packed position of pixel `k`. `TWO_ROWS`: the cell
/// touches two raw rows (else the row bit is always 0).
#[inline(always)]
fn packed_cell<const TWO_ROWS: bool>(
    window: &[u8; WINDOW_LEN],
    out: &mut [u8],
    mut a: u32,
    d: u32,
    rounding: i32,
) {
    for px in out.iter_mut() {
        let x = 1 + (a >> 29) as usize;
        let o = if TWO_ROWS {
            x + ((a >> Q_FRAC_BITS) & 1) as usize * W
        } else {
            x
        };
        let wx = ((a >> 21) & 0xff) as i32;
        let wy = ((a >> (Q_FRAC_BITS - 8)) & 0xff) as i32;
        if let Some(&[i00, i10, .., i01, i11]) = window.get(o..o + W + 2) {
            *px = bilinear_rounded([i00, i10, i01, i11], wx, wy, rounding);
        }
        // Keeps the next pixel's loads after this store: eight interleaved pixels run out
        // of registers on the rover CPU (a compiler-only barrier, no instruction is emitted).
        core::sync::atomic::compiler_fence(core::sync::atomic::Ordering::SeqCst);
        a = a.wrapping_add(d);
    }
}

/// The checked per-pixel path of [`rectify_row`] for all cells of `out`, lattice rows `upper`,
/// `lower` at row fraction `b`.
fn checked_cells(upper: &[MapNode], lower: &[MapNode], b: i32, raw: &[u8], out: &mut [u8]) {
    let step = LATTICE_STEP_PX as i32;
    for (cell, out_cell) in out.chunks_mut(LATTICE_STEP_PX).enumerate() {
        let corners = (upper.get(cell..cell + 2), lower.get(cell..cell + 2));
        let (Some(&[p00, p10]), Some(&[p01, p11])) = corners else {
            out_cell.fill(0);
            continue;
        };
        let column = |p0: MapNode, p1: MapNode| {
            (
                p0.u.wrapping_mul(step - b)
                    .wrapping_add(p1.u.wrapping_mul(b)),
                p0.v.wrapping_mul(step - b)
                    .wrapping_add(p1.v.wrapping_mul(b)),
            )
        };
        checked_cell(raw, out_cell, column(p00, p01), column(p10, p11));
    }
}

/// One cell on the checked path: left and right column-interpolated nodes `(lu, lv)`,
/// `(ru, rv)` (1/2048 px); the raw position `q` in 1/16384 px is stepped by `R - L` per
/// pixel (wrapping, like the flight build's i32 arithmetic).
#[inline(never)]
fn checked_cell(raw: &[u8], out: &mut [u8], (lu, lv): (i32, i32), (ru, rv): (i32, i32)) {
    let step = LATTICE_STEP_PX as i32;
    let (mut qu, mut qv) = (lu.wrapping_mul(step), lv.wrapping_mul(step));
    let (du, dv) = (ru.wrapping_sub(lu), rv.wrapping_sub(lv));
    for px in out.iter_mut() {
        *px = sample(raw, qu, qv);
        qu = qu.wrapping_add(du);
        qv = qv.wrapping_add(dv);
    }
}

/// Bilinear sample of `raw` at `(qu, qv)` (1/16384 px), 8-bit weights, rounded half up; 0
/// outside.
#[inline(always)]
fn sample(raw: &[u8], qu: i32, qv: i32) -> u8 {
    if qu < 0 || qv < 0 {
        return 0;
    }
    let (x, y) = ((qu >> Q_FRAC_BITS) as usize, (qv >> Q_FRAC_BITS) as usize);
    if x + 1 >= W || y + 1 >= H {
        return 0;
    }
    let wx = (qu >> (Q_FRAC_BITS - 8)) & 0xff;
    let wy = (qv >> (Q_FRAC_BITS - 8)) & 0xff;
    let top = y * W + x;
    // The 2 x 2 neighbourhood: one window of W + 2 bytes, indexed at fixed offsets inside it.
    let Some(window) = raw.get(top..top + W + 2) else {
        return 0;
    };
    let (Some(&i00), Some(&i10), Some(&i01), Some(&i11)) = (
        window.first(),
        window.get(1),
        window.get(W),
        window.get(W + 1),
    ) else {
        return 0;
    };
    bilinear([i00, i10, i01, i11], wx, wy)
}

/// The module doc's bilinear formula for the neighbourhood `[I00, I10, I01, I11]` and the
/// weights `wx`, `wy` (0..=255): `I00 (256 - wx) + I10 wx = 256 I00 + (I10 - I00) wx`,
/// exactly (and the same along y), so three multiplications; every term fits an i32.
#[inline(always)]
fn bilinear(i: [u8; 4], wx: i32, wy: i32) -> u8 {
    bilinear_rounded(i, wx, wy, 1 << 15)
}

/// [`bilinear`] with its rounding term `rounding` (always `2^15`) passed in.
#[inline(always)]
fn bilinear_rounded([i00, i10, i01, i11]: [u8; 4], wx: i32, wy: i32, rounding: i32) -> u8 {
    let (i00, i10, i01, i11) = (
        i32::from(i00),
        i32::from(i10),
        i32::from(i01),
        i32::from(i11),
    );
    let upper = (i00 << 8) + (i10 - i00) * wx;
    let lower = (i01 << 8) + (i11 - i01) * wx;
    (((upper << 8) + rounding + (lower - upper) * wy) >> 16) as u8
}
