//! SIL-EXEC-1: the flight schedule on the host simulator runs every group at its rate.

/// SIL-EXEC-1: 10 s at 200 Hz: RG1 2000 runs, RG2 200, RG3 50 (5 Hz capture-policy checks),
/// RG4 2, RG2B 200 (RG2's rate, half a period later); stereo captures complete: 8, the first after the 2 s alignment, then one per second
/// (VO retry: the still rover's uniform grey frames give VO no keyframe); no device faults.
#[test]
fn sil_exec_1_schedule_counts_on_host() {
    let summary = match sim_host::commands::still::run_still(2000) {
        Ok(s) => s,
        Err(e) => panic!("run failed: {e}"),
    };
    let runs: Vec<u64> = summary.groups.iter().map(|g| g.runs).collect();
    assert_eq!(runs, vec![2000, 200, 50, 2, 200]);
    assert_eq!(summary.stereo_frames, 8);
    assert_eq!(summary.device_faults, 0);
}
