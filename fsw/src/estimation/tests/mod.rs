//! Tests of the estimator (requirement ids EST-n, see `docs/requirements.md`).
extern crate std;

mod harness;
mod monte_carlo;
mod truth;

use super::state::{log_quat, ErrorVec, I_BA, I_BG, I_P, I_THETA, I_V};
use super::*;
use crate::types::{Mat6, Quat, RelativePose};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rover_hal::{ImuSample, SunReading};
use truth::{relative_pose, Motion, Truth};

fn quiet_config() -> EkfConfig {
    EkfConfig {
        imu_noise: ImuNoise {
            gyro_rad_s_sqrt_hz: 0.0,
            gyro_bias_rad_s2_sqrt_hz: 0.0,
            accel_m_s2_sqrt_hz: 0.0,
            accel_bias_m_s3_sqrt_hz: 0.0,
        },
        ..EkfConfig::default()
    }
}

fn p0_diag(s: [f64; 5]) -> CoreCov {
    let mut p = CoreCov::zeros();
    for b in 0..5 {
        for k in 0..3 {
            p[(3 * b + k, 3 * b + k)] = s[b] * s[b];
        }
    }
    p
}

fn rest_sample(t_us: u64) -> ImuSample {
    ImuSample {
        t_us,
        gyro_rad_s: [0.0; 3],
        accel_m_s2: [0.0, 0.0, -MARS_GRAVITY_M_S2],
        valid: true,
    }
}

/// Error-state difference `b - a` in the filter's convention (core only).
fn core_diff(a: &NominalState, b: &NominalState) -> SVectorCore {
    let mut d = SVectorCore::zeros();
    let dth = log_quat(&(a.q_nr.inverse() * b.q_nr));
    let parts = [
        dth,
        b.b_g - a.b_g,
        b.v_n - a.v_n,
        b.b_a - a.b_a,
        b.p_n - a.p_n,
    ];
    for (i, v) in parts.iter().enumerate() {
        d.fixed_rows_mut::<3>(3 * i).copy_from(v);
    }
    d
}
type SVectorCore = nalgebra::SVector<f64, CORE_DIM>;

#[test]
fn est_1_static_level_propagation_stays_at_rest() {
    let mut ekf = Ekf::new(
        quiet_config(),
        NominalState::at_rest(0),
        &p0_diag([0.01; 5]),
    )
    .unwrap();
    for k in 1..=2000u64 {
        ekf.propagate(&rest_sample(k * 5_000)).unwrap();
    }
    let x = ekf.state();
    assert_eq!(x.t_us, 10_000_000);
    assert!(x.v_n.norm() < 1e-12, "v = {}", x.v_n);
    assert!(x.p_n.norm() < 1e-12, "p = {}", x.p_n);
    assert!(log_quat(&x.q_nr).norm() < 1e-15);
    // Covariance stays symmetric.
    let p = ekf.covariance();
    assert!((p - p.transpose()).amax() == 0.0);
}

/// EST-2: the discrete transition `F_k` (eq. 27) is the Jacobian of the nominal step: a
/// rank-one covariance `dx dx'` propagates to `(F dx)(F dx)'`, compared with the difference of
/// two nominal propagations started `dx` apart, for each error component.
#[test]
fn est_2_transition_matches_nonlinear_step() {
    let motion = Motion::drive(0.1);
    let t0 = 3.7;
    let x0 = NominalState {
        t_us: 1_000_000,
        q_nr: motion.q_nr(t0),
        b_g: Vector3::new(1e-4, -2e-4, 3e-4),
        v_n: motion.v_n(t0),
        b_a: Vector3::new(0.01, -0.02, 0.005),
        p_n: Vector3::new(1.0, 2.0, 0.3),
    };
    let w = motion.omega_r(t0) + Vector3::new(0.05, -0.1, 0.2);
    let f = motion.f_r(t0) + Vector3::new(0.3, -0.2, 0.1);
    let s0 = ImuSample {
        t_us: 1_000_000,
        gyro_rad_s: [w.x, w.y, w.z],
        accel_m_s2: [f.x, f.y, f.z],
        valid: true,
    };
    let mut s1 = s0;
    s1.t_us = 1_005_000;
    s1.gyro_rad_s[2] += 0.01;
    s1.accel_m_s2[0] += 0.05;
    let eps = [1e-5, 1e-6, 1e-5, 1e-5, 1e-5];
    for i in 0..CORE_DIM {
        let mut dx = ErrorVec::zeros();
        dx[i] = eps[i / 3];
        let dx15 = dx.fixed_rows::<CORE_DIM>(0).into_owned();
        let p0 = dx15 * dx15.transpose();
        let mut a = Ekf::new(quiet_config(), x0, &p0).unwrap();
        let mut b = Ekf::new(quiet_config(), x0, &CoreCov::zeros()).unwrap();
        b.inject(&dx);
        // Give both filters the first sample as the held sample.
        a.hold = Some(state::ImuHold {
            gyro_rad_s: w,
            accel_m_s2: f,
        });
        b.hold = a.hold;
        a.propagate(&s1).unwrap();
        b.propagate(&s1).unwrap();
        let delta = core_diff(a.state(), b.state());
        let expect = delta * delta.transpose();
        let got = a.core_covariance();
        let err = (got - expect).norm();
        assert!(
            err <= 1e-4 * expect.norm() + 1e-22,
            "column {i}: |P - d d'| = {err:e}, |d d'| = {:e}",
            expect.norm()
        );
    }
}

