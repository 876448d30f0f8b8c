//! Error kinds shared by all devices.

/// What went wrong with a device call, independent of the device implementation.
///
/// The flight code decides its response from the kind alone; the concrete error stays available
/// for telemetry through `Debug`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ErrorKind {
    /// No new data yet (a poll that would block).
    NotReady,
    /// The device did not answer in time.
    Timeout,
    /// The device answered with data it flags as invalid or out of range.
    InvalidData,
    /// The device is busy with an earlier request (for example a capture in progress).
    Busy,
    /// The device reports a hardware fault.
    Hardware,
    /// The request itself was invalid (for example a command with a non-finite value).
    InvalidRequest,
    /// Anything else.
    Other,
}

/// A device error: anything that can say which [`ErrorKind`] it is.
pub trait Error: core::fmt::Debug {
    /// The kind of this error.
    fn kind(&self) -> ErrorKind;
}

impl Error for ErrorKind {
    fn kind(&self) -> ErrorKind {
        *self
    }
}

/// A device that cannot fail uses `Infallible` as its error.
impl Error for core::convert::Infallible {
    fn kind(&self) -> ErrorKind {
        match *self {}
    }
}
