//! The keyframe stage of [`VisualOdometry`]: the motion's inliers carried into the next
//! keyframe (feature persistence), the Forstner operator row by row away from them, the
//! best-first selection of new features with the minimum distance (H04 sec. 2 "Feature
//! Selection"), their templates and stereo matches, and the commit of the keyframe and the
//! output. Work items of at most [`SORT_CHUNK`] features or candidates, one image row, or one
//! stereo match.

use super::{KeyFeature, Phase, VisualOdometry, SORT_CHUNK};
use crate::vo::features::{select_more, BORDER_PX, END_ROW, FIRST_ROW, GRID_COLS, GRID_PX};
use crate::vo::image::Image;
use crate::vo::motion::relative_pose;
use crate::vo::stereo::match_and_triangulate;
use crate::vo::{VoError, VoOutput};

impl<const N: usize> VisualOdometry<N> {
    /// Carries up to [`SORT_CHUNK`] correspondences into the next keyframe
    /// ([`Self::seed_carried`]); after the last one, on to detection.
    #[inline(always)]
    pub(super) fn seed_item(&mut self, next: usize) {
        let stop = (next + SORT_CHUNK).min(self.pair_count.min(N));
        for index in next..stop {
            self.seed_carried(index);
        }
        self.phase = if stop < self.pair_count.min(N) {
            Phase::Seed { next: stop }
        } else {
            Phase::Detect { row: FIRST_ROW }
        };
    }

    /// The Forstner operator on image row `row` of the left image, the cells covered by the
    /// carried features skipped ([`Self::skip_mask`], once per grid row); after the last row,
    /// on to the selection.
    #[inline(always)]
    pub(super) fn detect_item(&mut self, row: usize, left: &Image) {
        if row < END_ROW {
            if row == FIRST_ROW || row % GRID_PX == 0 {
                self.skip_cells = self.skip_mask(row / GRID_PX);
            }
            let skip = self.skip_cells;
            self.detector
                .process_row_masked(left, row, &self.config, skip);
            self.phase = Phase::Detect { row: row + 1 };
        } else {
            self.phase = Phase::Select;
        }
    }

    /// Compacts the candidates and starts the best-first heap behind the carried features.
    #[inline(always)]
    pub(super) fn select_item(&mut self) {
        // Sort and select in bounded chunks (at most SORT_CHUNK heap steps or
        // candidates per item), the same operations in the same order as one sort.
        let n = self.detector.compact_candidates();
        self.selected_count = self.carried.min(N);
        self.phase = Phase::Heapify { next: n / 2 };
    }

    /// Up to [`SORT_CHUNK`] steps of building the best-first heap, from `next` down.
    #[inline(always)]
    pub(super) fn heapify_item(&mut self, next: usize) {
        let stop = next.saturating_sub(SORT_CHUNK);
        for start in (stop..next).rev() {
            self.detector.best_heapify_step(start);
        }
        self.phase = if stop == 0 {
            Phase::Choose {
                left: self.detector.candidates().len(),
            }
        } else {
            Phase::Heapify { next: stop }
        };
    }

    /// Up to [`SORT_CHUNK`] candidates popped best first (`left` still in the heap) and
    /// selected with the minimum distance; when the features are found or the candidates run
    /// out, the keyframe is cleared for the new one, or the update fails with too few
    /// features.
    #[inline(always)]
    pub(super) fn choose_item(&mut self, mut left: usize) -> Option<Result<VoOutput, VoError>> {
        // The candidates best first, popped from the heap only as far as the greedy
        // selection needs them (the order of the full sort, `features::pop_best`).
        let mut count = self.selected_count;
        for _ in 0..SORT_CHUNK {
            if count >= self.selected.len() {
                break;
            }
            let Some(c) = self.detector.pop_best(left) else {
                break;
            };
            left -= 1;
            count = select_more(
                core::slice::from_ref(&c),
                self.config.min_distance_px,
                &mut self.selected,
                count,
            );
        }
        self.selected_count = count;
        if left > 0 && count < self.selected.len() {
            self.phase = Phase::Choose { left };
            return None;
        }
        self.quality.features = count as u16;
        self.key_valid = false;
        self.key_count = 0;
        if count < usize::from(self.config.min_features) {
            let e = VoError::TooFewFeatures {
                found: count as u16,
            };
            return Some(Err(self.pending.unwrap_or(e)));
        }
        self.phase = Phase::Carry { next: 0 };
        None
    }

