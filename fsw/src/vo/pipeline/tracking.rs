//! The tracking stage of [`VisualOdometry`]: each keyframe feature searched for in the new
//! left image around its position predicted by the motion prior, refined by an affine warp and
//! stereo matched in the new pair (H04 sec. 2 "Feature Tracking"), one feature per work item.

use super::{Phase, VisualOdometry};
use crate::vo::image::Image;
use crate::vo::motion::Correspondence;
use crate::vo::stereo::{match_and_triangulate, triangulate_config};
use crate::vo::track::{refine_warp, search_near, Affine2, WarpModel};
use crate::vo::VoError;

impl<const N: usize> VisualOdometry<N> {
    /// Tracks keyframe feature `next` ([`Self::track_feature`]); after the last one, on to the
    /// motion hypotheses, or the motion fails with too few tracked features.
    #[inline(always)]
    pub(super) fn track_item(&mut self, next: usize, left: &Image, right: &Image) {
        if next < self.key_count.min(N) {
            self.track_feature(next, left, right);
            self.phase = Phase::Track { next: next + 1 };
        } else {
            self.quality.tracked = self.pair_count as u16;
            if self.pair_count < usize::from(self.config.min_tracked) {
                self.fail_motion(VoError::TooFewTracked {
                    found: self.pair_count as u16,
                });
            } else {
                self.phase = Phase::Hypotheses { done: 0 };
            }
        }
    }
    /// Tracks keyframe feature `index` into the new pair and stores the correspondence.
    fn track_feature(&mut self, index: usize, left: &Image, right: &Image) {
        let Some(feature) = self.key.get(index).copied() else {
            return;
        };
        let [xl, yl, xr, yr] = feature.pixels.map(f64::from);
        let Ok(previous) = triangulate_config(&self.camera, [xl, yl, xr, yr], &self.config) else {
            return;
        };
        // The feature's offset from its template centre (0 for a detected feature, at most half
        // a pixel for a carried one): template coordinates (du, dv) of eq. 9.
        let (du, dv) = (xl - libm::round(xl), yl - libm::round(yl));
        // Projection with the motion prior (eq. 11 without noise).
        let predicted = self.motion.rotation * previous.position_m + self.motion.translation_m;
        let Some((xp, yp)) = self.camera.project_left(&predicted) else {
            return;
        };
        if !(xp.abs() < 1e5 && yp.abs() < 1e5) {
            return;
        }
        let radius = i32::from(self.config.search_radius_px);
        let (x0, y0) = (libm::round(xp - du) as i32, libm::round(yp - dv) as i32);
        let (x0, y0) = (
            x0.saturating_add(self.flow_px.0),
            y0.saturating_add(self.flow_px.1),
        );
        let Some((xs, ys, score)) = search_near(
            &feature.template,
            left,
            x0,
            y0,
            radius,
            self.config.min_correlation,
        ) else {
            return;
        };
        if score < self.config.min_correlation {
            return;
        }
        self.flow_px = (
            (xs - x0 + self.flow_px.0).clamp(-radius, radius),
            (ys - y0 + self.flow_px.1).clamp(-radius, radius),
        );
        let template_f = feature.template.map(f32::from);
        let init = Affine2::translation(f64::from(xs), f64::from(ys));
        let Some(refined) = refine_warp(&template_f, left, init, WarpModel::Affine, 10) else {
            return;
        };
        let (xt, yt) = refined.warp.apply(du, dv);
        let shift = libm::hypot(
            refined.warp.c - f64::from(xs),
            refined.warp.f - f64::from(ys),
        );
        if !(shift <= self.config.max_refine_shift_px) {
            return;
        }
        // Disparity of the predicted point: the stereo search of a tracked feature only covers a
        // window around it (the prior already placed the feature within the tracking radius).
        let predicted_disparity = self.camera.fx_px * self.camera.baseline_m / predicted.z;
        let window = (self.config.track_disparity_margin_px > 0).then_some(predicted_disparity);
        let (current, (xr1, yr1)) = match match_and_triangulate(
            &self.camera,
            left,
            right,
            (xt, yt),
            window,
            &self.config,
        ) {
            Ok(matched) => matched,
            Err(reason) => return self.quality.stereo_rejects.count(reason),
        };
        let pair = Correspondence::new(
            previous.position_m,
            previous.covariance,
            current.position_m,
            current.covariance,
            &self.motion.rotation,
        );
        if let (Some(pair), Some(slot), Some(px)) = (
            pair,
            self.pairs.get_mut(self.pair_count),
            self.current_px.get_mut(self.pair_count),
        ) {
            *slot = pair;
            *px = [xt as f32, yt as f32, xr1 as f32, yr1 as f32];
            self.pair_count += 1;
        }
    }
}