/// EST-3: the relative-pose Jacobian (eq. 31, 39-40) matches finite differences of the residual
/// for the clone endpoint and for the current-state endpoint.
#[test]
fn est_3_relative_pose_jacobian_matches_finite_differences() {
    let motion = Motion::drive(0.1);
    let mut truth = Truth::new(motion, 5_000, Vector3::zeros(), Vector3::zeros());
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut ekf = Ekf::new(
        EkfConfig::default(),
        NominalState::at_rest(0),
        &p0_diag([0.01, 1e-4, 0.01, 1e-3, 0.01]),
    )
    .unwrap();
    ekf.reset(
        NominalState {
            q_nr: motion.q_nr(0.0),
            v_n: motion.v_n(0.0),
            ..NominalState::at_rest(0)
        },
        &p0_diag([0.01, 1e-4, 0.01, 1e-3, 0.01]),
    )
    .unwrap();
    ekf.clone_at(0).unwrap();
    for _ in 0..400 {
        truth.advance(&mut rng);
        ekf.propagate(&truth.imu(&mut rng)).unwrap();
    }
    // The measurement the filter predicts (zero residual), so the finite differences see the
    // Jacobian and not the curvature of the rotation log at a non-zero residual.
    let (q0, p0) = ekf.clone_pose(ekf.clone_handle(0).unwrap()).unwrap();
    let x = ekf.state();
    let m = RelativePose {
        t0_us: 0,
        t1_us: x.t_us,
        rot_0_1: q0.inverse() * x.q_nr,
        trans_0_1_m: q0.inverse() * (x.p_n - p0),
        covariance: Mat6::identity() * 1e-6,
        observed: [true; 6],
    };
    let (inn, dof) = ekf.relative_pose_innovation(&m).unwrap();
    assert_eq!(dof, 6);
    let eps = 1e-7;
    for (c, &col) in inn.cols.iter().enumerate() {
        let mut dx = ErrorVec::zeros();
        dx[col] = eps;
        let mut e2 = ekf.clone();
        e2.inject(&dx);
        let (inn2, _) = e2.relative_pose_innovation(&m).unwrap();
        let numeric = (inn2.r - inn.r) / eps;
        let analytic = -inn.h.column(c);
        assert!(
            (numeric - analytic).amax() < 1e-5,
            "column {col}: numeric {numeric} analytic {analytic}"
        );
    }
}

