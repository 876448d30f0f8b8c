//! `sim-host replay`: replay a call tape through the flight software on the host, with the
//! replay devices of `rover_replay` and the replay driver the rover-CPU image uses
//! ([`fsw_image::flight_replay::Replay`]), and print the per-frame digest lines the image prints.

use fsw::flight::Platform;
use fsw_image::flight_replay::{build_fsw, FlightSetup, Replay};
use rover_hal::IMAGE_PIXELS;
use rover_replay::devices::{
    ReplayClock, ReplayImu, ReplayMobility, ReplayPower, ReplayStereo, ReplaySun, ReplayTelemetry,
    ZeroCounter,
};
use rover_replay::tape::SliceSource;
use rover_replay::{Divergence, Player};
use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;

type Tape = Rc<RefCell<Player>>;

/// The replay devices on the host (execution counter always 0).
pub struct HostReplayPlatform<'a>(std::marker::PhantomData<&'a ()>);

impl<'a> Platform for HostReplayPlatform<'a> {
    type Clock = ReplayClock<Tape, ZeroCounter>;
    type Imu = ReplayImu<Tape>;
    type Mobility = ReplayMobility<Tape>;
    type Camera = ReplayStereo<Tape, SliceSource<'a>, Vec<u8>>;
    type Sun = ReplaySun<Tape>;
    type Power = ReplayPower<Tape>;
    type Telemetry = ReplayTelemetry<Tape>;
    type ImageMemory = crate::devices::HostImageMemory;
}

/// Result of a host replay.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayOutcome {
    /// Digest of every replayed frame.
    pub digests: Vec<u64>,
    /// Frames whose digest differs from the recording's.
    pub mismatches: u64,
    /// Running digest over all frames.
    pub running: u64,
    /// What stopped the replay early, if anything.
    pub divergence: Option<Divergence>,
    /// The printed lines (progress every 200 frames and the summary).
    pub text: String,
}

impl ReplayOutcome {
    /// True when every frame matched the recording and nothing diverged.
    pub fn passed(&self) -> bool {
        self.divergence.is_none() && self.mismatches == 0 && !self.digests.is_empty()
    }
}

/// Replay `tape` (the bytes of a tape file) through the flight software.
pub fn replay(tape: &[u8]) -> anyhow::Result<ReplayOutcome> {
    let mut replay = Replay::open(SliceSource::new(tape))
        .map_err(|e| anyhow::anyhow!("not a call tape: {e:?}"))?;
    let header = *replay.header();
    let player: Tape = Rc::new(RefCell::new(Player::new()));
    let slots = [
        [vec![0u8; IMAGE_PIXELS], vec![0u8; IMAGE_PIXELS]],
        [vec![0u8; IMAGE_PIXELS], vec![0u8; IMAGE_PIXELS]],
    ];
    let devices = fsw::flight::Devices::<HostReplayPlatform<'_>> {
        clock: ReplayClock::new(player.clone(), ZeroCounter),
        imu: ReplayImu::new(player.clone()),
        mobility: ReplayMobility::new(player.clone()),
        camera: ReplayStereo::new(
            player.clone(),
            SliceSource::new(tape),
            slots,
            header.calibration,
        )
        .with_lens(header.lens),
        sun: ReplaySun::new(player.clone()),
        power: ReplayPower::new(player.clone(), header.has_power()),
        telemetry: ReplayTelemetry::new(player.clone()),
        image_memory: crate::devices::host_image_memory(),
    };
    let mut fsw = build_fsw(devices, &FlightSetup::from_header(&header))
        .map_err(|e| anyhow::anyhow!("flight software refused its configuration: {e:?}"))?;
    fsw.start_vo();
    let mut text = String::new();
    let mut digests = Vec::new();
    while replay
        .load(&player)
        .map_err(|e| anyhow::anyhow!("bad tape after {} frames: {e:?}", replay.frames()))?
    {
        fsw.tick();
        match replay.finish(&player, &fsw, &mut text) {
            Ok(check) => digests.push(check.digest),
            Err(_) => break,
        }
    }
    replay.summary(&mut text);
    Ok(ReplayOutcome {
        digests,
        mismatches: replay.mismatches(),
        running: replay.running(),
        divergence: replay.divergence(),
        text,
    })
}

/// `sim-host replay TAPE [--digests FILE]`.
#[derive(Debug, Clone, clap::Args)]
pub struct ReplayArgs {
    /// Tape file written by `record`.
    pub tape: PathBuf,
    /// Also write the digest of every frame, one hex value per line, to this file.
    #[arg(long)]
    pub digests: Option<PathBuf>,
}

