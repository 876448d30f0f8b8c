//! Host tests: tape round trips, malformed tapes, divergence detection, image loading.

use crate::devices::{
    ReplayClock, ReplayImu, ReplayMobility, ReplayPower, ReplayStereo, ReplaySun, ReplayTelemetry,
    ZeroCounter,
};
use crate::player::{Divergence, MobilityOutput, Player};
use crate::tape::{
    decode_record, encode_record, FrameMark, SliceSource, TapeReader, HEADER_BYTES,
    MAX_RECORD_BYTES, MAX_WAYPOINTS, NAME_BYTES,
};
use crate::{Call, CallKind, Digest, FrameInfo, ImagesRef, Record, TapeError, TapeHeader};
use rover_hal::{
    CaptureStatus, Clock, ErrorKind, Imu, ImuSample, JointState, Mobility, MobilityCommand, Power,
    PowerReading, StereoCalibration, StereoCamera, SunReading, SunSensor, Telemetry,
};
use std::cell::RefCell;
use std::rc::Rc;
use std::vec;
use std::vec::Vec;

fn calibration() -> StereoCalibration {
    StereoCalibration {
        fx_px: 384.5,
        fy_px: 384.25,
        cx_px: 319.5,
        cy_px: 239.5,
        baseline_m: 0.084,
        rot_rover_from_camera: [[0.0, -0.5, 0.5], [1.0, 0.0, 0.0], [0.0, 0.5, 0.5]],
        pos_camera_in_rover_m: [0.2, 0.0, -0.6],
    }
}

fn header() -> TapeHeader {
    let mut scenario = [0u8; NAME_BYTES];
    scenario[..5].copy_from_slice(b"slope");
    let mut waypoints = [[0.0; 2]; MAX_WAYPOINTS];
    waypoints[1] = [4.5, -0.0];
    TapeHeader {
        version: crate::tape::VERSION,
        frame_period_us: 5000,
        frames: 2,
        seed: 7,
        calibration: calibration(),
        lens: None,
        start_pose: [0.1, -0.2, 0.3, 0.01, -0.02, f64::MIN_POSITIVE],
        nav_params: [1.5e-4; crate::tape::NAV_PARAMS],
        waypoints,
        waypoint_count: 2,
        scenario,
    }
}

fn every_call() -> Vec<Call> {
    let joints = JointState {
        t_us: 42,
        drive_angle_rad: [1.0, -2.0, 3.5, f64::NAN, 0.0, -0.0],
        drive_rate_rad_s: [0.25; 6],
        steer_angle_rad: [-0.5; 6],
        rocker_rad: 0.125,
        bogie_rad: [0.5, -0.75],
        wheel_valid: [true, false, true, true, false, true],
        suspension_valid: true,
    };
    vec![
        Call::ClockNow(Ok(u64::MAX)),
        Call::ClockNow(Err(ErrorKind::Timeout)),
        Call::ImuRead(Ok(ImuSample {
            t_us: 5000,
            gyro_rad_s: [1e-3, -2e-3, f64::INFINITY],
            accel_m_s2: [0.0, 0.0, -3.711],
            valid: true,
        })),
        Call::ImuRead(Err(ErrorKind::NotReady)),
        Call::JointsRead(Ok(joints)),
        Call::JointsRead(Err(ErrorKind::Hardware)),
        Call::MobilityCommand(Ok(())),
        Call::MobilityCommand(Err(ErrorKind::InvalidRequest)),
        Call::MobilityStop(Ok(())),
        Call::SunRead(Ok(SunReading {
            t_us: 9,
            sun_dir_rover: [0.8, 0.0, -0.6],
            sun_in_view: false,
        })),
        Call::SunRead(Err(ErrorKind::InvalidData)),
        Call::CameraTrigger(Ok(123)),
        Call::CameraTrigger(Err(ErrorKind::Busy)),
        Call::CameraPoll(Ok(CaptureStatus::Idle)),
        Call::CameraPoll(Ok(CaptureStatus::InProgress)),
        Call::CameraPoll(Ok(CaptureStatus::Ready)),
        Call::CameraFrame(Ok(FrameInfo {
            capture_t_us: 123,
            sequence: 4,
            left_len: 8,
            right_len: 8,
            images: 1,
        })),
        Call::CameraFrame(Err(ErrorKind::NotReady)),
        Call::CameraRelease(Ok(())),
        Call::TelemetrySend(Err(ErrorKind::Other)),
        Call::PowerRead(Ok(PowerReading {
            t_us: 15_000,
            energy_used_j: 1234.5,
            bus_power_w: f64::NAN,
            valid: false,
        })),
        Call::PowerRead(Err(ErrorKind::Hardware)),
    ]
}

