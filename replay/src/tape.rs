//! The call-tape format: a header, then records, all little-endian.
//!
//! ```text
//! header   "RVRTAPE4" (the last byte is the version; "RVRTAPE3" is read too), then the
//!          fixed-size body of [`TapeHeader`] (HEADER_BYTES in all)
//! record   tag: u8, len: u8, body: [u8; len]
//! images   a record with tag IMAGES whose body is ImagesRef (id, left_len, right_len),
//!          followed by left_len + right_len bytes of pixels (not counted in len)
//! ```
//!
//! Call records ([`Call`]) carry a status byte (0: `Ok`, otherwise the [`ErrorKind`] code of
//! [`error_code`]) and, when `Ok`, the value. A frame ends with [`Record::FrameEnd`] (the tick
//! and the recording run's digest of that frame); the tape ends with [`Record::End`].
//!
//! Every decoder checks lengths and codes and returns a [`TapeError`] instead of panicking.
//!
//! Versions: 4 added the power subsystem's reads ([`Call::PowerRead`]); a version-3 tape has
//! the same header and records without them, and still loads ([`TapeHeader::version`]: its
//! replay power device answers `NotReady` without consuming a record,
//! [`crate::devices::ReplayPower::new`]).

use rover_hal::{
    CaptureStatus, ErrorKind, ImuSample, JointState, LensCalibration, PowerReading, RawCamera,
    StereoCalibration, SunReading, WHEEL_COUNT,
};

/// Magic bytes at the start of a tape written now (the last byte is the format version,
/// [`VERSION`]).
pub const MAGIC: [u8; 8] = *b"RVRTAPE4";
/// Format version written now: 4, with the power subsystem's reads.
pub const VERSION: u8 = b'4';
/// Oldest format version read: 3 (no power reads; otherwise the same).
pub const OLDEST_VERSION: u8 = b'3';
/// The first version whose tapes carry [`Call::PowerRead`].
pub const POWER_VERSION: u8 = b'4';
/// Largest number of path waypoints a header carries.
pub const MAX_WAYPOINTS: usize = 16;
/// Number of flight-configuration parameters a header carries ([`TapeHeader::nav_params`]).
pub const NAV_PARAMS: usize = 16;
/// Bytes of the scenario name field (UTF-8, NUL padded).
pub const NAME_BYTES: usize = 32;
/// Size of the encoded header, bytes.
pub const HEADER_BYTES: usize = 8
    + 4
    + 4
    + 8
    + 17 * 8
    + LENS_BYTES
    + 6 * 8
    + NAV_PARAMS * 8
    + 1
    + MAX_WAYPOINTS * 16
    + NAME_BYTES;
/// Bytes of the lens calibration field: a presence byte and two raw cameras of 18 `f64`.
const LENS_BYTES: usize = 1 + 2 * 18 * 8;
/// Largest encoded record (tag, length and body), bytes.
pub const MAX_RECORD_BYTES: usize = 2 + 255;

/// What went wrong reading or writing a tape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TapeError {
    /// The tape does not start with [`MAGIC`].
    BadMagic,
    /// The tape ended inside a header or a record.
    Truncated,
    /// An unknown record tag.
    UnknownTag(u8),
    /// A record's length does not match its tag and status.
    BadLength(u8),
    /// An invalid status, error or capture code inside a record.
    BadCode(u8),
    /// The output buffer is too small for the record.
    BufferTooSmall,
    /// A header field is out of range (too many waypoints, name too long).
    BadHeader,
    /// The byte source failed (I/O error of the file system or semihosting).
    Io,
    /// A frame holds more records than the [`crate::Player`] can queue.
    FrameTooLong,
}

