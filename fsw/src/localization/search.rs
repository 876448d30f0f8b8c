//! Maximum-likelihood matching of a local scan against the global map by best-first
//! branch-and-bound over `(x, y, yaw)` (V99 sec. 5; Olson & Matthies 1998; Olson 2000).
//!
//! **Likelihood.** A pose puts scan point `p_k` at a map cell whose squared distance to the
//! nearest occupied cell is `d_k^2` (the distance transform, [`GlobalMap`]). Each point
//! contributes `ln max(p_in(d_k), p_out)` with the Gaussian inlier density
//! `p_in(d) ~ exp(-d^2 / (2 sigma^2))` and the uniform outlier floor `p_out`, which meet at
//! `d_out` ([`LocalizerConfig::outlier_distance_m`]): up to a constant the term is
//! `-min(d^2, d_out^2) / (2 sigma^2)`. It is tabulated per squared distance in integer
//! milli-nats, so sums are exact and identical in every search order.
//!
//! **Pose space.** The search moves the scan's centroid `c` (G frame), which decorrelates
//! translation and yaw: a pose is `T = T_0 + (i, j) MAP_CELL_M`, `yaw = yaw_0 + t dyaw` with
//! integers `|i|, |j| <= H_xy`, `|t| <= H_yaw`, and `p_W = T + R(yaw) (p_G - c)`. The
//! translation step is the map cell and `dyaw = MAP_CELL_M / r_max` (`r_max` the largest
//! distance of a point from `c`), so that neighbouring poses move the scan by at most one cell
//! (V99 sec. 5). The window is `window_sigmas` prior standard deviations per axis.
//!
//! **Bound.** For a box of poses (a translation rectangle and a yaw interval), each point at
//! the interval's middle yaw can move by at most `r_k * half_span` (chord below arc) while the
//! yaw varies, so every cell it can reach lies in a window of cells; the smallest squared
//! distance over that window (min-pooled pyramid, [`GlobalMap::min_d2_window`]) gives the
//! largest term the point can have in the box. The sum over points is never below the best
//! likelihood inside the box, so pruning a box whose bound is below the best pose found is
//! safe, and the search returns the optimum of the discretised pose space.
//!
//! **Search.** The prior pose is evaluated first (V99 sec. 5: "we then test the nominal
//! position") and a greedy dive along the children of the highest bound gives an incumbent;
//! boxes are split in 2 along every dimension wider than one pose (up to 8 children) and taken
//! best bound first from a fixed-capacity heap. A second pass proves that
//! no pose outside the peak's neighbourhood comes within [`LocalizerConfig::ambiguity_nats`] of
//! the optimum (the qualitative-failure test).
//!
//! **Peak and covariance.** A parabola through the optimum and its two neighbours on each
//! axis gives the sub-step peak; the covariance is the second moment of the likelihood
//! `exp(L - L_max)` over the `5 x 5 x 5` poses around the optimum plus the quantisation
//! variance `step^2 / 12` (a Gaussian fitted to the likelihood's fall-off, V99 sec. 5 and
//! Olson 2000), times [`LocalizerConfig::covariance_scale`].

use super::map::GlobalMap;
use super::scan::LocalScan;
use super::{
    LocalizationError, LocalizerConfig, MAP_CELL_M, MAX_D2_CELLS, MAX_HALF_WINDOW_CELLS,
    MAX_HALF_YAW_STEPS, MAX_POINTS, QUEUE_CAPACITY,
};
use crate::perception::{GridFrame, TerrainGrid};
use heapless::binary_heap::{BinaryHeap, Max};

mod fix;
mod likelihood;

pub(crate) use fix::congruence;
pub use fix::LocalizationFix;

/// Yaw poses of the largest window.
const YAW_POSES: usize = 2 * MAX_HALF_YAW_STEPS as usize + 1;
/// Half-size of the neighbourhood of the covariance fit, pose steps (5 x 5 x 5 poses).
const FIT_HALF: i32 = 2;
/// Largest magnitude of a tabulated term, milli-nats (keeps 256 terms inside `i32`).
const MAX_TERM_MILLI: f64 = 1.0e6;
/// Slack on the yaw sweep of a box, cells (floating-point rounding of the point positions).
const SWEEP_SLACK_CELLS: f64 = 1.0e-9;