/// Compare records by their encodings (NaN != NaN under `PartialEq`).
fn same(a: &Record, b: &Record) -> bool {
    let (mut x, mut y) = ([0u8; MAX_RECORD_BYTES], [0u8; MAX_RECORD_BYTES]);
    match (encode_record(a, &mut x), encode_record(b, &mut y)) {
        (Ok(n), Ok(m)) => x[..n] == y[..m],
        _ => false,
    }
}

#[test]
fn every_record_round_trips() {
    let mut records: Vec<Record> = every_call().into_iter().map(Record::Call).collect();
    records.push(Record::Images(ImagesRef {
        id: 3,
        left_len: 10,
        right_len: 11,
        offset: 0,
    }));
    records.push(Record::FrameEnd {
        tick: 17,
        digest: 0xdead_beef_0123_4567,
    });
    records.push(Record::End);
    for record in &records {
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let n = encode_record(record, &mut buf).expect("encode");
        assert_eq!(usize::from(buf[1]) + 2, n);
        let back = decode_record(buf[0], &buf[2..n]).expect("decode");
        assert!(same(record, &back), "{record:?} came back as {back:?}");
    }
}

#[test]
fn header_round_trips_and_checks() {
    let h = header();
    let mut buf = [0u8; HEADER_BYTES];
    assert_eq!(h.encode(&mut buf), Ok(HEADER_BYTES));
    let back = TapeHeader::decode(&buf).expect("decode");
    assert_eq!(back, h);
    assert_eq!(back.scenario_name(), "slope");
    assert_eq!(back.waypoints().len(), 2);
    assert!(back.waypoints[1][1].is_sign_negative());
    let mut bad = buf;
    bad[0] = b'X';
    assert_eq!(TapeHeader::decode(&bad), Err(TapeError::BadMagic));
    assert_eq!(
        TapeHeader::decode(&buf[..HEADER_BYTES - 1]),
        Err(TapeError::Truncated)
    );
    // Version 3 (before the power reads) still loads, and says so; other versions do not.
    let mut v3 = buf;
    v3[7] = b'3';
    let old = TapeHeader::decode(&v3).expect("version 3");
    assert_eq!((old.version, old.has_power()), (b'3', false));
    assert_eq!(
        TapeHeader {
            version: b'4',
            ..old
        },
        h
    );
    assert!(h.has_power());
    for v in [b'2', b'5', b'0'] {
        let mut other = buf;
        other[7] = v;
        assert_eq!(TapeHeader::decode(&other), Err(TapeError::BadMagic));
    }
    // Encoding writes the current version whatever the header says.
    let mut again = [0u8; HEADER_BYTES];
    assert_eq!(old.encode(&mut again), Ok(HEADER_BYTES));
    assert_eq!(again, buf);
    let mut too_many = h;
    too_many.waypoint_count = MAX_WAYPOINTS as u8 + 1;
    assert_eq!(too_many.encode(&mut buf), Err(TapeError::BadHeader));
    assert_eq!(h.encode(&mut [0u8; 10]), Err(TapeError::BufferTooSmall));
}

