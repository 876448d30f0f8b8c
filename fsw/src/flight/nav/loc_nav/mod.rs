//! Terrain-map localization in the navigator (V99 sec. 5): hazard maps of the
//! hazcam pair, accumulated into a local map, are matched against the uplinked global map
//! ([`crate::localization`]) and the fix is fused into the EKF as an absolute pose at its
//! capture time (`Ekf::update_absolute_pose`, gated by eq. 46).
//!
//! - **Global map**: uplinked by the ground ([`Navigator::uplink_global_map`]: occupied world
//!   points, e.g. the rocks of a descent image), built once (distance transform and pyramid,
//!   about 13.5 M rover-CPU instructions: uplink while stopped).
//! - **Local map**: with [`LocalizationSettings::enabled`] the hazard mapper runs on path
//!   drives too (every [`LocalizationSettings::map_interval_m`] of EKF travel; goal-directed
//!   drives keep their own map schedule). Each finished map's hazard cells are appended to
//!   a local scan in the frame of its first map (V99: "six stereo pairs were used to build an
//!   elevation map"); their relative placement is the EKF's.
//! - **Search**: after [`LocalizationSettings::maps_per_fix`] maps the scan is re-expressed
//!   in the frame of the newest map and searched (branch and bound, background work items,
//!   the stereo pipeline stays busy meanwhile so no capture or VO replay interleaves) around
//!   that map's EKF pose. The prior covariance is the EKF's at the capture, carried to the grid
//!   origin; the search window is capped at [`LocalizationSettings::max_search_sigma_m`] and
//!   [`LocalizationSettings::max_search_sigma_yaw_rad`] (a larger error ends on the window's
//!   edge: `PeakOnWindowEdge`, not a fix).
//! - **Fusion**: the fix is carried to the rover reference point
//!   ([`LocalizationFix::transfer`]) and applied at the capture's clone: the capture clone
//!   kept for it (VO off) or VO's keyframe clone of the same capture (VO on). A clone that is
//!   gone makes the fix stale (counted, not fused). Every search failure is counted and never
//!   fused; the scan then starts again.

mod steps;

use crate::estimation::CloneHandle;
use crate::localization::{GlobalMap, LocalScan, LocalizationError, Localizer, LocalizerConfig};
use crate::perception::GridFrame;

/// Cost units (10,000 rover-CPU instructions) of one node expansion of the search: up to 8
/// children of up to [`MAX_POINTS`] point terms (about 60 instructions each, `docs/results/timing.md`).
pub const LOC_NODE_COST_UNITS: u32 = 12;

/// Settings of terrain-map localization in the navigator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalizationSettings {
    /// Localize against the uplinked global map. Off: nothing of this module runs.
    pub enabled: bool,
    /// EKF travel between the hazard maps of a path drive, m (goal-directed drives map every
    /// [`NavConfig::map_interval_m`]).
    pub map_interval_m: f64,
    /// Hazard maps accumulated into one local map before a search (at least 1).
    pub maps_per_fix: u8,
    /// A local map whose first map was taken farther than this from the newest one starts
    /// again from the newest (the EKF's relative drift would blur it), m.
    pub max_scan_span_m: f64,
    /// Cap of the search prior's 1-sigma position error per axis, m (the search window is
    /// `window_sigmas` times it; the branch-and-bound queue holds about 0.8 m).
    pub max_search_sigma_m: f64,
    /// Cap of the search prior's 1-sigma heading error, rad.
    pub max_search_sigma_yaw_rad: f64,
    /// Gate the fix with the EKF's Mahalanobis test (eq. 46, 95 %, 3 dof).
    pub gated: bool,
    /// Path drives with VO off or lost: EKF travel after which the rover stops to localize
    /// (V99 sec. 5), turning in place to the [`Self::stop_views`] headings whose hazcam wedge
    /// holds the most mapped rocks (localization target selection); counted from the last stop
    /// or fused fix. 0: no routine stops (only the maps made while driving, and the sigma
    /// trigger). m.
    pub stop_interval_m: f64,
    /// A stop is also due when the horizontal position 1-sigma exceeds this fraction of fault
    /// protection's limit ([`ProtectionConfig::max_position_sigma_m`]; V99 sec. 3's replan
    /// trigger "position uncertainty above a limit: localize now"), once the rover has
    /// travelled [`Self::stop_min_spacing_m`] since the last stop.
    pub stop_sigma_fraction: f64,
    /// Least EKF travel between two stops, m.
    pub stop_min_spacing_m: f64,
    /// Views (turns in place and hazard maps) of one stop, 1 to [`MAX_STOP_VIEWS`].
    pub stop_views: u8,
    /// A stop waiting this long for a view's map is given up (counted), s.
    pub stop_timeout_s: f64,
    /// The localizer's tuning.
    pub localizer: LocalizerConfig,
}

