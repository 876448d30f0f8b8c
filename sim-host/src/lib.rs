//! # sim-host: the host simulator of a Rocky 8 class rover
//!
//! Implements every `rover-hal` device for a simulated rover and runs the flight software
//! ([`fsw::flight::Fsw`]) in closed loop on the host. This first version simulates a rover
//! standing still on level ground (IMU at rest under Mars gravity, joint encoders at rest, a
//! stereo pair that completes a capture a fixed number of frames after its trigger, a sun
//! sensor); it exists so the HAL has two implementations (this one and the rover-CPU image) and
//! the executive's schedule and timing can be checked on the host.

pub mod devices;
pub mod render;
pub mod run;
pub mod surface;
