//! # fsw-image library: what the rover-CPU image shares with the host
//!
//! The flight software's construction ([`flight_replay::build_fsw`]), the per-frame digest of
//! its outputs ([`flight_replay::digest_frame`]) and the replay driver
//! ([`flight_replay::Replay`]) are compiled both into the rover-CPU image and into the host
//! simulator (`sim-host record` and `sim-host replay`), so a call tape replayed on either CPU
//! goes through the same code and is checked with the same digest.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod flight_replay;
