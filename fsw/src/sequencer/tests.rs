//! SEQ-1..4: the sequencer's repairs keep every constraint on random plans, drop by
//! priority, reorder after an obstacle (V99 Fig. 3) and put a localization first.

use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::vec::Vec as StdVec;

fn target(x: f64, y: f64, priority: u8) -> Target {
    Target {
        position_m: [x, y],
        priority,
        window_open_s: 0.0,
        window_close_s: 1e9,
        dwell_s: 300.0,
        dwell_energy_j: 3000.0,
    }
}

fn situation(energy: f64) -> Situation {
    Situation {
        now_s: 0.0,
        position_m: [0.0, 0.0],
        energy_available_j: energy,
        end_s: 1e9,
    }
}

/// The plan's timeline recomputed independently of the sequencer (the constraints of the module
/// doc), `Err` on the first broken constraint.
fn independent_check(seq: &Sequencer, s: &Situation) -> Result<(), &'static str> {
    let m = ResourceModel::rocky8();
    if seq.plan().is_empty() && !seq.localization_due() {
        // Nothing planned: nothing to break (even with the energy or the time already gone).
        return Ok(());
    }
    let (mut t, mut e, mut pos) = (s.now_s, 0.0, s.position_m);
    if seq.localization_due() {
        t += m.localization_s;
        e += m.localization_s * m.idle_power_w + m.localization_energy_j;
    }
    for (n, &k) in seq.plan().iter().enumerate() {
        let tg = seq.targets()[k as usize];
        let penalty = if n == 0 {
            seq.penalty_m[k as usize]
        } else {
            0.0
        };
        let d = ((tg.position_m[0] - pos[0]).powi(2) + (tg.position_m[1] - pos[1]).powi(2)).sqrt()
            * m.detour_factor
            + penalty;
        t += d / m.speed_m_s;
        e += d / m.speed_m_s * m.drive_power_w;
        if t < tg.window_open_s {
            e += (tg.window_open_s - t) * m.idle_power_w;
            t = tg.window_open_s;
        }
        if t > tg.window_close_s + 1e-6 {
            return Err("window");
        }
        t += tg.dwell_s;
        e += tg.dwell_s * m.idle_power_w + tg.dwell_energy_j;
        pos = tg.position_m;
    }
    if t > s.end_s + 1e-6 {
        return Err("horizon");
    }
    if e > s.energy_available_j + 1e-6 {
        return Err("energy");
    }
    Ok(())
}

/// SEQ-1: on 500 random problems (3-8 targets over 30 m, random priorities, windows, dwells,
/// energy and horizon, obstacle penalties, localizations), after every replan: the plan keeps
/// every constraint (checked independently), every target is planned, visited or dropped with a
/// reason, no dropped target could be inserted anywhere in the final plan (the repair is
/// maximal), and replanning the same situation gives the same plan (deterministic).
#[test]
fn seq_1_repairs_keep_every_constraint_on_random_plans() {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let (mut dropped_total, mut planned_total, mut unrepairable) = (0, 0, 0);
    for case in 0..500 {
        let n = rng.random_range(3..=MAX_TARGETS);
        let targets: StdVec<Target> = (0..n)
            .map(|_| {
                let open = rng.random_range(0.0..3000.0);
                Target {
                    position_m: [rng.random_range(-15.0..15.0), rng.random_range(-15.0..15.0)],
                    priority: rng.random_range(0..5),
                    window_open_s: open,
                    window_close_s: open + rng.random_range(100.0..5000.0),
                    dwell_s: rng.random_range(0.0..600.0),
                    dwell_energy_j: rng.random_range(0.0..5000.0),
                }
            })
            .collect();
        let mut seq = Sequencer::new(&targets, ResourceModel::rocky8()).unwrap();
        let mut s = Situation {
            now_s: 0.0,
            position_m: [0.0, 0.0],
            energy_available_j: rng.random_range(5e3..1.5e5),
            end_s: rng.random_range(1000.0..8000.0),
        };
        for step in 0..4 {
            if rng.random_bool(0.3) {
                let i = rng.random_range(0..n);
                seq.set_leg_penalty(i, rng.random_range(0.0..20.0)).unwrap();
            }
            if rng.random_bool(0.2) {
                seq.request_localization();
            }
            seq.replan(&s).unwrap();
            match seq.check(&s) {
                Ok(()) => independent_check(&seq, &s)
                    .unwrap_or_else(|e| panic!("case {case} step {step}: {e}")),
                Err(_) => {
                    // Only a localization that does not fit by itself is left unrepaired.
                    assert!(seq.localization_due() && seq.plan().is_empty());
                    assert!(independent_check(&seq, &s).is_err());
                    unrepairable += 1;
                    break;
                }
            }
            for i in 0..n {
                let planned = seq.plan().contains(&(i as u8));
                match seq.status(i).unwrap() {
                    TargetStatus::Pending => {
                        assert!(planned, "case {case}: {i} pending, unplanned")
                    }
                    TargetStatus::Visited => assert!(!planned),
                    TargetStatus::Dropped(_) => {
                        assert!(!planned);
                        assert!(
                            seq.insert(&s, seq.plan(), i as u8, false).is_err(),
                            "case {case}: dropped {i} fits"
                        );
                        dropped_total += 1;
                    }
                }
            }
            planned_total += seq.plan().len();
            let again = {
                let mut c = seq.clone();
                c.replan(&s).unwrap();
                c.plan().to_vec()
            };
            assert_eq!(again, seq.plan().to_vec(), "case {case}: not deterministic");
            // Execute the first target, then time, position and energy move on.
            if let Some(slot) = seq.timeline().first().copied() {
                if seq.localization_due() {
                    seq.localized();
                }
                let i = slot.target as usize;
                seq.visited(i).unwrap();
                s.now_s = slot.end_s;
                s.position_m = seq.targets()[i].position_m;
                s.energy_available_j -= slot.energy_j * rng.random_range(0.9..1.4);
            }
        }
    }
    assert!(
        dropped_total > 100 && planned_total > 500,
        "{dropped_total} {planned_total}"
    );
    assert!(unrepairable < 75, "{unrepairable}");
}

