//! Monte Carlo acceptance tests of the estimator (EST-8 to EST-12).

use super::harness::{run, RunStats, Scenario};
use super::truth::{Motion, Truth};
use super::*;
use rand::Rng;
use rand_distr::StandardNormal;
extern crate std;
use std::vec::Vec;

/// Two-sided 95% bounds of the average NEES of a 3-dof quantity over 50 runs:
/// `chi2_150(0.025)/50` and `chi2_150(0.975)/50` (117.98 and 185.80).
const NEES3_50_BOUNDS: (f64, f64) = (117.98 / 50.0, 185.80 / 50.0);

fn average(runs: &[RunStats], f: impl Fn(&RunStats) -> &Vec<f64>) -> Vec<f64> {
    let n = f(&runs[0]).len();
    (0..n)
        .map(|i| runs.iter().map(|r| f(r)[i]).sum::<f64>() / runs.len() as f64)
        .collect()
}

/// EST-8 (NEES) and EST-9 (gate acceptance): 50 runs of a 30 s drive on a rolling slope with
/// kinematic odometry at 5 Hz (5 dof), VO at 1 Hz with 40 ms latency and the sun sensor every
/// 5 s. The run-averaged NEES of attitude and position lies inside the 95% chi-square bounds at
/// (nearly) every 1 s checkpoint, and the gate accepts 95% of the consistent kinematic
/// measurements within binomial tolerance.
#[test]
fn est_8_9_monte_carlo_nees_and_gate_acceptance() {
    let sc = Scenario::drive();
    let runs: Vec<RunStats> = (0..50).map(|seed| run(&sc, 1000 + seed)).collect();
    let nees_t = average(&runs, |r| &r.nees_theta);
    let nees_p = average(&runs, |r| &r.nees_p);
    let (lo, hi) = NEES3_50_BOUNDS;
    let inside = |v: &Vec<f64>| v.iter().filter(|x| (lo..=hi).contains(*x)).count();
    std::println!("NEES attitude per checkpoint: {nees_t:.2?}");
    std::println!("NEES position per checkpoint: {nees_p:.2?}");
    let mean = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    std::println!(
        "mean NEES attitude {:.3}, position {:.3}, bounds [{lo:.3}, {hi:.3}]",
        mean(&nees_t),
        mean(&nees_p)
    );
    // With 30 checkpoints each inside with probability 0.95, at most 4 outside (P > 0.93).
    assert!(
        nees_t.len() == 30 && nees_t.len() - inside(&nees_t) <= 4,
        "attitude NEES"
    );
    assert!(nees_p.len() - inside(&nees_p) <= 4, "position NEES");
    assert!((lo..=hi).contains(&mean(&nees_t)) && (lo..=hi).contains(&mean(&nees_p)));

    let total: usize = runs.iter().map(|r| r.kin_total).sum();
    let accepted: usize = runs.iter().map(|r| r.kin_accepted).sum();
    let rate = accepted as f64 / total as f64;
    let sd = (0.95 * 0.05 / total as f64).sqrt();
    std::println!("gate: accepted {accepted} of {total} = {rate:.4} (binomial sd {sd:.4})");
    assert!((rate - 0.95).abs() <= 3.0 * sd, "acceptance {rate}");
    let vo: usize = runs.iter().map(|r| r.vo_applied).sum();
    let sun: usize = runs.iter().map(|r| r.sun_applied).sum();
    assert!(vo >= 50 * 27 && sun >= 50 * 5, "vo {vo} sun {sun}");
}

/// Power of the 5-dof test at 11.07 against a slip with non-centrality `k^2`, sampled.
fn power_5dof(k: f64, rng: &mut ChaCha8Rng) -> f64 {
    let n = 200_000;
    let hits = (0..n)
        .filter(|_| {
            let mut d2 = 0.0;
            for i in 0..5 {
                let z: f64 = rng.sample(StandardNormal);
                let z = if i == 0 { z + k } else { z };
                d2 += z * z;
            }
            d2 > 11.070
        })
        .count();
    hits as f64 / n as f64
}

