//! # fuzz-hal: the seeded adversarial-HAL fuzzer of the flight software
//!
//! Builds [`fsw::flight::Fsw`] behind devices whose answers come from one seeded PRNG
//! ([`devices`]) and ticks it frame by frame. A run is a sequence of episodes; each builds a new
//! flight software (random start pose, random 2-4 waypoint path within 4 m) and mixes
//! plausible stretches (the rover aligns, drives and arrives) with garbage bursts on a random
//! subset of devices at a random intensity, so that the deep code paths (alignment, driving,
//! gate, VO, sun updates, arrival, safing) see garbage too.
//!
//! Invariants checked after EVERY frame ([`Violation`]):
//! - no panic (each tick runs under `catch_unwind`);
//! - every motor command finite and within the rover's limits
//!   (`fsw::kinematics::ROCKY8.limits`: `|wheel rate| <= wheel_rate_rad_s`,
//!   `|steer| <= steer_rad`), and no moving command once the navigator is `Safed`;
//! - the EKF state and covariance finite, or the navigator `Safed`; `Safed` latched;
//! - the executive consistent: the frame tick counts up by one, group runs, device health
//!   counters, stereo frames, command and telemetry counters never decrease;
//! - the power reading the flight software keeps finite, non-negative, and its energy used
//!   never decreasing.
//!
//! Everything is deterministic: the same seed and frame count give the same run (the clock's
//! execution counter is simulated too).

pub mod devices;
pub mod rng;

use devices::{
    FuzzCamera, FuzzClock, FuzzImu, FuzzMobility, FuzzPower, FuzzSun, FuzzTelemetry, Shared,
    SharedRc, DEVICES, DEVICE_NAMES,
};
use fsw::estimation::ephemeris::SunEphemeris;
use fsw::flight::nav::NavMode;
use fsw::flight::{Devices, Fsw, FswConfig, Platform};
use rng::Rng;
use std::cell::RefCell;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::rc::Rc;

/// The fuzzer's device types.
pub struct FuzzPlatform;

impl Platform for FuzzPlatform {
    type Clock = FuzzClock;
    type Imu = FuzzImu;
    type Mobility = FuzzMobility;
    type Camera = FuzzCamera;
    type Sun = FuzzSun;
    type Power = FuzzPower;
    type Telemetry = FuzzTelemetry;
    type ImageMemory = fsw::rectify::ImageMemory<Vec<fsw::rectify::MapNode>, Vec<u8>>;
}

/// Settings of a run.
#[derive(Debug, Clone, Copy)]
pub struct FuzzConfig {
    /// Minor frames to tick, over all episodes.
    pub frames: u64,
    /// Seed.
    pub seed: u64,
    /// Build the VO state and hand out textured pairs (VO works on them: slower).
    pub vo: bool,
    /// Keep the last garbage answers and attach them to each violation (slower; to analyse a
    /// finding, rerun its seed with it).
    pub trace: bool,
}

/// Kinds of invariant violation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViolationKind {
    /// `Fsw::tick` panicked.
    Panic,
    /// A motor command non-finite or outside the limits.
    CommandOutOfLimits,
    /// A moving command while the navigator was safed.
    MovingWhileSafed,
    /// EKF state or covariance non-finite and the navigator not safed.
    EkfNotFinite,
    /// The navigator left `Safed`.
    SafedNotLatched,
    /// An executive or health counter went backwards, or the tick did not count up by one.
    CountersInconsistent,
    /// The kept power reading is non-finite or negative, or its energy used decreased.
    PowerImplausible,
}

/// One invariant violation.
#[derive(Debug, Clone)]
pub struct Violation {
    /// Kind.
    pub kind: ViolationKind,
    /// Episode (0-based).
    pub episode: u64,
    /// Frame within the episode.
    pub frame_in_episode: u64,
    /// Frame of the run (0-based).
    pub frame: u64,
    /// Garbage probabilities per device of the frame (0: plausible).
    pub garbage: [f64; DEVICES],
    /// Navigation mode after the frame.
    pub mode: NavMode,
    /// What exactly.
    pub detail: String,
    /// The last garbage answers before it (tracing runs only).
    pub trace: Vec<String>,
}

