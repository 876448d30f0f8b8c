//! The simulated `rover-hal` devices, by where their readings come from:
//!
//! - [`world`]: the devices of the simulated rover, reading the shared [`crate::world::World`]
//!   and applying the scenario's injected faults (what the flight software sees in a run);
//! - [`standing`]: the devices of a rover standing still on level ground with simulated time
//!   only (the `still` command);
//! - [`renderer`]: the image source of the world's stereo camera (the textured renderer, or
//!   flat grey frames).
//!
//! Shared by all of them (this module): the host's image memory, the nominal hazcam
//! calibration, the capture protocol of a simulated stereo camera and a counting telemetry
//! sink.

pub mod renderer;
pub mod standing;
pub mod world;

use rover_hal::{
    CaptureStatus, ErrorKind, StereoCalibration, StereoFrame, Telemetry, IMAGE_PIXELS,
};

/// The flight software's stereo-rectification memory on the host (heap buffers; external RAM
/// on the rover CPU).
pub type HostImageMemory = fsw::rectify::ImageMemory<Vec<fsw::rectify::MapNode>, Vec<u8>>;

/// Full-size [`HostImageMemory`]: the map and two rectified images.
pub fn host_image_memory() -> HostImageMemory {
    fsw::rectify::ImageMemory {
        map: vec![fsw::rectify::MapNode::default(); fsw::rectify::MAP_NODES],
        left: vec![0; IMAGE_PIXELS],
        right: vec![0; IMAGE_PIXELS],
    }
}

/// Rocky 8 hazcam calibration (REFERENCE.md): 640x480, 79.5 x 64.0 deg FOV, 8.4 cm baseline,
/// pitched 45 deg down, mounted 0.2 m ahead of and 0.6 m above the rover reference point. The
/// simulator's own nominal head ([`crate::sensors::hazcam::nominal_hazcam`], written from
/// the published figures): what a ground calibration file says, never the per-seed true head.
pub fn hazcam_calibration() -> StereoCalibration {
    crate::sensors::hazcam::nominal_hazcam()
}

/// The capture protocol of a simulated stereo camera (trigger, poll, frame, release): a capture
/// completes `latency_polls` polls after its trigger and stays ready until released or
/// retriggered. Shared by every simulated camera.
#[derive(Debug, Clone)]
pub struct CaptureProtocol {
    pending: Option<(u64, u32)>,
    ready: Option<u64>,
    sequence: u32,
    latency_polls: u32,
}

impl CaptureProtocol {
    /// A protocol whose captures complete after `latency_polls` polls.
    pub fn new(latency_polls: u32) -> Self {
        Self {
            pending: None,
            ready: None,
            sequence: 0,
            latency_polls,
        }
    }

    /// Start a capture stamped `t_us`; returns the new sequence number.
    pub fn trigger(&mut self, t_us: u64) -> u32 {
        self.pending = Some((t_us, self.latency_polls));
        self.ready = None;
        self.sequence = self.sequence.wrapping_add(1);
        self.sequence
    }

    /// Advance the capture by one poll.
    pub fn poll(&mut self) -> CaptureStatus {
        if self.ready.is_some() {
            return CaptureStatus::Ready;
        }
        match self.pending {
            None => CaptureStatus::Idle,
            Some((t, 0)) => {
                self.ready = Some(t);
                self.pending = None;
                CaptureStatus::Ready
            }
            Some((t, n)) => {
                self.pending = Some((t, n - 1));
                CaptureStatus::InProgress
            }
        }
    }

    /// Borrow `left` and `right` as the completed frame.
    pub fn frame<'a>(&self, left: &'a [u8], right: &'a [u8]) -> Result<StereoFrame<'a>, ErrorKind> {
        let t = self.ready.ok_or(ErrorKind::NotReady)?;
        Ok(StereoFrame {
            left,
            right,
            capture_t_us: t,
            sequence: self.sequence,
        })
    }

    /// Give the buffers back.
    pub fn release(&mut self) {
        self.ready = None;
        self.pending = None;
    }

    /// Sequence number of the last trigger.
    pub fn sequence(&self) -> u32 {
        self.sequence
    }
}

/// A telemetry sink's injected refusal: the error to answer with now, if any.
pub type TelemetryRefusal = Box<dyn Fn() -> Option<ErrorKind>>;

/// Telemetry sink that counts records and bytes and keeps the last record.
#[derive(Default)]
pub struct CountingTelemetry {
    /// Records received.
    pub records: u64,
    /// Bytes received.
    pub bytes: u64,
    /// The last record.
    pub last: Vec<u8>,
    /// Records refused by an injected fault.
    pub refused: u64,
    /// Injected refusal (scenario faults on `telemetry`); `None`: every record is taken.
    pub refusal: Option<TelemetryRefusal>,
}

impl CountingTelemetry {
    /// A sink that refuses records when `refusal` says so.
    pub fn with_refusal(refusal: TelemetryRefusal) -> Self {
        Self {
            refusal: Some(refusal),
            ..Self::default()
        }
    }
}

impl Telemetry for CountingTelemetry {
    type Error = ErrorKind;
    fn send(&mut self, record: &[u8]) -> Result<(), ErrorKind> {
        if let Some(e) = self.refusal.as_ref().and_then(|r| r()) {
            self.refused += 1;
            return Err(e);
        }
        self.records += 1;
        self.bytes += record.len() as u64;
        self.last.clear();
        self.last.extend_from_slice(record);
        Ok(())
    }
}
