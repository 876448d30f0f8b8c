//! Localization target selection (V99 sec. 5): "It is important to select a location that has
//! very distinctive terrain to enable the localization to be performed with the smallest
//! uncertainty."
//!
//! V99 predicts the uncertainty of the match for each possible target from a probability map
//! of the terrain. This is the simple form of it: the predicted information of a match grows
//! with the number of occupied cells of the global map the hazcams will see, so each candidate
//! heading is scored by the occupied cells whose centres fall inside the camera wedge
//! ([`crate::perception::Wedge`]) at that heading from the expected viewpoint, and the best is
//! returned (the first of equal scores, so the caller lists the cheapest turn first). It does
//! not model occlusion or the geometry of the cells (a row of rocks constrains one direction
//! only).

use super::map::GlobalMap;
use super::MAP_CELL_M;
use crate::perception::Wedge;

/// The hazcam wedge used to predict what a capture will see (V99 sec. 4: "a wedge of the
/// ground plane, with limited downrange radius R and half-angle alpha").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetWedge {
    /// Half-angle, rad.
    pub half_angle_rad: f64,
    /// Inner radius from the camera's nadir, m.
    pub min_range_m: f64,
    /// Downrange radius, m.
    pub max_range_m: f64,
}

impl Default for TargetWedge {
    /// The Rocky 8 hazcam wedge measured on the SIL scenes (`docs/hazard-navigation.md`:
    /// about 70 deg, 0.3 to 2.8 m).
    fn default() -> Self {
        Self {
            half_angle_rad: 35.0_f64.to_radians(),
            min_range_m: 0.3,
            max_range_m: 2.8,
        }
    }
}

/// The chosen localization target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetChoice {
    /// Index of the chosen heading in the candidate list.
    pub index: usize,
    /// The chosen heading, rad from north towards east.
    pub heading_rad: f64,
    /// Occupied global-map cells inside its wedge.
    pub occupied_cells: u32,
}

/// Largest downrange radius considered, m (bounds the cell loop to 101 x 101 cells).
const MAX_RANGE_M: f64 = 10.0;

/// Scores each heading of `candidates_rad` (rad from north towards east) by the occupied cells
/// of `global` inside `wedge` with its apex at `apex_m` (`[x, y]`, m, `W`: the expected camera
/// nadir) and returns the best. `None` when the map is not finished, the apex or the wedge is
/// not finite (or its range beyond 10 m), or no candidate sees an occupied cell. At most
/// `candidates.len() * 101^2` cell tests.
pub fn select_target(
    global: &GlobalMap,
    apex_m: [f64; 2],
    candidates_rad: &[f64],
    wedge: &TargetWedge,
) -> Option<TargetChoice> {
    let valid = global.is_ready()
        && apex_m.iter().all(|v| v.is_finite())
        && wedge.half_angle_rad.is_finite()
        && wedge.min_range_m.is_finite()
        && wedge.max_range_m > 0.0
        && wedge.max_range_m <= MAX_RANGE_M;
    if !valid {
        return None;
    }
    let (ci, cj) = global.cell_of(apex_m).map_or_else(
        || {
            let o = global.origin_m();
            (
                libm::floor((apex_m[0] - o[0]) / MAP_CELL_M),
                libm::floor((apex_m[1] - o[1]) / MAP_CELL_M),
            )
        },
        |(i, j)| (i as f64, j as f64),
    );
    if !(libm::fabs(ci) < 1.0e6 && libm::fabs(cj) < 1.0e6) {
        return None;
    }
    let (ci, cj) = (ci as i32, cj as i32);
    let reach = libm::ceil(wedge.max_range_m / MAP_CELL_M) as i32 + 1;
    let mut best: Option<TargetChoice> = None;
    for (index, &heading) in candidates_rad.iter().enumerate() {
        if !heading.is_finite() {
            continue;
        }
        let w = Wedge {
            apex_m,
            heading_rad: heading,
            half_angle_rad: wedge.half_angle_rad,
            min_range_m: wedge.min_range_m,
            max_range_m: wedge.max_range_m,
        };
        let mut count = 0u32;
        for i in ci - reach..=ci + reach {
            for j in cj - reach..=cj + reach {
                if global.d2_at(i, j) != 0 || i < 0 || j < 0 {
                    continue;
                }
                if w.contains(global.cell_centre(i as usize, j as usize)) {
                    count += 1;
                }
            }
        }
        if count > 0 && best.is_none_or(|b| count > b.occupied_cells) {
            best = Some(TargetChoice {
                index,
                heading_rad: heading,
                occupied_cells: count,
            });
        }
    }
    best
}