#[test]
fn malformed_records_are_errors_not_panics() {
    assert_eq!(decode_record(0xEE, &[]), Err(TapeError::UnknownTag(0xEE)));
    // Imu read, status Ok but no body.
    assert_eq!(decode_record(2, &[0]), Err(TapeError::Truncated));
    // Bad error code.
    assert_eq!(decode_record(2, &[9]), Err(TapeError::BadCode(9)));
    // Trailing bytes.
    assert_eq!(decode_record(4, &[0, 0]), Err(TapeError::BadLength(4)));
    // Bad capture status and bad bool.
    assert_eq!(decode_record(8, &[0, 3]), Err(TapeError::BadCode(3)));
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = encode_record(&Record::Call(every_call()[9]), &mut buf).expect("encode");
    buf[n - 1] = 2;
    assert_eq!(
        decode_record(buf[0], &buf[2..n]),
        Err(TapeError::BadCode(2))
    );
    // Every prefix of a valid record decodes to an error, never a panic.
    let n = encode_record(&Record::Call(every_call()[4]), &mut buf).expect("encode");
    for k in 0..n - 2 {
        assert!(decode_record(buf[0], &buf[2..2 + k]).is_err());
    }
    // A reader over random bytes fails cleanly.
    let mut x = 0x1234_5678_u32;
    let mut noise = vec![0u8; 4096];
    for b in noise.iter_mut() {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        *b = x as u8;
    }
    let mut tape = tape_bytes(&[], &[]);
    tape.truncate(HEADER_BYTES);
    tape.extend_from_slice(&noise);
    let mut reader = TapeReader::open(SliceSource::new(&tape)).expect("header");
    let mut player = Player::new();
    for _ in 0..100 {
        player.begin_frame();
        if reader.load_frame(&mut player).is_err() {
            return;
        }
    }
}

/// A tape with `frames` of records; `pixels` is appended after each Images record.
fn tape_bytes(frames: &[Vec<Record>], pixels: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; HEADER_BYTES];
    header().encode(&mut out).expect("header");
    for (tick, frame) in frames.iter().enumerate() {
        for r in frame {
            let mut buf = [0u8; MAX_RECORD_BYTES];
            let n = encode_record(r, &mut buf).expect("encode");
            out.extend_from_slice(&buf[..n]);
            if let Record::Images(i) = r {
                let len = (i.left_len + i.right_len) as usize;
                out.extend_from_slice(&pixels[..len]);
            }
        }
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let end = Record::FrameEnd {
            tick: tick as u64,
            digest: 100 + tick as u64,
        };
        let n = encode_record(&end, &mut buf).expect("encode");
        out.extend_from_slice(&buf[..n]);
    }
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = encode_record(&Record::End, &mut buf).expect("encode");
    out.extend_from_slice(&buf[..n]);
    out
}

type Shared = Rc<RefCell<Player>>;

