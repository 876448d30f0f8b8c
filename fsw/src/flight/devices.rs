//! # Checked device reads
//!
//! Every device reading is checked before the flight software keeps it: a call error, a
//! reading the device flags invalid, non-finite or beyond the [`Plausibility`] limits, a time
//! stamp that does not advance, goes backwards or leaps ahead of the device's time base. Each
//! outcome is counted in the device's [`DeviceHealth`]; only checked readings are kept
//! ([`super::FlightState`]) and handed to the navigator. [`checked`] is the one read preamble
//! of the timestamped devices (IMU, joints, sun sensor, power); the camera's frames are checked
//! by the stereo stage ([`super::stereo`]).

use super::health::DeviceHealth;
use super::{DeviceId, Platform, Work};
use rover_hal::{ErrorKind, Imu, Mobility, Power, SunSensor};

/// Plausibility limits of device readings: a finite reading outside them is refused
/// and counted in [`DeviceHealth::invalid`]; a time stamp that leaps ahead is refused and
/// counted in [`DeviceHealth::time_jumps`] so that it cannot poison the device's time base.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausibility {
    /// Largest angular rate reading, rad/s: the measurement range of a tactical MEMS IMU of the
    /// rover's class (ADIS16488-class, +-450 deg/s); a reading beyond it cannot come from the
    /// sensor working.
    pub gyro_max_rad_s: f64,
    /// Largest specific-force reading, m/s^2 (the same class: +-18 g0; wheel shocks on rocks
    /// stay inside it).
    pub accel_max_m_s2: f64,
    /// Largest wheel rate reading, as a multiple of the motor limit.
    pub drive_rate_factor: f64,
    /// Margin beyond the steering, rocker and bogie limits of the geometry, rad.
    pub angle_margin_rad: f64,
    /// A time stamp may lead the last accepted one by at most this many minor frames per frame
    /// elapsed since (plus one frame).
    pub stamp_lead_factor: u64,
    /// Readings in a row that continue a leaped time base before it is accepted as the
    /// device's new time base ([`DeviceHealth::resyncs`]).
    pub resync_readings: u32,
    /// Largest bus power, W: ten times the power MER needs to drive (100 W, NASA, "Mars
    /// Exploration Rover - Rover Energy"). A power reading above it is refused, and so is one
    /// whose energy used grew faster than this since the last accepted reading (since boot for
    /// the first): an energy leap would otherwise lock out every later reading, whose energy
    /// used must not be lower.
    pub bus_power_max_w: f64,
}

impl Default for Plausibility {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl Plausibility {
    /// The default limits (as [`Default`], usable in a `const`).
    pub const DEFAULT: Self = Self {
        gyro_max_rad_s: 450.0 * core::f64::consts::PI / 180.0,
        accel_max_m_s2: 18.0 * 9.80665,
        drive_rate_factor: 2.0,
        angle_margin_rad: 0.2,
        stamp_lead_factor: 4,
        resync_readings: 20,
        bus_power_max_w: 1_000.0,
    };
}

/// Time-base state of one device: the frame of its last accepted reading and a candidate new
/// time base after a leap.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TimeBase {
    /// Minor frame of the last accepted reading.
    pub last_tick: u64,
    /// A leaped stamp and its frame, and how many readings in a row continued it.
    pub candidate: Option<(u64, u64, u32)>,
}

impl TimeBase {
    /// A reading at minor frame `tick` passed every check and was kept.
    pub fn accept(&mut self, tick: u64) {
        self.last_tick = tick;
        self.candidate = None;
    }
}

/// Frame period of the schedule, us (200 Hz).
pub(super) const FRAME_PERIOD_US: u64 = 5_000;

/// Fraction of the accelerometer's range at which a reading counts as saturated (clipped by
/// the sensor): an IMU shock ([`nav::Navigator::imu_shock`]).
const IMU_SATURATION: f64 = 0.999;