impl LocalizationSettings {
    /// Off, with the defaults of an enabled localization: a map every 0.5 m, 4 maps per local
    /// map (about 1.5 m of travel plus the 2.5 m the hazcams see), 3 m span, search prior capped
    /// at 0.3 m and 0.05 rad (1 sigma), gated, the localizer's defaults.
    pub const DEFAULT: Self = Self {
        enabled: false,
        map_interval_m: 0.5,
        maps_per_fix: 4,
        max_scan_span_m: 3.0,
        max_search_sigma_m: 0.3,
        max_search_sigma_yaw_rad: 0.05,
        gated: true,
        stop_interval_m: 5.0,
        stop_sigma_fraction: 0.5,
        stop_min_spacing_m: 1.0,
        stop_views: 3,
        stop_timeout_s: 30.0,
        localizer: LocalizerConfig::DEFAULT,
    };

    /// True when the numbers are finite and positive (checked when the navigator builds it).
    pub fn is_valid(&self) -> bool {
        self.map_interval_m.is_finite()
            && self.map_interval_m > 0.0
            && self.maps_per_fix >= 1
            && self.max_scan_span_m.is_finite()
            && self.max_scan_span_m >= 0.0
            && self.max_search_sigma_m.is_finite()
            && self.max_search_sigma_m > 0.0
            && self.max_search_sigma_yaw_rad.is_finite()
            && self.max_search_sigma_yaw_rad > 0.0
            && self.stop_interval_m.is_finite()
            && self.stop_interval_m >= 0.0
            && self.stop_sigma_fraction > 0.0
            && self.stop_min_spacing_m.is_finite()
            && self.stop_min_spacing_m >= 0.0
            && (1..=MAX_STOP_VIEWS as u8).contains(&self.stop_views)
            && self.stop_timeout_s.is_finite()
            && self.stop_timeout_s > 0.0
            && self.localizer.is_valid()
    }
}

/// Counters of terrain-map localization (telemetry and the simulator's summary).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct LocCounters {
    /// Global-map uplinks accepted.
    pub uplinks: u32,
    /// Hazard maps added to local maps.
    pub maps: u32,
    /// Searches started.
    pub searches: u32,
    /// Searches that could not start (too few points, map not ready, prior too uncertain or
    /// invalid); the local map then starts again, except with too few points, when it keeps
    /// growing.
    pub not_started: u32,
    /// Searches that ended without a fix (ambiguous, too few inliers, peak on the window's
    /// edge, budget): a detected failure, not fused.
    pub failed: u32,
    /// Fixes fused into the EKF.
    pub updates: u32,
    /// Fixes the EKF's gate refused.
    pub rejected: u32,
    /// Fixes whose capture state was gone (clone released) or that met an EKF error.
    pub stale: u32,
    /// Localization stops (path drives).
    pub stops: u32,
    /// Stops made without turning: no mapped rock in any candidate view, or a mapped rock
    /// inside the circle the rover sweeps turning in place.
    pub stops_without_turn: u32,
    /// Stops given up waiting for a view's map.
    pub stop_timeouts: u32,
    /// Hazard maps the views of stops asked for.
    pub views: u32,
}

/// The last localization fix as fused (or refused), for telemetry and the simulator's
/// consistency check (NEES against the truth).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocFixReport {
    /// Capture time of the newest map of the local map, microseconds since boot.
    pub t_us: u64,
    /// Rover reference point `[x north, y east]` (m) and heading (rad from north) at `t_us`,
    /// from the fix.
    pub pose: [f64; 3],
    /// Covariance of `pose` (m^2, m^2 rad, rad^2).
    pub covariance: [[f64; 3]; 3],
    /// The EKF's estimate of the same pose before the update.
    pub prior: [f64; 3],
    /// Mahalanobis squared distance of the fix against the EKF (eq. 46).
    pub d2: f64,
    /// True when the fix was fused.
    pub applied: bool,
    /// Points of the local map and inliers at the optimum.
    pub points: u16,
    /// Inliers at the optimum.
    pub inliers: u16,
    /// Nodes the search evaluated.
    pub nodes: u32,
    /// Counter value of [`LocCounters::searches`] of this fix (a new report has a new value).
    pub search: u32,
}