/// EST-4: bad inputs are refused with an error value and leave the state unchanged.
#[test]
fn est_4_bad_inputs_are_refused() {
    let mut ekf = Ekf::new(
        quiet_config(),
        NominalState::at_rest(1000),
        &p0_diag([0.01; 5]),
    )
    .unwrap();
    let before = ekf.clone();
    let mut s = rest_sample(2000);
    s.gyro_rad_s[1] = f64::NAN;
    assert_eq!(ekf.propagate(&s), Err(EstError::NonFiniteInput));
    let mut s = rest_sample(2000);
    s.accel_m_s2[0] = f64::INFINITY;
    assert_eq!(ekf.propagate(&s), Err(EstError::NonFiniteInput));
    let mut s = rest_sample(2000);
    s.valid = false;
    assert_eq!(ekf.propagate(&s), Err(EstError::InvalidSample));
    assert!(matches!(
        ekf.propagate(&rest_sample(999)),
        Err(EstError::TimeBackwards { .. })
    ));
    assert!(matches!(
        ekf.propagate(&rest_sample(1000)),
        Err(EstError::TimeNotAdvancing { .. })
    ));
    assert!(matches!(
        ekf.clone_at(999),
        Err(EstError::TimeBackwards { .. })
    ));
    assert_eq!(ekf.state(), before.state());
    assert_eq!(ekf.covariance(), before.covariance());

    // Gap: flagged, still propagated.
    let step = ekf.propagate(&rest_sample(1_000_000)).unwrap();
    assert!(step.gap);
    assert!(!ekf.propagate(&rest_sample(1_005_000)).unwrap().gap);

    // Relative poses: malformed, unknown endpoints.
    let good = RelativePose {
        t0_us: 1_000_000,
        t1_us: 1_005_000,
        rot_0_1: Quat::identity(),
        trans_0_1_m: Vector3::zeros(),
        covariance: Mat6::identity() * 1e-6,
        observed: [true; 6],
    };
    assert_eq!(
        ekf.gate_relative_pose(&good),
        Err(EstError::NoStateAtTime { t_us: 1_000_000 })
    );
    let h = ekf.clone_at(1_005_000).unwrap();
    ekf.propagate(&rest_sample(1_010_000)).unwrap();
    let mut m = good;
    m.t0_us = 1_005_000;
    m.t1_us = 1_007_000;
    assert_eq!(
        ekf.gate_relative_pose(&m),
        Err(EstError::NoStateAtTime { t_us: 1_007_000 })
    );
    m.t1_us = 1_005_000;
    assert_eq!(
        ekf.gate_relative_pose(&m),
        Err(EstError::InvalidMeasurement)
    );
    m.t1_us = 1_010_000;
    assert!(ekf.gate_relative_pose(&m).is_ok());
    let mut bad = m;
    bad.trans_0_1_m.x = f64::NAN;
    assert_eq!(
        ekf.update_relative_pose(&bad, true),
        Err(EstError::NonFiniteInput)
    );
    let mut bad = m;
    bad.observed = [false; 6];
    assert_eq!(
        ekf.update_relative_pose(&bad, true),
        Err(EstError::InvalidMeasurement)
    );
    let mut bad = m;
    bad.covariance[(2, 2)] = 0.0;
    assert_eq!(
        ekf.update_relative_pose(&bad, true),
        Err(EstError::InvalidMeasurement)
    );

    // Sun sensor: no ephemeris, not in view, not a unit vector, stale.
    let sun = SunReading {
        t_us: 1_010_000,
        sun_dir_rover: [1.0, 0.0, 0.0],
        sun_in_view: true,
    };
    assert_eq!(ekf.update_sun(&sun), Err(EstError::SunUnavailable));
    ekf.config.sun = Some(crate::estimation::ephemeris::SunEphemeris::from_site(
        -90.0, 0.0, 12.0,
    )); // s_N = north
    assert_eq!(
        ekf.update_sun(&SunReading {
            sun_in_view: false,
            ..sun
        }),
        Err(EstError::SunUnavailable)
    );
    assert_eq!(
        ekf.update_sun(&SunReading {
            sun_dir_rover: [2.0, 0.0, 0.0],
            ..sun
        }),
        Err(EstError::InvalidMeasurement)
    );
    assert_eq!(
        ekf.update_sun(&SunReading {
            sun_dir_rover: [f64::NAN, 0.0, 0.0],
            ..sun
        }),
        Err(EstError::NonFiniteInput)
    );
    assert_eq!(
        ekf.update_sun(&SunReading {
            t_us: 900_000,
            ..sun
        }),
        Err(EstError::StaleMeasurement)
    );
    assert!(ekf.update_sun(&sun).unwrap().applied);
    assert_eq!(ekf.update_zero_velocity(0), Err(EstError::StaleMeasurement));
    assert_eq!(
        ekf.update_zero_rate(1_010_000, &Vector3::new(f64::NAN, 0.0, 0.0)),
        Err(EstError::NonFiniteInput)
    );

    // Clone window: full, stale handles.
    let mut handles = [h; MAX_CLONES];
    for (k, slot) in handles.iter_mut().enumerate().skip(1) {
        ekf.propagate(&rest_sample(1_010_000 + 5_000 * k as u64))
            .unwrap();
        *slot = ekf.clone_at(ekf.time_us()).unwrap();
    }
    assert_eq!(ekf.clone_count(), MAX_CLONES);
    ekf.propagate(&rest_sample(1_100_000)).unwrap();
    assert_eq!(ekf.clone_at(1_100_000), Err(EstError::CloneWindowFull));
    ekf.release(handles[0]).unwrap();
    assert_eq!(ekf.release(handles[0]), Err(EstError::UnknownClone));
    let reused = ekf.clone_at(1_100_000).unwrap();
    assert_eq!(ekf.clone_pose(handles[0]), Err(EstError::UnknownClone));
    assert!(ekf.clone_pose(reused).is_ok());

    // Covariance health: an attitude variance above the limit latches a fault.
    let mut p0 = p0_diag([0.01; 5]);
    p0[(0, 0)] = 2.0;
    ekf.reset(NominalState::at_rest(0), &p0).unwrap();
    assert!(matches!(
        ekf.update_zero_velocity(0),
        Err(EstError::CovarianceUnhealthy { index: 0 })
    ));
    assert!(ekf.fault());
    assert_eq!(ekf.propagate(&rest_sample(5000)), Err(EstError::Faulted));
    ekf.reset(NominalState::at_rest(0), &p0_diag([0.01; 5]))
        .unwrap();
    assert!(!ekf.fault());
    assert!(ekf.propagate(&rest_sample(5000)).is_ok());
}

