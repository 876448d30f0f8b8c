//! Track memory: the body's heave from the terrain its front wheels have already rolled over
//! (V99 sec. 6 undulating-terrain odometry; KIN-13).
//!
//! The common mode of the contact angles (all wheel tangents tilted alike) is the direction of
//! the body's motion in its own x-z plane, which the wheel rates observe only at second order
//! ([`super::contact`], `docs/kinematics.md` "In closed loop: the common mode"). The odometry
//! takes the angles relative to their mean, i.e. it assumes the body moves parallel to its own
//! x axis; where the body heaves (it pitches more than its centre climbs, or less), that motion
//! is tilted and its horizontal projection comes out short.
//!
//! The rover itself measures the missing vertical: driving forward, the middle and rear wheels
//! roll over the ground the front wheels of the same side have just rolled over, and every wheel
//! of radius `r` on a terrain profile has its **axle centre** on the same curve (the profile
//! offset by `r`), whatever its contact angle. The memory keeps the path of each front axle
//! centre in `N` (horizontal position and height, a sample every [`TrackConfig::spacing_m`]);
//! when a trailing axle centre, placed with the predicted body pose, the attitude and the
//! suspension, lies over a remembered segment (within [`TrackConfig::lateral_tolerance_m`] of
//! it), the height difference is the error of the predicted body height. The caller
//! ([`crate::flight`]'s kinematic dead reckoning) moves its step's vertical by a fraction of the
//! mean difference and keeps the step's 3D length, which the rim travel measures well: the
//! correction acts on the direction of the step, which is what the wheels do not see.
//!
//! Frames: `N` (x north, y east, z down), `R` (x forward, y right, z down); axle centres are
//! the origins of the contact frames `C_i` (H04 Table 1). Capacities are fixed
//! ([`TRACK_SAMPLES`] per side, `f32` samples: 12 bytes each); every search is bounded
//! ([`TRACK_SEARCH`] segments per trailing wheel and step). Deterministic: no time input.

use crate::types::{Mat3, Vec3};
use rover_hal::WHEEL_COUNT;

/// Samples kept per side (the front axle's path, oldest overwritten first). At the default
/// spacing of 1 cm this is 0.96 m of travel, more than the 0.748 m wheelbase of Rocky 8.
pub const TRACK_SAMPLES: usize = 96;

/// Segments a trailing wheel's search may step over per call, forward or backward from where
/// it matched last (8 cm at 1 cm spacing; a 20 Hz step at 0.1 m/s is 5 mm).
pub const TRACK_SEARCH: usize = 8;

/// Wheel indices (`wheel - 1`, H04 numbering 1 RF, 2 LF, 3 RM, 4 LM, 5 RR, 6 LR) of the front
/// wheel of each side (right, left).
const FRONT: [usize; 2] = [0, 1];
/// Trailing wheels (middle, rear) of each side (right, left).
const TRAILING: [[usize; 2]; 2] = [[2, 4], [3, 5]];

/// Tuning of the track memory (flight software parameters; `docs/kinematics.md`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackConfig {
    /// Whether the dead reckoning uses the memory at all.
    pub enabled: bool,
    /// Horizontal travel of a front axle between two samples, m (> 0).
    pub spacing_m: f64,
    /// Largest horizontal distance of a trailing axle centre from the remembered segment for
    /// a match, m: beyond it (a turn, a side step) the wheel is not on the front wheel's track.
    pub lateral_tolerance_m: f64,
    /// Fraction of the mean height difference applied per kinematic step (0..=1).
    pub gain: f64,
    /// Largest vertical correction per kinematic step, m.
    pub max_step_m: f64,
}

impl TrackConfig {
    /// The flight values: 1 cm samples, 3 cm lateral tolerance (a wheel is 0.11 m wide), a
    /// tenth of the difference per step (a time constant of 10 steps: 0.5 s or 5 cm at
    /// 0.1 m/s) and at most 1 mm per step.
    pub const DEFAULT: Self = Self {
        enabled: true,
        spacing_m: 0.01,
        lateral_tolerance_m: 0.03,
        gain: 0.1,
        max_step_m: 0.001,
    };
}

