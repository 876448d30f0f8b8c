//! `sim-host record`: run a scenario segment with every HAL device wrapped in a recording
//! decorator and write the call tape (format: `rover_replay::tape`).
//!
//! Each decorator appends the result of every call to the tape in call order: clock `now_us`,
//! IMU, joints, sun, power, mobility command and stop results, camera trigger, poll, frame and release,
//! telemetry send results. When a camera poll reports a capture ready, the decorator borrows the
//! pair (`StereoCamera::frame` is a query) and appends the pixels after the poll's record, once
//! per capture. `Clock::counter` is not recorded (timing telemetry only). After every frame the
//! recorder writes the frame's digest ([`fsw_image::flight_replay::frame_digest`]), so a replay
//! on any CPU can check itself frame by frame.

use crate::closed_loop::{run_with, RunHooks, RunOptions, WorldPlatform};
use crate::devices::renderer::{StereoRenderer, TexturedRenderer};
use crate::devices::world::{
    CounterMode, WorldClock, WorldImu, WorldMobility, WorldPower, WorldStereo, WorldSun,
};
use crate::devices::{hazcam_calibration, CountingTelemetry};
use crate::scenario::Scenario;
use crate::world::FRAME_US;
use fsw::flight::{Devices, Fsw, Platform};
use fsw_image::flight_replay::frame_digest;
use rover_hal::{
    CaptureStatus, Clock, Error, ErrorKind, Imu, ImuSample, JointState, Mobility, MobilityCommand,
    Power, PowerReading, StereoCalibration, StereoCamera, StereoFrame, SunReading, SunSensor,
    Telemetry,
};
use rover_replay::tape::{
    encode_record, HEADER_BYTES, MAX_RECORD_BYTES, MAX_WAYPOINTS, NAME_BYTES,
};
use rover_replay::TapeHeader;
use rover_replay::{Call, Digest, FrameInfo, FrameOutputs, ImagesRef, MobilityOutput, Record};
use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;

/// The tape being written, shared by the recording devices.
#[derive(Debug, Default)]
pub struct Recorder {
    records: Vec<u8>,
    outputs: FrameOutputs,
    images: u32,
    /// `(capture time, sequence, pixel digest)` of the pair last written.
    last_images: Option<(u64, u32, u64)>,
    tick: u64,
    digests: Vec<u64>,
    error: Option<String>,
}

impl Recorder {
    fn push(&mut self, record: Record) {
        let mut buf = [0u8; MAX_RECORD_BYTES];
        match encode_record(&record, &mut buf) {
            Ok(n) => self.records.extend_from_slice(&buf[..n]),
            Err(e) => self.fail(format!("cannot encode {record:?}: {e:?}")),
        }
    }

    fn call(&mut self, call: Call) {
        self.push(Record::Call(call));
    }

    fn fail(&mut self, message: String) {
        self.error.get_or_insert(message);
    }

    /// Append the pair `frame` unless it is the one last written; returns its id.
    fn images(&mut self, frame: &StereoFrame<'_>) -> u32 {
        let pixels = Digest::new().bytes(frame.left).bytes(frame.right).value();
        let key = (frame.capture_t_us, frame.sequence, pixels);
        if self.last_images != Some(key) {
            self.images += 1;
            self.last_images = Some(key);
            let (Ok(left_len), Ok(right_len)) = (
                u32::try_from(frame.left.len()),
                u32::try_from(frame.right.len()),
            ) else {
                self.fail("image too large".into());
                return self.images;
            };
            self.push(Record::Images(ImagesRef {
                id: self.images,
                left_len,
                right_len,
                offset: 0,
            }));
            self.records.extend_from_slice(frame.left);
            self.records.extend_from_slice(frame.right);
        }
        self.images
    }

    /// The id of the pair last written if `frame` is that pair.
    fn images_of(&self, frame: &StereoFrame<'_>) -> Option<u32> {
        let pixels = Digest::new().bytes(frame.left).bytes(frame.right).value();
        (self.last_images == Some((frame.capture_t_us, frame.sequence, pixels)))
            .then_some(self.images)
    }

