//! IMU propagation (H04 eq. 26-27 and App. B eq. 50-51).
//!
//! Nominal state, over one sample interval `dt` (trapezoidal rule on the two samples that bound
//! the interval, the previous one held, [`ImuHold`]):
//! - `w = (w_prev + w_k)/2 - b_g`, `q_{k+1} = q_k (x) exp(w dt)`, renormalized;
//! - `a_N = (C_k (f_prev - b_a) + C_{k+1} (f_k - b_a))/2 + g`;
//! - `p_{k+1} = p_k + v_k dt + a_N dt^2/2`, `v_{k+1} = v_k + a_N dt`.
//!
//! Error state: `F_c` of eq. 26 for the rover-frame attitude error has the non-zero blocks
//! `F_tt = -[w]x`, `F_tbg = -I`, `F_vt = -C [f]x`, `F_vba = -C`, `F_pv = I`. The transition
//! matrix is the second-order series `F_k = I + F_c dt + F_c^2 dt^2/2`, except `F_tt`, which is
//! the exact `exp(-[w]x dt)`; its non-identity blocks are kept in [`Transition`] and applied
//! block by block (never as a dense 15x15 or `DIM x DIM` product). `Q_k = int F G Q_c G' F'` is
//! taken to the leading order of each block (white noise integrated once into velocity and
//! twice into position; bias walks integrated into attitude, velocity and position), see
//! `docs/estimation.md`.

use super::state::{clone_index, exp_quat, renormalize, Cov, CORE_DIM, DIM};
use super::state::{rot, ImuHold, I_BA, I_BG, I_P, I_THETA, I_V};
use super::{Ekf, EstError};
use crate::types::{Mat3, Vec3};
use rover_hal::ImuSample;

/// Outcome of one propagation step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PropagationStep {
    /// Length of the step, s.
    pub dt_s: f64,
    /// True when the interval exceeded [`super::EkfConfig::max_imu_dt_us`]: the new sample was
    /// held over the whole gap (zero-order hold) instead of the trapezoidal rule.
    pub gap: bool,
}

/// The discrete error-state transition `F_k` (eq. 27), kept as the quantities its non-identity
/// blocks are made of:
/// `F_tt = exp(-[w]x dt)`, `F_tbg = -I dt + [w]x dt^2/2`,
/// `F_vt = -C [f]x dt + C [f]x [w]x dt^2/2`, `F_vbg = C [f]x dt^2/2`, `F_vba = -C dt`,
/// `F_pt = -C [f]x dt^2/2`, `F_pv = I dt`, `F_pba = -C dt^2/2`.
#[derive(Debug, Clone, Copy)]
struct Transition {
    th_th: Mat3,
    c: Mat3,
    w: Vec3,
    f: Vec3,
    dt: f64,
    h: f64,
}

impl Transition {
    /// `F_k` of eq. 27 for body rate `w` (rad/s), specific force `f` (m/s^2, rover frame),
    /// attitude `c` (`C(q_nr)`), rotation increment `delta = exp([w]x dt)`, step `dt` (s).
    fn new(w: &Vec3, f: &Vec3, c: &Mat3, delta: &Mat3, dt: f64) -> Self {
        Self {
            th_th: delta.transpose(),
            c: *c,
            w: *w,
            f: *f,
            dt,
            h: 0.5 * dt * dt,
        }
    }

    /// `col <- F_k col` for one column of the top 15 rows. The blocks are applied as cross
    /// products and two products by `C` (the zero and identity blocks are skipped; the bias rows
    /// are unchanged):
    /// - `th' = F_tt th - dt bg + h (w x bg)`;
    /// - `v' = v - C (f x u + dt ba)` with `u = dt th - h (w x th) - h bg`;
    /// - `p' = p + dt v - h C (f x th + ba)`, where `h = dt^2/2`.
    #[inline(always)]
    fn apply(&self, c: &mut [f64; CORE_DIM]) {
        let th = Vec3::new(c[I_THETA], c[I_THETA + 1], c[I_THETA + 2]);
        let bg = Vec3::new(c[I_BG], c[I_BG + 1], c[I_BG + 2]);
        let v = Vec3::new(c[I_V], c[I_V + 1], c[I_V + 2]);
        let ba = Vec3::new(c[I_BA], c[I_BA + 1], c[I_BA + 2]);
        let p = Vec3::new(c[I_P], c[I_P + 1], c[I_P + 2]);
        let (dt, h) = (self.dt, self.h);
        let th2 = self.th_th * th - bg * dt + self.w.cross(&bg) * h;
        let u = th * dt - self.w.cross(&th) * h - bg * h;
        let v2 = v - self.c * (self.f.cross(&u) + ba * dt);
        let p2 = p + v * dt - self.c * (self.f.cross(&th) + ba) * h;
        for k in 0..3 {
            c[I_THETA + k] = th2[k];
            c[I_V + k] = v2[k];
            c[I_P + k] = p2[k];
        }
    }
}

