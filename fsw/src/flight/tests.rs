//! HAL-1: every device reading is checked and counted; bad readings are not kept.

use super::*;
use rover_hal::{CaptureStatus, ErrorKind, MobilityCommand, StereoCalibration, StereoFrame};

/// A scripted sequence of results, replayed one per call and then repeating the last.
struct Script<T: Copy, const N: usize> {
    items: [Result<T, ErrorKind>; N],
    next: usize,
}

impl<T: Copy, const N: usize> Script<T, N> {
    fn new(items: [Result<T, ErrorKind>; N]) -> Self {
        Self { items, next: 0 }
    }
    fn pop(&mut self) -> Result<T, ErrorKind> {
        let item = self.items[self.next.min(N - 1)];
        self.next += 1;
        item
    }
}

struct TestClock;
impl Clock for TestClock {
    type Error = ErrorKind;
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        Ok(0)
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        Ok(0)
    }
    fn counter_hz(&self) -> u64 {
        1_000_000
    }
}

struct TestImu(Script<ImuSample, 7>);
impl Imu for TestImu {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<ImuSample, ErrorKind> {
        self.0.pop()
    }
}

struct TestMobility(Script<JointState, 4>);
impl Mobility for TestMobility {
    type Error = ErrorKind;
    fn read_joints(&mut self) -> Result<JointState, ErrorKind> {
        self.0.pop()
    }
    fn command(&mut self, _: &MobilityCommand) -> Result<(), ErrorKind> {
        Ok(())
    }
    fn stop(&mut self) -> Result<(), ErrorKind> {
        Ok(())
    }
}

/// A camera that never completes a capture (with the lens calibration it reports).
struct StuckCamera(Option<rover_hal::LensCalibration>);
impl StereoCamera for StuckCamera {
    fn lens_calibration(&self) -> Option<rover_hal::LensCalibration> {
        self.0
    }
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        StereoCalibration {
            fx_px: 1.0,
            fy_px: 1.0,
            cx_px: 0.0,
            cy_px: 0.0,
            baseline_m: 0.1,
            rot_rover_from_camera: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            pos_camera_in_rover_m: [0.0; 3],
        }
    }
    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        Ok(0)
    }
    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        Ok(CaptureStatus::InProgress)
    }
    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        Err(ErrorKind::NotReady)
    }
    fn release(&mut self) -> Result<(), ErrorKind> {
        Ok(())
    }
}

struct TestSun(Script<SunReading, 3>);
impl SunSensor for TestSun {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<SunReading, ErrorKind> {
        self.0.pop()
    }
}

/// A power subsystem replaying a script of readings.
struct TestPower(Script<PowerReading, 10>);
impl Power for TestPower {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<PowerReading, ErrorKind> {
        self.0.pop()
    }
}

/// A power subsystem that has no reading yet (`NotReady`, not a fault).
fn no_power() -> TestPower {
    TestPower(Script::new([Err(ErrorKind::NotReady); 10]))
}

struct RefusingTelemetry;
impl Telemetry for RefusingTelemetry {
    type Error = ErrorKind;
    fn send(&mut self, _: &[u8]) -> Result<(), ErrorKind> {
        Err(ErrorKind::Busy)
    }
}

struct TestPlatform;
impl Platform for TestPlatform {
    type Clock = TestClock;
    type Imu = TestImu;
    type Mobility = TestMobility;
    type Camera = StuckCamera;
    type Sun = TestSun;
    type Power = TestPower;
    type Telemetry = RefusingTelemetry;
    type ImageMemory =
        crate::rectify::ImageMemory<std::vec::Vec<crate::rectify::MapNode>, std::vec::Vec<u8>>;
}

fn imu(t_us: u64) -> ImuSample {
    ImuSample {
        t_us,
        gyro_rad_s: [0.0; 3],
        accel_m_s2: [0.0, 0.0, -3.711],
        valid: true,
    }
}

fn joints(t_us: u64) -> JointState {
    JointState {
        t_us,
        wheel_valid: [true; 6],
        suspension_valid: true,
        ..JointState::default()
    }
}

