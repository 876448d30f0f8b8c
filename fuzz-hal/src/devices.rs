//! The adversarial devices: every answer comes from the shared seeded PRNG. While a device is
//! in a plausible stretch it answers like a Rocky 8 standing or driving on level ground (the
//! joints follow the accepted motor commands, the sun comes from the flight's own ephemeris), so
//! the navigator aligns, drives and arrives; inside a garbage burst it answers with errors of
//! every `ErrorKind`, non-finite, huge or tiny values, stale, backwards or jumping time stamps,
//! invalid flags, wrong-size or blank images and captures that are lost or never complete.
//! The power subsystem reports the battery energy a standing or driving rover uses (a constant
//! awake power plus a share for the commanded wheel rates, integrated over the frames), or
//! garbage: errors, hostile numbers, negative or decreasing energy, invalid flags, bad stamps.

use crate::rng::Rng;
use fsw::estimation::ephemeris::SunEphemeris;
use rover_hal::{
    CaptureStatus, Clock, ErrorKind, Imu, ImuSample, JointState, Mobility, MobilityCommand, Power,
    PowerReading, StereoCalibration, StereoCamera, StereoFrame, SunReading, SunSensor, Telemetry,
    IMAGE_PIXELS, IMAGE_WIDTH_PX, WHEEL_COUNT,
};
use std::cell::{Cell, RefCell};
use std::rc::Rc;

/// Minor frame, microseconds.
pub const FRAME_US: u64 = 5_000;
/// Mars gravity, m/s^2.
const GRAVITY_M_S2: f64 = 3.711;
/// Bus power of the plausible rover standing awake, W (the simulator's awake power, rounded).
const AWAKE_POWER_W: f64 = 98.37;
/// Bus power added by the plausible rover's wheels at the rate limit, W.
const DRIVE_POWER_W: f64 = 20.0;

/// Number of devices.
pub const DEVICES: usize = 7;
/// The devices, in the order of [`Shared::garbage`] and of the fault counts.
pub const DEVICE_NAMES: [&str; DEVICES] = [
    "clock",
    "imu",
    "mobility",
    "camera",
    "sun",
    "telemetry",
    "power",
];
/// Index of each device.
pub const CLOCK: usize = 0;
/// IMU.
pub const IMU: usize = 1;
/// Joints and motors.
pub const MOBILITY: usize = 2;
/// Stereo camera.
pub const CAMERA: usize = 3;
/// Sun sensor.
pub const SUN: usize = 4;
/// Telemetry sink.
pub const TELEMETRY: usize = 5;
/// Power subsystem.
pub const POWER: usize = 6;

/// Every error kind a device can answer.
pub const ERROR_KINDS: [ErrorKind; 7] = [
    ErrorKind::NotReady,
    ErrorKind::Timeout,
    ErrorKind::InvalidData,
    ErrorKind::Busy,
    ErrorKind::Hardware,
    ErrorKind::InvalidRequest,
    ErrorKind::Other,
];

/// A motor command the device received that broke the invariants (non-finite or outside the
/// rover's limits, or a moving command while the navigator was safed).
#[derive(Debug, Clone, Copy)]
pub struct BadCommand {
    /// The command.
    pub command: MobilityCommand,
}

