//! Telemetry sink.

use crate::Error;

/// A sink for encoded telemetry records (one record per call, already framed by the caller).
pub trait Telemetry {
    /// Error type of this sink.
    type Error: Error;

    /// Queue one record for downlink. [`crate::ErrorKind::Busy`] means the record was not taken.
    fn send(&mut self, record: &[u8]) -> Result<(), Self::Error>;
}
