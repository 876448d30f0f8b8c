//! The simulated vehicle: geometry, wheel-terrain contact, placement on the terrain, rolling
//! motion, motors.

pub mod contact;
pub mod forces;
pub mod geometry;
pub mod motors;
pub mod placement;
pub mod rolling;

#[cfg(test)]
mod tests;
