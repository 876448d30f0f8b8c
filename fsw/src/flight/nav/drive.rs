//! # Drive: guidance, fault protection, stop-and-go and the motor command (RG2)
//!
//! The drive turns the navigation pose and the slip vector into the motor command: the path
//! follower ([`Guidance`], H04 sec. 5, H05 sec. V: carrot heading, eq. 47-49), speed limiting
//! and inverse kinematics (eq. 16-25, or the rough-terrain inverse kinematics on the
//! odometry's windowed contact angles). It owns fault protection ([`protection`]: slip limit,
//! motor stall, position uncertainty, arrival check, sensor loss), the wait for VO's first
//! keyframe at the start, and the stop-and-go drive without VO (RB sec. 5, H04 sec. 2): stops
//! every [`DriveConfig::blind_stop_interval_m`] of wheel travel so that zero-velocity updates
//! re-anchor the IMU velocity. Why stop-and-go: note 0024.
//!
//! [`super::Navigator::guidance_cycle`] wires it: the sensor and protection checks first
//! ([`Drive::protect`]), then the goal-directed navigation's say, then guidance
//! ([`Drive::follow`]) and the motor command ([`Drive::motor`]).

use super::protection::{FaultResponse, Protection, ProtectionConfig};
use super::RG2_PERIOD_S;
use crate::guidance::{Guidance, GuidanceCommand, GuidanceConfig, Pose2, SlipVector};
use crate::kinematics::inverse::inverse_kinematics_scaled;
use crate::kinematics::{ContactAngles, RoverGeometry, SuspensionState, VehicleCommand};
use rover_hal::{JointState, MobilityCommand, WHEEL_COUNT};

/// Waypoint capacity of the path.
pub const MAX_WAYPOINTS: usize = 32;

/// Fraction of fault protection's position-sigma limit at which a stop of the stop-and-go
/// drive without VO is due whatever the wheel travel.
pub const BLIND_SIGMA_FRACTION: f64 = 0.5;

/// Settings of the drive (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveConfig {
    /// Guidance settings.
    pub guidance: GuidanceConfig,
    /// Fault-protection limits (slip, stall, uncertainty, arrival, sensor loss).
    pub protection: ProtectionConfig,
    /// Slip compensation: guidance on the EKF pose with the slip vector (on) or on the 3D
    /// kinematic dead reckoning without slip vector (off: a rover without slip compensation,
    /// H05 Fig. 9).
    pub slip_compensation: bool,
    /// Stop-and-go without VO: while VO is off or lost, the rover stops after every
    /// `blind_stop_interval_m` of wheel travel for [`Self::blind_stop_cycles`], so that
    /// zero-velocity updates re-anchor the IMU velocity; between stops a kinematic interval the
    /// gate rejects is not fused and the IMU carries the motion (the slip is then measured
    /// against the IMU, eq. 46). 0 disables it (the kinematic intervals are fused with the slip
    /// allowance). m.
    pub blind_stop_interval_m: f64,
    /// RG2 cycles of each stop of the stop-and-go drive without VO.
    pub blind_stop_cycles: u32,
    /// Minor frames without a checked IMU sample after which the rover is held.
    pub imu_timeout_frames: u32,
    /// RG2 cycles without a checked joint reading after which the rover is held.
    pub joints_timeout_cycles: u32,
    /// RG2 cycles the rover waits at the start for VO's first keyframe (VO running) before it
    /// drives without VO.
    pub vo_start_timeout_cycles: u32,
    /// Rough-terrain inverse kinematics: the motor command is computed with the odometry's
    /// windowed contact angles (V99 sec. 6, relative to their mean;
    /// [`crate::kinematics::inverse_kinematics_contact`], Tarokh and McDermott 2005) instead of
    /// contacts below the axles (eq. 16-25); a failing rough-terrain solve falls back to eq.
    /// 16-25 for that cycle. Why: note 0031.
    pub ik_contact_angles: bool,
    /// Contact angles at or beyond this magnitude (rad) are taken as 0 by the rough-terrain
    /// inverse kinematics ([`ContactAngles::new`]).
    pub ik_contact_max_angle_rad: f64,
    /// Contact angles below this magnitude (rad) are taken as 0 by the rough-terrain inverse
    /// kinematics, and turns in place always use eq. 16-25 (on flat ground the estimated
    /// angles are noise). Why: note 0031.
    pub ik_contact_min_angle_rad: f64,
}