/// HAL-1: IMU, joints, camera, sun and telemetry faults are each counted with their kind, and
/// only checked readings are kept.
#[test]
fn hal_1_device_faults_are_counted_and_bad_readings_dropped() {
    let mut nan = imu(30);
    nan.gyro_rad_s[1] = f64::NAN;
    let mut flagged = imu(40);
    flagged.valid = false;
    let imu_script = Script::new([
        Ok(imu(10)),              // good
        Ok(imu(10)),              // stale
        Ok(imu(5)),               // backwards
        Ok(nan),                  // non-finite
        Ok(flagged),              // device says invalid
        Err(ErrorKind::NotReady), // no new data: not a fault
        Err(ErrorKind::Timeout),  // fault, repeated from here on
    ]);
    let mut bad_joints = joints(2);
    bad_joints.rocker_rad = f64::INFINITY;
    let joint_script = Script::new([
        Ok(joints(1)),
        Ok(bad_joints),
        Ok(joints(0)),
        Err(ErrorKind::Hardware),
    ]);
    let long_vector = SunReading {
        t_us: 1,
        sun_dir_rover: [2.0, 0.0, 0.0],
        sun_in_view: true,
    };
    let sun_script = Script::new([
        Ok(long_vector),
        Ok(SunReading {
            t_us: 2,
            sun_dir_rover: [0.0, 0.0, -1.0],
            sun_in_view: true,
        }),
        Err(ErrorKind::Timeout),
    ]);
    let devices = Devices::<TestPlatform> {
        clock: TestClock,
        imu: TestImu(imu_script),
        mobility: TestMobility(joint_script),
        camera: StuckCamera(None),
        sun: TestSun(sun_script),
        power: no_power(),
        telemetry: RefusingTelemetry,
        image_memory: crate::rectify::ImageMemory {
            map: std::vec::Vec::new(),
            left: std::vec::Vec::new(),
            right: std::vec::Vec::new(),
        },
    };
    let config = FswConfig::rocky8([0.0; 3], 0.0);
    let mut fsw = match Fsw::new(devices, &config, &[[0.0, 0.0], [1.0, 0.0]]) {
        Ok(f) => f,
        Err(e) => panic!("schedule refused: {e:?}"),
    };
    // 8 frames: IMU read 8 times; RG2 at tick 1 only; RG3 at tick 2 (no capture: the navigator
    // is not aligned, so no capture is due); RG4 at tick 3.
    for _ in 0..8 {
        fsw.tick();
    }
    let s = fsw.state();
    let h = s.health[DeviceId::Imu as usize];
    assert_eq!(
        (h.good, h.stale, h.time_backwards, h.invalid, h.errors),
        (1, 1, 1, 2, 2)
    );
    assert_eq!(s.imu.map(|i| i.t_us), Some(10));
    let h = s.health[DeviceId::Joints as usize];
    assert_eq!((h.good, h.faults()), (1, 0));
    assert_eq!(s.joints.map(|j| j.t_us), Some(1));
    // The sun reading with a vector of length 2 is invalid and not kept.
    let h = s.health[DeviceId::Sun as usize];
    assert_eq!((h.good, h.invalid), (0, 1));
    assert!(s.sun.is_none());
    // No capture was triggered before the navigator wants one, and telemetry refused the two
    // records (status and navigation) of the one RG2 cycle.
    assert!(s.capture_pending_t_us.is_none());
    assert_eq!(s.telemetry_dropped, 2);
    // Run to the next RG2 and RG3 releases: joints go backwards; still no capture.
    for _ in 8..210 {
        fsw.tick();
    }
    let s = fsw.state();
    let h = s.health[DeviceId::Joints as usize];
    assert_eq!((h.invalid, h.time_backwards), (1, 1));
    assert!(h.errors >= 1);
    assert_eq!(s.health[DeviceId::Camera as usize].faults(), 0);
    assert!(s.capture_pending_t_us.is_none());
    assert_eq!(s.stereo_frames, 0);
}

/// The last `FrameStatus` record the flight software sent (the navigation records are
/// accepted and ignored).
struct StatusTelemetry(Option<crate::flight::FrameStatus>);
impl Telemetry for StatusTelemetry {
    type Error = ErrorKind;
    fn send(&mut self, record: &[u8]) -> Result<(), ErrorKind> {
        if let Some((&tag, body)) = record.split_first() {
            if tag == RecordKind::FrameStatus as u8 {
                self.0 = Some(postcard::from_bytes(body).map_err(|_| ErrorKind::InvalidData)?);
            }
        }
        Ok(())
    }
}

struct PowerPlatform;
impl Platform for PowerPlatform {
    type Clock = TestClock;
    type Imu = TestImu;
    type Mobility = TestMobility;
    type Camera = StuckCamera;
    type Sun = TestSun;
    type Power = TestPower;
    type Telemetry = StatusTelemetry;
    type ImageMemory =
        crate::rectify::ImageMemory<std::vec::Vec<crate::rectify::MapNode>, std::vec::Vec<u8>>;
}

