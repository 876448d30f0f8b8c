//! Terrain-map localization in the navigator (V99 sec. 5, issue 17): hazard maps of the
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

use super::filter::NavFilter;
use super::goal::{GoalCtx, GoalNav};
use super::{hazard_nav, yaw_of, StereoStage};
use crate::estimation::absolute_pose::AbsolutePose;
use crate::estimation::CloneHandle;
use crate::kinematics::VehicleCommand;
use crate::localization::{
    GlobalMap, LocalScan, LocalizationError, LocalizationFix, Localizer, LocalizerConfig,
    SearchProgress, MAX_POINTS,
};
use crate::perception::GridFrame;
use crate::types::Vec3;

/// Cost units (10,000 rover-CPU instructions) of one node expansion of the search: up to 8
/// children of up to [`MAX_POINTS`] point terms (about 60 instructions each, `docs/timing.md`).
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

impl GoalNav {
    /// The storage of terrain-map localization (about 82 KB; external RAM on the rover CPU).
    /// Without it, an enabled localization is refused by [`Self::start_vo`] (counted).
    pub fn provide_localization_memory(&mut self, store: &'static mut LocNav) {
        self.loc.store = Some(store);
        self.loc.built = false;
    }

    /// Build terrain-map localization in its storage when
    /// [`LocalizationSettings::enabled`]; called by [`Self::start_vo`]. Settings it refuses, or
    /// no storage ([`Self::provide_localization_memory`]), leave it off (counted in
    /// [`NavCounters::command_errors`]).
    pub(super) fn start_localization(&mut self) {
        let s = self.config.localization;
        if !s.enabled || self.loc.is_some() {
            return;
        }
        let valid = s.is_valid();
        let Some(l) = self.loc.store.as_deref_mut().filter(|_| valid) else {
            self.build_errors = self.build_errors.saturating_add(1);
            return;
        };
        if l.localizer.init(s.localizer).is_err() {
            self.build_errors = self.build_errors.saturating_add(1);
            return;
        }
        l.restart_scan();
        l.search_scan.clear();
        l.pending = None;
        l.clone = None;
        l.counters = LocCounters::default();
        l.last_fix = None;
        l.last_error = None;
        l.stop = Stop::Idle;
        l.view_count = 0;
        l.last_stop_xy = None;
        l.nadir_offset_m = [0.0; 2];
        self.loc.built = true;
    }

    /// Ground command: the global map for localization, as occupied world points `[x north,
    /// y east]` (`N`, m; e.g. the rocks of a descent image) in a 38.4 m square centred on
    /// `centre_m`. Replaces any earlier map and builds its distance transform at once (about
    /// 13.5 M rover-CPU instructions: uplink while the rover stands). Returns the points
    /// inserted (points outside the square or non-finite are dropped); `None` when
    /// localization is off or the centre is not finite.
    pub fn uplink_global_map(&mut self, centre_m: [f64; 2], points: &[[f64; 2]]) -> Option<usize> {
        let l = self.loc.as_mut()?;
        if !l.map.reset_centred(centre_m) {
            return None;
        }
        let n = l.map.insert_points(points);
        l.map.finish();
        l.counters.uplinks = l.counters.uplinks.saturating_add(1);
        // A search started on the old map cannot finish on the new one (`MapChanged`).
        Some(n)
    }

    /// Counters of terrain-map localization (zero when it is off).
    pub fn localization_counters(&self) -> LocCounters {
        self.loc.as_ref().map(|l| l.counters).unwrap_or_default()
    }

    /// The last localization fix offered to the EKF, if any.
    pub fn last_localization(&self) -> Option<LocFixReport> {
        self.loc.as_ref().and_then(|l| l.last_fix)
    }

    /// Why the last search gave no fix, if one failed.
    pub fn last_localization_error(&self) -> Option<LocalizationError> {
        self.loc.as_ref().and_then(|l| l.last_error)
    }

    /// True when localization was built ([`Self::start_vo`]).
    pub(super) fn loc_on(&self) -> bool {
        self.loc.is_some()
    }

