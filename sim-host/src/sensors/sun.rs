//! Sun sensor (RB sec. 3): the unit vector towards the sun in the rover frame `R`, with
//! angular noise, valid when the sun is inside the sensor's upward-looking cone; and the sun's
//! direction at the site from a Mars solar ephemeris.
//!
//! # Ephemeris
//! The Mars24 algorithm (Allison & McEwen 2000, Planet. Space Sci. 48, 215-235; NASA GISS
//! Mars24 "Algorithm and Worked Examples"), reduced to a site, a season and a time of day:
//! - solar declination from the areocentric solar longitude `Ls`:
//!   `sin(delta) = sin(25.19 deg) sin(Ls)` (Mars24 step D-1 without its small `0.25 deg sin(Ls)`
//!   planetographic term; `Ls` is held constant over a run: it changes by about 0.5 deg per sol);
//! - hour angle from the local true solar time `LTST` (hours of a 24-hour sol):
//!   `H = 15 deg (LTST - 12)`, with `LTST` advancing 24 hours per sol of 88 775.244 s;
//! - elevation `e` and azimuth `A` (from north towards east) at latitude `phi` from the spherical
//!   triangle: `sin(e) = sin(phi) sin(delta) + cos(phi) cos(delta) cos(H)`, and the unit vector
//!   towards the sun in `W` (x north, y east, z down)
//!   `[cos(phi) sin(delta) - sin(phi) cos(delta) cos(H), -cos(delta) sin(H), -sin(e)]`.

