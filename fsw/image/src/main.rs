//! # fsw-image: the flight software on the rover CPU
//!
//! A Cortex-M7 (`thumbv7em-none-eabihf`, `-C target-cpu=cortex-m7`) image linked by
//! cortex-m-rt with the repository's `memory.x`. It runs in QEMU `mps2-an500`: SysTick starts
//! each 5 ms minor frame, the flight executive runs the schedule for a fixed number of frames,
//! the per-group counts and timing go out through semihosting, and the exit code says whether the
//! counts matched the schedule. A panic prints its message and exits with a failure code.
//!
//! On the host this binary only explains how to build it for the target.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod target;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "fsw-image is the rover-CPU image: build and run it with `cargo xtask qemu` \
         (target thumbv7em-none-eabihf, QEMU mps2-an500)"
    );
    std::process::exit(2);
}
