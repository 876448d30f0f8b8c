//! Replay of a call tape through the flight software, and the digest of its outputs.
//!
//! ## Digest of a frame
//!
//! [`frame_digest`] is FNV-1a 64 ([`rover_replay::Digest`]) over, in this order:
//!
//! 1. the frame's tick;
//! 2. selected public flight state from [`Fsw::state`] ([`digest_frame`]);
//! 3. every mobility output the flight code issued in the frame, in call order (the bit
//!    patterns of each [`rover_hal::MobilityCommand`], or a stop marker);
//! 4. every telemetry record it sent, in call order;
//! 5. the count of outputs that did not fit in [`FrameOutputs`].
//!
//! **Timing-derived data is excluded**: the execution counter is not replayed (on the rover CPU
//! it is SysTick, on the host it is zero), so the executive's cycle-slip count and timing-fault
//! flag legitimately differ. They are left out of the flight state (`exec_status`) and out of
//! [`fsw::telemetry::FrameStatus`] records (`cycle_slips`, `timing_fault`); every other field is
//! digested.
//!
//! To digest more flight state (the navigation state being added to [`FlightState`]), add one
//! line to [`digest_frame`]: for example `h.f64s(state.ekf_covariance.as_slice());`.

use core::fmt::Write;
use fsw::flight::nav::Navigator;
use fsw::flight::{DeviceHealth, FrameStatus};
use fsw::flight::{Devices, FlightState, Fsw, FswConfig, FswError, Platform};
use fsw::telemetry::RecordKind;
use rover_replay::tape::{ByteSource, FrameMark, TapeReader, MAX_WAYPOINTS, NAV_PARAMS};
use rover_replay::{Digest, Divergence, FrameOutputs, MobilityOutput, TapeError, TapeHandle};

/// What the flight software is built with apart from its devices: the path and the start pose
/// (from the scenario for a replay, defaults for the rover standing still).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightSetup {
    /// Path waypoints (north, east), m; the first `waypoint_count` are used.
    pub waypoints: [[f64; 2]; MAX_WAYPOINTS],
    /// Number of waypoints.
    pub waypoint_count: usize,
    /// Start pose: north, east, down (m), roll, pitch, yaw (rad).
    pub start_pose: [f64; 6],
    /// Scenario flight parameters ([`nav_params`]); `None`: the defaults.
    pub nav_params: Option<[f64; NAV_PARAMS]>,
}

impl FlightSetup {
    /// A rover standing still at the origin facing north with no path, under the fixed sun of
    /// the still devices (30 deg up, due north: local noon at 60 deg S on the equinox), so that
    /// the alignment takes its heading from the sun as on a real drive.
    pub fn still() -> Self {
        let mut config = FswConfig::rocky8([0.0; 3], 0.0);
        config.nav.filter.ekf.sun = Some(fsw::estimation::ephemeris::SunEphemeris::from_site(
            -60.0, 0.0, 12.0,
        ));
        Self {
            waypoints: [[0.0; 2]; MAX_WAYPOINTS],
            waypoint_count: 0,
            start_pose: [0.0; 6],
            nav_params: Some(nav_params(&config)),
        }
    }

    /// The setup recorded in a tape's header.
    pub fn from_header(header: &rover_replay::TapeHeader) -> Self {
        Self {
            waypoints: header.waypoints,
            waypoint_count: usize::from(header.waypoint_count).min(MAX_WAYPOINTS),
            start_pose: header.start_pose,
            nav_params: Some(header.nav_params),
        }
    }
}

/// The drive-dependent flight parameters a tape carries ([`rover_replay::TapeHeader::nav_params`]):
/// the mission inputs on top of the nominal profile [`FswConfig::rocky8`]: sun ephemeris
/// (latitude, declination, hour angle at clock zero, in use), cruise speed, slip compensation,
/// VO enabled, arrival tolerance, slip limit, position-sigma limit, 6 spare zeros. Nothing else of the configuration depends on the drive.
pub fn nav_params(config: &FswConfig) -> [f64; NAV_PARAMS] {
    let n = &config.nav;
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    let (lat, dec, h0) = match n.filter.ekf.sun {
        Some(e) => (e.latitude_rad, e.declination_rad, e.hour_angle_t0_rad),
        None => (0.0, 0.0, 0.0),
    };
    let mut p = [0.0; NAV_PARAMS];
    let values = [
        lat,
        dec,
        h0,
        flag(n.filter.ekf.sun.is_some()),
        n.drive.guidance.cruise_speed_m_s,
        flag(n.drive.slip_compensation),
        flag(n.vo.enabled),
        n.drive.protection.arrival_tolerance_m,
        n.drive.protection.slip_limit,
        n.drive.protection.max_position_sigma_m,
    ];
    for (slot, v) in p.iter_mut().zip(values) {
        *slot = v;
    }
    p
}

