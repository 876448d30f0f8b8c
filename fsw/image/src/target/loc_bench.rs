//! The terrain-map localization (V99 sec. 5; `fsw::localization`) measured on a
//! synthetic rock field, since the tape's scene (a sand slope) has no rocks to match.
//!
//! A deterministic field (xorshift64, fixed seed) of [`ROCKS`] rocks, 0.1 to 0.4 m in radius,
//! over a 28 m square (0.5 rocks per m^2, between `marsyard-25m`'s 0.3 and the rockier 1.0 of
//! `docs/localization.md`) gives the global map: rock centres and a 0.1 m lattice inside each
//! disc, displaced per rock by up to 0.05 m (the map's error). Building it (insertion and the
//! distance transform, `GlobalMap::finish`) is one measured task. Each of [`TRIALS`] trials
//! places the rover at a random pose, marks the hazard cells of a `TerrainGrid` that fall in a
//! rock inside the hazcam wedge (0.3-3.2 m ahead, 35 deg half-angle), and localizes them from a
//! prior displaced by up to 2 sigma of a 0.3 m / 0.03 rad prior (the search window of the
//! flight's defaults): one measured `Localizer::localize` call each, the whole search.

use super::measure::{Meter, Stats};
use fsw::localization::{GlobalMap, Localizer, LocalizerConfig};
use fsw::perception::grid::{cell_centre, CellClass, GridFrame, TerrainGrid};
use fsw::perception::{GRID_COLS, GRID_ROWS};
use fsw::sequencer::{ResourceModel, Sequencer, Situation, Target, MAX_TARGETS};

/// Rocks of the synthetic field.
const ROCKS: usize = 392;
/// Localization trials.
pub const TRIALS: usize = 8;
/// Half-side of the field, m.
const HALF_M: f64 = 14.0;
/// Prior 1-sigma of the trials: x, y (m) and heading (rad).
const PRIOR_SIGMA: [f64; 3] = [0.3, 0.3, 0.03];

/// A rock: centre (m, world) and radius (m).
#[derive(Clone, Copy, Default)]
struct Rock {
    c: [f64; 2],
    r: f64,
}

/// xorshift64 (Marsaglia 2003): deterministic on host and target.
struct Rng(u64);

impl Rng {
    fn next_f64(&mut self) -> f64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        (x >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `[lo, hi)`.
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }
}

/// The localization's statics (in `.extram`, built in the initialisation phase).
pub struct LocBench {
    global: &'static mut GlobalMap,
    localizer: &'static mut Localizer,
    grid: &'static mut TerrainGrid,
    rocks: &'static mut [Rock; ROCKS],
}

impl LocBench {
    /// The map, the localizer with the flight defaults and a terrain grid, in `.extram`. Each
    /// is built by its own function, so that their by-value temporaries do not share a frame.
    #[inline(never)]
    pub fn install() -> Option<Self> {
        let global = install_global()?;
        let localizer = install_localizer()?;
        let grid = install_grid()?;
        let rocks = install_rocks()?;
        Some(Self {
            global,
            localizer,
            grid,
            rocks,
        })
    }

    /// [`TRIALS`] replans of the on-board sequencer (V99 sec. 3) on random problems
    /// of [`MAX_TARGETS`] targets over 30 m with random priorities, windows, dwells and energy
    /// (the largest plans it takes), each after a leg penalty and, every other one, a
    /// localization request, committed to one target as the navigator's replans are (into
    /// `stats`; a replan error counts as an error).
    pub fn sequencer(&mut self, meter: &mut Meter, stats: &mut Stats) {
        let mut rng = Rng(0x5851_F42D_4C95_7F2D);
        for trial in 0..TRIALS {
            let mut targets = [Target {
                position_m: [0.0; 2],
                priority: 0,
                window_open_s: 0.0,
                window_close_s: 0.0,
                dwell_s: 0.0,
                dwell_energy_j: 0.0,
            }; MAX_TARGETS];
            for t in targets.iter_mut() {
                let open = rng.range(0.0, 3000.0);
                *t = Target {
                    position_m: [rng.range(-15.0, 15.0), rng.range(-15.0, 15.0)],
                    priority: (rng.range(0.0, 5.0)) as u8,
                    window_open_s: open,
                    window_close_s: open + rng.range(100.0, 5000.0),
                    dwell_s: rng.range(0.0, 600.0),
                    dwell_energy_j: rng.range(0.0, 5000.0),
                };
            }
            let Ok(mut seq) = Sequencer::new(&targets, ResourceModel::rocky8()) else {
                stats.add(0, false);
                continue;
            };
            let situation = Situation {
                now_s: 0.0,
                position_m: [0.0, 0.0],
                energy_available_j: rng.range(5e4, 1.5e5),
                end_s: rng.range(4000.0, 8000.0),
            };
            let _ = seq.set_leg_penalty(trial % MAX_TARGETS, rng.range(0.0, 20.0));
            if trial % 2 == 1 {
                seq.request_localization();
            }
            // As the navigator replans while driving: committed to a target
            // (`fsw::flight::nav::mission`), its hysteresis.
            let committed = Some((trial + 3) % MAX_TARGETS);
            let hysteresis = fsw::flight::nav::mission::COMMIT_HYSTERESIS_S;
            let (r, n) = meter.measure(|| seq.replan_committed(&situation, committed, hysteresis));
            stats.add(n, r.is_ok());
        }
    }

