//! Guidance adapter (RG2): the navigation pose and slip vector into the path follower
//! (eq. 47-49), speed limiting and inverse kinematics (eq. 16-25) to the motor command.

use super::*;

/// Fraction of fault protection's position-sigma limit at which a stop of the stop-and-go
/// drive without VO is due whatever the wheel travel.
pub const BLIND_SIGMA_FRACTION: f64 = 0.5;

impl Navigator {
    /// RG2, after [`Self::kinematic_cycle`]: guidance and inverse kinematics. Returns the motor
    /// command, or `None` when the rover must be stopped (aligning, arrived, safed, a sensor
    /// lost, waiting for VO's first keyframe, or a guidance/kinematics failure).
    ///
    /// With VO running the rover does not start before VO holds its first keyframe (at most
    /// [`NavConfig::vo_start_timeout_cycles`], then it drives on the kinematic fallback,
    /// counted in [`NavCounters::vo_start_timeouts`]): the first metres on a slope are where
    /// slip, unseen without VO, is learnt as a heading error.
    pub fn guidance_cycle(&mut self) -> Option<MobilityCommand> {
        self.command = VehicleCommand::default();
        // The wheel rates commanded in the previous cycle (stall check), then cleared until a
        // new command is made.
        let commanded = core::mem::replace(&mut self.last_wheel_rates, [0.0; 6]);
        self.mission_book(commanded.iter().any(|r| *r != 0.0));
        if self.mode != NavMode::Driving {
            return None;
        }
        let holding = self.frames_without_imu >= self.config.imu_timeout_frames
            || self.cycles_without_joints >= self.config.joints_timeout_cycles;
        if let Some(r) = self
            .protection
            .sensor_hold(&self.config.protection, holding)
        {
            self.fault_stop(r);
            return None;
        }
        if holding {
            self.counters.sensor_holds = self.counters.sensor_holds.saturating_add(1);
            return None;
        }
        if let Some(j) = self.last_joints {
            if let Some(r) =
                self.protection
                    .motors(&self.config.protection, &commanded, &j.drive_rate_rad_s)
            {
                self.fault_stop(r);
                return None;
            }
        }
        let sigma_h = self.horizontal_sigma_m();
        if sigma_h > self.config.protection.max_position_sigma_m {
            self.fault_stop(FaultResponse::PositionUncertain);
            return None;
        }
        if self.vo.is_some() && !self.vo_started {
            if self.cycles_waiting_vo < self.config.vo_start_timeout_cycles {
                self.cycles_waiting_vo = self.cycles_waiting_vo.saturating_add(1);
                self.counters.vo_start_holds = self.counters.vo_start_holds.saturating_add(1);
                return None;
            }
            self.vo_started = true;
            self.counters.vo_start_timeouts = self.counters.vo_start_timeouts.saturating_add(1);
        }
        if self.blind_stop_due() {
            return None;
        }
        // A localization stop (path drives, V99 sec. 5): hold, or turn in place to a view.
        let stop = self.loc_command();
        if let Some(turn) = stop {
            return self.hold_or_turn(turn);
        }
        // The day's targets: hold for a plan, or stand at a target for its dwell (V99 sec. 3).
        if self.mission_command().is_some() {
            return None;
        }
        // Goal-directed driving: hold for a map, or turn in place for a gaze (V99 sec. 4).
        if self.config.hazard_avoidance && !self.hazard_on() {
            self.counters.command_errors = self.counters.command_errors.saturating_add(1);
            return None;
        }
        if let Some(turn) = self.hazard_command() {
            return self.hold_or_turn(turn);
        }
        let (ekf, guidance, joints) = match (
            self.ekf_running.then_some(&self.ekf),
            self.guidance.as_mut(),
            &self.last_joints,
        ) {
            (Some(e), Some(g), Some(j)) => (e, g, *j),
            _ => return None,
        };
        let (nav_pose, slip) = if self.config.slip_compensation {
            let x = ekf.state();
            (
                PoseEstimate {
                    p_n: x.p_n,
                    q_nr: x.q_nr,
                },
                self.slip,
            )
        } else {
            (self.traj.kin3d, SlipVector::default())
        };
        let pose = Pose2 {
            x_m: nav_pose.p_n.x,
            y_m: nav_pose.p_n.y,
            phi_rad: yaw_of(&nav_pose.q_nr),
        };
        let out = match guidance.step(pose, slip) {
            Ok(o) => o,
            Err(_) => {
                self.counters.command_errors = self.counters.command_errors.saturating_add(1);
                return None;
            }
        };
        self.last_guidance = Some(out);
        if out.goal_reached {
            // The end of a planned path short of the goal: hold and map again.
            if self.hazard_subgoal_reached() {
                return None;
            }
            let p = &self.config.protection;
            if out.goal_distance_m + p.arrival_sigmas * sigma_h <= p.arrival_tolerance_m {
                // With targets: the dwell at this one, then on to the next.
                if !self.mission_arrived() {
                    self.mode = NavMode::Arrived;
                }
            } else {
                self.fault_stop(FaultResponse::ArrivedUncertain);
            }
            return None;
        }
        let cmd = VehicleCommand {
            x_dot_m_s: out.x_dot_m_s,
            y_dot_m_s: out.y_dot_m_s,
            yaw_rate_rad_s: out.phi_dot_rad_s,
        };
        self.motor_command(cmd, &joints)
    }

    /// A stop's or a gaze's say: `None` holds the rover still, `Some(turn)` turns it in place.
    fn hold_or_turn(&mut self, turn: Option<VehicleCommand>) -> Option<MobilityCommand> {
        let turn = turn?;
        let joints = self.last_joints?;
        self.motor_command(turn, &joints)
    }