/// HAL-2: the RG4 `power` task keeps and hands to the navigator only plausible
/// readings. A decreasing energy, a NaN energy, a reading the device flags invalid, a negative
/// or infinite bus power, an energy leap (1e300 J, faster than the largest bus power) are
/// counted invalid, a backwards time stamp and a call error are counted as such, and none of
/// them replaces the last accepted reading (the leap does not lock out the next normal one);
/// the status telemetry carries the accepted energy and power.
#[test]
fn hal_2_power_readings_checked_and_passed_to_the_navigator() {
    // RG4 runs at ticks 3, 1003, 2003... (5 s apart); the stamps follow the frame time.
    let reading = |k: u64, energy_used_j: f64, bus_power_w: f64| PowerReading {
        t_us: 5_000 * (1_000 * k + 3),
        energy_used_j,
        bus_power_w,
        valid: true,
    };
    let first = reading(0, 10.0, 50.0);
    let last = reading(8, 600.0, 40.0);
    let flagged = PowerReading {
        valid: false,
        ..reading(3, 400.0, 50.0)
    };
    let backwards = PowerReading {
        t_us: 1_000,
        ..reading(7, 550.0, 50.0)
    };
    let script = Script::new([
        Ok(first),
        Ok(reading(1, 5.0, 50.0)),      // less energy used than before
        Ok(reading(2, f64::NAN, 50.0)), // non-finite energy
        Ok(flagged),                    // the device says invalid
        Ok(reading(4, 450.0, -1.0)),    // negative power
        Ok(reading(5, 500.0, f64::INFINITY)), // non-finite power
        Ok(reading(6, 1e300, 50.0)),    // an energy leap
        Ok(backwards),
        Ok(last),
        Err(ErrorKind::Timeout),
    ]);
    let devices = Devices::<PowerPlatform> {
        clock: TestClock,
        imu: TestImu(Script::new([Err(ErrorKind::NotReady); 7])),
        mobility: TestMobility(Script::new([Err(ErrorKind::NotReady); 4])),
        camera: StuckCamera(None),
        sun: TestSun(Script::new([Err(ErrorKind::NotReady); 3])),
        power: TestPower(script),
        telemetry: StatusTelemetry(None),
        image_memory: crate::rectify::ImageMemory {
            map: std::vec::Vec::new(),
            left: std::vec::Vec::new(),
            right: std::vec::Vec::new(),
        },
    };
    let config = FswConfig::rocky8([0.0; 3], 0.0);
    let mut fsw = match Fsw::new(devices, &config, &[[0.0, 0.0], [1.0, 0.0]]) {
        Ok(f) => f,
        Err(e) => panic!("schedule refused: {e:?}"),
    };
    let power = |f: &Fsw<PowerPlatform>| f.state().health[DeviceId::Power as usize];
    // The first reading is accepted; the next seven are each refused and the first stays.
    for _ in 0..4 {
        fsw.tick();
    }
    assert_eq!(fsw.state().power, Some(first));
    assert_eq!(fsw.nav().goal().last_power(), Some(first));
    for k in 1..8u64 {
        for _ in 0..1_000 {
            fsw.tick();
        }
        assert_eq!(fsw.state().power, Some(first), "reading {k} refused");
        assert_eq!(
            fsw.nav().goal().last_power(),
            Some(first),
            "reading {k} not passed on"
        );
    }
    let h = power(&fsw);
    assert_eq!(
        (h.good, h.invalid, h.time_backwards, h.errors),
        (1, 6, 1, 0)
    );
    // The ninth reading is accepted, then the device fails.
    for _ in 0..2_000 {
        fsw.tick();
    }
    assert_eq!(fsw.state().power, Some(last));
    assert_eq!(fsw.nav().goal().last_power(), Some(last));
    let h = power(&fsw);
    assert_eq!(
        (h.good, h.invalid, h.time_backwards, h.errors),
        (2, 6, 1, 1)
    );
    // The other devices' health is untouched by the power task.
    assert_eq!(fsw.state().health[DeviceId::Sun as usize].faults(), 0);
    // The status telemetry (RG2) carries the accepted reading and the power health.
    for _ in 0..10 {
        fsw.tick();
    }
    let Some(status) = fsw.devices.as_ref().and_then(|a| a.devices.telemetry.0) else {
        panic!("no status record");
    };
    assert_eq!(status.energy_used_j, 600.0);
    assert_eq!(status.bus_power_w, 40.0);
    assert_eq!(status.health[DeviceId::Power as usize], h);
}

