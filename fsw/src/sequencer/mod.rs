//! On-board sequencing of the day's science targets with iterative repair (V99 sec. 3, after
//! CASPER: S. Chien et al., "Using iterative repair to improve the responsiveness of planning
//! and scheduling", AIPS 2000; iterative repair after M. Zweben et al., "Scheduling and
//! rescheduling with iterative repair", 1994).
//!
//! The plan is an order of the pending targets, each a goto (travel at the rover's speed over
//! the straight-line distance times a detour factor, plus, for the leg from the rover's
//! position, any penalty learnt from the path planner) followed by a dwell (science) inside the target's time window. Its timeline has
//! three kinds of constraint (V99 sec. 3: temporal, resource, state):
//! - **time windows**: each dwell starts inside its target's window (the rover waits, idling, for
//!   a window that has not opened);
//! - **energy**: the energy of travel, waiting and dwells stays within the energy available;
//! - **horizon**: the last dwell ends before the end of the plan (the end of the sol's drive).
//!
//! [`Sequencer::replan`] builds the plan from the rover's situation (time, position, energy):
//! targets are inserted in priority order at the position that adds the least time while every
//! constraint holds (cheapest insertion, the travelling-salesman heuristic V99 names); a target
//! that fits nowhere is a conflict, resolved by dropping it (the lowest priorities are inserted
//! last, so they are the ones dropped); then or-opt moves (one target moved elsewhere) shorten
//! the plan while it stays feasible; a last pass re-inserts any dropped target that now fits.
//! Every loop is bounded by [`MAX_TARGETS`]; there is no recursion and no allocation.
//!
//! Replanning triggers (V99 sec. 3: "position estimate uncertainty ... too large", "used more
//! battery power than expected", an unexpected obstacle): the caller replans when the rover
//! arrives, when the energy or time left departs from the timeline, or when the path planner
//! reports a leg longer than estimated ([`Sequencer::set_leg_penalty`]); and
//! [`Sequencer::request_localization`] puts a localization activity (its time and energy) at
//! the head of the plan, dropping targets if it no longer fits.
//!
//! Frames and units: positions in the world frame `W` (x north, y east), m; times s (mission
//! time); energies J; powers W.

mod replan;
#[cfg(test)]
mod tests;

use heapless::Vec;

/// Largest number of targets of a plan.
pub const MAX_TARGETS: usize = 8;

/// A science target (V99 sec. 3: a goal with a priority and a temporal constraint).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Position in `W` (x north, y east), m.
    pub position_m: [f64; 2],
    /// Priority: higher is more important (dropped last).
    pub priority: u8,
    /// The dwell may start from this time, s.
    pub window_open_s: f64,
    /// The dwell must start by this time, s.
    pub window_close_s: f64,
    /// Duration of the science at the target, s.
    pub dwell_s: f64,
    /// Energy of the science instruments during the dwell (above the idle power), J.
    pub dwell_energy_j: f64,
}

/// The rover's resource model (the simulator's energy model is its own, `sim-host`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResourceModel {
    /// Planned driving speed, m/s (including the stops of the drive).
    pub speed_m_s: f64,
    /// Power while driving, W.
    pub drive_power_w: f64,
    /// Power while standing (avionics, heaters), W.
    pub idle_power_w: f64,
    /// Travel length over the straight-line distance (obstacle detours, path following).
    pub detour_factor: f64,
    /// Duration of one localization (a turn-in-place panorama and the match), s.
    pub localization_s: f64,
    /// Energy of one localization above the idle power, J.
    pub localization_energy_j: f64,
    /// Margin (fraction) on the time and energy spent up to the end of a target's dwell when a
    /// lower-priority target comes before it in the plan: such an order must still fit with
    /// them multiplied by `1 + priority_margin`, so that a model error on the way (a detour
    /// longer than planned, a slower drive) costs the less important target, not the more
    /// important one. Orders by priority need no margin.
    pub priority_margin: f64,
}