/// Largest number of views of one localization stop.
pub const MAX_STOP_VIEWS: usize = 4;

/// Candidate headings of a stop's views, relative to the current heading, cheapest turn first
/// (rad): the eight 45-degree directions.
const VIEW_OFFSETS_RAD: [f64; 8] = [
    0.0,
    core::f64::consts::FRAC_PI_4,
    -core::f64::consts::FRAC_PI_4,
    core::f64::consts::FRAC_PI_2,
    -core::f64::consts::FRAC_PI_2,
    3.0 * core::f64::consts::FRAC_PI_4,
    -3.0 * core::f64::consts::FRAC_PI_4,
    core::f64::consts::PI,
];

/// Where a localization stop is.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Stop {
    /// Driving.
    Idle,
    /// Turning in place to view `view`.
    Turning { view: u8 },
    /// Standing for the map of view `view`, from a capture at or after `since_us`.
    Waiting { view: u8, since_us: u64 },
    /// Standing while the search runs.
    Searching,
}

/// A search in progress.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pending {
    /// Capture time of the newest map (the fix's time).
    t_us: u64,
}

/// State of terrain-map localization (about 82 KB: the global map 49 KB, the localizer
/// 24 KB, two scans of 4 KB). The platform provides it
/// ([`crate::flight::Fsw::provide_localization_memory`]): on the rover CPU a static in external
/// RAM, like the image buffers, so that it does not count against the internal RAM of the
/// flight state.
pub struct LocNav {
    map: GlobalMap,
    localizer: Localizer,
    /// The local map: hazard points of the maps so far, in the frame of the first.
    scan: LocalScan,
    /// The local map re-expressed in the newest map's frame (the search's input).
    search_scan: LocalScan,
    /// Grid frame of the first map of the local map.
    anchor: Option<GridFrame>,
    /// Capture time and grid frame of the newest map of the local map.
    newest: Option<(u64, GridFrame)>,
    maps_in_scan: u8,
    pending: Option<Pending>,
    /// The capture clone kept for the newest map when VO does not hold it.
    clone: Option<CloneHandle>,
    counters: LocCounters,
    last_fix: Option<LocFixReport>,
    last_error: Option<LocalizationError>,
    stop: Stop,
    /// Headings of the current stop's views, rad from north.
    views: [f64; MAX_STOP_VIEWS],
    view_count: u8,
    /// EKF position of the last stop or fused fix (stops are counted from it).
    last_stop_xy: Option<[f64; 2]>,
    /// Camera nadir (grid origin) in the rover frame, `[forward, right]` m, from the last map.
    nadir_offset_m: [f64; 2],
}

impl LocNav {
    /// Placeholder: the compile-time value of the storage before [`Navigator::start_vo`]
    /// builds it.
    pub const EMPTY: Self = Self {
        map: GlobalMap::new(),
        localizer: Localizer::EMPTY,
        scan: LocalScan::new(),
        search_scan: LocalScan::new(),
        anchor: None,
        newest: None,
        maps_in_scan: 0,
        pending: None,
        clone: None,
        counters: LocCounters {
            uplinks: 0,
            maps: 0,
            searches: 0,
            not_started: 0,
            failed: 0,
            updates: 0,
            rejected: 0,
            stale: 0,
            stops: 0,
            stops_without_turn: 0,
            stop_timeouts: 0,
            views: 0,
        },
        last_fix: None,
        last_error: None,
        stop: Stop::Idle,
        views: [0.0; MAX_STOP_VIEWS],
        view_count: 0,
        last_stop_xy: None,
        nadir_offset_m: [0.0; 2],
    };

