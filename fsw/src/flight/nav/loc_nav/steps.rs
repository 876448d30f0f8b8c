//! Terrain-map localization's steps in the goal-directed navigation ([`GoalNav`]): the uplink,
//! the local map after each hazard map, the stop and its views, the search and the fusion of
//! its fix (module doc of [`super`]).

use super::*;
use crate::estimation::absolute_pose::AbsolutePose;
use crate::estimation::CloneHandle;
use crate::flight::nav::filter::NavFilter;
use crate::flight::nav::goal::{GoalCtx, GoalNav};
use crate::flight::nav::{hazard_nav, yaw_of, StereoStage};
use crate::kinematics::VehicleCommand;
use crate::localization::{LocalizationFix, SearchProgress, MAX_POINTS};
use crate::types::Vec3;

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
    pub(in crate::flight::nav) fn start_localization(&mut self) {
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
    pub(in crate::flight::nav) fn loc_on(&self) -> bool {
        self.loc.is_some()
    }

    /// A hazard map started on the capture of `clone` with VO off: localization keeps the
    /// clone (the fix is applied there); the one it held before is released. With
    /// localization off the clone is released.
    pub(in crate::flight::nav) fn loc_keep_clone(
        &mut self,
        clone: Option<CloneHandle>,
    ) -> Option<CloneHandle> {
        match self.loc.as_mut() {
            Some(l) => core::mem::replace(&mut l.clone, clone),
            None => clone,
        }
    }

    /// After a hazard map finished: add it to the local map and start a search when the local
    /// map is complete. Returns true when a search runs (the stereo pipeline stays busy).
    pub(in crate::flight::nav) fn loc_after_map(&mut self, ctx: &mut GoalCtx<'_>) -> bool {
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
    pub(in crate::flight::nav) fn loc_command(
        &mut self,
        filter: &NavFilter,
        max_sigma: f64,
        vo_lost: bool,
    ) -> Option<Option<VehicleCommand>> {
        // Goal-directed drives stop only with the day's targets, on the sigma trigger (the
        // sequencer's "localize now", V99 sec. 3).
        // Not while dwelling at a target or waiting for a plan.
        let mission = matches!(
            self.mission_phase(),
            crate::flight::nav::MissionPhase::Driving { .. }
        );
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
    pub(in crate::flight::nav) fn loc_stop_active(&self) -> bool {
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
    pub(in crate::flight::nav) fn loc_step(
        &mut self,
        quantum: u32,
        ctx: &mut GoalCtx<'_>,
    ) -> (u32, bool) {
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
    pub(in crate::flight::nav) fn loc_abandon(&mut self, filter: &NavFilter) {
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
