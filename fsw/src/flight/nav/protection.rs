//! Fault protection of the drive (MER-style safe stops): the checks that stop the
//! rover when going on would be dishonest or unsafe, each a documented response with telemetry.
//!
//! | response | trigger | action |
//! |---|---|---|
//! | [`FaultResponse::SlipLimit`] | slip over [`ProtectionConfig::slip_limit`] (1 - EKF travel / wheel travel) over a window of [`ProtectionConfig::slip_window_m`] of wheel travel, with VO fusing (MER stops at 40 % slip) | stop, latched |
//! | [`FaultResponse::MotorStall`] | a wheel commanded above [`ProtectionConfig::stall_min_rate_rad_s`] turns at less than [`ProtectionConfig::stall_fraction`] of it for [`ProtectionConfig::stall_cycles`] RG2 cycles | stop, latched |
//! | [`FaultResponse::PositionUncertain`] | horizontal position 1-sigma over [`ProtectionConfig::max_position_sigma_m`] | stop, latched |
//! | [`FaultResponse::ArrivedUncertain`] | guidance reached the goal, but its distance to the goal plus [`ProtectionConfig::arrival_sigmas`] times the horizontal position sigma `sqrt(P_nn + P_ee)` exceeds [`ProtectionConfig::arrival_tolerance_m`] | stop (not `Arrived`), latched |
//! | [`FaultResponse::SensorLoss`] | a sensor hold lasting [`ProtectionConfig::sensor_loss_cycles`] RG2 cycles | stop, latched |
//!
//! A latched stop ([`super::NavMode::Stopped`]) holds the rover until the ground resets the
//! flight software; the filter keeps running so the ground sees the estimate.

use rover_hal::WHEEL_COUNT;

/// Why the drive was stopped by fault protection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum FaultResponse {
    /// No fault-protection stop.
    #[default]
    None,
    /// Slip over the limit with VO confirming it.
    SlipLimit,
    /// A drive motor does not turn although commanded (wheel index `wheel - 1`).
    MotorStall {
        /// Wheel index, 0-5.
        wheel: u8,
    },
    /// The position estimate is too uncertain to drive on.
    PositionUncertain,
    /// The goal was reached by the estimate, but the estimate cannot support the arrival.
    ArrivedUncertain,
    /// A sensor stayed lost for too long.
    SensorLoss,
    /// The RoverBug planner found the goal unreachable (V99 sec. 4: it went round the
    /// obstacle that blocks it).
    GoalUnreachable,
    /// The RoverBug planner stopped without a verdict (no way on within its limits).
    PlannerBlocked,
}

/// Fault-protection limits (constant during a drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProtectionConfig {
    /// Slip limit, fraction (MER: 0.4).
    pub slip_limit: f64,
    /// Wheel travel over which the slip is measured, m.
    pub slip_window_m: f64,
    /// Smallest commanded wheel rate the stall check looks at, rad/s.
    pub stall_min_rate_rad_s: f64,
    /// A wheel turning at less than this fraction of its command is stalled.
    pub stall_fraction: f64,
    /// RG2 cycles of stall before the stop.
    pub stall_cycles: u32,
    /// Largest horizontal position 1-sigma to drive on, m.
    pub max_position_sigma_m: f64,
    /// Goal tolerance the arrival must be supported to (mission input), m.
    pub arrival_tolerance_m: f64,
    /// `Arrived` only when the estimated distance to the goal plus this many horizontal sigmas
    /// is within [`Self::arrival_tolerance_m`] (1: the true position is within the tolerance
    /// with about 63 % probability for a circular 2D error).
    pub arrival_sigmas: f64,
    /// RG2 cycles of a sensor hold before the stop is latched.
    pub sensor_loss_cycles: u32,
}

impl Default for ProtectionConfig {
    /// MER's 40 % slip limit over 0.5 m of wheel travel (5 s at 0.1 m/s); a stall is under 10 %
    /// of a command above 0.2 rad/s for 2 s; 1 m of position sigma; 0.3 m arrival tolerance at
    /// one sigma; 60 s of sensor loss.
    fn default() -> Self {
        Self {
            slip_limit: 0.4,
            slip_window_m: 0.5,
            stall_min_rate_rad_s: 0.2,
            stall_fraction: 0.1,
            stall_cycles: 40,
            max_position_sigma_m: 1.0,
            arrival_tolerance_m: 0.3,
            arrival_sigmas: 1.0,
            sensor_loss_cycles: 1200,
        }
    }
}

/// The running state of the checks.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Protection {
    /// Wheel travel in the current slip window, m.
    wheel_m: f64,
    /// EKF travel in the current slip window, m.
    ekf_m: f64,
    /// The window saw a VO update fused (the EKF travel is measured, not the wheels').
    vo_in_window: bool,
    /// Cycles each wheel has looked stalled.
    stall: [u32; WHEEL_COUNT],
    /// Cycles of the current sensor hold.
    hold_cycles: u32,
    /// The last slip measured over a whole window (fraction), for telemetry.
    pub last_slip: f64,
}