/// EST-10: kinematic measurements with an injected slip (forward or lateral, `k` sigma in the
/// metric of `S`) are rejected at the rate the chi-square test predicts: at 3 sigma about 2/3 of
/// them (no 95% gate can reject every 3-sigma slip under noise), at 5 sigma 97%, at 7 sigma all.
#[test]
fn est_10_gate_rejects_injected_slip() {
    let mut sc = Scenario::drive();
    sc.duration_us = 20_000_000;
    sc.slip_sigmas = [3.0, 5.0, 7.0];
    let runs: Vec<RunStats> = (0..15).map(|seed| run(&sc, 2000 + seed)).collect();
    let total: usize = runs.iter().map(|r| r.slip_total).sum();
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    for (j, k) in sc.slip_sigmas.iter().enumerate() {
        let rejected: usize = runs.iter().map(|r| r.slip_rejected[j]).sum();
        let rate = rejected as f64 / total as f64;
        let theory = power_5dof(*k, &mut rng);
        let sd = (theory * (1.0 - theory) / total as f64).sqrt().max(1e-3);
        std::println!(
            "slip {k} sigma: rejected {rejected}/{total} = {rate:.4}, chi-square power {theory:.4}"
        );
        assert!(
            (rate - theory).abs() <= 4.0 * sd,
            "slip {k}: {rate} vs {theory}"
        );
        assert!(rate > 0.6);
    }
    let all7: usize = runs.iter().map(|r| r.slip_rejected[2]).sum();
    assert!(all7 as f64 >= 0.999 * total as f64);
}

/// EST-11: static IMU with ZUPT at 10 Hz and a zero-rate update every second: the gyro bias
/// converges on all three axes and velocity stays bounded; without ZUPT velocity drifts.
#[test]
fn est_11_static_gyro_bias_converges_zupt_bounds_velocity() {
    let run_static = |zupt: bool| {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let gb = Vector3::new(4e-5, -3e-5, 5e-5);
        let mut truth = Truth::new(
            Motion::at_rest(),
            5_000,
            gb,
            Vector3::new(2e-3, -3e-3, 1e-3),
        );
        // Gyro 1e-4 rad/s/sqrt(Hz) averaged over 1 s. The truth's biases walk at the
        // filter's densities: a bias stable to 1e-6 rad/s^2/sqrt(Hz) (the flight profile's
        // 1.9e-5 lets it wander by 1e-4 rad/s in 30 s, more than this test resolves).
        let config = EkfConfig {
            zero_rate_sigma_rad_s: 1.0e-4,
            imu_noise: ImuNoise {
                gyro_bias_rad_s2_sqrt_hz: 1.0e-6,
                ..ImuNoise::default()
            },
            ..EkfConfig::default()
        };
        truth.noise = config.imu_noise;
        let x0 = NominalState {
            q_nr: truth.pose.q_nr,
            ..NominalState::at_rest(0)
        };
        let mut ekf = Ekf::new(config, x0, &p0_diag([2e-3, 1e-4, 1e-3, 5e-3, 1e-3])).unwrap();
        let sigma0 = ekf.core_covariance()[(I_BG + 2, I_BG + 2)].sqrt();
        let (mut sum, mut n, mut vmax) = (Vector3::zeros(), 0.0, 0.0f64);
        for k in 1..=24_000u64 {
            truth.advance(&mut rng);
            let s = truth.imu(&mut rng);
            ekf.propagate(&s).unwrap();
            sum += Vector3::from(s.gyro_rad_s);
            n += 1.0;
            if zupt && k % 20 == 0 {
                ekf.update_zero_velocity(s.t_us).unwrap();
            }
            if k % 200 == 0 {
                ekf.update_zero_rate(s.t_us, &(sum / n)).unwrap();
                sum = Vector3::zeros();
                n = 0.0;
            }
            vmax = vmax.max(ekf.state().v_n.norm());
        }
        let err = truth.gyro_bias - ekf.state().b_g;
        let p = ekf.core_covariance();
        let sig = Vector3::new(p[(3, 3)].sqrt(), p[(4, 4)].sqrt(), p[(5, 5)].sqrt());
        (err, sig, sigma0, vmax)
    };
    let (err, sig, sigma0, vmax) = run_static(true);
    std::println!("static: bias error {err:?} sigma {sig:?} (initial {sigma0:e}), |v|max {vmax:e}");
    for k in 0..3 {
        assert!(
            err[k].abs() <= 3.0 * sig[k] && sig[k] < 0.25 * sigma0,
            "axis {k}"
        );
        assert!(err[k].abs() < 0.3 * sigma0, "axis {k}: {}", err[k]);
    }
    assert!(vmax < 5e-3, "|v| max {vmax}");
    let (_, _, _, vmax_free) = run_static(false);
    std::println!("static without ZUPT: |v|max {vmax_free:e}");
    assert!(vmax_free > 5.0 * vmax);
}

