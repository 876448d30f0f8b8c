//! The software-in-the-loop (SIL) acceptance cases: closed-loop scenario runs of the flight
//! software with thresholds, each tagged with a requirement id. One table of cases serves both
//! the tests (`tests/tests/sil_scenarios.rs`) and the results page (`sim-host sil`, which writes
//! `docs/sil-results.md`), so the thresholds are written once.
//!
//! Every case renders the stereo images (the flight VO runs on them) and uses the simulated
//! time as the execution counter, so the figures are deterministic for a scenario and seed.

use crate::closed_loop::{run, RunOptions};
use crate::devices::hazcam_calibration;
use crate::devices::renderer::{StereoRenderer, TexturedRenderer};
use crate::devices::world::CounterMode;
use crate::output::summary::{summarise, Summary};
use crate::scenario::Scenario;
use std::path::{Path, PathBuf};

/// How a measured value is compared with its threshold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compare {
    /// Pass when `value <= threshold`.
    AtMost,
    /// Pass when `value >= threshold`.
    AtLeast,
}

/// One check of a case.
#[derive(Debug, Clone, Copy)]
pub struct Check {
    /// What is measured (table text).
    pub what: &'static str,
    /// The measurement from the run's summary (`None`: the estimate does not exist).
    pub value: fn(&Summary) -> Option<f64>,
    /// Comparison.
    pub compare: Compare,
    /// Threshold.
    pub threshold: f64,
    /// Unit (table text).
    pub unit: &'static str,
    /// A requirement (failing fails the test) or a goal (reported only).
    pub required: bool,
    /// A requirement that the flight software does not meet yet on the current simulator:
    /// reported as failing, listed in `docs/sil-results.md` with the reason, and not failing
    /// the tests until it is fixed.
    pub open: bool,
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
    /// The lumped slip model of before issue 13 (one body-level slip with its chosen lateral
    /// constant), whatever the scenario says: a reference against the default per-wheel
    /// rigid-wheel terramechanics.
    pub lumped: bool,
    /// Visual odometry off in the flight software (the images are then not rendered unless
    /// `localization` uses them).
    pub no_vo: bool,
    /// Terrain-map localization on, against the MARDI map the simulator uplinks (issue 17).
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

const BASE: Variant = Variant {
    no_slip: false,
    exact_dimensions: false,
    lumped: false,
    no_vo: false,
    localization: false,
    map_tie_fault: false,
    energy_budget_kj: None,
};

/// SIL-SEQ-2: `multi-target` with 54 kJ, less than the simulator's energy model needs for
/// every target (56 kJ) but far more than the flight software's a-priori model says the plan
/// takes (about 30 kJ): only the power telemetry shows the shortfall.
const ENERGY_SHORT: Variant = Variant {
    energy_budget_kj: Some(54),
    ..BASE
};

/// Requirement: the truth energy of the run within the mission's budget (ratio).
const WITHIN_ENERGY_BUDGET: Check = req(
    "truth energy used / the mission's budget",
    |s| {
        s.targets
            .as_ref()
            .map(|t| s.energy.used_j / t.energy_budget_j)
    },
    Compare::AtMost,
    1.0,
    "",
);

/// Outcome `outcome` of target `i` as a flag.
fn target_is(s: &Summary, i: usize, outcome: &str) -> Option<f64> {
    let t = s.targets.as_ref()?;
    Some(if t.outcomes.get(i).map(String::as_str) == Some(outcome) {
        1.0
    } else {
        0.0
    })
}

/// No slip, with the per-seed dimension and calibration errors (the gate's false alarms).
const NO_SLIP: Variant = Variant {
    no_slip: true,
    ..BASE
};

/// VO off, terrain-map localization on (V99 sec. 5, issue 17).
const LOCALIZATION: Variant = Variant {
    no_vo: true,
    localization: true,
    ..BASE
};

/// As [`LOCALIZATION`] with a map registered 1.5 m off.
const LOCALIZATION_WRONG_MAP: Variant = Variant {
    map_tie_fault: true,
    ..LOCALIZATION
};

/// VO off: IMU, sun sensor and kinematics only (RB's comparison).
const NO_VO: Variant = Variant {
    no_vo: true,
    ..BASE
};

/// The kinematic cases: no slip and exact dimensions, so that only the difference between the
/// flight kinematics and the truth kinematics is left.
const KINEMATIC: Variant = Variant {
    no_slip: true,
    exact_dimensions: true,
    ..BASE
};

/// The lumped slip model of before issue 13 (reference).
const LUMPED: Variant = Variant {
    lumped: true,
    ..BASE
};

/// The measured result of one check.
#[derive(Debug, Clone, Copy)]
pub struct CheckResult {
    /// The check.
    pub check: Check,
    /// Measured value.
    pub value: Option<f64>,
    /// Passed.
    pub pass: bool,
}

/// A finished case.
#[derive(Debug, Clone)]
pub struct CaseResult {
    /// The case.
    pub case: Case,
    /// The run's summary.
    pub summary: Summary,
    /// Check results in the case's order.
    pub checks: Vec<CheckResult>,
}

impl CaseResult {
    /// True when every required check passed.
    pub fn passed(&self) -> bool {
        self.checks.iter().all(|c| c.pass || !c.check.required)
    }
}

const fn req(
    what: &'static str,
    value: fn(&Summary) -> Option<f64>,
    compare: Compare,
    threshold: f64,
    unit: &'static str,
) -> Check {
    Check {
        what,
        value,
        compare,
        threshold,
        unit,
        required: true,
        open: false,
    }
}

const fn goal(
    what: &'static str,
    value: fn(&Summary) -> Option<f64>,
    compare: Compare,
    threshold: f64,
    unit: &'static str,
) -> Check {
    Check {
        required: false,
        ..req(what, value, compare, threshold, unit)
    }
}

/// A requirement not met yet (see [`Check::open`]).
const fn open(
    what: &'static str,
    value: fn(&Summary) -> Option<f64>,
    compare: Compare,
    threshold: f64,
    unit: &'static str,
) -> Check {
    Check {
        open: true,
        ..goal(what, value, compare, threshold, unit)
    }
}

fn flag(b: bool) -> Option<f64> {
    Some(if b { 1.0 } else { 0.0 })
}

/// Requirement: the RoverBug planner's verdict is `reached`.
const PLANNER_REACHED: Check = req(
    "planner status reached",
    |s| flag(s.planner.as_ref()?.status == "reached"),
    Compare::AtLeast,
    1.0,
    "",
);

/// Requirement: no truth-side collision with a hazard (`sim_host::hazards`).
const NO_COLLISION: Check = req(
    "truth-side collisions",
    |s| Some(f64::from(s.collisions)),
    Compare::AtMost,
    0.0,
    "",
);

/// H04 Fig. 17 (open): planar 2D odometry at least 30 % of the distance off over an extreme
/// traverse without slip...
const KIN2D_H04: Check = open(
    "2D kinematics error / distance",
    |s| s.error_pct.kin2d,
    Compare::AtLeast,
    30.0,
    "%",
);

/// ... while the flight 3D kinematics stays within 3 % (open).
const KIN3D_H04: Check = open(
    "3D kinematics error / distance",
    |s| s.error_pct.kin3d,
    Compare::AtMost,
    3.0,
    "%",
);

/// Requirement: the rover reached the goal within the scenario's tolerance.
const GOAL_REACHED: Check = req(
    "goal reached",
    |s| flag(s.goal_reached),
    Compare::AtLeast,
    1.0,
    "",
);

/// Requirement (issue 20): the drive ends honestly: either `Arrived` with the goal reached in
/// truth, or stopped by fault protection or safed (with its reason in the summary); never
/// `Arrived` outside the goal tolerance, never still driving.
const HONEST_END: Check = req(
    "arrived within tolerance, or stopped safe",
    |s| {
        flag(
            (s.nav_mode == "Arrived" && s.goal_reached)
                || s.fault_protection.stopped_safe
                || s.nav_mode == "Safed",
        )
    },
    Compare::AtLeast,
    1.0,
    "",
);

/// Requirement (issue 20): never `Arrived` outside the goal tolerance.
const NO_FALSE_ARRIVAL: Check = req(
    "no Arrived outside the tolerance",
    |s| flag(s.nav_mode != "Arrived" || s.goal_reached),
    Compare::AtLeast,
    1.0,
    "",
);

/// A fault scenario of issue 20 whose only requirement is an honest end.
const fn fault_case(id: &'static str, scenario: &'static str, title: &'static str) -> Case {
    Case {
        id,
        scenario,
        no_slip_comp: false,
        variant: BASE,
        title,
        checks: &[HONEST_END, NO_FALSE_ARRIVAL],
    }
}

/// Goal (issue 7): EKF final error at most 0.5 % of the distance.
const EKF_ONE_PERCENT: Check = req(
    "EKF error / distance",
    |s| s.error_pct.ekf,
    Compare::AtMost,
    1.0,
    "%",
);

const EKF_HALF_PERCENT: Check = goal(
    "EKF error / distance",
    |s| s.error_pct.ekf,
    Compare::AtMost,
    0.5,
    "%",
);

/// The SIL cases (H04 sec. 6, H05 sec. VI; issue thresholds).
pub const CASES: [Case; 31] = [
    Case {
        id: "SIL-GNC-1",
        scenario: "slope-10-cross",
        no_slip_comp: false,
        variant: BASE,
        title: "10 deg sand cross slope, slip compensation on (H05 Fig. 9)",
        checks: &[
            req(
                "cross-track max",
                |s| Some(s.cross_track_m.max),
                Compare::AtMost,
                0.15,
                "m",
            ),
            req(
                "goal miss",
                |s| Some(s.goal_miss_m),
                Compare::AtMost,
                0.10,
                "m",
            ),
            goal(
                "cross-track rms",
                |s| Some(s.cross_track_m.rms),
                Compare::AtMost,
                0.05,
                "m",
            ),
            req(
                "gate rejection fraction (slip detected, issue 14)",
                |s| s.slip.gate_reject_fraction,
                Compare::AtLeast,
                0.5,
                "",
            ),
        ],
    },
    Case {
        id: "SIL-GATE-1",
        scenario: "flat-firm",
        no_slip_comp: false,
        variant: NO_SLIP,
        title: "firm flat ground without slip: the gate's false alarms near its 5 % design \
                (issue 14)",
        checks: &[
            req(
                "gate rejection fraction",
                |s| s.slip.gate_reject_fraction,
                Compare::AtLeast,
                0.02,
                "",
            ),
            req(
                "gate rejection fraction",
                |s| s.slip.gate_reject_fraction,
                Compare::AtMost,
                0.08,
                "",
            ),
            GOAL_REACHED,
        ],
    },
    Case {
        id: "SIL-GATE-2",
        scenario: "rough-kinematics",
        no_slip_comp: false,
        variant: NO_SLIP,
        title: "firm rough ground without slip: few false alarms (issue 14)",
        checks: &[
            req(
                "gate rejection fraction",
                |s| s.slip.gate_reject_fraction,
                Compare::AtMost,
                0.10,
                "",
            ),
            GOAL_REACHED,
        ],
    },
    Case {
        id: "SIL-RB-1",
        scenario: "dunes-long",
        no_slip_comp: false,
        variant: NO_VO,
        title: "long sandy traverse without VO: EKF (IMU, sun, gated kinematics) against dead \
                reckoning (wheel odometry with gyro attitude; RB, issue 14)",
        checks: &[
            req(
                "EKF error / DR error",
                |s| Some(s.error_pct.ekf? / s.error_pct.dr?.max(1e-9)),
                Compare::AtMost,
                0.6,
                "x",
            ),
            goal(
                "EKF error / DR error (not worse)",
                |s| Some(s.error_pct.ekf? / s.error_pct.dr?.max(1e-9)),
                Compare::AtMost,
                1.0,
                "x",
            ),
            // A rate, not a count: the run ends where fault protection stops the rover at
            // the slip limit on the steep flanks (as SIL-NAV-2 with VO), so its length varies.
            // 8 per minute is the old count (50 over the first 6 min of the traverse); the sun
            // is read every 5 s (12 per minute).
            req(
                "sun updates applied per minute of the run",
                |s| Some(f64::from(s.nav.sun_applied) / (s.sim_time_s / 60.0).max(1e-9)),
                Compare::AtLeast,
                8.0,
                "",
            ),
        ],
    },
    Case {
        id: "SIL-GNC-2",
        scenario: "slope-10-cross",
        no_slip_comp: true,
        variant: BASE,
        title: "10 deg sand cross slope, slip compensation off: drifts downhill (H05 Fig. 9)",
        checks: &[open(
            "cross-track max (downhill drift)",
            |s| Some(s.cross_track_m.max),
            Compare::AtLeast,
            0.5,
            "m",
        )],
    },
    Case {
        id: "SIL-NAV-1",
        scenario: "marsyard-25m",
        no_slip_comp: false,
        variant: BASE,
        title: "25 m Mars Yard path with rocks (H04 sec. 6)",
        checks: &[
            req(
                "VO error / distance",
                |s| s.error_pct.vo,
                Compare::AtMost,
                2.5,
                "%",
            ),
            EKF_ONE_PERCENT,
            req(
                "EKF attitude error max",
                |s| s.max_attitude_error_deg.ekf,
                Compare::AtMost,
                2.0,
                "deg",
            ),
            req(
                "VO attitude error max",
                |s| s.max_attitude_error_deg.vo,
                Compare::AtMost,
                2.0,
                "deg",
            ),
            GOAL_REACHED,
            EKF_HALF_PERCENT,
        ],
    },
    Case {
        id: "SIL-KIN-1",
        scenario: "rough-kinematics",
        no_slip_comp: false,
        variant: BASE,
        title: "very rough terrain: 3D kinematics against planar 2D (H04 Fig. 17)",
        checks: &[
            req(
                "3D kinematics error / distance (radius scale from VO, KIN-14)",
                |s| s.error_pct.kin3d,
                Compare::AtMost,
                3.0,
                "%",
            ),
            goal(
                "2D error / 3D error",
                |s| Some(s.error_pct.kin2d? / s.error_pct.kin3d?.max(1e-9)),
                Compare::AtLeast,
                10.0,
                "x",
            ),
        ],
    },
    Case {
        id: "SIL-GNC-3",
        scenario: "slope-20-cross",
        no_slip_comp: false,
        variant: BASE,
        title: "20 deg sand cross slope: heavy slip, the gate rejects kinematics",
        checks: &[
            GOAL_REACHED,
            req(
                "gate rejection fraction",
                |s| s.slip.gate_reject_fraction,
                Compare::AtLeast,
                0.5,
                "",
            ),
            req(
                "cross-track max",
                |s| Some(s.cross_track_m.max),
                Compare::AtMost,
                0.3,
                "m",
            ),
        ],
    },
    Case {
        id: "SIL-GNC-4",
        scenario: "slope-10-faults",
        no_slip_comp: false,
        variant: BASE,
        title: "10 deg slope with black frames, IMU dropout, NaN joints and no sun: fallbacks",
        checks: &[
            req(
                "goal reached",
                |s| flag(s.goal_reached),
                Compare::AtLeast,
                1.0,
                "",
            ),
            req(
                "cross-track max",
                |s| Some(s.cross_track_m.max),
                Compare::AtMost,
                0.15,
                "m",
            ),
            HONEST_END,
            NO_FALSE_ARRIVAL,
            req(
                "device faults counted",
                |s| Some(f64::from(s.device_faults)),
                Compare::AtLeast,
                100.0,
                "",
            ),
            req(
                "VO failures counted",
                |s| s.vo.failures.map(|f| f as f64),
                Compare::AtLeast,
                1.0,
                "",
            ),
            req(
                "sensor holds (rover stopped)",
                |s| Some(f64::from(s.nav.sensor_holds)),
                Compare::AtLeast,
                1.0,
                "",
            ),
            req(
                "not safed",
                |s| flag(s.nav_mode != "Safed"),
                Compare::AtLeast,
                1.0,
                "",
            ),
        ],
    },
    Case {
        id: "SIL-NAV-2",
        scenario: "dunes-long",
        no_slip_comp: false,
        variant: BASE,
        title: "over 50 m across 15-25 deg sandy dunes",
        checks: &[
            open(
                "goal reached",
                |s| flag(s.goal_reached),
                Compare::AtLeast,
                1.0,
                "",
            ),
            HONEST_END,
            EKF_HALF_PERCENT,
        ],
    },
    Case {
        id: "SIL-KIN-2",
        scenario: "rough-kinematics",
        no_slip_comp: false,
        variant: KINEMATIC,
        title:
            "very rough terrain without slip, exact dimensions: flight 3D kinematics against the \
                independent truth kinematics (issue 13)",
        checks: &[
            req(
                "3D kinematics error / distance (not zero)",
                |s| s.error_pct.kin3d,
                Compare::AtLeast,
                1e-6,
                "%",
            ),
            open(
                "3D kinematics error / distance",
                |s| s.error_pct.kin3d,
                Compare::AtMost,
                1.0,
                "%",
            ),
        ],
    },
    Case {
        id: "SIL-KIN-3",
        scenario: "rock-crawl",
        no_slip_comp: false,
        variant: KINEMATIC,
        title: "rock crawl without slip: planar 2D odometry against 3D kinematics (H04 Fig. 17)",
        checks: &[
            KIN2D_H04,
            KIN3D_H04,
        ],
    },
    Case {
        id: "SIL-KIN-4",
        scenario: "undulating",
        no_slip_comp: false,
        variant: KINEMATIC,
        title: "undulating ground without slip: flight 3D kinematics against averaged wheel \
                odometry (V99 sec. 6)",
        checks: &[
            GOAL_REACHED,
            req(
                "3D kinematics distance error (track memory, KIN-13; 1.07 % without)",
                |s| s.distance_error_pct.kin3d,
                Compare::AtMost,
                0.5,
                "%",
            ),
            goal(
                "3D kinematics distance error (V99 estimator: 0.3 %)",
                |s| s.distance_error_pct.kin3d,
                Compare::AtMost,
                0.3,
                "%",
            ),
            goal(
                "averaged wheel odometry distance error (V99: 2 %)",
                |s| Some(s.distance_error_pct.wheel_average),
                Compare::AtLeast,
                0.0,
                "%",
            ),
        ],
    },
    Case {
        id: "SIL-KIN-5",
        scenario: "step-climb",
        no_slip_comp: false,
        variant: BASE,
        title: "right wheels over a vertical step of one wheel radius (issue 13)",
        checks: &[
            req(
                "goal reached",
                |s| flag(s.goal_reached),
                Compare::AtLeast,
                1.0,
                "",
            ),
            goal(
                "3D kinematics error / distance",
                |s| s.error_pct.kin3d,
                Compare::AtMost,
                3.0,
                "%",
            ),
        ],
    },
    Case {
        id: "SIL-KIN-6",
        scenario: "rock-field-crawl",
        no_slip_comp: false,
        variant: KINEMATIC,
        title: "2 m crawl without slip through a staggered field of boulders under both tracks \
                (H04 Fig. 17's terrain: the suspension to its limits over a short traverse)",
        checks: &[
            HONEST_END,
            open("goal reached", |s| flag(s.goal_reached), Compare::AtLeast, 1.0, ""),
            KIN2D_H04,
            KIN3D_H04,
        ],
    },
    Case {
        id: "SIL-SLIP-1",
        scenario: "slope-10-cross",
        no_slip_comp: false,
        variant: LUMPED,
        title: "10 deg sand cross slope with the lumped slip model of before issue 13 \
                (reference: its lateral constant was chosen for H05 Fig. 9's drift)",
        checks: &[
            goal(
                "goal reached",
                |s| flag(s.goal_reached),
                Compare::AtLeast,
                1.0,
                "",
            ),
            goal(
                "cross-track max",
                |s| Some(s.cross_track_m.max),
                Compare::AtMost,
                0.15,
                "m",
            ),
        ],
    },
    Case {
        id: "SIL-LOC-1",
        scenario: "marsyard-25m",
        no_slip_comp: false,
        variant: LOCALIZATION,
        title: "Mars Yard without VO, terrain-map localization against a MARDI map (V99 sec. 5)",
        checks: &[
            GOAL_REACHED,
            EKF_ONE_PERCENT,
            req(
                "localization fixes fused",
                |s| s.localization.as_ref().map(|l| f64::from(l.updates)),
                Compare::AtLeast,
                1.0,
                "",
            ),
            req(
                "fix NEES mean (3 dof; not overconfident: 95 % chi-square)",
                |s| s.localization.as_ref().and_then(|l| l.nees_mean),
                Compare::AtMost,
                7.815,
                "",
            ),
            goal(
                "fused fix position error max",
                |s| s.localization.as_ref().and_then(|l| l.fused_error_max_m),
                Compare::AtMost,
                0.3,
                "m",
            ),
        ],
    },
    Case {
        id: "SIL-LOC-2",
        scenario: "marsyard-25m",
        no_slip_comp: false,
        variant: LOCALIZATION_WRONG_MAP,
        title: "As SIL-LOC-1 with the uplinked map registered 1.5 m off: failed matches are detected, not fused",
        checks: &[
            GOAL_REACHED,
            EKF_ONE_PERCENT,
            req(
                "largest error of a fused fix (none fused: 0)",
                |s| {
                    s.localization
                        .as_ref()
                        .map(|l| l.fused_error_max_m.unwrap_or(0.0))
                },
                Compare::AtMost,
                0.5,
                "m",
            ),
            goal(
                "searches ended without a fix, or fixes refused by the gate",
                |s| {
                    s.localization
                        .as_ref()
                        .map(|l| f64::from(l.failed + l.rejected))
                },
                Compare::AtLeast,
                1.0,
                "",
            ),
        ],
    },
    Case {
        id: "SIL-SEQ-1",
        scenario: "multi-target",
        no_slip_comp: false,
        variant: BASE,
        title: "Three science targets, the first behind an unknown wall: the sequencer reorders (V99 sec. 3, Fig. 3)",
        checks: &[
            req(
                "every target visited within the tolerance (largest truth miss)",
                |s| s.targets.as_ref().map(|_| s.goal_miss_m),
                Compare::AtMost,
                0.3,
                "m",
            ),
            req(
                "targets visited",
                |s| s.targets.as_ref().map(|t| f64::from(t.counters.visited)),
                Compare::AtLeast,
                3.0,
                "",
            ),
            open(
                "replans that changed the order (Fig. 3)",
                |s| s.targets.as_ref().map(|t| f64::from(t.counters.reorders)),
                Compare::AtLeast,
                1.0,
                "",
            ),
            WITHIN_ENERGY_BUDGET,
            NO_COLLISION,
        ],
    },
    Case {
        id: "SIL-SEQ-2",
        scenario: "multi-target",
        no_slip_comp: false,
        variant: ENERGY_SHORT,
        title: "As SIL-SEQ-1 with energy for two targets only, which the a-priori model does not show: the power telemetry drops the least important (V99 sec. 3)",
        checks: &[
            open(
                "least important target (T2) dropped for energy",
                |s| target_is(s, 2, "DroppedEnergy"),
                Compare::AtLeast,
                1.0,
                "",
            ),
            req(
                "most important target (T0) visited",
                |s| target_is(s, 0, "Visited"),
                Compare::AtLeast,
                1.0,
                "",
            ),
            WITHIN_ENERGY_BUDGET,
            req(
                "replans triggered by the energy telemetry",
                |s| s.targets.as_ref().map(|t| f64::from(t.counters.energy_triggers)),
                Compare::AtLeast,
                1.0,
                "",
            ),
            goal(
                "fitted power / truth mean power (drive)",
                |s| s.targets.as_ref().map(|t| t.counters.drive_power_w / s.energy.mean_power_w),
                Compare::AtMost,
                1.05,
                "",
            ),
            NO_COLLISION,
        ],
    },
    Case {
        id: "SIL-SLIP-2",
        scenario: "marsyard-25m",
        no_slip_comp: false,
        variant: LUMPED,
        title: "Mars Yard with the lumped slip model of before issue 13 (reference)",
        checks: &[
            goal(
                "goal reached",
                |s| flag(s.goal_reached),
                Compare::AtLeast,
                1.0,
                "",
            ),
            goal(
                "EKF error / distance",
                |s| s.error_pct.ekf,
                Compare::AtMost,
                1.0,
                "%",
            ),
        ],
    },
    fault_case(
        "SIL-FP-1",
        "fault-camera-blackout-30s",
        "Mars Yard with 30 s of black frames (issue 20)",
    ),
    fault_case(
        "SIL-FP-2",
        "fault-dead-camera",
        "Mars Yard with a dead camera (issue 20)",
    ),
    fault_case(
        "SIL-FP-3",
        "fault-stuck-imu",
        "Mars Yard with the IMU stuck from 60 s (issue 20)",
    ),
    fault_case(
        "SIL-FP-4",
        "fault-imu-bias",
        "Mars Yard with large IMU bias jumps at 60 s (issue 20)",
    ),
    fault_case(
        "SIL-FP-5",
        "fault-slope-20-combined",
        "20 deg sand slope with combined faults (issue 20)",
    ),
    Case {
        id: "SIL-FP-6",
        scenario: "fault-full-slip",
        no_slip_comp: false,
        variant: BASE,
        title: "100 % slip from 10 s: the drive stops within 10 s of the slip limit (issue 20)",
        checks: &[
            HONEST_END,
            NO_FALSE_ARRIVAL,
            req(
                "stopped on the slip limit",
                |s| flag(s.fault_protection.last_response == "SlipLimit"),
                Compare::AtLeast,
                1.0,
                "",
            ),
            req(
                "end of the run (onset 10 s + 10 s + 1 s of run-out)",
                |s| Some(s.sim_time_s),
                Compare::AtMost,
                21.0,
                "s",
            ),
        ],
    },
    Case {
        id: "SIL-FP-7",
        scenario: "fault-motor-stall",
        no_slip_comp: false,
        variant: BASE,
        title: "10 deg slope with wheel 3's motor stalled from 10 s (issue 20)",
        checks: &[
            HONEST_END,
            NO_FALSE_ARRIVAL,
            req(
                "stopped on the stall",
                |s| flag(s.fault_protection.last_response.starts_with("MotorStall")),
                Compare::AtLeast,
                1.0,
                "",
            ),
        ],
    },
    Case {
        id: "SIL-HAZ-1",
        scenario: "rockfield-goal",
        no_slip_comp: false,
        variant: BASE,
        title: "go to a goal 20 m away behind hazard rocks: hazard maps and RoverBug (issue 16, V99 \
                sec. 4)",
        checks: &[
            GOAL_REACHED,
            PLANNER_REACHED,
            NO_COLLISION,
            req(
                "path length / straight line",
                |s| {
                    let p = s.planner.as_ref()?;
                    Some(p.path_length_m / p.straight_line_m.max(1e-9))
                },
                Compare::AtMost,
                1.5,
                "x",
            ),
        ],
    },
    Case {
        id: "SIL-HAZ-2",
        scenario: "cul-de-sac",
        no_slip_comp: false,
        variant: BASE,
        title: "a concave obstacle across the straight line: boundary following takes the rover round \
                it to the goal (issue 16)",
        checks: &[
            GOAL_REACHED,
            PLANNER_REACHED,
            NO_COLLISION,
            req(
                "boundary-following episodes",
                |s| Some(f64::from(s.planner.as_ref()?.boundary_following)),
                Compare::AtLeast,
                1.0,
                "",
            ),
        ],
    },
    Case {
        id: "SIL-HAZ-3",
        scenario: "unreachable",
        no_slip_comp: false,
        variant: BASE,
        title: "goal inside a closed ring of rocks: the rover goes round it, halts and reports the goal \
                unreachable (issue 16)",
        checks: &[
            req(
                "planner status unreachable",
                |s| flag(s.planner.as_ref()?.status == "unreachable"),
                Compare::AtLeast,
                1.0,
                "",
            ),
            req(
                "stopped safe (GoalUnreachable)",
                |s| {
                    flag(
                        s.fault_protection.stopped_safe
                            && s.fault_protection.last_response == "GoalUnreachable",
                    )
                },
                Compare::AtLeast,
                1.0,
                "",
            ),
            open(
                "truth-side collisions",
                |s| Some(f64::from(s.collisions)),
                Compare::AtMost,
                0.0,
                "",
            ),
        ],
    },
];

/// The case with `id` and the slip-compensation setting, if any.
pub fn case(id: &str) -> Option<Case> {
    CASES.iter().copied().find(|c| c.id == id)
}

/// Run `case` with the scenarios in `scenarios_dir`.
pub fn run_case(case: Case, scenarios_dir: &Path) -> anyhow::Result<CaseResult> {
    let mut scenario = Scenario::load(&scenarios_dir.join(format!("{}.toml", case.scenario)))?;
    case.variant.apply(&mut scenario);
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
            no_slip_comp: case.no_slip_comp,
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
    let summary = summarise(&result);
    let checks = case
        .checks
        .iter()
        .map(|c| {
            let value = (c.value)(&summary);
            let pass = value.is_some_and(|v| match c.compare {
                Compare::AtMost => v <= c.threshold,
                Compare::AtLeast => v >= c.threshold,
            });
            CheckResult {
                check: *c,
                value,
                pass,
            }
        })
        .collect();
    Ok(CaseResult {
        case,
        summary,
        checks,
    })
}

/// Why the open requirements fail (the page is generated, so the explanation lives here).
const OPEN_NOTES: &str = "
## Open requirements and why

Since issue 13 the simulator's truth motion is its own rough-terrain kinematics (rim contact
with contact angles, rolling solve of body twist and suspension rates from all six wheels,
holonomic placement; `docs/simulator.md`), no longer the flight kinematics' planar fit. The
flight software was checked against itself before; these requirements failed and are kept in
the table as `requirement (open)` (they do not fail the tests) until the flight software meets
them on every seed:

- **SIL-KIN-1, SIL-KIN-2** (3D kinematics at most 3 % with slip, 1 % without slip and with exact
  dimensions on `rough-kinematics`): met on the SIL seed since the flight inverse kinematics
  drives the wheels at rates the terrain admits (rough-terrain IK on the estimated contact
  angles, Tarokh & McDermott 2005; `docs/kinematics.md`): 5.3 -> 2.9 % and 2.0 -> 0.93 %. The
  cause of the failure was the flat-ground IK: six wheels driven at rates computed for flat
  ground fight each other on 0.35 m bumps and the truth's Coulomb contacts let them scrub, which
  an odometry that assumes rolling cannot see. Kept `open`: on seeds 2 and 3 KIN-2 measured 1.16
  and 1.29 % and KIN-1 3.6 % on seed 3 (helper runs before the deadband, `docs/kinematics.md`).
  Since the track memory of the 3D dead reckoning (the body's heave from the ground its front
  wheels already rolled over, `docs/kinematics.md`) KIN-1 fails on the SIL seed too: 3.08 ->
  3.41 %. The slip makes the rim travel longer than the motion, and the dead reckoning's short
  horizontal (its step tilted with the body's pitch) had hidden part of it; kinematics cannot
  see slip. KIN-2 (no slip) went 0.80 -> 0.71 %. Since the dead reckoning's own wheel-radius
  scale, learnt from VO over capture intervals the slip gate accepted throughout (KIN-14,
  `docs/kinematics.md`), KIN-1 is met on seeds 1-3 and is a requirement again: 3.41 / 1.00 /
  4.18 % -> 1.27 / 1.01 / 2.14 % (the per-seed wheel radii and dimension errors, not the slip,
  were most of it: the truth's mean slip on this run is 1.2 %). Without VO the scale stays 1.
- **SIL-KIN-4** (`undulating`, V99's 0.3 % for the kinematic estimator): met on seeds 1-3 with
  the track memory (distance error -1.07 / -1.04 / -1.05 % -> +0.24 / +0.27 / +0.24 %); the
  zero-mean contact angles had missed the body's heave over the ridges. The rough-terrain IK
  still gets the zero-mean angles (it drives `undulating` less well than eq. 16-25 did).
- **SIL-KIN-3** (`rock-crawl`, H04 Fig. 17): the 3D kinematics meets its 3 %; planar 2D odometry
  is about 9 % off (15 % before the rough-terrain IK drove the wheels at rates the bumps admit),
  not the 30 % H04 saw over its extreme kinematic simulation. H04's Fig. 17 covers a short
  traverse (about 0.15 m of x travel, as printed); at that scale the same run shows the effect
  (`tools/x_window_error.py`, seed 1, the worst window picked after the fact, not a criterion;
  re-run in session 21): over 0.15 m of x travel from x = 1.35 m (the right wheels on the
  0.15 m rock) the 2D x distance is 43.7 % long and the 3D 3.9 %, over 0.3 m 29.5 % and 2.9 %,
  over 1 m 10.8 % and 1.8 %; over the whole 6 m the 2D x distance is 3.6 % long (its 9.6 %
  position error is mostly heading). A denser field
  (a rock under each track every 0.3 m, 0.05-0.15 m high, over 3 m) was tried: the truth's
  placement stopped converging on it (now caught: an implausible quasi-static twist falls back to
  the kinematic solve, World::force_fallbacks), the rover scrubbed about 30 % of its rim
  travel, VO delivered 11 poses in 39 s and fault protection stopped it `PositionUncertain`. It
  is not the SIL scenario until the flight software handles it.
- **SIL-GNC-2** (`slope-10-cross` without slip compensation drifts at least 0.5 m downhill, H05
  Fig. 9): the requirement encoded H05's measured drift. With the rigid-wheel terramechanics
  (Ishigami et al.'s sand) the uncompensated rover drifts 0.32 m: the published soil gives a
  smaller crab than H05's Johnson Valley sand. The check shows that slip compensation matters;
  the simulator is not tuned to reproduce the figure.
- **SIL-NAV-2** (`dunes-long`: goal reached): with the rigid-wheel sand the slip over a 0.5 m
  window exceeds the mission's limit (0.7) on the steepest flanks (up to 21 deg) and fault
  protection stops the rover (`SlipLimit`), as it should; the estimate stays within its 0.5 %
  goal and the end is honest (checked).
- **SIL-SEQ-1** (the reorder of V99 Fig. 3) **and SIL-SEQ-2** (the least important target, T2,
  dropped for energy), **SIL-HAZ-3** (no truth-side collision): open since issue 18 (session
  12). They depend on which way RoverBug goes round an obstacle it learns on the way, and that
  choice changes with the timing of the hazard maps and with rounding-level changes of the
  estimate. With issue 18's third pass (the ZUPT in its own phase, RG2B) seed 1 goes round the
  wall's east end: SEQ-1 reorders to T1, T2, T0 and visits all three; SEQ-2 first lost T0 there
  (after T1 the calibrated detour factor of 2.19 priced it out, and T2 was visited instead), which
  the sequencer's priority margin now prevents (`docs/sequencer.md`): T2 is dropped for energy,
  T0 and T1 visited. Seeds 2 and 3 go round the west end to T0 first: SEQ-1 visits all three
  without a reorder (none needed), SEQ-2 visits T0 and drops T1 and T2 with about 26 kJ of the
  54 kJ left; `unreachable` (HAZ-3) has no contact on seeds 1 and 2 and ends `blocked` with 2
  contacts on seed 3, as before. The gaze turn's swept corners near the ring
  (`docs/hazard-navigation.md`) and the planner's choice of wall end are the flight software to
  fix; these stay `open` until they hold on every seed. Session 17: the inverse compositional
  tracking (`docs/vo.md`) moved seed 1's path by millimetres; SEQ-2 then rode the wall's east
  face 0.804 m from its outline, where a gaze turn needs 0.805 m, and the refused gazes (no
  motion) reached the planner's gaze limit: T0 and then T1 dropped `Blocked(GazeLimit)`, T0's
  requirement failed. The room move before a gaze (a short forward drive inside the mapped
  wedge, `docs/hazard-navigation.md`) fixed it: T0 visited, T1 and T2 dropped for energy.
  `unreachable` (HAZ-3) touches a rock twice on seed 1 since the tracking change (at (11.73,
  1.0) m, t = 178 and 189 s; the room move changes nothing there): not investigated yet.
- **SIL-NAV-2**'s EKF goal on `dunes-long` flips with rounding-level changes: seed 1 gave 0.33 %
  with the expanded Joseph update and 20 % (24 VO failures) with the Cholesky downdate of issue
  18, but on seeds 2 and 3 both forms give the same (6.6 / 6.3 % and 10.0 / 11.3 %) and the code
  of issue 17 gives 6.5 % and 21.5 % (55 VO failures) there: the slip on the steep dune flanks
  breaks VO tracking on some runs whatever the update form.
- **Session 19: the background quantum went from 100 to 60 cost units per minor frame**: the
  rover CPU's largest minor frame with its background slice took 133 % of the 5 ms period at
  CPI 2.0, now 80 % (`docs/timing.md`); a VO update with the rectification of its pair (about
  14,000 cost units on the timing tape) now takes about 1.1 s of slices instead of about
  0.7 s. All cases re-run: no check changed its
  verdict except SIL-NAV-2's EKF goal (18.7 -> 0.27 %, which flips with small changes, above).
  The figures moved both ways within their seed scatter (EKF error, seeds 1 / 2 / 3, 100 -> 60
  units): marsyard-25m 0.26 / 0.44 / 0.16 -> 0.41 / 0.39 / 0.34 %, slope-10-cross 0.55 / 1.15 /
  0.43 -> 0.57 / 1.11 / 0.41 %, rough-kinematics 0.33 / 1.00 / 0.09 -> 0.32 / 1.02 / 0.06 %,
  slope-10-faults 0.88 / 1.02 / 0.24 -> 0.67 / 1.24 / 1.85 % (GNC-4 runs seed 3). At 60 units
  `rockfield-goal` (SIL-HAZ-1) first failed: the planner handed guidance a 6.7 cm
  boundary-following path ending 5 cm away, inside guidance's stopping tolerance, and the rover
  held and mapped on one spot until fault protection stopped it (`SlipLimit` at 3.5 m of 20 m).
  Fixed in the flight software (every cut path driven ends at least `min_reach`, 0.1 m, away,
  `docs/planning.md` step 10), not by keeping the larger quantum: HAZ-1 then reached its goal
  (path 1.056 x the straight line).
- **Session 20: the rough-terrain inverse kinematics drives on contact angles estimated over
  10 mm windows of travel** (`docs/kinematics.md`, the windowed angles for the inverse
  kinematics, KIN-15): 2.4-4.8 deg rms against the truth's contacts instead of 5.8-8.9 deg per
  joint step (seed 1, no slip). All cases re-run: no requirement changed its verdict. KIN-1
  1.29 -> 1.14 % (its 2D/3D goal 7.2 -> 8.3 x), KIN-2 0.630 -> 0.632 %, KIN-3 2D 9.33 -> 9.55 %
  and 3D 0.68 -> 0.67 %, KIN-4 0.035 -> 0.022 %, KIN-5 3.80 -> 3.81 %, HAZ-3 contacts 1 -> 0.
  Two flips of the kind described above: SIL-SEQ-1 made no reorder this time (all three targets
  visited; open), and SIL-LOC-2's goal (a search that ends without a fix, or a fix the gate
  refuses) is 0 instead of 1: the localization started no search on the shifted map (26 map
  checks found too few of its rocks inside the search window, `TooFewPoints`, against 24 and
  one search before); nothing was fused either way. A variant that linearised each window at
  its last step's configuration (0.8 KB less stack) ended SIL-HAZ-3 `Blocked(GazeLimit)`
  instead of `Unreachable`: the gaze-limit weakness of `docs/hazard-navigation.md` (a gaze
  given up next to the ring still counts towards the limit), still open.
- **SIL-KIN-6** (`rock-field-crawl`, session 20): the terrain H04 describes for Fig. 17 (a
  boulder 0.075-0.15 m high under each track every 0.3-0.4 m, staggered, over 2 m; written once,
  not tuned). Session 20: fault protection stopped the rover (`PositionUncertain`) after 1.1 m,
  planar 2D odometry 13.8 % off and 3D kinematics 5.6 %. The stop came from a series of IMU
  shocks (the truth's wedged rover slid 7 cm sideways within 25 ms, a known limitation of the
  quasi-static truth, `docs/simulator.md`) that left the filter's velocity more than 1 m/s off
  while a slip hold kept the wheels from correcting it. Since FP-9 (session 21,
  `docs/fault-protection.md`) the rover crosses the field: goal reached (miss 0.28 m against
  0.3 m), 3D kinematics 1.43 % (its 3 % met), planar 2D 10.2 % (H04's 30 % still open), the
  truth scrubbing 17.9 % of the wheels' ground travel. The EKF ends 12 % off: the teleports
  are seen by neither the wheels nor the clipped IMU, and VO failed twice after the first
  (`TooFewTracked`, while the filter's prior was 0.28 m off: about 70 px at 1.5 m, beyond
  the flight tracker's 8 px search around the prior). With the truth's own contact
  angles fed to the inverse kinematics (a diagnostic, not in the code) the scrub was 35-42 %:
  it is not the angle estimate; the truth's contacts on the caps or what the inverse
  kinematics leaves out remain to be separated.
- SIL-SLIP-1/2 are references: the lumped slip model of before issue 13 (its lateral constant
  chosen to reproduce H05's drift) on the two cases that the per-wheel rigid-wheel
  terramechanics, now the default (`docs/terramechanics.md`), runs in SIL-GNC-1 and SIL-NAV-1.
";

/// The results as a Markdown page.
pub fn markdown(results: &[CaseResult]) -> String {
    let mut s = String::new();
    s += "# SIL results\n\n";
    s += "Generated by `cargo run --release -p sim-host -- sil` (do not edit by hand). Each case is a\n";
    s += "closed-loop run of the flight software on the simulator with rendered stereo images; the\n";
    s += "thresholds live in `sim-host/src/sil.rs` and the same cases run as tests in\n";
    s += "`tests/tests/sil_scenarios.rs`. Requirement checks fail the tests; goals are reported.\n";
    s += "Errors are horizontal position errors at the end of the run divided by the distance driven.\n\n";
    s += "| id | scenario | check | kind | threshold | measured | result |\n";
    s += "|---|---|---|---|---|---|---|\n";
    for r in results {
        let mut notes = r.case.variant.label();
        if r.case.no_slip_comp {
            notes = if notes.is_empty() {
                "no slip comp".to_string()
            } else {
                format!("no slip comp, {notes}")
            };
        }
        let scenario = if notes.is_empty() {
            r.case.scenario.to_string()
        } else {
            format!("{} ({notes})", r.case.scenario)
        };
        for c in &r.checks {
            let op = match c.check.compare {
                Compare::AtMost => "<=",
                Compare::AtLeast => ">=",
            };
            let value = c
                .value
                .map_or("-".to_string(), |v| format!("{v:.3} {}", c.check.unit));
            s += &format!(
                "| {} | {} | {} | {} | {op} {} {} | {} | {} |\n",
                r.case.id,
                scenario,
                c.check.what,
                if c.check.required {
                    "requirement"
                } else if c.check.open {
                    "requirement (open)"
                } else {
                    "goal"
                },
                c.check.threshold,
                c.check.unit,
                value.trim(),
                if c.pass { "pass" } else { "FAIL" }
            );
        }
    }
    s += OPEN_NOTES;
    s += "\n## Runs\n\n";
    s += "Distance errors (V99 sec. 6): path length of the estimate against the true horizontal path\n";
    s += "length; `wheel avg` is averaged wheel odometry with the true pitch (simulator-side baseline).\n";
    s += "`scrub` is the truth's sliding of the wheels' contacts along their rolling tangents against the\n";
    s += "ground speed each wheel drives, % of that ground travel, absolute / net (`truth_scrub_pct`,\n";
    s += "`truth_scrub_net_pct`): wheel rates that do not fit the terrain; no odometry sees it.\n";
    let fallbacks: u64 = results
        .iter()
        .map(|r| r.summary.truth_force_fallbacks)
        .sum();
    s += &format!(
        "Truth steps that fell back from the quasi-static force model to the kinematic solve, over \
         all runs: {fallbacks} (`truth_force_fallbacks` in `summary.json`).\n\n"
    );
    s += "| id | distance m | sim time s | EKF % | VO % | kin3d % | kin2d % | kin3d dist % | wheel avg dist % | scrub % | gate rejects | VO updates/failures | cross-track rms/max m | goal miss m |\n";
    s += "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.2}"));
    for r in results {
        let m = &r.summary;
        s += &format!(
            "| {} | {:.2} | {:.1} | {} | {} | {} | {} | {} | {:.2} | {:.1}/{:+.1} | {} | {}/{} | {:.3}/{:.3} | {:.3} |\n",
            r.case.id,
            m.distance_m,
            m.sim_time_s,
            f(m.error_pct.ekf),
            f(m.error_pct.vo),
            f(m.error_pct.kin3d),
            f(m.error_pct.kin2d),
            f(m.distance_error_pct.kin3d),
            m.distance_error_pct.wheel_average,
            m.truth_scrub_pct,
            m.truth_scrub_net_pct,
            m.slip
                .gate_reject_fraction
                .map_or("-".to_string(), |x| format!("{:.0} %", 100.0 * x)),
            m.vo.updates.unwrap_or(0),
            m.vo.failures.unwrap_or(0),
            m.cross_track_m.rms,
            m.cross_track_m.max,
            m.goal_miss_m
        );
    }
    s
}

/// `sim-host sil [OPTIONS]`.
#[derive(Debug, Clone, clap::Args)]
pub struct SilArgs {
    /// Results page to write.
    #[arg(long, default_value = "docs/sil-results.md")]
    pub out: PathBuf,
    /// Directory of the scenario files.
    #[arg(long, default_value = "scenarios")]
    pub scenarios: PathBuf,
    /// Also write each case's `summary.json` into this directory, as `<case id>.json`.
    #[arg(long)]
    pub summaries: Option<PathBuf>,
}

/// Run `sim-host sil`: every case in parallel, the results page (written and printed), and
/// the summaries; fails when a requirement fails.
pub fn main(args: SilArgs) -> anyhow::Result<()> {
    use rayon::prelude::*;
    println!(
        "sim-host sil: {} cases with rendered stereo, in parallel",
        CASES.len()
    );
    let results: Vec<_> = CASES
        .par_iter()
        .map(|c| run_case(*c, &args.scenarios))
        .collect::<anyhow::Result<_>>()?;
    if let Some(dir) = &args.summaries {
        std::fs::create_dir_all(dir)?;
        for r in &results {
            let json = serde_json::to_string_pretty(&r.summary)?;
            std::fs::write(dir.join(format!("{}.json", r.case.id)), json + "\n")?;
        }
    }
    let page = markdown(&results);
    std::fs::write(&args.out, &page)?;
    print!("{page}");
    println!("written to {}", args.out.display());
    if results.iter().all(|r| r.passed()) {
        Ok(())
    } else {
        anyhow::bail!("a SIL requirement failed")
    }
}
