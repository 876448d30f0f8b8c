//! # sim-host: the host simulator of a Rocky 8 class rover
//!
//! Implements every `rover-hal` device for a simulated rover and runs the flight software
//! ([`fsw::flight::Fsw`]) in closed loop on the host. The truth comes from physics and
//! geometry; the flight code sees only HAL readings. See `docs/simulator.md`.
//!
//! - [`terrain`]: analytic height models (yard with rocks, slopes, rough terrain, dunes, step).
//! - [`vehicle`]: Rocky 8 geometry, placement on the terrain, motors.
//! - [`slip`]: per-wheel slip from the rocker-bogie loads and the rigid-wheel terramechanics of
//!   [`rigid_wheel`] (the default); [`slip_lumped`]: the lumped slip model (an option).
//! - [`sensors`]: IMU, encoders, sun sensor, fault injection.
//! - [`camera`]: the stereo renderer interface; [`render`]: the rasterising hazcam renderer and
//!   the procedural albedo texture.
//! - [`world`]: the truth state and its step; [`hal_devices`]: the HAL devices on it.
//! - [`energy`]: the truth energy model (battery power and energy used along the truth state).
//! - [`driver`]: the simulator's reference driver (not flight code).
//! - [`hazards`]: the truth-side hazard check (collisions of the rover with rocks and blocks).
//! - [`scenario`], [`sim`], [`output`], [`report`]: scenario files, runs, outputs;
//!   [`plot`]: the report figures (plotters, SVG) and their geometry checks.
//! - [`sil`]: the SIL acceptance cases (tests and `docs/sil-results.md`).
//! - [`campaign`]: Monte Carlo campaigns (spec, plan, runs, statistics, report, Slurm;
//!   `docs/campaigns.md`).
//! - [`detection`]: slip detection probability against slip magnitude and the slip-hold
//!   policy (`docs/slip-detection.md`).
//! - [`descent_map`]: the uplinked global map of terrain-map localization (descent or
//!   orbital image of the truth rocks, with its resolution and errors).
//! - [`devices`], [`run`]: the standing-still devices of the `still` command.
//! - [`record`], [`replay`]: call tapes of the HAL inputs (`record`) and their replay through
//!   the flight software with per-frame output digests (`replay`), for bit-identical
//!   host/target comparison (`docs/timing.md`).

pub mod camera;
pub mod campaign;
pub mod descent_map;
pub mod detection;
pub mod devices;
pub mod driver;
pub mod energy;
pub mod hal_devices;
pub mod hazards;
pub mod output;
pub mod plot;
pub mod record;
pub mod render;
pub mod replay;
pub mod report;
pub mod rigid_wheel;
pub mod run;
pub mod scenario;
pub mod sensors;
pub mod sil;
pub mod sim;
pub mod slip;
pub mod slip_lumped;
pub mod surface;
pub mod terrain;
pub mod terramechanics;
pub mod vehicle;
pub mod world;