/// EST-5: clones are reference counted by time stamp; releasing the last reference clears the
/// clone's covariance rows and columns; a clone between IMU samples propagates to its time.
#[test]
fn est_5_clone_window_reference_counting() {
    let mut ekf = Ekf::new(
        quiet_config(),
        NominalState::at_rest(0),
        &p0_diag([0.01; 5]),
    )
    .unwrap();
    ekf.propagate(&rest_sample(5_000)).unwrap();
    let a = ekf.clone_at(5_000).unwrap();
    let b = ekf.clone_at(5_000).unwrap();
    assert_eq!(a, b);
    assert_eq!(ekf.clone_count(), 1);
    let i = state::clone_index(0);
    assert_eq!(
        ekf.covariance()[(i, i)],
        ekf.covariance()[(I_THETA, I_THETA)]
    );
    assert_eq!(ekf.covariance()[(i + 3, I_P)], ekf.covariance()[(I_P, I_P)]);
    // Clone at a time between samples: the state is brought to that time.
    let c = ekf.clone_at(7_500).unwrap();
    assert_eq!(ekf.time_us(), 7_500);
    assert_eq!(c.t_us(), 7_500);
    ekf.propagate(&rest_sample(10_000)).unwrap();
    ekf.release(a).unwrap();
    assert_eq!(ekf.clone_count(), 2);
    ekf.release(b).unwrap();
    assert_eq!(ekf.clone_count(), 1);
    assert!(ekf.covariance().row(i).iter().all(|v| *v == 0.0));
    assert!(ekf.covariance().column(i + 5).iter().all(|v| *v == 0.0));
    assert!(ekf.clone_handle(7_500).is_some());
    assert!(ekf.clone_handle(5_000).is_none());
}

/// A filter initialised on a 0.1 m/s drive and 600 IMU samples (3 s) of it with their true
/// poses (EST-6, EST-6b).
/// The VO relative pose of the late-update tests between two true poses (with a 4 mm bias
/// along x, so that the update moves the filter).
fn late_vo_pose(
    from: &truth::TruePose,
    to: &truth::TruePose,
    rng: &mut ChaCha8Rng,
) -> RelativePose {
    relative_pose(
        from,
        to,
        &[2e-3, 2e-3, 2e-3, 5e-3, 5e-3, 5e-3],
        [true; 6],
        Vector3::new(0.004, 0.0, 0.0),
        rng,
    )
}

fn late_vo_drive(
    seed: u64,
) -> (
    Ekf,
    std::vec::Vec<ImuSample>,
    std::vec::Vec<truth::TruePose>,
    ChaCha8Rng,
) {
    let motion = Motion::drive(0.1);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut truth = Truth::new(
        motion,
        5_000,
        Vector3::new(3e-5, -2e-5, 4e-5),
        Vector3::new(2e-3, -1e-3, 3e-3),
    );
    let sc = harness::Scenario::drive();
    let ekf = harness::init_filter(&sc, &truth, &mut rng);
    let mut samples = std::vec::Vec::new();
    let mut truth_poses = std::vec::Vec::new();
    for _ in 0..900 {
        truth.advance(&mut rng);
        samples.push(truth.imu(&mut rng));
        truth_poses.push(truth.pose);
    }
    (ekf, samples, truth_poses, rng)
}