impl Default for TrackConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One side's front-axle path: a ring of samples `[north m, east m, down m]` in `N`.
#[derive(Debug, Clone, Copy)]
struct SidePath {
    samples: [[f32; 3]; TRACK_SAMPLES],
    /// Samples recorded since the reset (the newest is `count - 1`; those older than
    /// `count - TRACK_SAMPLES` are overwritten).
    count: u64,
    /// Per trailing wheel (middle, rear): the segment `[k, k + 1]` it matched last (absolute
    /// sample number).
    cursor: [u64; 2],
}

impl SidePath {
    const EMPTY: Self = Self {
        samples: [[0.0; 3]; TRACK_SAMPLES],
        count: 0,
        cursor: [0; 2],
    };

    fn sample(&self, k: u64) -> Option<[f64; 3]> {
        let slot = usize::try_from(k % TRACK_SAMPLES as u64).ok()?;
        let s = self.samples.get(slot)?;
        Some([f64::from(s[0]), f64::from(s[1]), f64::from(s[2])])
    }

    fn oldest(&self) -> u64 {
        self.count.saturating_sub(TRACK_SAMPLES as u64)
    }

    fn push(&mut self, p: &Vec3, spacing_m: f64) {
        if let Some(last) = self.count.checked_sub(1).and_then(|k| self.sample(k)) {
            let (dx, dy) = (p.x - last[0], p.y - last[1]);
            if dx * dx + dy * dy < spacing_m * spacing_m {
                return;
            }
        }
        let slot = (self.count % TRACK_SAMPLES as u64) as usize;
        if let Some(s) = self.samples.get_mut(slot) {
            *s = [p.x as f32, p.y as f32, p.z as f32];
            self.count = self.count.saturating_add(1);
        }
    }

    /// Height (m, `N` down) of the remembered path under the horizontal position of `q`, found
    /// from trailing wheel `w`'s last segment by at most [`TRACK_SEARCH`] steps; `None` when
    /// `q` is before the oldest or past the newest segment, farther than `tol` from it, or
    /// more than [`TRACK_SEARCH`] segments away (the search resumes from where it stopped at
    /// the next call, so a wheel that was off the track catches up).
    fn height_under(&mut self, w: usize, q: &Vec3, tol: f64) -> Option<f64> {
        if self.count < 2 {
            return None;
        }
        let (first, last) = (self.oldest(), self.count.saturating_sub(2));
        // `max` then `min`, not `clamp` (its bound assertion is a panic path).
        let mut k = self.cursor.get(w).copied()?.max(first).min(last);
        for _ in 0..=TRACK_SEARCH {
            let a = self.sample(k)?;
            let b = self.sample(k.saturating_add(1))?;
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len2 = dx * dx + dy * dy;
            if len2 <= 0.0 {
                return None;
            }
            let (qx, qy) = (q.x - a[0], q.y - a[1]);
            let u = (qx * dx + qy * dy) / len2;
            let step = if u < 0.0 && k > first {
                Some(k.saturating_sub(1))
            } else if u > 1.0 && k < last {
                Some(k.saturating_add(1))
            } else {
                None
            };
            if let Some(next) = step {
                k = next;
                continue;
            }
            if let Some(c) = self.cursor.get_mut(w) {
                *c = k;
            }
            if !(0.0..=1.0).contains(&u) {
                return None;
            }
            let lateral = (qx * dy - qy * dx).abs() / libm::sqrt(len2);
            return (lateral <= tol).then(|| a[2] + u * (b[2] - a[2]));
        }
        if let Some(c) = self.cursor.get_mut(w) {
            *c = k;
        }
        None
    }
}

/// The front axles' paths and the statistics of their use (`N`, m).
#[derive(Debug, Clone, Copy)]
pub struct TrackMemory {
    config: TrackConfig,
    sides: [SidePath; 2],
    /// Steps with at least one trailing wheel over its side's remembered path.
    pub matched_steps: u32,
    /// Steps without (memory still filling, turning, reset).
    pub unmatched_steps: u32,
    /// Sum of the vertical corrections applied, m (`N` down).
    pub correction_sum_m: f64,
}

impl TrackMemory {
    /// An empty memory with `config`.
    pub const fn new(config: TrackConfig) -> Self {
        Self {
            config,
            sides: [SidePath::EMPTY; 2],
            matched_steps: 0,
            unmatched_steps: 0,
            correction_sum_m: 0.0,
        }
    }

