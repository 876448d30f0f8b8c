//! The result of a localization ([`LocalizationFix`]) and its last step: the sub-step peak
//! around the optimum and the covariance from the likelihood's fall-off (module doc of
//! [`super`], "Peak and covariance").

use super::{Leaf, Localizer, FIT_HALF};
use crate::localization::map::GlobalMap;
use crate::localization::{LocalizationError, MAP_CELL_M};

/// A localization: the pose of the grid frame `G` in `W` and its covariance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalizationFix {
    /// Pose of `G` in `W`: `[x north (m), y east (m), heading (rad)]` (sub-step peak).
    pub pose: [f64; 3],
    /// Covariance of `pose`, `[x, y, heading]` (m^2, m^2 rad, rad^2).
    pub covariance: [[f64; 3]; 3],
    /// The prior pose of `G` the search started from.
    pub prior: [f64; 3],
    /// Log-likelihood at the best discrete pose, nats (0 when every point is at distance 0).
    pub log_likelihood: f64,
    /// Gap to the best pose found outside the peak's neighbourhood, nats; `None` when no pose
    /// outside it comes within [`LocalizerConfig::ambiguity_nats`].
    pub runner_up_gap_nats: Option<f64>,
    /// Points of the scan.
    pub points: u16,
    /// Inliers at the best discrete pose (distance at most `outlier_distance_m`).
    pub inliers: u16,
    /// Nodes evaluated (bounds and poses, both passes).
    pub nodes: u32,
    /// Point terms evaluated (nodes times points, plus the peak fit).
    pub point_evaluations: u32,
    /// Largest number of queued boxes.
    pub queue_peak: u16,
    /// Yaw step of the pose space, rad.
    pub yaw_step_rad: f64,
    /// Half-widths of the search window: cells, cells, yaw steps.
    pub window: [i32; 3],
}

impl LocalizationFix {
    /// The correction carried to another point of the rover rigidly attached to `G` (the
    /// rover reference point of the estimator): given its estimated pose at capture
    /// `estimated = [x, y, yaw]` (`W`, m, rad; estimated with the same error as the prior),
    /// its corrected pose and covariance. With the lever arm `l = R(prior_yaw)' (xy - prior_xy)`
    /// in `G`: `xy' = pose_xy + R(pose_yaw) l`, `yaw' = yaw + pose_yaw - prior_yaw`, covariance
    /// `J P J'` with `J = [[1, 0, -(R l)_y], [0, 1, (R l)_x], [0, 0, 1]]`. `None` for a
    /// non-finite input.
    pub fn transfer(&self, estimated: [f64; 3]) -> Option<([f64; 3], [[f64; 3]; 3])> {
        if !estimated.iter().all(|v| v.is_finite()) {
            return None;
        }
        let (s0, c0) = libm::sincos(self.prior[2]);
        let (dx, dy) = (estimated[0] - self.prior[0], estimated[1] - self.prior[1]);
        let l = [c0 * dx + s0 * dy, -s0 * dx + c0 * dy];
        let (s, c) = libm::sincos(self.pose[2]);
        let rl = [c * l[0] - s * l[1], s * l[0] + c * l[1]];
        let pose = [
            self.pose[0] + rl[0],
            self.pose[1] + rl[1],
            estimated[2] + self.pose[2] - self.prior[2],
        ];
        let j = [[1.0, 0.0, -rl[1]], [0.0, 1.0, rl[0]], [0.0, 0.0, 1.0]];
        Some((pose, congruence(&j, &self.covariance)))
    }
}

/// `J P J'` for 3x3 matrices (also the navigator's lever-arm transfer).
pub(crate) fn congruence(j: &[[f64; 3]; 3], p: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            let mut acc = 0.0;
            for a in 0..3 {
                for b in 0..3 {
                    acc += j[r][a] * p[a][b] * j[c][b];
                }
            }
            *v = acc;
        }
    }
    out
}