/// The scenario segment a tape was recorded from: what the replay needs besides the calls
/// (the camera calibration, which the camera returns without a call result) and what the flight
/// software's construction needs (the path and the start pose).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TapeHeader {
    /// Format version of the tape (the last byte of its magic, ASCII: `b'3'`, `b'4'`). Read
    /// from the tape; [`TapeHeader::encode`] always writes [`VERSION`].
    pub version: u8,
    /// Minor-frame period of the recording, microseconds.
    pub frame_period_us: u32,
    /// Frames recorded.
    pub frames: u32,
    /// Seed of the simulation.
    pub seed: u64,
    /// Calibration of the stereo camera.
    pub calibration: StereoCalibration,
    /// Lens calibration of the raw cameras when the camera delivers raw images (the tape's
    /// pixels are then raw).
    pub lens: Option<LensCalibration>,
    /// True start pose of the rover: north, east, down (m), roll, pitch, yaw (rad).
    pub start_pose: [f64; 6],
    /// The recording flight software's configuration parameters that the scenario set (IMU
    /// noise, sun direction...); their meaning is defined by the consumer
    /// (`fsw_image::flight_replay::nav_params`).
    pub nav_params: [f64; NAV_PARAMS],
    /// Path waypoints (north, east), m; the first `waypoint_count` are used.
    pub waypoints: [[f64; 2]; MAX_WAYPOINTS],
    /// Number of waypoints.
    pub waypoint_count: u8,
    /// Scenario name, UTF-8, NUL padded.
    pub scenario: [u8; NAME_BYTES],
}

impl TapeHeader {
    /// The tape carries the power subsystem's reads ([`Call::PowerRead`]; version 4 on).
    pub fn has_power(&self) -> bool {
        self.version >= POWER_VERSION
    }

    /// The used waypoints.
    pub fn waypoints(&self) -> &[[f64; 2]] {
        let n = usize::from(self.waypoint_count).min(MAX_WAYPOINTS);
        self.waypoints.get(..n).unwrap_or(&[])
    }

    /// The scenario name (up to the first NUL; empty when it is not UTF-8).
    pub fn scenario_name(&self) -> &str {
        let end = self
            .scenario
            .iter()
            .position(|b| *b == 0)
            .unwrap_or(NAME_BYTES);
        self.scenario
            .get(..end)
            .and_then(|b| core::str::from_utf8(b).ok())
            .unwrap_or("")
    }

    /// Encode into `out` (at least [`HEADER_BYTES`]); returns the bytes written.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, TapeError> {
        if usize::from(self.waypoint_count) > MAX_WAYPOINTS {
            return Err(TapeError::BadHeader);
        }
        let mut w = Writer::new(out);
        w.bytes(&MAGIC)?;
        w.u32(self.frame_period_us)?;
        w.u32(self.frames)?;
        w.u64(self.seed)?;
        put_calibration(&mut w, &self.calibration)?;
        put_lens(&mut w, self.lens.as_ref())?;
        w.f64s(&self.start_pose)?;
        w.f64s(&self.nav_params)?;
        w.u8(self.waypoint_count)?;
        for p in &self.waypoints {
            w.f64s(p)?;
        }
        w.bytes(&self.scenario)?;
        Ok(w.pos)
    }

    /// Decode from the first [`HEADER_BYTES`] of `bytes` (versions [`OLDEST_VERSION`] to
    /// [`VERSION`]).
    pub fn decode(bytes: &[u8]) -> Result<Self, TapeError> {
        let mut r = Reader::new(bytes);
        let magic = r.take(8)?;
        let version = match magic.split_last() {
            Some((&v, stem))
                if stem == MAGIC.get(..7).unwrap_or(&[])
                    && (OLDEST_VERSION..=VERSION).contains(&v) =>
            {
                v
            }
            _ => return Err(TapeError::BadMagic),
        };
        let frame_period_us = r.u32()?;
        let frames = r.u32()?;
        let seed = r.u64()?;
        let calibration = get_calibration(&mut r)?;
        let lens = get_lens(&mut r)?;
        let start_pose = r.f64s::<6>()?;
        let nav_params = r.f64s::<NAV_PARAMS>()?;
        let waypoint_count = r.u8()?;
        if usize::from(waypoint_count) > MAX_WAYPOINTS {
            return Err(TapeError::BadHeader);
        }
        let mut waypoints = [[0.0; 2]; MAX_WAYPOINTS];
        for p in waypoints.iter_mut() {
            *p = r.f64s::<2>()?;
        }
        let mut scenario = [0u8; NAME_BYTES];
        scenario.copy_from_slice(r.take(NAME_BYTES)?);
        Ok(Self {
            version,
            frame_period_us,
            frames,
            seed,
            calibration,
            lens,
            start_pose,
            nav_params,
            waypoints,
            waypoint_count,
            scenario,
        })
    }
}