/// SEQ-2: energy over budget drops the lowest-priority target first (V99 sec. 3).
#[test]
fn seq_2_energy_shortfall_drops_the_lowest_priority() {
    let targets = [
        target(5.0, 0.0, 3),
        target(10.0, 0.0, 1),
        target(15.0, 0.0, 2),
    ];
    let mut seq = Sequencer::new(&targets, ResourceModel::rocky8()).unwrap();
    seq.replan(&situation(1e6)).unwrap();
    assert_eq!(seq.plan(), &[0, 1, 2]);
    // Enough for two targets only (a straight line out: 15 m in all).
    let need_all = seq.timeline()[2].energy_j;
    let need_two = need_all - 300.0 * 25.0 - 3000.0;
    seq.replan(&situation(need_two + 1.0)).unwrap();
    assert_eq!(seq.plan(), &[0, 2]);
    assert_eq!(
        seq.status(1),
        Some(TargetStatus::Dropped(DropReason::Energy))
    );
    assert_eq!(seq.counters().drops, 1);
}

/// SEQ-3: V99 Fig. 3. Three targets; the first leg meets an unknown obstacle whose detour
/// brings the rover near the third target: the replan from there reorders the remaining ones.
#[test]
fn seq_3_obstacle_reorders_the_sequence() {
    let targets = [
        target(10.0, 0.0, 1),
        target(10.0, 10.0, 1),
        target(0.0, 12.0, 1),
    ];
    let mut seq = Sequencer::new(&targets, ResourceModel::rocky8()).unwrap();
    seq.replan(&situation(1e7)).unwrap();
    assert_eq!(seq.plan(), &[0, 1, 2]);
    // The way to target 0 is blocked: RoverBug's boundary following took the rover north
    // round the obstacle to (2, 11), and the path planner says target 0 is 25 m further.
    seq.set_leg_penalty(0, 25.0).unwrap();
    let s = Situation {
        position_m: [2.0, 11.0],
        ..situation(1e7)
    };
    seq.replan(&s).unwrap();
    assert_eq!(seq.plan(), &[2, 1, 0]);
    assert_eq!(seq.counters().reorders, 1);
    assert_eq!(seq.check(&s), Ok(()));
}

