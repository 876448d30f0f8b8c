//! VO-14: stereo matching on real images (Middlebury 2014 "motorcycle", exported by
//! `tools/middlebury_eval.py`). Ignored by default: it needs `VO_MIDDLEBURY_DIR`.

use super::features::{select_with_min_distance, ForstnerDetector, END_ROW, FIRST_ROW};
use super::image::Image;
use super::stereo::match_along_row;
use super::VoConfig;
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

#[test]
#[ignore = "needs VO_MIDDLEBURY_DIR from tools/middlebury_eval.py"]
fn vo_14_middlebury_disparity() {
    let dir = std::env::var("VO_MIDDLEBURY_DIR").expect("set VO_MIDDLEBURY_DIR");
    let dir = Path::new(&dir);
    let left = read_pgm(&dir.join("left.pgm"));
    let right = read_pgm(&dir.join("right.pgm"));
    let truth: Vec<f32> = std::fs::read(dir.join("disparity.f32"))
        .unwrap()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(truth.len(), IMAGE_PIXELS);
    let (l, r) = (Image::new(&left).unwrap(), Image::new(&right).unwrap());
    let config = VoConfig::default();
    let mut detector = Box::new(ForstnerDetector::default());
    for y in FIRST_ROW..END_ROW {
        detector.process_row(&l, y, &config);
    }
    detector.sort_candidates();
    let mut selected = [(0u16, 0u16); 200];
    let n = select_with_min_distance(detector.candidates(), config.min_distance_px, &mut selected);
    let mut errors = Vec::new();
    let mut matched = 0;
    for &(x, y) in &selected[..n] {
        let Ok((xr, _yr)) = match_along_row(&l, &r, f64::from(x), f64::from(y), &config) else {
            continue;
        };
        matched += 1;
        let gt = truth[usize::from(y) * IMAGE_WIDTH_PX + usize::from(x)];
        if gt.is_finite() {
            errors.push((f64::from(x) - xr - f64::from(gt)).abs());
        }
    }
    errors.sort_by(|a, b| a.total_cmp(b));
    let median = errors[errors.len() / 2];
    let within_1px = errors.iter().filter(|&&e| e <= 1.0).count() as f64 / errors.len() as f64;
    let p90 = errors[errors.len() * 9 / 10];
    println!(
        "VO-14 Middlebury motorcycle: {n} features, {matched} stereo matches, {} with ground \
         truth; median disparity error {median:.3} px, 90th percentile {p90:.3} px, within 1 px \
         {:.1} %",
        errors.len(),
        within_1px * 100.0
    );
    assert!(matched >= n / 2, "{matched} of {n} matched");
    assert!(median < 0.5, "median disparity error {median} px");
}