/// What [`rover_hal::StereoCamera::frame`] returned, without the pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameInfo {
    /// Exposure time, microseconds since boot.
    pub capture_t_us: u64,
    /// Capture sequence number.
    pub sequence: u32,
    /// Length of the left image, bytes.
    pub left_len: u32,
    /// Length of the right image, bytes.
    pub right_len: u32,
    /// Id of the [`ImagesRef`] whose pixels the frame returned.
    pub images: u32,
}

/// A stereo pair stored in the tape: its id, image lengths and where its pixels are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImagesRef {
    /// Id (1 for the first pair of the tape, then counting up).
    pub id: u32,
    /// Left image length, bytes.
    pub left_len: u32,
    /// Right image length, bytes.
    pub right_len: u32,
    /// Byte offset of the left image's first pixel in the tape (the right image follows).
    /// Not encoded: the reader fills it in.
    pub offset: u64,
}

/// The kind of a device call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum CallKind {
    /// `Clock::now_us`.
    ClockNow = 1,
    /// `Imu::read`.
    ImuRead = 2,
    /// `Mobility::read_joints`.
    JointsRead = 3,
    /// `Mobility::command`.
    MobilityCommand = 4,
    /// `Mobility::stop`.
    MobilityStop = 5,
    /// `SunSensor::read`.
    SunRead = 6,
    /// `StereoCamera::trigger`.
    CameraTrigger = 7,
    /// `StereoCamera::poll`.
    CameraPoll = 8,
    /// `StereoCamera::frame`.
    CameraFrame = 9,
    /// `StereoCamera::release`.
    CameraRelease = 10,
    /// `Telemetry::send`.
    TelemetrySend = 11,
    /// `Power::read` (tape version 4 on).
    PowerRead = 12,
}

/// Record tag of [`Record::Images`].
const TAG_IMAGES: u8 = 0x40;
/// Record tag of [`Record::FrameEnd`].
const TAG_FRAME_END: u8 = 0x41;
/// Record tag of [`Record::End`].
const TAG_END: u8 = 0x42;

/// The result of one device call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Call {
    /// `Clock::now_us`.
    ClockNow(Result<u64, ErrorKind>),
    /// `Imu::read`.
    ImuRead(Result<ImuSample, ErrorKind>),
    /// `Mobility::read_joints`.
    JointsRead(Result<JointState, ErrorKind>),
    /// `Mobility::command` (the command itself is an output, see [`crate::FrameOutputs`]).
    MobilityCommand(Result<(), ErrorKind>),
    /// `Mobility::stop`.
    MobilityStop(Result<(), ErrorKind>),
    /// `SunSensor::read`.
    SunRead(Result<SunReading, ErrorKind>),
    /// `StereoCamera::trigger`.
    CameraTrigger(Result<u64, ErrorKind>),
    /// `StereoCamera::poll`.
    CameraPoll(Result<CaptureStatus, ErrorKind>),
    /// `StereoCamera::frame`.
    CameraFrame(Result<FrameInfo, ErrorKind>),
    /// `StereoCamera::release`.
    CameraRelease(Result<(), ErrorKind>),
    /// `Telemetry::send` (the record itself is an output).
    TelemetrySend(Result<(), ErrorKind>),
    /// `Power::read` (tape version 4 on).
    PowerRead(Result<PowerReading, ErrorKind>),
}