/// State shared by the fuzz loop and the devices.
pub struct Shared {
    /// The PRNG every answer comes from.
    pub rng: Rng,
    /// True time, microseconds (advances one minor frame per tick).
    pub t_us: u64,
    /// Per device: answer garbage with this probability per call in the current frame (0:
    /// plausible).
    pub garbage: [f64; DEVICES],
    /// Garbage answers given, per device.
    pub fault_counts: [u64; DEVICES],
    /// Calls answered, per device.
    pub calls: [u64; DEVICES],
    /// The plausible battery energy used since the episode's start, J.
    pub energy_j: f64,
    /// The plausible world: wheel angles integrated from the accepted commands.
    pub wheel_angle_rad: [f64; WHEEL_COUNT],
    /// The last accepted command (the plausible joints follow it).
    pub command: MobilityCommand,
    /// Heading of the plausible rover, rad (the start heading).
    pub yaw_rad: f64,
    /// Sun ephemeris of the plausible sun.
    pub sun: SunEphemeris,
    /// Wheel-rate and steering limits of the rover.
    pub limits: (f64, f64),
    /// Motor commands with a moving wheel are invariant violations (the navigator is safed).
    pub must_stand: bool,
    /// Invariant violations found by the mobility device since the last check.
    pub bad_commands: Vec<BadCommand>,
    /// Commands received.
    pub commands: u64,
    /// Commands refused (garbage answer).
    pub commands_refused: u64,
    /// Keep the last [`TRACE_LEN`] garbage answers in [`Self::trace`] (for a finding's report).
    pub tracing: bool,
    /// The last garbage answers: (time of the frame, us; device; the answer).
    pub trace: std::collections::VecDeque<(u64, &'static str, String)>,
}

/// Garbage answers kept by a tracing run.
pub const TRACE_LEN: usize = 24;

impl Shared {
    /// A plausible world at time 0.
    pub fn new(seed: u64, yaw_rad: f64, sun: SunEphemeris, limits: (f64, f64)) -> Self {
        Self {
            rng: Rng::new(seed),
            t_us: 0,
            garbage: [0.0; DEVICES],
            fault_counts: [0; DEVICES],
            calls: [0; DEVICES],
            energy_j: 0.0,
            wheel_angle_rad: [0.0; WHEEL_COUNT],
            command: MobilityCommand::default(),
            yaw_rad,
            sun,
            limits,
            must_stand: false,
            bad_commands: Vec::new(),
            commands: 0,
            commands_refused: 0,
            tracing: false,
            trace: Default::default(),
        }
    }

    /// Advance the plausible world by one minor frame.
    pub fn advance(&mut self) {
        self.t_us = self.t_us.saturating_add(FRAME_US);
        let dt = FRAME_US as f64 * 1e-6;
        for i in 0..WHEEL_COUNT {
            self.wheel_angle_rad[i] += self.command.wheel_rate_rad_s[i] * dt;
        }
        self.energy_j += self.bus_power_w() * dt;
    }

    /// Bus power of the plausible rover, W: awake, plus the drive's share for the mean
    /// commanded wheel rate against the limit.
    fn bus_power_w(&self) -> f64 {
        let rate: f64 = self
            .command
            .wheel_rate_rad_s
            .iter()
            .map(|r| r.abs())
            .sum::<f64>()
            / WHEEL_COUNT as f64;
        AWAKE_POWER_W + DRIVE_POWER_W * (rate / self.limits.0.max(1e-9)).min(1.0)
    }

    /// Whether this call of `device` gets a garbage answer (and count it).
    fn bad(&mut self, device: usize) -> bool {
        self.calls[device] += 1;
        let p = self.garbage[device];
        let bad = p > 0.0 && self.rng.chance(p);
        if bad {
            self.fault_counts[device] += 1;
        }
        bad
    }

    fn error(&mut self) -> ErrorKind {
        ERROR_KINDS[self.rng.below(ERROR_KINDS.len() as u64) as usize]
    }

    /// A hostile number: non-finite, huge, tiny, signed zero, random bits or random values.
    fn value(&mut self) -> f64 {
        match self.rng.below(14) {
            0 => f64::NAN,
            1 => f64::INFINITY,
            2 => f64::NEG_INFINITY,
            3 => f64::MAX,
            4 => -f64::MAX,
            5 => 1e300,
            6 => 1e6 * self.rng.sign(),
            7 => f64::MIN_POSITIVE,
            8 => 5e-324,
            9 => -0.0,
            10 => f64::from_bits(self.rng.next_u64()),
            11 => self.rng.uniform(-1e3, 1e3),
            12 => self.rng.uniform(-10.0, 10.0),
            _ => self.rng.uniform(-1.0, 1.0) * 1e12,
        }
    }

    /// Maybe replace `v` with a hostile number (each with probability one half).
    fn maybe(&mut self, v: &mut f64) {
        if self.rng.chance(0.5) {
            *v = self.value();
        }
    }

    /// A hostile time stamp for a reading whose good stamp is `t_us` and last stamp `last`.
    fn stamp(&mut self, t_us: u64, last: u64) -> u64 {
        match self.rng.below(9) {
            0 => last,
            1 => last.saturating_sub(1 + self.rng.below(10_000_000)),
            2 => t_us.saturating_add(3_600_000_000),
            3 => 0,
            4 => u64::MAX,
            5 => t_us.saturating_add(self.rng.below(100_000)),
            6 => t_us.wrapping_add(self.rng.next_u64() >> self.rng.below(64)),
            7 => t_us.saturating_sub(self.rng.below(20_000)),
            _ => t_us,
        }
    }

