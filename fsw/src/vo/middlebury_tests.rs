//! VO-14 and VO-16: the flight stereo matcher and motion core on real images (Middlebury 2014
//! "motorcycle", and Middlebury 2006 "Aloe" when present), exported by
//! `tools/middlebury_eval.py`. Ignored by default: they need `VO_MIDDLEBURY_DIR`.
//!
//! VO-14 (real): Forstner features of the left image, stereo matched along the rows by the
//! flight matcher, compared with the ground-truth disparity.
//! VO-16 (real feature geometry, SYNTHETIC motion): the ground-truth 3D points at the features
//! of the motorcycle pair, moved by known random rigid motions and seen again with pixel noise
//! and the real stereo errors of the flight matcher; the motion core must recover the motion
//! with a consistent covariance. Only the images, the features and their stereo errors are
//! real; the second view is synthetic.

use super::features::{select_with_min_distance, ForstnerDetector, END_ROW, FIRST_ROW};
use super::image::Image;
use super::motion::{estimate_motion, Correspondence};
use super::stereo::{match_along_row, point_from_pixels, project_right, PinholeStereo};
use super::{StereoRejectCounts, VoConfig, TEMPLATE_HALF};
use crate::types::{Mat3, Vec3};
use nalgebra::Rotation3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rover_hal::{IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX};
use std::{boxed::Box, path::Path, println, string::String, vec::Vec};

/// Reads a binary (P5) 640x480 8-bit PGM.
fn read_pgm(path: &Path) -> Vec<u8> {
    let bytes = std::fs::read(path).unwrap();
    let header = String::from_utf8_lossy(&bytes[..20]).into_owned();
    let mut fields = header.split_ascii_whitespace();
    assert_eq!(fields.next(), Some("P5"));
    let w: usize = fields.next().unwrap().parse().unwrap();
    let h: usize = fields.next().unwrap().parse().unwrap();
    assert_eq!((w, h), (IMAGE_WIDTH_PX, IMAGE_HEIGHT_PX));
    bytes[bytes.len() - IMAGE_PIXELS..].to_vec()
}

fn read_truth(path: &Path) -> Vec<f32> {
    let truth: Vec<f32> = std::fs::read(path)
        .unwrap()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(truth.len(), IMAGE_PIXELS);
    truth
}

fn read_calibration(path: &Path) -> std::collections::HashMap<String, f64> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter_map(|l| {
            let (k, v) = l.split_once('=')?;
            Some((k.trim().into(), v.trim().parse().ok()?))
        })
        .collect()
}

/// One matched feature: left pixel, right pixel, ground-truth disparity (NaN if unknown).
#[derive(Clone, Copy, Debug)]
struct Matched {
    xl: f64,
    yl: f64,
    xr: f64,
    yr: f64,
    truth: f64,
}

/// Statistics of one pair.
struct PairStats {
    features: usize,
    rejected: Vec<(u16, u16)>,
    matched: Vec<Matched>,
    rejects: StereoRejectCounts,
}

fn match_pair(dir: &Path, config: &VoConfig) -> PairStats {
    let left = read_pgm(&dir.join("left.pgm"));
    let right = read_pgm(&dir.join("right.pgm"));
    let truth = read_truth(&dir.join("disparity.f32"));
    let (l, r) = (Image::new(&left).unwrap(), Image::new(&right).unwrap());
    let mut detector = Box::new(ForstnerDetector::default());
    for y in FIRST_ROW..END_ROW {
        detector.process_row(&l, y, config);
    }
    detector.sort_candidates();
    let mut selected = [(0u16, 0u16); 200];
    let n = select_with_min_distance(detector.candidates(), config.min_distance_px, &mut selected);
    let mut matched = Vec::new();
    let mut rejects = StereoRejectCounts::default();
    let mut rejected = Vec::new();
    for &(x, y) in &selected[..n] {
        match match_along_row(&l, &r, f64::from(x), f64::from(y), config) {
            Ok((xr, yr)) => matched.push(Matched {
                xl: f64::from(x),
                yl: f64::from(y),
                xr,
                yr,
                truth: f64::from(truth[usize::from(y) * IMAGE_WIDTH_PX + usize::from(x)]),
            }),
            Err(e) => {
                rejects.count(e);
                rejected.push((x, y));
            }
        }
    }
    PairStats {
        features: n,
        rejected,
        matched,
        rejects,
    }
}