/// NAV-1: the navigator aligns on 400 samples at rest (tilt from gravity, heading from the sun
/// sensor against the ephemeris), then commands forward motion along the path; losing the IMU
/// stops the rover; an invalid path is refused with an error value. Without a sun reading the
/// alignment waits `AlignConfig::sun_wait_samples` more samples and takes the plan's heading.
#[test]
fn nav_1_alignment_drive_command_and_sensor_loss_hold() {
    use crate::estimation::ephemeris::SunEphemeris;
    use nav::{NavConfig, NavError, NavMode, Navigator};
    let calib = StuckCamera(None).calibration();
    let path = [[0.0, 0.0], [5.0 * 0.3_f64.cos(), 5.0 * 0.3_f64.sin()]];
    // A 2 deg roll (right side down) seen by the accelerometer at rest; the rover actually
    // faces 0.3 rad east of north while the plan says north.
    let roll = 2.0_f64.to_radians();
    let true_yaw = 0.3;
    let g = 3.711;
    let mut config = NavConfig::rocky8([0.0; 3], 0.0);
    let ephemeris = SunEphemeris::from_site(-14.6, 30.0, 10.5);
    config.filter.ekf.sun = Some(ephemeris);
    let q_true = crate::types::Quat::from_euler_angles(roll, 0.0, true_yaw);
    let imu = |k: u64| ImuSample {
        t_us: 5_000 * (k + 1),
        gyro_rad_s: [1e-4, 0.0, 0.0],
        accel_m_s2: [0.0, -g * roll.sin(), -g * roll.cos()],
        valid: true,
    };
    // Without the sun: the plan's heading after the wait.
    let mut blind = match Navigator::new(config, &path, &calib) {
        Ok(n) => n,
        Err(e) => panic!("navigator refused: {e:?}"),
    };
    let wait = u64::from(config.align.samples + config.align.sun_wait_samples);
    for k in 0..wait - 1 {
        blind.propagate(Some(&imu(k)));
    }
    assert_eq!(blind.mode(), NavMode::Aligning, "waits for the sun");
    blind.propagate(Some(&imu(wait)));
    assert_eq!(blind.mode(), NavMode::Driving);
    assert_eq!(blind.counters().heading_from_plan, 1);
    assert!(blind.pose().q_nr.euler_angles().2.abs() < 1e-12);
    let mut nav = match Navigator::new(config, &path, &calib) {
        Ok(n) => n,
        Err(e) => panic!("navigator refused: {e:?}"),
    };
    assert_eq!(nav.mode(), NavMode::Aligning);
    for k in 0..400u64 {
        if k == 3 {
            let t_us = 5_000 * (k + 1);
            let s_n = ephemeris.sun_dir_n(t_us).unwrap_or_default();
            let s_r = q_true.inverse_transform_vector(&s_n);
            nav.sun(&SunReading {
                t_us,
                sun_dir_rover: [s_r.x, s_r.y, s_r.z],
                sun_in_view: true,
            });
        }
        nav.propagate(Some(&imu(k)));
        assert!(nav.guidance_cycle().is_none(), "no motion while aligning");
    }
    assert_eq!(nav.mode(), NavMode::Driving);
    assert_eq!(nav.counters().heading_from_sun, 1);
    let (r, p, y) = nav.pose().q_nr.euler_angles();
    assert!((r - roll).abs() < 1e-9 && p.abs() < 1e-9, "{r} {p}");
    assert!((y - true_yaw).abs() < 1e-9, "heading from the sun: {y}");
    let heading_sigma = nav.ekf().map(|e| e.heading_sigma_rad()).unwrap_or(1.0);
    assert!(heading_sigma < 0.03, "sun heading sigma {heading_sigma}");
    let bias = nav.ekf().map(|e| e.state().b_g.x);
    assert!(bias.is_some_and(|b| (b - 1e-4).abs() < 1e-12));
    nav.kinematic_cycle(Some(&joints(2_000_000)));
    let Some(cmd) = nav.guidance_cycle() else {
        panic!("no command after alignment");
    };
    // Path straight ahead: wheels straight, all turning forward.
    assert!(cmd.wheel_rate_rad_s.iter().all(|w| *w > 0.0));
    assert!(cmd.steer_angle_rad.iter().all(|s| s.abs() < 0.05));
    // No IMU for the timeout: the rover is held.
    for _ in 0..20 {
        nav.propagate(None);
    }
    assert!(nav.guidance_cycle().is_none());
    assert_eq!(nav.counters().sensor_holds, 1);
    // Bad paths are refused.
    let bad = Navigator::new(NavConfig::rocky8([0.0; 3], 0.0), &[[0.0, 0.0]], &calib);
    assert!(matches!(bad, Err(NavError::Path(_))));
    let nan = Navigator::new(NavConfig::rocky8([f64::NAN, 0.0, 0.0], 0.0), &path, &calib);
    assert!(matches!(nan, Err(NavError::BadConfig)));
}

