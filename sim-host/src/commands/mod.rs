//! The subcommands of the main command (`sim-host <command>`), one module each: its options
//! (`clap`), what it runs and what it prints or writes. `main.rs` only dispatches.
//!
//! - [`run`]: one scenario in closed loop, its outputs and summary table; [`run::RunFlags`] are
//!   the options of a run, shared with [`compare`].
//! - [`compare`]: the main command's default: a scenario with and without slip compensation,
//!   compared, with the H05 Fig. 9 top view.
//! - [`still`]: the flight executive on a rover standing still (per-rate-group timing).
//! - [`sil`]: the SIL acceptance cases (tests and `docs/results/sil-results.md`).
//! - [`detection`]: slip detection probability against slip magnitude and the slip-hold
//!   policy (`docs/results/slip-detection.md`).
//! - [`record`], [`replay`]: call tapes of the HAL inputs and their replay through the flight
//!   software with per-frame output digests, for bit-identical host/target comparison
//!   (`docs/results/timing.md`).
//! - [`campaign`]: Monte Carlo campaigns (plan, run, gather, local, slurm; [`crate::campaign`]).

pub mod campaign;
pub mod compare;
pub mod detection;
pub mod record;
pub mod replay;
pub mod run;
pub mod sil;
pub mod still;