/// Counters of the drive (telemetry, [`super::NavCounters`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DriveCounters {
    /// Fault-protection stops.
    pub fault_stops: u32,
    /// Guidance or inverse-kinematics failures (the rover was stopped for that cycle).
    pub command_errors: u32,
    /// Cycles the rover was held stopped because a sensor was lost.
    pub sensor_holds: u32,
    /// Stops of the stop-and-go drive without VO.
    pub blind_stops: u32,
    /// RG2 cycles the rover was held at the start waiting for VO's first keyframe.
    pub vo_start_holds: u32,
    /// Starts that gave up waiting for VO's first keyframe.
    pub vo_start_timeouts: u32,
}

/// What guidance made of one RG2 cycle ([`Drive::follow`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Follow {
    /// No command this cycle (no path, or guidance failed: counted).
    Hold,
    /// Guidance reached the end of its path, `distance_m` (m) from its goal by the estimate.
    Reached {
        /// Estimated distance to the goal, m.
        distance_m: f64,
    },
    /// Drive with this body command (rover frame, m/s and rad/s).
    Drive(VehicleCommand),
}

/// The drive component.
pub struct Drive {
    config: DriveConfig,
    guidance: Option<Guidance<MAX_WAYPOINTS>>,
    /// The rover command of the last RG2 cycle (rover frame, m/s and rad/s).
    command: VehicleCommand,
    last_guidance: Option<GuidanceCommand>,
    protection: Protection,
    /// Why fault protection stopped the drive.
    fault_response: FaultResponse,
    /// Wheel rates of the last motor command, rad/s (stall check).
    last_wheel_rates: [f64; WHEEL_COUNT],
    /// Stop-and-go without VO: wheel travel since the last stop, m, and RG2 cycles left in the
    /// current stop.
    blind_travel_m: f64,
    blind_hold_left: u32,
    /// RG2 cycles the rover waited for VO's first keyframe.
    cycles_waiting_vo: u32,
    counters: DriveCounters,
}

impl Drive {
    /// Placeholder (the compile-time value of a static navigator before its initialisation).
    pub const EMPTY: Self = Self {
        config: DriveConfig {
            guidance: GuidanceConfig {
                carrot_radius_m: 0.0,
                k1: 0.0,
                k2: 0.0,
                k3: 0.0,
                sample_period_s: 0.0,
                cruise_speed_m_s: 0.0,
                max_wheel_speed_m_s: 0.0,
                max_yaw_rate_rad_s: 0.0,
                max_crab_speed_m_s: 0.0,
                goal_tolerance_m: 0.0,
                approach_gain_per_s: 0.0,
                min_speed_m_s: 0.0,
                wheel_xy_m: [[0.0; 2]; 6],
            },
            protection: ProtectionConfig {
                slip_limit: 0.0,
                slip_window_m: 0.0,
                stall_min_rate_rad_s: 0.0,
                stall_fraction: 0.0,
                stall_cycles: 0,
                max_position_sigma_m: 0.0,
                arrival_tolerance_m: 0.0,
                arrival_sigmas: 0.0,
                sensor_loss_cycles: 0,
            },
            slip_compensation: false,
            blind_stop_interval_m: 0.0,
            blind_stop_cycles: 0,
            imu_timeout_frames: 0,
            joints_timeout_cycles: 0,
            vo_start_timeout_cycles: 0,
            ik_contact_angles: false,
            ik_contact_max_angle_rad: 0.0,
            ik_contact_min_angle_rad: 0.0,
        },
        guidance: None,
        command: VehicleCommand {
            x_dot_m_s: 0.0,
            y_dot_m_s: 0.0,
            yaw_rate_rad_s: 0.0,
        },
        last_guidance: None,
        protection: Protection::EMPTY,
        fault_response: FaultResponse::None,
        last_wheel_rates: [0.0; WHEEL_COUNT],
        blind_travel_m: 0.0,
        blind_hold_left: 0,
        cycles_waiting_vo: 0,
        counters: DriveCounters {
            fault_stops: 0,
            command_errors: 0,
            sensor_holds: 0,
            blind_stops: 0,
            vo_start_holds: 0,
            vo_start_timeouts: 0,
        },
    };