#[test]
fn replay_devices_return_the_tape_in_order() {
    let sample = ImuSample {
        t_us: 5000,
        gyro_rad_s: [0.1, 0.2, 0.3],
        accel_m_s2: [0.0, 0.0, -3.711],
        valid: true,
    };
    let power = PowerReading {
        t_us: 10_000,
        energy_used_j: 512.25,
        bus_power_w: 98.5,
        valid: true,
    };
    let pixels: Vec<u8> = (0..16u8).collect();
    let frame = FrameInfo {
        capture_t_us: 5000,
        sequence: 1,
        left_len: 8,
        right_len: 8,
        images: 1,
    };
    let frames = vec![
        vec![
            Record::Call(Call::ClockNow(Ok(5000))),
            Record::Call(Call::ImuRead(Ok(sample))),
            Record::Call(Call::CameraTrigger(Ok(5000))),
            Record::Call(Call::CameraPoll(Ok(CaptureStatus::Ready))),
            Record::Images(ImagesRef {
                id: 1,
                left_len: 8,
                right_len: 8,
                offset: 0,
            }),
            Record::Call(Call::CameraFrame(Ok(frame))),
            Record::Call(Call::CameraRelease(Ok(()))),
        ],
        vec![
            Record::Call(Call::MobilityCommand(Err(ErrorKind::InvalidRequest))),
            Record::Call(Call::MobilityStop(Ok(()))),
            Record::Call(Call::TelemetrySend(Ok(()))),
            Record::Call(Call::SunRead(Err(ErrorKind::Timeout))),
            Record::Call(Call::PowerRead(Ok(power))),
        ],
    ];
    let bytes = tape_bytes(&frames, &pixels);
    let mut reader = TapeReader::open(SliceSource::new(&bytes)).expect("open");
    assert_eq!(reader.header(), &header());
    let tape: Shared = Rc::new(RefCell::new(Player::new()));
    let mut clock = ReplayClock::new(tape.clone(), ZeroCounter);
    let mut imu = ReplayImu::new(tape.clone());
    let mut mobility = ReplayMobility::new(tape.clone());
    let mut sun = ReplaySun::new(tape.clone());
    let mut power_device = ReplayPower::new(tape.clone(), reader.header().has_power());
    let mut telemetry = ReplayTelemetry::new(tape.clone());
    let slots = [[vec![0u8; 8], vec![0u8; 8]], [vec![0u8; 8], vec![0u8; 8]]];
    let mut camera =
        ReplayStereo::new(tape.clone(), SliceSource::new(&bytes), slots, calibration());

    tape.borrow_mut().begin_frame();
    let mark = reader.load_frame(&mut tape.borrow_mut()).expect("frame 0");
    assert_eq!(
        mark,
        FrameMark::Frame {
            tick: 0,
            digest: 100
        }
    );
    assert_eq!(clock.now_us(), Ok(5000));
    assert_eq!(clock.counter(), Ok(0));
    assert_eq!(imu.read(), Ok(sample));
    assert_eq!(camera.trigger(), Ok(5000));
    assert_eq!(camera.poll(), Ok(CaptureStatus::Ready));
    assert_eq!(camera.loaded(), Some(1));
    {
        let f = camera.frame().expect("frame");
        assert_eq!(f.left, &pixels[..8]);
        assert_eq!(f.right, &pixels[8..16]);
        assert_eq!((f.capture_t_us, f.sequence), (5000, 1));
    }
    assert_eq!(camera.release(), Ok(()));
    assert_eq!(camera.calibration(), calibration());
    assert_eq!(tape.borrow_mut().end_frame(), Ok(()));

    tape.borrow_mut().begin_frame();
    let mark = reader.load_frame(&mut tape.borrow_mut()).expect("frame 1");
    assert_eq!(
        mark,
        FrameMark::Frame {
            tick: 1,
            digest: 101
        }
    );
    let cmd = MobilityCommand {
        steer_angle_rad: [0.1; 6],
        wheel_rate_rad_s: [f64::NAN; 6],
    };
    assert_eq!(mobility.command(&cmd), Err(ErrorKind::InvalidRequest));
    assert_eq!(mobility.stop(), Ok(()));
    assert_eq!(telemetry.send(&[1, 2, 3]), Ok(()));
    assert_eq!(sun.read(), Err(ErrorKind::Timeout));
    assert_eq!(power_device.read(), Ok(power));
    {
        let p = tape.borrow();
        let out = p.outputs();
        assert_eq!(out.mobility().len(), 2);
        assert!(
            matches!(out.mobility()[0], MobilityOutput::Command(c) if c.steer_angle_rad == [0.1; 6])
        );
        assert_eq!(out.mobility()[1], MobilityOutput::Stop);
        assert_eq!(out.telemetry().collect::<Vec<_>>(), vec![&[1u8, 2, 3][..]]);
    }
    assert_eq!(tape.borrow_mut().end_frame(), Ok(()));
    tape.borrow_mut().begin_frame();
    assert_eq!(
        reader.load_frame(&mut tape.borrow_mut()),
        Ok(FrameMark::End)
    );
    assert_eq!(tape.borrow().divergence(), None);
    assert_eq!(tape.borrow().calls(), 11);
}