/// EST-12: over a 1 km traverse (0.25 m/s, 50 Hz IMU, kinematic odometry at 2 Hz) the heading
/// error stays bounded with sun-sensor updates every 10 s and grows without them.
#[test]
fn est_12_heading_bounded_with_sun_over_1km() {
    let mut sc = Scenario::drive();
    sc.motion = Motion::drive(0.25);
    sc.imu_dt_us = 20_000;
    sc.duration_us = 4_000_000_000;
    sc.kin = Some((
        500_000,
        [2e-3, 2e-3, 2e-3, 5e-3, 5e-3, 5e-3],
        super::harness::KIN_OBSERVED,
    ));
    sc.vo = None;
    sc.sun_period_us = Some(10_000_000);
    sc.sample_period_us = 100_000_000;
    // A gyro bias stable to 1e-6 rad/s^2/sqrt(Hz) (truth and filter): the bounds below are
    // those of the sun sensor over a stable gyro; with the flight profile's 1.9e-5 the heading
    // between two sun readings 10 s apart wanders by about 0.5 deg.
    sc.config.imu_noise.gyro_bias_rad_s2_sqrt_hz = 1.0e-6;
    let with: Vec<RunStats> = (0..2).map(|s| run(&sc, 3000 + s)).collect();
    sc.sun_period_us = None;
    let without: Vec<RunStats> = (0..2).map(|s| run(&sc, 3000 + s)).collect();
    let rms = |runs: &[RunStats], i: usize| {
        (runs
            .iter()
            .map(|r| r.heading_err_rad[i].powi(2))
            .sum::<f64>()
            / runs.len() as f64)
            .sqrt()
    };
    let n = with[0].heading_err_rad.len();
    assert_eq!(n, 40);
    let sig_with: Vec<f64> = with[0].heading_sigma_rad.clone();
    let sig_without: Vec<f64> = without[0].heading_sigma_rad.clone();
    std::println!(
        "heading sigma with sun (deg, per 25 m):    {:.3?}",
        sig_with.iter().map(|v| v.to_degrees()).collect::<Vec<_>>()
    );
    std::println!(
        "heading sigma without sun (deg, per 25 m): {:.3?}",
        sig_without
            .iter()
            .map(|v| v.to_degrees())
            .collect::<Vec<_>>()
    );
    std::println!(
        "heading rms error at 1 km: with {:.3} deg, without {:.3} deg",
        rms(&with, n - 1).to_degrees(),
        rms(&without, n - 1).to_degrees()
    );
    let max_with = (0..n).map(|i| rms(&with, i)).fold(0.0, f64::max);
    // Bounded: errors and sigma stay at the sun-sensor level for the whole kilometre.
    assert!(max_with < 0.01, "max heading rms with sun {max_with}");
    assert!(sig_with.iter().all(|s| *s < 0.006));
    // Grows without: sigma increases along the traverse and ends far above the sun case.
    assert!(sig_without[n - 1] > sig_without[n / 2] && sig_without[n / 2] > sig_without[2]);
    assert!(sig_without[n - 1] > 4.0 * sig_with[n - 1]);
    for r in &without {
        for (e, s) in r.heading_err_rad.iter().zip(&r.heading_sigma_rad) {
            assert!(e.abs() < 4.0 * s, "error {e} sigma {s}");
        }
    }
}
