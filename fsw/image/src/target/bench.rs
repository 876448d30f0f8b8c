//! The navigation tasks measured on the inputs of a recorded call tape.
//!
//! The flight software calls these modules from its tasks (`fsw::flight::nav`); this runs each
//! of them on its own, on the tape's real inputs, and measures each call: every valid IMU sample is propagated by the EKF; every joint reading (RG2, 20 Hz) goes
//! through forward kinematics, kinematic odometry, the Mahalanobis gate and the relative-pose
//! update over the last RG2 interval (between two clones), guidance on the EKF pose and inverse
//! kinematics of its command; every stereo pair goes through one full visual-odometry update
//! (`VisualOdometry::<150>::start`, then `step` one work item at a time, each item measured by kind;
//! images in `.extram`) and, when it gives a pose,
//! the gate and update between the two capture clones. When the tape's camera delivers raw
//! images (a lens calibration in the header), each pair is first rectified
//! (`fsw::rectify`, `rectify_pair`, one row item at a time) into the buffers VO reads. Updates are applied ungated so that
//! every update is measured whole.

use super::devices::ImageBuffer;
use super::loc_bench::LocBench;
use super::measure::{Meter, Stats};
use super::report;
use super::semihost::HostFile;
use fsw::estimation::{CloneHandle, CoreCov, Ekf, EkfConfig, NominalState};
use fsw::guidance::{Guidance, GuidanceConfig, Path, Pose2, SlipVector};
use fsw::kinematics::{
    forward_kinematics_from_joints, inverse_kinematics, inverse_kinematics_contact,
    wheel_contact_points, ContactAngles, KinematicOdometry, OdometryConfig, SuspensionRates,
    SuspensionState, VehicleCommand, ROCKY8,
};
use fsw::perception::{CameraPose, HazardMapper, MapProgress};
use fsw::planning::{ConvexPolygon, Planner, Wedge};
use fsw::rectify::{ImageMemory, MapNode, Rectifier, RectifyConfig, RectifyProgress};
use fsw::types::{Quat, Vec3};
use fsw::vo::{Progress, VisualOdometry, WorkKind};
use rover_hal::{ImuSample, JointState, StereoFrame};
use rover_replay::tape::{PayloadSource, TapeReader, MAX_WAYPOINTS};
use rover_replay::{Call, FrameInfo, ImagesRef, Record, TapeError, TapeHeader};

/// Largest number of work items of one VO update (far above the pipeline's bound).
const MAX_VO_ITEMS: usize = 8192;

/// Feature capacity of the visual odometry.
pub const VO_FEATURES: usize = 150;

/// Names of the measured tasks, in report order.
const TASKS: [&str; 16] = [
    "ekf_propagate",
    "ekf_gate_relative_pose",
    "ekf_update_relative_pose",
    "ekf_clone",
    "forward_kinematics",
    "kinematic_odometry",
    "inverse_kinematics",
    "guidance_step",
    "vo_update",
    "hazard_map",
    "roverbug_plan",
    "rectify_pair",
    "ekf_gate_fuse_without_vo",
    "localization_map",
    "localize",
    "sequencer_replan",
];
const PROPAGATE: usize = 0;
const GATE: usize = 1;
const UPDATE: usize = 2;
const CLONE: usize = 3;
const FK: usize = 4;
const ODOMETRY: usize = 5;
const IK: usize = 6;
const GUIDANCE: usize = 7;
const VO: usize = 8;
const HAZARD_MAP: usize = 9;
const PLAN: usize = 10;
const RECTIFY: usize = 11;
const FUSE_WITHOUT_VO: usize = 12;

/// Largest number of work items of one hazard map (far above the mapper's bound).
const MAX_MAP_ITEMS: usize = 4096;

/// Visual-odometry outcomes over the tape.
#[derive(Clone, Copy, Default)]
struct VoSummary {
    updates: u32,
    poses: u32,
    failures: u32,
    inliers_min: u16,
    inliers_max: u16,
    features_max: u16,
    work_items_max: u32,
}

