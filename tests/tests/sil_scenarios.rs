//! The CI tier of the SIL acceptance (SIL-GNC-1..4, SIL-NAV-1..2, SIL-KIN-1..6, SIL-SLIP-1..2,
//! SIL-GATE-1..2, SIL-RB-1, SIL-FP-1..7, SIL-HAZ-1..3, SIL-LOC-1..2, SIL-SEQ-1..2): each case
//! runs closed loop on the first `CI_SEEDS` acceptance seeds with rendered stereo, and every
//! check value must be the value the release tier recorded for that case and seed in
//! `docs/results/sil-seeds.jsonl` (bit for bit: the flight software and the simulator are
//! deterministic). A change of flight or simulator behaviour fails here until the release tier
//! is run again (`sim-host sil`), and the release tier's verdicts must agree with the table's
//! `open` flags (`sim_host::commands::sil::seeds::consistency`, a unit test of `sim-host`).

use sim_host::commands::sil::seeds::{acceptance_seeds, read_rows, CI_SEEDS, RELEASE_ROWS};
use sim_host::commands::sil::{case, run_case};
use std::path::PathBuf;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn check(id: &str) {
    let Some(c) = case(id) else {
        panic!("no SIL case {id}");
    };
    let rows = match read_rows(&root().join(RELEASE_ROWS)) {
        Ok(r) => r,
        Err(e) => panic!("{e:#}: run the release tier (`sim-host sil`)"),
    };
    for seed in acceptance_seeds(CI_SEEDS) {
        let run = match run_case(c, &root().join("scenarios"), seed, None) {
            Ok(r) => r,
            Err(e) => panic!("{id} seed {seed}: run failed: {e:#}"),
        };
        let Some(recorded) = rows.iter().find(|r| r.case == id && r.seed == seed) else {
            panic!(
                "{id} seed {seed}: not in {RELEASE_ROWS}: run the release tier (`sim-host sil`)"
            );
        };
        for ((k, v), r) in c.checks.iter().zip(&run.values).zip(&recorded.values) {
            println!(
                "{id} seed {seed} {}: {v:?} {} (release tier {r:?}; per seed {})",
                k.what,
                k.unit,
                if k.passes(*v) { "pass" } else { "FAIL" }
            );
        }
        assert_eq!(
            run.values, recorded.values,
            "{id} seed {seed}: the check values differ from the release tier's \
             ({RELEASE_ROWS}): flight or simulator behaviour changed; run `sim-host sil` again"
        );
    }
}

#[test]
fn sil_gnc_1_slope_10_with_compensation() {
    check("SIL-GNC-1");
}

#[test]
fn sil_gnc_2_slope_10_without_compensation_drifts() {
    check("SIL-GNC-2");
}

#[test]
fn sil_nav_1_marsyard() {
    check("SIL-NAV-1");
}

#[test]
fn sil_loc_1_marsyard_localization_without_vo() {
    check("SIL-LOC-1");
}

#[test]
fn sil_loc_2_wrong_map_is_not_fused() {
    check("SIL-LOC-2");
}

#[test]
fn sil_seq_1_multi_target_reorder() {
    check("SIL-SEQ-1");
}

#[test]
fn sil_seq_2_energy_shortfall_drops_the_least_important() {
    check("SIL-SEQ-2");
}

#[test]
fn sil_kin_1_rough_kinematics() {
    check("SIL-KIN-1");
}

#[test]
fn sil_gnc_3_slope_20() {
    check("SIL-GNC-3");
}

#[test]
fn sil_nav_2_dunes_long() {
    check("SIL-NAV-2");
}

#[test]
fn sil_gnc_4_faults_and_fallbacks() {
    check("SIL-GNC-4");
}

#[test]
fn sil_kin_2_rough_without_slip() {
    check("SIL-KIN-2");
}

#[test]
fn sil_kin_3_rock_crawl() {
    check("SIL-KIN-3");
}

#[test]
fn sil_kin_4_undulating_contact_angles() {
    check("SIL-KIN-4");
}

#[test]
fn sil_kin_5_step_climb() {
    check("SIL-KIN-5");
}

#[test]
fn sil_kin_6_rock_field_crawl() {
    check("SIL-KIN-6");
}

#[test]
fn sil_kin_7_fig17_short_crawl() {
    check("SIL-KIN-7");
}

#[test]
fn sil_slip_1_lumped_slope_reference() {
    check("SIL-SLIP-1");
}

#[test]
fn sil_slip_2_lumped_marsyard_reference() {
    check("SIL-SLIP-2");
}

#[test]
fn sil_gate_1_flat_firm_false_alarms() {
    check("SIL-GATE-1");
}

#[test]
fn sil_gate_2_rough_firm_false_alarms() {
    check("SIL-GATE-2");
}

#[test]
fn sil_rb_1_ekf_against_dead_reckoning_without_vo() {
    check("SIL-RB-1");
}

#[test]
fn sil_fp_1_camera_blackout() {
    check("SIL-FP-1");
}

#[test]
fn sil_fp_2_dead_camera() {
    check("SIL-FP-2");
}

#[test]
fn sil_fp_3_stuck_imu() {
    check("SIL-FP-3");
}

#[test]
fn sil_fp_4_imu_bias() {
    check("SIL-FP-4");
}

#[test]
fn sil_fp_5_slope_20_combined() {
    check("SIL-FP-5");
}

#[test]
fn sil_fp_6_full_slip() {
    check("SIL-FP-6");
}

#[test]
fn sil_fp_7_motor_stall() {
    check("SIL-FP-7");
}

#[test]
fn sil_haz_1_rockfield_goal_reached_without_collision() {
    check("SIL-HAZ-1");
}

#[test]
fn sil_haz_2_cul_de_sac_boundary_following() {
    check("SIL-HAZ-2");
}

#[test]
fn sil_haz_3_unreachable_goal_reported() {
    check("SIL-HAZ-3");
}