/// Prints the VO-14 figures of one pair; returns (gross errors, range-end matches).
fn report_pair(name: &str, stats: &PairStats, config: &VoConfig) -> (usize, usize) {
    let mut errors = Vec::new();
    let mut range_end = 0;
    for m in &stats.matched {
        let d = m.xl - m.xr;
        // Ends of the searched range: the configured limits, and the largest disparity whose
        // template still fits in the right image.
        let lo = f64::from(config.min_disparity_px);
        let hi = f64::from(config.max_disparity_px).min(m.xl - TEMPLATE_HALF as f64);
        if d < lo + 0.5 || d > hi - 0.5 {
            range_end += 1;
            println!(
                "  {name}: range-end match at ({}, {}): disparity {d:.2}, truth {:.2}",
                m.xl, m.yl, m.truth
            );
        }
        if m.truth.is_finite() {
            errors.push((d - m.truth).abs());
            if (d - m.truth).abs() > 2.0 {
                println!(
                    "  {name}: gross error at ({}, {}): disparity {d:.2}, truth {:.2}",
                    m.xl, m.yl, m.truth
                );
            }
        }
    }
    errors.sort_by(|a, b| a.total_cmp(b));
    let n = errors.len().max(1);
    let median = errors.get(errors.len() / 2).copied().unwrap_or(f64::NAN);
    let p90 = errors
        .get(errors.len() * 9 / 10)
        .copied()
        .unwrap_or(f64::NAN);
    let within_1px = errors.iter().filter(|&&e| e <= 1.0).count();
    let gross = errors.iter().filter(|&&e| e > 2.0).count();
    // Robust standard deviation of the disparity error of the good matches (MAD x 1.4826).
    let mad = median * 1.4826;
    println!(
        "VO-14 {name}: {} features, {} stereo matches, {} with ground truth; disparity error \
         median {median:.3} px (robust sigma {mad:.3} px), 90th percentile {p90:.3} px, within \
         1 px {:.1} %, gross (> 2 px) {gross} ({:.2} %), range-end matches {range_end}; \
         rejected: {:?}",
        stats.features,
        stats.matched.len(),
        errors.len(),
        within_1px as f64 / n as f64 * 100.0,
        gross as f64 / n as f64 * 100.0,
        stats.rejects
    );
    println!(
        "  {name}: gross errors {:.2} % of the {} matched features, {:.2} % of the {} with ground \
         truth",
        gross as f64 / stats.matched.len().max(1) as f64 * 100.0,
        stats.matched.len(),
        gross as f64 / n as f64 * 100.0,
        errors.len()
    );
    (gross, range_end)
}

fn dataset_dirs() -> Vec<(String, std::path::PathBuf)> {
    let dir = std::env::var("VO_MIDDLEBURY_DIR").expect("set VO_MIDDLEBURY_DIR");
    let dir = Path::new(&dir);
    let mut out = std::vec![(String::from("motorcycle"), dir.to_path_buf())];
    let aloe = dir.join("aloe");
    if aloe.join("left.pgm").exists() {
        out.push((String::from("aloe"), aloe));
    }
    out
}

/// The default configuration, or with the stereo rules' settings from `VO_STEREO_RULES`
/// ("left_right_tolerance_px,half_window_px,half_min_std,half_min_correlation[,uniqueness_margin[,left_right_window_px[,left_right_step]]]")
/// to explore them.
fn tuned_config() -> VoConfig {
    let mut config = VoConfig::default();
    if let Ok(rules) = std::env::var("VO_STEREO_RULES") {
        let v: Vec<f64> = rules
            .split(',')
            .map(|x| x.trim().parse().unwrap())
            .collect();
        config.left_right_tolerance_px = v[0];
        config.half_window_px = v[1] as u16;
        config.half_min_std = v[2] as f32;
        config.half_min_correlation = v[3] as f32;
        if let Some(&margin) = v.get(4) {
            config.uniqueness_margin = margin as f32;
        }
        if let Some(&window) = v.get(5) {
            config.left_right_window_px = window as u16;
        }
        if let Some(&step) = v.get(6) {
            config.left_right_step = step as u8;
        }
        println!("stereo rules {rules}");
    }
    config
}