/// SEQ-4: a localization request goes first and costs its time and energy; windows are met by
/// waiting; a closed window drops its target; invalid inputs are refused.
#[test]
fn seq_4_localization_windows_and_invalid_inputs() {
    let mut late = target(5.0, 0.0, 1);
    late.window_open_s = 2000.0;
    late.window_close_s = 2100.0;
    let mut gone = target(6.0, 0.0, 2);
    gone.window_close_s = 10.0;
    let mut seq = Sequencer::new(&[late, gone], ResourceModel::rocky8()).unwrap();
    seq.replan(&situation(1e7)).unwrap();
    assert_eq!(seq.plan(), &[0]);
    assert_eq!(
        seq.status(1),
        Some(TargetStatus::Dropped(DropReason::Window))
    );
    let slot = seq.timeline()[0];
    assert!(slot.arrive_s < 2000.0 && slot.start_s == 2000.0);
    seq.request_localization();
    seq.replan(&situation(1e7)).unwrap();
    assert!(seq.localization_due());
    let with_loc = seq.timeline()[0];
    // 90 s of localization replace 90 s of the wait: the energy grows by its 1.8 kJ only.
    assert!((with_loc.energy_j - slot.energy_j - 1800.0).abs() < 1e-6);
    assert_eq!(with_loc.start_s, 2000.0);
    assert_eq!(seq.counters().localizations, 1);
    // Invalid inputs.
    let mut bad = target(f64::NAN, 0.0, 1);
    assert_eq!(
        Sequencer::new(&[bad], ResourceModel::rocky8()).err(),
        Some(SequencerError::InvalidInput)
    );
    bad = target(0.0, 0.0, 1);
    bad.window_close_s = -1.0;
    assert!(Sequencer::new(&[bad], ResourceModel::rocky8()).is_err());
    assert_eq!(
        Sequencer::new(
            &[target(0.0, 0.0, 1); MAX_TARGETS + 1],
            ResourceModel::rocky8()
        )
        .err(),
        Some(SequencerError::TooManyTargets)
    );
    assert!(seq.set_leg_penalty(0, f64::NAN).is_err());
    assert_eq!(
        seq.set_leg_penalty(5, 1.0),
        Err(SequencerError::NoSuchTarget)
    );
    let mut nan = situation(1e7);
    nan.now_s = f64::NAN;
    assert_eq!(seq.replan(&nan), Err(SequencerError::InvalidInput));
    assert_eq!(seq.visited(7), Err(SequencerError::NoSuchTarget));
}

/// SEQ-5: an unreachable target leaves the plan for good; the commitment keeps the target the
/// rover drives to unless another order saves more than the hysteresis; a recalibrated model
/// (more power than planned) drops a target the old one kept.
#[test]
fn seq_5_unreachable_commitment_and_recalibration() {
    let targets = [
        target(10.0, 0.0, 1),
        target(10.0, 10.0, 1),
        target(0.0, 12.0, 1),
    ];
    let mut seq = Sequencer::new(&targets, ResourceModel::rocky8()).unwrap();
    seq.replan(&situation(1e7)).unwrap();
    assert_eq!(seq.plan(), &[0, 1, 2]);
    // Near target 2 the best order starts there; committed to 0 with a small hysteresis the
    // order changes anyway (the saving is far larger), with a huge one it keeps 0 first.
    let near = Situation {
        position_m: [1.0, 11.0],
        ..situation(1e7)
    };
    let mut free = seq.clone();
    free.replan(&near).unwrap();
    let best = free.duration(&near).unwrap();
    assert_eq!(free.plan()[0], 2);
    let mut kept = seq.clone();
    kept.replan_committed(&near, Some(0), 1e6).unwrap();
    assert_eq!(kept.plan()[0], 0);
    assert!(kept.duration(&near).unwrap() > best);
    let mut switched = seq.clone();
    switched.replan_committed(&near, Some(0), 10.0).unwrap();
    assert_eq!(switched.plan(), free.plan());
    assert!(seq.replan_committed(&near, Some(0), f64::NAN).is_err());
    // Unreachable: out now and in every later replan, even with all the energy in the world.
    seq.unreachable(1).unwrap();
    assert_eq!(seq.plan(), &[0, 2]);
    seq.replan(&situation(1e9)).unwrap();
    assert!(!seq.plan().contains(&1));
    assert_eq!(
        seq.status(1),
        Some(TargetStatus::Dropped(DropReason::Unreachable))
    );
    assert_eq!(seq.unreachable(9), Err(SequencerError::NoSuchTarget));
    // Recalibration: the energy of the plan under the rocky8 model, then powers 4x as high.
    let need = seq.timeline().last().unwrap().energy_j;
    seq.replan(&situation(need * 1.05)).unwrap();
    assert_eq!(seq.plan().len(), 2);
    let mut hungry = ResourceModel::rocky8();
    hungry.drive_power_w *= 4.0;
    hungry.idle_power_w *= 4.0;
    seq.set_model(hungry).unwrap();
    assert_eq!(seq.model(), hungry);
    seq.replan(&situation(need * 1.05)).unwrap();
    assert!(seq.plan().len() < 2);
    assert!([0, 2]
        .iter()
        .any(|&i| seq.status(i) == Some(TargetStatus::Dropped(DropReason::Energy))));
    hungry.speed_m_s = 0.0;
    assert!(seq.set_model(hungry).is_err());
}