/// EST-6: a VO result that arrives frames after its capture, applied at the capture clones,
/// gives the same clone states, residual and `d_m^2` (to 1e-9) as the same update applied at
/// capture time; the current state receives the correction through the cross-covariance and
/// differs from "update at capture, then propagate" only at second order.
#[test]
fn est_6_late_vo_equals_update_at_capture() {
    let (ekf, samples, truth_poses, mut rng) = late_vo_drive(6);
    let (capture0, capture1, arrival) = (100usize, 300usize, 340usize);
    let poses = [truth_poses[capture0], truth_poses[capture1]];
    let mut late = ekf.clone();
    let mut on_time = ekf.clone();
    let mut h = std::vec::Vec::new();
    for (k, s) in samples.iter().enumerate() {
        late.propagate(s).unwrap();
        if k == capture0 || k == capture1 {
            h.push(late.clone_at(s.t_us).unwrap());
        }
        if k == arrival {
            break;
        }
    }
    let m = relative_pose(
        &poses[0],
        &poses[1],
        &[2e-3, 2e-3, 2e-3, 5e-3, 5e-3, 5e-3],
        [true; 6],
        Vector3::new(0.004, 0.0, 0.0),
        &mut rng,
    );
    let d_late = late.update_relative_pose(&m, false).unwrap();
    // The same measurement applied at capture time, between the first clone and the state.
    let mut h_on = std::vec::Vec::new();
    for (k, s) in samples.iter().enumerate() {
        on_time.propagate(s).unwrap();
        if k == capture0 || k == capture1 {
            h_on.push(on_time.clone_at(s.t_us).unwrap());
        }
        if k == capture1 {
            break;
        }
    }
    let d_on = on_time.update_relative_pose(&m, false).unwrap();
    assert!(d_late.applied && d_on.applied);
    assert!((d_late.d2 - d_on.d2).abs() <= 1e-9 * d_on.d2.max(1.0));
    assert!((d_late.residual - d_on.residual).amax() <= 1e-12);
    for k in 0..2 {
        let (ql, pl) = late.clone_pose(h[k]).unwrap();
        let (qo, po) = on_time.clone_pose(h_on[k]).unwrap();
        assert!(
            log_quat(&(ql.inverse() * qo)).norm() <= 1e-9,
            "clone {k} attitude"
        );
        assert!((pl - po).norm() <= 1e-9, "clone {k} position");
    }
    // The on-time state at capture 1 is the clone; its correction equals the late clone's.
    let (ql, pl) = late.clone_pose(h[1]).unwrap();
    assert!(log_quat(&(ql.inverse() * on_time.state().q_nr)).norm() <= 1e-9);
    assert!((pl - on_time.state().p_n).norm() <= 1e-9);
    // Current state: propagate the on-time filter to the arrival time and compare.
    for s in samples.iter().take(arrival + 1).skip(capture1 + 1) {
        on_time.propagate(s).unwrap();
    }
    let d = core_diff(late.state(), on_time.state());
    std::println!(
        "late VO vs at-capture, current state difference: {:?}",
        d.as_slice()
    );
    assert!(d.fixed_rows::<3>(I_THETA).norm() < 1e-7);
    assert!(d.fixed_rows::<3>(I_V).norm() < 1e-5);
    assert!(d.fixed_rows::<3>(I_P).norm() < 1e-6);
    assert!(d.fixed_rows::<3>(I_BG).norm() < 1e-9 && d.fixed_rows::<3>(I_BA).norm() < 1e-9);
}

/// EST-6b: with a [`super::Recorder`] started at the capture, the late VO update restores the
/// filter at capture time, applies the update there and replays what happened since (IMU
/// samples, a kinematic interval with its clone and release): the current state and covariance
/// equal, to 1e-9, those of the filter that applied the same update at capture time.
#[test]
fn est_6b_late_vo_by_replay_equals_update_at_capture() {
    let (ekf, samples, truth_poses, mut rng) = late_vo_drive(61);
    let (capture0, capture1, kin0, kin1, arrival) = (100usize, 300, 320, 330, 400);
    let vo = late_vo_pose(&truth_poses[capture0], &truth_poses[capture1], &mut rng);
    let kin = relative_pose(
        &truth_poses[kin0],
        &truth_poses[kin1],
        &[1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3],
        [true, true, true, true, true, false],
        Vector3::zeros(),
        &mut rng,
    );
    // Live filter with a recorder; the reference applies VO at capture time.
    let mut live = ekf.clone();
    let mut reference = ekf.clone();
    let mut recorder = super::Recorder::new();
    for (k, s) in samples.iter().enumerate().take(arrival + 1) {
        live.propagate(s).unwrap();
        reference.propagate(s).unwrap();
        if recorder.active() {
            recorder.propagate(s);
        }
        if k == capture0 || k == capture1 {
            live.clone_at(s.t_us).unwrap();
            reference.clone_at(s.t_us).unwrap();
        }
        if k == capture1 {
            recorder.begin(&live);
            reference.update_relative_pose(&vo, false).unwrap();
        }
        if k == kin0 {
            for f in [&mut live, &mut reference] {
                f.clone_at(s.t_us).unwrap();
            }
            recorder.clone_at(s.t_us);
        }
        if k == kin1 {
            for f in [&mut live, &mut reference] {
                f.update_relative_pose(&kin, true).unwrap();
                let h = f.clone_handle(kin.t0_us).unwrap();
                f.release(h).unwrap();
            }
            recorder.relative_pose(&kin, true);
            recorder.release(kin.t0_us);
        }
    }
    assert!(recorder.active() && !recorder.overflowed());
    let d = recorder.apply_late(&mut live, &vo, false).unwrap();
    assert!(d.applied);
    let diff = core_diff(live.state(), reference.state());
    std::println!("late VO by replay vs at-capture: {:?}", diff.as_slice());
    assert!(diff.norm() <= 1e-9, "state differs: {diff:?}");
    let dp = (live.covariance() - reference.covariance()).amax();
    assert!(dp <= 1e-9, "covariance differs by {dp}");
    assert_eq!(live.clone_count(), reference.clone_count());
    assert!(!recorder.active());
    // Without a recording the late update is refused and the filter is unchanged.
    let before = live.state().p_n;
    assert!(recorder.apply_late(&mut live, &vo, false).is_err());
    assert_eq!(live.state().p_n, before);
}