#[test]
#[ignore = "needs VO_MIDDLEBURY_DIR from tools/middlebury_eval.py"]
fn vo_14_middlebury_disparity() {
    let config = tuned_config();
    let mut failures = Vec::new();
    for (name, dir) in dataset_dirs() {
        let stats = match_pair(&dir, &config);
        // For the side-by-side with OpenCV (`tools/middlebury_eval.py --compare`): the flight
        // matcher's features and matches, one line each (xl, yl, xr, yr; NaN when rejected).
        let mut csv = String::from("xl,yl,xr,yr\n");
        for m in &stats.matched {
            csv.push_str(&std::format!("{},{},{:.4},{:.4}\n", m.xl, m.yl, m.xr, m.yr));
        }
        for &(x, y) in &stats.rejected {
            csv.push_str(&std::format!("{x},{y},nan,nan\n"));
        }
        std::fs::write(dir.join("flight_matches.csv"), csv).unwrap();
        let (gross, range_end) = report_pair(&name, &stats, &config);
        let matched = stats.matched.len();
        if matched < stats.features / 2 {
            failures.push(std::format!(
                "{name}: {matched} of {} matched",
                stats.features
            ));
        }
        // Acceptance (VO-14): gross errors at most 3 % of the matched features. The share of
        // the matches with ground truth is printed as well (it is the stricter figure).
        if gross * 100 > 3 * matched {
            failures.push(std::format!("{name}: {gross} gross of {matched} matched"));
        }
        if range_end > 0 {
            failures.push(std::format!("{name}: {range_end} range-end matches"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

/// Median of a chi-square variable with 6 and 3 degrees of freedom.
const CHI2_6_MEDIAN: f64 = 5.348;
const CHI2_3_MEDIAN: f64 = 2.366;

#[test]
#[ignore = "needs VO_MIDDLEBURY_DIR from tools/middlebury_eval.py"]
fn vo_16_middlebury_geometry_synthetic_motion() {
    let dir = std::env::var("VO_MIDDLEBURY_DIR").expect("set VO_MIDDLEBURY_DIR");
    let dir = Path::new(&dir);
    let config = VoConfig::default();
    let stats = match_pair(dir, &config);
    let cal = read_calibration(&dir.join("calibration.txt"));
    // The right camera's principal point is `doffs` to the right of the left one's: shifting
    // the right pixels by -doffs gives the common-principal-point pair of PinholeStereo.
    let doffs = cal["doffs_px"];
    let cam = PinholeStereo {
        fx_px: cal["fx_px"],
        fy_px: cal["fy_px"],
        cx_px: cal["cx_px"],
        cy_px: cal["cy_px"],
        baseline_m: cal["baseline_m"],
    };
    // Real features with truth: truth point, measured frame-0 pixels, real disparity error.
    let mut points = Vec::new();
    for m in stats.matched.iter().filter(|m| m.truth.is_finite()) {
        let truth_px = [m.xl, m.yl, m.xl - m.truth - doffs, m.yl];
        let Ok(p) = point_from_pixels(&cam, truth_px, &config) else {
            continue;
        };
        let measured = [m.xl, m.yl, m.xr - doffs, m.yr];
        let error = (m.xl - m.xr) - m.truth;
        points.push((p.position_m, measured, error));
    }
    println!("VO-16: {} real features with truth", points.len());
    let trials = 300;
    let mut rng = ChaCha8Rng::seed_from_u64(16);
    let noise = Normal::new(0.0, 0.3).unwrap();
    let (mut ok, mut failed) = (0usize, Vec::new());
    let (mut nees6, mut nees_t, mut errs_t) = (Vec::new(), Vec::new(), Vec::new());
    for trial in 0..trials {
        let deg = core::f64::consts::PI / 180.0;
        let axis = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let angle = rng.random_range(0.0..3.0) * deg;
        let rot: Mat3 = Rotation3::new(axis.normalize() * angle).into_inner();
        let trans = Vec3::new(
            rng.random_range(-0.15..0.15),
            rng.random_range(-0.05..0.05),
            rng.random_range(-0.15..0.15),
        );
        let mut pairs: Vec<Correspondence> = Vec::new();
        for &(p0, measured, _) in &points {
            let p1 = rot * p0 + trans;
            let (Some((xl, yl)), Some((xr, _))) = (cam.project_left(&p1), project_right(&cam, &p1))
            else {
                continue;
            };
            // The real disparity error of another feature (independent of frame 0's).
            let other = points[rng.random_range(0..points.len())].2;
            let px1 = [
                xl + noise.sample(&mut rng),
                yl + noise.sample(&mut rng),
                xr - other + noise.sample(&mut rng),
                yl + noise.sample(&mut rng),
            ];
            if !(5.0..635.0).contains(&px1[0]) || !(5.0..475.0).contains(&px1[1]) {
                continue;
            }
            let (Ok(s0), Ok(s1)) = (
                point_from_pixels(&cam, measured, &config),
                point_from_pixels(&cam, px1, &config),
            ) else {
                continue;
            };
            if let Some(c) = Correspondence::new(
                s0.position_m,
                s0.covariance,
                s1.position_m,
                s1.covariance,
                &Mat3::identity(),
            ) {
                pairs.push(c);
            }
        }
        let mut inliers = std::vec![false; pairs.len()];
        let mut scratch = std::vec![0.0; pairs.len()];
        match estimate_motion(&pairs, &config, &mut inliers, &mut scratch) {
            Ok(est) => {
                ok += 1;
                if est.rounds_reverted > 0 {
                    println!("VO-16 trial {trial}: a round was dropped");
                }
                let d_rot = Rotation3::from_matrix_unchecked(rot * est.motion.rotation.transpose())
                    .scaled_axis();
                let d_t = trans - est.motion.translation_m;
                let e = nalgebra::Vector6::new(d_rot.x, d_rot.y, d_rot.z, d_t.x, d_t.y, d_t.z);
                let info = est.covariance.try_inverse().unwrap();
                nees6.push((e.transpose() * info * e)[(0, 0)]);
                let cov_t = est.covariance.fixed_view::<3, 3>(3, 3).into_owned();
                nees_t.push((d_t.transpose() * cov_t.try_inverse().unwrap() * d_t)[(0, 0)]);
                errs_t.push(d_t.norm());
            }
            Err(e) => failed.push((trial, pairs.len(), e)),
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let inside_t = nees_t.iter().filter(|&&d| d <= 7.815).count() as f64 / nees_t.len() as f64;
    let inside_6 = nees6.iter().filter(|&&d| d <= 12.59).count() as f64 / nees6.len() as f64;
    let (m6, mt, me) = (median(&mut nees6), median(&mut nees_t), median(&mut errs_t));
    println!(
        "VO-16 Middlebury geometry, synthetic motion: {ok} of {trials} solved, failures {:?}; \
         translation error median {:.2} mm, max {:.2} mm; NEES 6-dof median {m6:.2} (chi2_6 \
         median {CHI2_6_MEDIAN}), inside the 95 % gate {:.1} %; translation Mahalanobis^2 \
         median {mt:.2} (chi2_3 median {CHI2_3_MEDIAN}), inside the 95 % gate {:.1} %",
        &failed[..failed.len().min(8)],
        me * 1e3,
        errs_t.last().copied().unwrap_or(f64::NAN) * 1e3,
        inside_6 * 100.0,
        inside_t * 100.0
    );
    assert_eq!(ok, trials, "failures {failed:?}");
    assert!(
        (0.5 * CHI2_6_MEDIAN..=2.0 * CHI2_6_MEDIAN).contains(&m6),
        "NEES median {m6}"
    );
    assert!(
        (0.5 * CHI2_3_MEDIAN..=2.0 * CHI2_3_MEDIAN).contains(&mt),
        "translation NEES median {mt}"
    );
}
