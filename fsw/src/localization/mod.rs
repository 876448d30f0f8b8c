//! # Terrain-map localization (V99 sec. 5; Olson & Matthies 1998; Olson 2000)
//!
//! V99 sec. 5: "The problem is formulated in terms of maximum-likelihood estimation, using the
//! distances from the occupied cells in the local map to their closest occupied cells in the
//! global map as measurements", with "a probability density function for the measurements that
//! is the weighted sum of two terms representing the cases where the measurement is an inlier
//! [...] or an outlier", found by "a multi-resolution search strategy which is guaranteed to
//! locate the optimal position in the discretized search space", with "subpixel localization"
//! by a fit to the peak and the uncertainty "measured by the rate at which the likelihood
//! function falls off from the peak" plus "the probability that a qualitative failure has
//! occurred". See `docs/localization.md`.
//!
//! - [`map`]: the global occupancy map in the world frame `W` ([`GlobalMap`]): occupied cells
//!   from uplinked world points or from the rover's own hazard grids, its truncated squared
//!   Euclidean distance transform (Felzenszwalb & Huttenlocher's 1-D lower envelope, exact)
//!   and a min-pooled pyramid for the search bounds.
//! - [`scan`]: the local measurement ([`LocalScan`]): occupied points of one hazard grid in the
//!   grid frame `G`, at most [`MAX_POINTS`], deterministically subsampled.
//! - [`search`]: the likelihood, the best-first branch-and-bound over `(x, y, yaw)`, the peak
//!   fit, the covariance and the failure tests ([`Localizer`]).
//! - [`target`]: localization target selection (V99 sec. 5: where to look).
//!
//! Frames: world `W` = navigation frame `N` (x north, y east, m; yaw from north towards east,
//! rad); grid `G` of [`crate::perception::GridFrame`] (x_G forward, y_G right, origin at the left
//! camera's nadir). A pose `[x, y, yaw]` is the pose of `G` in `W`: `p_W = [x, y] + R(yaw) p_G`.
//!
//! No allocation, no recursion, every loop bounded, every failure a [`LocalizationError`].

// `!(x > limit)` is used on purpose: it is true for NaN, so a non-finite value fails the check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod map;
pub mod scan;
pub mod search;
pub mod target;

#[cfg(test)]
mod tests;

pub use map::GlobalMap;
pub use scan::LocalScan;
pub use search::{LocalizationFix, Localizer, SearchProgress};
pub use target::{select_target, TargetChoice, TargetWedge};

/// Side of a global-map cell, m. 0.2 m: twice the hazard grid's 0.1 m cell, finer than an
/// orbital image (HiRISE 0.25-0.32 m/pixel) and than a descent image from above ~300 m
/// (`docs/localization.md`), and the step of the pose search (V99 sec. 5: "the pose space is
/// first discretized at the same resolution as the occupancy grids").
pub const MAP_CELL_M: f64 = 0.2;
/// Cells along each side of the global map (38.4 m at [`MAP_CELL_M`]).
pub const MAP_SIDE: usize = 192;
/// Cells of the global map.
pub const MAP_CELLS: usize = MAP_SIDE * MAP_SIDE;
/// Levels of the min-pooled pyramid above the distance transform: level `l` has cells of
/// `2^l` map cells (`ceil(MAP_SIDE / 2^l)` per side); level 8 is a single cell.
pub const PYRAMID_LEVELS: usize = 8;
/// Largest squared distance stored in the distance transform, cells^2 (`u8`): 255 cells^2 is
/// 15.97 cells, 3.19 m. Every larger distance reads 255 (far beyond the outlier distance).
pub const MAX_D2_CELLS: u8 = 255;

/// Most points of a local scan.
pub const MAX_POINTS: usize = 256;
/// Largest half-width of the translation search window, cells (+-6.4 m at [`MAP_CELL_M`]).
pub const MAX_HALF_WINDOW_CELLS: i32 = 32;
/// Largest half-width of the yaw search window, yaw steps.
pub const MAX_HALF_YAW_STEPS: i32 = 16;
/// Capacity of the branch-and-bound priority queue, nodes (16 bytes each).
pub const QUEUE_CAPACITY: usize = 1024;