    /// Record a garbage answer of `device` (tracing runs only).
    fn note(&mut self, device: usize, answer: impl FnOnce() -> String) {
        if self.tracing {
            if self.trace.len() == TRACE_LEN {
                self.trace.pop_front();
            }
            let t = self.t_us;
            self.trace.push_back((t, DEVICE_NAMES[device], answer()));
        }
    }

    /// Time of the plausible readings (microseconds).
    fn now(&self) -> u64 {
        self.t_us
    }
}

/// The shared state as the devices hold it.
pub type SharedRc = Rc<RefCell<Shared>>;

/// Clock: simulated time and an execution counter that advances by 1 us per call.
pub struct FuzzClock {
    shared: SharedRc,
    counter: u64,
    last: u64,
}

impl FuzzClock {
    /// A clock on `shared`.
    pub fn new(shared: SharedRc) -> Self {
        Self {
            shared,
            counter: 0,
            last: 0,
        }
    }
}

impl Clock for FuzzClock {
    type Error = ErrorKind;
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        let t = s.now();
        if s.bad(CLOCK) {
            if s.rng.chance(0.3) {
                return Err(s.error());
            }
            return Ok(s.stamp(t, self.last));
        }
        self.last = t;
        Ok(t)
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        if s.bad(CLOCK) {
            return match s.rng.below(5) {
                0 | 1 => Err(s.error()),
                2 => Ok(self.counter.wrapping_sub(s.rng.below(1_000_000_000))),
                3 => Ok(u64::MAX - s.rng.below(1000)),
                _ => Ok(self
                    .counter
                    .wrapping_add(s.rng.next_u64() >> s.rng.below(64))),
            };
        }
        // Deterministic: 1 us of "execution" per call (no host timing in the fuzzer).
        self.counter = self.counter.wrapping_add(1_000);
        Ok(self.counter)
    }
    fn counter_hz(&self) -> u64 {
        1_000_000_000
    }
}

/// IMU: a standing rover (with small noise) or garbage.
pub struct FuzzImu {
    shared: SharedRc,
    last: u64,
}

impl FuzzImu {
    /// An IMU on `shared`.
    pub fn new(shared: SharedRc) -> Self {
        Self { shared, last: 0 }
    }
}

impl Imu for FuzzImu {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<ImuSample, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        let t = s.now();
        let noise = |s: &mut Shared, sigma: f64| s.rng.uniform(-sigma, sigma);
        let mut sample = ImuSample {
            t_us: t,
            gyro_rad_s: [
                noise(&mut s, 1e-3),
                noise(&mut s, 1e-3),
                noise(&mut s, 1e-3),
            ],
            accel_m_s2: [
                noise(&mut s, 1e-2),
                noise(&mut s, 1e-2),
                -GRAVITY_M_S2 + noise(&mut s, 1e-2),
            ],
            valid: true,
        };
        if s.bad(IMU) {
            if s.rng.chance(0.25) {
                let e = s.error();
                s.note(IMU, || format!("read -> Err({e:?})"));
                return Err(e);
            }
            for v in sample
                .gyro_rad_s
                .iter_mut()
                .chain(sample.accel_m_s2.iter_mut())
            {
                s.maybe(v);
            }
            if s.rng.chance(0.2) {
                sample.valid = false;
            }
            if s.rng.chance(0.4) {
                sample.t_us = s.stamp(t, self.last);
            }
            s.note(IMU, || format!("read -> {sample:?}"));
        }
        self.last = sample.t_us;
        Ok(sample)
    }
}

/// Joints and motors: the joints follow the accepted commands; every command is checked
/// against the invariants.
pub struct FuzzMobility {
    shared: SharedRc,
    last: u64,
}

impl FuzzMobility {
    /// Mobility on `shared`.
    pub fn new(shared: SharedRc) -> Self {
        Self { shared, last: 0 }
    }
}