/// EST-6c: the sliced replay (a few operations per call while the live filter goes on) gives
/// the same filter, bit for bit, as the one-shot replay at the moment it catches up; an
/// overflowed recording is abandoned and leaves the live filter alone.
#[test]
fn est_6c_sliced_replay_equals_one_shot_replay() {
    let (ekf, samples, truth_poses, mut rng) = late_vo_drive(62);
    let (capture0, capture1, arrival) = (100usize, 300, 400);
    let vo = late_vo_pose(&truth_poses[capture0], &truth_poses[capture1], &mut rng);
    let mut live = ekf.clone();
    let mut recorder = super::Recorder::new();
    for (k, s) in samples.iter().enumerate().take(arrival + 1) {
        live.propagate(s).unwrap();
        recorder.propagate(s);
        if k == capture0 || k == capture1 {
            live.clone_at(s.t_us).unwrap();
        }
        if k == capture1 {
            recorder.begin(&live);
        }
    }
    let (mut one_shot, mut one_shot_recorder) = (live.clone(), recorder.clone());
    let (mut filter, mut overflow_recorder) = (live.clone(), recorder.clone());
    let d = recorder.start_late(&vo, false).unwrap();
    assert!(d.applied && recorder.replaying());
    // A second start is refused (and ends that recording).
    let mut twice = recorder.clone();
    assert!(twice.start_late(&vo, false).is_err() && !twice.active());
    let mut caught_up = None;
    for (k, s) in samples.iter().enumerate().skip(arrival + 1).take(60) {
        for (f, r) in [
            (&mut live, &mut recorder),
            (&mut one_shot, &mut one_shot_recorder),
        ] {
            f.propagate(s).unwrap();
            r.propagate(s);
        }
        if k == arrival + 10 {
            // A live measurement while the replay runs: recorded, and replayed too.
            for (f, r) in [
                (&mut live, &mut recorder),
                (&mut one_shot, &mut one_shot_recorder),
            ] {
                f.clone_at(s.t_us).unwrap();
                r.clone_at(s.t_us);
            }
        }
        match recorder.replay_step(&mut live, 7) {
            super::ReplayProgress::Working => {}
            super::ReplayProgress::Done => {
                caught_up = Some(k);
                break;
            }
            other => panic!("unexpected {other:?}"),
        }
    }
    let k = caught_up.expect("the replay catches up");
    assert!(k > arrival + 10, "{k}: the replay took several slices");
    one_shot_recorder
        .apply_late(&mut one_shot, &vo, false)
        .unwrap();
    assert_eq!(live.state(), one_shot.state());
    assert_eq!(live.covariance(), one_shot.covariance());
    assert!(!recorder.active() && !recorder.replaying());
    assert_eq!(
        recorder.replay_step(&mut live, 7),
        super::ReplayProgress::Idle
    );
    // Overflow while replaying: abandoned, the live filter untouched.
    overflow_recorder.start_late(&vo, false).unwrap();
    for s in samples
        .iter()
        .skip(arrival + 1)
        .take(super::replay::REPLAY_IMU)
    {
        filter.propagate(s).unwrap();
        overflow_recorder.propagate(s);
    }
    let before = filter.clone();
    assert_eq!(
        overflow_recorder.replay_step(&mut filter, 7),
        super::ReplayProgress::Abandoned
    );
    assert_eq!(filter.state(), before.state());
    assert!(!overflow_recorder.active());
}