    /// A hazard map started on the capture of `clone` with VO off: localization keeps the
    /// clone (the fix is applied there); the one it held before is released. With
    /// localization off the clone is released.
    pub(super) fn loc_keep_clone(&mut self, clone: Option<CloneHandle>) -> Option<CloneHandle> {
        match self.loc.as_mut() {
            Some(l) => core::mem::replace(&mut l.clone, clone),
            None => clone,
        }
    }

    /// After a hazard map finished: add it to the local map and start a search when the local
    /// map is complete. Returns true when a search runs (the stereo pipeline stays busy).
    pub(super) fn loc_after_map(&mut self, ctx: &mut GoalCtx<'_>) -> bool {
        let (max_new, span, maps_per_fix) = {
            let s = &self.config.localization;
            let per = usize::from(s.maps_per_fix.max(1));
            (MAX_POINTS / per, s.max_scan_span_m, s.maps_per_fix.max(1))
        };
        let (t_us, frame) = {
            let (Some(h), true) = (self.hazard.as_ref(), self.loc.is_some()) else {
                return false;
            };
            let Some(map) = h.mapper.map() else {
                return false;
            };
            (map.capture_t_us, map.grid)
        };
        let Some(h) = self.hazard.as_ref() else {
            return false;
        };
        let grid = h.mapper.grid();
        let Some(l) = self.loc.as_mut() else {
            return false;
        };
        if let Some(a) = l.anchor {
            let (dx, dy) = (
                frame.origin_world_m[0] - a.origin_world_m[0],
                frame.origin_world_m[1] - a.origin_world_m[1],
            );
            let d = crate::linalg::sqrt(dx * dx + dy * dy);
            if d > span || !d.is_finite() {
                l.restart_scan();
            }
        }
        let anchor = *l.anchor.get_or_insert(frame);
        l.scan.append_grid(grid, &frame, &anchor, max_new);
        l.newest = Some((t_us, frame));
        l.maps_in_scan = l.maps_in_scan.saturating_add(1);
        l.counters.maps = l.counters.maps.saturating_add(1);
        let (stop_view, early) = match l.stop {
            Stop::Waiting { view, since_us } if t_us >= since_us => (Some(view), false),
            // A map of a capture taken before the view was reached (triggered during the
            // turn) took the request: ask again.
            Stop::Waiting { .. } => (None, true),
            _ => (None, false),
        };
        if early {
            self.request_map();
        }
        let Some(l) = self.loc.as_mut() else {
            return false;
        };
        let (stopping, view_count) = (l.stop != Stop::Idle, l.view_count);
        let driving_fix_due = l.maps_in_scan >= maps_per_fix;
        // The camera nadir in the rover frame (for the target selection of the next stop).
        if let Some(rover) = self.loc_capture_pose(t_us, ctx) {
            let (s, c) = libm::sincos(rover[2]);
            let (dx, dy) = (
                frame.origin_world_m[0] - rover[0],
                frame.origin_world_m[1] - rover[1],
            );
            let offset = [c * dx + s * dy, -s * dx + c * dy];
            if let (Some(l), true) = (self.loc.as_mut(), offset.iter().all(|v| v.is_finite())) {
                l.nadir_offset_m = offset;
            }
        }
        match stop_view {
            Some(view) if view.saturating_add(1) < view_count => {
                if let Some(l) = self.loc.as_mut() {
                    l.stop = Stop::Turning {
                        view: view.saturating_add(1),
                    };
                }
                false
            }
            Some(_) => {
                // The stop's last view: search now, whatever the number of maps.
                let started = self.loc_start_search(ctx);
                let pos = ekf_xy(ctx.filter);
                if let Some(l) = self.loc.as_mut() {
                    if started {
                        l.stop = Stop::Searching;
                    } else {
                        l.stop = Stop::Idle;
                        l.last_stop_xy = Some(pos);
                    }
                }
                started
            }
            // While a stop turns or waits, the maps of the drive do not start a search.
            None if stopping || !driving_fix_due => false,
            None => self.loc_start_search(ctx),
        }
    }

