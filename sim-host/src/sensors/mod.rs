//! Sensor models: IMU, joint encoders, sun sensor, and fault injection.

pub mod encoders;
pub mod faults;
pub mod imu;
pub mod sun;
