//! The replay state shared by the replay devices: the current frame's records, the outputs the
//! flight software produced in the frame, and the first divergence.

use crate::tape::{Call, CallKind, ImagesRef, Record, TapeError};
use core::cell::RefCell;
use core::ops::Deref;
use rover_hal::MobilityCommand;

/// Largest number of records (calls and image pairs) in one frame of a tape.
pub const MAX_RECORDS_PER_FRAME: usize = 64;
/// Largest number of mobility outputs (commands and stops) kept per frame.
pub const MAX_MOBILITY_OUTPUTS: usize = 8;
/// Largest number of telemetry records kept per frame.
pub const MAX_TELEMETRY_RECORDS: usize = 16;
/// Largest number of telemetry bytes kept per frame.
pub const MAX_TELEMETRY_BYTES: usize = 2048;

/// One mobility output of the flight software, in call order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MobilityOutput {
    /// `Mobility::command` with this command.
    Command(MobilityCommand),
    /// `Mobility::stop`.
    Stop,
}

/// What the flight software sent to its actuators and downlink in one frame (the outputs a
/// digest covers), with fixed capacities; what does not fit is counted.
#[derive(Debug, Clone)]
pub struct FrameOutputs {
    mobility: [MobilityOutput; MAX_MOBILITY_OUTPUTS],
    mobility_len: usize,
    telemetry: [u8; MAX_TELEMETRY_BYTES],
    telemetry_ends: [usize; MAX_TELEMETRY_RECORDS],
    telemetry_len: usize,
    dropped: u32,
}

impl Default for FrameOutputs {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameOutputs {
    /// No outputs.
    pub const fn new() -> Self {
        Self {
            mobility: [MobilityOutput::Stop; MAX_MOBILITY_OUTPUTS],
            mobility_len: 0,
            telemetry: [0; MAX_TELEMETRY_BYTES],
            telemetry_ends: [0; MAX_TELEMETRY_RECORDS],
            telemetry_len: 0,
            dropped: 0,
        }
    }

    /// Forget all outputs (start of a frame).
    pub fn clear(&mut self) {
        self.mobility_len = 0;
        self.telemetry_len = 0;
        self.dropped = 0;
    }

    /// Keep a mobility output (counted in [`Self::dropped`] when full).
    pub fn push_mobility(&mut self, output: MobilityOutput) {
        match self.mobility.get_mut(self.mobility_len) {
            Some(slot) => {
                *slot = output;
                self.mobility_len += 1;
            }
            None => self.dropped = self.dropped.saturating_add(1),
        }
    }

    /// Keep a telemetry record (counted in [`Self::dropped`] when full).
    pub fn push_telemetry(&mut self, record: &[u8]) {
        let start = self.telemetry_end(self.telemetry_len);
        let end = start.saturating_add(record.len());
        let fits = self.telemetry_len < MAX_TELEMETRY_RECORDS && end <= MAX_TELEMETRY_BYTES;
        match (fits, self.telemetry.get_mut(start..end)) {
            (true, Some(dst)) => {
                // Equal lengths by construction; a zip copy has no length-mismatch panic.
                for (d, s) in dst.iter_mut().zip(record.iter()) {
                    *d = *s;
                }
                if let Some(e) = self.telemetry_ends.get_mut(self.telemetry_len) {
                    *e = end;
                }
                self.telemetry_len += 1;
            }
            _ => self.dropped = self.dropped.saturating_add(1),
        }
    }

    fn telemetry_end(&self, count: usize) -> usize {
        match count.checked_sub(1) {
            Some(i) => self.telemetry_ends.get(i).copied().unwrap_or(0),
            None => 0,
        }
    }

    /// Mobility outputs, in call order.
    pub fn mobility(&self) -> &[MobilityOutput] {
        self.mobility.get(..self.mobility_len).unwrap_or(&[])
    }

    /// Telemetry records, in call order.
    pub fn telemetry(&self) -> impl Iterator<Item = &[u8]> + '_ {
        (0..self.telemetry_len).map(move |i| {
            let (start, end) = (self.telemetry_end(i), self.telemetry_end(i + 1));
            self.telemetry.get(start..end).unwrap_or(&[])
        })
    }

    /// Outputs that did not fit.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }
}

/// Why a replay stopped matching its tape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Divergence {
    /// The flight software made call `got` where the tape has `expected` next (`None`: the
    /// tape has no more calls in this frame).
    UnexpectedCall {
        /// Calls served before this one since the start of the replay.
        call: u64,
        /// Next call on the tape.
        expected: Option<CallKind>,
        /// Call the flight software made.
        got: CallKind,
    },
    /// The frame ended with calls left on the tape (the flight software made fewer calls).
    UnusedCalls {
        /// Calls served since the start of the replay.
        call: u64,
        /// Next call on the tape.
        expected: Option<CallKind>,
    },
    /// A camera frame refers to images the replay camera does not hold.
    Images {
        /// Id the tape's frame record names.
        wanted: u32,
    },
    /// The tape could not be read.
    Tape(TapeError),
}