/// A box of poses: translations `[x0, x0 + 2^lx)`, `[y0, y0 + 2^ly)` (cells) and yaw steps
/// `[t0, t0 + 2^lt)`, with the upper bound of its log-likelihood (milli-nats). Ordered by the
/// bound first (the heap's key), the rest only for determinism.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct Node {
    bound: i32,
    x0: i16,
    y0: i16,
    t0: i16,
    lx: u8,
    ly: u8,
    lt: u8,
}

/// One pose of the discretised space and its log-likelihood, milli-nats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Leaf {
    pub score: i32,
    pub x: i32,
    pub y: i32,
    pub t: i32,
}

impl Leaf {
    /// True when `self` is preferred to `other`: higher likelihood, then the pose closest to
    /// the prior (`|x| + |y| + |t|`), then the smallest `(x, y, t)`. Brute force and the
    /// branch-and-bound use the same order, so they return the same pose.
    pub fn better_than(&self, other: &Leaf) -> bool {
        let key = |l: &Leaf| (l.x.abs() + l.y.abs() + l.t.abs(), l.x, l.y, l.t);
        self.score > other.score || (self.score == other.score && key(self) < key(other))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Idle,
    Search,
    Ambiguity,
}

/// Progress of a resumable search ([`Localizer::step`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SearchProgress {
    /// More work is needed; nodes evaluated so far.
    Working {
        /// Nodes (bounds and poses) evaluated so far.
        nodes: u32,
    },
    /// The search ended with a fix or an error.
    Finished(Result<LocalizationFix, LocalizationError>),
}

/// The terrain-map localizer: configuration, the likelihood table and the state of one
/// resumable search (about 24 KB: the queue 16 KB, the scan 6 KB).
#[derive(Debug, Clone)]
pub struct Localizer {
    config: LocalizerConfig,
    /// Per squared distance (cells^2): the log-likelihood term, milli-nats (non-increasing).
    lut: [i32; MAX_D2_CELLS as usize + 1],
    /// Squared outlier distance, cells^2.
    inlier_d2: u32,
    /// Scan points relative to their centroid, G frame, in cells.
    points: [[f64; 2]; MAX_POINTS],
    /// Distance of each point from the centroid, cells.
    radius: [f64; MAX_POINTS],
    n: usize,
    centroid_g_m: [f64; 2],
    prior: [f64; 3],
    /// Prior centroid position relative to the map corner, cells.
    base: [f64; 2],
    yaw_step: f64,
    half: [i32; 3],
    cos_t: [f64; YAW_POSES],
    sin_t: [f64; YAW_POSES],
    queue: BinaryHeap<Node, Max, QUEUE_CAPACITY>,
    best: Leaf,
    runner_up: Option<i32>,
    phase: Phase,
    nodes: u32,
    point_evaluations: u32,
    queue_peak: usize,
    revision: u32,
}

impl Localizer {
    /// A localizer with `config` ([`LocalizationError::InvalidConfig`] when out of range):
    /// [`Self::EMPTY`] initialised by [`Self::init`].
    pub fn new(config: LocalizerConfig) -> Result<Self, LocalizationError> {
        let mut localizer = Self::EMPTY;
        localizer.init(config)?;
        Ok(localizer)
    }

