//! Power subsystem: the battery's energy and the bus power (V99 sec. 3: the "current power
//! reserves" CASPER monitors; a rover's power distribution unit integrates the battery current
//! and voltage it measures).

use crate::Error;

/// One reading of the power subsystem.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PowerReading {
    /// Time of the reading, microseconds since boot.
    pub t_us: u64,
    /// Energy drawn from the battery since boot (the power distribution unit's integral of bus
    /// voltage times battery current), J. Never decreases while the battery discharges; a
    /// charging source is not modelled, so it is monotone.
    pub energy_used_j: f64,
    /// Bus power averaged over the last reading interval, W (non-negative).
    pub bus_power_w: f64,
    /// True when the power distribution unit trusts its current and voltage sensing.
    pub valid: bool,
}

/// The power distribution unit, read at a low rate.
pub trait Power {
    /// Error type of this device.
    type Error: Error;

    /// The latest reading.
    fn read(&mut self) -> Result<PowerReading, Self::Error>;
}