    /// Build the field's map (into `map_stats`) and run the trials (into `loc_stats`; a trial
    /// that ends in an error value counts as an error).
    pub fn run(&mut self, meter: &mut Meter, map_stats: &mut Stats, loc_stats: &mut Stats) {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let rocks = &mut *self.rocks;
        for r in rocks.iter_mut() {
            r.c = [rng.range(-HALF_M, HALF_M), rng.range(-HALF_M, HALF_M)];
            r.r = rng.range(0.1, 0.4);
        }
        let global = &mut *self.global;
        let (ok, n) = meter.measure(|| {
            if !global.reset_centred([0.0, 0.0]) {
                return false;
            }
            let mut rng = Rng(0x2545_F491_4F6C_DD1D);
            for r in rocks.iter() {
                let off = [rng.range(-0.05, 0.05), rng.range(-0.05, 0.05)];
                let steps = libm::ceil(r.r / 0.1) as i32;
                for a in -steps..=steps {
                    for b in -steps..=steps {
                        let (dx, dy) = (f64::from(a) * 0.1, f64::from(b) * 0.1);
                        if dx * dx + dy * dy <= r.r * r.r {
                            global.insert_point([r.c[0] + dx + off[0], r.c[1] + dy + off[1]]);
                        }
                    }
                }
            }
            global.finish();
            global.is_ready()
        });
        map_stats.add(n, ok);
        let tan = libm::tan(35.0_f64.to_radians());
        let cov = [
            [PRIOR_SIGMA[0] * PRIOR_SIGMA[0], 0.0, 0.0],
            [0.0, PRIOR_SIGMA[1] * PRIOR_SIGMA[1], 0.0],
            [0.0, 0.0, PRIOR_SIGMA[2] * PRIOR_SIGMA[2]],
        ];
        for _ in 0..TRIALS {
            let truth = GridFrame::new(
                [rng.range(-4.0, 4.0), rng.range(-4.0, 4.0), 0.0],
                rng.range(-3.1, 3.1),
            );
            self.grid.clear();
            for i in 0..GRID_ROWS {
                for j in 0..GRID_COLS {
                    let g = cell_centre(i, j);
                    if !(g[0] >= 0.3 && g[0] <= 3.2 && libm::fabs(g[1]) <= g[0] * tan + 0.2) {
                        continue;
                    }
                    let w = truth.to_world_xy(g);
                    let inside = rocks.iter().any(|r| {
                        let (dx, dy) = (w[0] - r.c[0], w[1] - r.c[1]);
                        dx * dx + dy * dy <= r.r * r.r
                    });
                    if inside {
                        self.grid.set_class(i, j, CellClass::Hazard);
                    }
                }
            }
            let prior = GridFrame::new(
                [
                    truth.origin_world_m[0] + rng.range(-2.0, 2.0) * PRIOR_SIGMA[0],
                    truth.origin_world_m[1] + rng.range(-2.0, 2.0) * PRIOR_SIGMA[1],
                    0.0,
                ],
                truth.heading_rad + rng.range(-2.0, 2.0) * PRIOR_SIGMA[2],
            );
            let (global, localizer, grid) = (&*self.global, &mut *self.localizer, &*self.grid);
            let (r, n) = meter.measure(|| localizer.localize(global, grid, &prior, cov));
            loc_stats.add(n, r.is_ok());
        }
    }
}

#[inline(never)]
fn install_global() -> Option<&'static mut GlobalMap> {
    const EMPTY: GlobalMap = GlobalMap::new();
    super::take_static!(extram, GlobalMap, EMPTY)
}

#[inline(never)]
fn install_localizer() -> Option<&'static mut Localizer> {
    let localizer = super::take_static!(extram, Localizer, Localizer::EMPTY)?;
    localizer.init(LocalizerConfig::default()).ok()?;
    Some(localizer)
}

#[inline(never)]
fn install_grid() -> Option<&'static mut TerrainGrid> {
    const EMPTY: TerrainGrid = TerrainGrid::new();
    super::take_static!(extram, TerrainGrid, EMPTY)
}

#[inline(never)]
fn install_rocks() -> Option<&'static mut [Rock; ROCKS]> {
    super::take_static!(extram, [Rock; ROCKS], [Rock::default(); ROCKS])
}