/// NAV-2: an IMU worse than the filter is configured for. After alignment the
/// accelerometer takes a 0.05 m/s^2 bias step along x (5 sigma of the configured turn-on
/// bias, with the configured bias walk far too small to follow it); VO is off and the VO-loss
/// fallback disabled, so only the gated kinematics corrects the filter. Without the streak
/// recovery every interval is rejected once the velocity has drifted and the filter coasts
/// on the IMU for ever; with it, the streak is flagged and the filter comes back.
#[test]
fn nav_2_rejection_streak_recovers_a_filter_tuned_too_tight() {
    use nav::{NavConfig, Navigator};
    let run = |recover: bool| {
        let mut config = NavConfig::rocky8([0.0; 3], 0.0);
        // VO built but never started (no images): no VO update ever arrives, and with an
        // infinite timeout the VO-loss fallback never engages.
        config.vo.enabled = true;
        config.vo.timeout_cycles = u32::MAX;
        config.align.sun_wait_samples = 0;
        if !recover {
            config.kin.reject_streak_cycles = u32::MAX;
        }
        let calib = crate::vo::rocky8_hazcam();
        let mut nav = match Navigator::new(config, &[[0.0, 0.0], [100.0, 0.0]], &calib) {
            Ok(n) => n,
            Err(e) => panic!("navigator refused: {e:?}"),
        };
        let r = config.geometry.wheel_radius_m;
        let (g, v_cruise, t_start, t_ramp, t_bias) = (3.711, 0.1, 2.5, 0.5, 5.0);
        let (mut x, mut v, mut error_30s) = (0.0_f64, 0.0_f64, 0.0_f64);
        let dt = 0.005;
        for k in 1..=60 * 200u64 {
            let t = k as f64 * dt;
            let a = if t > t_start && t <= t_start + t_ramp {
                v_cruise / t_ramp
            } else {
                0.0
            };
            v += a * dt;
            x += v * dt;
            let bias = if t > t_bias { 0.05 } else { 0.0 };
            let t_us = k * 5_000;
            nav.propagate(Some(&ImuSample {
                t_us,
                gyro_rad_s: [0.0; 3],
                accel_m_s2: [a + bias, 0.0, -g],
                valid: true,
            }));
            if k % 10 == 0 {
                nav.kinematic_cycle(Some(&JointState {
                    drive_angle_rad: [x / r; 6],
                    drive_rate_rad_s: [v / r; 6],
                    ..joints(t_us)
                }));
                let _ = nav.guidance_cycle();
                if k == 30 * 200 {
                    error_30s = (nav.pose().p_n.x - x).abs();
                }
            }
        }
        let c = nav.counters();
        (
            (nav.pose().p_n.x - x).abs(),
            error_30s,
            c.kin_streaks,
            c.kin_tested,
            c.kin_rejected,
        )
    };
    let (final_off, _, streaks_off, tested, rejected) = run(false);
    assert_eq!(streaks_off, 0);
    assert!(
        final_off > 10.0 && rejected > tested * 9 / 10,
        "without recovery the filter should diverge: {final_off} m, {rejected}/{tested} rejected"
    );
    // With the recovery the position error of the streak stays (relative poses do not observe
    // absolute position) but stops growing: velocity and bias are re-estimated.
    let (final_on, at_30s, streaks_on, tested, rejected) = run(true);
    std::eprintln!(
        "NAV-2: without recovery {final_off:.2} m; with: {at_30s:.3} m at 30 s, {final_on:.3} m \
         at 60 s, {streaks_on} streak(s), {rejected}/{tested} rejected"
    );
    assert!(
        (1..=3).contains(&streaks_on),
        "the streak is flagged: {streaks_on}"
    );
    assert!(
        final_on < 1.0 && (final_on - at_30s).abs() < 0.05 && rejected < tested / 4,
        "with recovery the error stays bounded: {at_30s} m at 30 s, {final_on} m at 60 s, \
         {rejected}/{tested} rejected"
    );
}

/// NAV-3 (RB): a rover slipping 30 % without VO (below the 40 % slip limit). The
/// wheels turn for 0.1 m/s while the rover moves at 0.07 m/s; the IMU measures the true accelerations. Without the
/// stop-and-go drive the VO-loss fallback fuses every kinematic interval (with its slip
/// allowance) and the filter follows the wheels; with it the rover stops every metre of wheel
/// travel, the zero-velocity updates anchor the IMU velocity, the gate rejects the slipping
/// intervals and the IMU carries the motion.
#[test]
fn nav_3_stop_and_go_without_vo_measures_slip_with_the_imu() {
    use nav::{NavConfig, Navigator};
    let run = |stop_and_go: bool| {
        let mut config = NavConfig::rocky8([0.0; 3], 0.0);
        config.vo.enabled = false;
        config.align.sun_wait_samples = 0;
        if !stop_and_go {
            config.drive.blind_stop_interval_m = 0.0;
        }
        // The ground accepts the uncertainty of a drive without VO (as on `dunes-long`).
        config.drive.protection.max_position_sigma_m = 100.0;
        let calib = crate::vo::rocky8_hazcam();
        let mut nav = match Navigator::new(config, &[[0.0, 0.0], [100.0, 0.0]], &calib) {
            Ok(n) => n,
            Err(e) => panic!("navigator refused: {e:?}"),
        };
        let r = config.geometry.wheel_radius_m;
        let (g, slip, accel) = (3.711, 0.3, 0.2);
        // Truth: ground speed `v`, wheel rim speed `u` (each follows the command with the same
        // acceleration limit), wheel travel `w`.
        let (mut x, mut v, mut u, mut w) = (0.0_f64, 0.0_f64, 0.0_f64, 0.0_f64);
        let mut driving = false;
        let dt = 0.005;
        for k in 1..=90 * 200u64 {
            let t_us = k * 5_000;
            let target = if driving { 0.1 } else { 0.0 };
            let du = (target - u).clamp(-accel * dt, accel * dt);
            u += du;
            let v_new = u * (1.0 - slip);
            let a = (v_new - v) / dt;
            v = v_new;
            x += v * dt;
            w += u * dt;
            nav.propagate(Some(&ImuSample {
                t_us,
                gyro_rad_s: [0.0; 3],
                accel_m_s2: [a, 0.0, -g],
                valid: true,
            }));
            if k % 10 == 0 {
                nav.kinematic_cycle(Some(&JointState {
                    drive_angle_rad: [w / r; 6],
                    drive_rate_rad_s: [u / r; 6],
                    ..joints(t_us)
                }));
                driving = nav.guidance_cycle().is_some();
            }
            // RG2B: half an RG2 period later.
            if k % 10 == 5 {
                nav.zero_velocity_cycle();
            }
        }
        let c = nav.counters();
        (
            (nav.pose().p_n.x - x).abs(),
            x,
            c.blind_stops,
            c.kin_imu_carried,
        )
    };
    let (err_off, x_off, stops_off, carried_off) = run(false);
    let (err_on, x_on, stops_on, carried_on) = run(true);
    std::eprintln!(
        "NAV-3: without stop-and-go {err_off:.3} m error over {x_off:.2} m; with: {err_on:.3} m \
         over {x_on:.2} m, {stops_on} stops, {carried_on} intervals carried by the IMU"
    );
    assert_eq!((stops_off, carried_off), (0, 0));
    assert!(
        err_off > 0.3 * x_off,
        "the fallback follows the wheels: {err_off} m"
    );
    assert!(
        stops_on >= 3 && carried_on > 100,
        "{stops_on} stops, {carried_on} carried"
    );
    assert!(
        err_on < 0.05 * x_on,
        "the IMU measures the slip: {err_on} m over {x_on} m"
    );
}