    /// A placeholder (zero configuration and table, idle): the compile-time value of a
    /// statically allocated localizer before [`Self::init`]. Not meant to run.
    pub const EMPTY: Self = Self {
        config: LocalizerConfig {
            sigma_m: 0.0,
            outlier_distance_m: 0.0,
            window_sigmas: 0.0,
            min_window_m: 0.0,
            min_yaw_window_rad: 0.0,
            max_nodes: 0,
            min_points: 0,
            min_inliers: 0,
            min_inlier_fraction: 0.0,
            ambiguity_nats: 0.0,
            neighbourhood_steps: 0,
            covariance_scale: 0.0,
        },
        lut: [0; MAX_D2_CELLS as usize + 1],
        inlier_d2: 0,
        points: [[0.0; 2]; MAX_POINTS],
        radius: [0.0; MAX_POINTS],
        n: 0,
        centroid_g_m: [0.0; 2],
        prior: [0.0; 3],
        base: [0.0; 2],
        yaw_step: 0.0,
        half: [0; 3],
        cos_t: [1.0; YAW_POSES],
        sin_t: [0.0; YAW_POSES],
        queue: BinaryHeap::new(),
        best: Leaf {
            score: i32::MIN,
            x: 0,
            y: 0,
            t: 0,
        },
        runner_up: None,
        phase: Phase::Idle,
        nodes: 0,
        point_evaluations: 0,
        queue_peak: 0,
        revision: 0,
    };

    /// [`Self::new`] in place: this localizer becomes the one `new(config)` returns (every
    /// field rewritten, the arrays in loops: no 24 KB temporary on the stack). Refuses an
    /// invalid configuration (nothing changed then).
    pub fn init(&mut self, config: LocalizerConfig) -> Result<(), LocalizationError> {
        if !config.is_valid() {
            return Err(LocalizationError::InvalidConfig);
        }
        let scale = MAP_CELL_M * MAP_CELL_M / (2.0 * config.sigma_m * config.sigma_m);
        let d_out = config.outlier_distance_m / MAP_CELL_M;
        let cap = (d_out * d_out * scale).min(MAX_TERM_MILLI / 1000.0);
        for (d2, v) in self.lut.iter_mut().enumerate() {
            let nats = (d2 as f64 * scale).min(cap);
            *v = -(libm::round(nats * 1000.0).clamp(0.0, MAX_TERM_MILLI) as i32);
        }
        self.config = config;
        self.inlier_d2 = libm::floor(d_out * d_out) as u32;
        self.points.fill([0.0; 2]);
        self.radius.fill(0.0);
        self.n = 0;
        self.centroid_g_m = [0.0; 2];
        self.prior = [0.0; 3];
        self.base = [0.0; 2];
        self.yaw_step = 0.0;
        self.half = [0; 3];
        self.cos_t.fill(1.0);
        self.sin_t.fill(0.0);
        self.queue.clear();
        self.best = Leaf {
            score: i32::MIN,
            x: 0,
            y: 0,
            t: 0,
        };
        self.runner_up = None;
        self.phase = Phase::Idle;
        self.nodes = 0;
        self.point_evaluations = 0;
        self.queue_peak = 0;
        self.revision = 0;
        Ok(())
    }

    /// The configuration.
    pub fn config(&self) -> &LocalizerConfig {
        &self.config
    }

    /// True while a search is running.
    pub fn is_busy(&self) -> bool {
        self.phase != Phase::Idle
    }

    /// Localizes the hazard cells of `grid` ([`LocalScan::from_grid`]) whose estimated
    /// placement is `frame` (the prior: origin `x, y` and heading) against `global`, with the
    /// prior covariance `prior_cov` of `[x, y, heading]` of `G` (m^2, m^2 rad, rad^2). The
    /// whole search in one call: at most [`LocalizerConfig::max_nodes`] nodes of at most
    /// [`MAX_POINTS`] point terms each, plus 131 poses of the peak fit.
    pub fn localize(
        &mut self,
        global: &GlobalMap,
        grid: &TerrainGrid,
        frame: &GridFrame,
        prior_cov: [[f64; 3]; 3],
    ) -> Result<LocalizationFix, LocalizationError> {
        let scan = LocalScan::from_grid(grid);
        let prior = [
            frame.origin_world_m[0],
            frame.origin_world_m[1],
            frame.heading_rad,
        ];
        self.localize_scan(global, &scan, prior, prior_cov)
    }

    /// [`Self::start`], then [`Self::step`] until the search ends.
    pub fn localize_scan(
        &mut self,
        global: &GlobalMap,
        scan: &LocalScan,
        prior: [f64; 3],
        prior_cov: [[f64; 3]; 3],
    ) -> Result<LocalizationFix, LocalizationError> {
        self.start(global, scan, prior, prior_cov)?;
        // Each step evaluates at least one node; the budget ends the search.
        let limit = self.config.max_nodes.saturating_add(2);
        for _ in 0..limit {
            if let SearchProgress::Finished(r) = self.step(global, u32::MAX) {
                return r;
            }
        }
        self.phase = Phase::Idle;
        Err(LocalizationError::NodeBudgetExceeded)
    }