    /// Rewrites the component for a new drive with `config`, following `guidance`'s path.
    pub fn init(&mut self, config: &DriveConfig, guidance: Guidance<MAX_WAYPOINTS>) {
        self.config = *config;
        self.guidance = Some(guidance);
        self.command = VehicleCommand::default();
        self.last_guidance = None;
        self.protection = Protection::default();
        self.fault_response = FaultResponse::None;
        self.last_wheel_rates = [0.0; WHEEL_COUNT];
        self.blind_travel_m = 0.0;
        self.blind_hold_left = 0;
        self.cycles_waiting_vo = 0;
        self.counters = DriveCounters::default();
    }

    /// The settings.
    pub fn config(&self) -> &DriveConfig {
        &self.config
    }

    /// Counters.
    pub fn counters(&self) -> DriveCounters {
        self.counters
    }

    /// The rover command of the last RG2 cycle (rover frame, m/s and rad/s).
    pub fn command(&self) -> VehicleCommand {
        self.command
    }

    /// The last guidance output (carrot, cross-track projection, goal distance).
    pub fn guidance_output(&self) -> Option<&GuidanceCommand> {
        self.last_guidance.as_ref()
    }

    /// The guidance path follower, if a path was given.
    pub fn guidance(&self) -> Option<&Guidance<MAX_WAYPOINTS>> {
        self.guidance.as_ref()
    }

    /// The goal of the path guidance follows (`N`, m).
    pub fn goal(&self) -> Option<[f64; 2]> {
        self.guidance.as_ref().map(|g| g.path().goal())
    }

    /// Why fault protection stopped the drive ([`FaultResponse::None`] before).
    pub fn fault_response(&self) -> FaultResponse {
        self.fault_response
    }

    /// The slip measured over the last complete fault-protection window (1 - EKF travel /
    /// wheel travel), fraction.
    pub fn window_slip(&self) -> f64 {
        self.protection.last_slip
    }

    /// The path guidance follows is replaced (the goal-directed navigation's plans).
    pub fn set_guidance(&mut self, guidance: Guidance<MAX_WAYPOINTS>) {
        self.guidance = Some(guidance);
    }

    /// A fault-protection stop is latched (the navigator decided it applies): counted.
    pub fn latch(&mut self, response: FaultResponse) {
        self.fault_response = response;
        self.counters.fault_stops = self.counters.fault_stops.saturating_add(1);
    }

    /// A command failure the navigator found (counted in [`DriveCounters::command_errors`]).
    pub fn command_error(&mut self) {
        self.counters.command_errors = self.counters.command_errors.saturating_add(1);
    }

    /// One kinematic interval's travel for the slip window of fault protection (`verified`:
    /// VO fused since the last interval, or the IMU anchored by a stop). Returns the slip
    /// response when a window closes over the limit.
    pub fn travel(&mut self, wheel_m: f64, ekf_m: f64, verified: bool) -> Option<FaultResponse> {
        self.protection
            .travel(&self.config.protection, wheel_m, ekf_m, verified)
    }

    /// RG2, first: the command is cleared until a new one is made; returns the wheel rates
    /// commanded in the previous cycle (stall check), rad/s.
    pub fn begin_cycle(&mut self) -> [f64; WHEEL_COUNT] {
        self.command = VehicleCommand::default();
        core::mem::replace(&mut self.last_wheel_rates, [0.0; WHEEL_COUNT])
    }