/// FP-3: a finite but implausible IMU sample (1e6 m/s^2) is refused as invalid; a
/// stamp one hour ahead is refused as a time leap and does not poison the time base (the next
/// normal readings are accepted); a leap that persists for `resync_readings` readings becomes
/// the new time base (counted).
#[test]
fn fp_3_implausible_values_and_time_leaps() {
    let mut spike = imu(20);
    spike.accel_m_s2[0] = 1.0e6;
    let imu_script = Script::new([
        Ok(imu(10)),
        Ok(spike),
        Ok(imu(30)),
        Ok(imu(3_600_000_000)),
        Ok(imu(40)),
        Ok(imu(50)),
        Err(ErrorKind::NotReady),
    ]);
    let devices = Devices::<TestPlatform> {
        clock: TestClock,
        imu: TestImu(imu_script),
        mobility: TestMobility(Script::new([Err(ErrorKind::NotReady); 4])),
        camera: StuckCamera(None),
        sun: TestSun(Script::new([Err(ErrorKind::NotReady); 3])),
        power: no_power(),
        telemetry: RefusingTelemetry,
        image_memory: crate::rectify::ImageMemory {
            map: std::vec::Vec::new(),
            left: std::vec::Vec::new(),
            right: std::vec::Vec::new(),
        },
    };
    let config = FswConfig::rocky8([0.0; 3], 0.0);
    let mut fsw = match Fsw::new(devices, &config, &[[0.0, 0.0], [1.0, 0.0]]) {
        Ok(f) => f,
        Err(e) => panic!("schedule refused: {e:?}"),
    };
    for _ in 0..8 {
        fsw.tick();
    }
    let s = fsw.state();
    let h = s.health[DeviceId::Imu as usize];
    assert_eq!((h.good, h.invalid, h.time_jumps, h.resyncs), (4, 1, 1, 0));
    assert_eq!(s.imu.map(|i| i.t_us), Some(50));
    // The refused specific force is beyond the accelerometer's range: an IMU shock (FP-8).
    assert_eq!(fsw.nav().counters().imu_shocks, 1);

    // A persistent leap: the device's clock really moved on by an hour.
    let limits = Plausibility::default();
    let mut health = DeviceHealth::default();
    let mut base = TimeBase::default();
    let mut previous = None;
    for tick in 0..10u64 {
        let t = 5_000 * tick + 5_000;
        if devices::check_time(&mut health, &mut base, previous, t, tick, &limits) {
            previous = Some(t);
            base.accept(tick);
        }
    }
    let mut accepted_at = None;
    for tick in 10..40u64 {
        let t = 3_600_000_000 + 5_000 * tick;
        if devices::check_time(&mut health, &mut base, previous, t, tick, &limits) {
            previous = Some(t);
            base.accept(tick);
            accepted_at.get_or_insert(tick);
        }
    }
    assert_eq!(
        accepted_at,
        Some(10 + u64::from(limits.resync_readings) - 1)
    );
    assert_eq!(
        (health.time_jumps, health.resyncs),
        (limits.resync_readings - 1, 1)
    );
}

/// FP-4: after an accepted IMU time-base change the navigator re-anchors the
/// filter's timeline: the next samples of the new base propagate one frame each (no hour-long
/// gap), the state stays where it was, and the drive goes on.
#[test]
fn fp_4_imu_time_rebase_keeps_the_filter() {
    use nav::{NavConfig, NavMode, Navigator};
    let mut config = NavConfig::rocky8([0.0; 3], 0.0);
    config.align.sun_wait_samples = 0;
    config.vo.enabled = false;
    let calib = crate::vo::rocky8_hazcam();
    let mut nav = match Navigator::new(config, &[[0.0, 0.0], [5.0, 0.0]], &calib) {
        Ok(n) => n,
        Err(e) => panic!("navigator refused: {e:?}"),
    };
    for k in 1..=600u64 {
        nav.propagate(Some(&imu(5_000 * k)));
    }
    assert_eq!(nav.mode(), NavMode::Driving);
    let before = nav.pose();
    let leap = 3_600_000_000u64;
    nav.imu_time_rebase(leap - 5_000);
    for k in 0..200u64 {
        nav.propagate(Some(&imu(leap + 5_000 * k)));
    }
    let Some(ekf) = nav.ekf() else {
        panic!("filter stopped")
    };
    assert_eq!(ekf.time_us(), leap + 5_000 * 199);
    assert_eq!(nav.counters().time_rebases, 1);
    assert_eq!(nav.counters().ekf_errors, 0);
    assert_eq!(nav.mode(), NavMode::Driving);
    // One second at rest in the new base: the position and its uncertainty barely move (an
    // hour-long propagation across the leap grows the position sigma to about 100 m).
    assert!((nav.pose().p_n - before.p_n).norm() < 0.01);
    let i = crate::estimation::state::I_P;
    let sigma = (ekf.covariance()[(i, i)] + ekf.covariance()[(i + 1, i + 1)]).sqrt();
    assert!(sigma < 0.5, "position sigma {sigma} m");
}