impl Call {
    /// Which call this is the result of.
    pub fn kind(&self) -> CallKind {
        match self {
            Call::ClockNow(_) => CallKind::ClockNow,
            Call::ImuRead(_) => CallKind::ImuRead,
            Call::JointsRead(_) => CallKind::JointsRead,
            Call::MobilityCommand(_) => CallKind::MobilityCommand,
            Call::MobilityStop(_) => CallKind::MobilityStop,
            Call::SunRead(_) => CallKind::SunRead,
            Call::CameraTrigger(_) => CallKind::CameraTrigger,
            Call::CameraPoll(_) => CallKind::CameraPoll,
            Call::CameraFrame(_) => CallKind::CameraFrame,
            Call::CameraRelease(_) => CallKind::CameraRelease,
            Call::TelemetrySend(_) => CallKind::TelemetrySend,
            Call::PowerRead(_) => CallKind::PowerRead,
        }
    }
}

/// One record of a tape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Record {
    /// A device call's result.
    Call(Call),
    /// A stereo pair (its pixels follow the record in the tape).
    Images(ImagesRef),
    /// End of a minor frame: its tick and the recording run's digest of its outputs.
    FrameEnd {
        /// Tick of the frame (0 for the first).
        tick: u64,
        /// Digest of the frame's outputs in the recording run.
        digest: u64,
    },
    /// End of the tape.
    End,
}

/// Code of an [`ErrorKind`] in a tape (1 to 7; an unknown future kind is recorded as `Other`).
pub fn error_code(kind: ErrorKind) -> u8 {
    match kind {
        ErrorKind::NotReady => 1,
        ErrorKind::Timeout => 2,
        ErrorKind::InvalidData => 3,
        ErrorKind::Busy => 4,
        ErrorKind::Hardware => 5,
        ErrorKind::InvalidRequest => 6,
        _ => 7,
    }
}

/// The [`ErrorKind`] of a tape code.
pub fn error_from_code(code: u8) -> Result<ErrorKind, TapeError> {
    Ok(match code {
        1 => ErrorKind::NotReady,
        2 => ErrorKind::Timeout,
        3 => ErrorKind::InvalidData,
        4 => ErrorKind::Busy,
        5 => ErrorKind::Hardware,
        6 => ErrorKind::InvalidRequest,
        7 => ErrorKind::Other,
        c => return Err(TapeError::BadCode(c)),
    })
}

/// Encode `record` into `out` (at least [`MAX_RECORD_BYTES`] is always enough); returns the
/// bytes written. The pixels of an [`Record::Images`] are not written: the caller appends them.
pub fn encode_record(record: &Record, out: &mut [u8]) -> Result<usize, TapeError> {
    let mut body = [0u8; 255];
    let mut w = Writer::new(&mut body);
    let tag = match record {
        Record::Call(call) => {
            encode_call(call, &mut w)?;
            call.kind() as u8
        }
        Record::Images(i) => {
            w.u32(i.id)?;
            w.u32(i.left_len)?;
            w.u32(i.right_len)?;
            TAG_IMAGES
        }
        Record::FrameEnd { tick, digest } => {
            w.u64(*tick)?;
            w.u64(*digest)?;
            TAG_FRAME_END
        }
        Record::End => TAG_END,
    };
    let len = w.pos;
    let len_byte = u8::try_from(len).map_err(|_| TapeError::BufferTooSmall)?;
    let mut o = Writer::new(out);
    o.u8(tag)?;
    o.u8(len_byte)?;
    o.bytes(body.get(..len).ok_or(TapeError::BufferTooSmall)?)?;
    Ok(o.pos)
}

/// Decode one record from its `tag` and `body` (the `len` bytes after the tag and length).
/// An [`Record::Images`] comes back with `offset` 0.
pub fn decode_record(tag: u8, body: &[u8]) -> Result<Record, TapeError> {
    let mut r = Reader::new(body);
    let record = match tag {
        TAG_IMAGES => Record::Images(ImagesRef {
            id: r.u32()?,
            left_len: r.u32()?,
            right_len: r.u32()?,
            offset: 0,
        }),
        TAG_FRAME_END => Record::FrameEnd {
            tick: r.u64()?,
            digest: r.u64()?,
        },
        TAG_END => Record::End,
        t => Record::Call(decode_call(t, &mut r)?),
    };
    if r.pos != body.len() {
        return Err(TapeError::BadLength(tag));
    }
    Ok(record)
}

