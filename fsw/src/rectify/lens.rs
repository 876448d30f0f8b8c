//! The raw cameras' lens model (Brown-Conrady radial-tangential, equations in
//! [`RawCamera`]): its checks, the distortion, its Jacobian, the bounded inverse and the raw
//! position of one lattice node of the map (module doc of [`super`], "Map").

use super::{
    MapNode, MapStats, RectifyError, H, MAX_NORMALIZED, MIN_JACOBIAN_DET, NODE_FRAC_BITS,
    ROUND_TRIP_TOL_PX, UNDISTORT_ITERATIONS, W,
};
use rover_hal::RawCamera;

/// Checks one raw camera: finite values, positive focal lengths, coefficients within +-100,
/// an orthonormal rotation.
pub(super) fn check_camera(c: &RawCamera) -> Result<(), RectifyError> {
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
pub(super) fn map_node(
    c: &RawCamera,
    ray: [f64; 3],
    stats: &mut MapStats,
) -> Result<MapNode, RectifyError> {
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
