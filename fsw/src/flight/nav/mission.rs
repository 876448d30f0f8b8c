//! The day's targets: the CASPER-style sequencer ([`crate::sequencer`], V99 sec. 3) drives the
//! goal-directed navigation ([`super::hazard_nav`]) from target to target, with the power
//! subsystem's energy telemetry.

use super::*;
use rover_hal::PowerReading;

/// The mission state of the navigator: the latest power reading.
pub(super) struct Mission {
    /// Latest accepted power reading (checked by the flight task: time advancing, finite,
    /// energy not decreasing).
    pub(super) power: Option<PowerReading>,
}

impl Mission {
    /// No reading.
    pub(super) const EMPTY: Self = Self { power: None };
}

impl Navigator {
    /// RG4: a checked power reading (the battery energy used since boot, J, and the bus power,
    /// W; V99 sec. 3: "current power reserves").
    pub fn power(&mut self, reading: &PowerReading) {
        self.mission.power = Some(*reading);
    }

    /// The latest power reading the navigator has, if any.
    pub fn last_power(&self) -> Option<PowerReading> {
        self.mission.power
    }
}