fn put_result<T>(
    w: &mut Writer<'_>,
    result: &Result<T, ErrorKind>,
    put: impl FnOnce(&mut Writer<'_>, &T) -> Result<(), TapeError>,
) -> Result<(), TapeError> {
    match result {
        Ok(v) => {
            w.u8(0)?;
            put(w, v)
        }
        Err(kind) => w.u8(error_code(*kind)),
    }
}

fn get_result<T>(
    r: &mut Reader<'_>,
    get: impl FnOnce(&mut Reader<'_>) -> Result<T, TapeError>,
) -> Result<Result<T, ErrorKind>, TapeError> {
    match r.u8()? {
        0 => Ok(Ok(get(r)?)),
        code => Ok(Err(error_from_code(code)?)),
    }
}

fn encode_call(call: &Call, w: &mut Writer<'_>) -> Result<(), TapeError> {
    let unit = |_: &mut Writer<'_>, _: &()| Ok(());
    match call {
        Call::ClockNow(r) | Call::CameraTrigger(r) => put_result(w, r, |w, t| w.u64(*t)),
        Call::ImuRead(r) => put_result(w, r, |w, s| {
            w.u64(s.t_us)?;
            w.f64s(&s.gyro_rad_s)?;
            w.f64s(&s.accel_m_s2)?;
            w.bool(s.valid)
        }),
        Call::JointsRead(r) => put_result(w, r, |w, j| {
            w.u64(j.t_us)?;
            w.f64s(&j.drive_angle_rad)?;
            w.f64s(&j.drive_rate_rad_s)?;
            w.f64s(&j.steer_angle_rad)?;
            w.f64(j.rocker_rad)?;
            w.f64s(&j.bogie_rad)?;
            for v in &j.wheel_valid {
                w.bool(*v)?;
            }
            w.bool(j.suspension_valid)
        }),
        Call::SunRead(r) => put_result(w, r, |w, s| {
            w.u64(s.t_us)?;
            w.f64s(&s.sun_dir_rover)?;
            w.bool(s.sun_in_view)
        }),
        Call::PowerRead(r) => put_result(w, r, |w, p| {
            w.u64(p.t_us)?;
            w.f64(p.energy_used_j)?;
            w.f64(p.bus_power_w)?;
            w.bool(p.valid)
        }),
        Call::CameraPoll(r) => put_result(w, r, |w, s| {
            w.u8(match s {
                CaptureStatus::Idle => 0,
                CaptureStatus::InProgress => 1,
                CaptureStatus::Ready => 2,
            })
        }),
        Call::CameraFrame(r) => put_result(w, r, |w, f| {
            w.u64(f.capture_t_us)?;
            w.u32(f.sequence)?;
            w.u32(f.left_len)?;
            w.u32(f.right_len)?;
            w.u32(f.images)
        }),
        Call::MobilityCommand(r)
        | Call::MobilityStop(r)
        | Call::CameraRelease(r)
        | Call::TelemetrySend(r) => put_result(w, r, unit),
    }
}

fn decode_call(tag: u8, r: &mut Reader<'_>) -> Result<Call, TapeError> {
    let unit = |_: &mut Reader<'_>| Ok(());
    Ok(match tag {
        1 => Call::ClockNow(get_result(r, |r| r.u64())?),
        2 => Call::ImuRead(get_result(r, |r| {
            Ok(ImuSample {
                t_us: r.u64()?,
                gyro_rad_s: r.f64s()?,
                accel_m_s2: r.f64s()?,
                valid: r.bool()?,
            })
        })?),
        3 => Call::JointsRead(get_result(r, |r| {
            let t_us = r.u64()?;
            let drive_angle_rad = r.f64s::<WHEEL_COUNT>()?;
            let drive_rate_rad_s = r.f64s::<WHEEL_COUNT>()?;
            let steer_angle_rad = r.f64s::<WHEEL_COUNT>()?;
            let rocker_rad = r.f64()?;
            let bogie_rad = r.f64s::<2>()?;
            let mut wheel_valid = [false; WHEEL_COUNT];
            for v in wheel_valid.iter_mut() {
                *v = r.bool()?;
            }
            Ok(JointState {
                t_us,
                drive_angle_rad,
                drive_rate_rad_s,
                steer_angle_rad,
                rocker_rad,
                bogie_rad,
                wheel_valid,
                suspension_valid: r.bool()?,
            })
        })?),
        4 => Call::MobilityCommand(get_result(r, unit)?),
        5 => Call::MobilityStop(get_result(r, unit)?),
        6 => Call::SunRead(get_result(r, |r| {
            Ok(SunReading {
                t_us: r.u64()?,
                sun_dir_rover: r.f64s()?,
                sun_in_view: r.bool()?,
            })
        })?),
        7 => Call::CameraTrigger(get_result(r, |r| r.u64())?),
        8 => Call::CameraPoll(get_result(r, |r| match r.u8()? {
            0 => Ok(CaptureStatus::Idle),
            1 => Ok(CaptureStatus::InProgress),
            2 => Ok(CaptureStatus::Ready),
            c => Err(TapeError::BadCode(c)),
        })?),
        9 => Call::CameraFrame(get_result(r, |r| {
            Ok(FrameInfo {
                capture_t_us: r.u64()?,
                sequence: r.u32()?,
                left_len: r.u32()?,
                right_len: r.u32()?,
                images: r.u32()?,
            })
        })?),
        10 => Call::CameraRelease(get_result(r, unit)?),
        11 => Call::TelemetrySend(get_result(r, unit)?),
        12 => Call::PowerRead(get_result(r, |r| {
            Ok(PowerReading {
                t_us: r.u64()?,
                energy_used_j: r.f64()?,
                bus_power_w: r.f64()?,
                valid: r.bool()?,
            })
        })?),
        t => return Err(TapeError::UnknownTag(t)),
    })
}

fn put_calibration(w: &mut Writer<'_>, c: &StereoCalibration) -> Result<(), TapeError> {
    w.f64s(&[c.fx_px, c.fy_px, c.cx_px, c.cy_px, c.baseline_m])?;
    for row in &c.rot_rover_from_camera {
        w.f64s(row)?;
    }
    w.f64s(&c.pos_camera_in_rover_m)
}

fn put_lens(w: &mut Writer<'_>, lens: Option<&LensCalibration>) -> Result<(), TapeError> {
    w.u8(u8::from(lens.is_some()))?;
    let zero = RawCamera {
        fx_px: 0.0,
        fy_px: 0.0,
        cx_px: 0.0,
        cy_px: 0.0,
        k1: 0.0,
        k2: 0.0,
        k3: 0.0,
        p1: 0.0,
        p2: 0.0,
        rot_raw_from_rect: [[0.0; 3]; 3],
    };
    let (left, right) = lens.map_or((zero, zero), |l| (l.left, l.right));
    for c in [left, right] {
        w.f64s(&[
            c.fx_px, c.fy_px, c.cx_px, c.cy_px, c.k1, c.k2, c.k3, c.p1, c.p2,
        ])?;
        for row in &c.rot_raw_from_rect {
            w.f64s(row)?;
        }
    }
    Ok(())
}

fn get_lens(r: &mut Reader<'_>) -> Result<Option<LensCalibration>, TapeError> {
    let present = r.u8()?;
    let mut camera = || -> Result<RawCamera, TapeError> {
        let [fx_px, fy_px, cx_px, cy_px, k1, k2, k3, p1, p2] = r.f64s::<9>()?;
        Ok(RawCamera {
            fx_px,
            fy_px,
            cx_px,
            cy_px,
            k1,
            k2,
            k3,
            p1,
            p2,
            rot_raw_from_rect: [r.f64s::<3>()?, r.f64s::<3>()?, r.f64s::<3>()?],
        })
    };
    let left = camera()?;
    let right = camera()?;
    match present {
        0 => Ok(None),
        1 => Ok(Some(LensCalibration { left, right })),
        _ => Err(TapeError::BadHeader),
    }
}

fn get_calibration(r: &mut Reader<'_>) -> Result<StereoCalibration, TapeError> {
    let [fx_px, fy_px, cx_px, cy_px, baseline_m] = r.f64s::<5>()?;
    let rot_rover_from_camera = [r.f64s::<3>()?, r.f64s::<3>()?, r.f64s::<3>()?];
    Ok(StereoCalibration {
        fx_px,
        fy_px,
        cx_px,
        cy_px,
        baseline_m,
        rot_rover_from_camera,
        pos_camera_in_rover_m: r.f64s()?,
    })
}

/// Little-endian writer into a byte slice.
struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    fn bytes(&mut self, b: &[u8]) -> Result<(), TapeError> {
        let end = self
            .pos
            .checked_add(b.len())
            .ok_or(TapeError::BufferTooSmall)?;
        self.buf
            .get_mut(self.pos..end)
            .ok_or(TapeError::BufferTooSmall)?
            .copy_from_slice(b);
        self.pos = end;
        Ok(())
    }
    fn u8(&mut self, v: u8) -> Result<(), TapeError> {
        self.bytes(&[v])
    }
    fn bool(&mut self, v: bool) -> Result<(), TapeError> {
        self.u8(u8::from(v))
    }
    fn u32(&mut self, v: u32) -> Result<(), TapeError> {
        self.bytes(&v.to_le_bytes())
    }
    fn u64(&mut self, v: u64) -> Result<(), TapeError> {
        self.bytes(&v.to_le_bytes())
    }
    fn f64(&mut self, v: f64) -> Result<(), TapeError> {
        self.u64(v.to_bits())
    }
    fn f64s(&mut self, v: &[f64]) -> Result<(), TapeError> {
        v.iter().try_for_each(|x| self.f64(*x))
    }
}

/// Little-endian reader over a byte slice.
struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], TapeError> {
        let end = self.pos.checked_add(n).ok_or(TapeError::Truncated)?;
        let out = self.buf.get(self.pos..end).ok_or(TapeError::Truncated)?;
        self.pos = end;
        Ok(out)
    }
    fn array<const K: usize>(&mut self) -> Result<[u8; K], TapeError> {
        <[u8; K]>::try_from(self.take(K)?).map_err(|_| TapeError::Truncated)
    }
    fn u8(&mut self) -> Result<u8, TapeError> {
        Ok(self.array::<1>()?[0])
    }
    fn bool(&mut self) -> Result<bool, TapeError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            c => Err(TapeError::BadCode(c)),
        }
    }
    fn u32(&mut self) -> Result<u32, TapeError> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    fn u64(&mut self) -> Result<u64, TapeError> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    fn f64(&mut self) -> Result<f64, TapeError> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn f64s<const K: usize>(&mut self) -> Result<[f64; K], TapeError> {
        let mut out = [0.0; K];
        for v in out.iter_mut() {
            *v = self.f64()?;
        }
        Ok(out)
    }
}