    /// Starts a search of `scan` (`G` frame) against `global` around the prior pose of `G`
    /// `prior = [x, y, heading]` (`W`, m, rad) with covariance `prior_cov`. Errors:
    /// [`LocalizationError::MapNotReady`], [`LocalizationError::InvalidPrior`],
    /// [`LocalizationError::TooFewPoints`], [`LocalizationError::PriorTooUncertain`]. A search
    /// already running is abandoned.
    pub fn start(
        &mut self,
        global: &GlobalMap,
        scan: &LocalScan,
        prior: [f64; 3],
        prior_cov: [[f64; 3]; 3],
    ) -> Result<(), LocalizationError> {
        self.phase = Phase::Idle;
        self.queue.clear();
        if !global.is_ready() {
            return Err(LocalizationError::MapNotReady);
        }
        if !prior_is_valid(&prior, &prior_cov) {
            return Err(LocalizationError::InvalidPrior);
        }
        let pts = scan.points();
        let n = pts.len().min(MAX_POINTS);
        if n < usize::from(self.config.min_points) {
            return Err(LocalizationError::TooFewPoints { points: n as u16 });
        }
        // Centroid and radii (points are finite and within 100 m: LocalScan::push).
        let (mut sx, mut sy) = (0.0, 0.0);
        for p in pts.iter().take(n) {
            sx += p[0];
            sy += p[1];
        }
        let c = [sx / n as f64, sy / n as f64];
        let mut r_max = 0.0f64;
        for ((p, dst), r) in pts
            .iter()
            .zip(self.points.iter_mut())
            .zip(self.radius.iter_mut())
        {
            let q = [(p[0] - c[0]) / MAP_CELL_M, (p[1] - c[1]) / MAP_CELL_M];
            *dst = q;
            *r = libm::hypot(q[0], q[1]);
            r_max = r_max.max(*r);
        }
        // One yaw step moves the farthest point by one cell (at least 1 m of lever arm).
        self.yaw_step = 1.0 / r_max.max(1.0 / MAP_CELL_M);
        // Prior of the centroid: T0 = o + R(yaw0) c, covariance J P J'.
        let (s0, c0) = libm::sincos(prior[2]);
        let rc = [c0 * c[0] - s0 * c[1], s0 * c[0] + c0 * c[1]];
        let t0 = [prior[0] + rc[0], prior[1] + rc[1]];
        let j = [[1.0, 0.0, -rc[1]], [0.0, 1.0, rc[0]], [0.0, 0.0, 1.0]];
        let pc = congruence(&j, &prior_cov);
        let k = self.config.window_sigmas;
        let half_xy = |var: f64| {
            let w =
                (k * crate::linalg::sqrt(var.max(0.0))).max(self.config.min_window_m) / MAP_CELL_M;
            libm::ceil(w).max(2.0)
        };
        let half_t = (k * crate::linalg::sqrt(pc[2][2].max(0.0)))
            .max(self.config.min_yaw_window_rad)
            / self.yaw_step;
        let half = [
            half_xy(pc[0][0]),
            half_xy(pc[1][1]),
            libm::ceil(half_t).max(2.0),
        ];
        let max_xy = f64::from(MAX_HALF_WINDOW_CELLS);
        if !(half[0] <= max_xy && half[1] <= max_xy && half[2] <= f64::from(MAX_HALF_YAW_STEPS)) {
            return Err(LocalizationError::PriorTooUncertain);
        }
        self.half = [half[0] as i32, half[1] as i32, half[2] as i32];
        let origin = global.origin_m();
        self.base = [
            (t0[0] - origin[0]) / MAP_CELL_M,
            (t0[1] - origin[1]) / MAP_CELL_M,
        ];
        let step = self.yaw_step;
        for (t, (cs, sn)) in self.cos_t.iter_mut().zip(self.sin_t.iter_mut()).enumerate() {
            let yaw = prior[2] + f64::from(t as i32 - MAX_HALF_YAW_STEPS) * step;
            let (s, c) = libm::sincos(yaw);
            *cs = c;
            *sn = s;
        }
        self.n = n;
        self.centroid_g_m = c;
        self.prior = prior;
        self.nodes = 0;
        self.point_evaluations = 0;
        self.queue_peak = 0;
        self.runner_up = None;
        self.revision = global.revision();
        // The nominal pose first (V99 sec. 5), then the root box.
        self.best = Leaf {
            score: self.score(global, 0, 0, 0),
            x: 0,
            y: 0,
            t: 0,
        };
        self.nodes = 1;
        self.phase = Phase::Search;
        let root = self.root();
        self.dive(global, root);
        self.push_root(global)
    }