/// Result of a run.
#[derive(Debug, Clone, Default)]
pub struct FuzzReport {
    /// Frames ticked.
    pub frames: u64,
    /// Episodes (flight software instances).
    pub episodes: u64,
    /// Violations found (all of them).
    pub violations: u64,
    /// The first violations, with details (at most [`MAX_KEPT`]).
    pub first: Vec<Violation>,
    /// Garbage answers given, per device ([`DEVICE_NAMES`]).
    pub fault_counts: [u64; DEVICES],
    /// Device calls, per device.
    pub calls: [u64; DEVICES],
    /// Frames that ended in each navigation mode: aligning, driving, arrived, safed.
    pub mode_frames: [u64; 5],
    /// Episodes that reached driving, arrived, safed.
    pub episodes_reached: [u64; 3],
    /// Frames inside garbage bursts.
    pub garbage_frames: u64,
    /// Motor commands received, and refused by the fuzzed device.
    pub commands: (u64, u64),
    /// Stereo frames the flight software completed, and VO updates, over all episodes.
    pub stereo_frames: u64,
    /// VO relative poses delivered, over all episodes.
    pub vo_updates: u64,
    /// VO attempts that failed, over all episodes.
    pub vo_failures: u64,
    /// Wall time, s.
    pub wall_s: f64,
}

/// Frames an episode goes on after the navigator safed (checking that it stays safed and
/// stopped).
pub const SAFED_WATCH_FRAMES: u64 = 2_000;

/// Violations kept with details.
pub const MAX_KEPT: usize = 20;

fn mode_index(m: NavMode) -> usize {
    match m {
        NavMode::Aligning => 0,
        NavMode::Driving => 1,
        NavMode::Arrived => 2,
        NavMode::Safed => 3,
        NavMode::Stopped => 4,
    }
}

/// Counters that must never decrease, read after every frame.
fn monotonic_counters(fsw: &Fsw<FuzzPlatform>) -> Vec<u64> {
    let state = fsw.state();
    let exec = fsw.executive();
    let nav = fsw.nav().counters();
    let mut v: Vec<u64> = exec.groups().iter().map(|g| g.runs).collect();
    v.push(exec.cycle_slips());
    v.push(exec.clock_faults());
    for h in &state.health {
        v.extend([h.good, h.errors, h.stale, h.time_backwards, h.invalid].map(u64::from));
    }
    v.extend(
        [
            state.stereo_frames,
            state.telemetry_dropped,
            state.commands_sent,
            state.commands_refused,
            nav.kin_tested,
            nav.kin_rejected,
            nav.zupts,
            nav.vo_updates,
            nav.vo_fused,
            nav.vo_failures,
        ]
        .map(u64::from),
    );
    v
}

fn ekf_finite(fsw: &Fsw<FuzzPlatform>) -> Result<(), String> {
    let Some(ekf) = fsw.nav().ekf() else {
        return Ok(());
    };
    let x = ekf.state();
    let q = x.q_nr.quaternion();
    let finite = x.p_n.iter().all(|v| v.is_finite())
        && x.v_n.iter().all(|v| v.is_finite())
        && x.b_g.iter().all(|v| v.is_finite())
        && x.b_a.iter().all(|v| v.is_finite())
        && q.coords.iter().all(|v| v.is_finite());
    if !finite {
        return Err(format!(
            "state p_n {:?} v_n {:?} b_g {:?} b_a {:?} q {:?}",
            x.p_n.as_slice(),
            x.v_n.as_slice(),
            x.b_g.as_slice(),
            x.b_a.as_slice(),
            q.coords.as_slice()
        ));
    }
    let p = ekf.covariance();
    if let Some(k) = p.iter().position(|v| !v.is_finite()) {
        let n = p.nrows();
        return Err(format!(
            "covariance ({}, {}) = {} (column-major entry {k})",
            k % n,
            k / n,
            p[(k % n, k / n)]
        ));
    }
    Ok(())
}