/// The chi-square distribution function with `k` degrees of freedom at `x`: the regularised
/// lower incomplete gamma function `P(k/2, x/2)` by its power series (converges for every `x`;
/// 200 terms are far more than the quantiles below need).
fn chi2_cdf(k: usize, x: f64) -> f64 {
    let (a, z) = (0.5 * k as f64, 0.5 * x);
    let mut term = 1.0 / a;
    let mut sum = term;
    for n in 1..200 {
        term *= z / (a + n as f64);
        sum += term;
    }
    libm::exp(a * libm::log(z) - z - libm::lgamma(a)) * sum
}

/// EST-7: the gates' chi-square tables (H04 eq. 46; kinematic odometry 5 dof, 11.07) are the
/// 95 % and 99.9 % quantiles: the distribution function, computed independently of the tables,
/// is 0.95 and 0.999 at every entry (to the tables' three decimals), and dof outside 1..6 has
/// no threshold.
#[test]
fn est_7_chi_square_table() {
    for k in 1..=6 {
        let (Some(t95), Some(t999)) = (gate::chi2_95(k), gate::chi2_999(k)) else {
            panic!("no threshold for {k} dof");
        };
        // Half a unit of the third decimal moves the distribution function by at most the
        // density there times 5e-4.
        assert!(
            (chi2_cdf(k, t95) - 0.95).abs() < 5e-5,
            "{k} dof: {}",
            chi2_cdf(k, t95)
        );
        assert!(
            (chi2_cdf(k, t999) - 0.999).abs() < 5e-6,
            "{k} dof: {}",
            chi2_cdf(k, t999)
        );
    }
    assert!((chi2_cdf(2, 2.0 * core::f64::consts::LN_2) - 0.5).abs() < 1e-12);
    assert_eq!(gate::chi2_95(0), None);
    assert_eq!(gate::chi2_95(7), None);
    assert_eq!(gate::chi2_999(7), None);
}

use nalgebra::Vector3;

/// EST-8: `update_relative_pose_allowance` gates on every observed component at the
/// measurement's own covariance and fuses with the allowance: with no allowance it is
/// bit-identical to the gated update; with an infinite lateral allowance it gives the same
/// gate decision as the full measurement and the same state as fusing the measurement without
/// that component; a finite allowance equals fusing with that variance added; a rejected
/// measurement changes nothing.
#[test]
fn est_8_subset_update_gates_whole_and_fuses_part() {
    let (ekf, samples, truth_poses, mut rng) = late_vo_drive(8);
    let mut base = ekf.clone();
    let mut h0 = None;
    for (k, s) in samples.iter().enumerate().take(201) {
        base.propagate(s).unwrap();
        if k == 100 {
            h0 = Some(base.clone_at(s.t_us).unwrap());
        }
    }
    assert!(h0.is_some());
    // A measurement with a 3 mm lateral offset, within the gate.
    let m = relative_pose(
        &truth_poses[100],
        &truth_poses[200],
        &[2e-3, 2e-3, 2e-3, 5e-3, 5e-3, 5e-3],
        [true, true, true, true, true, false],
        Vector3::new(0.0, 0.003, 0.0),
        &mut rng,
    );
    let mut full = base.clone();
    let mut all = base.clone();
    let d_full = full.update_relative_pose(&m, true).unwrap();
    let d_all = all.update_relative_pose_allowance(&m, [0.0; 6]).unwrap();
    assert!(d_full.accepted && d_full.applied && d_all.applied);
    assert_eq!(full.state(), all.state());
    assert_eq!(full.covariance(), all.covariance());

    let keep = [0.0, 0.0, 0.0, 0.0, f64::INFINITY, 0.0];
    let mut sub = base.clone();
    let d_sub = sub.update_relative_pose_allowance(&m, keep).unwrap();
    assert_eq!(d_sub.d2, d_full.d2);
    let mut reduced = m;
    reduced.observed[4] = false;
    let mut reference = base.clone();
    reference.update_relative_pose(&reduced, false).unwrap();
    let d = core_diff(sub.state(), reference.state());
    assert!(d.norm() < 1e-12, "{:?}", d.as_slice());
    // The lateral offset was not fused: the full update moved the state further sideways.
    let lateral = |e: &Ekf| {
        let q = e.state().q_nr;
        q.inverse_transform_vector(&e.state().p_n).y
    };
    assert!((lateral(&full) - lateral(&base)).abs() > (lateral(&sub) - lateral(&base)).abs());
    // A finite allowance: the same as the measurement with that variance added, fused.
    let mut widened = m;
    widened.covariance[(4, 4)] += 1e-5;
    let mut reference = base.clone();
    reference.update_relative_pose(&widened, false).unwrap();
    let mut allowed = base.clone();
    let d_allowed = allowed
        .update_relative_pose_allowance(&m, [0.0, 0.0, 0.0, 0.0, 1e-5, 0.0])
        .unwrap();
    assert_eq!(d_allowed.d2, d_full.d2);
    let d = core_diff(allowed.state(), reference.state());
    assert!(d.norm() < 1e-12, "{:?}", d.as_slice());
    assert!(allowed
        .update_relative_pose_allowance(&m, [0.0, 0.0, 0.0, 0.0, f64::NAN, 0.0])
        .is_err());

    // Far outside the gate: nothing is applied.
    let far = relative_pose(
        &truth_poses[100],
        &truth_poses[200],
        &[2e-3, 2e-3, 2e-3, 5e-3, 5e-3, 5e-3],
        [true, true, true, true, true, false],
        Vector3::new(0.0, 0.5, 0.0),
        &mut rng,
    );
    let mut rejected = base.clone();
    let d = rejected.update_relative_pose_allowance(&far, keep).unwrap();
    assert!(!d.accepted && !d.applied);
    assert_eq!(rejected.state(), base.state());
}