impl Mobility for FuzzMobility {
    type Error = ErrorKind;
    fn read_joints(&mut self) -> Result<JointState, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        let t = s.now();
        let mut j = JointState {
            t_us: t,
            drive_angle_rad: s.wheel_angle_rad,
            drive_rate_rad_s: s.command.wheel_rate_rad_s,
            steer_angle_rad: s.command.steer_angle_rad,
            rocker_rad: 0.0,
            bogie_rad: [0.0; 2],
            wheel_valid: [true; WHEEL_COUNT],
            suspension_valid: true,
        };
        if s.bad(MOBILITY) {
            if s.rng.chance(0.25) {
                let e = s.error();
                s.note(MOBILITY, || format!("read_joints -> Err({e:?})"));
                return Err(e);
            }
            for v in j
                .drive_angle_rad
                .iter_mut()
                .chain(j.drive_rate_rad_s.iter_mut())
                .chain(j.steer_angle_rad.iter_mut())
                .chain(j.bogie_rad.iter_mut())
                .chain(std::iter::once(&mut j.rocker_rad))
            {
                if s.rng.chance(0.3) {
                    *v = s.value();
                }
            }
            for ok in j.wheel_valid.iter_mut() {
                *ok = !s.rng.chance(0.2);
            }
            j.suspension_valid = !s.rng.chance(0.2);
            if s.rng.chance(0.4) {
                j.t_us = s.stamp(t, self.last);
            }
            s.note(MOBILITY, || format!("read_joints -> {j:?}"));
        }
        self.last = j.t_us;
        Ok(j)
    }

    fn command(&mut self, command: &MobilityCommand) -> Result<(), ErrorKind> {
        let mut s = self.shared.borrow_mut();
        s.commands += 1;
        let (rate_limit, steer_limit) = s.limits;
        let tol = 1e-9;
        let ok = command
            .wheel_rate_rad_s
            .iter()
            .all(|r| r.is_finite() && r.abs() <= rate_limit + tol)
            && command
                .steer_angle_rad
                .iter()
                .all(|a| a.is_finite() && a.abs() <= steer_limit + tol);
        let moving = command.wheel_rate_rad_s.iter().any(|r| *r != 0.0);
        if !ok || (s.must_stand && moving) {
            s.bad_commands.push(BadCommand { command: *command });
        }
        if s.bad(MOBILITY) {
            s.commands_refused += 1;
            let e = s.error();
            s.note(MOBILITY, || format!("command -> Err({e:?})"));
            return Err(e);
        }
        if ok {
            s.command = *command;
        }
        Ok(())
    }

    fn stop(&mut self) -> Result<(), ErrorKind> {
        let mut s = self.shared.borrow_mut();
        if s.bad(MOBILITY) {
            return Err(s.error());
        }
        s.command.wheel_rate_rad_s = [0.0; WHEEL_COUNT];
        Ok(())
    }
}

/// Sun sensor: the ephemeris' sun seen by the standing rover, or garbage.
pub struct FuzzSun {
    shared: SharedRc,
    last: u64,
}

impl FuzzSun {
    /// A sun sensor on `shared`.
    pub fn new(shared: SharedRc) -> Self {
        Self { shared, last: 0 }
    }
}

impl SunSensor for FuzzSun {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<SunReading, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        let t = s.now();
        let (dir, in_view) = match s.sun.sun_dir_n(t) {
            Some(n) => {
                // R = Rz(yaw): v_R = Rz(-yaw) v_N (level rover).
                let (sn, cs) = s.yaw_rad.sin_cos();
                ([cs * n.x + sn * n.y, -sn * n.x + cs * n.y, n.z], true)
            }
            None => ([0.0, 0.0, -1.0], false),
        };
        let mut r = SunReading {
            t_us: t,
            sun_dir_rover: dir,
            sun_in_view: in_view,
        };
        if s.bad(SUN) {
            if s.rng.chance(0.25) {
                let e = s.error();
                s.note(SUN, || format!("read -> Err({e:?})"));
                return Err(e);
            }
            match s.rng.below(3) {
                0 => {
                    for v in r.sun_dir_rover.iter_mut() {
                        s.maybe(v);
                    }
                }
                1 => {
                    // Finite, unit length, wrong direction.
                    let a = s.rng.uniform(-3.2, 3.2);
                    let b = s.rng.uniform(-1.6, 1.6);
                    r.sun_dir_rover = [a.cos() * b.cos(), a.sin() * b.cos(), b.sin()];
                }
                _ => {
                    let k = s.rng.uniform(0.0, 3.0);
                    r.sun_dir_rover = r.sun_dir_rover.map(|v| v * k);
                }
            }
            r.sun_in_view = s.rng.chance(0.7);
            if s.rng.chance(0.4) {
                r.t_us = s.stamp(t, self.last);
            }
            s.note(SUN, || format!("read -> {r:?}"));
        }
        self.last = r.t_us;
        Ok(r)
    }
}