/// Replay state: the records of the current frame, the frame's outputs and the first
/// divergence (latched; after it every call returns an error).
#[derive(Debug, Clone)]
pub struct Player {
    queue: [Record; MAX_RECORDS_PER_FRAME],
    head: usize,
    len: usize,
    outputs: FrameOutputs,
    calls: u64,
    divergence: Option<Divergence>,
}

impl Default for Player {
    fn default() -> Self {
        Self::new()
    }
}

fn record_kind(record: Option<&Record>) -> Option<CallKind> {
    match record {
        Some(Record::Call(c)) => Some(c.kind()),
        _ => None,
    }
}

impl Player {
    /// An empty player.
    pub const fn new() -> Self {
        Self {
            queue: [Record::End; MAX_RECORDS_PER_FRAME],
            head: 0,
            len: 0,
            outputs: FrameOutputs::new(),
            calls: 0,
            divergence: None,
        }
    }

    /// Start a frame: forget the previous frame's outputs and any records left.
    pub fn begin_frame(&mut self) {
        self.head = 0;
        self.len = 0;
        self.outputs.clear();
    }

    /// Queue a record of the current frame.
    pub fn push(&mut self, record: Record) -> Result<(), TapeError> {
        let slot = self
            .queue
            .get_mut(self.len)
            .ok_or(TapeError::FrameTooLong)?;
        *slot = record;
        self.len += 1;
        Ok(())
    }

    fn front(&self) -> Option<&Record> {
        if self.head < self.len {
            self.queue.get(self.head)
        } else {
            None
        }
    }

    /// The next call's result when it is a `kind` call; otherwise latch a divergence and return
    /// `None`.
    pub fn take(&mut self, kind: CallKind) -> Option<Call> {
        if self.divergence.is_some() {
            return None;
        }
        match self.front() {
            Some(Record::Call(c)) if c.kind() == kind => {
                let call = *c;
                self.head += 1;
                self.calls = self.calls.saturating_add(1);
                Some(call)
            }
            other => {
                self.divergence = Some(Divergence::UnexpectedCall {
                    call: self.calls,
                    expected: record_kind(other),
                    got: kind,
                });
                None
            }
        }
    }

    /// The next record when it is a stereo pair.
    pub fn take_images(&mut self) -> Option<ImagesRef> {
        match self.front() {
            Some(Record::Images(i)) if self.divergence.is_none() => {
                let images = *i;
                self.head += 1;
                Some(images)
            }
            _ => None,
        }
    }

    /// End the frame: records left over are a divergence (the first is returned).
    pub fn end_frame(&mut self) -> Result<(), Divergence> {
        if self.divergence.is_none() && self.front().is_some() {
            self.divergence = Some(Divergence::UnusedCalls {
                call: self.calls,
                expected: record_kind(self.front()),
            });
        }
        match self.divergence {
            Some(d) => Err(d),
            None => Ok(()),
        }
    }

    /// Latch a divergence found by a device (the first one is kept).
    pub fn flag(&mut self, divergence: Divergence) {
        if self.divergence.is_none() {
            self.divergence = Some(divergence);
        }
    }

    /// The first divergence, if any.
    pub fn divergence(&self) -> Option<Divergence> {
        self.divergence
    }

    /// Outputs of the current frame.
    pub fn outputs(&self) -> &FrameOutputs {
        &self.outputs
    }

    /// Outputs of the current frame, for the devices to add to.
    pub fn outputs_mut(&mut self) -> &mut FrameOutputs {
        &mut self.outputs
    }

    /// Calls served since the start.
    pub fn calls(&self) -> u64 {
        self.calls
    }
}

/// Shared access to the [`Player`] from every replay device (`&'static RefCell<Player>` on the
/// target, `Rc<RefCell<Player>>` on the host).
pub trait TapeHandle {
    /// Run `f` on the player; `None` if it is already borrowed (a re-entrant call, which the
    /// devices report as an error).
    fn with<R>(&self, f: impl FnOnce(&mut Player) -> R) -> Option<R>;
}

impl<T: Deref<Target = RefCell<Player>>> TapeHandle for T {
    fn with<R>(&self, f: impl FnOnce(&mut Player) -> R) -> Option<R> {
        let mut player = self.deref().try_borrow_mut().ok()?;
        Some(f(&mut player))
    }
}