/// SEQ-6: priority repair. The most important target fits only behind another one (a leg
/// penalty on the way from the rover); the energy allows two targets: the least important is
/// dropped, not the most important (insertion into the empty plan alone would drop it).
#[test]
fn seq_6_a_penalised_high_priority_target_displaces_the_lowest() {
    let targets = [
        target(10.0, 0.0, 3),
        target(2.0, 10.0, 2),
        target(-8.0, 12.0, 1),
    ];
    let mut seq = Sequencer::new(&targets, ResourceModel::rocky8()).unwrap();
    seq.set_leg_penalty(0, 40.0).unwrap();
    // Energy of [1, 0] (no penalty: target 0 is not first) with a little to spare.
    let mut timeline = Vec::new();
    seq.evaluate(&situation(1e9), &[1, 0], Some(&mut timeline), false)
        .unwrap();
    let need = timeline[1].energy_j;
    // Target 0 alone, first with its penalty, needs more than that.
    assert!(seq
        .evaluate(&situation(need * 1.02), &[0], None, false)
        .is_err());
    let tight = situation(need * 1.02);
    seq.replan(&tight).unwrap();
    assert_eq!(seq.plan(), &[1, 0]);
    assert_eq!(
        seq.status(2),
        Some(TargetStatus::Dropped(DropReason::Energy))
    );
    assert_eq!(seq.check(&tight), Ok(()));
    independent_check(&seq, &tight).unwrap();
}

/// SEQ-7 (priority margin): a less important target on the way to a more important one is not
/// put first when the important one then fits only without the margin (a detour longer than
/// planned would cost it): with energy for both in that order but not for the margin, the less
/// important target is dropped. Without the margin (`priority_margin` 0) both are planned, the
/// less important first. The important target itself may still go behind a less important one
/// when that is its only way (SEQ-6).
#[test]
fn seq_7_a_less_important_target_first_needs_the_priority_margin() {
    let targets = [target(20.0, 0.0, 3), target(10.0, 0.5, 1)];
    let mut bare = ResourceModel::rocky8();
    bare.priority_margin = 0.0;
    let mut seq = Sequencer::new(&targets, bare).unwrap();
    let mut timeline = Vec::new();
    seq.evaluate(&situation(1e9), &[1, 0], Some(&mut timeline), false)
        .unwrap();
    let need = timeline[1].energy_j;
    let tight = situation(need * 1.1);
    // The other order needs more (back from the far target), and more than there is.
    assert!(seq.evaluate(&tight, &[0, 1], None, false).is_err());
    seq.replan(&tight).unwrap();
    assert_eq!(seq.plan(), &[1, 0]);
    let mut seq = Sequencer::new(&targets, ResourceModel::rocky8()).unwrap();
    assert!(need * 1.1 < need * (1.0 + ResourceModel::rocky8().priority_margin));
    seq.replan(&tight).unwrap();
    assert_eq!(seq.plan(), &[0]);
    assert_eq!(
        seq.status(1),
        Some(TargetStatus::Dropped(DropReason::Energy))
    );
    assert_eq!(seq.check(&tight), Ok(()));
    independent_check(&seq, &tight).unwrap();
    // With energy for the margin, the way past the less important target is planned again.
    let ample = situation(need * 1.6);
    seq.replan(&ample).unwrap();
    assert_eq!(seq.plan(), &[1, 0]);
    let mut bad = ResourceModel::rocky8();
    bad.priority_margin = f64::NAN;
    assert!(seq.set_model(bad).is_err());
}
