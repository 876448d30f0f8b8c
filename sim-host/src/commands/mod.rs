//! The subcommands of the main command (`sim-host <command>`), one module each: its options
//! (`clap`), what it runs and what it prints or writes.
//!
//! - `run` and `compare` (in `main.rs`): one scenario in closed loop; a scenario with and
//!   without slip compensation, compared.
//! - [`still`]: the flight executive on a rover standing still (per-rate-group timing).
//! - [`sil`]: the SIL acceptance cases (tests and `docs/sil-results.md`).
//! - [`detection`]: slip detection probability against slip magnitude and the slip-hold
//!   policy (`docs/slip-detection.md`).
//! - [`record`], [`replay`]: call tapes of the HAL inputs and their replay through the flight
//!   software with per-frame output digests, for bit-identical host/target comparison
//!   (`docs/timing.md`).
//! - [`campaign`]: Monte Carlo campaigns (plan, run, gather, local, slurm; [`crate::campaign`]).

pub mod campaign;
pub mod detection;
pub mod record;
pub mod replay;
pub mod sil;
pub mod still;