impl Ekf {
    /// IMU propagation to the sample's time (eq. 26-27, 50-51). Refuses a sample flagged
    /// invalid, non-finite values, a time stamp not after the state time, and runs nothing
    /// while a covariance fault is latched.
    pub fn propagate(&mut self, sample: &ImuSample) -> Result<PropagationStep, EstError> {
        if self.fault {
            return Err(EstError::Faulted);
        }
        if !sample.valid {
            return Err(EstError::InvalidSample);
        }
        if sample
            .gyro_rad_s
            .iter()
            .chain(sample.accel_m_s2.iter())
            .any(|v| !v.is_finite())
        {
            return Err(EstError::NonFiniteInput);
        }
        let now = self.x.t_us;
        if sample.t_us < now {
            return Err(EstError::TimeBackwards {
                state_t_us: now,
                t_us: sample.t_us,
            });
        }
        if sample.t_us == now {
            return Err(EstError::TimeNotAdvancing {
                state_t_us: now,
                t_us: sample.t_us,
            });
        }
        let new = ImuHold {
            gyro_rad_s: Vec3::from(sample.gyro_rad_s),
            accel_m_s2: Vec3::from(sample.accel_m_s2),
        };
        let dt_us = sample.t_us.saturating_sub(now);
        let gap = dt_us > self.config.max_imu_dt_us;
        let prev = match self.hold {
            Some(h) if !gap => h,
            _ => new,
        };
        let dt_s = self.step(sample.t_us, &prev, &new);
        self.hold = Some(new);
        self.check_core_health()?;
        Ok(PropagationStep { dt_s, gap })
    }

    /// Propagate to `t_us` (not before the state time) with the last sample held; used to
    /// bring the state to a clone time that falls between IMU samples.
    pub(crate) fn propagate_held(&mut self, t_us: u64) -> Result<(), EstError> {
        let now = self.x.t_us;
        if t_us < now {
            return Err(EstError::TimeBackwards {
                state_t_us: now,
                t_us,
            });
        }
        if t_us == now {
            return Ok(());
        }
        let hold = self.hold.ok_or(EstError::NoStateAtTime { t_us })?;
        self.step(t_us, &hold, &hold);
        self.check_core_health()
    }

    /// One step from the state time to `t_us` with samples `prev` (at the state time) and
    /// `new` (at `t_us`). Returns `dt` in seconds.
    fn step(&mut self, t_us: u64, prev: &ImuHold, new: &ImuHold) -> f64 {
        self.touch();
        let dt = t_us.saturating_sub(self.x.t_us) as f64 * 1.0e-6;
        let x = &mut self.x;
        let w = (prev.gyro_rad_s + new.gyro_rad_s) * 0.5 - x.b_g;
        let f_prev = prev.accel_m_s2 - x.b_a;
        let f_new = new.accel_m_s2 - x.b_a;
        let c0 = rot(&x.q_nr);
        let dq = exp_quat(&(w * dt));
        let delta = rot(&dq);
        let c1 = c0 * delta;
        x.q_nr = renormalize(&(x.q_nr * dq));
        let a_n = (c0 * f_prev + c1 * f_new) * 0.5 + self.config.gravity_n_m_s2;
        x.p_n += x.v_n * dt + a_n * (0.5 * dt * dt);
        x.v_n += a_n * dt;
        x.t_us = t_us;
        let f = (f_prev + f_new) * 0.5;
        let phi = Transition::new(&w, &f, &c0, &delta, dt);
        self.propagate_covariance(&phi, &c0);
        dt
    }