impl ResourceModel {
    /// A Rocky 8 class rover: 0.1 m/s with its stops counted as 0.075 m/s, 60 W driving (six
    /// wheel motors and avionics), 25 W standing, detour factor 1.2, a 90 s localization
    /// drawing 1.8 kJ above idle (eight hazcam captures and the turns between them). Figures of
    /// the class, not of a measured vehicle. Priority margin 0.5: the travel of a leg is its
    /// straight line times the detour factor, and the detour factors measured on the SIL's
    /// legs reach 1.8 times the planned 1.2 (2.19 on `multi-target` after the wall).
    pub fn rocky8() -> Self {
        Self {
            speed_m_s: 0.075,
            drive_power_w: 60.0,
            idle_power_w: 25.0,
            detour_factor: 1.2,
            localization_s: 90.0,
            localization_energy_j: 1800.0,
            priority_margin: 0.5,
        }
    }

    fn is_valid(&self) -> bool {
        let pos = [self.speed_m_s, self.detour_factor];
        let nonneg = [
            self.drive_power_w,
            self.idle_power_w,
            self.localization_s,
            self.localization_energy_j,
            self.priority_margin,
        ];
        pos.iter().all(|v| v.is_finite() && *v > 0.0)
            && nonneg.iter().all(|v| v.is_finite() && *v >= 0.0)
            && self.detour_factor >= 1.0
    }
}

/// The rover's situation when it replans.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Situation {
    /// Mission time, s.
    pub now_s: f64,
    /// Position in `W`, m.
    pub position_m: [f64; 2],
    /// Energy left for the plan, J.
    pub energy_available_j: f64,
    /// The plan must end by this time, s.
    pub end_s: f64,
}

/// Why a target left the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DropReason {
    /// Its window cannot be met (or has closed).
    Window,
    /// Not enough energy with the higher-priority targets kept.
    Energy,
    /// It does not fit before the end of the plan.
    Horizon,
    /// The path planner found no way to it ([`Sequencer::unreachable`]); never reconsidered.
    Unreachable,
}

/// State of a target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TargetStatus {
    /// In the plan, or waiting for a replan to place it.
    Pending,
    /// Reached and its dwell done ([`Sequencer::visited`]).
    Visited,
    /// Not in the plan: the last replan found no place for it.
    Dropped(DropReason),
}

/// A constraint the timeline breaks (the conflict classes of iterative repair).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Conflict {
    /// A dwell would start after its window closes.
    Window,
    /// The energy of the plan exceeds the energy available.
    Energy,
    /// The plan ends after the end of the plan.
    Horizon,
}

impl From<Conflict> for DropReason {
    fn from(c: Conflict) -> Self {
        match c {
            Conflict::Window => DropReason::Window,
            Conflict::Energy => DropReason::Energy,
            Conflict::Horizon => DropReason::Horizon,
        }
    }
}

/// Errors of the sequencer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SequencerError {
    /// More than [`MAX_TARGETS`] targets.
    TooManyTargets,
    /// A non-finite or out-of-range target, model, situation or penalty.
    InvalidInput,
    /// A target index out of range.
    NoSuchTarget,
}

/// One entry of the planned timeline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slot {
    /// Target index.
    pub target: u8,
    /// Arrival time, s.
    pub arrive_s: f64,
    /// Dwell start (after any wait for the window), s.
    pub start_s: f64,
    /// Dwell end, s.
    pub end_s: f64,
    /// Energy used from the replan up to the dwell's end, J.
    pub energy_j: f64,
}

/// Counters of the sequencer (telemetry).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SequencerCounters {
    /// Replans.
    pub replans: u32,
    /// Targets dropped by replans (a target dropped twice counts twice).
    pub drops: u32,
    /// Replans whose order of the kept targets differs from the previous plan's.
    pub reorders: u32,
    /// Localizations inserted at the head of the plan.
    pub localizations: u32,
}

/// The sequencer: targets, their status, the current plan and its timeline.
#[derive(Debug, Clone)]
pub struct Sequencer {
    targets: Vec<Target, MAX_TARGETS>,
    status: [TargetStatus; MAX_TARGETS],
    /// Extra travel length of the leg from the rover's position into each target, m (the path
    /// planner's report of an obstacle on the way).
    penalty_m: [f64; MAX_TARGETS],
    model: ResourceModel,
    plan: Vec<u8, MAX_TARGETS>,
    timeline: Vec<Slot, MAX_TARGETS>,
    localize_first: bool,
    counters: SequencerCounters,
}