/// Run the fuzzer; `progress` is called about every million frames.
pub fn run(config: FuzzConfig, mut progress: impl FnMut(&FuzzReport)) -> FuzzReport {
    let start = std::time::Instant::now();
    let mut report = FuzzReport::default();
    let mut plan = Rng::new(config.seed ^ 0x5DEE_CE66_D1CE_4E5B);
    let limits = fsw::kinematics::ROCKY8.limits;
    let mut next_progress = 1_000_000;
    while report.frames < config.frames {
        let episode = report.episodes;
        report.episodes += 1;
        // The episode: start pose, path, sun, length.
        let start_n = [
            plan.uniform(-50.0, 50.0),
            plan.uniform(-50.0, 50.0),
            plan.uniform(-1.0, 1.0),
        ];
        let yaw = plan.uniform(-std::f64::consts::PI, std::f64::consts::PI);
        let sun = SunEphemeris::from_site(
            plan.uniform(-30.0, 30.0),
            plan.uniform(0.0, 360.0),
            plan.uniform(9.0, 15.0),
        );
        let mut path = vec![[start_n[0], start_n[1]]];
        let (mut heading, mut p) = (yaw, [start_n[0], start_n[1]]);
        for _ in 0..plan.range(1, 4) {
            let len = plan.uniform(0.3, 2.0);
            p = [p[0] + len * heading.cos(), p[1] + len * heading.sin()];
            path.push(p);
            heading += plan.uniform(-1.5, 1.5);
        }
        let episode_frames = plan.range(4_000, 60_000).min(config.frames - report.frames);
        let shared: SharedRc = Rc::new(RefCell::new(Shared::new(
            plan.next_u64(),
            yaw,
            sun,
            (limits.wheel_rate_rad_s, limits.steer_rad),
        )));
        shared.borrow_mut().tracing = config.trace;
        let devices = Devices::<FuzzPlatform> {
            clock: FuzzClock::new(shared.clone()),
            imu: FuzzImu::new(shared.clone()),
            mobility: FuzzMobility::new(shared.clone()),
            camera: FuzzCamera::new(shared.clone(), config.vo),
            sun: FuzzSun::new(shared.clone()),
            power: FuzzPower::new(shared.clone()),
            telemetry: FuzzTelemetry::new(shared.clone()),
            image_memory: fsw::rectify::ImageMemory {
                map: Vec::new(),
                left: Vec::new(),
                right: Vec::new(),
            },
        };
        let mut fsw_config = FswConfig::rocky8(start_n, yaw);
        fsw_config.nav.filter.ekf.sun = Some(sun);
        let mut fsw = match Fsw::new(devices, &fsw_config, &path) {
            Ok(f) => Box::new(f),
            Err(e) => panic!("the flight software refused a valid configuration: {e:?}"),
        };
        if config.vo {
            fsw.start_vo();
        }
        // Phases: a plausible stretch long enough to align first, then bursts.
        let mut phase_left = plan.range(1_500, 8_000);
        let mut in_burst = false;
        let mut counters = monotonic_counters(&fsw);
        let mut kept_energy: Option<f64> = None;
        let mut prev_mode = fsw.nav().mode();
        let mut reached = [false; 3];
        let mut stop_episode = false;
        let mut safed_frames = 0u64;
        for f in 0..episode_frames {
            if phase_left == 0 {
                in_burst = !in_burst;
                let mut s = shared.borrow_mut();
                if in_burst {
                    phase_left = if plan.chance(0.1) {
                        plan.range(200, 3_000)
                    } else {
                        plan.range(1, 200)
                    };
                    let intensity = [0.02, 0.2, 0.5, 1.0][plan.below(4) as usize];
                    let mask = plan.range(1, 1 << DEVICES);
                    for (d, g) in s.garbage.iter_mut().enumerate() {
                        *g = if mask & (1 << d) != 0 { intensity } else { 0.0 };
                    }
                } else {
                    phase_left = plan.range(50, 3_000);
                    s.garbage = [0.0; DEVICES];
                }
            }
            phase_left -= 1;
            if in_burst {
                report.garbage_frames += 1;
            }
            {
                let mut s = shared.borrow_mut();
                s.advance();
                s.must_stand = matches!(prev_mode, NavMode::Safed | NavMode::Stopped);
            }
            let tick = catch_unwind(AssertUnwindSafe(|| fsw.tick()));
            let frame = report.frames;
            report.frames += 1;
            let mut found: Vec<(ViolationKind, String)> = Vec::new();
            let mode = match &tick {
                Ok(_) => fsw.nav().mode(),
                Err(_) => prev_mode,
            };
            match tick {
                Err(e) => {
                    let msg = e
                        .downcast_ref::<&str>()
                        .map(|s| s.to_string())
                        .or_else(|| e.downcast_ref::<String>().cloned())
                        .unwrap_or_default();
                    found.push((ViolationKind::Panic, msg));
                    stop_episode = true;
                }
                Ok(r) => {
                    if r.tick != f {
                        found.push((
                            ViolationKind::CountersInconsistent,
                            format!("frame report tick {} at frame {f}", r.tick),
                        ));
                    }
                    let now = monotonic_counters(&fsw);
                    if let Some(k) = now.iter().zip(&counters).position(|(a, b)| a < b) {
                        found.push((
                            ViolationKind::CountersInconsistent,
                            format!("counter {k}: {} -> {}", counters[k], now[k]),
                        ));
                    }
                    counters = now;
                    let kept = fsw.state().power.map(|p| p.energy_used_j);
                    if let Some(p) = fsw.state().power {
                        let plausible = p.energy_used_j.is_finite()
                            && p.bus_power_w.is_finite()
                            && p.energy_used_j >= 0.0
                            && p.bus_power_w >= 0.0
                            && kept_energy.is_none_or(|e| p.energy_used_j >= e);
                        if !plausible {
                            found.push((
                                ViolationKind::PowerImplausible,
                                format!("{p:?} after {kept_energy:?} J"),
                            ));
                        }
                    }
                    kept_energy = kept.or(kept_energy);
                    if let Err(detail) = ekf_finite(&fsw) {
                        if mode != NavMode::Safed {
                            found.push((ViolationKind::EkfNotFinite, detail));
                        }
                    }
                    if prev_mode == NavMode::Safed && mode != NavMode::Safed {
                        found.push((ViolationKind::SafedNotLatched, format!("{mode:?}")));
                    }
                    // A fault-protection stop is latched too (or escalates to Safed).
                    if prev_mode == NavMode::Stopped
                        && !matches!(mode, NavMode::Stopped | NavMode::Safed)
                    {
                        found.push((ViolationKind::SafedNotLatched, format!("{mode:?}")));
                    }
                }
            }
            {
                let mut s = shared.borrow_mut();
                for bad in s.bad_commands.drain(..) {
                    let c = bad.command;
                    let in_limits = c
                        .wheel_rate_rad_s
                        .iter()
                        .all(|r| r.is_finite() && r.abs() <= limits.wheel_rate_rad_s + 1e-9)
                        && c.steer_angle_rad
                            .iter()
                            .all(|a| a.is_finite() && a.abs() <= limits.steer_rad + 1e-9);
                    let kind = if in_limits {
                        ViolationKind::MovingWhileSafed
                    } else {
                        ViolationKind::CommandOutOfLimits
                    };
                    found.push((kind, format!("{c:?}")));
                }
            }
            report.mode_frames[mode_index(mode)] += 1;
            match mode {
                NavMode::Driving => reached[0] = true,
                NavMode::Arrived => reached[1] = true,
                NavMode::Safed => reached[2] = true,
                NavMode::Aligning | NavMode::Stopped => {}
            }
            if !found.is_empty() {
                report.violations += found.len() as u64;
                let (garbage, trace) = {
                    let s = shared.borrow();
                    let trace = s
                        .trace
                        .iter()
                        .map(|(t, d, a)| format!("t={t} us {d}: {a}"))
                        .collect::<Vec<_>>();
                    (s.garbage, trace)
                };
                for (kind, detail) in found {
                    if report.first.len() < MAX_KEPT {
                        report.first.push(Violation {
                            kind,
                            episode,
                            frame_in_episode: f,
                            frame,
                            garbage,
                            mode,
                            detail,
                            trace: trace.clone(),
                        });
                    }
                }
                // One finding per episode is enough: the state is suspect from here on.
                stop_episode = true;
            }
            // Safed and a fault-protection stop are latched: watch them for a while (no motion,
            // they stay), then start a new episode so that the frames keep exercising the
            // drive.
            if matches!(mode, NavMode::Safed | NavMode::Stopped) {
                safed_frames += 1;
                if safed_frames > SAFED_WATCH_FRAMES {
                    stop_episode = true;
                }
            }
            prev_mode = mode;
            if report.frames >= next_progress {
                next_progress += 1_000_000;
                report.wall_s = start.elapsed().as_secs_f64();
                progress(&report);
            }
            if stop_episode {
                break;
            }
        }
        for (k, n) in reached.iter().enumerate() {
            report.episodes_reached[k] += u64::from(*n);
        }
        let s = shared.borrow();
        for d in 0..DEVICE_NAMES.len() {
            report.fault_counts[d] += s.fault_counts[d];
            report.calls[d] += s.calls[d];
        }
        report.commands.0 += s.commands;
        report.commands.1 += s.commands_refused;
        report.stereo_frames += u64::from(fsw.state().stereo_frames);
        report.vo_updates += u64::from(fsw.nav().counters().vo_updates);
        report.vo_failures += u64::from(fsw.nav().counters().vo_failures);
    }
    report.wall_s = start.elapsed().as_secs_f64();
    report
}

