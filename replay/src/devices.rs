//! Replay devices: each HAL call returns the next recorded result of its kind from the
//! [`Player`](crate::Player); a call the tape does not have next latches a
//! [`Divergence`](crate::Divergence) and returns [`ErrorKind::Other`]. Commands and telemetry
//! records go to the frame's [`FrameOutputs`](crate::FrameOutputs) for the digest.

use crate::player::{Divergence, MobilityOutput, TapeHandle};
use crate::tape::{Call, CallKind, PayloadSource};
use rover_hal::{
    CaptureStatus, Clock, Error, ErrorKind, Imu, ImuSample, JointState, Mobility, MobilityCommand,
    Power, PowerReading, StereoCalibration, StereoCamera, StereoFrame, SunReading, SunSensor,
    Telemetry,
};

fn take<H: TapeHandle>(tape: &H, kind: CallKind) -> Option<Call> {
    tape.with(|p| p.take(kind)).flatten()
}

/// Clock: `now_us` from the tape, the execution counter from `counter` (not recorded: it feeds
/// timing telemetry only).
#[derive(Debug)]
pub struct ReplayClock<H, C> {
    tape: H,
    counter: C,
}

impl<H: TapeHandle, C: Clock> ReplayClock<H, C> {
    /// A clock replaying `tape`, counting with `counter`.
    pub fn new(tape: H, counter: C) -> Self {
        Self { tape, counter }
    }
}