    /// Writes up to [`SORT_CHUNK`] carried features into the new keyframe
    /// ([`Self::carry_feature`]); after the last one, on to the new features' stereo matches.
    #[inline(always)]
    pub(super) fn carry_item(&mut self, next: usize, left: &Image) {
        let end = self.carried.min(self.selected_count).min(N);
        let stop = (next + SORT_CHUNK).min(end);
        for index in next..stop {
            self.carry_feature(index, left);
        }
        self.phase = if stop < end {
            Phase::Carry { next: stop }
        } else {
            Phase::StereoNew { next: end }
        };
    }

    /// Stereo matches new feature `next` ([`Self::stereo_new_feature`]); after the last one,
    /// on to the finish.
    #[inline(always)]
    pub(super) fn stereo_item(&mut self, next: usize, left: &Image, right: &Image) {
        if next < self.selected_count.min(N) {
            self.stereo_new_feature(next, left, right);
            self.phase = Phase::StereoNew { next: next + 1 };
        } else {
            self.phase = Phase::Finish;
        }
    }
    /// Feature persistence: correspondence `index`, when it is an inlier of the motion, becomes a
    /// feature of the next keyframe at its tracked position in the new pair (its stereo match
    /// there, from the tracking item, is kept), unless its template centre is within the border
    /// or it is closer than `min_distance_px` to a feature carried before it. Carried features
    /// fill `selected` and `current_px` from the front, so the detector only adds new features
    /// away from them ([`select_more`]).
    fn seed_carried(&mut self, index: usize) {
        if !self.inliers.get(index).copied().unwrap_or(false) {
            return;
        }
        let Some(&px) = self.current_px.get(index) else {
            return;
        };
        let (xc, yc) = (libm::round(f64::from(px[0])), libm::round(f64::from(px[1])));
        let border = BORDER_PX as f64;
        let inside = xc >= border
            && xc < (rover_hal::IMAGE_WIDTH_PX - BORDER_PX) as f64
            && yc >= border
            && yc < (rover_hal::IMAGE_HEIGHT_PX - BORDER_PX) as f64;
        if !inside {
            return;
        }
        let candidate = crate::vo::features::Candidate {
            interest: 1.0,
            x: xc as u16,
            y: yc as u16,
        };
        let count = self.carried.min(N);
        let kept = select_more(
            core::slice::from_ref(&candidate),
            self.config.min_distance_px,
            &mut self.selected,
            count,
        );
        if kept > count {
            // `count <= index`: the slot was read (or is this one) already.
            if let Some(slot) = self.current_px.get_mut(count) {
                *slot = px;
            }
            self.carried = kept;
        }
    }

