//! The simulated vehicle: geometry, placement on the terrain, motors.

pub mod geometry;
pub mod motors;
pub mod placement;

#[cfg(test)]
mod tests;