/// The flight configuration for `setup`: the nominal profile [`FswConfig::rocky8`] at the
/// planned start pose with the mission inputs of [`nav_params`] (a still setup keeps the
/// defaults).
pub fn flight_config(setup: &FlightSetup) -> FswConfig {
    let [n, e, d, _, _, yaw] = setup.start_pose;
    let mut config = FswConfig::rocky8([n, e, d], yaw);
    let Some(p) = setup.nav_params else {
        return config;
    };
    let nav = &mut config.nav;
    nav.filter.ekf.sun = (p[3] != 0.0).then_some(fsw::estimation::ephemeris::SunEphemeris {
        latitude_rad: p[0],
        declination_rad: p[1],
        hour_angle_t0_rad: p[2],
    });
    nav.drive.guidance.cruise_speed_m_s = p[4];
    nav.drive.slip_compensation = p[5] != 0.0;
    nav.vo.enabled = p[6] != 0.0;
    nav.drive.protection.arrival_tolerance_m = p[7];
    nav.drive.protection.slip_limit = p[8];
    nav.drive.protection.max_position_sigma_m = p[9];
    config
}

/// The path of `setup`: its waypoints, or a 1 m path north for a setup without a path (a
/// still rover: guidance commands, the still devices do not move).
fn setup_path(setup: &FlightSetup) -> &[[f64; 2]] {
    let count = setup.waypoint_count.min(MAX_WAYPOINTS);
    match setup.waypoints.get(..count) {
        Some(w) if count >= 2 => w,
        _ => &[[0.0, 0.0], [1.0, 0.0]],
    }
}

/// Build the flight software around `devices` for `setup` (host replay; a value of about
/// 220 KB). Identical to [`init_fsw`] on [`Fsw::EMPTY`], the rover-CPU image's way.
pub fn build_fsw<P: Platform>(
    devices: Devices<P>,
    setup: &FlightSetup,
) -> Result<Fsw<P>, FswError> {
    Fsw::new(devices, &flight_config(setup), setup_path(setup))
}

/// Initialise the flight software `fsw` in place around `devices` for `setup` ([`Fsw::init`]):
/// the rover-CPU image's construction of its static. A setup without a path gets a 1 m path
/// north (a still rover: guidance commands, the still devices do not move).
pub fn init_fsw<P: Platform>(
    fsw: &mut Fsw<P>,
    devices: Devices<P>,
    setup: &FlightSetup,
) -> Result<(), FswError> {
    fsw.init(devices, &flight_config(setup), setup_path(setup))
}

/// Selected public flight state, the navigation state (`nav`: EKF nominal state and full
/// covariance, clone count, slip vector, gate, rover command, counters, dead reckoning) and the
/// frame's outputs, into `h` (see the module doc). Timing-derived state (`exec_status`) is
/// excluded.
pub fn digest_frame(
    h: &mut Digest,
    state: &FlightState,
    nav: Option<&Navigator>,
    outputs: &FrameOutputs,
) {
    if let Some(nav) = nav {
        digest_nav(h, nav);
    }
    h.put(&state.imu)
        .put(&state.joints)
        .put(&state.sun)
        .put(&state.power)
        .put(&state.capture_pending_t_us)
        .put(&state.last_capture_t_us);
    for d in &state.health {
        digest_health(h, d);
    }
    h.u32(state.stereo_frames).u32(state.telemetry_dropped);
    for m in outputs.mobility() {
        match m {
            MobilityOutput::Command(c) => h.u8(1).put(c),
            MobilityOutput::Stop => h.u8(2),
        };
    }
    for record in outputs.telemetry() {
        digest_telemetry(h, record);
    }
    h.u32(outputs.dropped());
}

/// Digest of frame `tick`: the tick, then [`digest_frame`].
pub fn frame_digest(
    tick: u64,
    state: &FlightState,
    nav: Option<&Navigator>,
    outputs: &FrameOutputs,
) -> u64 {
    let mut h = Digest::new();
    h.u64(tick);
    digest_frame(&mut h, state, nav, outputs);
    h.value()
}

fn f64s(h: &mut Digest, values: &[f64]) {
    for v in values {
        h.u64(v.to_bits());
    }
}