/// FP-5: a spike within the sensor's range during the alignment (3 m/s^2 in one of
/// 400 samples) restarts the alignment instead of being averaged into the attitude; the next
/// 400 clean samples align.
#[test]
fn fp_5_alignment_dispersion_restarts() {
    use nav::{NavConfig, NavMode, Navigator};
    let mut config = NavConfig::rocky8([0.0; 3], 0.0);
    config.align.sun_wait_samples = 0;
    config.vo.enabled = false;
    let calib = crate::vo::rocky8_hazcam();
    let mut nav = match Navigator::new(config, &[[0.0, 0.0], [5.0, 0.0]], &calib) {
        Ok(n) => n,
        Err(e) => panic!("navigator refused: {e:?}"),
    };
    for k in 1..=400u64 {
        let mut s = imu(5_000 * k);
        if k == 100 {
            s.accel_m_s2[0] = 3.0;
        }
        nav.propagate(Some(&s));
    }
    assert_eq!(nav.mode(), NavMode::Aligning);
    assert_eq!(nav.counters().align_restarts, 1);
    for k in 401..=800u64 {
        nav.propagate(Some(&imu(5_000 * k)));
    }
    assert_eq!(nav.mode(), NavMode::Driving);
    let (r, p, _) = nav.pose().q_nr.euler_angles();
    assert!(r.abs() < 1e-9 && p.abs() < 1e-9, "tilt {r} {p}");
}

/// A wide-angle raw camera of the hazcam class (the rectified geometry is the hazcam's).
fn hazcam_lens() -> rover_hal::LensCalibration {
    let camera = rover_hal::RawCamera {
        fx_px: 390.3,
        fy_px: 389.2,
        cx_px: 312.4,
        cy_px: 247.1,
        k1: -0.2834,
        k2: 0.07396,
        k3: 0.0,
        p1: 0.000_194,
        p2: 0.000_018,
        rot_raw_from_rect: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    };
    rover_hal::LensCalibration {
        left: camera,
        right: camera,
    }
}

/// A flight software on a camera with `lens`, `memory` rectification memory and the hazcam's
/// rectified geometry; `start_vo` called.
fn fsw_with_lens(
    lens: Option<rover_hal::LensCalibration>,
    full_memory: bool,
) -> Fsw<HazcamPlatform> {
    let n = |len: usize| if full_memory { len } else { 0 };
    let devices = Devices::<HazcamPlatform> {
        clock: TestClock,
        imu: TestImu(Script::new([Err(ErrorKind::NotReady); 7])),
        mobility: TestMobility(Script::new([Err(ErrorKind::NotReady); 4])),
        camera: HazcamCamera(StuckCamera(lens)),
        sun: TestSun(Script::new([Err(ErrorKind::NotReady); 3])),
        power: no_power(),
        telemetry: RefusingTelemetry,
        image_memory: crate::rectify::ImageMemory {
            map: vec![crate::rectify::MapNode::default(); n(crate::rectify::MAP_NODES)],
            left: vec![0u8; n(rover_hal::IMAGE_PIXELS)],
            right: vec![0u8; n(rover_hal::IMAGE_PIXELS)],
        },
    };
    let config = FswConfig::rocky8([0.0; 3], 0.0);
    let mut fsw = match Fsw::new(devices, &config, &[[0.0, 0.0], [1.0, 0.0]]) {
        Ok(f) => f,
        Err(e) => panic!("schedule refused: {e:?}"),
    };
    fsw.start_vo();
    fsw
}

/// The stuck camera with the hazcam's rectified geometry.
struct HazcamCamera(StuckCamera);
impl StereoCamera for HazcamCamera {
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        let h = core::f64::consts::FRAC_1_SQRT_2;
        StereoCalibration {
            fx_px: 384.791_625_3,
            fy_px: 384.079_510_6,
            cx_px: 319.5,
            cy_px: 239.5,
            baseline_m: 0.084,
            rot_rover_from_camera: [[0.0, -h, h], [1.0, 0.0, 0.0], [0.0, h, h]],
            pos_camera_in_rover_m: [0.2, 0.0, -0.6],
        }
    }
    fn lens_calibration(&self) -> Option<rover_hal::LensCalibration> {
        self.0.lens_calibration()
    }
    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        self.0.trigger()
    }
    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        self.0.poll()
    }
    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        self.0.frame()
    }
    fn release(&mut self) -> Result<(), ErrorKind> {
        self.0.release()
    }
}