/// EST-8b: a relative pose gated with its innovation kept
/// (`gate_relative_pose_kept`) gives the gate's decision bit for bit, and fusing the kept
/// innovation with another set of observed components and added variances
/// (`fuse_kept_relative_pose`, the kinematic aiding without VO) equals the ungated update of
/// the measurement so modified, up to rounding; once the filter has changed the kept
/// innovation is refused as stale, and invalid variances are refused.
#[test]
fn est_8b_kept_innovation_fuses_like_the_modified_measurement() {
    let (ekf, samples, truth_poses, mut rng) = late_vo_drive(8);
    let mut base = ekf.clone();
    for (k, s) in samples.iter().enumerate().take(201) {
        base.propagate(s).unwrap();
        if k == 100 {
            base.clone_at(s.t_us).unwrap();
        }
    }
    let m = relative_pose(
        &truth_poses[100],
        &truth_poses[200],
        &[2e-3, 2e-3, 2e-3, 5e-3, 5e-3, 5e-3],
        [true, true, true, true, true, false],
        Vector3::new(0.0, 0.003, 0.0),
        &mut rng,
    );
    let gate = base.gate_relative_pose(&m).unwrap();
    let (kept_gate, kept) = base.gate_relative_pose_kept(&m).unwrap();
    assert_eq!(kept_gate, gate);
    // z observed with a variance added, the rotation dropped, slip allowances on x and y.
    let extra = [0.0, 0.0, 1e-8, 4e-6, 4e-6, 2.5e-7];
    let observed = [false, false, false, true, true, true];
    let mut modified = m;
    modified.observed = observed;
    for (k, e) in extra.iter().enumerate() {
        modified.covariance[(k, k)] += e;
    }
    let mut reference = base.clone();
    reference.update_relative_pose(&modified, false).unwrap();
    let mut fused = base.clone();
    fused
        .fuse_kept_relative_pose(&kept, observed, extra)
        .unwrap();
    let d = core_diff(fused.state(), reference.state());
    assert!(d.norm() < 1e-12, "{:?}", d.as_slice());
    let dp = (fused.covariance() - reference.covariance()).abs().max();
    assert!(dp < 1e-15, "covariance differs by {dp}");
    // The filter changed (the fusion itself, or a propagation): the kept innovation is stale.
    assert_eq!(
        fused.fuse_kept_relative_pose(&kept, observed, extra),
        Err(EstError::StaleMeasurement)
    );
    let mut propagated = base.clone();
    propagated.propagate(&samples[201]).unwrap();
    assert_eq!(
        propagated.fuse_kept_relative_pose(&kept, observed, extra),
        Err(EstError::StaleMeasurement)
    );
    let mut refused = base.clone();
    for (obs, ex) in [
        ([false; 6], extra),
        (observed, [0.0, 0.0, 0.0, f64::NAN, 0.0, 0.0]),
        (observed, [0.0, 0.0, 0.0, -1.0, 0.0, 0.0]),
    ] {
        assert_eq!(
            refused.fuse_kept_relative_pose(&kept, obs, ex),
            Err(EstError::InvalidMeasurement)
        );
    }
    assert_eq!(refused.state(), base.state());
}