fn digest_nav(h: &mut Digest, nav: &Navigator) {
    h.u8(nav.mode() as u8);
    if let Some(ekf) = nav.ekf() {
        let x = ekf.state();
        h.u64(x.t_us);
        f64s(h, x.q_nr.coords.as_slice());
        f64s(h, x.b_g.as_slice());
        f64s(h, x.v_n.as_slice());
        f64s(h, x.b_a.as_slice());
        f64s(h, x.p_n.as_slice());
        f64s(h, ekf.covariance().as_slice());
        h.u32(ekf.clone_count() as u32);
    }
    let slip = nav.slip();
    let gate = nav.gate();
    let cmd = nav.command();
    let kin3d = nav.kin3d();
    f64s(
        h,
        &[
            slip.x_m,
            slip.y_m,
            slip.phi_rad,
            gate.d2,
            cmd.x_dot_m_s,
            cmd.y_dot_m_s,
            cmd.yaw_rate_rad_s,
        ],
    );
    f64s(h, kin3d.p_n.as_slice());
    f64s(h, &nav.kin2d());
    let c = nav.counters();
    for v in [
        c.kin_tested,
        c.kin_rejected,
        c.kin_held,
        c.kin_ungated,
        c.zupts,
        c.vo_updates,
        c.vo_fused,
        c.vo_failures,
        c.sun_applied,
        c.ekf_errors,
        c.command_errors,
    ] {
        h.u32(v);
    }
}

fn digest_health(h: &mut Digest, d: &DeviceHealth) {
    h.u32(d.good)
        .u32(d.errors)
        .u32(d.stale)
        .u32(d.time_backwards)
        .u32(d.invalid);
}

/// A telemetry record: [`FrameStatus`] without its timing-derived fields (`cycle_slips`,
/// `timing_fault`); any other record (or one that does not decode) byte for byte.
fn digest_telemetry(h: &mut Digest, record: &[u8]) {
    let status = match record.split_first() {
        Some((tag, body)) if *tag == RecordKind::FrameStatus as u8 => {
            postcard::from_bytes::<FrameStatus>(body).ok()
        }
        _ => None,
    };
    match status {
        Some(s) => {
            h.u8(RecordKind::FrameStatus as u8).u64(s.tick);
            for d in &s.health {
                digest_health(h, d);
            }
            h.u32(s.stereo_frames)
                .u32(s.telemetry_dropped)
                .f64(s.energy_used_j)
                .u32(s.bus_power_w.to_bits());
        }
        None => {
            h.u8(0xFF).u32(record.len() as u32).bytes(record);
        }
    }
}

/// Frames between two progress lines of [`Replay`].
pub const REPORT_EVERY: u64 = 200;

/// Outcome of one replayed frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameCheck {
    /// Tick of the frame (from the tape).
    pub tick: u64,
    /// Digest of the replayed frame.
    pub digest: u64,
    /// Digest the recording run computed.
    pub recorded: u64,
}

/// The replay driver shared by the host and the rover CPU: loads a frame's calls into the
/// player before the caller ticks the flight software, then checks the frame.
///
/// Use: `while replay.load(&tape)? { fsw.tick(); replay.finish(&tape, &fsw, out)?; }` then
/// [`Replay::summary`].
#[derive(Debug)]
pub struct Replay<S: ByteSource> {
    reader: TapeReader<S>,
    pending: Option<(u64, u64)>,
    frames: u64,
    mismatches: u64,
    first_mismatch: Option<u64>,
    running: Digest,
    divergence: Option<Divergence>,
}

impl<S: ByteSource> Replay<S> {
    /// A replay of the tape in `source` (its header is read).
    pub fn open(source: S) -> Result<Self, TapeError> {
        Ok(Self {
            reader: TapeReader::open(source)?,
            pending: None,
            frames: 0,
            mismatches: 0,
            first_mismatch: None,
            running: Digest::new(),
            divergence: None,
        })
    }

    /// The tape's header.
    pub fn header(&self) -> &rover_replay::TapeHeader {
        self.reader.header()
    }

    /// Queue the next frame's calls in the player. `Ok(false)` at the end of the tape or after
    /// a divergence.
    pub fn load<H: TapeHandle>(&mut self, tape: &H) -> Result<bool, TapeError> {
        if self.divergence.is_some() {
            return Ok(false);
        }
        let reader = &mut self.reader;
        let mark = tape
            .with(|p| {
                p.begin_frame();
                reader.load_frame(p)
            })
            .ok_or(TapeError::Io)??;
        match mark {
            FrameMark::Frame { tick, digest } => {
                self.pending = Some((tick, digest));
                Ok(true)
            }
            FrameMark::End => Ok(false),
        }
    }