    fn end_frame<P: Platform>(&mut self, fsw: &Fsw<P>) {
        let digest = frame_digest(self.tick, fsw.state(), Some(fsw.nav()), &self.outputs);
        self.push(Record::FrameEnd {
            tick: self.tick,
            digest,
        });
        self.digests.push(digest);
        self.outputs.clear();
        self.tick += 1;
    }
}

type Shared = Rc<RefCell<Recorder>>;

/// A device wrapped in a recording decorator.
pub struct Rec<D> {
    inner: D,
    rec: Shared,
}

impl<D> Rec<D> {
    fn new(inner: D, rec: &Shared) -> Self {
        Self {
            inner,
            rec: rec.clone(),
        }
    }
}

fn kind<T, E: Error>(r: Result<T, E>) -> Result<T, ErrorKind> {
    r.map_err(|e| e.kind())
}

impl<D: Clock> Clock for Rec<D> {
    type Error = ErrorKind;
    fn now_us(&mut self) -> Result<u64, ErrorKind> {
        let r = kind(self.inner.now_us());
        self.rec.borrow_mut().call(Call::ClockNow(r));
        r
    }
    fn counter(&mut self) -> Result<u64, ErrorKind> {
        kind(self.inner.counter())
    }
    fn counter_hz(&self) -> u64 {
        self.inner.counter_hz()
    }
}

impl<D: Imu> Imu for Rec<D> {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<ImuSample, ErrorKind> {
        let r = kind(self.inner.read());
        self.rec.borrow_mut().call(Call::ImuRead(r));
        r
    }
}

impl<D: Mobility> Mobility for Rec<D> {
    type Error = ErrorKind;
    fn read_joints(&mut self) -> Result<JointState, ErrorKind> {
        let r = kind(self.inner.read_joints());
        self.rec.borrow_mut().call(Call::JointsRead(r));
        r
    }
    fn command(&mut self, command: &MobilityCommand) -> Result<(), ErrorKind> {
        let r = kind(self.inner.command(command));
        let mut rec = self.rec.borrow_mut();
        rec.outputs.push_mobility(MobilityOutput::Command(*command));
        rec.call(Call::MobilityCommand(r));
        r
    }
    fn stop(&mut self) -> Result<(), ErrorKind> {
        let r = kind(self.inner.stop());
        let mut rec = self.rec.borrow_mut();
        rec.outputs.push_mobility(MobilityOutput::Stop);
        rec.call(Call::MobilityStop(r));
        r
    }
}

impl<D: SunSensor> SunSensor for Rec<D> {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<SunReading, ErrorKind> {
        let r = kind(self.inner.read());
        self.rec.borrow_mut().call(Call::SunRead(r));
        r
    }
}

impl<D: Power> Power for Rec<D> {
    type Error = ErrorKind;
    fn read(&mut self) -> Result<PowerReading, ErrorKind> {
        let r = kind(self.inner.read());
        self.rec.borrow_mut().call(Call::PowerRead(r));
        r
    }
}

impl<D: Telemetry> Telemetry for Rec<D> {
    type Error = ErrorKind;
    fn send(&mut self, record: &[u8]) -> Result<(), ErrorKind> {
        let r = kind(self.inner.send(record));
        let mut rec = self.rec.borrow_mut();
        rec.outputs.push_telemetry(record);
        rec.call(Call::TelemetrySend(r));
        r
    }
}