// The statics below live in `.extram` (not loaded, not zeroed): each is set to its type's
// compile-time placeholder (`EMPTY`, copied from flash) and then built in place by its `init`,
// so that no constructor passes the state through the stack.

/// The EKF's static (its symbol names it in the memory map), built in place.
fn ekf_static(start: NominalState, p0: &CoreCov) -> Option<&'static mut Ekf> {
    let ekf = super::take_static!(extram, Ekf, Ekf::EMPTY)?;
    ekf.init(EkfConfig::default(), start, p0).ok()?;
    Some(ekf)
}

/// The visual odometry's static, built in place.
fn vo_static(
    config: fsw::vo::VoConfig,
    calibration: &rover_hal::StereoCalibration,
) -> Option<&'static mut VisualOdometry<VO_FEATURES>> {
    let vo = super::take_static!(extram, VisualOdometry<VO_FEATURES>, VisualOdometry::EMPTY)?;
    vo.init(config, calibration).ok()?;
    Some(vo)
}

/// The hazard mapper's static, built in place.
fn install_mapper(
    config: fsw::perception::PerceptionConfig,
    calibration: &rover_hal::StereoCalibration,
) -> Option<&'static mut HazardMapper> {
    let m = super::take_static!(extram, HazardMapper, HazardMapper::EMPTY)?;
    m.init(config, calibration).ok()?;
    Some(m)
}

/// The RoverBug planner's static with its goal, built in place.
fn install_planner(
    config: fsw::planning::PlannerConfig,
    goal: [f64; 2],
) -> Option<&'static mut Planner> {
    let p = super::take_static!(extram, Planner, Planner::EMPTY)?;
    p.init(config).ok()?;
    p.set_goal(goal).ok()?;
    Some(p)
}

/// The stereo frame `f` names, borrowed from the loaded image buffers (`None` when a length
/// exceeds a buffer).
fn frame_of<'a>(
    images: &'a [&'static mut ImageBuffer; 2],
    f: &FrameInfo,
) -> Option<StereoFrame<'a>> {
    let [left, right] = images;
    Some(StereoFrame {
        left: left.get(..f.left_len as usize)?,
        right: right.get(..f.right_len as usize)?,
        capture_t_us: f.capture_t_us,
        sequence: f.sequence,
    })
}

fn bench_static(bench: Bench) -> Option<&'static mut Bench> {
    super::take_static!(Bench, bench)
}