struct HazcamPlatform;
impl Platform for HazcamPlatform {
    type Clock = TestClock;
    type Imu = TestImu;
    type Mobility = TestMobility;
    type Camera = HazcamCamera;
    type Sun = TestSun;
    type Power = TestPower;
    type Telemetry = RefusingTelemetry;
    type ImageMemory =
        crate::rectify::ImageMemory<std::vec::Vec<crate::rectify::MapNode>, std::vec::Vec<u8>>;
}

/// RECT-6: the flight software builds the rectification map from the camera's lens calibration
/// at `start_vo` and then runs VO; a NaN or absurd lens calibration, or missing image memory,
/// sets the fault flag and leaves VO off (it never runs on unrectified images); a camera
/// without a lens calibration runs VO on its (rectified) images directly.
#[test]
fn rect_6_lens_calibration_at_start_vo() {
    let ok = fsw_with_lens(Some(hazcam_lens()), true);
    assert!(ok.state().rectifying);
    assert_eq!(ok.state().rectify_fault, None);
    assert!(ok.rectifier().has_map());
    assert!(ok.nav().vo().built());
    let stats = ok.rectifier().map_stats();
    assert!(stats.min_margin_px > 1.0 && stats.max_round_trip_px < 0.01);

    let mut nan = hazcam_lens();
    nan.right.k2 = f64::NAN;
    let mut absurd = hazcam_lens();
    absurd.left.k1 = -0.9;
    for (lens, memory, want) in [
        (nan, true, crate::rectify::RectifyError::BadCalibration),
        (absurd, true, crate::rectify::RectifyError::Folded),
        (hazcam_lens(), false, crate::rectify::RectifyError::Memory),
    ] {
        let f = fsw_with_lens(Some(lens), memory);
        assert_eq!(f.state().rectify_fault, Some(want));
        assert!(!f.state().rectifying);
        assert!(!f.nav().vo().built(), "VO must stay off: {want:?}");
    }

    let plain = fsw_with_lens(None, false);
    assert!(!plain.state().rectifying);
    assert_eq!(plain.state().rectify_fault, None);
    assert!(plain.nav().vo().built());
}

/// NAV-4: a used navigator initialised in place (`Navigator::init`, the rover CPU's way) runs
/// bit for bit as a new one: every field is rewritten, the filter, recorder and VO storage in
/// place. The sequence: alignment at rest, kinematic intervals, guidance, an IMU gap.
#[test]
fn nav_4_in_place_init_of_a_used_navigator_runs_as_a_new_one() {
    use nav::{NavConfig, NavMode, Navigator};
    let calib = StuckCamera(None).calibration();
    let path = [[0.0, 0.0], [5.0, 1.0]];
    // No sun: the alignment ends after its 400 samples.
    let mut config = NavConfig::rocky8([0.0; 3], 0.0);
    config.align.sun_wait_samples = 0;
    let run = |nav: &mut Navigator, samples: u64| {
        let mut out = std::vec::Vec::new();
        nav.start_vo();
        for k in 0..samples {
            nav.propagate(Some(&imu(5_000 * (k + 1))));
            if k % 10 == 9 {
                nav.kinematic_cycle(Some(&joints(5_000 * (k + 1))));
                out.push(format!("{:?}", nav.guidance_cycle()));
            }
        }
        for _ in 0..25 {
            nav.propagate(None);
        }
        out.push(format!("{:?}", nav.guidance_cycle()));
        let ekf = nav.ekf().map(|e| (*e.state(), *e.covariance()));
        out.push(format!(
            "{:?} {:?} {:?} {:?} {:?} {}",
            nav.mode(),
            nav.pose(),
            nav.counters(),
            ekf,
            nav.slip(),
            nav.vo().built()
        ));
        out
    };
    let mut fresh = std::boxed::Box::new(Navigator::new(config, &path, &calib).unwrap());
    let expected = run(&mut fresh, 420);
    assert!(expected.len() > 40);
    assert!(
        expected.last().is_some_and(|s| s.starts_with("Driving")),
        "{expected:?}"
    );
    // Used with another start and path, then initialised in place.
    let mut other = NavConfig::rocky8([1.0, 2.0, 0.0], 0.4);
    other.align.sun_wait_samples = 0;
    let mut used =
        std::boxed::Box::new(Navigator::new(other, &[[1.0, 2.0], [3.0, 3.0]], &calib).unwrap());
    // Twice: stopped after the alignment, and in the middle of it.
    assert_ne!(run(&mut used, 420), expected);
    used.init(&config, &path, &calib).unwrap();
    assert_eq!(run(&mut used, 420), expected);
    used.init(&other, &[[1.0, 2.0], [3.0, 3.0]], &calib)
        .unwrap();
    assert_ne!(run(&mut used, 200), expected);
    used.init(&config, &path, &calib).unwrap();
    assert_eq!(used.mode(), NavMode::Aligning);
    assert!(!used.vo().built());
    assert_eq!(run(&mut used, 420), expected);
}