/// Check a time stamp against the previous accepted one at minor frame `tick`: stale or
/// backwards are faults; a stamp that leads the previous one by more than
/// `stamp_lead_factor` frames per elapsed frame (plus a frame) is a leap, refused and counted,
/// unless `resync_readings` readings in a row continue it (a real change of the device's time
/// base, accepted and counted in [`DeviceHealth::resyncs`]). The caller records a reading that
/// passes every check with [`TimeBase::accept`].
pub(super) fn check_time(
    health: &mut DeviceHealth,
    base: &mut TimeBase,
    previous: Option<u64>,
    t_us: u64,
    tick: u64,
    limits: &Plausibility,
) -> bool {
    let Some(p) = previous else {
        return true;
    };
    if t_us == p {
        health.stale = health.stale.saturating_add(1);
        return false;
    }
    if t_us < p {
        health.time_backwards = health.time_backwards.saturating_add(1);
        return false;
    }
    let frames = tick.saturating_sub(base.last_tick).saturating_add(1);
    let allowed = frames
        .saturating_mul(limits.stamp_lead_factor)
        .saturating_mul(FRAME_PERIOD_US)
        .saturating_add(FRAME_PERIOD_US);
    if t_us - p <= allowed {
        return true;
    }
    // A leap: does it continue a candidate time base?
    let continues = match base.candidate {
        Some((c_t, c_tick, _)) if t_us > c_t => {
            let f = tick.saturating_sub(c_tick).saturating_add(1);
            t_us - c_t
                <= f.saturating_mul(limits.stamp_lead_factor)
                    .saturating_mul(FRAME_PERIOD_US)
                    .saturating_add(FRAME_PERIOD_US)
        }
        _ => false,
    };
    let count = match (continues, base.candidate) {
        (true, Some((_, _, n))) => n.saturating_add(1),
        _ => 1,
    };
    if count >= limits.resync_readings {
        health.resyncs = health.resyncs.saturating_add(1);
        return true;
    }
    base.candidate = Some((t_us, tick, count));
    health.time_jumps = health.time_jumps.saturating_add(1);
    false
}

/// Stale or backwards time stamps (the camera, whose stamps are its trigger times).
pub(super) fn check_order(health: &mut DeviceHealth, previous: Option<u64>, t_us: u64) -> bool {
    match previous {
        Some(p) if t_us == p => {
            health.stale = health.stale.saturating_add(1);
            false
        }
        Some(p) if t_us < p => {
            health.time_backwards = health.time_backwards.saturating_add(1);
            false
        }
        _ => true,
    }
}

fn all_finite(values: &[f64]) -> bool {
    values.iter().all(|v| v.is_finite())
}

pub(super) fn count_invalid(health: &mut DeviceHealth) {
    health.invalid = health.invalid.saturating_add(1);
}

pub(super) fn count_error(health: &mut DeviceHealth, kind: ErrorKind) {
    // A poll with no new data is not a fault; everything else is.
    if kind != ErrorKind::NotReady {
        health.errors = health.errors.saturating_add(1);
    }
}

/// A device-specific verdict on a reading whose time stamp passed [`check_time`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verdict {
    /// Plausible: kept.
    Plausible,
    /// Out of range, non-finite or flagged invalid by the device: counted, not kept.
    Invalid,
    /// Not a measurement (the sun out of view): neither kept nor counted.
    Ignored,
}

impl Verdict {
    /// [`Verdict::Plausible`] when `plausible`, [`Verdict::Invalid`] otherwise.
    fn of(plausible: bool) -> Self {
        if plausible {
            Verdict::Plausible
        } else {
            Verdict::Invalid
        }
    }
}

/// What [`checked`] made of a device call.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Checked<T> {
    /// Passed every check (counted good; the time base advanced).
    Accepted(T),
    /// Its time stamp passed but the device-specific check refused it (counted invalid).
    Invalid(T),
    /// A call error, a time fault, or a reading without a measurement.
    Refused,
}