    /// Advances the search by at most `max_nodes` node expansions (each evaluates up to 8
    /// children of up to [`MAX_POINTS`] point terms). `global` must be the map given to
    /// [`Self::start`], unchanged ([`LocalizationError::MapChanged`]).
    pub fn step(&mut self, global: &GlobalMap, max_nodes: u32) -> SearchProgress {
        if self.phase == Phase::Idle {
            return SearchProgress::Finished(Err(LocalizationError::NotStarted));
        }
        if global.revision() != self.revision {
            return self.fail(LocalizationError::MapChanged);
        }
        for _ in 0..max_nodes.max(1) {
            if self.nodes > self.config.max_nodes {
                return self.fail(LocalizationError::NodeBudgetExceeded);
            }
            let threshold = self.threshold();
            let Some(node) = self.queue.pop() else {
                if let Some(done) = self.end_of_pass(global) {
                    return done;
                }
                continue;
            };
            if node.bound < threshold {
                self.queue.clear();
                if let Some(done) = self.end_of_pass(global) {
                    return done;
                }
                continue;
            }
            if let Err(e) = self.expand(global, &node) {
                return self.fail(e);
            }
            if self.phase == Phase::Ambiguity && self.runner_up.is_some() {
                return self.fail(LocalizationError::Ambiguous);
            }
        }
        SearchProgress::Working { nodes: self.nodes }
    }

    fn fail(&mut self, e: LocalizationError) -> SearchProgress {
        self.phase = Phase::Idle;
        self.queue.clear();
        SearchProgress::Finished(Err(e))
    }

    /// Score below which a box is pruned in the current pass.
    fn threshold(&self) -> i32 {
        match self.phase {
            Phase::Ambiguity => self.best.score.saturating_sub(self.ambiguity_milli()),
            _ => self.best.score,
        }
    }

    fn ambiguity_milli(&self) -> i32 {
        libm::round(self.config.ambiguity_nats * 1000.0).clamp(0.0, 1.0e9) as i32
    }

    /// The end of a pass: the search pass hands over to the ambiguity pass, which ends the
    /// search (`Some`), unless the optimum already fails a check.
    fn end_of_pass(&mut self, global: &GlobalMap) -> Option<SearchProgress> {
        match self.phase {
            Phase::Search => {
                let b = self.best;
                let edge = b.x.abs() >= self.half[0]
                    || b.y.abs() >= self.half[1]
                    || b.t.abs() >= self.half[2];
                if edge {
                    return Some(self.fail(LocalizationError::PeakOnWindowEdge));
                }
                let inliers = self.inliers(global, &b);
                let points = self.n as u16;
                let fraction = f64::from(inliers) / f64::from(points.max(1));
                if inliers < self.config.min_inliers || fraction < self.config.min_inlier_fraction {
                    return Some(self.fail(LocalizationError::TooFewInliers { inliers, points }));
                }
                self.phase = Phase::Ambiguity;
                if let Err(e) = self.push_root(global) {
                    return Some(self.fail(e));
                }
                None
            }
            Phase::Ambiguity => {
                self.phase = Phase::Idle;
                Some(SearchProgress::Finished(self.finish(global)))
            }
            Phase::Idle => Some(SearchProgress::Finished(Err(LocalizationError::NotStarted))),
        }
    }