    /// The grid cells of grid row `cell_row` (bit per grid column) that are covered by the
    /// carried features' exclusion disks: each of 9 sample pixels of the cell (a 3x3 lattice:
    /// corners, edge midpoints, centre) is closer than `min_distance_px` to some carried feature.
    /// The greedy selection ([`select_more`]) drops every candidate within those disks, so the
    /// detector need not score these cells (it could only miss a candidate in a sliver of a
    /// cell between the samples).
    fn skip_mask(&self, cell_row: usize) -> u64 {
        const OFFSETS: [usize; 3] = [0, GRID_PX / 2, GRID_PX - 1];
        let min_d = f64::from(self.config.min_distance_px);
        let min_d2 = min_d * min_d;
        let top = cell_row * GRID_PX;
        let reach = libm::ceil(min_d).min(1e4) as usize;
        let mut covered = [0u16; GRID_COLS];
        for &(x, y) in self.selected.get(..self.carried.min(N)).unwrap_or(&[]) {
            let (fx, fy) = (f64::from(x), f64::from(y));
            // Rows of the samples closer than min_d.
            let mut row_dy2 = [f64::INFINITY; 3];
            let mut any = false;
            for (slot, off) in row_dy2.iter_mut().zip(OFFSETS) {
                let dy = fy - (top + off) as f64;
                if dy * dy < min_d2 {
                    *slot = dy * dy;
                    any = true;
                }
            }
            if !any {
                continue;
            }
            let first = usize::from(x).saturating_sub(reach) / GRID_PX;
            let last = ((usize::from(x) + reach) / GRID_PX).min(GRID_COLS - 1);
            for c in first..=last {
                let Some(bits) = covered.get_mut(c) else {
                    continue;
                };
                for (i, off_x) in OFFSETS.iter().enumerate() {
                    let dx = fx - (c * GRID_PX + off_x) as f64;
                    for (j, dy2) in row_dy2.iter().enumerate() {
                        if dx * dx + dy2 < min_d2 {
                            *bits |= 1 << (3 * j + i);
                        }
                    }
                }
            }
        }
        let mut mask = 0u64;
        for (c, &bits) in covered.iter().enumerate() {
            if bits == 0x1ff && c < u64::BITS as usize {
                mask |= 1u64 << c;
            }
        }
        mask
    }

    /// Writes carried feature `index` (see [`Self::seed_carried`]) into the new keyframe: its
    /// pixels in this pair and the template around its nearest integer pixel.
    fn carry_feature(&mut self, index: usize, left: &Image) {
        let (Some(&(x, y)), Some(&pixels)) = (self.selected.get(index), self.current_px.get(index))
        else {
            return;
        };
        let Some(template) = left.template(i32::from(x), i32::from(y)) else {
            return;
        };
        if let Some(slot) = self.key.get_mut(self.key_count) {
            *slot = KeyFeature { pixels, template };
            self.key_count += 1;
        }
    }

    /// Stereo matches selected feature `index` of the new left image into the keyframe.
    fn stereo_new_feature(&mut self, index: usize, left: &Image, right: &Image) {
        let Some(&(x, y)) = self.selected.get(index) else {
            return;
        };
        let (xl, yl) = (f64::from(x), f64::from(y));
        let (xr, yr) =
            match match_and_triangulate(&self.camera, left, right, (xl, yl), None, &self.config) {
                Ok((_, right_px)) => right_px,
                Err(reason) => return self.quality.stereo_rejects.count(reason),
            };
        let Some(template) = left.template(i32::from(x), i32::from(y)) else {
            return;
        };
        if let Some(slot) = self.key.get_mut(self.key_count) {
            *slot = KeyFeature {
                pixels: [xl as f32, yl as f32, xr as f32, yr as f32],
                template,
            };
            self.key_count += 1;
        }
    }

    /// Commits the new keyframe and builds the output.
    pub(super) fn finish(&mut self) -> Result<VoOutput, VoError> {
        self.quality.stereo_matches = self.key_count as u16;
        let t0_us = self.key_t_us;
        let had_keyframe_motion = self.estimate;
        if self.key_count < usize::from(self.config.min_matches) {
            self.key_valid = false;
            let e = VoError::TooFewMatches {
                found: self.key_count as u16,
            };
            return Err(self.pending.unwrap_or(e));
        }
        self.key_valid = true;
        self.key_t_us = self.frame_t_us;
        self.key_checksum = self.frame_checksum;
        if let Some(e) = self.pending {
            return Err(e);
        }
        let pose = match had_keyframe_motion {
            Some(estimate) => Some(relative_pose(
                &self.mount,
                &estimate,
                t0_us,
                self.frame_t_us,
            )?),
            None => None,
        };
        Ok(VoOutput {
            pose,
            quality: self.quality,
        })
    }
}