impl Sequencer {
    /// A sequencer of `targets` (at most [`MAX_TARGETS`], each with a finite position, a window
    /// `open <= close`, non-negative dwell and energy) under `model`. No plan until
    /// [`Self::replan`].
    pub fn new(targets: &[Target], model: ResourceModel) -> Result<Self, SequencerError> {
        if targets.len() > MAX_TARGETS {
            return Err(SequencerError::TooManyTargets);
        }
        if !model.is_valid() || !targets.iter().all(target_is_valid) {
            return Err(SequencerError::InvalidInput);
        }
        let mut list = Vec::new();
        for t in targets {
            list.push(*t).map_err(|_| SequencerError::TooManyTargets)?;
        }
        Ok(Self {
            targets: list,
            status: [TargetStatus::Pending; MAX_TARGETS],
            penalty_m: [0.0; MAX_TARGETS],
            model,
            plan: Vec::new(),
            timeline: Vec::new(),
            localize_first: false,
            counters: SequencerCounters::default(),
        })
    }

    /// The targets.
    pub fn targets(&self) -> &[Target] {
        &self.targets
    }

    /// Status of target `i` (`None` out of range).
    pub fn status(&self, i: usize) -> Option<TargetStatus> {
        if i < self.targets.len() {
            self.status.get(i).copied()
        } else {
            None
        }
    }

    /// The planned order of target indices.
    pub fn plan(&self) -> &[u8] {
        &self.plan
    }

    /// The timeline of the plan from the last replan.
    pub fn timeline(&self) -> &[Slot] {
        &self.timeline
    }

    /// Counters.
    pub fn counters(&self) -> SequencerCounters {
        self.counters
    }

    /// The next goal: the first planned target and its position (`W`, m); `None` when the plan
    /// is empty.
    pub fn next_goal(&self) -> Option<(usize, [f64; 2])> {
        let i = usize::from(*self.plan.first()?);
        Some((i, self.targets.get(i)?.position_m))
    }

    /// True when a localization is at the head of the plan ([`Self::request_localization`]).
    pub fn localization_due(&self) -> bool {
        self.localize_first
    }

    /// The resource model the plan is timed with.
    pub fn model(&self) -> ResourceModel {
        self.model
    }

    /// Replace the resource model (the caller's calibration of the powers from the energy
    /// telemetry); replan afterwards. Errors: a model [`Self::new`] would refuse.
    pub fn set_model(&mut self, model: ResourceModel) -> Result<(), SequencerError> {
        if !model.is_valid() {
            return Err(SequencerError::InvalidInput);
        }
        self.model = model;
        Ok(())
    }

    /// Extra length of the leg into target `i` ([`Self::set_leg_penalty`]), m; 0 out of range.
    pub fn leg_penalty(&self, i: usize) -> f64 {
        self.penalty_m.get(i).copied().unwrap_or(0.0)
    }

    /// The path planner found no way to target `i` (RoverBug's unreachable verdict, V99
    /// sec. 4): it leaves the plan as [`DropReason::Unreachable`] and later replans do not
    /// reconsider it.
    pub fn unreachable(&mut self, i: usize) -> Result<(), SequencerError> {
        if i >= self.targets.len() {
            return Err(SequencerError::NoSuchTarget);
        }
        if let Some(s) = self.status.get_mut(i) {
            *s = TargetStatus::Dropped(DropReason::Unreachable);
        }
        self.counters.drops = self.counters.drops.saturating_add(1);
        self.plan.retain(|&k| usize::from(k) != i);
        Ok(())
    }

    /// Duration (s, from `situation.now_s` to the end of the last dwell) of the current plan,
    /// or its first conflict.
    pub fn duration(&self, situation: &Situation) -> Result<f64, Conflict> {
        self.evaluate(situation, &self.plan, None, false)
    }

    /// Record the localization at the head of the plan as done.
    pub fn localized(&mut self) {
        self.localize_first = false;
    }

    /// Target `i` reached and its science done: it leaves the plan.
    pub fn visited(&mut self, i: usize) -> Result<(), SequencerError> {
        if i >= self.targets.len() {
            return Err(SequencerError::NoSuchTarget);
        }
        if let Some(s) = self.status.get_mut(i) {
            *s = TargetStatus::Visited;
        }
        self.plan.retain(|&k| usize::from(k) != i);
        Ok(())
    }

