//! # Telemetry records
//!
//! Fixed-size records, serialised with `postcard` into a caller-provided buffer (no allocation)
//! and handed to the HAL [`rover_hal::Telemetry`] sink. Each record starts with a one-byte
//! [`RecordKind`] tag so a ground tool can split a mixed stream. The records are the flight
//! software's statuses as they are ([`crate::flight::FrameStatus`],
//! [`crate::flight::nav::NavStatus`]); this module only frames and encodes them.

use serde::{Deserialize, Serialize};

/// Largest encoded record, bytes. Every record type is checked against it in the tests.
pub const MAX_RECORD_BYTES: usize = 320;

/// Tag byte that starts every record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[repr(u8)]
pub enum RecordKind {
    /// [`crate::flight::FrameStatus`].
    FrameStatus = 1,
    /// [`crate::flight::nav::NavStatus`].
    NavStatus = 2,
}

/// Encoding failed: the buffer is too small for the record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EncodeError;

/// Encode a record with its tag into `buffer`; returns the used prefix.
pub fn encode<'a, T: Serialize>(
    kind: RecordKind,
    record: &T,
    buffer: &'a mut [u8],
) -> Result<&'a [u8], EncodeError> {
    let (tag, body) = buffer.split_first_mut().ok_or(EncodeError)?;
    *tag = kind as u8;
    let used = postcard::to_slice(record, body)
        .map_err(|_| EncodeError)?
        .len();
    buffer.get(..used + 1).ok_or(EncodeError)
}