    /// RG2: the sensor and protection checks before the rover may move, with `imu_gap_frames`
    /// and `joint_gap_cycles` since the last checked readings, the last `joints`, the wheel
    /// rates `commanded` in the previous cycle and the EKF's horizontal 1-sigma `sigma_h` (m).
    /// `Err(Some(r))`: fault protection stops the drive with `r`; `Err(None)`: hold this cycle
    /// (a sensor is lost, counted).
    pub fn protect(
        &mut self,
        imu_gap_frames: u32,
        joint_gap_cycles: u32,
        joints: Option<&JointState>,
        commanded: &[f64; WHEEL_COUNT],
        sigma_h: f64,
    ) -> Result<(), Option<FaultResponse>> {
        let holding = imu_gap_frames >= self.config.imu_timeout_frames
            || joint_gap_cycles >= self.config.joints_timeout_cycles;
        let c = &self.config.protection;
        if let Some(r) = self.protection.sensor_hold(c, holding) {
            return Err(Some(r));
        }
        if holding {
            self.counters.sensor_holds = self.counters.sensor_holds.saturating_add(1);
            return Err(None);
        }
        if let Some(j) = joints {
            if let Some(r) = self.protection.motors(c, commanded, &j.drive_rate_rad_s) {
                return Err(Some(r));
            }
        }
        if sigma_h > c.max_position_sigma_m {
            return Err(Some(FaultResponse::PositionUncertain));
        }
        Ok(())
    }

    /// RG2 at the start, while VO runs and holds no keyframe yet: true while the rover waits
    /// (counted, at most [`DriveConfig::vo_start_timeout_cycles`]); false once the wait is
    /// over (counted as a timeout: the rover drives without VO).
    pub fn wait_for_vo(&mut self) -> bool {
        if self.cycles_waiting_vo < self.config.vo_start_timeout_cycles {
            self.cycles_waiting_vo = self.cycles_waiting_vo.saturating_add(1);
            self.counters.vo_start_holds = self.counters.vo_start_holds.saturating_add(1);
            return true;
        }
        self.counters.vo_start_timeouts = self.counters.vo_start_timeouts.saturating_add(1);
        false
    }

    /// Stop-and-go without VO ([`DriveConfig::blind_stop_interval_m`], or when the position
    /// sigma `sigma_h` (m) reaches [`BLIND_SIGMA_FRACTION`] of fault protection's limit):
    /// counts the wheels' travel (`joints`' rates, nominal `wheel_radius_m`) while VO is off or
    /// lost (`vo_lost`) and returns `true` while the rover must stand (a stop of
    /// [`DriveConfig::blind_stop_cycles`] after each interval; zero-velocity updates apply
    /// meanwhile). With VO alive the count restarts.
    pub fn blind_stop_due(
        &mut self,
        vo_lost: bool,
        joints: Option<&JointState>,
        sigma_h: f64,
        wheel_radius_m: f64,
    ) -> bool {
        let c = &self.config;
        if !(vo_lost && c.blind_stop_interval_m > 0.0) {
            self.blind_travel_m = 0.0;
            self.blind_hold_left = 0;
            return false;
        }
        if self.blind_hold_left > 0 {
            self.blind_hold_left -= 1;
            return true;
        }
        // Wheel travel of the last RG2 period (mean measured wheel rate times the nominal
        // radius): a rover spinning its wheels in place still stops on schedule.
        if let Some(j) = joints {
            let mean_rate = j
                .drive_rate_rad_s
                .iter()
                .map(|r| libm::fabs(*r))
                .sum::<f64>()
                / 6.0;
            let d = mean_rate * wheel_radius_m * RG2_PERIOD_S;
            if d.is_finite() {
                self.blind_travel_m += d;
            }
        }
        // A stop is also due when the IMU-carried position sigma reaches half of fault
        // protection's limit: the stop's zero-velocity updates bring it back (the position
        // error between stops is mostly the integrated velocity error, which they observe),
        // rather than the drive stopping for good (`PositionUncertain`). At least a fifth of
        // the interval after the last stop: a sigma the stop did not bring down must not hold
        // the rover for good.
        let sigma_due = sigma_h > BLIND_SIGMA_FRACTION * c.protection.max_position_sigma_m
            && self.blind_travel_m >= 0.2 * c.blind_stop_interval_m;
        if self.blind_travel_m >= c.blind_stop_interval_m || sigma_due {
            self.blind_travel_m = 0.0;
            self.blind_hold_left = c.blind_stop_cycles;
            self.counters.blind_stops = self.counters.blind_stops.saturating_add(1);
            return true;
        }
        false
    }

