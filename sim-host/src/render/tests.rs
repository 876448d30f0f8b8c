//! Tests of the renderer (requirements SIM-R1 ... SIM-R8 in docs/requirements.md).

use super::*;
use crate::devices::hazcam_calibration;
use rover_hal::IMAGE_PIXELS;
use std::sync::{Arc, OnceLock};

const W: usize = IMAGE_WIDTH_PX;
const H: usize = IMAGE_HEIGHT_PX;

/// The default texture, generated once for all tests.
fn texture() -> Arc<AlbedoTexture> {
    static TEXTURE: OnceLock<Arc<AlbedoTexture>> = OnceLock::new();
    TEXTURE
        .get_or_init(|| Arc::new(AlbedoTexture::new(TextureParams::default())))
        .clone()
}

fn mat_mul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|m| a[i][m] * b[m][j]).sum();
        }
    }
    c
}

/// `R_WR` from yaw, pitch, roll (z-y-x, rover frame x forward, y right, z down).
fn rot_zyx(yaw: f64, pitch: f64, roll: f64) -> [[f64; 3]; 3] {
    let (sy, cy) = yaw.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sr, cr) = roll.sin_cos();
    let rz = [[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]];
    let ry = [[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]];
    let rx = [[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]];
    mat_mul(rz, mat_mul(ry, rx))
}

fn buffers() -> (Vec<u8>, Vec<u8>) {
    (vec![0u8; IMAGE_PIXELS], vec![0u8; IMAGE_PIXELS])
}

fn quiet(exposure_dn: f64, ambient: f64) -> RenderSettings {
    RenderSettings {
        exposure_dn,
        ambient,
        noise_sigma_dn: 0.0,
        ..RenderSettings::default()
    }
}

const ZENITH_SUN: Sun = Sun {
    direction_w: [0.0, 0.0, -1.0],
};

/// Flat ground at height 0, albedo 0.6 with Gaussian dark dots (sigma 1.2 cm) at `dots`.
struct Dots {
    dots: Vec<[f64; 2]>,
}

impl TerrainSurface for Dots {
    fn height_m(&self, _x: f64, _y: f64) -> f64 {
        0.0
    }
    fn albedo(&self, x: f64, y: f64) -> f64 {
        let s2 = 2.0 * 0.012f64.powi(2);
        let dark: f64 = self
            .dots
            .iter()
            .map(|d| (-((x - d[0]).powi(2) + (y - d[1]).powi(2)) / s2).exp())
            .sum();
        0.6 - 0.5 * dark.min(1.0)
    }
}
impl FilteredAlbedo for Dots {}

/// Intensity-weighted centroid of the darkening below `background` within `r` px of `guess`.
fn dark_centroid(img: &[u8], guess: [f64; 2], r: i64, background: f64) -> [f64; 2] {
    let (mut sw, mut su, mut sv) = (0.0, 0.0, 0.0);
    let (gu, gv) = (guess[0].round() as i64, guess[1].round() as i64);
    for v in (gv - r).max(0)..=(gv + r).min(H as i64 - 1) {
        for u in (gu - r).max(0)..=(gu + r).min(W as i64 - 1) {
            let w = (background - f64::from(img[v as usize * W + u as usize])).max(0.0);
            sw += w;
            su += w * u as f64;
            sv += w * v as f64;
        }
    }
    assert!(sw > 100.0, "no marker near {guess:?}");
    [su / sw, sv / sw]
}

