//! # rover-replay: call tapes and output digests for bit-identical host/target replay
//!
//! A **call tape** is the sequence of results of every HAL device call the flight software made,
//! in call order, recorded while it ran in the simulator: IMU reads, joint reads, sun reads,
//! power reads, mobility command and stop results, camera trigger, poll, frame and release
//! results, telemetry send results and `Clock::now_us`. The stereo images the camera returned follow the poll that
//! reported them ready. `Clock::counter` is **not** recorded: it is the execution-time counter,
//! which feeds only timing telemetry.
//!
//! Replaying the tape through the devices of [`devices`] gives the flight software exactly the
//! inputs it had in the simulator, on any CPU, whatever it does with them internally: the
//! replay devices return the recorded results in order and flag a [`Divergence`] when the
//! flight code makes a call the tape does not have next. A per-frame [`Digest`] of the flight
//! outputs (commands, telemetry, selected flight state) recorded with the tape then shows
//! whether the replay computed bit-identical outputs.
//!
//! - [`tape`]: the binary format (header, records, encode and decode) and a streaming
//!   [`tape::TapeReader`] over any [`tape::ByteSource`].
//! - [`digest`]: FNV-1a 64 over little-endian bit patterns, and [`digest::Digestible`] for the
//!   HAL data types.
//! - [`player`]: the records of the current frame ([`Player`]) and the outputs the flight
//!   software produced in it ([`FrameOutputs`]).
//! - [`devices`]: replay devices implementing the HAL traits.
//!
//! Flight rules: `no_std`, no allocation, no panics on any input (a malformed tape is an error
//! value), bounded loops.
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod devices;
pub mod digest;
pub mod player;
pub mod tape;

pub use digest::{Digest, Digestible};
pub use player::{Divergence, FrameOutputs, MobilityOutput, Player, TapeHandle};
pub use tape::{Call, CallKind, FrameInfo, ImagesRef, Record, TapeError, TapeHeader};

#[cfg(test)]
mod tests;
