//! Sensor models: IMU, joint encoders, sun sensor, the hazcam head and its lenses, and fault injection.

pub mod camera_model;
pub mod encoders;
pub mod faults;
pub mod imu;
pub mod lens;
pub mod sun;
