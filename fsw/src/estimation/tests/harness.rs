//! Closed-loop estimator scenario: truth + noisy IMU, kinematic relative poses between clones,
//! late VO between capture clones, sun sensor; collects NEES, gate and heading statistics.

use super::truth::{gauss3, relative_pose, Motion, TruePose, Truth};
use crate::estimation::state::{exp_quat, log_quat, rot, I_P, I_THETA};
use crate::estimation::{CloneHandle, CoreCov, Ekf, EkfConfig, NominalState};
use crate::types::{Mat3, RelativePose, Vec3, Vec6};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rover_hal::SunReading;
extern crate std;
use std::vec::Vec;

/// What a run does.
#[derive(Debug, Clone, Copy)]
pub struct Scenario {
    pub motion: Motion,
    pub imu_dt_us: u64,
    pub duration_us: u64,
    /// Kinematic odometry period, noise `[rot (rad); trans (m)]`, observed mask.
    pub kin: Option<(u64, [f64; 6], [bool; 6])>,
    /// VO capture period, latency, noise.
    pub vo: Option<(u64, u64, [f64; 6])>,
    /// Sun-sensor period.
    pub sun_period_us: Option<u64>,
    /// Initial 1-sigma of `[theta (rad), b_g (rad/s), v (m/s), b_a (m/s^2), p (m)]`.
    pub p0_sigma: [f64; 5],
    /// NEES and heading sampled at this period.
    pub sample_period_us: u64,
    /// Slip probes: for each `k`, a copy of every kinematic measurement with a translation slip
    /// of `k` sigma (Mahalanobis, `s' S^-1 s = k^2`) is gated (not applied).
    pub slip_sigmas: [f64; 3],
    pub config: EkfConfig,
}

impl Scenario {
    pub fn drive() -> Self {
        let config = EkfConfig {
            sun: Some(crate::estimation::ephemeris::SunEphemeris::from_site(
                -14.6, 30.0, 10.0,
            )),
            sun_sigma_rad: 0.01,
            ..EkfConfig::default()
        };
        Self {
            motion: Motion::drive(0.08),
            imu_dt_us: 5_000,
            duration_us: 30_000_000,
            kin: Some((200_000, [2e-3, 2e-3, 2e-3, 3e-3, 3e-3, 3e-3], KIN_OBSERVED)),
            vo: Some((1_000_000, 40_000, [2e-3, 2e-3, 2e-3, 5e-3, 5e-3, 5e-3])),
            sun_period_us: Some(5_000_000),
            p0_sigma: [0.01, 5e-5, 0.01, 5e-3, 0.01],
            sample_period_us: 1_000_000,
            slip_sigmas: [0.0; 3],
            config,
        }
    }
}

/// Kinematic odometry observes 5 of 6 DOF (H04); here the vertical translation is dropped.
pub const KIN_OBSERVED: [bool; 6] = [true, true, true, true, true, false];

/// Per-run statistics.
#[derive(Debug, Clone, Default)]
pub struct RunStats {
    pub nees_theta: Vec<f64>,
    pub nees_p: Vec<f64>,
    pub heading_err_rad: Vec<f64>,
    pub heading_sigma_rad: Vec<f64>,
    pub kin_total: usize,
    pub kin_accepted: usize,
    /// Slip probes gated and rejected, per entry of `slip_sigmas`.
    pub slip_total: usize,
    pub slip_rejected: [usize; 3],
    pub vo_applied: usize,
    pub sun_applied: usize,
    pub last_err_theta: Vec3,
    pub last_err_p: Vec3,
}

/// Attitude error of the estimate (rover frame, `C_true = C_est exp([e]x)`).
pub fn theta_err(ekf: &Ekf, truth: &TruePose) -> Vec3 {
    log_quat(&(ekf.state().q_nr.inverse() * truth.q_nr))
}

fn nees3(e: &Vec3, p: &Mat3) -> f64 {
    let chol = p.cholesky().expect("covariance block positive definite");
    e.dot(&chol.solve(e))
}

/// Initial filter from the truth with a sampled initial error.
pub fn init_filter(sc: &Scenario, truth: &Truth, rng: &mut ChaCha8Rng) -> Ekf {
    let s = sc.p0_sigma;
    // The truth biases are drawn around zero with the p0 sigmas (in `run`); the estimate is
    // zero. Attitude, velocity and position errors are drawn here.
    let d_theta = gauss3(rng) * s[0];
    let x0 = NominalState {
        t_us: truth.pose.t_us,
        q_nr: truth.pose.q_nr * exp_quat(&(-d_theta)),
        b_g: Vec3::zeros(),
        v_n: truth.pose.v_n - gauss3(rng) * s[2],
        b_a: Vec3::zeros(),
        p_n: truth.pose.p_n - gauss3(rng) * s[4],
    };
    let mut p0 = CoreCov::zeros();
    for k in 0..3 {
        for (b, sig) in s.iter().enumerate() {
            p0[(3 * b + k, 3 * b + k)] = sig * sig;
        }
    }
    Ekf::new(sc.config, x0, &p0).expect("valid initial state")
}