    /// RG2: guidance (eq. 47-49) on the navigation `pose` with the `slip` vector (zero without
    /// slip compensation).
    pub fn follow(&mut self, pose: Pose2, slip: SlipVector) -> Follow {
        let Some(guidance) = self.guidance.as_mut() else {
            return Follow::Hold;
        };
        let out = match guidance.step(pose, slip) {
            Ok(o) => o,
            Err(_) => {
                self.counters.command_errors = self.counters.command_errors.saturating_add(1);
                return Follow::Hold;
            }
        };
        self.last_guidance = Some(out);
        if out.goal_reached {
            return Follow::Reached {
                distance_m: out.goal_distance_m,
            };
        }
        Follow::Drive(VehicleCommand {
            x_dot_m_s: out.x_dot_m_s,
            y_dot_m_s: out.y_dot_m_s,
            yaw_rate_rad_s: out.phi_dot_rad_s,
        })
    }

    /// Fault protection's arrival check: the estimated distance `distance_m` to the goal plus
    /// [`ProtectionConfig::arrival_sigmas`] horizontal sigmas `sigma_h` (m) within the arrival
    /// tolerance.
    pub fn arrival_supported(&self, distance_m: f64, sigma_h: f64) -> bool {
        let p = &self.config.protection;
        distance_m + p.arrival_sigmas * sigma_h <= p.arrival_tolerance_m
    }

    /// The body command `cmd` (rover frame) scaled to the wheel-rate limit and turned into
    /// wheel commands by inverse kinematics (eq. 16-25) at the suspension state of `joints`;
    /// with [`DriveConfig::ik_contact_angles`] the rough-terrain inverse kinematics on the
    /// odometry's windowed `contact_angles` (rad), falling back to eq. 16-25 when it fails.
    /// `None` (counted) when the kinematics fails.
    pub fn motor(
        &mut self,
        cmd: VehicleCommand,
        joints: &JointState,
        contact_angles: [f64; WHEEL_COUNT],
        geometry: &RoverGeometry,
    ) -> Option<MobilityCommand> {
        let state = SuspensionState::from_joints(joints);
        // Turns in place on eq. 16-25 (`DriveConfig::ik_contact_min_angle_rad`).
        let translating = cmd.x_dot_m_s != 0.0 || cmd.y_dot_m_s != 0.0;
        if self.config.ik_contact_angles && translating {
            let mut angles = contact_angles;
            for a in angles.iter_mut() {
                if libm::fabs(*a) < self.config.ik_contact_min_angle_rad {
                    *a = 0.0;
                }
            }
            let contact = ContactAngles::new(&angles, self.config.ik_contact_max_angle_rad);
            if contact != ContactAngles::LEVEL {
                if let Some(m) = self.scaled_inverse(cmd, &state, Some(&contact), geometry) {
                    return Some(m);
                }
            }
        }
        let m = self.scaled_inverse(cmd, &state, None, geometry);
        if m.is_none() {
            self.counters.command_errors = self.counters.command_errors.saturating_add(1);
        }
        m
    }

    /// [`Self::motor`] with the contacts at `contact` (`None`: below the axles, eq. 16-25): the
    /// command inverted and scaled to the wheel-rate limit in one solve
    /// ([`inverse_kinematics_scaled`]: the wheel rates are linear in the command and the
    /// steering does not change with the scale; the stored command is scaled with them);
    /// `None` when the solve fails. One solve per RG2 cycle.
    fn scaled_inverse(
        &mut self,
        mut cmd: VehicleCommand,
        state: &SuspensionState,
        contact: Option<&ContactAngles>,
        geometry: &RoverGeometry,
    ) -> Option<MobilityCommand> {
        let limit = geometry.limits.wheel_rate_rad_s;
        let (solution, k) =
            inverse_kinematics_scaled(geometry, state, &cmd, contact, limit).ok()?;
        if k < 1.0 {
            cmd.x_dot_m_s *= k;
            cmd.y_dot_m_s *= k;
            cmd.yaw_rate_rad_s *= k;
        }
        self.command = cmd;
        self.last_wheel_rates = solution.command.wheel_rate_rad_s;
        Some(solution.command)
    }
}
