//! # sim-host: the host simulator of a Rocky 8 class rover
//!
//! Implements every `rover-hal` device for a simulated rover and runs the flight software
//! ([`fsw::flight::Fsw`]) in closed loop on the host. The truth comes from physics and
//! geometry; the flight code sees only HAL readings. See `docs/simulator.md`.
//!
//! The truth:
//! - [`terrain`], [`surface`]: analytic height models (yard with rocks, slopes, rough terrain,
//!   dunes, step) and the surface trait the renderer and the vehicle model read.
//! - [`vehicle`]: Rocky 8 geometry, wheel-terrain contact, placement on the terrain, rolling
//!   motion, quasi-static forces, motors.
//! - [`soil`]: terramechanics parameters and the slip models (per-wheel rigid-wheel
//!   terramechanics, the default; the lumped model, an option).
//! - [`world`]: the truth state and its step (motors, contacts, slip, forces, placement,
//!   sensor sampling).
//! - [`energy`]: the truth energy model (battery power and energy used along the truth state).
//! - [`hazards`]: the truth-side hazard check (collisions of the rover with rocks and blocks).
//! - [`descent_map`]: the uplinked global map of terrain-map localization (descent or
//!   orbital image of the truth rocks, with its resolution and errors).
//!
//! What the flight software sees:
//! - [`sensors`]: IMU, encoders, sun sensor, the hazcam head and its lenses, fault injection.
//! - [`render`]: the rasterising hazcam renderer and the procedural albedo texture.
//! - [`devices`]: the `rover-hal` devices (on the world, or on a rover standing still) and the
//!   stereo camera's image source.
//!
//! Runs and their products:
//! - [`scenario`]: scenario files (TOML).
//! - [`closed_loop`]: one closed-loop run of a scenario with the flight software (or the
//!   reference driver of [`driver`]) commanding the motors, and its result.
//! - [`output`]: the output files of a run (TUM trajectories, `summary.json`, `report.html`);
//!   [`figure`]: the SVG figures (plotters) and their geometry checks.
//! - [`campaign`]: Monte Carlo campaigns (spec, plan, runs, statistics, report, Slurm;
//!   `docs/campaigns.md`).
//! - [`commands`]: the subcommands of the main command (run, compare, still, sil, detection,
//!   record, replay, campaign).

pub mod campaign;
pub mod closed_loop;
pub mod commands;
pub mod descent_map;
pub mod devices;
pub mod driver;
pub mod energy;
pub mod figure;
pub mod hazards;
pub mod output;
pub mod render;
pub mod scenario;
pub mod sensors;
pub mod soil;
pub mod surface;
pub mod terrain;
pub mod vehicle;
pub mod world;