/// SIM-R1: a dark dot at a known ground point lands on the pixel the pinhole model predicts,
/// in both cameras, within 0.5 px (prediction computed here from the calibration, independently
/// of the renderer's own projection).
#[test]
fn sim_r1_marker_lands_on_predicted_pixel_in_both_cameras() {
    let calib = hazcam_calibration();
    let r_wr = rot_zyx(0.5, 0.04, -0.03);
    let p_r = [3.0, -2.0, -0.25];
    // Left camera pose: R_WK = R_WR R_RK, C = p_R + R_WR t.
    let r_wk = mat_mul(r_wr, calib.rot_rover_from_camera);
    let t = calib.pos_camera_in_rover_m;
    let c: Vec<f64> = (0..3)
        .map(|i| p_r[i] + (0..3).map(|m| r_wr[i][m] * t[m]).sum::<f64>())
        .collect();
    // Dots at several ranges and bearings (in the rover frame, then to W).
    let offsets = [
        [0.8, -0.3],
        [1.2, 0.25],
        [1.8, -0.6],
        [2.6, 0.5],
        [1.0, 0.0],
    ];
    let dots: Vec<[f64; 2]> = offsets
        .iter()
        .map(|o| {
            [
                p_r[0] + r_wr[0][0] * o[0] + r_wr[0][1] * o[1],
                p_r[1] + r_wr[1][0] * o[0] + r_wr[1][1] * o[1],
            ]
        })
        .collect();
    let surface = Dots { dots: dots.clone() };
    let settings = quiet(300.0, 0.0);
    let mut renderer = StereoRenderer::new(calib, settings);
    let pose = CameraPose::from_rover(r_wr, p_r, &calib);
    let (mut left, mut right) = buffers();
    renderer
        .render(&surface, &pose, &ZENITH_SUN, 0, &mut left, &mut right)
        .unwrap();
    // The ground is level, so the shade is cos(0) = 1 everywhere: background = 300 * 0.6.
    let background = 300.0 * 0.6 - 0.5;
    let mut worst: f64 = 0.0;
    for d in &dots {
        let pw = [d[0] - c[0], d[1] - c[1], 0.0 - c[2]];
        let pk: Vec<f64> = (0..3)
            .map(|j| (0..3).map(|i| r_wk[i][j] * pw[i]).sum())
            .collect();
        let predict = |x: f64| {
            [
                calib.cx_px + calib.fx_px * x / pk[2],
                calib.cy_px + calib.fy_px * pk[1] / pk[2],
            ]
        };
        let want_l = predict(pk[0]);
        let want_r = predict(pk[0] - calib.baseline_m);
        let got_l = dark_centroid(&left, want_l, 25, background);
        let got_r = dark_centroid(&right, want_r, 25, background);
        for (got, want) in [(got_l, want_l), (got_r, want_r)] {
            let e = ((got[0] - want[0]).powi(2) + (got[1] - want[1]).powi(2)).sqrt();
            worst = worst.max(e);
            assert!(e < 0.5, "dot {d:?}: at {got:?}, predicted {want:?}");
        }
    }
    println!("SIM-R1 worst marker error {worst:.3} px");
}

/// SIM-R2: looking straight down at level ground (a fronto-parallel plane at depth Z), the right
/// image is the left one shifted by the disparity `d = f_x B / Z` (here 16 px).
#[test]
fn sim_r2_fronto_parallel_right_is_left_shifted_by_disparity() {
    let calib = hazcam_calibration();
    let disparity = 16.0;
    let depth = calib.fx_px * calib.baseline_m / disparity;
    // Camera x = east, y = south, z = down.
    let pose = CameraPose {
        rot_world_from_camera: [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
        pos_world_m: [1.3, -0.7, -depth],
    };
    let surface = TexturedSurface::new(HeightFn(|_x: f64, _y: f64| 0.0), texture());
    let mut renderer = StereoRenderer::new(calib, quiet(500.0, 0.3));
    let (mut left, mut right) = buffers();
    let stats = renderer
        .render_point_sampled(&surface, &pose, &ZENITH_SUN, 0, &mut left, &mut right)
        .unwrap();
    assert_eq!(stats.sky_pixels, [0, 0]);
    let d = disparity as usize;
    let (mut max_diff, mut sum_diff, mut n) = (0i32, 0i64, 0i64);
    let mut shifted_wrong = 0i64;
    for v in 0..H {
        for u in 0..W - d - 1 {
            let r = i32::from(right[v * W + u]);
            let diff = (r - i32::from(left[v * W + u + d])).abs();
            max_diff = max_diff.max(diff);
            sum_diff += i64::from(diff);
            shifted_wrong += i64::from((r - i32::from(left[v * W + u + d + 1])).abs());
            n += 1;
        }
    }
    let mean = sum_diff as f64 / n as f64;
    println!("SIM-R2 max |diff| {max_diff} DN, mean {mean:.4} DN");
    assert!(max_diff <= 1, "max diff {max_diff}");
    assert!(mean < 0.05);
    // One pixel off is clearly worse: the test can tell the disparity.
    assert!(shifted_wrong as f64 / n as f64 > 20.0 * mean.max(0.05));
}

/// SIM-R3: the same inputs give identical bytes, whatever the number of threads; another noise
/// seed or texture seed gives other images; the texture is a function of its seed.
#[test]
fn sim_r3_determinism() {
    let calib = hazcam_calibration();
    let surface = TexturedSurface::new(HeightFn(|x: f64, y: f64| 0.05 * (x + 0.5 * y)), texture());
    let pose = CameraPose::from_rover(rot_zyx(1.0, 0.02, 0.0), [5.0, 2.0, -0.4], &calib);
    let sun = Sun::from_azimuth_elevation(2.0, 0.6);
    let render = |seed: u64| {
        let mut renderer = StereoRenderer::new(calib, RenderSettings::default());
        let (mut l, mut r) = buffers();
        renderer
            .render(&surface, &pose, &sun, seed, &mut l, &mut r)
            .unwrap();
        (l, r)
    };
    let a = render(7);
    let b = render(7);
    assert!(a == b);
    let single = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| render(7));
    assert!(a == single);
    let c = render(8);
    assert!(a.0 != c.0 && a.1 != c.1);
    // Left and right noise differ.
    assert!(a.0 != a.1);
    // Texture: same seed same values, other seed other values.
    let small = |seed| {
        AlbedoTexture::new(TextureParams {
            seed,
            size_log2: 8,
            ..TextureParams::default()
        })
    };
    let (t1, t2, t3) = (small(3), small(3), small(4));
    let points: Vec<(f64, f64)> = (0..500)
        .map(|k| (0.013 * k as f64, 0.007 * k as f64))
        .collect();
    assert!(points
        .iter()
        .all(|&(x, y)| t1.albedo(x, y) == t2.albedo(x, y)));
    let differ = points
        .iter()
        .filter(|&&(x, y)| (t1.albedo(x, y) - t3.albedo(x, y)).abs() > 0.01)
        .count();
    assert!(differ > 300);
}