/// A sequential source of tape bytes (a file on the host, semihosting on the target, a slice).
pub trait ByteSource {
    /// Fill `buf` with the next bytes; [`TapeError::Truncated`] at the end of the tape.
    fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), TapeError>;
    /// Skip `n` bytes.
    fn skip(&mut self, n: u64) -> Result<(), TapeError>;
}

/// A random-access source of image pixels (the tape again, through its own handle).
pub trait PayloadSource {
    /// Fill `buf` with the bytes at `offset` of the tape.
    fn read_at(&mut self, offset: u64, buf: &mut [u8]) -> Result<(), TapeError>;
}

/// A tape held in memory.
#[derive(Debug, Clone, Copy)]
pub struct SliceSource<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> SliceSource<'a> {
    /// A source reading `data` from its start.
    pub fn new(data: &'a [u8]) -> Self {
        Self { data, pos: 0 }
    }
}

impl ByteSource for SliceSource<'_> {
    fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), TapeError> {
        let end = self
            .pos
            .checked_add(buf.len())
            .ok_or(TapeError::Truncated)?;
        buf.copy_from_slice(self.data.get(self.pos..end).ok_or(TapeError::Truncated)?);
        self.pos = end;
        Ok(())
    }
    fn skip(&mut self, n: u64) -> Result<(), TapeError> {
        let n = usize::try_from(n).map_err(|_| TapeError::Truncated)?;
        let end = self.pos.checked_add(n).ok_or(TapeError::Truncated)?;
        if end > self.data.len() {
            return Err(TapeError::Truncated);
        }
        self.pos = end;
        Ok(())
    }
}