impl FuzzReport {
    /// Human-readable summary.
    pub fn summary(&self, config: &FuzzConfig) -> String {
        use std::fmt::Write;
        let mut out = String::new();
        let rate = self.frames as f64 / self.wall_s.max(1e-9);
        let _ = writeln!(
            out,
            "fuzz-hal: seed {} vo {}: {} frames ({:.1} h of flight time) in {} episodes, {:.1} s, {:.0} frames/s",
            config.seed,
            config.vo,
            self.frames,
            self.frames as f64 * 0.005 / 3600.0,
            self.episodes,
            self.wall_s,
            rate
        );
        let _ = writeln!(
            out,
            "  frames in garbage bursts: {} ({:.1} %); frames aligning/driving/arrived/safed/stopped: {:?}",
            self.garbage_frames,
            100.0 * self.garbage_frames as f64 / self.frames.max(1) as f64,
            self.mode_frames
        );
        let _ = writeln!(
            out,
            "  episodes that drove / arrived / safed: {:?} of {}; motor commands {} (refused {}); stereo frames {}, VO poses {} (failed {})",
            self.episodes_reached, self.episodes, self.commands.0, self.commands.1, self.stereo_frames, self.vo_updates, self.vo_failures
        );
        for (d, name) in DEVICE_NAMES.iter().enumerate() {
            let _ = writeln!(
                out,
                "  {name:<9} calls {:>11}  garbage answers {:>10}",
                self.calls[d], self.fault_counts[d]
            );
        }
        let _ = writeln!(out, "  violations: {}", self.violations);
        for v in &self.first {
            let _ = writeln!(
                out,
                "  - {:?} at frame {} (episode {}, frame {} of it), mode {:?}, garbage {:?}: {}",
                v.kind, v.frame, v.episode, v.frame_in_episode, v.mode, v.garbage, v.detail
            );
            for line in &v.trace {
                let _ = writeln!(out, "      {line}");
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A short run is deterministic, reaches driving, calls every device and gives garbage to the
    /// frequently called ones.
    #[test]
    fn short_run_is_deterministic_and_clean() {
        let config = FuzzConfig {
            frames: 60_000,
            seed: 3,
            vo: true,
            trace: false,
        };
        let a = run(config, |_| {});
        let b = run(config, |_| {});
        assert_eq!(a.frames, 60_000);
        assert_eq!(a.fault_counts, b.fault_counts);
        assert_eq!(a.mode_frames, b.mode_frames);
        assert!(a.calls.iter().all(|&n| n > 0), "{a:?}");
        let clock_imu_mobility_telemetry = [0, 1, 2, 5];
        assert!(
            clock_imu_mobility_telemetry
                .iter()
                .all(|&d| a.fault_counts[d] > 0),
            "{a:?}"
        );
        assert!(a.mode_frames[1] > 0, "never drove: {a:?}");
    }
}