/// SIM-R4: the image noise is Gaussian with the configured standard deviation (plus the 1/12
/// DN^2 of quantization), zero mean, independent between pixels and between the two cameras.
#[test]
fn sim_r4_noise_statistics_match_the_parameter() {
    let calib = hazcam_calibration();
    let flat = HeightFn(|_x: f64, _y: f64| 0.0);
    // Albedo 0.5, shade 1 (sun at zenith, level ground), exposure 200: exactly 100 DN.
    let pose = CameraPose::from_rover(rot_zyx(0.3, 0.0, 0.0), [0.0, 0.0, -0.25], &calib);
    let mut renderer = StereoRenderer::new(calib, quiet(200.0, 0.0));
    let (mut l, mut r) = buffers();
    renderer
        .render(&flat, &pose, &ZENITH_SUN, 1, &mut l, &mut r)
        .unwrap();
    assert!(l.iter().chain(r.iter()).all(|&p| p == 100));
    for sigma in [1.0, 3.0, 5.0] {
        renderer.set_settings(RenderSettings {
            noise_sigma_dn: sigma,
            ..quiet(200.0, 0.0)
        });
        renderer
            .render(&flat, &pose, &ZENITH_SUN, 42, &mut l, &mut r)
            .unwrap();
        let e = |img: &[u8]| -> Vec<f64> { img.iter().map(|&p| f64::from(p) - 100.0).collect() };
        let (el, er) = (e(&l), e(&r));
        let n = el.len() as f64;
        let expected_sd = (sigma * sigma + 1.0 / 12.0).sqrt();
        for img in [&el, &er] {
            let mean = img.iter().sum::<f64>() / n;
            let sd = (img.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
            println!(
                "SIM-R4 sigma {sigma}: mean {mean:.4}, sd {sd:.4} (expected {expected_sd:.4})"
            );
            assert!(mean.abs() < 0.02 * sigma.max(1.0));
            assert!((sd / expected_sd - 1.0).abs() < 0.02);
            // Fraction of rounded values beyond 1.5 sigma - 0.5 DN, that is of noise beyond
            // 1.5 sigma (sigma = 1, 3, 5 puts 1.5 sigma half-way between integers): 13.36 %.
            let tail = img.iter().filter(|v| v.abs() > 1.5 * sigma).count() as f64 / n;
            assert!((tail - 0.1336).abs() < 0.004, "tail {tail}");
        }
        let corr = |a: &[f64], b: &[f64]| {
            let s: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
            s / (a.iter().map(|x| x * x).sum::<f64>() * b.iter().map(|x| x * x).sum::<f64>()).sqrt()
        };
        assert!(corr(&el, &er).abs() < 0.01);
        assert!(corr(&el[..el.len() - 1], &el[1..]).abs() < 0.01);
        assert!(corr(&el[..el.len() - W], &el[W..]).abs() < 0.01);
    }
}

/// Per 32x32 cell, the largest Forstner/Harris corner strength (smaller eigenvalue of the
/// structure tensor summed over 5x5 pixels), DN^2.
fn cell_corner_strength(img: &[u8]) -> Vec<f64> {
    let g = |u: usize, v: usize| f64::from(img[v * W + u]);
    let mut gxx = vec![0.0; W * H];
    let mut gyy = vec![0.0; W * H];
    let mut gxy = vec![0.0; W * H];
    for v in 1..H - 1 {
        for u in 1..W - 1 {
            let gx = 0.5 * (g(u + 1, v) - g(u - 1, v));
            let gy = 0.5 * (g(u, v + 1) - g(u, v - 1));
            gxx[v * W + u] = gx * gx;
            gyy[v * W + u] = gy * gy;
            gxy[v * W + u] = gx * gy;
        }
    }
    let mut cells = Vec::new();
    for cv in 0..H / 32 {
        for cu in 0..W / 32 {
            let mut best: f64 = 0.0;
            for v in (cv * 32).max(3)..(cv * 32 + 32).min(H - 3) {
                for u in (cu * 32).max(3)..(cu * 32 + 32).min(W - 3) {
                    let (mut a, mut b, mut c) = (0.0, 0.0, 0.0);
                    for dv in 0..5 {
                        for du in 0..5 {
                            let i = (v + dv - 2) * W + u + du - 2;
                            a += gxx[i];
                            b += gyy[i];
                            c += gxy[i];
                        }
                    }
                    let lambda_min = 0.5 * (a + b) - (0.25 * (a - b).powi(2) + c * c).sqrt();
                    best = best.max(lambda_min);
                }
            }
            cells.push(best);
        }
    }
    cells
}

/// SIM-R5: an image of the textured yard has corner structure everywhere: in at least 90 % of
/// the 32x32 cells the strongest corner is several times stronger than noise alone gives; the
/// texture has contrast at the centimetre to metre scales a hazcam resolves at 0.5-5 m.
#[test]
fn sim_r5_textured_yard_has_corners_everywhere() {
    let calib = hazcam_calibration();
    let sun = Sun::from_azimuth_elevation(2.4, 0.7);
    let pose = CameraPose::from_rover(rot_zyx(0.2, 0.0, 0.0), [1.0, 1.0, -0.25], &calib);
    let mut renderer = StereoRenderer::new(calib, RenderSettings::default());
    let (mut l, mut r) = buffers();
    // Noise alone (uniform albedo) sets the floor.
    renderer
        .render(
            &HeightFn(|_x: f64, _y: f64| 0.0),
            &pose,
            &sun,
            3,
            &mut l,
            &mut r,
        )
        .unwrap();
    let floor = cell_corner_strength(&l);
    let mut sorted = floor.clone();
    sorted.sort_by(f64::total_cmp);
    let noise_level = sorted[sorted.len() - 1];
    let yard = TexturedSurface::new(HeightFn(|_x: f64, _y: f64| 0.0), texture());
    renderer
        .render(&yard, &pose, &sun, 3, &mut l, &mut r)
        .unwrap();
    for img in [&l, &r] {
        let cells = cell_corner_strength(img);
        let threshold = 5.0 * noise_level;
        let strong = cells.iter().filter(|&&c| c > threshold).count();
        let fraction = strong as f64 / cells.len() as f64;
        println!(
            "SIM-R5 noise floor {noise_level:.1} DN^2, {:.1} % of cells above {threshold:.1}",
            100.0 * fraction
        );
        assert!(fraction >= 0.9);
    }
    // Texture contrast at 1 cm, 5 cm, 20 cm and 1 m separations.
    let t = texture();
    let mean: f64 = (0..10_000)
        .map(|k| t.albedo(0.0137 * k as f64, 0.0071 * k as f64))
        .sum::<f64>()
        / 1e4;
    assert!((mean - 0.25).abs() < 0.04, "mean albedo {mean}");
    for lag in [0.01, 0.05, 0.2, 1.0] {
        let rms = ((0..10_000)
            .map(|k| {
                let (x, y) = (0.0137 * k as f64, 0.0071 * k as f64);
                (t.albedo(x + lag, y) - t.albedo(x, y)).powi(2)
            })
            .sum::<f64>()
            / 1e4)
            .sqrt();
        println!("SIM-R5 albedo rms difference at {lag} m: {rms:.4}");
        assert!(rms > 0.02, "lag {lag}: {rms}");
    }
}

/// SIM-R6: Lambertian shading `exposure * albedo * (ambient + (1 - ambient) cos i)` on level
/// ground and on a 10 deg slope facing the sun; pixels that see no terrain show the sky value.
#[test]
fn sim_r6_lambert_shading_and_sky() {
    let calib = hazcam_calibration();
    let (exposure, ambient, albedo) = (400.0, 0.3, 0.5);
    let mut renderer = StereoRenderer::new(calib, quiet(exposure, ambient));
    let sun = Sun::from_azimuth_elevation(std::f64::consts::PI, 30f64.to_radians());
    let (mut l, mut r) = buffers();
    let centre = |img: &[u8]| f64::from(img[240 * W + 320]);
    let level = HeightFn(|_x: f64, _y: f64| 0.0);
    let pose = CameraPose::from_rover(rot_zyx(0.0, 0.0, 0.0), [0.0, 0.0, -0.25], &calib);
    renderer
        .render(&level, &pose, &sun, 0, &mut l, &mut r)
        .unwrap();
    let want = exposure * albedo * (ambient + (1.0 - ambient) * 0.5);
    assert!((centre(&l) - want).abs() <= 0.5 && (centre(&r) - want).abs() <= 0.5);
    // A slope rising to the north faces the southern sun: incidence 90 - 40 deg.
    let slope = 10f64.to_radians();
    let rising = HeightFn(move |x: f64, _y: f64| slope.tan() * x);
    renderer
        .render(&rising, &pose, &sun, 0, &mut l, &mut r)
        .unwrap();
    let want = exposure * albedo * (ambient + (1.0 - ambient) * 40f64.to_radians().sin());
    assert!((centre(&l) - want).abs() <= 0.5, "{} vs {want}", centre(&l));
    // Rover pitched 55 deg nose up: the optical axis is 10 deg above the horizon.
    let up = CameraPose::from_rover(
        rot_zyx(0.0, 55f64.to_radians(), 0.0),
        [0.0, 0.0, -0.25],
        &calib,
    );
    let stats = renderer
        .render(&level, &up, &sun, 0, &mut l, &mut r)
        .unwrap();
    assert!(stats.sky_pixels[0] > 100 * W && stats.sky_pixels[1] > 100 * W);
    let sky = renderer.settings().sky_dn as u8;
    assert!(l[..W * 50].iter().all(|&p| p == sky));
    assert!(l[W * (H - 20)..].iter().all(|&p| p != sky));
}

/// SIM-R7: every pixel that sees terrain is rendered (no holes or missing mesh at the image
/// borders) for both cameras, on level ground, 10 deg slopes up, down and across, and bumpy
/// ground, at several headings.
#[test]
fn sim_r7_ground_covers_every_pixel() {
    let calib = hazcam_calibration();
    let mut renderer = StereoRenderer::new(calib, quiet(400.0, 0.3));
    let sun = Sun::from_azimuth_elevation(1.0, 0.8);
    let (mut l, mut r) = buffers();
    let s = 10f64.to_radians().tan();
    let terrains: Vec<Box<dyn Fn(f64, f64) -> f64 + Sync>> = vec![
        Box::new(|_x, _y| 0.0),
        Box::new(move |x, _y| s * x),
        Box::new(move |x, _y| -s * x),
        Box::new(move |_x, y| s * y),
        Box::new(|x, y| {
            0.05 * (3.0 * x).sin() * (2.0 * y).cos() + 0.02 * (11.0 * x + 7.0 * y).sin()
        }),
    ];
    for (k, height) in terrains.iter().enumerate() {
        let surface = HeightFn(height);
        for yaw in [0.0, 1.3, -2.5] {
            // The rover sits on the ground: pitch and roll follow the local slope.
            let ground = height(0.0, 0.0);
            // (Slope averaged over the rover's size.)
            let gx = height(0.5, 0.0) - height(-0.5, 0.0);
            let gy = height(0.0, 0.5) - height(0.0, -0.5);
            let (sy, cy) = f64::sin_cos(yaw);
            let pitch = (gx * cy + gy * sy).atan();
            let roll = -(-gx * sy + gy * cy).atan();
            let pose = CameraPose::from_rover(
                rot_zyx(yaw, pitch, roll),
                [0.0, 0.0, -ground - 0.25],
                &calib,
            );
            let stats = renderer
                .render(&surface, &pose, &sun, 0, &mut l, &mut r)
                .unwrap();
            assert_eq!(stats.sky_pixels, [0, 0], "terrain {k}, yaw {yaw}");
        }
    }
}

/// SIM-R8: bad inputs are refused with an error value.
#[test]
fn sim_r8_bad_input_is_refused() {
    let calib = hazcam_calibration();
    let flat = HeightFn(|_x: f64, _y: f64| 0.0);
    let pose = CameraPose::from_rover(rot_zyx(0.0, 0.0, 0.0), [0.0, 0.0, -0.25], &calib);
    let mut renderer = StereoRenderer::new(calib, RenderSettings::default());
    let (mut l, mut r) = buffers();
    let mut short = vec![0u8; 10];
    assert!(matches!(
        renderer.render(&flat, &pose, &ZENITH_SUN, 0, &mut short, &mut r),
        Err(RenderError::BufferSize { .. })
    ));
    let mut bad = pose;
    bad.pos_world_m[1] = f64::NAN;
    assert_eq!(
        renderer.render(&flat, &bad, &ZENITH_SUN, 0, &mut l, &mut r),
        Err(RenderError::BadPose)
    );
    let mut skew = pose;
    skew.rot_world_from_camera[0][0] = 2.0;
    assert_eq!(
        renderer.render(&flat, &skew, &ZENITH_SUN, 0, &mut l, &mut r),
        Err(RenderError::BadPose)
    );
    let dark = Sun {
        direction_w: [0.0; 3],
    };
    assert_eq!(
        renderer.render(&flat, &pose, &dark, 0, &mut l, &mut r),
        Err(RenderError::BadSun)
    );
    renderer.set_settings(RenderSettings {
        noise_sigma_dn: f64::NAN,
        ..RenderSettings::default()
    });
    assert_eq!(
        renderer.render(&flat, &pose, &ZENITH_SUN, 0, &mut l, &mut r),
        Err(RenderError::BadSettings)
    );
    let mut broken = calib;
    broken.fx_px = 0.0;
    let mut renderer = StereoRenderer::new(broken, RenderSettings::default());
    assert_eq!(
        renderer.render(&flat, &pose, &ZENITH_SUN, 0, &mut l, &mut r),
        Err(RenderError::BadCalibration)
    );
}

/// The hazcam calibration and true lenses drawn from the lens tolerances with `seed` (the focal
/// and principal-point arguments of `draw_truth` as SIM-LENS-4 has always used them).
fn drawn_lenses(seed: u64) -> (StereoCalibration, rover_hal::LensCalibration) {
    use crate::sensors::hazcam_lens;
    use rand::SeedableRng;
    let calib = hazcam_calibration();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let truth = hazcam_lens::draw_truth(
        &hazcam_lens::nominal_lens(),
        &calib,
        [0.002, -0.001],
        [0.3, -0.4],
        &hazcam_lens::LensTolerances::default(),
        &mut rng,
    );
    (calib, truth)
}

/// SIM-LENS-4: through the wide-angle lenses (true lenses with drawn errors), a dark dot at a
/// known ground point lands on the raw pixel the lens model predicts (projection computed here
/// with `sensors::hazcam_lens::project`, independently of the rig's inverse map), in both cameras,
/// within 0.5 px, including dots far off axis where the distortion moves them by tens of
/// pixels.
#[test]
fn sim_lens_4_marker_lands_on_predicted_raw_pixel() {
    use crate::sensors::hazcam_lens;
    let (calib, truth) = drawn_lenses(9);
    let r_wr = rot_zyx(0.2, 0.03, -0.02);
    let p_r = [1.0, 2.0, -0.2];
    let r_wk = mat_mul(r_wr, calib.rot_rover_from_camera);
    let t = calib.pos_camera_in_rover_m;
    let c: Vec<f64> = (0..3)
        .map(|i| p_r[i] + (0..3).map(|m| r_wr[i][m] * t[m]).sum::<f64>())
        .collect();
    // Ahead, and far to the sides near the raw images' borders.
    let offsets = [
        [0.9, 0.0],
        [1.5, 0.35],
        [0.75, -0.6],
        [0.8, 0.62],
        [2.2, -1.7],
        [1.3, 1.1],
    ];
    let dots: Vec<[f64; 2]> = offsets
        .iter()
        .map(|o| {
            [
                p_r[0] + r_wr[0][0] * o[0] + r_wr[0][1] * o[1],
                p_r[1] + r_wr[1][0] * o[0] + r_wr[1][1] * o[1],
            ]
        })
        .collect();
    let surface = Dots { dots: dots.clone() };
    let mut rig = super::lens_rig::LensRig::new(truth, &calib, quiet(300.0, 0.0)).unwrap();
    let pose = CameraPose::from_rover(r_wr, p_r, &calib);
    let (mut left, mut right) = buffers();
    rig.render(&surface, &pose, &ZENITH_SUN, 0, &mut left, &mut right)
        .unwrap();
    let background = 300.0 * 0.6 - 0.5;
    let (mut worst, mut largest_shift): (f64, f64) = (0.0, 0.0);
    for d in &dots {
        let pw = [d[0] - c[0], d[1] - c[1], 0.0 - c[2]];
        let pk: Vec<f64> = (0..3)
            .map(|j| (0..3).map(|i| r_wk[i][j] * pw[i]).sum())
            .collect();
        let want_l = hazcam_lens::project(&truth.left, [pk[0], pk[1], pk[2]]).unwrap();
        let want_r =
            hazcam_lens::project(&truth.right, [pk[0] - calib.baseline_m, pk[1], pk[2]]).unwrap();
        let pinhole_l = [
            calib.cx_px + calib.fx_px * pk[0] / pk[2],
            calib.cy_px + calib.fy_px * pk[1] / pk[2],
        ];
        largest_shift =
            largest_shift.max((want_l[0] - pinhole_l[0]).hypot(want_l[1] - pinhole_l[1]));
        for (img, want) in [(&left, want_l), (&right, want_r)] {
            assert!(
                want[0] > 12.0 && want[0] < 627.0 && want[1] > 12.0 && want[1] < 467.0,
                "dot {d:?} at {want:?} is not inside the image"
            );
            let got = dark_centroid(img, want, 12, background);
            let e = (got[0] - want[0]).hypot(got[1] - want[1]);
            worst = worst.max(e);
            assert!(e < 0.5, "dot {d:?}: at {got:?}, predicted {want:?}");
        }
    }
    println!(
        "SIM-LENS-4 worst raw marker error {worst:.3} px (largest lens shift from the pinhole \
         position {largest_shift:.1} px)"
    );
    assert!(largest_shift > 20.0, "{largest_shift}");
}

/// SIM-LENS-5: the lens rig shades only the pinhole pixels its raw images read (the used-pixel
/// masks); the raw images are byte-identical to shading every pixel, on the textured, sloped
/// yard with true lenses, image noise on, seen from a tilted pose.
#[test]
fn sim_lens_5_used_pixel_masks_change_no_raw_byte() {
    let (calib, truth) = drawn_lenses(5);
    let surface = TexturedSurface::new(HeightFn(|x: f64, y: f64| 0.05 * (x + 0.5 * y)), texture());
    let pose = CameraPose::from_rover(rot_zyx(0.3, -0.35, 0.05), [0.4, -0.2, -0.3], &calib);
    let settings = RenderSettings::default();
    assert!(settings.noise_sigma_dn > 0.0);
    let mut rig = super::lens_rig::LensRig::new(truth, &calib, settings).unwrap();
    let (mut l0, mut r0) = buffers();
    let masked = rig
        .render(&surface, &pose, &ZENITH_SUN, 7, &mut l0, &mut r0)
        .unwrap();
    rig.shade_every_pixel();
    let (mut l1, mut r1) = buffers();
    let full = rig
        .render(&surface, &pose, &ZENITH_SUN, 7, &mut l1, &mut r1)
        .unwrap();
    assert!(l0 == l1 && r0 == r1, "raw images differ");
    assert_eq!(masked, full);
    // The scene is not trivial: textured ground in both images.
    let spread = |img: &[u8]| img.iter().max().unwrap() - img.iter().min().unwrap();
    assert!(spread(&l0) > 50 && spread(&r0) > 50);
}