    /// The views of a stop at `pos` heading `yaw`: up to `n` of the eight 45-degree headings,
    /// best first by the mapped rocks their hazcam wedge would see from the camera nadir at
    /// that heading; only the current heading when no candidate sees a mapped rock or when a
    /// mapped rock lies within `sweep` (m) of the rover (turning in place would touch it).
    fn plan_views(&mut self, pos: [f64; 2], yaw: f64, n: usize, sweep: f64) {
        self.views = [yaw; MAX_STOP_VIEWS];
        self.view_count = 1;
        let clear = match self.map.cell_of(pos) {
            Some((i, j)) => {
                let d = crate::linalg::sqrt(f64::from(self.map.d2_at(i as i32, j as i32)))
                    * crate::localization::MAP_CELL_M;
                d - 0.5 * crate::localization::MAP_CELL_M >= sweep
            }
            None => false,
        };
        if !clear {
            self.counters.stops_without_turn = self.counters.stops_without_turn.saturating_add(1);
            return;
        }
        let wedge = crate::localization::TargetWedge::default();
        let mut taken = [false; VIEW_OFFSETS_RAD.len()];
        let mut count = 0usize;
        for _ in 0..n.min(MAX_STOP_VIEWS) {
            let mut best: Option<(usize, u32)> = None;
            for (k, offset) in VIEW_OFFSETS_RAD.iter().enumerate() {
                if taken.get(k).copied().unwrap_or(true) {
                    continue;
                }
                let heading = yaw + offset;
                let (sh, ch) = libm::sincos(heading);
                let o = self.nadir_offset_m;
                let apex = [
                    pos[0] + ch * o[0] - sh * o[1],
                    pos[1] + sh * o[0] + ch * o[1],
                ];
                let seen = crate::localization::select_target(&self.map, apex, &[heading], &wedge)
                    .map_or(0, |c| c.occupied_cells);
                if seen > 0 && best.is_none_or(|(_, b)| seen > b) {
                    best = Some((k, seen));
                }
            }
            let Some((k, _)) = best else {
                break;
            };
            if let (Some(t), Some(v), Some(offset)) = (
                taken.get_mut(k),
                self.views.get_mut(count),
                VIEW_OFFSETS_RAD.get(k),
            ) {
                *t = true;
                *v = crate::guidance::carrot::wrap_pi(yaw + offset);
                count += 1;
            }
        }
        if count == 0 {
            self.counters.stops_without_turn = self.counters.stops_without_turn.saturating_add(1);
            return;
        }
        // Visit the views in one sweep: ordered by their turn from the current heading,
        // starting on the side of the smaller turn.
        // (A bubble sort of at most four: no library sort, whose order-violation check is a
        // panic path.)
        let turn = |h: f64| crate::guidance::carrot::wrap_pi(h - yaw);
        let mut v = self.views;
        for _ in 0..MAX_STOP_VIEWS {
            for k in 0..MAX_STOP_VIEWS - 1 {
                if k + 1 < count && turn(v[k]) > turn(v[k + 1]) {
                    v.swap(k, k + 1);
                }
            }
        }
        if let Some(chosen) = v.get_mut(..count) {
            let (first, last) = (
                chosen.first().map_or(0.0, |h| turn(*h)),
                chosen.last().map_or(0.0, |h| turn(*h)),
            );
            if libm::fabs(last) < libm::fabs(first) {
                chosen.reverse();
            }
        }
        self.views = v;
        self.view_count = count as u8;
    }

    fn restart_scan(&mut self) {
        self.scan.clear();
        self.anchor = None;
        self.newest = None;
        self.maps_in_scan = 0;
    }
}

/// `D P D` with `D = diag(min(1, cap_i / sigma_i))`: the covariance with each standard
/// deviation capped, correlations kept.
fn cap_covariance(p: &[[f64; 3]; 3], caps: [f64; 3]) -> [[f64; 3]; 3] {
    let mut d = [1.0; 3];
    for (k, (dk, cap)) in d.iter_mut().zip(caps).enumerate() {
        let sigma = crate::linalg::sqrt(p[k][k].max(0.0));
        if sigma > cap {
            *dk = cap / sigma;
        }
    }
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = d[r] * p[r][c] * d[c];
        }
    }
    out
}

/// Variance given to the dummy measurement that reads the EKF's covariance of `[x, y, yaw]`
/// through the absolute-pose gate (`S = H P H' + R`), m^2 and rad^2.
const READ_VARIANCE: f64 = 1e-12;

/// Where the navigator keeps terrain-map localization: the storage the platform provided and
/// whether it was built for this drive.
pub struct LocSlot {
    store: Option<&'static mut LocNav>,
    built: bool,
}

impl LocSlot {
    /// No storage, not built.
    pub(super) const NONE: Self = Self {
        store: None,
        built: false,
    };

    /// The state when built.
    fn as_ref(&self) -> Option<&LocNav> {
        if self.built {
            self.store.as_deref()
        } else {
            None
        }
    }