use nalgebra::{Rotation3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::Deserialize;

/// Mean solar day of Mars (a sol), s (Allison & McEwen 2000).
pub const SOL_S: f64 = 88_775.244;
/// Obliquity of Mars' equator to its orbit, degrees (Mars24: `sin` of it is 0.42565).
pub const OBLIQUITY_DEG: f64 = 25.19;

/// Solar declination for the areocentric solar longitude `ls_deg`, rad.
pub fn declination_rad(ls_deg: f64) -> f64 {
    (OBLIQUITY_DEG.to_radians().sin() * ls_deg.to_radians().sin()).asin()
}

/// Hour angle of the sun at local true solar time `lst_h` (hours), rad (negative before noon).
pub fn hour_angle_rad(lst_h: f64) -> f64 {
    (15.0 * (lst_h - 12.0)).to_radians()
}

/// Unit vector towards the sun in `W` (x north, y east, z down) at latitude `latitude_deg`
/// (north positive), solar longitude `ls_deg` and local true solar time `lst_h` (hours).
pub fn sun_direction_w(latitude_deg: f64, ls_deg: f64, lst_h: f64) -> Vector3<f64> {
    let (sp, cp) = latitude_deg.to_radians().sin_cos();
    let (sd, cd) = declination_rad(ls_deg).sin_cos();
    let (sh, ch) = hour_angle_rad(lst_h).sin_cos();
    let up = sp * sd + cp * cd * ch;
    Vector3::new(cp * sd - sp * cd * ch, -cd * sh, -up)
}

/// Elevation above the horizon (rad) and azimuth from north towards east (rad, `(-pi, pi]`) of
/// a direction in `W`.
pub fn elevation_azimuth(v_w: &Vector3<f64>) -> (f64, f64) {
    ((-v_w.z).clamp(-1.0, 1.0).asin(), v_w.y.atan2(v_w.x))
}

/// Sun sensor parameters.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default)]
pub struct SunParams {
    /// Angular noise on each of the two axes across the line of sight, rad (1-sigma).
    pub noise_rad: f64,
    /// Half-angle of the sensor's field of view around `-z_R` (up), degrees.
    pub fov_half_deg: f64,
}

impl Default for SunParams {
    /// 0.01 rad noise (a coarse digital sun sensor; RB used 0.314 rad for its simulation); 60 deg
    /// half-angle cone.
    fn default() -> Self {
        Self {
            noise_rad: 0.01,
            fov_half_deg: 60.0,
        }
    }
}

impl SunParams {
    /// Reading of the sun at `sun_w` (unit vector in `W`) for a rover whose attitude is
    /// `rot_w_from_r`: `(vector in R, in view)`.
    pub fn measure(
        &self,
        sun_w: &Vector3<f64>,
        rot_w_from_r: &Rotation3<f64>,
        rng: &mut ChaCha8Rng,
    ) -> ([f64; 3], bool) {
        let s = rot_w_from_r.inverse() * sun_w;
        // Two axes across the line of sight.
        let helper = if s.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = s.cross(&helper).normalize();
        let e2 = s.cross(&e1);
        let (n1, n2): (f64, f64) = (rng.sample(StandardNormal), rng.sample(StandardNormal));
        let m = (s + e1 * (self.noise_rad * n1) + e2 * (self.noise_rad * n2)).normalize();
        let in_view = -s.z >= self.fov_half_deg.to_radians().cos();
        ([m.x, m.y, m.z], in_view)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn from_az_el(az_deg: f64, el_deg: f64) -> Vector3<f64> {
        let (sa, ca) = az_deg.to_radians().sin_cos();
        let (se, ce) = el_deg.to_radians().sin_cos();
        Vector3::new(ce * ca, ce * sa, -se)
    }

    /// SIM-8: level rover facing north sees the sun at its azimuth and elevation, with the
    /// stated angular noise; a sun behind the sensor cone is reported out of view.
    #[test]
    fn sim_8_sun_direction_noise_and_view() {
        let p = SunParams::default();
        let sun = from_az_el(135.0, 40.0);
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let level = Rotation3::identity();
        let n = 20_000;
        let mut sum2 = 0.0;
        for _ in 0..n {
            let (v, in_view) = p.measure(&sun, &level, &mut rng);
            assert!(in_view);
            let v = Vector3::from(v);
            sum2 += v.angle(&sun).powi(2);
        }
        // The angle is Rayleigh: E[angle^2] = 2 sigma^2.
        let rms = (sum2 / n as f64 / 2.0).sqrt();
        assert!((rms / p.noise_rad - 1.0).abs() < 0.03, "{rms}");
        let low = from_az_el(135.0, 10.0);
        assert!(!p.measure(&low, &level, &mut rng).1);
    }

    /// SIM-19: at local noon the sun is on the meridian at elevation `90 - |phi - delta|`, to
    /// the north when the declination is north of the site; the declination is zero at the
    /// equinox and `+-25.19 deg` at the solstices.
    #[test]
    fn sim_19_noon_elevation() {
        assert!(declination_rad(0.0).abs() < 1e-15);
        assert!((declination_rad(90.0).to_degrees() - 25.19).abs() < 1e-12);
        assert!((declination_rad(270.0).to_degrees() + 25.19).abs() < 1e-12);
        for (lat, ls) in [
            (-14.6, 0.0),
            (-14.6, 270.0),
            (4.6, 90.0),
            (-1.9, 150.0),
            (40.0, 30.0),
        ] {
            let v = sun_direction_w(lat, ls, 12.0);
            let (e, az) = elevation_azimuth(&v);
            let delta = declination_rad(ls).to_degrees();
            let want = 90.0 - (lat - delta).abs();
            assert!((e.to_degrees() - want).abs() < 1e-9, "{lat} {ls}");
            assert!(v.y.abs() < 1e-12, "on the meridian");
            let north = delta > lat;
            assert_eq!(az.abs() < 1.0, north, "{lat} {ls} {az}");
            assert!((v.norm() - 1.0).abs() < 1e-12);
        }
    }

    /// SIM-19: the hour angle advances 15 deg per Mars hour (a 24th of a sol), 360 deg per sol;
    /// at the equator at equinox the sun's elevation is `90 deg - |H|`.
    #[test]
    fn sim_19_hour_angle_rate() {
        let mars_hour_s = SOL_S / 24.0;
        let site = crate::scenario::Site {
            latitude_deg: 0.0,
            solar_longitude_deg: 0.0,
            local_solar_time_h: 9.0,
        };
        for k in 0..6 {
            let t = k as f64 * mars_hour_s;
            let h = hour_angle_rad(site.local_solar_time_at_h(t));
            assert!((h.to_degrees() - (-45.0 + 15.0 * k as f64)).abs() < 1e-9);
            let (e, _) = elevation_azimuth(&site.sun_w(t));
            assert!((e.to_degrees() - (90.0 - h.to_degrees().abs())).abs() < 1e-9);
        }
        // One sol later the sun is back.
        let a = site.sun_w(0.0);
        let b = site.sun_w(SOL_S);
        assert!((a - b).norm() < 1e-9);
    }

    /// SIM-19: the morning sun is in the east (azimuth in (0, 180) deg, `y_W > 0`), the
    /// afternoon sun in the west; elevation rises through the morning.
    #[test]
    fn sim_19_morning_sun_in_the_east() {
        for (lat, ls) in [(-14.6, 0.0), (4.6, 90.0), (-30.0, 270.0)] {
            let am = sun_direction_w(lat, ls, 9.0);
            let pm = sun_direction_w(lat, ls, 15.0);
            let (e_am, az_am) = elevation_azimuth(&am);
            let (e_pm, az_pm) = elevation_azimuth(&pm);
            assert!(am.y > 0.0 && az_am > 0.0 && az_am < std::f64::consts::PI);
            assert!(pm.y < 0.0 && az_pm < 0.0);
            // Symmetric about noon.
            assert!((e_am - e_pm).abs() < 1e-12);
            let later = sun_direction_w(lat, ls, 9.5);
            assert!(elevation_azimuth(&later).0 > e_am);
        }
    }
}
