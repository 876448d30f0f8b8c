//! `sim-host still`: the flight software on the devices of a rover standing still ([`crate::devices::standing`]), and the executive's statistics per rate group.

use crate::devices::standing::{
    ConstantPower, FixedSun, GreyStereo, SimClock, SimTime, StillImu, StillMobility,
};
use crate::devices::CountingTelemetry;
use fsw::exec::ExecConfig;
use fsw::flight::{Devices, Fsw, FswConfig, Platform};

/// The simulated platform's device types.
pub struct SimPlatform;

impl Platform for SimPlatform {
    type Clock = SimClock;
    type Imu = StillImu;
    type Mobility = StillMobility;
    type Camera = GreyStereo;
    type Sun = FixedSun;
    type Power = ConstantPower;
    type Telemetry = CountingTelemetry;
    type ImageMemory = crate::devices::HostImageMemory;
}

/// Per-group figures of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupSummary {
    /// Group name.
    pub name: &'static str,
    /// Times the group ran.
    pub runs: u64,
    /// Largest execution time, microseconds.
    pub max_us: u64,
    /// Mean execution time, microseconds.
    pub mean_us: u64,
    /// Task overruns in the group.
    pub overruns: u64,
}

/// Figures of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSummary {
    /// Frames run.
    pub frames: u64,
    /// Simulated time, seconds.
    pub sim_time_s: f64,
    /// Per group.
    pub groups: Vec<GroupSummary>,
    /// Frames that exceeded the minor-frame period.
    pub cycle_slips: u64,
    /// Stereo frames completed.
    pub stereo_frames: u32,
    /// Device faults counted (all devices).
    pub device_faults: u32,
}

/// Run `frames` minor frames of the flight software on the still-rover devices.
pub fn run_still(frames: u64) -> anyhow::Result<RunSummary> {
    let time = SimTime::default();
    let config = ExecConfig::default();
    let devices = Devices::<SimPlatform> {
        clock: SimClock::new(time.clone()),
        imu: StillImu::new(time.clone()),
        mobility: StillMobility::new(time.clone()),
        camera: GreyStereo::new(time.clone(), 3),
        sun: FixedSun::new(time.clone()),
        power: ConstantPower::new(time.clone()),
        telemetry: CountingTelemetry::default(),
        image_memory: crate::devices::host_image_memory(),
    };
    // The still rover cannot move: the path only gives guidance something to command.
    let mut fsw_config = FswConfig::rocky8([0.0; 3], 0.0);
    // The ephemeris of the fixed sun (30 deg up, due north at local noon at 60 deg S on the
    // equinox; it moves 0.04 deg in 10 s), so the alignment takes its heading from the sun.
    fsw_config.nav.filter.ekf.sun = Some(fsw::estimation::ephemeris::SunEphemeris::from_site(
        -60.0, 0.0, 12.0,
    ));
    let mut fsw = Fsw::new(devices, &fsw_config, &[[0.0, 0.0], [1.0, 0.0]])
        .map_err(|e| anyhow::anyhow!("flight software refused its configuration: {e:?}"))?;
    fsw.start_vo();
    for _ in 0..frames {
        fsw.tick();
        time.advance(u64::from(config.frame_period_us));
    }
    let exec = fsw.executive();
    let groups = exec
        .groups()
        .iter()
        .enumerate()
        .map(|(g, state)| GroupSummary {
            name: state.config.name,
            runs: state.runs,
            max_us: state.timing.max_us,
            mean_us: state.timing.mean_us(),
            overruns: exec
                .tasks()
                .iter()
                .filter(|t| t.config.group == g)
                .map(|t| t.timing.overruns)
                .sum(),
        })
        .collect();
    let state = fsw.state();
    Ok(RunSummary {
        frames,
        sim_time_s: time.now_us() as f64 * 1e-6,
        groups,
        cycle_slips: exec.cycle_slips(),
        stereo_frames: state.stereo_frames,
        device_faults: state.health.iter().map(|h| h.faults()).sum(),
    })
}

/// `sim-host still [--frames N]`.
#[derive(Debug, Clone, clap::Args)]
pub struct StillArgs {
    /// Number of 5 ms minor frames.
    #[arg(long, default_value_t = 2000)]
    pub frames: u64,
}

/// Run `sim-host still` and print the per-rate-group counts and execution times.
pub fn main(args: StillArgs) -> anyhow::Result<()> {
    let summary = run_still(args.frames)?;
    println!(
        "sim-host: {} frames, {:.2} s simulated, {} stereo frames, {} cycle slips, {} device faults",
        summary.frames,
        summary.sim_time_s,
        summary.stereo_frames,
        summary.cycle_slips,
        summary.device_faults
    );
    println!(
        "{:<6} {:>8} {:>10} {:>10} {:>9}",
        "group", "runs", "max_us", "mean_us", "overruns"
    );
    for g in &summary.groups {
        println!(
            "{:<6} {:>8} {:>10} {:>10} {:>9}",
            g.name, g.runs, g.max_us, g.mean_us, g.overruns
        );
    }
    Ok(())
}