/// Run `sim-host replay`: print the digest lines; fails unless every frame matches the
/// recording.
pub fn main(args: ReplayArgs) -> anyhow::Result<()> {
    let tape = std::fs::read(&args.tape)?;
    let outcome = replay(&tape)?;
    print!("{}", outcome.text);
    if let Some(file) = args.digests {
        let lines: String = outcome
            .digests
            .iter()
            .map(|d| format!("{d:016x}\n"))
            .collect();
        std::fs::write(file, lines)?;
    }
    if !outcome.passed() {
        anyhow::bail!("the replay does not reproduce the recording");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::replay;
    use crate::commands::record::{record, RecordOptions};
    use crate::scenario::Scenario;
    use rover_replay::tape::{decode_record, encode_record, HEADER_BYTES, MAX_RECORD_BYTES};
    use rover_replay::{Call, CallKind, Divergence, Record};

    fn recording(seconds: f64) -> crate::commands::record::Recording {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../scenarios/slope-10-cross.toml"
        );
        let scenario = match Scenario::load(std::path::Path::new(path)) {
            Ok(s) => s,
            Err(e) => panic!("scenario: {e}"),
        };
        match record(
            &scenario,
            RecordOptions {
                seconds,
                seed: None,
                render: true,
            },
        ) {
            Ok(r) => r,
            Err(e) => panic!("record: {e}"),
        }
    }

    /// Offsets of every record of a tape (walking the format by hand).
    fn records(tape: &[u8]) -> Vec<(usize, Record)> {
        let mut out = Vec::new();
        let mut pos = HEADER_BYTES;
        while pos + 2 <= tape.len() {
            let (tag, len) = (tape[pos], usize::from(tape[pos + 1]));
            let record = match decode_record(tag, &tape[pos + 2..pos + 2 + len]) {
                Ok(r) => r,
                Err(e) => panic!("record at {pos}: {e:?}"),
            };
            out.push((pos, record));
            pos += 2 + len;
            if let Record::Images(i) = record {
                pos += (i.left_len + i.right_len) as usize;
            }
        }
        out
    }

    #[test]
    fn host_replay_reproduces_the_recording_digests() {
        // 6 s: captures start after the 2 s alignment (capture policy, docs/vo.md), the rover
        // waits for VO's first keyframe, and two stereo pairs need the first 0.10 m of travel
        // after it.
        let rec = recording(6.0);
        assert_eq!(rec.digests.len(), 1200);
        assert!(rec.image_pairs >= 2, "{} stereo pairs", rec.image_pairs);
        let outcome = match replay(&rec.tape) {
            Ok(o) => o,
            Err(e) => panic!("replay: {e}"),
        };
        assert!(outcome.passed(), "{}", outcome.text);
        assert_eq!(outcome.digests, rec.digests);
        assert!(outcome.text.contains("replay end frames 1200 mismatches 0"));
        // Recording is deterministic.
        assert_eq!(recording(6.0).tape, rec.tape);
    }

    #[test]
    fn tampered_tapes_are_caught() {
        let rec = recording(0.5);
        let all = records(&rec.tape);

        // A changed IMU reading: same calls, different outputs (digest mismatch).
        let Some((pos, imu)) = all
            .iter()
            .find(|(_, r)| matches!(r, Record::Call(Call::ImuRead(Ok(_)))))
            .copied()
        else {
            panic!("no IMU read on the tape")
        };
        let Record::Call(Call::ImuRead(Ok(mut sample))) = imu else {
            unreachable!()
        };
        sample.gyro_rad_s[0] += 1e-9;
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let n = match encode_record(&Record::Call(Call::ImuRead(Ok(sample))), &mut buf) {
            Ok(n) => n,
            Err(e) => panic!("{e:?}"),
        };
        let mut tape = rec.tape.clone();
        tape[pos..pos + n].copy_from_slice(&buf[..n]);
        let outcome = match replay(&tape) {
            Ok(o) => o,
            Err(e) => panic!("replay: {e}"),
        };
        assert!(outcome.mismatches > 0 && outcome.divergence.is_none());
        assert!(!outcome.passed());

        // A missing sun read, and a missing power read (RG4, recorded since tape version 4):
        // the flight code makes a call the tape does not have next.
        let drop_first = |is: &dyn Fn(&Record) -> bool, kind: CallKind| {
            let Some((pos, _)) = all.iter().find(|(_, r)| is(r)).copied() else {
                panic!("no {kind:?} on the tape")
            };
            let len = 2 + usize::from(rec.tape[pos + 1]);
            let mut tape = rec.tape.clone();
            tape.drain(pos..pos + len);
            let outcome = match replay(&tape) {
                Ok(o) => o,
                Err(e) => panic!("replay: {e}"),
            };
            assert!(
                matches!(
                    outcome.divergence,
                    Some(Divergence::UnexpectedCall { got, .. }) if got == kind
                ),
                "{:?}",
                outcome.divergence
            );
            assert!(!outcome.passed());
        };
        drop_first(
            &|r| matches!(r, Record::Call(Call::SunRead(_))),
            CallKind::SunRead,
        );
        drop_first(
            &|r| matches!(r, Record::Call(Call::PowerRead(Ok(_)))),
            CallKind::PowerRead,
        );
    }
}