/// The checked read of a timestamped device: a call error is counted (`reading`'s error
/// kind), the time stamp `stamp` of the reading goes through [`check_time`] against the last
/// accepted one (`previous`) at minor frame `tick`, then `verdict` judges the value; a
/// plausible reading is counted good and advances the device's time base.
#[allow(clippy::too_many_arguments)]
fn checked<T>(
    health: &mut DeviceHealth,
    base: &mut TimeBase,
    reading: Result<T, ErrorKind>,
    stamp: impl FnOnce(&T) -> u64,
    previous: Option<u64>,
    tick: u64,
    limits: &Plausibility,
    verdict: impl FnOnce(&T) -> Verdict,
) -> Checked<T> {
    let r = match reading {
        Err(kind) => {
            count_error(health, kind);
            return Checked::Refused;
        }
        Ok(r) => r,
    };
    if !check_time(health, base, previous, stamp(&r), tick, limits) {
        return Checked::Refused;
    }
    match verdict(&r) {
        Verdict::Plausible => {
            health.good = health.good.saturating_add(1);
            base.accept(tick);
            Checked::Accepted(r)
        }
        Verdict::Invalid => {
            count_invalid(health);
            Checked::Invalid(r)
        }
        Verdict::Ignored => Checked::Refused,
    }
}