    /// RG2, from [`Self::guidance_cycle`] before guidance (path drives): a localization stop's
    /// say in the motor command. `Some(None)`: hold still (waiting for a view's map or the
    /// search); `Some(Some(c))`: turn in place with body command `c` to the next view;
    /// `None`: drive the path. A stop is due after [`LocalizationSettings::stop_interval_m`]
    /// of travel, or when the position sigma exceeds
    /// [`LocalizationSettings::stop_sigma_fraction`] of fault protection's limit;
    /// its views are the headings whose hazcam wedge holds the most mapped rocks
    /// ([`crate::localization::select_target`], V99 sec. 5's target selection).
    pub(super) fn loc_command(
        &mut self,
        filter: &NavFilter,
        max_sigma: f64,
        vo_lost: bool,
    ) -> Option<Option<VehicleCommand>> {
        // Goal-directed drives stop only with the day's targets, on the sigma trigger (the
        // sequencer's "localize now", V99 sec. 3).
        // Not while dwelling at a target or waiting for a plan.
        let mission = matches!(self.mission_phase(), super::MissionPhase::Driving { .. });
        if (self.config.hazard_avoidance && !mission) || !filter.is_running() {
            return None;
        }
        let s = self.config.localization;
        let x = *filter.state();
        let pos = [x.p_n.x, x.p_n.y];
        let yaw = yaw_of(&x.q_nr);
        let sigma = filter.horizontal_sigma_m();
        let sweep = self.sweep_m + hazard_nav::GAZE_TURN_MARGIN_M;
        let l = self.loc.as_mut()?;
        match l.stop {
            Stop::Idle => {
                if !l.map.is_ready() {
                    return None;
                }
                let last = *l.last_stop_xy.get_or_insert(pos);
                let d = libm::hypot(pos[0] - last[0], pos[1] - last[1]);
                // Routine stops only while VO is off or lost (with VO the maps of the drive
                // localize when the terrain allows; turning in place for views cost VO 5
                // failures on `marsyard-25m`); the sigma trigger always.
                let routine = !mission && vo_lost && s.stop_interval_m > 0.0;
                let due = (routine && d >= s.stop_interval_m)
                    || (sigma > s.stop_sigma_fraction * max_sigma && d >= s.stop_min_spacing_m);
                if !due {
                    return None;
                }
                l.counters.stops = l.counters.stops.saturating_add(1);
                l.plan_views(pos, yaw, usize::from(s.stop_views), sweep);
                l.stop = Stop::Turning { view: 0 };
                // The sequencer accounts the stop's time and energy (and may drop targets).
                self.mission_localization_started();
                Some(None)
            }
            Stop::Turning { view } => {
                let target = l.views.get(usize::from(view)).copied().unwrap_or(yaw);
                let e = crate::guidance::carrot::wrap_pi(target - yaw);
                if libm::fabs(e) <= hazard_nav::GAZE_TOLERANCE_RAD || !e.is_finite() {
                    l.stop = Stop::Waiting {
                        view,
                        since_us: x.t_us,
                    };
                    l.counters.views = l.counters.views.saturating_add(1);
                    self.request_map();
                    return Some(None);
                }
                let rate = if e > 0.0 {
                    hazard_nav::GAZE_RATE_RAD_S
                } else {
                    -hazard_nav::GAZE_RATE_RAD_S
                };
                Some(Some(VehicleCommand {
                    x_dot_m_s: 0.0,
                    y_dot_m_s: 0.0,
                    yaw_rate_rad_s: rate,
                }))
            }
            Stop::Waiting { since_us, .. } => {
                let waited_s = x.t_us.saturating_sub(since_us) as f64 * 1e-6;
                if waited_s > s.stop_timeout_s {
                    l.counters.stop_timeouts = l.counters.stop_timeouts.saturating_add(1);
                    l.stop = Stop::Idle;
                    l.last_stop_xy = Some(pos);
                    return None;
                }
                Some(None)
            }
            Stop::Searching => Some(None),
        }
    }

    /// True while a localization stop holds the rover (turning, waiting for a view's map,
    /// searching).
    pub(super) fn loc_stop_active(&self) -> bool {
        self.loc.as_ref().is_some_and(|l| l.stop != Stop::Idle)
    }

