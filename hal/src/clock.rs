//! Monotonic time and the execution-time counter.

use crate::Error;

/// Monotonic time since boot and a free-running counter for execution-time statistics.
///
/// Time stamps drive the flight software's logic (through the data they stamp); the counter feeds
/// timing telemetry only and never a control decision, so the same inputs give the same outputs
/// on the host and on the target.
pub trait Clock {
    /// Error type of this clock.
    type Error: Error;

    /// Microseconds since boot. Monotonic: a clock that goes backwards is a fault the caller
    /// detects and reports.
    fn now_us(&mut self) -> Result<u64, Self::Error>;

    /// Free-running execution counter (CPU cycles on hardware; a deterministic instruction-based
    /// count in QEMU with `-icount`; host nanoseconds in the simulator). Wraps at `u64::MAX`.
    fn counter(&mut self) -> Result<u64, Self::Error>;

    /// Counter ticks per second, to convert counter differences into time (Hz).
    fn counter_hz(&self) -> u64;
}
