//! Sensor models: IMU, joint encoders, sun sensor, the hazcam head and its lenses, and fault injection.

pub mod encoders;
pub mod faults;
pub mod hazcam;
pub mod hazcam_lens;
pub mod imu;
pub mod sun;
