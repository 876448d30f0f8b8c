//! The software-in-the-loop (SIL) acceptance cases: closed-loop scenario runs of the flight
//! software with thresholds, each tagged with a requirement id. One table of cases serves both
//! the tests (`tests/tests/sil_scenarios.rs`) and the results page (`sim-host sil`, which writes
//! `docs/results/sil-results.md`), so the thresholds are written once.
//!
//! Every case renders the stereo images (the flight VO runs on them) and uses the simulated
//! time as the execution counter, so the figures are deterministic for a scenario and seed.
//!
//! - this module: the case and check types, [`run_case`], the `sil` subcommand;
//! - [`cases`]: the table of cases ([`CASES`]) with the variants and checks they share;
//! - [`page`]: the results page, filled into the template `page.md`.

use crate::closed_loop::{run, RunOptions};
use crate::devices::hazcam_calibration;
use crate::devices::renderer::{StereoRenderer, TexturedRenderer};
use crate::devices::world::CounterMode;
use crate::output::summary::{summarise, Summary};
use crate::scenario::Scenario;
use std::path::Path;

pub mod batch;
pub mod cases;
pub mod command;
pub mod page;
pub mod seeds;

pub use cases::{case, CASES};
pub use command::{main, SilArgs};
pub use page::markdown;

/// How a measured value is compared with its threshold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compare {
    /// Pass when `value <= threshold`.
    AtMost,
    /// Pass when `value >= threshold`.
    AtLeast,
}

/// The statistic over the seeds at which a check holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stat {
    /// An error: its 95th percentile (nearest rank) within the threshold (`AtMost`), or its
    /// 5th percentile (`AtLeast`) beyond it. A seed without the value counts as the worst.
    Percentile,
    /// A verdict (goal reached, the right planner status, a safe stop): at least this
    /// fraction of the seeds pass it.
    Fraction(f64),
    /// Collisions, false arrivals, honest ends and what a scenario is built to provoke: every
    /// seed passes (the maximum, or the minimum, over the seeds).
    Every,
}

/// The fraction of seeds a verdict must pass ([`Stat::Fraction`]): the same 5 % a P95 error
/// leaves.
pub const VERDICT_FRACTION: f64 = 0.95;

/// The two runs a check can read: the case's run and, for a paired case, the same scenario
/// and seed without slip compensation (H05 Fig. 9's comparison). Dereferences to the case's
/// summary.
#[derive(Debug, Clone)]
pub struct Runs {
    /// The case's run.
    pub main: Summary,
    /// The paired run without slip compensation.
    pub no_comp: Option<Summary>,
}

impl std::ops::Deref for Runs {
    type Target = Summary;
    fn deref(&self) -> &Summary {
        &self.main
    }
}

/// One check of a case. Every check is a requirement; one the flight software does not meet
/// at its statistic over the release tier's seeds is open ([`cases::OPEN`]): shown failing,
/// with its value, and counted at the top of `docs/results/sil-results.md`. A unit test fails
/// when a check's release verdict contradicts the list (`seeds::consistency`).
#[derive(Debug, Clone, Copy)]
pub struct Check {
    /// What is measured (table text).
    pub what: &'static str,
    /// The measurement from the run's summaries (`None`: the estimate does not exist).
    pub value: fn(&Runs) -> Option<f64>,
    /// Comparison.
    pub compare: Compare,
    /// Threshold.
    pub threshold: f64,
    /// Unit (table text).
    pub unit: &'static str,
    /// The statistic over the seeds.
    pub stat: Stat,
}

impl Check {
    /// The check on one seed's value.
    pub fn passes(&self, value: Option<f64>) -> bool {
        value.is_some_and(|v| match self.compare {
            Compare::AtMost => v <= self.threshold,
            Compare::AtLeast => v >= self.threshold,
        })
    }
}

/// One SIL case: a scenario run and its checks.
#[derive(Debug, Clone, Copy)]
pub struct Case {
    /// Requirement id.
    pub id: &'static str,
    /// Scenario file stem in `scenarios/`.
    pub scenario: &'static str,
    /// Run without slip compensation.
    pub no_slip_comp: bool,
    /// Also run the same scenario and seed without slip compensation ([`Runs::no_comp`]).
    pub paired: bool,
    /// Scenario changes of this case (slip off, exact dimensions, slip model), applied to the
    /// scenario file before the run.
    pub variant: Variant,
    /// What the case shows.
    pub title: &'static str,
    /// Checks.
    pub checks: &'static [Check],
}

/// Scenario changes of a case.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Variant {
    /// The terrain produces no slip.
    pub no_slip: bool,
    /// The truth vehicle has the published dimensions exactly (no per-seed dimension or
    /// wheel-radius errors): what is left is the difference of the kinematic formulations.
    pub exact_dimensions: bool,
    /// The lumped slip model (one body-level slip with its chosen lateral
    /// constant), whatever the scenario says: a reference against the default per-wheel
    /// rigid-wheel terramechanics.
    pub lumped: bool,
    /// Visual odometry off in the flight software (the images are then not rendered unless
    /// `localization` uses them).
    pub no_vo: bool,
    /// Terrain-map localization on, against the MARDI map the simulator uplinks (V99 sec. 5).
    pub localization: bool,
    /// The uplinked map is registered wrongly: moved by [`MAP_TIE_FAULT_M`].
    pub map_tie_fault: bool,
    /// The mission's energy budget replaced, kJ (SIL-SEQ-2's shortfall).
    pub energy_budget_kj: Option<u32>,
}