/// The navigation state and the measurements.
pub struct Bench {
    ekf: &'static mut Ekf,
    vo: &'static mut VisualOdometry<VO_FEATURES>,
    mapper: &'static mut HazardMapper,
    planner: &'static mut Planner,
    loc: LocBench,
    calibration: rover_hal::StereoCalibration,
    guidance: Guidance<MAX_WAYPOINTS>,
    /// The pair VO and the mapper read (rectified from `raw` when the tape's camera has a lens
    /// calibration, loaded directly otherwise).
    images: [&'static mut ImageBuffer; 2],
    /// The tape's raw pair and the rectification (map in external RAM) when the camera has a
    /// lens calibration.
    rectify: Option<BenchRectify>,
    loaded: Option<u32>,
    kin: KinematicOdometry,
    /// Gyro rotation since the last joint reading (rad, `R`, the samples' rates times their
    /// intervals), passed to the odometry as the navigator passes its integrated rotation.
    gyro_since_joints: [f64; 3],
    last_imu_us: Option<u64>,
    vo_prior: KinematicOdometry,
    last_vo_capture_us: Option<u64>,
    start: NominalState,
    started: bool,
    prev_joints: Option<JointState>,
    kin_clone: Option<CloneHandle>,
    /// Kinematic intervals tested: every other one runs the fusion without VO instead of the
    /// gate and the update.
    kin_intervals: u32,
    capture: Option<CloneHandle>,
    prev_capture: Option<CloneHandle>,
    stats: [Stats; TASKS.len()],
    /// Instructions per VO work item, by kind (`fsw::vo::WorkKind`).
    vo_items: [Stats; WorkKind::COUNT],
    vo_summary: VoSummary,
    /// Instructions per rectification row item.
    rectify_row: Stats,
}

/// The bench's rectification: state, map and the tape's raw pair.
struct BenchRectify {
    rectifier: Rectifier,
    map: &'static mut [MapNode],
    raw: [&'static mut ImageBuffer; 2],
}

impl Bench {
    /// Build the navigation state for the tape's scenario in static memory; `None` when a
    /// module refuses its setup (or on a second call).
    #[inline(never)]
    pub fn install(
        header: &TapeHeader,
        images: [&'static mut ImageBuffer; 2],
        raw: [&'static mut ImageBuffer; 2],
        map: &'static mut [MapNode],
    ) -> Option<&'static mut Self> {
        let [n, e, d, roll, pitch, yaw] = header.start_pose;
        let mut start = NominalState::at_rest(0);
        start.p_n = Vec3::new(n, e, d);
        start.q_nr = Quat::from_euler_angles(roll, pitch, yaw);
        let p0 = CoreCov::identity() * 1e-4;
        let ekf = ekf_static(start, &p0)?;
        // The flight software's VO tuning (8 px tracking window with the EKF prior).
        let vo_config = fsw::flight::nav::NavConfig::rocky8([0.0; 3], 0.0)
            .vo
            .pipeline;
        let vo = vo_static(vo_config, &header.calibration)?;
        // The flight software's hazard-navigation settings (obstacle growth margin, clearance).
        let nav = fsw::flight::nav::NavConfig::rocky8([0.0; 3], 0.0);
        let mapper = install_mapper(nav.goal.perception, &header.calibration)?;
        let goal = header.waypoints().last().copied()?;
        let planner = install_planner(nav.goal.planner, goal)?;
        let loc = LocBench::install()?;
        let contacts = wheel_contact_points(&ROCKY8, &SuspensionState::default()).ok()?;
        let wheel_xy = contacts.map(|c| [c.x, c.y]);
        let path = Path::new(header.waypoints()).ok()?;
        let guidance = Guidance::new(path, GuidanceConfig::rocky8(wheel_xy)).ok()?;
        let mut images = images;
        let rectify = match header.lens {
            None => None,
            Some(lens) => {
                let [out_left, out_right] = &mut images;
                let mut memory = ImageMemory {
                    map,
                    left: &mut out_left[..],
                    right: &mut out_right[..],
                };
                let mut rectifier = Rectifier::new(RectifyConfig::default());
                rectifier
                    .build(&lens, &header.calibration, &mut memory)
                    .ok()?;
                Some(BenchRectify {
                    rectifier,
                    map: memory.map,
                    raw,
                })
            }
        };
        let bench = Self {
            ekf,
            vo,
            mapper,
            planner,
            loc,
            calibration: header.calibration,
            guidance,
            images,
            rectify,
            loaded: None,
            // The flight profile's odometry (with the contact-angle estimator the rough-terrain
            // inverse kinematics reads).
            // (`NavConfig::rocky8`'s odometry: `contact_translation` on.)
            kin: KinematicOdometry::new(
                ROCKY8,
                OdometryConfig {
                    contact_translation: true,
                    ..OdometryConfig::default()
                },
            ),
            vo_prior: KinematicOdometry::new(ROCKY8, OdometryConfig::default()),
            last_vo_capture_us: None,
            gyro_since_joints: [0.0; 3],
            last_imu_us: None,
            start,
            started: false,
            prev_joints: None,
            kin_clone: None,
            kin_intervals: 0,
            capture: None,
            prev_capture: None,
            stats: [Stats::new(); TASKS.len()],
            vo_items: [Stats::new(); WorkKind::COUNT],
            vo_summary: VoSummary {
                inliers_min: u16::MAX,
                ..VoSummary::default()
            },
            rectify_row: Stats::new(),
        };
        bench_static(bench)
    }

    /// Go through the tape's records and measure the tasks on them.
    pub fn run(
        &mut self,
        meter: &mut Meter,
        reader: &mut TapeReader<HostFile>,
        mut payload: HostFile,
    ) -> Result<(), TapeError> {
        let records = (u64::from(reader.header().frames) + 1)
            * (rover_replay::player::MAX_RECORDS_PER_FRAME as u64 + 1);
        for _ in 0..records {
            match reader.next_record()? {
                Record::End => {
                    self.localization(meter);
                    return Ok(());
                }
                Record::Call(Call::ImuRead(Ok(s))) => self.imu(meter, &s),
                Record::Call(Call::JointsRead(Ok(j))) => self.joints(meter, &j),
                Record::Call(Call::CameraTrigger(Ok(t))) => self.trigger(meter, t),
                Record::Images(i) => self.load(&mut payload, &i)?,
                Record::Call(Call::CameraFrame(Ok(f))) => self.visual_odometry(meter, &f),
                _ => {}
            }
        }
        Err(TapeError::FrameTooLong)
    }

    /// The terrain-map localization on its synthetic field ([`LocBench`]).
    fn localization(&mut self, meter: &mut Meter) {
        let [.., map, loc, seq] = &mut self.stats;
        self.loc.run(meter, map, loc);
        self.loc.sequencer(meter, seq);
    }

    /// The task statistics, by name.
    pub fn tasks(&self) -> impl Iterator<Item = (&'static str, &Stats)> + '_ {
        TASKS.iter().copied().zip(self.stats.iter())
    }

    /// Instructions per VO work item, by kind name.
    pub fn vo_items(&self) -> impl Iterator<Item = (&'static str, &Stats)> + '_ {
        WorkKind::ALL
            .iter()
            .map(|k| k.name())
            .zip(self.vo_items.iter())
    }

    /// Print the visual-odometry outcomes.
    pub fn report_vo(&self) {
        let v = &self.vo_summary;
        report(format_args!(
            "timing vo features {} updates {} poses {} failures {} inliers_min {} inliers_max {} features_max {} work_items_max {}\n",
            VO_FEATURES,
            v.updates,
            v.poses,
            v.failures,
            if v.poses == 0 { 0 } else { v.inliers_min },
            v.inliers_max,
            v.features_max,
            v.work_items_max
        ));
    }

    fn add(&mut self, task: usize, insns: u64, ok: bool) {
        if let Some(s) = self.stats.get_mut(task) {
            s.add(insns, ok);
        }
    }

    fn imu(&mut self, meter: &mut Meter, s: &ImuSample) {
        if !s.valid {
            return;
        }
        if !self.started {
            let mut x0 = self.start;
            x0.t_us = s.t_us;
            let p0 = CoreCov::identity() * 1e-4;
            self.started = self.ekf.reset(x0, &p0).is_ok();
            return;
        }
        let ekf = &mut *self.ekf;
        let (r, n) = meter.measure(|| ekf.propagate(s));
        self.add(PROPAGATE, n, r.is_ok());
        if let Some(t0) = self.last_imu_us.filter(|t0| s.t_us > *t0) {
            let dt = (s.t_us - t0) as f64 * 1e-6;
            for (g, w) in self.gyro_since_joints.iter_mut().zip(s.gyro_rad_s) {
                *g += w * dt;
            }
        }
        self.last_imu_us = Some(s.t_us);
    }

    fn joints(&mut self, meter: &mut Meter, j: &JointState) {
        if !self.started {
            return;
        }
        // Forward kinematics with suspension rates from the last two readings.
        if let Some(p) = self.prev_joints {
            let dt = j.t_us.saturating_sub(p.t_us) as f64 * 1e-6;
            if dt > 0.0 {
                let rates = SuspensionRates {
                    rocker_rad_s: (j.rocker_rad - p.rocker_rad) / dt,
                    bogie_rad_s: [
                        (j.bogie_rad[0] - p.bogie_rad[0]) / dt,
                        (j.bogie_rad[1] - p.bogie_rad[1]) / dt,
                    ],
                };
                let (r, n) = meter.measure(|| forward_kinematics_from_joints(&ROCKY8, j, &rates));
                self.add(FK, n, r.is_ok());
            }
        }
        self.prev_joints = Some(*j);

        // Kinematic odometry over the RG2 interval, then gate and update between two clones.
        let kin = &mut self.kin;
        // As flown: with the gyro's rotation over the step (the contact-angle step's 3-vector
        // path, `NavConfig::rocky8`).
        let [gx, gy, gz] = core::mem::take(&mut self.gyro_since_joints);
        let gyro = Some(fsw::types::Vec3::new(gx, gy, gz));
        let (r, n) = meter.measure(|| kin.update_with_gyro(j, gyro));
        if r.is_err() {
            let _ = self.kin.start(j);
        } else {
            self.add(ODOMETRY, n, true);
        }
        if self.vo_prior.update(j).is_err() {
            let _ = self.vo_prior.start(j);
        }
        if let Some(c0) = self.kin_clone.take() {
            if let Ok(m) = self.kin.take() {
                self.kin_intervals = self.kin_intervals.wrapping_add(1);
                if m.t0_us == c0.t_us() && self.kin_intervals % 2 == 0 {
                    // The navigator without VO: the gate keeps the innovation, then the
                    // interval is fused with z observed and slip allowances added
                    // (`Navigator::fuse_without_vo`, `NavConfig::rocky8` fractions).
                    let ekf = &mut *self.ekf;
                    let step = m.trans_0_1_m.norm();
                    let extra = [0.0, 0.0, 1.0e-8, 0.09 * step * step, 0.09 * step * step, {
                        let s = 0.2 * step + 5.0e-4;
                        s * s
                    }];
                    let mut observed = m.observed;
                    observed[5] = true;
                    let (r, n) = meter.measure(|| {
                        ekf.gate_relative_pose_kept(&m)
                            .and_then(|(_, k)| ekf.fuse_kept_relative_pose(&k, observed, extra))
                    });
                    self.add(FUSE_WITHOUT_VO, n, r.is_ok());
                } else if m.t0_us == c0.t_us() {
                    let ekf = &*self.ekf;
                    let (r, n) = meter.measure(|| ekf.gate_relative_pose(&m));
                    self.add(GATE, n, r.is_ok());
                    let ekf = &mut *self.ekf;
                    let (r, n) = meter.measure(|| ekf.update_relative_pose(&m, false));
                    self.add(UPDATE, n, r.is_ok());
                }
            }
            let _ = self.ekf.release(c0);
        }
        let ekf = &mut *self.ekf;
        let (r, n) = meter.measure(|| ekf.clone_at(j.t_us));
        self.add(CLONE, n, r.is_ok());
        self.kin_clone = r.ok();

        // Guidance on the EKF pose, inverse kinematics of its command.
        let x = self.ekf.state();
        let pose = Pose2 {
            x_m: x.p_n.x,
            y_m: x.p_n.y,
            phi_rad: x.q_nr.euler_angles().2,
        };
        let guidance = &mut self.guidance;
        let (r, n) = meter.measure(|| guidance.step(pose, SlipVector::default()));
        self.add(GUIDANCE, n, r.is_ok());
        let cmd = match r {
            Ok(c) => VehicleCommand {
                x_dot_m_s: c.x_dot_m_s,
                y_dot_m_s: c.y_dot_m_s,
                yaw_rate_rad_s: c.phi_dot_rad_s,
            },
            Err(_) => VehicleCommand {
                x_dot_m_s: 0.05,
                ..VehicleCommand::default()
            },
        };
        // The rough-terrain inverse kinematics on the odometry's contact angles (their sines
        // and cosines included) as the navigator runs it (`NavConfig::ik_contact_angles`), but
        // without its 0.1 rad deadband: the worst case, every cycle a rough-terrain solve
        // (eq. 16-25 only when every angle is exactly 0).
        let state = SuspensionState::from_joints(j);
        let angles = self.kin.contact_angles_rad();
        // `NavConfig::rocky8`'s `ik_contact_max_angle_rad`.
        let max_angle = 1.0;
        let (r, n) = meter.measure(|| {
            let contact = ContactAngles::new(&angles, max_angle);
            if contact == ContactAngles::LEVEL {
                inverse_kinematics(&ROCKY8, &state, &cmd)
            } else {
                inverse_kinematics_contact(&ROCKY8, &state, &cmd, &contact)
            }
        });
        self.add(IK, n, r.is_ok());
    }

    fn trigger(&mut self, meter: &mut Meter, t_us: u64) {
        if !self.started {
            return;
        }
        if let Some(stale) = self.capture.take() {
            let _ = self.ekf.release(stale);
        }
        let ekf = &mut *self.ekf;
        let (r, n) = meter.measure(|| ekf.clone_at(t_us));
        self.add(CLONE, n, r.is_ok());
        self.capture = r.ok();
    }

    fn load(&mut self, payload: &mut HostFile, i: &ImagesRef) -> Result<(), TapeError> {
        let [left, right] = match &mut self.rectify {
            Some(r) => &mut r.raw,
            None => &mut self.images,
        };
        let l = left
            .get_mut(..i.left_len as usize)
            .ok_or(TapeError::BufferTooSmall)?;
        payload.read_at(i.offset, l)?;
        let r = right
            .get_mut(..i.right_len as usize)
            .ok_or(TapeError::BufferTooSmall)?;
        payload.read_at(i.offset + u64::from(i.left_len), r)?;
        self.loaded = Some(i.id);
        Ok(())
    }

    fn visual_odometry(&mut self, meter: &mut Meter, f: &FrameInfo) {
        // The flight software reads a frame many times while its VO works on it: one update
        // per capture.
        if self.loaded != Some(f.images) || self.last_vo_capture_us == Some(f.capture_t_us) {
            return;
        }
        self.last_vo_capture_us = Some(f.capture_t_us);
        if self.rectify.is_some() && !self.rectify_pair(meter, f) {
            return;
        }
        let Some(frame) = frame_of(&self.images, f) else {
            return;
        };
        let prior = self.vo_prior.take().ok();
        // Item by item (one work item per `step`), so that each item is measured and
        // attributed to its kind; the update's cost is the sum.
        let vo = &mut *self.vo;
        let (started, mut n) = meter.measure(|| vo.start(&frame, prior.as_ref()));
        // An update that never finishes within MAX_VO_ITEMS items counts as an error.
        let mut r = Err(fsw::vo::VoError::NonFinite);
        match started {
            Err(e) => r = Err(e),
            Ok(()) => {
                for _ in 0..MAX_VO_ITEMS {
                    let vo = &mut *self.vo;
                    let kind = vo.next_work();
                    let (p, k) = meter.measure(|| vo.step(&frame, 1));
                    n += k;
                    if let Some(s) = kind.and_then(|kind| self.vo_items.get_mut(kind as usize)) {
                        s.add(k, true);
                    }
                    if let Progress::Finished(out) = p {
                        r = out;
                        break;
                    }
                }
            }
        }
        self.add(VO, n, r.is_ok());
        let v = &mut self.vo_summary;
        v.updates += 1;
        match &r {
            Ok(out) => {
                v.features_max = v.features_max.max(out.quality.features);
                v.work_items_max = v.work_items_max.max(out.quality.work_items);
                if out.pose.is_some() {
                    v.poses += 1;
                    v.inliers_min = v.inliers_min.min(out.quality.inliers);
                    v.inliers_max = v.inliers_max.max(out.quality.inliers);
                }
            }
            Err(_) => v.failures += 1,
        }
        // The VO pose between the previous and this capture, applied between their clones.
        let pose = r.ok().and_then(|o| o.pose);
        let capture = self.capture.take();
        if let Some(c) = capture {
            self.hazard_map_and_plan(meter, f, c);
        }
        if let (Some(m), Some(c0), Some(c1)) = (pose, self.prev_capture, capture) {
            if m.t0_us == c0.t_us() && m.t1_us == c1.t_us() {
                let ekf = &*self.ekf;
                let (r, n) = meter.measure(|| ekf.gate_relative_pose(&m));
                self.add(GATE, n, r.is_ok());
                let ekf = &mut *self.ekf;
                let (r, n) = meter.measure(|| ekf.update_relative_pose(&m, false));
                self.add(UPDATE, n, r.is_ok());
            }
        }
        if let Some(old) = self.prev_capture.take() {
            let _ = self.ekf.release(old);
        }
        self.prev_capture = capture;
    }

    /// Rectifies the raw pair of `f` into the VO images (`fsw::rectify`, one row item per
    /// `step`, the sum measured as `rectify_pair`). False when the pair could not be rectified
    /// (VO then skips it, as the flight software does).
    fn rectify_pair(&mut self, meter: &mut Meter, f: &FrameInfo) -> bool {
        let Some(r) = self.rectify.as_mut() else {
            return false;
        };
        let Some(raw) = frame_of(&r.raw, f) else {
            return false;
        };
        let [out_left, out_right] = &mut self.images;
        let mut memory = ImageMemory {
            map: &mut *r.map,
            left: &mut out_left[..],
            right: &mut out_right[..],
        };
        let rectifier = &mut r.rectifier;
        let (started, mut n) = meter.measure(|| rectifier.start(&raw));
        let mut ok = false;
        if started.is_ok() {
            for _ in 0..=Rectifier::ITEMS_PER_PAIR {
                let (p, k) = meter.measure(|| rectifier.step(&raw, &mut memory, 1));
                n += k;
                self.rectify_row.add(k, true);
                if let RectifyProgress::Finished(result) = p {
                    ok = result.is_ok();
                    break;
                }
            }
        }
        if let Some(s) = self.stats.get_mut(RECTIFY) {
            s.add(n, ok);
        }
        ok
    }

    /// Instructions per rectification row item.
    pub fn rectify_rows(&self) -> &Stats {
        &self.rectify_row
    }

    /// A hazard map of `frame` at the EKF pose of its capture clone (work item by work item,
    /// the sum is the map's cost) and the RoverBug step on it.
    fn hazard_map_and_plan(&mut self, meter: &mut Meter, f: &FrameInfo, capture: CloneHandle) {
        let Self {
            ekf,
            mapper,
            planner,
            calibration,
            images,
            stats,
            ..
        } = self;
        let Some(frame) = frame_of(images, f) else {
            return;
        };
        let frame = &frame;
        let mut add = |task: usize, insns: u64, ok: bool| {
            if let Some(s) = stats.get_mut(task) {
                s.add(insns, ok);
            }
        };
        let Ok((q, p)) = ekf.clone_pose(capture) else {
            return;
        };
        let rot = q.to_rotation_matrix().into_inner();
        let Ok(camera) = CameraPose::from_rover(&rot, &p, calibration) else {
            return;
        };
        let (started, mut n) = meter.measure(|| mapper.start(frame, &camera));
        let mut ok = started.is_ok();
        if ok {
            ok = false;
            for _ in 0..MAX_MAP_ITEMS {
                let (progress, k) = meter.measure(|| mapper.step(frame, 1));
                n += k;
                if let MapProgress::Finished(r) = progress {
                    ok = r.is_ok();
                    break;
                }
            }
        }
        add(HAZARD_MAP, n, ok);
        let Some(map) = mapper.map() else {
            return;
        };
        let w = map.wedge;
        let wedge = Wedge {
            apex: w.apex_m,
            heading_rad: w.heading_rad,
            half_angle_rad: w.half_angle_rad,
            min_range_m: w.min_range_m,
            max_range_m: w.max_range_m,
        };
        let (_, _, yaw) = q.euler_angles();
        // As the navigator flies it (`hazard_nav`): the polygons built one at a time as the
        // planner takes them, inside the measurement (a whole map's, 16 x 440 B, is not on the
        // stack).
        let mut polygons = map
            .obstacles
            .iter()
            .filter_map(|o| ConvexPolygon::from_points(&o.vertices).ok());
        let (r, n) =
            meter.measure(|| planner.plan_each([p.x, p.y], yaw, &wedge, polygons.by_ref()));
        add(PLAN, n, r.is_ok());
    }
}