    /// The path planner found the way from the rover's position into target `i` longer than
    /// the straight line allows (an unexpected obstacle, V99 Fig. 3): `extra_m` (m, finite and
    /// not negative) is added to the leg into `i` when it is the plan's first (from the situation's
    /// position; the planner knows nothing of the ways from the other targets) until the next
    /// call or [`Self::clear_leg_penalties`]. Replan afterwards.
    pub fn set_leg_penalty(&mut self, i: usize, extra_m: f64) -> Result<(), SequencerError> {
        if !(extra_m.is_finite() && extra_m >= 0.0) {
            return Err(SequencerError::InvalidInput);
        }
        match self.penalty_m.get_mut(i) {
            Some(p) if i < self.targets.len() => {
                *p = extra_m;
                Ok(())
            }
            _ => Err(SequencerError::NoSuchTarget),
        }
    }

    /// Forget every leg penalty (the rover has moved on: a visit, another goal).
    pub fn clear_leg_penalties(&mut self) {
        self.penalty_m = [0.0; MAX_TARGETS];
    }

    /// Put a localization (the model's time and energy) at the head of the plan (V99 sec. 3:
    /// the position uncertainty grew too large). Replan afterwards: targets that no longer fit
    /// are dropped by priority.
    pub fn request_localization(&mut self) {
        if !self.localize_first {
            self.counters.localizations = self.counters.localizations.saturating_add(1);
        }
        self.localize_first = true;
    }

    /// Travel time (s) and energy (J) of the leg from `from` (`W`, m) into target `to`; with
    /// `first` (the leg from the rover's position) its penalty is added.
    fn leg(&self, from: [f64; 2], to: usize, first: bool) -> (f64, f64) {
        let Some(t) = self.targets.get(to) else {
            return (f64::INFINITY, f64::INFINITY);
        };
        let (dx, dy) = (t.position_m[0] - from[0], t.position_m[1] - from[1]);
        let penalty = if first {
            self.penalty_m.get(to).copied().unwrap_or(0.0)
        } else {
            0.0
        };
        let length = crate::linalg::sqrt(dx * dx + dy * dy) * self.model.detour_factor + penalty;
        let time = length / self.model.speed_m_s;
        (time, time * self.model.drive_power_w)
    }

    /// The timeline of `order` from `situation`, or the first conflict; with `protect`, a
    /// target that a less important one precedes must fit with the priority margin
    /// ([`ResourceModel::priority_margin`]), except target `exempt`.
    fn evaluate(
        &self,
        situation: &Situation,
        order: &[u8],
        out: Option<&mut Vec<Slot, MAX_TARGETS>>,
        protect: bool,
    ) -> Result<f64, Conflict> {
        self.evaluate_except(situation, order, out, protect, None)
    }

    /// [`Self::evaluate`] with target `exempt` (if any) not held to the priority margin.
    fn evaluate_except(
        &self,
        situation: &Situation,
        order: &[u8],
        out: Option<&mut Vec<Slot, MAX_TARGETS>>,
        protect: bool,
        exempt: Option<u8>,
    ) -> Result<f64, Conflict> {
        let m = &self.model;
        let (mut t, mut e) = (situation.now_s, 0.0);
        if self.localize_first {
            t += m.localization_s;
            e += m.localization_s * m.idle_power_w + m.localization_energy_j;
            // The localization is not dropped: when it does not fit, no plan does.
            if t > situation.end_s {
                return Err(Conflict::Horizon);
            }
            if e > situation.energy_available_j {
                return Err(Conflict::Energy);
            }
        }
        let mut pos = situation.position_m;
        let mut slots: Vec<Slot, MAX_TARGETS> = Vec::new();
        // Lowest priority planned so far.
        let mut lowest_before = u8::MAX;
        let margin = 1.0 + m.priority_margin;
        for (n, &k) in order.iter().enumerate() {
            let i = usize::from(k);
            let Some(target) = self.targets.get(i) else {
                return Err(Conflict::Horizon);
            };
            let (dt, de) = self.leg(pos, i, n == 0);
            t += dt;
            e += de;
            let arrive = t;
            if t < target.window_open_s {
                e += (target.window_open_s - t) * m.idle_power_w;
                t = target.window_open_s;
            }
            if t > target.window_close_s {
                return Err(Conflict::Window);
            }
            let start = t;
            t += target.dwell_s;
            e += target.dwell_s * m.idle_power_w + target.dwell_energy_j;
            if t > situation.end_s {
                return Err(Conflict::Horizon);
            }
            if e > situation.energy_available_j {
                return Err(Conflict::Energy);
            }
            // A less important target comes first: this one must fit with the margin.
            if protect && target.priority > lowest_before && exempt != Some(k) {
                if situation.now_s + (t - situation.now_s) * margin > situation.end_s {
                    return Err(Conflict::Horizon);
                }
                if e * margin > situation.energy_available_j {
                    return Err(Conflict::Energy);
                }
            }
            lowest_before = lowest_before.min(target.priority);
            let _ = slots.push(Slot {
                target: k,
                arrive_s: arrive,
                start_s: start,
                end_s: t,
                energy_j: e,
            });
            pos = target.position_m;
        }
        if let Some(o) = out {
            *o = slots;
        }
        Ok(t - situation.now_s)
    }