    /// Starts the search of the local map around the newest map's EKF pose.
    fn loc_start_search(&mut self, ctx: &mut GoalCtx<'_>) -> bool {
        let Some((t_us, frame)) = self.loc.as_ref().and_then(|l| l.newest) else {
            return false;
        };
        let prior_cov = self.loc_prior_covariance(t_us, &frame, ctx);
        let caps = {
            let s = &self.config.localization;
            [
                s.max_search_sigma_m,
                s.max_search_sigma_m,
                s.max_search_sigma_yaw_rad,
            ]
        };
        let Some(l) = self.loc.as_mut() else {
            return false;
        };
        let Some(cov) = prior_cov else {
            l.counters.not_started = l.counters.not_started.saturating_add(1);
            l.restart_scan();
            return false;
        };
        // The local map in the newest map's frame.
        l.search_scan.clear();
        if let Some(anchor) = l.anchor {
            for p in l.scan.points() {
                let w = anchor.to_world_xy(*p);
                let g = frame.to_grid(&Vec3::new(w[0], w[1], 0.0));
                // Points are within 100 m of the anchor: the scan refuses nothing here unless
                // the frames are far apart, and a refused point is only a point less.
                let _ = l.search_scan.push([g[0], g[1]]);
            }
        }
        let prior = [
            frame.origin_world_m[0],
            frame.origin_world_m[1],
            frame.heading_rad,
        ];
        let search_cov = cap_covariance(&cov, caps);
        match l.localizer.start(&l.map, &l.search_scan, prior, search_cov) {
            Ok(()) => {
                l.counters.searches = l.counters.searches.saturating_add(1);
                l.pending = Some(Pending { t_us });
                *ctx.stage = StereoStage::Localizing;
                true
            }
            Err(e) => {
                l.counters.not_started = l.counters.not_started.saturating_add(1);
                l.last_error = Some(e);
                // Too few points: keep growing the local map (up to its span).
                if !matches!(e, LocalizationError::TooFewPoints { .. }) {
                    l.restart_scan();
                }
                false
            }
        }
    }

    /// The EKF's covariance of the grid frame's `[x, y, heading]` at the capture `t_us`
    /// (the rover pose's covariance from the filter, carried to the grid origin by the lever
    /// arm). `None` when the capture's state is gone.
    fn loc_prior_covariance(
        &self,
        t_us: u64,
        frame: &GridFrame,
        ctx: &GoalCtx<'_>,
    ) -> Option<[[f64; 3]; 3]> {
        let rover = self.loc_capture_pose(t_us, ctx)?;
        let ekf = ctx.filter.running()?;
        let probe = AbsolutePose {
            t_us,
            position_m: [rover[0], rover[1]],
            yaw_rad: rover[2],
            covariance: [
                [READ_VARIANCE, 0.0, 0.0],
                [0.0, READ_VARIANCE, 0.0],
                [0.0, 0.0, READ_VARIANCE],
            ],
        };
        let s = ekf.gate_absolute_pose(&probe).ok()?.residual_covariance;
        // Lever arm from the rover reference point to the grid origin, world frame.
        let (lx, ly) = (
            frame.origin_world_m[0] - rover[0],
            frame.origin_world_m[1] - rover[1],
        );
        let j = [[1.0, 0.0, -ly], [0.0, 1.0, lx], [0.0, 0.0, 1.0]];
        let mut p = [[0.0; 3]; 3];
        for (a, row) in p.iter_mut().enumerate() {
            for (b, v) in row.iter_mut().enumerate() {
                *v = s[(a, b)] - if a == b { READ_VARIANCE } else { 0.0 };
            }
        }
        Some(crate::localization::search::congruence(&j, &p))
    }

    /// The EKF's rover pose `[x, y, yaw]` at the capture `t_us` (from its clone), if the clone
    /// is live: the clone localization kept (VO off) or VO's keyframe clone.
    fn loc_capture_pose(&self, t_us: u64, ctx: &GoalCtx<'_>) -> Option<[f64; 3]> {
        let held = self.loc.as_ref().and_then(|l| l.clone);
        let handle = [held, ctx.key_clone]
            .into_iter()
            .flatten()
            .find(|h| h.t_us() == t_us)?;
        let (q, p) = ctx.filter.clone_pose(Some(handle))?;
        Some([p.x, p.y, yaw_of(&q)])
    }