    /// Forget the paths (the dead reckoning was re-anchored); the statistics stay.
    pub fn reset(&mut self) {
        self.sides = [SidePath::EMPTY; 2];
    }

    /// The tuning in use.
    pub fn config(&self) -> &TrackConfig {
        &self.config
    }

    /// The vertical correction (m, `N` down) for a body predicted at `p_n` (m, `N`) with
    /// attitude `r_nr` (`R` to `N`) and axle centres `axles_r_m` (m, `R`, index `wheel - 1`):
    /// [`TrackConfig::gain`] times the mean height difference of the trailing axles over their
    /// side's remembered path, clamped to [`TrackConfig::max_step_m`]; `None` when no trailing
    /// axle is over the path, when disabled, or on non-finite input.
    pub fn correction(
        &mut self,
        p_n: &Vec3,
        r_nr: &Mat3,
        axles_r_m: &[Vec3; WHEEL_COUNT],
    ) -> Option<f64> {
        if !self.config.enabled {
            return None;
        }
        let tol = self.config.lateral_tolerance_m;
        let (mut sum, mut n) = (0.0, 0u32);
        for (side, trailing) in self.sides.iter_mut().zip(TRAILING.iter()) {
            for (w, &wheel) in trailing.iter().enumerate() {
                let Some(a) = axles_r_m.get(wheel) else {
                    continue;
                };
                let q = p_n + r_nr * a;
                if !q.iter().all(|v| v.is_finite()) {
                    continue;
                }
                if let Some(h) = side.height_under(w, &q, tol) {
                    sum += h - q.z;
                    n += 1;
                }
            }
        }
        if n == 0 {
            self.unmatched_steps = self.unmatched_steps.saturating_add(1);
            return None;
        }
        let limit = self.config.max_step_m;
        let dz = self.config.gain * sum / f64::from(n);
        if !dz.is_finite() {
            return None;
        }
        let dz = if dz > limit {
            limit
        } else if dz < -limit {
            -limit
        } else {
            dz
        };
        self.matched_steps = self.matched_steps.saturating_add(1);
        self.correction_sum_m += dz;
        Some(dz)
    }

    /// Record the front axle centres of the body at `p_n` with attitude `r_nr` (after the
    /// step's correction), one sample per side whenever that axle has moved
    /// [`TrackConfig::spacing_m`] horizontally since its last sample.
    pub fn record(&mut self, p_n: &Vec3, r_nr: &Mat3, axles_r_m: &[Vec3; WHEEL_COUNT]) {
        if !self.config.enabled || self.config.spacing_m.is_nan() || self.config.spacing_m <= 0.0 {
            return;
        }
        for (side, &wheel) in self.sides.iter_mut().zip(FRONT.iter()) {
            if let Some(a) = axles_r_m.get(wheel) {
                let q = p_n + r_nr * a;
                if q.iter().all(|v| v.is_finite()) {
                    side.push(&q, self.config.spacing_m);
                }
            }
        }
    }
}