    /// After the tick: end the frame in the player, digest the flight software's state and
    /// outputs, compare with the recording and write a progress line every
    /// [`REPORT_EVERY`] frames.
    pub fn finish<P: Platform, H: TapeHandle, W: Write>(
        &mut self,
        tape: &H,
        fsw: &Fsw<P>,
        out: &mut W,
    ) -> Result<FrameCheck, Divergence> {
        let (tick, recorded) = self.pending.take().unwrap_or((self.frames, 0));
        let result = tape
            .with(|p| {
                p.end_frame()?;
                Ok(frame_digest(
                    tick,
                    fsw.state(),
                    Some(fsw.nav()),
                    p.outputs(),
                ))
            })
            .unwrap_or(Err(Divergence::Tape(TapeError::Io)));
        let digest = match result {
            Ok(d) => d,
            Err(d) => {
                self.divergence = Some(d);
                return Err(d);
            }
        };
        self.frames += 1;
        self.running.u64(digest);
        if digest != recorded {
            self.mismatches += 1;
            self.first_mismatch.get_or_insert(tick);
        }
        if self.frames % REPORT_EVERY == 0 {
            let _ = writeln!(
                out,
                "replay frame {tick} digest {digest:016x} running {:016x}",
                self.running.value()
            );
        }
        Ok(FrameCheck {
            tick,
            digest,
            recorded,
        })
    }

    /// Frames replayed.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Frames whose digest differed from the recording.
    pub fn mismatches(&self) -> u64 {
        self.mismatches
    }

    /// The running digest (over every frame's digest).
    pub fn running(&self) -> u64 {
        self.running.value()
    }

    /// The divergence that stopped the replay, if any.
    pub fn divergence(&self) -> Option<Divergence> {
        self.divergence
    }

    /// True when every frame matched and nothing diverged.
    pub fn passed(&self) -> bool {
        self.divergence.is_none() && self.mismatches == 0 && self.frames > 0
    }

    /// Write the final line: frames, mismatches, running digest, divergence.
    pub fn summary<W: Write>(&self, out: &mut W) {
        let _ = write!(
            out,
            "replay end frames {} mismatches {} running {:016x} first_mismatch ",
            self.frames,
            self.mismatches,
            self.running.value()
        );
        let _ = match self.first_mismatch {
            Some(t) => write!(out, "{t}"),
            None => write!(out, "none"),
        };
        let _ = match self.divergence {
            Some(d) => writeln!(out, " divergence {d:?}"),
            None => writeln!(out, " divergence none"),
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fsw::telemetry::{encode, MAX_RECORD_BYTES};
    use rover_hal::MobilityCommand;

    fn status_record(
        cycle_slips: u64,
        timing_fault: bool,
        tick: u64,
    ) -> ([u8; MAX_RECORD_BYTES], usize) {
        let status = FrameStatus {
            tick,
            cycle_slips,
            timing_fault,
            ..FrameStatus::default()
        };
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let n = match encode(RecordKind::FrameStatus, &status, &mut buf) {
            Ok(b) => b.len(),
            Err(e) => panic!("{e:?}"),
        };
        (buf, n)
    }

    fn digest(state: &FlightState, outputs: &FrameOutputs) -> u64 {
        frame_digest(7, state, None, outputs)
    }

    #[test]
    fn timing_derived_data_is_excluded_and_the_rest_counts() {
        let state = FlightState::default();
        let mut slipped = state.clone();
        slipped.exec_status = (12, true);
        let outputs = FrameOutputs::new();
        assert_eq!(digest(&state, &outputs), digest(&slipped, &outputs));

        let (a, n) = status_record(0, false, 3);
        let (b, m) = status_record(99, true, 3);
        let (c, k) = status_record(0, false, 4);
        let mut oa = FrameOutputs::new();
        oa.push_telemetry(&a[..n]);
        let mut ob = FrameOutputs::new();
        ob.push_telemetry(&b[..m]);
        let mut oc = FrameOutputs::new();
        oc.push_telemetry(&c[..k]);
        assert_eq!(digest(&state, &oa), digest(&state, &ob));
        assert_ne!(digest(&state, &oa), digest(&state, &oc));

        let mut moved = state.clone();
        moved.stereo_frames = 1;
        assert_ne!(digest(&state, &outputs), digest(&moved, &outputs));
        let mut commanded = FrameOutputs::new();
        commanded.push_mobility(MobilityOutput::Command(MobilityCommand {
            steer_angle_rad: [-0.0; 6],
            ..MobilityCommand::default()
        }));
        let mut commanded_zero = FrameOutputs::new();
        commanded_zero.push_mobility(MobilityOutput::Command(MobilityCommand::default()));
        assert_ne!(digest(&state, &commanded), digest(&state, &commanded_zero));
        assert_ne!(
            frame_digest(1, &state, None, &outputs),
            frame_digest(2, &state, None, &outputs)
        );
    }
}