    /// Background: advance the search by at most `quantum` cost units. Returns the units used
    /// and whether the search (and the stereo pipeline's work on this frame) finished.
    pub(super) fn loc_step(&mut self, quantum: u32, ctx: &mut GoalCtx<'_>) -> (u32, bool) {
        let nodes = (quantum / LOC_NODE_COST_UNITS).max(1);
        let progress = match self.loc.as_mut() {
            Some(l) => l.localizer.step(&l.map, nodes),
            None => SearchProgress::Finished(Err(LocalizationError::NotStarted)),
        };
        match progress {
            SearchProgress::Working { .. } => (quantum.max(1), false),
            SearchProgress::Finished(result) => {
                *ctx.stage = StereoStage::Idle;
                self.loc_finish(result, ctx);
                (quantum.max(1), true)
            }
        }
    }

    /// The search was abandoned (the frame was lost): counted as a failure.
    pub(super) fn loc_abandon(&mut self, filter: &NavFilter) {
        let pos = ekf_xy(filter);
        if let Some(l) = self.loc.as_mut() {
            if l.stop == Stop::Searching {
                l.stop = Stop::Idle;
                l.last_stop_xy = Some(pos);
            }
            if l.pending.take().is_some() {
                l.counters.failed = l.counters.failed.saturating_add(1);
                l.last_error = Some(LocalizationError::NotStarted);
                l.restart_scan();
            }
        }
    }

    /// A search ended: fuse the fix at its capture (gated), or count the failure.
    fn loc_finish(
        &mut self,
        result: Result<LocalizationFix, LocalizationError>,
        ctx: &mut GoalCtx<'_>,
    ) {
        let pos = ekf_xy(ctx.filter);
        if let Some(l) = self.loc.as_mut() {
            if l.stop == Stop::Searching {
                l.stop = Stop::Idle;
                l.last_stop_xy = Some(pos);
            }
        }
        let Some(pending) = self.loc.as_mut().and_then(|l| l.pending.take()) else {
            return;
        };
        let fix = match result {
            Ok(f) => f,
            Err(e) => {
                if let Some(l) = self.loc.as_mut() {
                    l.counters.failed = l.counters.failed.saturating_add(1);
                    l.last_error = Some(e);
                    l.restart_scan();
                }
                return;
            }
        };
        let t_us = pending.t_us;
        let estimate = self.loc_capture_pose(t_us, ctx);
        let gated = self.config.localization.gated;
        // The fix is applied at its capture's clone. No recording or replay can be active
        // here (the search runs in the stereo pipeline, which starts no capture meanwhile);
        // if one were, the update could not be replayed: stale.
        let transferred = estimate.and_then(|e| fix.transfer(e).map(|(p, c)| (e, p, c)));
        let outcome = match transferred {
            Some((prior, pose, covariance)) => {
                let m = AbsolutePose {
                    t_us,
                    position_m: [pose[0], pose[1]],
                    yaw_rad: pose[2],
                    covariance,
                };
                ctx.filter
                    .absolute_pose(&m, gated)
                    .map(|d| (prior, pose, covariance, d))
            }
            None => None,
        };
        let Some(l) = self.loc.as_mut() else {
            return;
        };
        l.restart_scan();
        let Some((prior, pose, covariance, d)) = outcome else {
            l.counters.stale = l.counters.stale.saturating_add(1);
            return;
        };
        if d.applied {
            l.counters.updates = l.counters.updates.saturating_add(1);
            l.last_stop_xy = Some(pos);
        } else {
            l.counters.rejected = l.counters.rejected.saturating_add(1);
        }
        l.last_fix = Some(LocFixReport {
            t_us,
            pose,
            covariance,
            prior,
            d2: d.d2,
            applied: d.applied,
            points: fix.points,
            inliers: fix.inliers,
            nodes: fix.nodes,
            search: l.counters.searches,
        });
    }
}

/// The EKF's horizontal position `[x, y]` (`N`, m).
fn ekf_xy(filter: &NavFilter) -> [f64; 2] {
    let p = filter.state().p_n;
    [p.x, p.y]
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
