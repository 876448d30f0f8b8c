//! The soil under the truth vehicle's wheels: terramechanics parameters and the two slip models
//! of the simulator (`slip_model` in the scenario, `docs/terramechanics.md`).
//!
//! - [`terramechanics`]: soil and wheel parameters (Bekker-Wong, published values) and the
//!   quasi-static wheel loads of a rocker-bogie; the building blocks of both models.
//! - [`rigid_wheel`]: the rigid wheel on deformable soil (Wong-Reece stress distribution): the
//!   force law of one wheel and its inverse (slip for a drawbar pull, slip angle for a side
//!   force).
//! - [`per_wheel_slip`]: the default slip model (`slip_model = "terramechanics"`): per-wheel
//!   slip from the rocker-bogie loads and the rigid-wheel law.
//! - [`lumped_slip`]: the lumped slip model (`slip_model = "lumped"`): one slip ratio and one
//!   slip angle for the whole vehicle from the slopes, for comparison.

pub mod lumped_slip;
pub mod per_wheel_slip;
pub mod rigid_wheel;
pub mod terramechanics;