impl<D: StereoCamera> StereoCamera for Rec<D> {
    type Error = ErrorKind;
    fn calibration(&self) -> StereoCalibration {
        self.inner.calibration()
    }
    fn lens_calibration(&self) -> Option<rover_hal::LensCalibration> {
        self.inner.lens_calibration()
    }
    fn trigger(&mut self) -> Result<u64, ErrorKind> {
        let r = kind(self.inner.trigger());
        self.rec.borrow_mut().call(Call::CameraTrigger(r));
        r
    }
    fn poll(&mut self) -> Result<CaptureStatus, ErrorKind> {
        let r = kind(self.inner.poll());
        let mut rec = self.rec.borrow_mut();
        rec.call(Call::CameraPoll(r));
        if r == Ok(CaptureStatus::Ready) {
            if let Ok(frame) = self.inner.frame() {
                rec.images(&frame);
            }
        }
        r
    }
    fn frame(&self) -> Result<StereoFrame<'_>, ErrorKind> {
        let r = kind(self.inner.frame());
        let mut rec = self.rec.borrow_mut();
        let info = match &r {
            Ok(frame) => {
                let Some(images) = rec.images_of(frame) else {
                    rec.fail(
                        "the camera returned a pair that no ready poll announced: \
                         the tape cannot replay it"
                            .into(),
                    );
                    return r;
                };
                Ok(FrameInfo {
                    capture_t_us: frame.capture_t_us,
                    sequence: frame.sequence,
                    left_len: frame.left.len() as u32,
                    right_len: frame.right.len() as u32,
                    images,
                })
            }
            Err(e) => Err(*e),
        };
        rec.call(Call::CameraFrame(info));
        r
    }
    fn release(&mut self) -> Result<(), ErrorKind> {
        let r = kind(self.inner.release());
        self.rec.borrow_mut().call(Call::CameraRelease(r));
        r
    }
}

/// The simulated devices, each wrapped in a recording decorator.
pub struct RecordingPlatform;

impl Platform for RecordingPlatform {
    type Clock = Rec<WorldClock>;
    type Imu = Rec<WorldImu>;
    type Mobility = Rec<WorldMobility>;
    type Camera = Rec<WorldStereo>;
    type Sun = Rec<WorldSun>;
    type Power = Rec<WorldPower>;
    type Telemetry = Rec<CountingTelemetry>;
    type ImageMemory = crate::devices::HostImageMemory;
}

struct Hooks {
    rec: Shared,
}

impl RunHooks for Hooks {
    type Platform = RecordingPlatform;
    fn wrap(&mut self, d: Devices<WorldPlatform>) -> Devices<RecordingPlatform> {
        let rec = &self.rec;
        Devices {
            clock: Rec::new(d.clock, rec),
            imu: Rec::new(d.imu, rec),
            mobility: Rec::new(d.mobility, rec),
            camera: Rec::new(d.camera, rec),
            sun: Rec::new(d.sun, rec),
            power: Rec::new(d.power, rec),
            telemetry: Rec::new(d.telemetry, rec),
            image_memory: d.image_memory,
        }
    }
    fn after_tick(&mut self, fsw: &Fsw<RecordingPlatform>) {
        self.rec.borrow_mut().end_frame(fsw);
    }
}

/// A recorded tape.
#[derive(Debug, Clone)]
pub struct Recording {
    /// The tape: header, records, end.
    pub tape: Vec<u8>,
    /// The recording run's digest of every frame.
    pub digests: Vec<u64>,
    /// Stereo pairs in the tape.
    pub image_pairs: u32,
}

/// Options of a recording.
#[derive(Debug, Clone, Copy)]
pub struct RecordOptions {
    /// Simulated seconds to record (the scenario's duration when longer).
    pub seconds: f64,
    /// Seed (default: the scenario's).
    pub seed: Option<u64>,
    /// Render the stereo images with the textured renderer (else uniform grey).
    pub render: bool,
}

