//! # GoalNav: the goal-directed navigation (V99 sec. 3-5)
//!
//! One component for the parts that drive towards goals rather than along a given path:
//!
//! - [`hazard_nav`]: hazard maps from the hazcam pair ([`crate::perception`]) feed the RoverBug
//!   planner ([`crate::planning`]), whose paths replace the drive's guidance path (V99 sec. 4);
//! - [`loc_nav`]: terrain-map localization against an uplinked global map (V99 sec. 5);
//! - [`mission`]: the day's targets through the CASPER-style sequencer (V99 sec. 3).
//!
//! Its step functions take what they read and write from the rest of the navigator in a
//! [`GoalCtx`]: the filter, the drive (its guidance path is replaced by the planner's), the
//! held frame's stage, VO's keyframe clone, the camera calibration; mode changes they imply
//! come back as [`ModeRequest`]s, which the navigator applies.

use super::drive::Drive;
use super::filter::NavFilter;
use super::hazard_nav::{self, HazardNav};
use super::in_place::InPlace;
use super::loc_nav::{LocSlot, LocalizationSettings};
use super::mission::Mission;
use super::protection::FaultResponse;
use super::StereoStage;
use crate::estimation::CloneHandle;
use crate::kinematics::RoverGeometry;
use crate::types::Vec3;
use rover_hal::{StereoCalibration, WHEEL_COUNT};

/// Settings of the goal-directed navigation (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalConfig {
    /// Goal-directed driving with hazard avoidance (V99 sec. 4, [`hazard_nav`]): the last
    /// waypoint is the goal; hazard maps from the hazcams feed the RoverBug planner, whose
    /// paths replace the guidance path. Off: the waypoints are followed as a path.
    pub hazard_avoidance: bool,
    /// Hazard mapping from the hazcam pair ([`crate::perception`]).
    pub perception: crate::perception::PerceptionConfig,
    /// RoverBug planner ([`crate::planning`]).
    pub planner: crate::planning::PlannerConfig,
    /// EKF travel between hazard maps while driving a planned path, m (the hazcams see about
    /// 0.3-2.8 m ahead, so a map each metre keeps the next obstacle in view twice).
    pub map_interval_m: f64,
    /// Terrain-map localization against an uplinked global map (V99 sec. 5, [`super::loc_nav`]).
    /// Off by default.
    pub localization: LocalizationSettings,
}

/// A mode change the goal-directed navigation asks the navigator for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModeRequest {
    /// The drive is over at its goal ([`super::NavMode::Arrived`]).
    Arrived,
    /// Fault protection stops the drive with this response (latched while driving).
    Stop(FaultResponse),
    /// A new target: an arrived rover drives again.
    Resume,
}

/// What a step of the goal-directed navigation reads and writes beyond its own state.
pub struct GoalCtx<'a> {
    /// The filter (pose, clones, localization fixes).
    pub filter: &'a mut NavFilter,
    /// The drive: its guidance path is replaced by the planner's paths.
    pub drive: &'a mut Drive,
    /// The stage of the held stereo frame (mapping, localizing).
    pub stage: &'a mut StereoStage,
    /// VO's keyframe clone (a localization fix of VO's keyframe capture is applied there).
    pub key_clone: Option<CloneHandle>,
    /// The camera calibration (the hazard map's camera pose).
    pub calibration: &'a StereoCalibration,
    /// The mode change the step asks for, if any (set by the step, applied by the navigator).
    pub mode: Option<ModeRequest>,
}

/// The goal-directed navigation component.
pub struct GoalNav {
    pub(super) config: GoalConfig,
    /// Radius of the circle the rover's footprint sweeps turning in place, m
    /// ([`hazard_nav::turn_sweep_radius`]).
    pub(super) sweep_m: f64,
    /// Goal-directed driving with hazard avoidance (built in place by [`Self::build`]).
    pub(super) hazard: InPlace<HazardNav>,
    /// Terrain-map localization (built in place by [`Self::build`]).
    pub(super) loc: LocSlot,
    /// The day's targets and the power telemetry ([`super::mission`]).
    pub(super) mission: Mission,
    /// Parts that could not be built (a configuration refused: counted in
    /// [`super::NavCounters::command_errors`], the drive holds).
    pub(super) build_errors: u32,
}

impl GoalNav {
    /// Placeholder (the compile-time value of a static navigator before its initialisation).
    pub const EMPTY: Self = Self {
        config: GoalConfig {
            hazard_avoidance: false,
            perception: crate::perception::PerceptionConfig::DEFAULT,
            planner: crate::planning::PlannerConfig::DEFAULT,
            map_interval_m: 0.0,
            localization: LocalizationSettings::DEFAULT,
        },
        sweep_m: 0.0,
        hazard: InPlace::unbuilt(HazardNav::EMPTY),
        loc: LocSlot::NONE,
        mission: Mission::EMPTY,
        build_errors: 0,
    };

    /// Rewrites the component for a new drive with `config`, the rover's turning sweep from
    /// its nominal contact points `points` (m, `R`) and `geometry`; the hazard navigation and
    /// localization are marked not built (their storage is kept for [`Self::build`]).
    pub fn init(
        &mut self,
        config: &GoalConfig,
        points: Option<[Vec3; WHEEL_COUNT]>,
        geometry: &RoverGeometry,
    ) {
        self.config = *config;
        self.sweep_m = hazard_nav::sweep_radius_of(points, geometry);
        self.hazard.built = false;
        self.loc.unbuild();
        self.mission = Mission::EMPTY;
        self.build_errors = 0;
    }

    /// The settings.
    pub fn config(&self) -> &GoalConfig {
        &self.config
    }

    /// Build terrain-map localization and the hazard navigation in their storage (after the
    /// navigator reached its final location; [`super::Navigator::start_vo`]), for the drive's
    /// goal `goal` (`N`, m, the last waypoint) and the camera `calibration`.
    pub fn build(&mut self, goal: Option<[f64; 2]>, calibration: &StereoCalibration) {
        self.start_localization();
        self.start_hazard_nav(goal, calibration);
    }

    /// Parts that could not be built (counted with the command errors).
    pub fn build_errors(&self) -> u32 {
        self.build_errors
    }
}
