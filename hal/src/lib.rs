//! # rover-hal: the devices the rover flight software talks to
//!
//! One trait per device, in the manner of `embedded-hal`: every call is fallible, every trait has
//! an associated [`Error`] whose [`Error::kind`] maps to the shared, `#[non_exhaustive]`
//! [`ErrorKind`]. The data types are plain structs with SI units in their field names.
//!
//! Two implementations exist: the host simulator (`sim-host`) and the rover-CPU image
//! (`fsw/image`, QEMU `mps2-an500`).
//!
//! ## Frames and units used throughout
//!
//! - **Rover frame `R`** (H04 Table 1, the body frame): origin at the rover reference point,
//!   `x` forward, `y` to the right, `z` down. Angles follow the right-hand rule about these axes,
//!   so positive yaw turns the rover to the right, as in H04 eq. 16-17.
//! - **Navigation frame `N`**: local level, fixed to the terrain at the start of the drive,
//!   `x` north, `y` east, `z` down (gravity is `+z`).
//! - **Camera frame `K`**: optical centre of the left hazcam, `x` right in the image, `y` down in
//!   the image, `z` along the optical axis.
//! - Time: `t_us`, microseconds since boot, from the same monotonic clock as [`Clock::now_us`].
//! - Wheel numbering (H04 Table 2): 1 right front, 2 left front, 3 right middle, 4 left middle,
//!   5 right rear, 6 left rear; arrays are indexed `wheel - 1`.
//!
//! The flight code never assumes a device answers: every read can fail (an `Err`), be stale
//! (time stamp not advancing), or carry garbage (NaN, out of range). Validity flags in the data
//! types let a device report a reading it knows to be bad without failing the whole call.
#![no_std]
// `unsafe` only in the FPU glue ([`fpu`]), where the lint is allowed on the one block.
// The flight lints are the workspace's (`Cargo.toml`); tests may panic.
#![cfg_attr(
    test,
    allow(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::unreachable
    )
)]

mod camera;
mod clock;
mod error;
pub mod fpu;
mod imu;
mod mobility;
mod power;
mod sun_sensor;
mod telemetry;

pub use camera::{
    CaptureStatus, LensCalibration, RawCamera, StereoCalibration, StereoCamera, StereoFrame,
    IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX,
};
pub use clock::Clock;
pub use error::{Error, ErrorKind};
pub use imu::{Imu, ImuSample};
pub use mobility::{JointState, Mobility, MobilityCommand, WHEEL_COUNT};
pub use power::{Power, PowerReading};
pub use sun_sensor::{SunReading, SunSensor};
pub use telemetry::Telemetry;
