//! The likelihood of the search (module doc of [`super`], "Likelihood" and "Bound"): the
//! log-likelihood of one pose, the upper bound over a box of poses and the inliers of a pose,
//! all from the tabulated per-point terms.

use super::{Leaf, Localizer, MAX_TERM_MILLI, SWEEP_SLACK_CELLS};
use crate::localization::map::GlobalMap;
use crate::localization::{MAX_D2_CELLS, MAX_HALF_YAW_STEPS};

impl Localizer {
    /// `(cos, sin)` of yaw step `t` from the table (the same values for leaves and boxes).
    fn trig(&self, t: i32) -> (f64, f64) {
        let k = (t + MAX_HALF_YAW_STEPS) as usize;
        (
            self.cos_t.get(k).copied().unwrap_or(1.0),
            self.sin_t.get(k).copied().unwrap_or(0.0),
        )
    }

    /// Map cell (floor) of the point at `(u, v)` cells, `None` when far outside any map.
    /// The floor by truncation (`as i32` rounds toward zero) and one correction for negative
    /// non-integers, for the coordinates whose floor is within `+-1e6` (`x >= -1e6` and
    /// `x < 1e6 + 1`): the same cells as `libm::floor`, in a handful of instructions instead of
    /// libm's software floor (two per point and pose).
    pub(crate) fn floor_cell(u: f64, v: f64) -> Option<(i32, i32)> {
        let lim = 1.0e6;
        if !(u >= -lim && u < lim + 1.0 && v >= -lim && v < lim + 1.0) {
            return None;
        }
        let floor = |x: f64| {
            let i = x as i32;
            if f64::from(i) > x {
                i - 1
            } else {
                i
            }
        };
        Some((floor(u), floor(v)))
    }

    /// Log-likelihood of the pose `(x, y, t)`, milli-nats (the sum of the points' terms).
    pub(crate) fn score(&mut self, global: &GlobalMap, x: i32, y: i32, t: i32) -> i32 {
        let (c, s) = self.trig(t);
        let mut sum = 0i32;
        for p in self.points.iter().take(self.n) {
            let u = self.base[0] + c * p[0] - s * p[1];
            let v = self.base[1] + s * p[0] + c * p[1];
            let d2 = match Self::floor_cell(u, v) {
                Some((i, j)) => global.d2_at(i.saturating_add(x), j.saturating_add(y)),
                None => MAX_D2_CELLS,
            };
            sum = sum.saturating_add(self.term(d2));
        }
        self.point_evaluations = self.point_evaluations.saturating_add(self.n as u32);
        sum
    }

    fn term(&self, d2: u8) -> i32 {
        self.lut
            .get(usize::from(d2))
            .copied()
            .unwrap_or(-(MAX_TERM_MILLI as i32))
    }

    /// Upper bound of the log-likelihood over the poses of `r` (milli-nats).
    pub(super) fn bound(&mut self, global: &GlobalMap, r: &[i32; 6]) -> i32 {
        let [xa, xb, ya, yb, ta, tb] = *r;
        let (c, s, half_span) = if ta == tb {
            let (c, s) = self.trig(ta);
            (c, s, 0.0)
        } else {
            let mid = 0.5 * (f64::from(ta) + f64::from(tb));
            let (s, c) = libm::sincos(self.prior[2] + mid * self.yaw_step);
            (c, s, 0.5 * f64::from(tb - ta) * self.yaw_step)
        };
        let mut sum = 0i32;
        for (p, rad) in self.points.iter().zip(self.radius.iter()).take(self.n) {
            let u = self.base[0] + c * p[0] - s * p[1];
            let v = self.base[1] + s * p[0] + c * p[1];
            let sweep = if half_span > 0.0 {
                rad * half_span + SWEEP_SLACK_CELLS
            } else {
                0.0
            };
            let d2 = match (
                Self::floor_cell(u - sweep, v - sweep),
                Self::floor_cell(u + sweep, v + sweep),
            ) {
                (Some((i0, j0)), Some((i1, j1))) => global.min_d2_window(
                    i0.saturating_add(xa),
                    i1.saturating_add(xb),
                    j0.saturating_add(ya),
                    j1.saturating_add(yb),
                ),
                _ => MAX_D2_CELLS,
            };
            sum = sum.saturating_add(self.term(d2));
        }
        self.point_evaluations = self.point_evaluations.saturating_add(self.n as u32);
        sum
    }

    /// Points within the outlier distance at the pose of `leaf`.
    pub(super) fn inliers(&self, global: &GlobalMap, leaf: &Leaf) -> u16 {
        let (c, s) = self.trig(leaf.t);
        let mut count = 0u16;
        for p in self.points.iter().take(self.n) {
            let u = self.base[0] + c * p[0] - s * p[1];
            let v = self.base[1] + s * p[0] + c * p[1];
            if let Some((i, j)) = Self::floor_cell(u, v) {
                let d2 = global.d2_at(i.saturating_add(leaf.x), j.saturating_add(leaf.y));
                if u32::from(d2) <= self.inlier_d2 {
                    count += 1;
                }
            }
        }
        count
    }
}