/// A step `t` (m, `N`) with its vertical moved by `dz` (m, `N` down) and its horizontal
/// scaled so that its 3D length stays (the rim travel measures the length, the track memory
/// the direction); when the new vertical alone is longer than the step (the rover barely
/// moved) only the vertical changes.
pub fn tilt_step(t: &Vec3, dz: f64) -> Vec3 {
    let z = t.z + dz;
    let h_old2 = t.x * t.x + t.y * t.y;
    let h_new2 = t.norm_squared() - z * z;
    if h_old2 > 0.0 && h_new2 > 0.0 {
        let s = libm::sqrt(h_new2 / h_old2);
        Vec3::new(t.x * s, t.y * s, z)
    } else {
        Vec3::new(t.x, t.y, z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level_axles(x: f64) -> [Vec3; WHEEL_COUNT] {
        // Front, middle, rear at +0.393, 0, -0.354 m (Rocky 8); right y = +0.311, left -0.311;
        // axle height 0 in R; `x` shifts all.
        let xs = [0.393 + x, 0.393 + x, x, x, -0.354 + x, -0.354 + x];
        core::array::from_fn(|i| {
            let y = if i % 2 == 0 { 0.311 } else { -0.311 };
            Vec3::new(xs[i], y, 0.0)
        })
    }

    /// Truth: the axle centres of every wheel on a sine profile of the along-track distance
    /// (wavelength 1.5 m, 8 cm peak to peak), the body driven along it in 5 mm steps whose
    /// predicted vertical is 0.5 mm off per step (a step direction 0.1 rad too steep, as a
    /// wrong common mode of the contact angles gives). The memory must not match before the
    /// middle axle reaches the front axle's first sample, and then cut the height drift (the
    /// slope error) by at least 5x: the remembered path ties the body to the ground it has
    /// already measured, whatever the ground's shape.
    #[test]
    fn kin_13_track_memory_cuts_the_slope_error_on_a_wave() {
        let profile = |x: f64| 0.04 * libm::sin(2.0 * core::f64::consts::PI * x / 1.5);
        let mut mem = TrackMemory::new(TrackConfig::DEFAULT);
        let identity = Mat3::identity();
        let bias = 0.0005;
        let mut z_err: f64 = 0.0;
        let mut first_match = None;
        let mut history = [0.0f64; 400];
        for (k, h) in history.iter_mut().enumerate() {
            let x = 0.005 * k as f64;
            // Each axle placed on the profile through its own height offset in R.
            let mut axles = level_axles(0.0);
            for a in axles.iter_mut() {
                a.z = profile(x + a.x) - profile(x);
            }
            z_err += bias;
            let p = Vec3::new(x, 0.0, profile(x) + z_err);
            if let Some(dz) = mem.correction(&p, &identity, &axles) {
                first_match.get_or_insert(x);
                z_err += dz;
            }
            mem.record(&Vec3::new(x, 0.0, profile(x) + z_err), &identity, &axles);
            *h = z_err;
        }
        let first = first_match.unwrap_or(f64::NAN);
        // The middle axle reaches the front's first sample after 0.393 m.
        assert!((0.39..0.41).contains(&first), "first match at {first}");
        // Drift per step over the last 100 steps (1.5 m to 2 m, all wheels on remembered
        // ground): at most a fifth of the uncorrected 0.5 mm.
        let rate = (history[399] - history[299]) / 100.0;
        assert!(rate.abs() < bias / 5.0, "drift {rate} m per step");
        assert!(mem.matched_steps > 300);
    }

    #[test]
    fn kin_13_track_memory_ignores_wheels_off_the_track() {
        let mut mem = TrackMemory::new(TrackConfig::DEFAULT);
        let identity = Mat3::identity();
        let axles = level_axles(0.0);
        for k in 0..200 {
            let x = 0.005 * f64::from(k);
            mem.record(&Vec3::new(x, 0.0, 0.0), &identity, &axles);
        }
        // The body moved 5 cm sideways: the trailing axles are off the front axles' tracks.
        // The middle axle is 17 segments past its search start (the oldest sample): the
        // first two calls only move the search on, the third finds the segment, off track.
        let p = Vec3::new(0.6, 0.05, 0.02);
        for _ in 0..4 {
            assert_eq!(mem.correction(&p, &identity, &axles), None);
        }
        // On the track, 2 cm too low: the correction is a tenth, clamped to 1 mm.
        let p = Vec3::new(0.6, 0.0, 0.02);
        let dz = mem.correction(&p, &identity, &axles).unwrap_or(f64::NAN);
        assert!((dz + 0.001).abs() < 1e-12, "dz {dz}");
        let p = Vec3::new(0.6, 0.0, 0.005);
        let dz = mem.correction(&p, &identity, &axles).unwrap_or(f64::NAN);
        assert!((dz + 0.0005).abs() < 1e-9, "dz {dz}");
        // Non-finite input matches nothing.
        let p = Vec3::new(f64::NAN, 0.0, 0.0);
        assert_eq!(mem.correction(&p, &identity, &axles), None);
    }

    #[test]
    fn kin_13_tilt_step_keeps_the_length() {
        let t = Vec3::new(0.004, 0.003, 0.0);
        let s = tilt_step(&t, 0.001);
        assert!((s.norm() - t.norm()).abs() < 1e-15);
        assert!((s.z - 0.001).abs() < 1e-15);
        assert!((s.y / s.x - 0.75).abs() < 1e-12);
        // Barely moving: only the vertical changes.
        let s = tilt_step(&Vec3::new(1e-4, 0.0, 0.0), 0.001);
        assert_eq!(s, Vec3::new(1e-4, 0.0, 0.001));
    }
}
