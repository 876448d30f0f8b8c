//! # fsw: slip-compensated rover navigation flight software
//!
//! The flight partition of a six-wheel rocker-bogie rover (JPL Rocky 8 class) that follows a
//! path on sandy slopes where its wheels slip (seeds H04 = Helmick et al. 2004, H05 = Helmick et
//! al. 2005, RB = Roumeliotis & Bekey, V99 = Volpe et al.).
//!
//! Rules that hold for every module: `no_std`, no allocation, fixed capacities, bounded loops, no
//! recursion, no panics on any input (bad input is an error value or a fault flag), and
//! deterministic arithmetic (`libm` for transcendental functions) so that the host simulator and
//! the rover CPU compute bit-identical outputs from the same inputs.
//!
//! Frames and units are those of [`rover_hal`]: rover frame `R` x forward, y right, z down;
//! navigation frame `N` x north, y east, z down; SI units, time in microseconds since boot.
//!
//! Modules (one per seed section, see `docs/architecture.md`):
//! - [`exec`]: the rate-group cyclic executive.
//! - [`estimation`]: the error-state EKF (IMU propagation, stochastic-cloning relative-pose
//!   updates, Mahalanobis slip gate, sun sensor, zero-velocity updates; H04 sec. 4, RB).
//! - [`flight`]: the top-level [`flight::Fsw`] that owns all state and runs one minor frame per
//!   [`flight::Fsw::tick`].
//! - [`perception`]: hazard map from the hazcam pair (V99 sec. 4): stereo ranging over a
//!   ground lattice, terrain grid classified by step, slope and roughness, obstacles as grown
//!   convex polygons and the visible wedge for the RoverBug planner.
//! - [`kinematics`]: rocker-bogie kinematics of Rocky 8 (H04 sec. 3, App. A): D-H model,
//!   contact points, wheel Jacobians, forward/inverse kinematics, vehicle odometry, planar model.
//! - [`planning`]: RoverBug path planning (V99 sec. 4): local tangent graph over convex obstacle
//!   polygons, motion-to-goal and boundary following with virtual sliding and gaze control.
//! - [`rectify`]: rectification of the raw wide-angle hazcam pair: a
//!   fixed-point map built once from the lens calibration, applied in background work items.
//! - [`types`]: shared math types ([`types::RelativePose`]).
//! - [`guidance`]: carrot heading and slip-compensation loops (H04 sec. 5, H05 sec. V).
//! - [`telemetry`]: fixed-size telemetry records encoded without allocation.
//! - [`vo`]: stereo visual odometry (H04 sec. 2, H05 sec. II): Forstner features, ray-gap
//!   triangulation (eq. 1-8), affine tracking (eq. 9-10), LMedS and maximum-likelihood motion
//!   (eq. 11), as a resumable pipeline with preallocated buffers.
#![no_std]
#![forbid(unsafe_code)]
// The flight lints are the workspace's (`Cargo.toml`); tests may panic.
#![cfg_attr(
    test,
    allow(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::unreachable
    )
)]

#[cfg(test)]
#[macro_use]
extern crate std;

pub mod estimation;
pub mod exec;
pub mod flight;
pub mod guidance;
pub mod kinematics;
pub mod linalg;
pub mod localization;
pub mod perception;
pub mod planning;
pub mod rectify;
pub mod sequencer;
pub mod telemetry;
pub mod types;
pub mod vo;

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    /// DOC-1: the module table of `docs/architecture.md` ("Flight code modules": the first cell
    /// of each row is the module name in backticks) lists exactly the `pub mod`s of this file.
    #[test]
    fn doc_1_architecture_module_table_matches_lib_rs() {
        let lib = include_str!("lib.rs");
        let declared: BTreeSet<&str> = lib
            .lines()
            .filter_map(|l| l.strip_prefix("pub mod "))
            .map(|l| l.trim_end_matches(';'))
            .collect();
        let page = include_str!("../../docs/architecture.md");
        let table = page
            .split("## Flight code modules")
            .nth(1)
            .and_then(|rest| rest.split("\n## ").next())
            .unwrap_or("");
        let listed: BTreeSet<&str> = table
            .lines()
            .filter_map(|l| l.strip_prefix("| `"))
            .filter_map(|l| l.split('`').next())
            .collect();
        assert!(declared.len() >= 10, "{declared:?}");
        assert_eq!(
            listed, declared,
            "docs/architecture.md's module table and fsw/src/lib.rs disagree"
        );
    }
}