    /// The root box over the whole window (sides padded to powers of two).
    fn root(&self) -> Node {
        let log2 = |h: i32| {
            let w = (2 * h + 1) as u32;
            (u32::BITS - (w - 1).leading_zeros()) as u8
        };
        Node {
            bound: 0,
            x0: -self.half[0] as i16,
            y0: -self.half[1] as i16,
            t0: -self.half[2] as i16,
            lx: log2(self.half[0]),
            ly: log2(self.half[1]),
            lt: log2(self.half[2]),
        }
    }

    /// The root box, queued if its bound passes.
    fn push_root(&mut self, global: &GlobalMap) -> Result<(), LocalizationError> {
        let root = self.root();
        self.consider(global, root)
    }

    /// The up to 8 children of `node`: halves along every dimension wider than one pose.
    fn children(node: &Node) -> heapless::Vec<Node, 8> {
        let halves = |start: i16, l: u8| -> [(i16, u8, bool); 2] {
            if l == 0 {
                [(start, 0, true), (start, 0, false)]
            } else {
                let h = 1i16 << (l - 1);
                [(start, l - 1, true), (start.saturating_add(h), l - 1, true)]
            }
        };
        let mut out = heapless::Vec::new();
        for (x0, lx, ux) in halves(node.x0, node.lx) {
            for (y0, ly, uy) in halves(node.y0, node.ly) {
                for (t0, lt, ut) in halves(node.t0, node.lt) {
                    if ux && uy && ut {
                        // At most 2 x 2 x 2 children: the push cannot fail.
                        let _ = out.push(Node {
                            bound: 0,
                            x0,
                            y0,
                            t0,
                            lx,
                            ly,
                            lt,
                        });
                    }
                }
            }
        }
        out
    }

    /// Splits `node` and considers each child.
    fn expand(&mut self, global: &GlobalMap, node: &Node) -> Result<(), LocalizationError> {
        // By reference: a `heapless::Vec` consumed by value drops its iterator through a
        // checked slice index (a panic path in the image).
        for child in Self::children(node).iter() {
            self.consider(global, *child)?;
        }
        Ok(())
    }

    /// A greedy dive from `node` to a pose along the child of the highest bound, recording
    /// the poses it meets: a good incumbent early keeps the best-first frontier (the queue)
    /// small. It changes only the incumbent, never the optimum.
    fn dive(&mut self, global: &GlobalMap, mut node: Node) {
        // Each level halves a dimension: at most 3 x 7 levels for the largest window.
        for _ in 0..32 {
            let mut next: Option<Node> = None;
            for c in Self::children(&node).iter() {
                let mut child = *c;
                let Some(range) = self.clip(&child) else {
                    continue;
                };
                self.nodes = self.nodes.saturating_add(1);
                if child.lx == 0 && child.ly == 0 && child.lt == 0 {
                    let leaf = Leaf {
                        score: self.score(global, range[0], range[2], range[4]),
                        x: range[0],
                        y: range[2],
                        t: range[4],
                    };
                    if leaf.better_than(&self.best) {
                        self.best = leaf;
                    }
                    continue;
                }
                child.bound = self.bound(global, &range);
                if next.is_none_or(|n| child.bound > n.bound) {
                    next = Some(child);
                }
            }
            match next {
                Some(n) if n.bound > self.best.score => node = n,
                _ => break,
            }
        }
    }

    /// Evaluates a box (its bound) or a single pose (its likelihood) and queues or records
    /// it.
    fn consider(&mut self, global: &GlobalMap, mut node: Node) -> Result<(), LocalizationError> {
        let Some(range) = self.clip(&node) else {
            return Ok(());
        };
        let inside_peak = self.phase == Phase::Ambiguity && self.within_peak(&range);
        if inside_peak {
            return Ok(());
        }
        self.nodes = self.nodes.saturating_add(1);
        if node.lx == 0 && node.ly == 0 && node.lt == 0 {
            let leaf = Leaf {
                score: self.score(global, range[0], range[2], range[4]),
                x: range[0],
                y: range[2],
                t: range[4],
            };
            match self.phase {
                Phase::Search => {
                    if leaf.better_than(&self.best) {
                        self.best = leaf;
                    }
                }
                Phase::Ambiguity => {
                    if leaf.score >= self.threshold() && !self.leaf_in_peak(&leaf) {
                        self.runner_up = Some(leaf.score);
                    }
                }
                Phase::Idle => {}
            }
            return Ok(());
        }
        node.bound = self.bound(global, &range);
        if node.bound < self.threshold() {
            return Ok(());
        }
        self.queue
            .push(node)
            .map_err(|_| LocalizationError::QueueFull)?;
        self.queue_peak = self.queue_peak.max(self.queue.len());
        Ok(())
    }