/// Record `seconds` of `scenario` with rendered stereo images.
pub fn record(scenario: &Scenario, options: RecordOptions) -> anyhow::Result<Recording> {
    let mut scenario = scenario.clone();
    scenario.duration_s = scenario.duration_s.min(options.seconds);
    let seed = options.seed.unwrap_or(scenario.seed);
    let renderer: Option<Box<dyn StereoRenderer>> = options.render.then(|| {
        let sun = scenario.site.sun_w(0.0);
        Box::new(TexturedRenderer::new(
            hazcam_calibration(),
            seed,
            [sun.x, sun.y, sun.z],
        )) as Box<dyn StereoRenderer>
    });
    let rec: Shared = Rc::new(RefCell::new(Recorder::default()));
    let mut hooks = Hooks { rec: rec.clone() };
    run_with(
        &scenario,
        RunOptions {
            seed: Some(seed),
            counter: CounterMode::SimTime,
            renderer,
            ..RunOptions::default()
        },
        &mut hooks,
    )?;
    drop(hooks);
    let mut recorder = Rc::try_unwrap(rec)
        .map_err(|_| anyhow::anyhow!("recorder still shared"))?
        .into_inner();
    if let Some(e) = recorder.error.take() {
        anyhow::bail!("recording failed: {e}");
    }
    recorder.push(Record::End);
    let header = header(&scenario, seed, recorder.tick)?;
    let mut tape = vec![0u8; HEADER_BYTES];
    header
        .encode(&mut tape)
        .map_err(|e| anyhow::anyhow!("tape header: {e:?}"))?;
    tape.extend_from_slice(&recorder.records);
    Ok(Recording {
        tape,
        digests: recorder.digests,
        image_pairs: recorder.images,
    })
}

fn header(scenario: &Scenario, seed: u64, frames: u64) -> anyhow::Result<TapeHeader> {
    if scenario.waypoints.len() > MAX_WAYPOINTS {
        anyhow::bail!("a tape holds at most {MAX_WAYPOINTS} waypoints");
    }
    let config =
        crate::closed_loop::flight_config(scenario, crate::closed_loop::DriveOptions::default());
    let nav = &config.nav;
    let mut waypoints = [[0.0; 2]; MAX_WAYPOINTS];
    for (dst, src) in waypoints.iter_mut().zip(&scenario.waypoints) {
        *dst = *src;
    }
    let mut name = [0u8; NAME_BYTES];
    let bytes = scenario.name.as_bytes();
    let n = bytes.len().min(NAME_BYTES);
    name[..n].copy_from_slice(&bytes[..n]);
    Ok(TapeHeader {
        version: rover_replay::tape::VERSION,
        frame_period_us: FRAME_US as u32,
        frames: u32::try_from(frames)?,
        seed,
        calibration: hazcam_calibration(),
        // The camera reports the nominal lenses unless the scenario has ideal ones.
        lens: (!scenario.sensors.ideal_lens).then(crate::sensors::hazcam_lens::nominal_lens),
        // The planned start (the flight configuration's), not the truth.
        start_pose: [
            nav.align.initial_position_n_m[0],
            nav.align.initial_position_n_m[1],
            nav.align.initial_position_n_m[2],
            0.0,
            0.0,
            nav.align.initial_yaw_rad,
        ],
        nav_params: fsw_image::flight_replay::nav_params(&config),
        waypoints,
        waypoint_count: scenario.waypoints.len() as u8,
        scenario: name,
    })
}

/// `sim-host record SCENARIO --out TAPE [OPTIONS]`.
#[derive(Debug, Clone, clap::Args)]
pub struct RecordArgs {
    /// Scenario file (TOML).
    pub scenario: PathBuf,
    /// Simulated seconds to record.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Seed (default: the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Tape file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Uniform grey images instead of rendered ones.
    #[arg(long)]
    pub no_render: bool,
}

/// Run `sim-host record`: write the tape and print what it holds.
pub fn main(args: RecordArgs) -> anyhow::Result<()> {
    let scenario = Scenario::load(&args.scenario)?;
    let start = std::time::Instant::now();
    let recording = record(
        &scenario,
        RecordOptions {
            seconds: args.seconds,
            seed: args.seed,
            render: !args.no_render,
        },
    )?;
    let out = args.out;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&out, &recording.tape)?;
    println!(
        "sim-host record {}: {} frames, {} stereo pairs, {} bytes in {} ({:.1} s)",
        scenario.name,
        recording.digests.len(),
        recording.image_pairs,
        recording.tape.len(),
        out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