impl Protection {
    /// Nothing measured yet (as [`Default`], usable in a `const`).
    pub(super) const EMPTY: Self = Self {
        wheel_m: 0.0,
        ekf_m: 0.0,
        vo_in_window: false,
        stall: [0; WHEEL_COUNT],
        hold_cycles: 0,
        last_slip: 0.0,
    };
}

impl Protection {
    /// One kinematic interval: `wheel_step_m` of wheel travel (the kinematic translation) and
    /// `ekf_step_m` of EKF travel over it, `vo_fused` when a VO update was fused since the last
    /// call. Returns the slip response when a window closes over the limit.
    pub fn travel(
        &mut self,
        c: &ProtectionConfig,
        wheel_step_m: f64,
        ekf_step_m: f64,
        vo_fused: bool,
    ) -> Option<FaultResponse> {
        if !(wheel_step_m.is_finite() && ekf_step_m.is_finite()) {
            return None;
        }
        self.wheel_m += wheel_step_m;
        self.ekf_m += ekf_step_m;
        self.vo_in_window |= vo_fused;
        if self.wheel_m < c.slip_window_m {
            return None;
        }
        let slip = 1.0 - self.ekf_m / self.wheel_m;
        let measured = self.vo_in_window;
        self.wheel_m = 0.0;
        self.ekf_m = 0.0;
        self.vo_in_window = false;
        self.last_slip = slip;
        (measured && slip > c.slip_limit).then_some(FaultResponse::SlipLimit)
    }

    /// One RG2 cycle of the motors: `commanded` and `measured` wheel rates, rad/s.
    pub fn motors(
        &mut self,
        c: &ProtectionConfig,
        commanded: &[f64; WHEEL_COUNT],
        measured: &[f64; WHEEL_COUNT],
    ) -> Option<FaultResponse> {
        let mut stalled = None;
        for (i, ((cmd, meas), count)) in commanded
            .iter()
            .zip(measured.iter())
            .zip(self.stall.iter_mut())
            .enumerate()
        {
            let cmd_abs = libm::fabs(*cmd);
            let turning = libm::fabs(*meas) >= c.stall_fraction * cmd_abs;
            if cmd_abs >= c.stall_min_rate_rad_s && !turning {
                *count = count.saturating_add(1);
                if *count >= c.stall_cycles && stalled.is_none() {
                    stalled = Some(FaultResponse::MotorStall { wheel: i as u8 });
                }
            } else {
                *count = 0;
            }
        }
        stalled
    }

    /// One RG2 cycle of a sensor hold (`holding`), or none.
    pub fn sensor_hold(&mut self, c: &ProtectionConfig, holding: bool) -> Option<FaultResponse> {
        if holding {
            self.hold_cycles = self.hold_cycles.saturating_add(1);
        } else {
            self.hold_cycles = 0;
        }
        (self.hold_cycles >= c.sensor_loss_cycles).then_some(FaultResponse::SensorLoss)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fp_1_slip_window_needs_vo_and_the_limit() {
        let c = ProtectionConfig::default();
        let mut p = Protection::default();
        // 100 % slip without VO: not measured, no stop.
        for _ in 0..200 {
            assert_eq!(p.travel(&c, 0.005, 0.0, false), None);
        }
        // 30 % slip with VO: under the limit.
        let mut out = None;
        for _ in 0..100 {
            out = out.or(p.travel(&c, 0.005, 0.0035, true));
        }
        assert_eq!(out, None);
        assert!((p.last_slip - 0.3).abs() < 1e-9);
        // 100 % slip with VO: stop when the 0.5 m window closes (100 intervals of 5 mm).
        let mut at = None;
        for k in 0..200 {
            if p.travel(&c, 0.005, 0.0, k % 20 == 0) == Some(FaultResponse::SlipLimit) {
                at = Some(k);
                break;
            }
        }
        assert_eq!(at, Some(99));
    }

    #[test]
    fn fp_2_stall_after_two_seconds_of_a_dead_wheel() {
        let c = ProtectionConfig::default();
        let mut p = Protection::default();
        let cmd = [1.0; WHEEL_COUNT];
        let mut meas = [1.0; WHEEL_COUNT];
        meas[4] = 0.02;
        let mut at = None;
        for k in 0..100u32 {
            if let Some(r) = p.motors(&c, &cmd, &meas) {
                at = Some((k, r));
                break;
            }
        }
        assert_eq!(at, Some((39, FaultResponse::MotorStall { wheel: 4 })));
        // A stopped rover (no command) is not stalled.
        let mut p = Protection::default();
        for _ in 0..100 {
            assert_eq!(p.motors(&c, &[0.0; WHEEL_COUNT], &[0.0; WHEEL_COUNT]), None);
        }
    }
}