impl PayloadSource for SliceSource<'_> {
    fn read_at(&mut self, offset: u64, buf: &mut [u8]) -> Result<(), TapeError> {
        let start = usize::try_from(offset).map_err(|_| TapeError::Truncated)?;
        let end = start.checked_add(buf.len()).ok_or(TapeError::Truncated)?;
        buf.copy_from_slice(self.data.get(start..end).ok_or(TapeError::Truncated)?);
        Ok(())
    }
}

/// Where [`TapeReader::load_frame`] stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameMark {
    /// A frame's records are queued; the recording run's tick and digest of that frame.
    Frame {
        /// Tick of the frame.
        tick: u64,
        /// Digest recorded for the frame.
        digest: u64,
    },
    /// The tape ended.
    End,
}

/// Streaming reader of a tape: the header, then one frame's records at a time.
#[derive(Debug)]
pub struct TapeReader<S: ByteSource> {
    source: S,
    pos: u64,
    header: TapeHeader,
}

impl<S: ByteSource> TapeReader<S> {
    /// Read the header of the tape in `source`.
    pub fn open(mut source: S) -> Result<Self, TapeError> {
        let mut bytes = [0u8; HEADER_BYTES];
        source.read_exact(&mut bytes)?;
        let header = TapeHeader::decode(&bytes)?;
        Ok(Self {
            source,
            pos: HEADER_BYTES as u64,
            header,
        })
    }