/// The images a camera can hand out.
const BLACK: usize = 0;
const GREY: usize = 1;
const TEXTURE: usize = 2;
// 3: stripes, 4: a 100-byte image (wrong size), 5: the right image of the textured pair;
// 3 and 4 handed out by garbage frames only.
const TEXTURE_RIGHT: usize = 5;

/// What happens to the capture in progress.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Capture {
    Idle,
    /// Completes after the given polls.
    Pending {
        t_us: u64,
        polls: u32,
    },
    /// Never completes.
    Never,
    Ready {
        t_us: u64,
    },
}

/// Stereo camera: captures complete after three polls with a textured, grey or black pair, or
/// garbage.
pub struct FuzzCamera {
    shared: SharedRc,
    images: [Vec<u8>; 6],
    capture: Capture,
    sequence: u32,
    /// Image of the completed capture, and its stamp and sequence as handed out (a garbage
    /// frame may lie about them).
    frame: Cell<(usize, usize, u64, u32)>,
    /// Hand out textured pairs in plausible stretches (VO work) at all.
    texture: bool,
}

impl FuzzCamera {
    /// A camera on `shared`; `texture`: plausible captures may carry a textured pair (VO
    /// works on it; slower).
    pub fn new(shared: SharedRc, texture: bool) -> Self {
        let mut rng = Rng::new(0x1234_5678);
        let texture_image: Vec<u8> = (0..IMAGE_PIXELS)
            .map(|_| (rng.next_u64() >> 56) as u8)
            .collect();
        let stripes: Vec<u8> = (0..IMAGE_PIXELS)
            .map(|i| {
                if (i / IMAGE_WIDTH_PX / 8) % 2 == 0 {
                    0
                } else {
                    255
                }
            })
            .collect();
        // The right image of the textured pair: the left one shifted 12 px (a fronto-parallel
        // wall at constant disparity).
        let texture_right: Vec<u8> = (0..IMAGE_PIXELS)
            .map(|i| {
                let x = i % IMAGE_WIDTH_PX;
                texture_image[i - x + (x + 12) % IMAGE_WIDTH_PX]
            })
            .collect();
        Self {
            shared,
            images: [
                vec![0; IMAGE_PIXELS],
                vec![128; IMAGE_PIXELS],
                texture_image,
                stripes,
                vec![7; 100],
                texture_right,
            ],
            capture: Capture::Idle,
            sequence: 0,
            frame: Cell::new((GREY, GREY, 0, 0)),
            texture,
        }
    }
}

