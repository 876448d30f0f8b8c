//! Builds the rectification map of a hazcam-class wide-angle lens and rectifies N raw pairs
//! (`pairs`), or only builds the map (`none`), for instruction counting on the host:
//! `valgrind --tool=callgrind target/release/examples/rectify_count pairs 4` minus the same run
//! with `none` gives x86-64 instructions per pair (see `docs/vo.md`, "Rectification").
// A host tool, not flight code: the flight crate's lints for panics and docs do not apply.
#![allow(missing_docs, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use fsw::rectify::*;
use rover_hal::{LensCalibration, RawCamera, StereoCalibration, StereoFrame, IMAGE_PIXELS};
use std::hint::black_box;

fn main() {
    let which = std::env::args().nth(1).unwrap_or_default();
    let n: u32 = std::env::args()
        .nth(2)
        .map(|s| s.parse().unwrap())
        .unwrap_or(4);
    let camera = RawCamera {
        fx_px: 390.3,
        fy_px: 389.2,
        cx_px: 312.4,
        cy_px: 247.1,
        k1: -0.2834,
        k2: 0.07396,
        k3: 0.0,
        p1: 0.000_194,
        p2: 0.000_018,
        rot_raw_from_rect: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    };
    let lens = LensCalibration {
        left: camera,
        right: camera,
    };
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let rect = StereoCalibration {
        fx_px: 384.791_625_3,
        fy_px: 384.079_510_6,
        cx_px: 319.5,
        cy_px: 239.5,
        baseline_m: 0.084,
        rot_rover_from_camera: [[0.0, -h, h], [1.0, 0.0, 0.0], [0.0, h, h]],
        pos_camera_in_rover_m: [0.2, 0.0, -0.6],
    };
    let mut memory = ImageMemory {
        map: vec![MapNode::default(); MAP_NODES],
        left: vec![0u8; IMAGE_PIXELS],
        right: vec![0u8; IMAGE_PIXELS],
    };
    let raw: Vec<u8> = (0..IMAGE_PIXELS)
        .map(|i| ((i as u64 * 2_654_435_761) >> 13) as u8)
        .collect();
    let mut rectifier = Rectifier::new(RectifyConfig::default());
    rectifier.build(&lens, &rect, &mut memory).unwrap();
    if which != "pairs" {
        return;
    }
    for k in 0..n {
        let frame = StereoFrame {
            left: &raw,
            right: &raw,
            capture_t_us: u64::from(k),
            sequence: k,
        };
        rectifier.start(&frame).unwrap();
        while let RectifyProgress::Working { .. } = rectifier.step(&frame, &mut memory, 100) {}
    }
    black_box(&memory.left);
}