    /// The box's poses inside the window, `[x_a, x_b, y_a, y_b, t_a, t_b]` (inclusive),
    /// `None` when none.
    fn clip(&self, node: &Node) -> Option<[i32; 6]> {
        let span = |start: i16, l: u8, h: i32| {
            let a = i32::from(start);
            let b = a + (1i32 << l) - 1;
            let (a, b) = (a.max(-h), b.min(h));
            (a <= b).then_some((a, b))
        };
        let (xa, xb) = span(node.x0, node.lx, self.half[0])?;
        let (ya, yb) = span(node.y0, node.ly, self.half[1])?;
        let (ta, tb) = span(node.t0, node.lt, self.half[2])?;
        Some([xa, xb, ya, yb, ta, tb])
    }

    fn neighbourhood(&self) -> i32 {
        i32::from(self.config.neighbourhood_steps)
    }

    /// True when every pose of `range` is inside the peak's neighbourhood.
    fn within_peak(&self, r: &[i32; 6]) -> bool {
        let n = self.neighbourhood();
        let b = self.best;
        r[0] >= b.x - n
            && r[1] <= b.x + n
            && r[2] >= b.y - n
            && r[3] <= b.y + n
            && r[4] >= b.t - n
            && r[5] <= b.t + n
    }

    fn leaf_in_peak(&self, l: &Leaf) -> bool {
        self.within_peak(&[l.x, l.x, l.y, l.y, l.t, l.t])
    }

    /// The optimum of the discretised pose space by exhaustive evaluation (tests): the same
    /// likelihood and order as the search, after [`Self::start`].
    #[cfg(test)]
    pub(crate) fn brute_force(&mut self, global: &GlobalMap) -> Leaf {
        let mut best = Leaf {
            score: i32::MIN,
            x: 0,
            y: 0,
            t: 0,
        };
        let h = self.half;
        for x in -h[0]..=h[0] {
            for y in -h[1]..=h[1] {
                for t in -h[2]..=h[2] {
                    let leaf = Leaf {
                        score: self.score(global, x, y, t),
                        x,
                        y,
                        t,
                    };
                    if leaf.better_than(&best) {
                        best = leaf;
                    }
                }
            }
        }
        best
    }

    /// The best discrete pose of the last search pass (tests).
    #[cfg(test)]
    pub(crate) fn best_leaf(&self) -> Leaf {
        self.best
    }
}

/// True when the prior pose is finite and its covariance finite, symmetric (1e-9 relative)
/// with a non-negative diagonal and 2x2 minors.
fn prior_is_valid(prior: &[f64; 3], cov: &[[f64; 3]; 3]) -> bool {
    if !prior
        .iter()
        .chain(cov.iter().flatten())
        .all(|v| v.is_finite())
    {
        return false;
    }
    if libm::fabs(prior[0]) > 1.0e6 || libm::fabs(prior[1]) > 1.0e6 || libm::fabs(prior[2]) > 1.0e3
    {
        return false;
    }
    for r in 0..3 {
        if !(cov[r][r] >= 0.0) {
            return false;
        }
        for c in 0..r {
            let (a, b) = (cov[r][c], cov[c][r]);
            if libm::fabs(a - b) > 1.0e-9 * (1.0 + libm::fabs(a)) {
                return false;
            }
            if a * a > cov[r][r] * cov[c][c] * (1.0 + 1.0e-9) + 1.0e-18 {
                return false;
            }
        }
    }
    true
}