impl<H: TapeHandle, C: Clock> Clock for ReplayClock<H, C> {
    type Error = ErrorKind;
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        match take(&self.tape, CallKind::ClockNow) {
            Some(Call::ClockNow(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        self.counter.counter().map_err(|e| e.kind())
    }
    fn counter_hz(&self) -> u64 {
        self.counter.counter_hz()
    }
}

/// An execution counter that always reads 0 (timing statistics all zero), for replays where
/// execution time does not matter.
#[derive(Debug, Clone, Copy, Default)]
pub struct ZeroCounter;

impl Clock for ZeroCounter {
    type Error = ErrorKind;
    /// Not a time source: always [`ErrorKind::Other`].
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        Err(ErrorKind::Other)
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        Ok(0)
    }
    fn counter_hz(&self) -> u64 {
        1_000_000_000
    }
}

/// IMU replaying `Imu::read`.
#[derive(Debug)]
pub struct ReplayImu<H> {
    tape: H,
}

impl<H: TapeHandle> ReplayImu<H> {
    /// An IMU replaying `tape`.
    pub fn new(tape: H) -> Self {
        Self { tape }
    }
}

impl<H: TapeHandle> Imu for ReplayImu<H> {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<ImuSample, ErrorKind> {
        match take(&self.tape, CallKind::ImuRead) {
            Some(Call::ImuRead(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
}

/// Mobility replaying joint reads and the results of commands and stops; the commands are
/// kept as outputs.
#[derive(Debug)]
pub struct ReplayMobility<H> {
    tape: H,
}

impl<H: TapeHandle> ReplayMobility<H> {
    /// Mobility replaying `tape`.
    pub fn new(tape: H) -> Self {
        Self { tape }
    }
}

impl<H: TapeHandle> Mobility for ReplayMobility<H> {
    type Error = ErrorKind;
    fn read_joints(&mut self) -> Result<JointState, ErrorKind> {
        match take(&self.tape, CallKind::JointsRead) {
            Some(Call::JointsRead(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
    fn command(&mut self, command: &MobilityCommand) -> Result<(), ErrorKind> {
        let out = MobilityOutput::Command(*command);
        let call = self
            .tape
            .with(|p| {
                p.outputs_mut().push_mobility(out);
                p.take(CallKind::MobilityCommand)
            })
            .flatten();
        match call {
            Some(Call::MobilityCommand(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
    fn stop(&mut self) -> Result<(), ErrorKind> {
        let call = self
            .tape
            .with(|p| {
                p.outputs_mut().push_mobility(MobilityOutput::Stop);
                p.take(CallKind::MobilityStop)
            })
            .flatten();
        match call {
            Some(Call::MobilityStop(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
}

/// Sun sensor replaying `SunSensor::read`.
#[derive(Debug)]
pub struct ReplaySun<H> {
    tape: H,
}

impl<H: TapeHandle> ReplaySun<H> {
    /// A sun sensor replaying `tape`.
    pub fn new(tape: H) -> Self {
        Self { tape }
    }
}

impl<H: TapeHandle> SunSensor for ReplaySun<H> {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<SunReading, ErrorKind> {
        match take(&self.tape, CallKind::SunRead) {
            Some(Call::SunRead(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
}

/// Power subsystem replaying `Power::read`.
#[derive(Debug)]
pub struct ReplayPower<H> {
    tape: H,
    recorded: bool,
}

impl<H: TapeHandle> ReplayPower<H> {
    /// A power subsystem replaying `tape`. `recorded`: the tape carries the power reads
    /// ([`crate::TapeHeader::has_power`]); a version-3 tape does not, and then every read
    /// answers [`ErrorKind::NotReady`] (no reading: not a fault for the flight software)
    /// without consuming a record.
    pub fn new(tape: H, recorded: bool) -> Self {
        Self { tape, recorded }
    }
}

impl<H: TapeHandle> Power for ReplayPower<H> {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<PowerReading, ErrorKind> {
        if !self.recorded {
            return Err(ErrorKind::NotReady);
        }
        match take(&self.tape, CallKind::PowerRead) {
            Some(Call::PowerRead(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
}

/// Telemetry sink replaying the results of `Telemetry::send`; the records are kept as outputs.
#[derive(Debug)]
pub struct ReplayTelemetry<H> {
    tape: H,
}

impl<H: TapeHandle> ReplayTelemetry<H> {
    /// A sink replaying `tape`.
    pub fn new(tape: H) -> Self {
        Self { tape }
    }
}

impl<H: TapeHandle> Telemetry for ReplayTelemetry<H> {
    type Error = ErrorKind;
    fn send(&mut self, record: &[u8]) -> Result<(), ErrorKind> {
        let call = self
            .tape
            .with(|p| {
                p.outputs_mut().push_telemetry(record);
                p.take(CallKind::TelemetrySend)
            })
            .flatten();
        match call {
            Some(Call::TelemetrySend(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
}

/// Stereo camera replaying trigger, poll, frame and release. The pixels of a pair are read from
/// the tape (through `payload`) when the poll that reported it ready is replayed, into the
/// spare one of two buffer slots, so the previous pair stays valid until then. Each buffer `B`
/// must hold a whole image.
#[derive(Debug)]
pub struct ReplayStereo<H, P, B> {
    tape: H,
    payload: P,
    slots: [[B; 2]; 2],
    current: usize,
    loaded: Option<u32>,
    calibration: StereoCalibration,
    lens: Option<rover_hal::LensCalibration>,
}

impl<H: TapeHandle, P: PayloadSource, B: AsRef<[u8]> + AsMut<[u8]>> ReplayStereo<H, P, B> {
    /// A camera replaying `tape` with `calibration`, reading pixels through `payload` into
    /// `slots` (two pairs of left and right buffers).
    pub fn new(tape: H, payload: P, slots: [[B; 2]; 2], calibration: StereoCalibration) -> Self {
        Self {
            tape,
            payload,
            slots,
            current: 0,
            loaded: None,
            calibration,
            lens: None,
        }
    }

    /// The same camera reporting the lens calibration `lens` (the tape header's): its pairs are
    /// raw images that the flight software rectifies.
    pub fn with_lens(mut self, lens: Option<rover_hal::LensCalibration>) -> Self {
        self.lens = lens;
        self
    }

    /// Id of the pair in the current slot.
    pub fn loaded(&self) -> Option<u32> {
        self.loaded
    }

    /// The current pair (left, right), whole buffers.
    pub fn current_images(&self) -> Option<(&[u8], &[u8])> {
        let [left, right] = self.slots.get(self.current)?;
        Some((left.as_ref(), right.as_ref()))
    }

    fn load_images(&mut self) {
        let Some(images) = self.tape.with(|p| p.take_images()).flatten() else {
            return;
        };
        let spare = 1 - self.current.min(1);
        let result = match self.slots.get_mut(spare) {
            Some([left, right]) => {
                let l = left.as_mut().get_mut(..images.left_len as usize);
                let r = right.as_mut().get_mut(..images.right_len as usize);
                match (l, r) {
                    (Some(l), Some(r)) => self.payload.read_at(images.offset, l).and_then(|_| {
                        let right_at = images.offset.saturating_add(u64::from(images.left_len));
                        self.payload.read_at(right_at, r)
                    }),
                    _ => Err(crate::TapeError::BufferTooSmall),
                }
            }
            None => Err(crate::TapeError::BufferTooSmall),
        };
        match result {
            Ok(()) => {
                self.current = spare;
                self.loaded = Some(images.id);
            }
            Err(e) => {
                self.tape.with(|p| p.flag(Divergence::Tape(e)));
            }
        }
    }
}

impl<H: TapeHandle, P: PayloadSource, B: AsRef<[u8]> + AsMut<[u8]>> StereoCamera
    for ReplayStereo<H, P, B>
{
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        self.calibration
    }
    fn lens_calibration(&self) -> Option<rover_hal::LensCalibration> {
        self.lens
    }
    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        match take(&self.tape, CallKind::CameraTrigger) {
            Some(Call::CameraTrigger(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        let result = match take(&self.tape, CallKind::CameraPoll) {
            Some(Call::CameraPoll(r)) => r,
            _ => return Err(ErrorKind::Other),
        };
        self.load_images();
        result
    }
    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        let info = match take(&self.tape, CallKind::CameraFrame) {
            Some(Call::CameraFrame(r)) => r?,
            _ => return Err(ErrorKind::Other),
        };
        let images = if self.loaded == Some(info.images) {
            self.slots.get(self.current).and_then(|[l, r]| {
                let left = l.as_ref().get(..info.left_len as usize)?;
                let right = r.as_ref().get(..info.right_len as usize)?;
                Some((left, right))
            })
        } else {
            None
        };
        match images {
            Some((left, right)) => Ok(StereoFrame {
                left,
                right,
                capture_t_us: info.capture_t_us,
                sequence: info.sequence,
            }),
            None => {
                self.tape.with(|p| {
                    p.flag(Divergence::Images {
                        wanted: info.images,
                    })
                });
                Err(ErrorKind::Other)
            }
        }
    }
    fn release(&mut self) -> Result<(), ErrorKind> {
        match take(&self.tape, CallKind::CameraRelease) {
            Some(Call::CameraRelease(r)) => r,
            _ => Err(ErrorKind::Other),
        }
    }
}