/// Tuning of the localizer ([`LocalizerConfig::default`] suits the Rocky 8 hazard grid
/// matched against a 0.2 m global map; reasons in `docs/localization.md`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalizerConfig {
    /// Standard deviation of the inlier density `p_in(d)` (Olson & Matthies 1998), m: map
    /// quantisation of both maps (0.2 m and 0.1 m cells, 0.06 and 0.03 m per axis), stereo
    /// ranging (a few cm at 3 m) and the global map's own point error.
    pub sigma_m: f64,
    /// Distance at which the inlier density falls to the outlier floor `p_out`, m: each
    /// point contributes `ln max(p_in(d), p_out)`, that is `-min(d^2, d_out^2) / (2 sigma^2)`
    /// up to a constant.
    pub outlier_distance_m: f64,
    /// Half-width of the search window in prior standard deviations (per axis).
    pub window_sigmas: f64,
    /// Smallest half-width of the translation window, m.
    pub min_window_m: f64,
    /// Smallest half-width of the yaw window, rad.
    pub min_yaw_window_rad: f64,
    /// Node budget of one localization (bounds and leaves evaluated, both passes);
    /// [`LocalizationError::NodeBudgetExceeded`] beyond it.
    pub max_nodes: u32,
    /// Fewest points of a scan.
    pub min_points: u16,
    /// Fewest inlier points (distance below `outlier_distance_m`) at the optimum.
    pub min_inliers: u16,
    /// Smallest inlier fraction at the optimum.
    pub min_inlier_fraction: f64,
    /// A pose outside the peak's neighbourhood within this many log-likelihood units (nats)
    /// of the optimum makes the match ambiguous (a qualitative failure, V99 sec. 5).
    pub ambiguity_nats: f64,
    /// Half-size of the peak's neighbourhood, pose steps (in x, y and yaw).
    pub neighbourhood_steps: u8,
    /// Factor on the covariance from the likelihood's fall-off (1: the bare Gaussian fit).
    /// Points of one rock share the rock's map error, so they are not the independent
    /// measurements the likelihood assumes; `docs/localization.md` gives the measured value.
    pub covariance_scale: f64,
}

impl Default for LocalizerConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl LocalizerConfig {
    /// The defaults as a constant (a statically allocated navigator's configuration):
    /// `sigma` 0.15 m, outlier distance 0.45 m, 3-sigma window (at least 0.4 m and 0.02 rad),
    /// 20,000 nodes, at least 10 points and 8 inliers (30 %), 3 nats of ambiguity over +-2
    /// steps, covariance scale 1 (reasons in `docs/localization.md`).
    pub const DEFAULT: Self = Self {
        sigma_m: 0.15,
        outlier_distance_m: 0.45,
        window_sigmas: 3.0,
        min_window_m: 0.4,
        min_yaw_window_rad: 0.02,
        max_nodes: 20_000,
        min_points: 10,
        min_inliers: 8,
        min_inlier_fraction: 0.3,
        ambiguity_nats: 3.0,
        neighbourhood_steps: 2,
        covariance_scale: 1.0,
    };
}

impl LocalizerConfig {
    /// True when every field is finite and in range.
    pub fn is_valid(&self) -> bool {
        let finite = [
            self.sigma_m,
            self.outlier_distance_m,
            self.window_sigmas,
            self.min_window_m,
            self.min_yaw_window_rad,
            self.min_inlier_fraction,
            self.ambiguity_nats,
            self.covariance_scale,
        ]
        .iter()
        .all(|v| v.is_finite());
        finite
            && self.sigma_m > 0.0
            && self.outlier_distance_m > 0.0
            && self.outlier_distance_m < crate::linalg::sqrt(f64::from(MAX_D2_CELLS)) * MAP_CELL_M
            && self.window_sigmas > 0.0
            && self.min_window_m >= 0.0
            && self.min_yaw_window_rad >= 0.0
            && self.max_nodes >= 1
            && self.min_points >= 3
            && (0.0..=1.0).contains(&self.min_inlier_fraction)
            && self.ambiguity_nats >= 0.0
            && self.neighbourhood_steps >= 1
            && self.covariance_scale > 0.0
    }
}

/// Why no fix was produced (every failure is a value, never a panic and never a pose).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LocalizationError {
    /// The configuration is out of range ([`LocalizerConfig::is_valid`]).
    InvalidConfig,
    /// The prior pose or its covariance has a non-finite value, or the covariance is not
    /// symmetric positive semi-definite.
    InvalidPrior,
    /// A point of the scan is non-finite or beyond 100 m.
    InvalidPoint,
    /// The scan is full ([`MAX_POINTS`]).
    ScanFull,
    /// The global map has points inserted since its last [`GlobalMap::finish`], or none.
    MapNotReady,
    /// The global map was changed during the search.
    MapChanged,
    /// The prior's search window exceeds [`MAX_HALF_WINDOW_CELLS`] or [`MAX_HALF_YAW_STEPS`]:
    /// localize earlier.
    PriorTooUncertain,
    /// Fewer than [`LocalizerConfig::min_points`] points in the scan.
    TooFewPoints {
        /// Points of the scan.
        points: u16,
    },
    /// Too few inliers at the best pose (featureless terrain or a wrong map).
    TooFewInliers {
        /// Inliers at the best pose.
        inliers: u16,
        /// Points of the scan.
        points: u16,
    },
    /// A pose outside the peak's neighbourhood is within
    /// [`LocalizerConfig::ambiguity_nats`] of the best (repeated or sparse terrain).
    Ambiguous,
    /// The best pose is on the edge of the search window: the optimum may lie outside it.
    PeakOnWindowEdge,
    /// The node budget ([`LocalizerConfig::max_nodes`]) was used up before the optimum was
    /// proven.
    NodeBudgetExceeded,
    /// The priority queue ([`QUEUE_CAPACITY`]) is full.
    QueueFull,
    /// [`Localizer::step`] was called without a started search.
    NotStarted,
    /// The likelihood fall-off around the peak gave no valid covariance.
    DegenerateCovariance,
}
