//! The replan of [`Sequencer`] (module doc of [`super`]): cheapest insertion of the targets in
//! priority order, the priority repair, or-opt moves, the re-insertion of dropped targets and
//! the commitment to the target being driven to.

use super::{DropReason, Sequencer, SequencerError, Situation, TargetStatus, MAX_TARGETS};
use heapless::Vec;

impl Sequencer {
    /// Build the plan from `situation` (module doc): cheapest insertion by priority, conflicts
    /// repaired by dropping, or-opt improvement, re-insertion of dropped targets. Visited
    /// targets stay out; dropped ones are reconsidered. Errors: a non-finite situation.
    pub fn replan(&mut self, situation: &Situation) -> Result<(), SequencerError> {
        self.replan_committed(situation, None, 0.0)
    }

    /// [`Self::replan`] with a commitment to the target the rover is driving to: when the best
    /// plan starts elsewhere, the plan with `committed` moved to its head is kept instead if it
    /// is feasible and at most `hysteresis_s` (s, finite, >= 0) longer. A rover turned away
    /// for a few seconds' gain would dither between targets as its position changes; V99's
    /// replan on an obstacle (Fig. 3) changes the order by far more. `None`: no commitment.
    pub fn replan_committed(
        &mut self,
        situation: &Situation,
        committed: Option<usize>,
        hysteresis_s: f64,
    ) -> Result<(), SequencerError> {
        if !(hysteresis_s.is_finite() && hysteresis_s >= 0.0) {
            return Err(SequencerError::InvalidInput);
        }
        let finite = situation.now_s.is_finite()
            && situation.end_s.is_finite()
            && situation.energy_available_j.is_finite()
            && situation.position_m.iter().all(|v| v.is_finite());
        if !finite {
            return Err(SequencerError::InvalidInput);
        }
        let previous = self.plan.clone();
        let candidates = self.candidates();
        let mut status = self.status;
        let mut order = self.insert_in_priority_order(situation, &candidates, &mut status);
        self.repair_priorities(situation, &candidates, &mut order, &mut status);
        self.or_opt(situation, &mut order);
        self.reinsert_dropped(situation, &candidates, &mut order, &mut status);
        self.keep_commitment(situation, &mut order, committed, hysteresis_s);
        self.adopt(situation, &previous, order, status);
        Ok(())
    }

    /// The targets a replan considers (not visited, not unreachable), in priority order
    /// (higher first; ties by index).
    fn candidates(&self) -> Vec<u8, MAX_TARGETS> {
        let mut candidates: Vec<u8, MAX_TARGETS> = Vec::new();
        for level in (0..=u8::MAX).rev() {
            for (i, t) in self.targets.iter().enumerate() {
                let out = matches!(
                    self.status.get(i),
                    Some(TargetStatus::Visited | TargetStatus::Dropped(DropReason::Unreachable))
                );
                if t.priority == level && !out {
                    let _ = candidates.push(i as u8);
                }
            }
        }
        candidates
    }

    /// Cheapest insertion of the `candidates` one after the other into an empty plan: each
    /// becomes pending in `status`, or dropped for the conflict of its best position.
    fn insert_in_priority_order(
        &self,
        situation: &Situation,
        candidates: &[u8],
        status: &mut [TargetStatus; MAX_TARGETS],
    ) -> Vec<u8, MAX_TARGETS> {
        let mut order: Vec<u8, MAX_TARGETS> = Vec::new();
        for &c in candidates {
            match self.insert(situation, &order, c, false) {
                Ok((o, _)) => {
                    order = o;
                    if let Some(s) = status.get_mut(usize::from(c)) {
                        *s = TargetStatus::Pending;
                    }
                }
                Err(conflict) => {
                    if let Some(s) = status.get_mut(usize::from(c)) {
                        *s = TargetStatus::Dropped(conflict.into());
                    }
                }
            }
        }
        order
    }