/// Run one scenario with `seed`; `sun` enables the sun-sensor updates.
pub fn run(sc: &Scenario, seed: u64) -> RunStats {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let gb = gauss3(&mut rng) * sc.p0_sigma[1];
    let ab = gauss3(&mut rng) * sc.p0_sigma[3];
    let mut truth = Truth::new(sc.motion, sc.imu_dt_us, gb, ab);
    // The truth's IMU is the one the filter is configured for (consistency tests).
    truth.noise = sc.config.imu_noise;
    let mut ekf = init_filter(sc, &truth, &mut rng);
    let mut stats = RunStats::default();

    let mut kin_start: Option<(CloneHandle, TruePose)> = None;
    let mut vo_prev: Option<(CloneHandle, TruePose)> = None;
    // A capture whose VO result is pending: (capture clone, truth, arrival time).
    let mut vo_pending: Option<(CloneHandle, TruePose, u64)> = None;
    let every = |t: u64, period: u64| period > 0 && t % period == 0;
    loop {
        let t = truth.pose.t_us;
        if t > 0 {
            let s = truth.imu(&mut rng);
            ekf.propagate(&s).expect("propagation");
        }
        // Kinematic odometry between the clone at the interval start and the current state.
        if let Some((period, sigma, observed)) = sc.kin {
            if every(t, period) {
                if let Some((h, pose0)) = kin_start.take() {
                    let m = relative_pose(
                        &pose0,
                        &truth.pose,
                        &sigma,
                        observed,
                        Vec3::zeros(),
                        &mut rng,
                    );
                    if sc.slip_sigmas.iter().any(|k| *k > 0.0) {
                        probe_slip(&ekf, &m, sc, &mut stats);
                    }
                    let d = ekf
                        .update_relative_pose(&m, true)
                        .expect("kinematic update");
                    stats.kin_total += 1;
                    stats.kin_accepted += usize::from(d.accepted);
                    ekf.release(h).expect("release");
                }
                kin_start = Some((ekf.clone_at(t).expect("clone"), truth.pose));
            }
        }
        if let Some((period, latency, sigma)) = sc.vo {
            if let Some((h1, pose1, arrival)) = vo_pending {
                if t >= arrival {
                    if let Some((h0, pose0)) = vo_prev.take() {
                        let m = relative_pose(
                            &pose0,
                            &pose1,
                            &sigma,
                            [true; 6],
                            Vec3::zeros(),
                            &mut rng,
                        );
                        let d = ekf.update_relative_pose(&m, false).expect("VO update");
                        stats.vo_applied += usize::from(d.applied);
                        ekf.release(h0).expect("release");
                    }
                    vo_prev = Some((h1, pose1));
                    vo_pending = None;
                }
            }
            if every(t, period) && vo_pending.is_none() {
                let h = ekf.clone_at(t).expect("capture clone");
                vo_pending = Some((h, truth.pose, t + latency));
            }
        }
        if let Some(period) = sc.sun_period_us {
            if every(t, period) && t > 0 {
                let s_n = sc
                    .config
                    .sun
                    .and_then(|e| e.sun_dir_n(t))
                    .expect("sun direction");
                let n = gauss3(&mut rng) * sc.config.sun_sigma_rad;
                let s_r = exp_quat(&n) * (rot(&truth.pose.q_nr).transpose() * s_n);
                let reading = SunReading {
                    t_us: t,
                    sun_dir_rover: [s_r.x, s_r.y, s_r.z],
                    sun_in_view: true,
                };
                let u = ekf.update_sun(&reading).expect("sun update");
                stats.sun_applied += usize::from(u.applied);
            }
        }
        if every(t, sc.sample_period_us) && t > 0 {
            let p = ekf.core_covariance();
            let e_theta = theta_err(&ekf, &truth.pose);
            let e_p = truth.pose.p_n - ekf.state().p_n;
            let ptt: Mat3 = p.fixed_view::<3, 3>(I_THETA, I_THETA).into_owned();
            let ppp: Mat3 = p.fixed_view::<3, 3>(I_P, I_P).into_owned();
            stats.nees_theta.push(nees3(&e_theta, &ptt));
            stats.nees_p.push(nees3(&e_p, &ppp));
            let heading_err = (rot(&ekf.state().q_nr) * e_theta).z;
            stats.heading_err_rad.push(heading_err);
            stats.heading_sigma_rad.push(ekf.heading_sigma_rad());
            stats.last_err_theta = e_theta;
            stats.last_err_p = e_p;
        }
        if t >= sc.duration_us {
            break;
        }
        truth.advance(&mut rng);
    }
    stats
}

/// Gate copies of `m` with a slip of `k` sigma along the forward or lateral axis of `R0`
/// (alternating), `k` in `sc.slip_sigmas`: the slip `s` satisfies `s' S^-1 s = k^2`.
fn probe_slip(ekf: &Ekf, m: &RelativePose, sc: &Scenario, stats: &mut RunStats) {
    let clean = ekf.gate_relative_pose(m).expect("gate");
    let s_inv = clean
        .residual_covariance
        .try_inverse()
        .expect("S invertible");
    let axis = 3 + stats.slip_total % 2;
    let mut e = Vec6::zeros();
    e[axis] = 1.0;
    let unit_d2 = e.dot(&(s_inv * e));
    stats.slip_total += 1;
    for (j, k) in sc.slip_sigmas.iter().enumerate() {
        let alpha = k / unit_d2.sqrt();
        let mut slipped = *m;
        slipped.trans_0_1_m[axis - 3] += alpha;
        let d = ekf.gate_relative_pose(&slipped).expect("gate");
        stats.slip_rejected[j] += usize::from(!d.accepted);
    }
}