impl StereoCamera for FuzzCamera {
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        // The flight software's own nominal hazcam (the fuzzer tests the flight code; it is not
        // the simulator, which keeps an independent camera model).
        fsw::vo::rocky8_hazcam()
    }

    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        let t = s.now();
        self.sequence = self.sequence.wrapping_add(1);
        if s.bad(CAMERA) {
            let choice = s.rng.below(4);
            s.note(CAMERA, || format!("trigger: garbage case {choice} (0 error, 1 never completes, 2 lost, 3 garbage stamp/frame)"));
            match choice {
                0 => return Err(s.error()),
                1 => {
                    self.capture = Capture::Never;
                    return Ok(t);
                }
                2 => {
                    // Accepted and lost.
                    self.capture = Capture::Idle;
                    return Ok(t);
                }
                _ => {
                    let stamp = s.stamp(t, t);
                    self.capture = Capture::Pending {
                        t_us: stamp,
                        polls: s.rng.below(5) as u32,
                    };
                    self.frame.set((
                        s.rng.below(6) as usize,
                        s.rng.below(6) as usize,
                        if s.rng.chance(0.5) {
                            stamp
                        } else {
                            s.stamp(t, t)
                        },
                        if s.rng.chance(0.7) {
                            self.sequence
                        } else {
                            s.rng.next_u64() as u32
                        },
                    ));
                    return Ok(stamp);
                }
            }
        }
        let image = if self.texture && s.rng.chance(0.5) {
            TEXTURE
        } else if s.rng.chance(0.8) {
            GREY
        } else {
            BLACK
        };
        let right = if image == TEXTURE {
            TEXTURE_RIGHT
        } else {
            image
        };
        self.capture = Capture::Pending { t_us: t, polls: 3 };
        self.frame.set((image, right, t, self.sequence));
        Ok(t)
    }

    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        if s.bad(CAMERA) {
            s.note(CAMERA, || "poll: garbage".to_string());
            return match s.rng.below(4) {
                0 => Err(s.error()),
                1 => Ok(CaptureStatus::Idle),
                2 => Ok(CaptureStatus::InProgress),
                _ => Ok(CaptureStatus::Ready),
            };
        }
        Ok(match self.capture {
            Capture::Idle => CaptureStatus::Idle,
            Capture::Never => CaptureStatus::InProgress,
            Capture::Pending { t_us, polls: 0 } => {
                self.capture = Capture::Ready { t_us };
                CaptureStatus::Ready
            }
            Capture::Pending { t_us, polls } => {
                self.capture = Capture::Pending {
                    t_us,
                    polls: polls - 1,
                };
                CaptureStatus::InProgress
            }
            Capture::Ready { .. } => CaptureStatus::Ready,
        })
    }

    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        let (left, right, t_us, sequence) = self.frame.get();
        if s.bad(CAMERA) {
            if s.rng.chance(0.3) {
                return Err(s.error());
            }
            let pick = |s: &mut Shared| s.rng.below(6) as usize;
            let (l, r) = (pick(&mut s), pick(&mut s));
            let t = s.now();
            let stamp = if s.rng.chance(0.5) {
                t_us
            } else {
                s.stamp(t, t_us)
            };
            s.note(CAMERA, || {
                format!("frame: images {l}/{r}, stamp {stamp} (capture {t_us})")
            });
            return Ok(StereoFrame {
                left: &self.images[l],
                right: &self.images[r],
                capture_t_us: stamp,
                sequence: s.rng.next_u64() as u32,
            });
        }
        match self.capture {
            Capture::Ready { .. } => Ok(StereoFrame {
                left: &self.images[left],
                right: &self.images[right],
                capture_t_us: t_us,
                sequence,
            }),
            _ => Err(ErrorKind::NotReady),
        }
    }

    fn release(&mut self) -> Result<(), ErrorKind> {
        let mut s = self.shared.borrow_mut();
        if s.bad(CAMERA) {
            return Err(s.error());
        }
        self.capture = Capture::Idle;
        Ok(())
    }
}

/// Power subsystem: the plausible battery energy and bus power, or garbage.
pub struct FuzzPower {
    shared: SharedRc,
    last: u64,
}

impl FuzzPower {
    /// A power subsystem on `shared`.
    pub fn new(shared: SharedRc) -> Self {
        Self { shared, last: 0 }
    }
}

impl Power for FuzzPower {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<PowerReading, ErrorKind> {
        let mut s = self.shared.borrow_mut();
        let t = s.now();
        let mut r = PowerReading {
            t_us: t,
            energy_used_j: s.energy_j,
            bus_power_w: s.bus_power_w(),
            valid: true,
        };
        if s.bad(POWER) {
            if s.rng.chance(0.25) {
                let e = s.error();
                s.note(POWER, || format!("read -> Err({e:?})"));
                return Err(e);
            }
            match s.rng.below(4) {
                0 => {
                    s.maybe(&mut r.energy_used_j);
                    s.maybe(&mut r.bus_power_w);
                }
                1 => {
                    // Less energy used than before (finite), or negative.
                    r.energy_used_j -= s.rng.uniform(1e-9, 1e4);
                }
                2 => r.bus_power_w = -s.rng.uniform(0.0, 1e3),
                _ => r.valid = false,
            }
            if s.rng.chance(0.4) {
                r.t_us = s.stamp(t, self.last);
            }
            s.note(POWER, || format!("read -> {r:?}"));
        }
        self.last = r.t_us;
        Ok(r)
    }
}

/// Telemetry sink: takes records, or refuses them with any error.
pub struct FuzzTelemetry {
    shared: SharedRc,
    /// Records taken.
    pub records: u64,
}

impl FuzzTelemetry {
    /// A sink on `shared`.
    pub fn new(shared: SharedRc) -> Self {
        Self { shared, records: 0 }
    }
}

impl Telemetry for FuzzTelemetry {
    type Error = ErrorKind;
    fn send(&mut self, record: &[u8]) -> Result<(), ErrorKind> {
        let mut s = self.shared.borrow_mut();
        if s.bad(TELEMETRY) {
            return Err(s.error());
        }
        if record.is_empty() {
            return Err(ErrorKind::InvalidRequest);
        }
        self.records += 1;
        Ok(())
    }
}