    /// Priority repair: a dropped target displaces lower-priority ones (the lowest first)
    /// when that makes it fit. Insertion in priority order already keeps the higher
    /// priorities, except where a target fits only behind another one (a leg penalty on the
    /// way from the rover: the insertion into the empty plan put it first).
    fn repair_priorities(
        &self,
        situation: &Situation,
        candidates: &[u8],
        order: &mut Vec<u8, MAX_TARGETS>,
        status: &mut [TargetStatus; MAX_TARGETS],
    ) {
        for &c in candidates {
            // The displaced targets leave for the reason the displacing one was dropped.
            let Some(TargetStatus::Dropped(reason)) = status.get(usize::from(c)).copied() else {
                continue;
            };
            if reason == DropReason::Unreachable {
                continue;
            }
            let Some(prio) = self.targets.get(usize::from(c)).map(|t| t.priority) else {
                continue;
            };
            let mut trial = order.clone();
            let mut removed: Vec<u8, MAX_TARGETS> = Vec::new();
            for _ in 0..MAX_TARGETS {
                if let Ok((o, _)) = self.insert(situation, &trial, c, false) {
                    *order = o;
                    if let Some(s) = status.get_mut(usize::from(c)) {
                        *s = TargetStatus::Pending;
                    }
                    for &r in &removed {
                        if let Some(s) = status.get_mut(usize::from(r)) {
                            *s = TargetStatus::Dropped(reason);
                        }
                    }
                    break;
                }
                // The lowest priority below `prio` in the trial (the last of equal ones).
                let victim = trial
                    .iter()
                    .enumerate()
                    .filter_map(|(k, &o)| {
                        let p = self.targets.get(usize::from(o))?.priority;
                        (p < prio).then_some((k, p))
                    })
                    .min_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0)));
                let Some((k, _)) = victim else {
                    break;
                };
                // Out of `trial` without `Vec::remove`, whose index check is a panic path.
                let mut rest: Vec<u8, MAX_TARGETS> = Vec::new();
                for (j, &o) in trial.iter().enumerate() {
                    if j == k {
                        let _ = removed.push(o);
                    } else {
                        let _ = rest.push(o);
                    }
                }
                trial = rest;
            }
        }
    }

    /// Or-opt: moves one target to another position while the plan gets shorter; a plan that
    /// keeps the priority margin keeps it.
    fn or_opt(&self, situation: &Situation, order: &mut Vec<u8, MAX_TARGETS>) {
        for _ in 0..MAX_TARGETS * MAX_TARGETS {
            let Ok(current) = self.evaluate(situation, order, None, false) else {
                break;
            };
            let protected = self.evaluate(situation, order, None, true).is_ok();
            let mut improved: Option<(Vec<u8, MAX_TARGETS>, f64)> = None;
            for from in 0..order.len() {
                let Some(&moved) = order.get(from) else {
                    break;
                };
                let mut rest: Vec<u8, MAX_TARGETS> = Vec::new();
                for (k, &o) in order.iter().enumerate() {
                    if k != from {
                        let _ = rest.push(o);
                    }
                }
                if let Ok((o, d)) = self.insert(situation, &rest, moved, protected) {
                    let best = improved.as_ref().map_or(current, |(_, b)| *b);
                    if d < best - 1e-9 {
                        improved = Some((o, d));
                    }
                }
            }
            match improved {
                Some((o, _)) => *order = o,
                None => break,
            }
        }
    }

    /// Re-inserts the dropped targets that fit the final order (highest priority first).
    fn reinsert_dropped(
        &self,
        situation: &Situation,
        candidates: &[u8],
        order: &mut Vec<u8, MAX_TARGETS>,
        status: &mut [TargetStatus; MAX_TARGETS],
    ) {
        for &c in candidates {
            let dropped = matches!(status.get(usize::from(c)), Some(TargetStatus::Dropped(_)));
            if dropped {
                if let Ok((o, _)) = self.insert(situation, order, c, false) {
                    *order = o;
                    if let Some(s) = status.get_mut(usize::from(c)) {
                        *s = TargetStatus::Pending;
                    }
                }
            }
        }
    }

    /// The commitment: the `committed` target moved to the head of `order` if that plan is
    /// feasible (with the priority margin when `order` keeps it) and at most `hysteresis_s`
    /// longer.
    fn keep_commitment(
        &self,
        situation: &Situation,
        order: &mut Vec<u8, MAX_TARGETS>,
        committed: Option<usize>,
        hysteresis_s: f64,
    ) {
        let head = order.first().map(|&k| usize::from(k));
        let protected = self.evaluate(situation, order, None, true).is_ok();
        if let (Some(c), Ok(best)) = (committed, self.evaluate(situation, order, None, false)) {
            if head != Some(c) && order.iter().any(|&k| usize::from(k) == c) {
                let mut alt: Vec<u8, MAX_TARGETS> = Vec::new();
                let _ = alt.push(c as u8);
                for &k in order.iter().filter(|&&k| usize::from(k) != c) {
                    let _ = alt.push(k);
                }
                if let Ok(d) = self.evaluate(situation, &alt, None, protected) {
                    if alt.len() == order.len() && d <= best + hysteresis_s {
                        *order = alt;
                    }
                }
            }
        }
    }

    /// Makes `order` and `status` the plan: counts the newly dropped targets and a change of
    /// the kept targets' order against `previous`, and builds the timeline.
    fn adopt(
        &mut self,
        situation: &Situation,
        previous: &[u8],
        mut order: Vec<u8, MAX_TARGETS>,
        status: [TargetStatus; MAX_TARGETS],
    ) {
        let newly_dropped = status
            .iter()
            .zip(self.status.iter())
            .filter(|(n, o)| matches!(n, TargetStatus::Dropped(_)) && **o == TargetStatus::Pending)
            .count() as u32;
        // Reordered: the targets of both plans, in the previous order and in the new one.
        let common = previous.iter().filter(|k| order.contains(k));
        let reordered = common
            .zip(order.iter().filter(|k| previous.contains(k)))
            .any(|(a, b)| a != b);
        if reordered {
            self.counters.reorders = self.counters.reorders.saturating_add(1);
        }
        self.counters.drops = self.counters.drops.saturating_add(newly_dropped);
        self.counters.replans = self.counters.replans.saturating_add(1);
        self.status = status;
        let mut timeline = Vec::new();
        // The order was built from feasible evaluations; a failure here would be a bug, so the
        // plan is emptied rather than kept inconsistent.
        if self
            .evaluate(situation, &order, Some(&mut timeline), false)
            .is_err()
        {
            order.clear();
            timeline.clear();
        }
        self.plan = order;
        self.timeline = timeline;
    }
}