    /// The body command `cmd` (rover frame) scaled to the wheel-rate limit and turned into
    /// wheel commands by inverse kinematics (eq. 16-25) at the suspension state of `joints`;
    /// with [`NavConfig::ik_contact_angles`] the rough-terrain inverse kinematics on the
    /// odometry's windowed contact angles
    /// ([`crate::kinematics::KinematicOdometry::windowed_contact_angles_rad`]), falling back
    /// to eq. 16-25 when it fails. `None` (counted) when the kinematics fails.
    fn motor_command(
        &mut self,
        cmd: VehicleCommand,
        joints: &JointState,
    ) -> Option<MobilityCommand> {
        let state = SuspensionState::from_joints(joints);
        // Turns in place on eq. 16-25 (`NavConfig::ik_contact_min_angle_rad`).
        let translating = cmd.x_dot_m_s != 0.0 || cmd.y_dot_m_s != 0.0;
        if self.config.ik_contact_angles && translating {
            let mut angles = self.odometry.windowed_contact_angles_rad();
            for a in angles.iter_mut() {
                if libm::fabs(*a) < self.config.ik_contact_min_angle_rad {
                    *a = 0.0;
                }
            }
            let contact = ContactAngles::new(&angles, self.config.ik_contact_max_angle_rad);
            if contact != ContactAngles::LEVEL {
                if let Some(m) = self.scaled_inverse(cmd, &state, Some(&contact)) {
                    return Some(m);
                }
            }
        }
        let m = self.scaled_inverse(cmd, &state, None);
        if m.is_none() {
            self.counters.command_errors = self.counters.command_errors.saturating_add(1);
        }
        m
    }

    /// [`Self::motor_command`] with the contacts at `contact` (`None`: below the axles, eq.
    /// 16-25): the command inverted and scaled to the wheel-rate limit in one solve
    /// ([`inverse_kinematics_scaled`]: the wheel rates are linear in the command and the
    /// steering does not change with the scale; the stored command is scaled with them);
    /// `None` when the solve fails. The results differ from scaling the command first
    /// ([`max_speed_scale_contact`](crate::kinematics::max_speed_scale_contact)) and solving
    /// again only by rounding: one solve per RG2 cycle instead of two (issue 18).
    fn scaled_inverse(
        &mut self,
        mut cmd: VehicleCommand,
        state: &SuspensionState,
        contact: Option<&ContactAngles>,
    ) -> Option<MobilityCommand> {
        let geometry = &self.config.geometry;
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

    /// Stop-and-go without VO ([`NavConfig::blind_stop_interval_m`], or when the position
    /// sigma reaches [`BLIND_SIGMA_FRACTION`] of fault protection's limit): counts the wheels'
    /// travel while VO is off or lost and returns `true` while the rover must stand
    /// (a stop of [`NavConfig::blind_stop_cycles`] after each interval; zero-velocity updates
    /// apply meanwhile, `kin_aiding`). With VO alive the count restarts.
    fn blind_stop_due(&mut self) -> bool {
        let c = &self.config;
        let vo_lost = self.vo_lost();
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
        if let Some(j) = &self.last_joints {
            let mean_rate = j
                .drive_rate_rad_s
                .iter()
                .map(|r| libm::fabs(*r))
                .sum::<f64>()
                / 6.0;
            let d = mean_rate * c.geometry.wheel_radius_m * RG2_PERIOD_S;
            if d.is_finite() {
                self.blind_travel_m += d;
            }
        }
        // A stop is also due when the IMU-carried position sigma reaches half of fault
        // protection's limit: the stop's zero-velocity updates bring it back (the position
        // error between stops is mostly the integrated velocity error, which they observe),
        // rather than the drive stopping for good (`PositionUncertain`). Measured on
        // `marsyard-25m` without VO: the sigma reached the 1 m limit 0.98 m into the first
        // 1 m interval and fell to 0.06 m at the stop.
        // (At least a fifth of the interval after the last stop: a sigma the stop did not
        // bring down must not hold the rover for good.)
        let sigma_due = self.horizontal_sigma_m()
            > BLIND_SIGMA_FRACTION * c.protection.max_position_sigma_m
            && self.blind_travel_m >= 0.2 * c.blind_stop_interval_m;
        if self.blind_travel_m >= c.blind_stop_interval_m || sigma_due {
            self.blind_travel_m = 0.0;
            self.blind_hold_left = c.blind_stop_cycles;
            self.counters.blind_stops = self.counters.blind_stops.saturating_add(1);
            return true;
        }
        false
    }

    /// VO is off ([`NavConfig::vo_enabled`]) or has not been fused for
    /// [`NavConfig::vo_timeout_cycles`]: the kinematic intervals fall back to the VO-loss
    /// handling (stop-and-go, or fusion with the slip allowance).
    pub(super) fn vo_lost(&self) -> bool {
        !self.config.vo_enabled || self.cycles_since_vo > self.config.vo_timeout_cycles
    }

    /// Horizontal position 1-sigma of the EKF, m (`sqrt(P_nn + P_ee)`); 0 before alignment.
    pub(super) fn horizontal_sigma_m(&self) -> f64 {
        match self.ekf_running.then_some(&self.ekf) {
            Some(e) => {
                let p = e.covariance();
                let i = crate::estimation::state::I_P;
                crate::linalg::sqrt((p[(i, i)] + p[(i + 1, i + 1)]).max(0.0))
            }
            None => 0.0,
        }
    }
}
