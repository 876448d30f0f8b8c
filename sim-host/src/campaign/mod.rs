//! Monte Carlo SIL campaigns (`sim-host campaign`, `docs/campaigns.md`).
//!
//! A campaign spec (TOML, [`spec`]) names a base scenario, a number of runs, a base seed,
//! dispersions of scenario parameters ([`params`]) and acceptance criteria on percentiles of
//! `summary.json` metrics. The steps:
//!
//! - [`plan`]: expand the spec into `DIR/manifest.json`, every run's index, seeds and drawn
//!   parameter values. Run `i` gets the seed [`run_seed`]`(base_seed, i)`, so any run can be
//!   replayed alone and the first `N` runs of a larger campaign are the same runs.
//! - [`exec`]: run one index, a shard or all of them (`rayon`, progress bar) and write
//!   `DIR/runs/<i>/summary.json` (or `error.txt` when the run failed).
//! - [`stats`]: gather the summaries in index order, compute statistics (nearest-rank
//!   percentiles, mean, sample standard deviation, min/max), check the criteria, list the
//!   worst runs; `DIR/stats.json` is a pure function of the manifest and the summaries, so
//!   local and Slurm execution give the same bytes.
//! - [`html`]: `DIR/report.html`, self-contained, figures drawn with `plotters`.
//! - [`slurm`]: `DIR/campaign.sbatch` (job array over the indices) and `DIR/gather.sbatch`
//!   (dependent on the array), optionally submitted.
//! - [`svg_labels`]: a check that no two text labels of an SVG overlap (used by the tests).
//! - the `campaign` subcommand of the main command: [`crate::commands::campaign`].

pub mod exec;
pub mod html;
pub mod params;
pub mod plan;
pub mod slurm;
pub mod spec;
pub mod stats;
pub mod svg_labels;

#[cfg(test)]
mod tests;

/// The golden-ratio increment of SplitMix64 (Steele, Lea, Flood, "Fast splittable pseudorandom
/// number generators", OOPSLA 2014; the constants of Vigna's public-domain `splitmix64.c`).
pub const SPLITMIX_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// The SplitMix64 output function (`mix64` variant 13 of Stafford, as in `splitmix64.c`).
pub fn splitmix64_mix(z: u64) -> u64 {
    let mut z = z;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The simulator seed of run `index` of a campaign with `base_seed`: the `(index + 1)`-th
/// output of a SplitMix64 generator started at `base_seed`,
/// `mix(base_seed + (index + 1) * 0x9E3779B97F4A7C15)` (wrapping arithmetic).
pub fn run_seed(base_seed: u64, index: u64) -> u64 {
    splitmix64_mix(base_seed.wrapping_add(index.wrapping_add(1).wrapping_mul(SPLITMIX_GAMMA)))
}

/// Seed of the dispersion draws of a run: `mix(run_seed + 0x9E3779B97F4A7C15)` (one SplitMix64
/// step from the run seed), so the draws are independent of the simulator's own streams.
pub fn draw_seed(run_seed: u64) -> u64 {
    splitmix64_mix(run_seed.wrapping_add(SPLITMIX_GAMMA))
}

/// 64-bit FNV-1a hash of `text` (the ChaCha8 stream of a dispersion: its name, so that adding
/// or reordering dispersions does not change the others' draws).
pub fn fnv1a64(text: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.as_bytes() {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}
