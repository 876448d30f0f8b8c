//! Sun direction from the flight software's own clock and ephemeris parameters (RB sec. 5.1:
//! the sun sensor measures the sun in the rover frame; the filter compares it with the sun's
//! direction in the local level frame `N`, which the rover computes).
//!
//! Over one drive (minutes to an hour) the solar declination is constant to a few arc-seconds,
//! so the ephemeris is the site latitude `phi`, the declination `delta` and the local true solar
//! hour angle `H_0` at flight-clock time 0, with `H` advancing 2 pi per sol:
//!
//! - `H(t) = H_0 + 2 pi t / T_sol`, `T_sol` = 88 775.244 s (one Mars solar day);
//! - up `= sin(phi) sin(delta) + cos(phi) cos(delta) cos(H)`,
//!   north `= cos(phi) sin(delta) - sin(phi) cos(delta) cos(H)`,
//!   east `= -cos(delta) sin(H)` (spherical astronomy, e.g. Allison & McEwen 2000 sec. 2);
//! - `s_N = [north, east, -up]` (`N`: x north, y east, z down).
//!
//! The ground uplinks `phi` (site), `delta` (from the season, `sin(delta) = sin(25.19 deg)
//! sin(L_s)`) and `H_0` (local true solar time at clock zero) with the drive.

use crate::types::Vec3;

/// Length of a Mars solar day (sol), s (Allison & McEwen 2000).
pub const SOL_S: f64 = 88_775.244;

/// Sun ephemeris for one drive (constant during the drive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunEphemeris {
    /// Site latitude (areocentric), rad, north positive.
    pub latitude_rad: f64,
    /// Solar declination, rad.
    pub declination_rad: f64,
    /// Local true solar hour angle at flight-clock time 0, rad (0 at local noon, negative in
    /// the morning).
    pub hour_angle_t0_rad: f64,
}

impl SunEphemeris {
    /// The ephemeris of a site at latitude `latitude_deg`, solar longitude `ls_deg` (season)
    /// and local true solar time `lst_h` (hours, 12 = noon) at clock zero.
    pub fn from_site(latitude_deg: f64, ls_deg: f64, lst_h: f64) -> Self {
        let deg = core::f64::consts::PI / 180.0;
        let obliquity = 25.19 * deg;
        Self {
            latitude_rad: latitude_deg * deg,
            declination_rad: libm::asin(libm::sin(obliquity) * libm::sin(ls_deg * deg)),
            hour_angle_t0_rad: (lst_h - 12.0) * 15.0 * deg,
        }
    }

    /// Unit vector towards the sun in `N` at flight-clock time `t_us`, or `None` when the
    /// parameters are not finite.
    pub fn sun_dir_n(&self, t_us: u64) -> Option<Vec3> {
        let h = self.hour_angle_t0_rad + core::f64::consts::TAU * ((t_us as f64) * 1e-6 / SOL_S);
        let (sp, cp) = libm::sincos(self.latitude_rad);
        let (sd, cd) = libm::sincos(self.declination_rad);
        let (sh, ch) = libm::sincos(h);
        let up = sp * sd + cp * cd * ch;
        let north = cp * sd - sp * cd * ch;
        let east = -cd * sh;
        let s = Vec3::new(north, east, -up);
        let n = s.norm();
        (n.is_finite() && n > 0.5).then(|| s / n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noon_elevation_and_morning_east() {
        let e = SunEphemeris::from_site(-14.6, 0.0, 12.0);
        let s = e.sun_dir_n(0).unwrap_or_default();
        // Declination 0 at Ls 0: noon elevation 90 - 14.6 deg, sun to the north.
        let elevation = libm::asin(-s.z).to_degrees();
        assert!((elevation - 75.4).abs() < 1e-9, "{elevation}");
        assert!(s.x > 0.0 && s.y.abs() < 1e-12);
        let morning = SunEphemeris::from_site(-14.6, 0.0, 9.0)
            .sun_dir_n(0)
            .unwrap_or_default();
        assert!(morning.y > 0.5, "morning sun in the east: {morning:?}");
    }

    #[test]
    fn hour_angle_advances_15_deg_per_mars_hour() {
        let e = SunEphemeris::from_site(0.0, 0.0, 9.0);
        let t_hour_us = (SOL_S / 24.0 * 1e6) as u64;
        let a = e.sun_dir_n(0).unwrap_or_default();
        let b = e.sun_dir_n(t_hour_us).unwrap_or_default();
        // On the equator at equinox the sun moves along the east-up great circle.
        let angle = libm::acos(a.dot(&b).clamp(-1.0, 1.0)).to_degrees();
        assert!((angle - 15.0).abs() < 1e-6, "{angle}");
    }
}