/// A version-3 tape has no power reads: its replay power device answers `NotReady` without
/// consuming a record, so the other devices replay in order; on a version-4 tape the same
/// call is a divergence when the tape has no power read next.
#[test]
fn version_3_tapes_replay_without_power_reads() {
    let frames = vec![vec![
        Record::Call(Call::SunRead(Err(ErrorKind::NotReady))),
        Record::Call(Call::TelemetrySend(Ok(()))),
    ]];
    let mut bytes = tape_bytes(&frames, &[]);
    bytes[7] = b'3';
    let tape: Shared = Rc::new(RefCell::new(Player::new()));
    let mut reader = TapeReader::open(SliceSource::new(&bytes)).expect("open");
    assert!(!reader.header().has_power());
    reader.load_frame(&mut tape.borrow_mut()).expect("frame");
    let mut sun = ReplaySun::new(tape.clone());
    let mut power = ReplayPower::new(tape.clone(), reader.header().has_power());
    let mut telemetry = ReplayTelemetry::new(tape.clone());
    assert_eq!(sun.read(), Err(ErrorKind::NotReady));
    assert_eq!(power.read(), Err(ErrorKind::NotReady));
    assert_eq!(telemetry.send(&[7]), Ok(()));
    assert_eq!(tape.borrow_mut().end_frame(), Ok(()));
    assert_eq!(tape.borrow().divergence(), None);

    let bytes = tape_bytes(&frames, &[]);
    let tape: Shared = Rc::new(RefCell::new(Player::new()));
    let mut reader = TapeReader::open(SliceSource::new(&bytes)).expect("open");
    assert!(reader.header().has_power());
    reader.load_frame(&mut tape.borrow_mut()).expect("frame");
    let mut sun = ReplaySun::new(tape.clone());
    let mut power = ReplayPower::new(tape.clone(), reader.header().has_power());
    assert_eq!(sun.read(), Err(ErrorKind::NotReady));
    assert_eq!(power.read(), Err(ErrorKind::Other));
    assert_eq!(
        tape.borrow().divergence(),
        Some(Divergence::UnexpectedCall {
            call: 1,
            expected: Some(CallKind::TelemetrySend),
            got: CallKind::PowerRead,
        })
    );
}