    /// The state when built, mutable.
    fn as_mut(&mut self) -> Option<&mut LocNav> {
        if self.built {
            self.store.as_deref_mut()
        } else {
            None
        }
    }

    /// True when built.
    fn is_some(&self) -> bool {
        self.built && self.store.is_some()
    }

    /// Marks it not built (a new drive); the storage is kept.
    pub(super) fn unbuild(&mut self) {
        self.built = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[allow(unused_imports)]
    use crate::estimation::NominalState;
    #[allow(unused_imports)]
    use crate::flight::nav::*;
    #[allow(unused_imports)]
    use crate::kinematics::ROCKY8;

    #[test]
    fn capped_covariance_keeps_correlation_and_small_sigmas() {
        let p = [[4.0, 1.0, 0.0], [1.0, 0.01, 0.0], [0.0, 0.0, 0.0025]];
        let c = cap_covariance(&p, [0.5, 0.5, 0.05]);
        assert!((c[0][0] - 0.25).abs() < 1e-12);
        assert_eq!(c[1][1], 0.01);
        assert_eq!(c[2][2], 0.0025);
        // Correlation coefficient unchanged.
        let rho = |m: &[[f64; 3]; 3]| m[0][1] / (m[0][0] * m[1][1]).sqrt();
        assert!((rho(&c) - rho(&p)).abs() < 1e-12);
    }

    /// A localization stop's views (target selection, V99 sec. 5): toward the mapped rocks,
    /// in one sweep; no turn when a mapped rock is inside the turning circle.
    #[test]
    fn stop_views_look_at_the_mapped_rocks_and_never_turn_into_one() {
        let mut l = LocNav::EMPTY;
        assert!(l.map.reset_centred([0.0, 0.0]));
        // A cluster of rocks 1.8 m east of the rover (heading north), one 2 m south-west.
        let mut pts = std::vec::Vec::new();
        for k in 0..12 {
            let a = f64::from(k) * 0.5;
            pts.push([0.2 * libm::cos(a), 1.8 + 0.2 * libm::sin(a)]);
        }
        pts.push([-1.4, -1.4]);
        l.map.insert_points(&pts);
        l.map.finish();
        l.plan_views([0.0, 0.0], 0.0, 3, 0.8);
        assert!(l.view_count >= 1);
        let views = &l.views[..usize::from(l.view_count)];
        // The east cluster is in view of the first-best heading (+90 deg or +45 deg) and the
        // views are ordered in one sweep (monotonic turn from the current heading).
        assert!(views
            .iter()
            .any(|h| (h - core::f64::consts::FRAC_PI_2).abs() < 1e-9
                || (h - core::f64::consts::FRAC_PI_4).abs() < 1e-9));
        let turns: std::vec::Vec<f64> = views
            .iter()
            .map(|h| crate::guidance::carrot::wrap_pi(*h))
            .collect();
        let increasing = turns.windows(2).all(|w| w[0] <= w[1]);
        let decreasing = turns.windows(2).all(|w| w[0] >= w[1]);
        assert!(increasing || decreasing, "{turns:?}");
        assert_eq!(l.counters.stops_without_turn, 0);

        // A mapped rock 0.5 m from the rover: inside the turning circle, so no turn.
        let mut l2 = LocNav::EMPTY;
        assert!(l2.map.reset_centred([0.0, 0.0]));
        pts.push([0.0, 0.5]);
        l2.map.insert_points(&pts);
        l2.map.finish();
        l2.plan_views([0.0, 0.0], 0.3, 3, 0.8);
        assert_eq!(l2.view_count, 1);
        assert_eq!(l2.views[0], 0.3);
        assert_eq!(l2.counters.stops_without_turn, 1);

        // No mapped rock anywhere near: the current heading only.
        let mut l3 = LocNav::EMPTY;
        assert!(l3.map.reset_centred([0.0, 0.0]));
        l3.map.insert_points(&[[15.0, 15.0]]);
        l3.map.finish();
        l3.plan_views([0.0, 0.0], -0.2, 3, 0.8);
        assert_eq!((l3.view_count, l3.views[0]), (1, -0.2));
        assert_eq!(l3.counters.stops_without_turn, 1);
    }

    #[test]
    fn default_settings_are_valid_and_off() {
        let s = LocalizationSettings::DEFAULT;
        assert!(s.is_valid());
        assert!(!s.enabled);
        let bad = LocalizationSettings {
            maps_per_fix: 0,
            ..s
        };
        assert!(!bad.is_valid());
    }
}