    /// Check the current plan against `situation` (every constraint of the module doc); the
    /// first conflict otherwise. A requested localization that does not fit by itself is a
    /// conflict no drop repairs: the plan is then empty and this reports it.
    pub fn check(&self, situation: &Situation) -> Result<(), Conflict> {
        self.evaluate(situation, &self.plan, None, false)
            .map(|_| ())
    }

    /// Cheapest feasible insertion of target `i` into `order`: the new order and its
    /// duration, or the conflict of the best infeasible position. Every other target must keep
    /// the priority margin; `i` itself is held to it too when a position allows, and otherwise
    /// (unless `protected_only`) may take a position without it: the only way to an important
    /// target may lead past a less important one, and that is the important target's own risk.
    fn insert(
        &self,
        situation: &Situation,
        order: &[u8],
        i: u8,
        protected_only: bool,
    ) -> Result<(Vec<u8, MAX_TARGETS>, f64), Conflict> {
        let first = self.insert_tier(situation, order, i, None);
        if first.is_ok() || protected_only {
            return first;
        }
        self.insert_tier(situation, order, i, Some(i))
    }

    /// [`Self::insert`] with the priority margin on for every target but `exempt`.
    fn insert_tier(
        &self,
        situation: &Situation,
        order: &[u8],
        i: u8,
        exempt: Option<u8>,
    ) -> Result<(Vec<u8, MAX_TARGETS>, f64), Conflict> {
        let mut best: Option<(Vec<u8, MAX_TARGETS>, f64)> = None;
        let mut conflict = Conflict::Window;
        for at in 0..=order.len() {
            let mut candidate: Vec<u8, MAX_TARGETS> = Vec::new();
            for (k, &o) in order.iter().enumerate() {
                if k == at {
                    let _ = candidate.push(i);
                }
                let _ = candidate.push(o);
            }
            if at == order.len() {
                let _ = candidate.push(i);
            }
            if candidate.len() != order.len() + 1 {
                continue;
            }
            match self.evaluate_except(situation, &candidate, None, true, exempt) {
                Ok(d) if best.as_ref().is_none_or(|(_, b)| d < *b) => best = Some((candidate, d)),
                Ok(_) => {}
                Err(c) => conflict = worst(conflict, c),
            }
        }
        best.ok_or(conflict)
    }
}

/// The more fundamental of two conflicts (a window that cannot be met stays one whatever the
/// energy; energy before the horizon).
fn worst(a: Conflict, b: Conflict) -> Conflict {
    let rank = |c: Conflict| match c {
        Conflict::Window => 0,
        Conflict::Horizon => 1,
        Conflict::Energy => 2,
    };
    if rank(b) > rank(a) {
        b
    } else {
        a
    }
}

fn target_is_valid(t: &Target) -> bool {
    t.position_m.iter().all(|v| v.is_finite())
        && t.window_open_s.is_finite()
        && t.window_close_s.is_finite()
        && t.window_open_s <= t.window_close_s
        && t.dwell_s.is_finite()
        && t.dwell_s >= 0.0
        && t.dwell_energy_j.is_finite()
        && t.dwell_energy_j >= 0.0
}
