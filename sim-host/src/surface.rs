//! The terrain as the renderer and the vehicle model see it.

/// A terrain surface in the world frame `W` of the simulator (x north, y east, z down, metres;
/// the same axes as the flight software's navigation frame `N`).
///
/// `height_m` is the ground elevation above the datum (positive up, so the ground point is
/// `(x, y, -height_m)` in `W`); `albedo` is the ground's reflectance in `[0, 1]`.
pub trait TerrainSurface: Sync {
    /// Elevation of the ground above the datum at `(x_m, y_m)`, metres (positive up).
    fn height_m(&self, x_m: f64, y_m: f64) -> f64;
    /// Reflectance of the ground at `(x_m, y_m)`, in `[0, 1]`.
    fn albedo(&self, x_m: f64, y_m: f64) -> f64;
    /// Whether the height has discontinuities (vertical faces of steps and blocks); the wheel
    /// contact search then looks for edges between its samples. Default: none.
    fn has_edges(&self) -> bool {
        false
    }
    /// Unit upward normal `(n_x, n_y, n_up)` at `(x_m, y_m)`; the default differentiates
    /// `height_m` numerically over 1 cm.
    fn normal_up(&self, x_m: f64, y_m: f64) -> [f64; 3] {
        let h = 0.01;
        let dzdx = (self.height_m(x_m + h, y_m) - self.height_m(x_m - h, y_m)) / (2.0 * h);
        let dzdy = (self.height_m(x_m, y_m + h) - self.height_m(x_m, y_m - h)) / (2.0 * h);
        let n = (dzdx * dzdx + dzdy * dzdy + 1.0).sqrt();
        [-dzdx / n, -dzdy / n, 1.0 / n]
    }
}