/// The map-tie fault of SIL-LOC-2: 1.5 m (north 1.2 m, east -0.9 m), beyond the localization's
/// search window (3 x 0.3 m) and five times a fix's error.
pub const MAP_TIE_FAULT_M: [f64; 2] = [1.2, -0.9];

impl Variant {
    /// The scenario as this variant runs it.
    pub fn apply(&self, scenario: &mut Scenario) {
        if self.no_slip {
            scenario.slip = false;
        }
        if self.exact_dimensions {
            scenario.sensors.dimension_error_m = 0.0;
            scenario.sensors.wheel_radius_error_m = 0.0;
        }
        if self.lumped {
            scenario.slip_model = crate::scenario::SlipModelKind::Lumped;
        }
        if let (Some(kj), Some(m)) = (self.energy_budget_kj, scenario.mission.as_mut()) {
            m.energy_budget_j = f64::from(kj) * 1000.0;
        }
    }

    /// Table text.
    pub fn label(&self) -> String {
        let mut parts = Vec::new();
        if self.no_slip {
            parts.push("no slip".to_string());
        }
        if self.exact_dimensions {
            parts.push("exact dimensions".to_string());
        }
        if self.lumped {
            parts.push("lumped slip model".to_string());
        }
        if self.no_vo {
            parts.push("no VO".to_string());
        }
        if self.localization {
            parts.push("localization".to_string());
        }
        if self.map_tie_fault {
            parts.push("map 1.5 m off".to_string());
        }
        if let Some(kj) = self.energy_budget_kj {
            parts.push(format!("energy budget {kj} kJ"));
        }
        parts.join(", ")
    }
}

impl Case {
    /// The `k`-th check is open ([`cases::OPEN`]).
    pub fn is_open(&self, k: usize) -> bool {
        cases::OPEN
            .iter()
            .any(|(id, i, _)| *id == self.id && *i == k)
    }
}

/// A case run on one seed.
#[derive(Debug, Clone)]
pub struct CaseRun {
    /// The case.
    pub case: Case,
    /// The seed (terrain, slip, noise and the rover unit's errors).
    pub seed: u64,
    /// The summaries.
    pub runs: Runs,
    /// The value of each check, in the case's order.
    pub values: Vec<Option<f64>>,
}

impl CaseRun {
    /// The checks of the case that fail on this seed.
    pub fn failing(&self) -> Vec<&'static str> {
        self.case
            .checks
            .iter()
            .zip(&self.values)
            .filter(|(c, v)| !c.passes(**v))
            .map(|(c, _)| c.what)
            .collect()
    }
}

/// One closed-loop run of `case`'s scenario on `seed` (with `no_slip_comp`), with `outputs`
/// writing every output of `sim-host run` there.
fn run_one(
    case: Case,
    scenarios_dir: &Path,
    seed: u64,
    no_slip_comp: bool,
    outputs: Option<&Path>,
) -> anyhow::Result<Summary> {
    let mut scenario = Scenario::load(&scenarios_dir.join(format!("{}.toml", case.scenario)))?;
    case.variant.apply(&mut scenario);
    scenario.seed = seed;
    scenario.terrain_seed = None;
    scenario.calibration_seed = None;
    let sun = scenario.site.sun_w(0.0);
    let renderer: Option<Box<dyn StereoRenderer>> =
        (!case.variant.no_vo || case.variant.localization).then(|| {
            Box::new(TexturedRenderer::new(
                hazcam_calibration(),
                scenario.seed,
                [sun.x, sun.y, sun.z],
            )) as Box<dyn StereoRenderer>
        });
    let result = run(
        &scenario,
        RunOptions {
            no_slip_comp,
            no_vo: case.variant.no_vo,
            localization: case.variant.localization,
            map_offset_m: if case.variant.map_tie_fault {
                MAP_TIE_FAULT_M
            } else {
                [0.0; 2]
            },
            counter: CounterMode::SimTime,
            renderer,
            ..RunOptions::default()
        },
    )?;
    match outputs {
        Some(dir) => crate::output::write_all(dir, &result),
        None => Ok(summarise(&result)),
    }
}

/// Run `case` on `seed` with the scenarios in `scenarios_dir`; `outputs` writes every output
/// of the case's run (and of its paired run, in `no-comp/`) there.
pub fn run_case(
    case: Case,
    scenarios_dir: &Path,
    seed: u64,
    outputs: Option<&Path>,
) -> anyhow::Result<CaseRun> {
    let main = run_one(case, scenarios_dir, seed, case.no_slip_comp, outputs)?;
    let no_comp = if case.paired {
        let dir = outputs.map(|o| o.join("no-comp"));
        Some(run_one(case, scenarios_dir, seed, true, dir.as_deref())?)
    } else {
        None
    };
    let runs = Runs { main, no_comp };
    let values = case.checks.iter().map(|c| (c.value)(&runs)).collect();
    Ok(CaseRun {
        case,
        seed,
        runs,
        values,
    })
}