impl<P: Platform> Work<'_, P> {
    /// RG1 `imu`: read and check the IMU. A saturated accelerometer axis (or one refused beyond
    /// its range) is an IMU shock for the navigator; a time base that re-synchronised
    /// re-anchors the filter's timeline.
    #[inline(never)]
    pub(super) fn read_imu(&mut self, tick: u64) {
        let i = DeviceId::Imu as usize;
        let (health, base) = (&mut self.state.health[i], &mut self.state.time_bases[i]);
        let previous = self.state.imu.map(|p| p.t_us);
        let resyncs = health.resyncs;
        let l = self.limits;
        let in_range =
            |v: &[f64; 3], max: f64| all_finite(v) && v.iter().all(|x| libm::fabs(*x) <= max);
        let reading = self
            .devices
            .imu
            .read()
            .map_err(|e| rover_hal::Error::kind(&e));
        let result = checked(
            health,
            base,
            reading,
            |s| s.t_us,
            previous,
            tick,
            l,
            |s| {
                let plausible = s.valid
                    && in_range(&s.gyro_rad_s, l.gyro_max_rad_s)
                    && in_range(&s.accel_m_s2, l.accel_max_m_s2);
                Verdict::of(plausible)
            },
        );
        let rebased = self.state.health[i].resyncs != resyncs;
        // A shock: an accelerometer axis at its range (clipped) or beyond it (refused); that
        // sample's velocity increment is unknown up to the range over one frame
        // (`KinAiding::imu_shock`).
        let shock = |s: &rover_hal::ImuSample| {
            all_finite(&s.accel_m_s2)
                && s.accel_m_s2
                    .iter()
                    .any(|a| libm::fabs(*a) >= IMU_SATURATION * l.accel_max_m_s2)
        };
        let shock_sigma_m_s = l.accel_max_m_s2 * FRAME_PERIOD_US as f64 * 1e-6;
        match result {
            Checked::Refused => {}
            Checked::Invalid(s) => {
                if s.valid && shock(&s) {
                    self.nav.imu_shock(shock_sigma_m_s);
                }
            }
            Checked::Accepted(s) => {
                if rebased {
                    // The filter's timeline restarts one frame before this sample.
                    self.nav
                        .imu_time_rebase(s.t_us.saturating_sub(FRAME_PERIOD_US));
                }
                if shock(&s) {
                    self.nav.imu_shock(shock_sigma_m_s);
                }
                self.state.imu = Some(s);
                self.fresh.imu = Some(s);
            }
        }
    }

    /// RG2 `joints`: read and check the joint encoders (finite, within the joint limits of the
    /// navigator's geometry plus a margin, the suspension reading valid).
    #[inline(never)]
    pub(super) fn read_joints(&mut self, tick: u64) {
        let i = DeviceId::Joints as usize;
        let (health, base) = (&mut self.state.health[i], &mut self.state.time_bases[i]);
        let previous = self.state.joints.map(|p| p.t_us);
        let limits = &self.nav.geometry().limits;
        let (l, m) = (self.limits, self.limits.angle_margin_rad);
        let reading = self
            .devices
            .mobility
            .read_joints()
            .map_err(|e| rover_hal::Error::kind(&e));
        let result = checked(
            health,
            base,
            reading,
            |j| j.t_us,
            previous,
            tick,
            l,
            |j| {
                let finite = all_finite(&j.drive_angle_rad)
                    && all_finite(&j.drive_rate_rad_s)
                    && all_finite(&j.steer_angle_rad)
                    && all_finite(&j.bogie_rad)
                    && j.rocker_rad.is_finite();
                let rate_max = l.drive_rate_factor * limits.wheel_rate_rad_s;
                let plausible = j
                    .drive_rate_rad_s
                    .iter()
                    .all(|r| libm::fabs(*r) <= rate_max)
                    && j.steer_angle_rad
                        .iter()
                        .all(|a| libm::fabs(*a) <= limits.steer_rad + m)
                    && libm::fabs(j.rocker_rad) <= limits.rocker_rad + m
                    && j.bogie_rad
                        .iter()
                        .all(|a| libm::fabs(*a) <= limits.bogie_rad + m);
                Verdict::of(finite && plausible && j.suspension_valid)
            },
        );
        if let Checked::Accepted(j) = result {
            self.state.joints = Some(j);
            self.fresh.joints = Some(j);
        }
    }

    /// RG4 `sun`: read and check the sun sensor (a reading with the sun out of view is neither
    /// kept nor counted; a direction that is not finite or not a unit vector within 10 % is
    /// invalid) and hand it to the navigator.
    #[inline(never)]
    pub(super) fn read_sun(&mut self, tick: u64) {
        let i = DeviceId::Sun as usize;
        let (health, base) = (&mut self.state.health[i], &mut self.state.time_bases[i]);
        let previous = self.state.sun.map(|p| p.t_us);
        let reading = self
            .devices
            .sun
            .read()
            .map_err(|e| rover_hal::Error::kind(&e));
        let result = checked(
            health,
            base,
            reading,
            |r| r.t_us,
            previous,
            tick,
            self.limits,
            |r| {
                let norm2: f64 = r.sun_dir_rover.iter().map(|v| v * v).sum();
                if !r.sun_in_view {
                    Verdict::Ignored
                } else if !all_finite(&r.sun_dir_rover) || !(0.81..=1.21).contains(&norm2) {
                    Verdict::Invalid
                } else {
                    Verdict::Plausible
                }
            },
        );
        if let Checked::Accepted(r) = result {
            self.state.sun = Some(r);
            self.nav.sun(&r);
        }
    }

    /// RG4 `power`: read the power subsystem (V99 sec. 3: the "current power reserves" the
    /// sequencer monitors). A reading the device flags invalid, with a non-finite or negative
    /// energy or bus power, with less energy used than the last accepted reading (the
    /// battery's discharge integral never decreases), or beyond
    /// [`Plausibility::bus_power_max_w`] (the bus power, or the growth of the energy used
    /// since the last accepted reading) is counted invalid and not passed on. A reading that
    /// passes is kept ([`super::FlightState::power`]) and handed to the navigator.
    #[inline(never)]
    pub(super) fn read_power(&mut self, tick: u64) {
        let i = DeviceId::Power as usize;
        let (health, base) = (&mut self.state.health[i], &mut self.state.time_bases[i]);
        let previous = self.state.power;
        let max_w = self.limits.bus_power_max_w;
        let reading = self
            .devices
            .power
            .read()
            .map_err(|e| rover_hal::Error::kind(&e));
        let stamp = previous.map(|p| p.t_us);
        let result = checked(
            health,
            base,
            reading,
            |r| r.t_us,
            stamp,
            tick,
            self.limits,
            |r| {
                let (t0_us, e0_j) = previous.map_or((0, 0.0), |p| (p.t_us, p.energy_used_j));
                let elapsed_s = r.t_us.saturating_sub(t0_us) as f64 * 1e-6;
                let plausible = r.valid
                    && r.energy_used_j.is_finite()
                    && r.bus_power_w.is_finite()
                    && r.energy_used_j >= e0_j
                    && r.energy_used_j - e0_j <= max_w * elapsed_s
                    && r.bus_power_w >= 0.0
                    && r.bus_power_w <= max_w;
                Verdict::of(plausible)
            },
        );
        if let Checked::Accepted(r) = result {
            self.state.power = Some(r);
            self.nav.power(&r);
        }
    }
}