    /// The tape's header.
    pub fn header(&self) -> &TapeHeader {
        &self.header
    }

    /// The next record. For [`Record::Images`] the pixels are skipped and their offset is
    /// filled in.
    pub fn next_record(&mut self) -> Result<Record, TapeError> {
        let mut head = [0u8; 2];
        self.source.read_exact(&mut head)?;
        let [tag, len] = head;
        let mut body = [0u8; 255];
        let body = body
            .get_mut(..usize::from(len))
            .ok_or(TapeError::Truncated)?;
        self.source.read_exact(body)?;
        self.pos = self.pos.saturating_add(2 + u64::from(len));
        let mut record = decode_record(tag, body)?;
        if let Record::Images(images) = &mut record {
            images.offset = self.pos;
            let pixels = u64::from(images.left_len) + u64::from(images.right_len);
            self.source.skip(pixels)?;
            self.pos = self.pos.saturating_add(pixels);
        }
        Ok(record)
    }

    /// Queue the next frame's records in `player` (after [`crate::Player::begin_frame`]) up to
    /// and including its [`Record::FrameEnd`].
    pub fn load_frame(&mut self, player: &mut crate::Player) -> Result<FrameMark, TapeError> {
        for _ in 0..=crate::player::MAX_RECORDS_PER_FRAME {
            match self.next_record()? {
                Record::FrameEnd { tick, digest } => return Ok(FrameMark::Frame { tick, digest }),
                Record::End => return Ok(FrameMark::End),
                record => player.push(record)?,
            }
        }
        Err(TapeError::FrameTooLong)
    }
}
