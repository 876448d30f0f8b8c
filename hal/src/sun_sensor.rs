//! Sun sensor (RB sec. 3: absolute orientation from the sun direction).

use crate::Error;

/// One sun-sensor reading.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SunReading {
    /// Time of the reading, microseconds since boot.
    pub t_us: u64,
    /// Unit vector towards the sun in the rover frame `R` (x forward, y right, z down).
    pub sun_dir_rover: [f64; 3],
    /// True when the sun is in the sensor's field of view and the vector is meaningful.
    pub sun_in_view: bool,
}

/// A sun sensor, read at a low rate.
pub trait SunSensor {
    /// Error type of this sensor.
    type Error: Error;

    /// The latest reading.
    fn read(&mut self) -> Result<SunReading, Self::Error>;
}