    /// `P <- F P F' + Q` (eq. 51) on the live blocks only: the core rows of every live column
    /// are multiplied by `F` (clone-clone blocks are unchanged, eq. 41), the core block is then
    /// multiplied by `F'` on the right, symmetrized, and `Q_k` added.
    fn propagate_covariance(&mut self, phi: &Transition, c: &Mat3) {
        let live = self.live_mask();
        let slice = self.p.as_mut_slice();
        // P[core, j] <- F P[core, j] for the core columns and the live clone columns.
        for (j, col) in slice.chunks_exact_mut(DIM).enumerate() {
            let is_live = j < CORE_DIM
                || live
                    .get(j.saturating_sub(CORE_DIM) / 6)
                    .copied()
                    .unwrap_or(false);
            if !is_live {
                continue;
            }
            if let Some(top) = col.get_mut(..CORE_DIM) {
                if let Ok(top) = <&mut [f64; CORE_DIM]>::try_from(top) {
                    phi.apply(top);
                }
            }
        }
        // Core block B = A F' with A = F P_cc now in place. The bias rows of F are identity
        // rows, so B[:, b] = A[:, b] for the bias columns (already in place), and only the nine
        // columns j in {theta, v, p} need B[:, j] = F A[j, :]' (B symmetric).
        const MOVING: [usize; 9] = [
            I_THETA,
            I_THETA + 1,
            I_THETA + 2,
            I_V,
            I_V + 1,
            I_V + 2,
            I_P,
            I_P + 1,
            I_P + 2,
        ];
        let mut b = [[0.0f64; CORE_DIM]; 9];
        for (bj, &j) in b.iter_mut().zip(MOVING.iter()) {
            for (k, v) in bj.iter_mut().enumerate() {
                *v = self.p[(j, k)];
            }
            phi.apply(bj);
        }
        for (bj, &j) in b.iter().zip(MOVING.iter()) {
            for (k, v) in bj.iter().enumerate() {
                self.p[(k, j)] = *v;
                self.p[(j, k)] = *v;
            }
        }
        // The theta/v/p block was written twice (rows and columns); make it exactly symmetric.
        for (a, &i) in MOVING.iter().enumerate() {
            for &j in MOVING.iter().skip(a + 1) {
                let m = 0.5 * (self.p[(i, j)] + self.p[(j, i)]);
                self.p[(i, j)] = m;
                self.p[(j, i)] = m;
            }
        }
        add_process_noise(&mut self.p, &self.config.imu_noise, c, phi.dt);
        // Clone rows of the core columns mirror the clone columns (symmetry).
        for (slot, on) in live.iter().enumerate() {
            if *on {
                let i = clone_index(slot);
                for r in 0..6 {
                    for k in 0..CORE_DIM {
                        self.p[(i + r, k)] = self.p[(k, i + r)];
                    }
                }
            }
        }
    }

    /// Health check after a propagation step (every cycle, not only after updates):
    /// the nominal state finite, and the core diagonal finite, non-negative and, for attitude
    /// and position, under [`super::EkfConfig::max_attitude_var_rad2`] and
    /// [`super::EkfConfig::max_position_var_m2`]. A failure latches the fault.
    fn check_core_health(&mut self) -> Result<(), EstError> {
        if !self.x.is_finite() {
            self.fault = true;
            return Err(EstError::CovarianceUnhealthy { index: usize::MAX });
        }
        for i in 0..CORE_DIM {
            let d = self.p[(i, i)];
            let limit = if i < 3 {
                self.config.max_attitude_var_rad2
            } else if (super::state::I_P..super::state::I_P + 3).contains(&i) {
                self.config.max_position_var_m2
            } else {
                f64::INFINITY
            };
            if !d.is_finite() || d < 0.0 || d > limit {
                self.fault = true;
                return Err(EstError::CovarianceUnhealthy { index: i });
            }
        }
        Ok(())
    }
}

/// `Q_k` (eq. 27) from the continuous densities of [`super::ImuNoise`], leading order per block:
/// attitude `s_g^2 dt + s_bg^2 dt^3/3`, attitude-gyro bias `-s_bg^2 dt^2/2`, gyro bias
/// `s_bg^2 dt`; velocity `s_a^2 dt + s_ba^2 dt^3/3`, velocity-accel bias `-C s_ba^2 dt^2/2`,
/// accel bias `s_ba^2 dt`; position-velocity `s_a^2 dt^2/2`, position `s_a^2 dt^3/3`,
/// position-accel bias `-C s_ba^2 dt^3/6`.
fn add_process_noise(core: &mut Cov, noise: &super::ImuNoise, c: &Mat3, dt: f64) {
    let sq = |v: f64| v * v;
    let qg = sq(noise.gyro_rad_s_sqrt_hz);
    let qbg = sq(noise.gyro_bias_rad_s2_sqrt_hz);
    let qa = sq(noise.accel_m_s2_sqrt_hz);
    let qba = sq(noise.accel_bias_m_s3_sqrt_hz);
    let (dt2, dt3) = (dt * dt, dt * dt * dt);
    for k in 0..3 {
        core[(I_THETA + k, I_THETA + k)] += qg * dt + qbg * dt3 / 3.0;
        core[(I_THETA + k, I_BG + k)] -= qbg * dt2 * 0.5;
        core[(I_BG + k, I_THETA + k)] -= qbg * dt2 * 0.5;
        core[(I_BG + k, I_BG + k)] += qbg * dt;
        core[(I_V + k, I_V + k)] += qa * dt + qba * dt3 / 3.0;
        core[(I_BA + k, I_BA + k)] += qba * dt;
        core[(I_P + k, I_V + k)] += qa * dt2 * 0.5;
        core[(I_V + k, I_P + k)] += qa * dt2 * 0.5;
        core[(I_P + k, I_P + k)] += qa * dt3 / 3.0;
        for m in 0..3 {
            let vba = -c[(k, m)] * qba * dt2 * 0.5;
            let pba = -c[(k, m)] * qba * dt3 / 6.0;
            core[(I_V + k, I_BA + m)] += vba;
            core[(I_BA + m, I_V + k)] += vba;
            core[(I_P + k, I_BA + m)] += pba;
            core[(I_BA + m, I_P + k)] += pba;
        }
    }
}