#[test]
fn divergence_is_detected_and_latched() {
    let frames = vec![vec![
        Record::Call(Call::ImuRead(Err(ErrorKind::NotReady))),
        Record::Call(Call::SunRead(Err(ErrorKind::NotReady))),
    ]];
    let bytes = tape_bytes(&frames, &[]);

    // A call the tape does not have next.
    let tape: Shared = Rc::new(RefCell::new(Player::new()));
    let mut reader = TapeReader::open(SliceSource::new(&bytes)).expect("open");
    reader.load_frame(&mut tape.borrow_mut()).expect("frame");
    let mut imu = ReplayImu::new(tape.clone());
    let mut sun = ReplaySun::new(tape.clone());
    let mut mobility = ReplayMobility::new(tape.clone());
    assert_eq!(mobility.read_joints(), Err(ErrorKind::Other));
    let expected = Divergence::UnexpectedCall {
        call: 0,
        expected: Some(CallKind::ImuRead),
        got: CallKind::JointsRead,
    };
    assert_eq!(tape.borrow().divergence(), Some(expected));
    // Latched: even the right call now fails, and the first divergence is kept.
    assert_eq!(imu.read(), Err(ErrorKind::Other));
    assert_eq!(sun.read(), Err(ErrorKind::Other));
    assert_eq!(tape.borrow_mut().end_frame(), Err(expected));

    // Fewer calls than recorded.
    let tape: Shared = Rc::new(RefCell::new(Player::new()));
    let mut reader = TapeReader::open(SliceSource::new(&bytes)).expect("open");
    reader.load_frame(&mut tape.borrow_mut()).expect("frame");
    let mut imu = ReplayImu::new(tape.clone());
    assert_eq!(imu.read(), Err(ErrorKind::NotReady));
    assert_eq!(
        tape.borrow_mut().end_frame(),
        Err(Divergence::UnusedCalls {
            call: 1,
            expected: Some(CallKind::SunRead)
        })
    );

    // More calls than recorded.
    let tape: Shared = Rc::new(RefCell::new(Player::new()));
    let mut reader = TapeReader::open(SliceSource::new(&bytes)).expect("open");
    reader.load_frame(&mut tape.borrow_mut()).expect("frame");
    let mut imu = ReplayImu::new(tape.clone());
    let mut sun = ReplaySun::new(tape.clone());
    assert!(imu.read().is_err() && sun.read().is_err());
    assert_eq!(imu.read(), Err(ErrorKind::Other));
    assert!(matches!(
        tape.borrow().divergence(),
        Some(Divergence::UnexpectedCall {
            expected: None,
            got: CallKind::ImuRead,
            ..
        })
    ));

    // A frame naming images the camera never loaded.
    let frames = vec![vec![Record::Call(Call::CameraFrame(Ok(FrameInfo {
        capture_t_us: 1,
        sequence: 1,
        left_len: 4,
        right_len: 4,
        images: 9,
    })))]];
    let bytes = tape_bytes(&frames, &[]);
    let tape: Shared = Rc::new(RefCell::new(Player::new()));
    let mut reader = TapeReader::open(SliceSource::new(&bytes)).expect("open");
    reader.load_frame(&mut tape.borrow_mut()).expect("frame");
    let slots = [[vec![0u8; 4], vec![0u8; 4]], [vec![0u8; 4], vec![0u8; 4]]];
    let camera = ReplayStereo::new(tape.clone(), SliceSource::new(&bytes), slots, calibration());
    assert!(camera.frame().is_err());
    assert_eq!(
        tape.borrow().divergence(),
        Some(Divergence::Images { wanted: 9 })
    );
}

#[test]
fn frame_capacity_is_enforced() {
    let frame: Vec<Record> = (0..=crate::player::MAX_RECORDS_PER_FRAME)
        .map(|_| Record::Call(Call::ClockNow(Ok(1))))
        .collect();
    let bytes = tape_bytes(&[frame], &[]);
    let mut reader = TapeReader::open(SliceSource::new(&bytes)).expect("open");
    let mut player = Player::new();
    assert_eq!(reader.load_frame(&mut player), Err(TapeError::FrameTooLong));
}

#[test]
fn outputs_overflow_is_counted() {
    let mut out = crate::FrameOutputs::new();
    for _ in 0..crate::player::MAX_MOBILITY_OUTPUTS + 2 {
        out.push_mobility(MobilityOutput::Stop);
    }
    out.push_telemetry(&[0u8; crate::player::MAX_TELEMETRY_BYTES]);
    out.push_telemetry(&[1]);
    assert_eq!(out.mobility().len(), crate::player::MAX_MOBILITY_OUTPUTS);
    assert_eq!(out.telemetry().count(), 1);
    assert_eq!(out.dropped(), 3);
    out.clear();
    assert_eq!(
        (out.mobility().len(), out.telemetry().count(), out.dropped()),
        (0, 0, 0)
    );
}

#[test]
fn fnv1a_known_values_and_bit_patterns() {
    // FNV-1a 64 reference values.
    assert_eq!(Digest::new().value(), 0xcbf2_9ce4_8422_2325);
    assert_eq!(Digest::new().bytes(b"a").value(), 0xaf63_dc4c_8601_ec8c);
    assert_eq!(
        Digest::new().bytes(b"foobar").value(),
        0x8594_4171_f739_67e8
    );
    // Bit patterns: 0.0 and -0.0 differ.
    assert_ne!(
        Digest::new().f64(0.0).value(),
        Digest::new().f64(-0.0).value()
    );
    assert_eq!(
        Digest::new().f64(1.5).value(),
        Digest::new().u64(1.5f64.to_bits()).value()
    );
}