impl Localizer {
    /// Sub-step peak, covariance and the fix (after both passes).
    pub(super) fn finish(
        &mut self,
        global: &GlobalMap,
    ) -> Result<LocalizationFix, LocalizationError> {
        let b = self.best;
        let s0 = f64::from(b.score);
        let peak = self.sub_step_peak(global, &b);
        let cov_c = self.peak_covariance(global, &b, &peak)?;
        // Centroid pose to the pose of G: o = T - R(yaw) c.
        let origin = global.origin_m();
        let t_w = [
            origin[0] + (self.base[0] + peak[0]) * MAP_CELL_M,
            origin[1] + (self.base[1] + peak[1]) * MAP_CELL_M,
        ];
        let yaw = self.prior[2] + peak[2] * self.yaw_step;
        let (s, c) = libm::sincos(yaw);
        let cg = self.centroid_g_m;
        let rc = [c * cg[0] - s * cg[1], s * cg[0] + c * cg[1]];
        let pose = [t_w[0] - rc[0], t_w[1] - rc[1], yaw];
        let j = [[1.0, 0.0, rc[1]], [0.0, 1.0, -rc[0]], [0.0, 0.0, 1.0]];
        let covariance = congruence(&j, &cov_c);
        let finite = pose
            .iter()
            .chain(covariance.iter().flatten())
            .all(|v| v.is_finite());
        let positive = covariance[0][0] > 0.0 && covariance[1][1] > 0.0 && covariance[2][2] > 0.0;
        if !(finite && positive) {
            return Err(LocalizationError::DegenerateCovariance);
        }
        Ok(LocalizationFix {
            pose,
            covariance,
            prior: self.prior,
            log_likelihood: s0 / 1000.0,
            runner_up_gap_nats: self.runner_up.map(|r| f64::from(b.score - r) / 1000.0),
            points: self.n as u16,
            inliers: self.inliers(global, &b),
            nodes: self.nodes,
            point_evaluations: self.point_evaluations,
            queue_peak: self.queue_peak as u16,
            yaw_step_rad: self.yaw_step,
            window: self.half,
        })
    }

    /// The sub-step peak around the optimum `b`, pose steps `[x, y, t]`: on each axis the
    /// vertex of the parabola through `b` and its two neighbours (within half a step; `b`'s
    /// own coordinate where the likelihood does not curve down).
    fn sub_step_peak(&mut self, global: &GlobalMap, b: &Leaf) -> [f64; 3] {
        let s0 = f64::from(b.score);
        // Parabola through the optimum and its neighbours on each axis.
        let mut offset = [0.0f64; 3];
        for (axis, o) in offset.iter_mut().enumerate() {
            let step = |k: i32| match axis {
                0 => (b.x + k, b.y, b.t),
                1 => (b.x, b.y + k, b.t),
                _ => (b.x, b.y, b.t + k),
            };
            let (xm, ym, tm) = step(-1);
            let (xp, yp, tp) = step(1);
            let sm = f64::from(self.score(global, xm, ym, tm));
            let sp = f64::from(self.score(global, xp, yp, tp));
            let curvature = sm - 2.0 * s0 + sp;
            if curvature < 0.0 {
                *o = (0.5 * (sm - sp) / curvature).clamp(-0.5, 0.5);
            }
        }
        [
            f64::from(b.x) + offset[0],
            f64::from(b.y) + offset[1],
            f64::from(b.t) + offset[2],
        ]
    }

    /// The covariance of the centroid pose `[x, y, yaw]` (m^2, m^2 rad, rad^2) about `peak`:
    /// the second moment of `exp(L - L_max)` over the `5 x 5 x 5` poses around the optimum `b`
    /// (inside the window), plus the quantisation variance `step^2 / 12` on the diagonal, times
    /// [`LocalizerConfig::covariance_scale`](super::LocalizerConfig::covariance_scale).
    fn peak_covariance(
        &mut self,
        global: &GlobalMap,
        b: &Leaf,
        peak: &[f64; 3],
    ) -> Result<[[f64; 3]; 3], LocalizationError> {
        let s0 = f64::from(b.score);
        // Second moment of exp(L - L_max) about the peak over the 5 x 5 x 5 poses.
        let mut m = [[0.0f64; 3]; 3];
        let mut w_sum = 0.0;
        for dx in -FIT_HALF..=FIT_HALF {
            for dy in -FIT_HALF..=FIT_HALF {
                for dt in -FIT_HALF..=FIT_HALF {
                    let (x, y, t) = (b.x + dx, b.y + dy, b.t + dt);
                    if x.abs() > self.half[0] || y.abs() > self.half[1] || t.abs() > self.half[2] {
                        continue;
                    }
                    let s = if dx == 0 && dy == 0 && dt == 0 {
                        s0
                    } else {
                        f64::from(self.score(global, x, y, t))
                    };
                    let w = libm::exp((s - s0) / 1000.0);
                    let d = [
                        f64::from(x) - peak[0],
                        f64::from(y) - peak[1],
                        f64::from(t) - peak[2],
                    ];
                    for (r, row) in m.iter_mut().enumerate() {
                        for (c, v) in row.iter_mut().enumerate() {
                            *v += w * d[r] * d[c];
                        }
                    }
                    w_sum += w;
                }
            }
        }
        if !(w_sum > 0.0) {
            return Err(LocalizationError::DegenerateCovariance);
        }
        // Steps to m, m, rad; quantisation variance step^2 / 12 on the diagonal.
        let unit = [MAP_CELL_M, MAP_CELL_M, self.yaw_step];
        let mut cov_c = [[0.0f64; 3]; 3];
        for (r, row) in cov_c.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                let q = if r == c { 1.0 / 12.0 } else { 0.0 };
                *v = (m[r][c] / w_sum + q) * unit[r] * unit[c] * self.config.covariance_scale;
            }
        }
        Ok(cov_c)
    }
}
