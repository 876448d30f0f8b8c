//! Inertial measurement unit.

use crate::Error;

/// One IMU sample in the rover frame `R` (x forward, y right, z down).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuSample {
    /// Time of the sample, microseconds since boot.
    pub t_us: u64,
    /// Angular rate of `R` relative to inertial space, expressed in `R`, rad/s.
    pub gyro_rad_s: [f64; 3],
    /// Specific force (acceleration minus gravity) in `R`, m/s^2. At rest on level ground it
    /// reads `[0, 0, -3.711]` on Mars.
    pub accel_m_s2: [f64; 3],
    /// The device's own health flag for this sample (saturation, built-in test).
    pub valid: bool,
}

/// An IMU, read at the high rate (RG1, default 200 Hz).
pub trait Imu {
    /// Error type of this IMU.
    type Error: Error;

    /// The latest sample. Returns [`crate::ErrorKind::NotReady`] when no new sample exists since
    /// the last read; a repeated time stamp is a stale sample.
    fn read(&mut self) -> Result<ImuSample, Self::Error>;
}
