//! Tests of the rectification (RECT-1 ... RECT-5).

use super::*;
use std::vec::Vec;

/// The rectified hazcam (fx = 320 / tan(39.75 deg), fy = 240 / tan(32 deg)).
fn rect() -> StereoCalibration {
    let h = core::f64::consts::FRAC_1_SQRT_2;
    StereoCalibration {
        fx_px: 384.791_625_3,
        fy_px: 384.079_510_6,
        cx_px: 319.5,
        cy_px: 239.5,
        baseline_m: 0.084,
        rot_rover_from_camera: [[0.0, -h, h], [1.0, 0.0, 0.0], [0.0, h, h]],
        pos_camera_in_rover_m: [0.2, 0.0, -0.6],
    }
}

/// A wide-angle lens of the simulator's class (EuRoC cam0 coefficients on 640 px), written
/// here independently; `rot_deg` turns the raw camera about its y axis.
fn lens_camera(rot_deg: f64, k3: f64) -> RawCamera {
    let (s, c) = libm::sincos(rot_deg.to_radians());
    RawCamera {
        fx_px: 390.3,
        fy_px: 389.2,
        cx_px: 312.4,
        cy_px: 247.1,
        k1: -0.2834,
        k2: 0.07396,
        k3,
        p1: 0.000_194,
        p2: 0.000_018,
        rot_raw_from_rect: [[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]],
    }
}

fn lens() -> LensCalibration {
    let mut right = lens_camera(0.0, 0.0);
    right.cx_px = 323.3;
    right.cy_px = 252.9;
    right.p1 = -0.000_105;
    LensCalibration {
        left: lens_camera(0.3, 0.0),
        right,
    }
}

fn memory() -> ImageMemory<Vec<MapNode>, Vec<u8>> {
    ImageMemory {
        map: vec![MapNode::default(); MAP_NODES],
        left: vec![0; IMAGE_PIXELS],
        right: vec![0; IMAGE_PIXELS],
    }
}

/// Exact raw position of rectified pixel `(x, y)` (test's own projection).
fn exact_raw(c: &RawCamera, r: &StereoCalibration, x: f64, y: f64) -> [f64; 2] {
    let v = [(x - r.cx_px) / r.fx_px, (y - r.cy_px) / r.fy_px, 1.0];
    let m = &c.rot_raw_from_rect;
    let a = [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2]);
    let (xn, yn) = (a[0] / a[2], a[1] / a[2]);
    let r2 = xn * xn + yn * yn;
    let g = 1.0 + c.k1 * r2 + c.k2 * r2 * r2 + c.k3 * r2 * r2 * r2;
    let xd = xn * g + 2.0 * c.p1 * xn * yn + c.p2 * (r2 + 2.0 * xn * xn);
    let yd = yn * g + c.p1 * (r2 + 2.0 * yn * yn) + 2.0 * c.p2 * xn * yn;
    [c.cx_px + c.fx_px * xd, c.cy_px + c.fy_px * yd]
}

/// Rectified position of raw pixel `(u, v)`: the exact inverse by bisection-free Newton on
/// the test's own projection (finite-difference Jacobian), to 1e-9 px.
fn exact_rect(c: &RawCamera, r: &StereoCalibration, u: f64, v: f64) -> [f64; 2] {
    let (mut x, mut y) = (r.cx_px + (u - c.cx_px), r.cy_px + (v - c.cy_px));
    for _ in 0..60 {
        let p = exact_raw(c, r, x, y);
        let (eu, ev) = (p[0] - u, p[1] - v);
        if eu.abs().max(ev.abs()) < 1e-9 {
            break;
        }
        let h = 1e-4;
        let px = exact_raw(c, r, x + h, y);
        let py = exact_raw(c, r, x, y + h);
        let j = [
            [(px[0] - p[0]) / h, (py[0] - p[0]) / h],
            [(px[1] - p[1]) / h, (py[1] - p[1]) / h],
        ];
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        x -= (j[1][1] * eu - j[0][1] * ev) / det;
        y -= (j[0][0] * ev - j[1][0] * eu) / det;
    }
    [x, y]
}

/// RECT-2: the fixed-point lattice map against the exact lens model at every rectified
/// pixel of both cameras: at most 0.05 px (interpolation between nodes 8 px apart and the
/// 1/256 px node rounding); the bounded inverse finds every node again within 0.01 px.
#[test]
fn rect_2_lattice_error() {
    let (lens, r) = (lens(), rect());
    let mut mem = memory();
    let mut rectifier = Rectifier::new(RectifyConfig::default());
    let stats = rectifier.build(&lens, &r, &mut mem).unwrap();
    println!("RECT-2 map stats {stats:?}");
    assert!(stats.max_round_trip_px < ROUND_TRIP_TOL_PX);
    assert!(stats.max_iterations <= 8, "{}", stats.max_iterations);
    let mut worst: f64 = 0.0;
    for (cam, c) in [lens.left, lens.right].iter().enumerate() {
        let nodes = &mem.map[cam * LATTICE_NODES..(cam + 1) * LATTICE_NODES];
        for y in 0..H {
            for x in 0..W {
                let (i, j) = (x / 8, y / 8);
                let (a, b) = ((x % 8) as f64 / 8.0, (y % 8) as f64 / 8.0);
                let n = |i: usize, j: usize| nodes[j * LATTICE_COLS + i];
                let lerp = |f: fn(&MapNode) -> i32| {
                    let top = f(&n(i, j)) as f64 * (1.0 - a) + f(&n(i + 1, j)) as f64 * a;
                    let bottom =
                        f(&n(i, j + 1)) as f64 * (1.0 - a) + f(&n(i + 1, j + 1)) as f64 * a;
                    (top * (1.0 - b) + bottom * b) / 256.0
                };
                let got = [lerp(|n| n.u), lerp(|n| n.v)];
                let want = exact_raw(c, &r, x as f64, y as f64);
                worst = worst.max((got[0] - want[0]).hypot(got[1] - want[1]));
            }
        }
    }
    println!("RECT-2 worst map error {worst:.4} px");
    assert!(worst < 0.05, "{worst}");
}

/// Pattern of the rectified scene: grey 160 with dark Gaussian dots (sigma 1.6 px) at `dots`,
/// a dark vertical line at x = 100.3 and a horizontal one at y = 400.6 (sigma 1.2 px).
fn scene(x: f64, y: f64, dots: &[[f64; 2]]) -> f64 {
    let mut v = 160.0;
    for d in dots {
        let e = ((x - d[0]).powi(2) + (y - d[1]).powi(2)) / (2.0 * 1.6 * 1.6);
        v -= 110.0 * (-e).exp();
    }
    v -= 80.0 * (-(x - 100.3).powi(2) / (2.0 * 1.2 * 1.2)).exp();
    v -= 80.0 * (-(y - 400.6).powi(2) / (2.0 * 1.2 * 1.2)).exp();
    v.max(0.0)
}

/// The raw image of the scene through camera `c` (each raw pixel takes the scene at its exact
/// rectified position).
fn raw_image(c: &RawCamera, r: &StereoCalibration, dots: &[[f64; 2]]) -> Vec<u8> {
    let mut img = vec![0u8; IMAGE_PIXELS];
    for v in 0..H {
        for u in 0..W {
            let p = exact_rect(c, r, u as f64, v as f64);
            img[v * W + u] = (scene(p[0], p[1], dots) + 0.5) as u8;
        }
    }
    img
}

fn dark_centroid(img: &[u8], at: [f64; 2], radius: i64) -> [f64; 2] {
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    let (cx, cy) = (at[0].round() as i64, at[1].round() as i64);
    for y in cy - radius..=cy + radius {
        for x in cx - radius..=cx + radius {
            let w = (160.0 - f64::from(img[y as usize * W + x as usize])).max(0.0);
            sw += w;
            sx += w * x as f64;
            sy += w * y as f64;
        }
    }
    [sx / sw, sy / sw]
}

/// RECT-1: a synthetic distorted pair (lens with k3 and a 0.3 deg raw rotation on the left)
/// rectified by the work items restores known points and straight lines within 0.3 px: dark
/// dots over the field (corners included) at their rectified positions, a vertical and a
/// horizontal line straight (per-row / per-column centroids from their true position). In the
/// raw images the same dots are displaced by up to tens of pixels.
#[test]
fn rect_1_synthetic_distorted_pair_is_restored() {
    let mut lens = lens();
    lens.left.k3 = -0.004;
    let r = rect();
    let dots = [
        [319.5, 239.5],
        [40.2, 30.7],
        [600.6, 35.1],
        [35.4, 450.2],
        [605.3, 447.8],
        [200.1, 120.9],
        [480.8, 330.3],
    ];
    let raw = [
        raw_image(&lens.left, &r, &dots),
        raw_image(&lens.right, &r, &dots),
    ];
    let mut mem = memory();
    let mut rectifier = Rectifier::new(RectifyConfig::default());
    rectifier.build(&lens, &r, &mut mem).unwrap();
    let frame = StereoFrame {
        left: &raw[0],
        right: &raw[1],
        capture_t_us: 7,
        sequence: 3,
    };
    rectifier.start(&frame).unwrap();
    let mut calls = 0;
    loop {
        calls += 1;
        match rectifier.step(&frame, &mut mem, 100) {
            RectifyProgress::Working { .. } => continue,
            RectifyProgress::Finished(result) => {
                result.unwrap();
                break;
            }
        }
    }
    // 960 rows at `row_cost` units, 100 units per call.
    let per_call = 100usize.div_ceil(usize::from(RectifyConfig::default().row_cost));
    assert_eq!(calls, 960usize.div_ceil(per_call));
    let (mut worst_dot, mut worst_line, mut raw_shift): (f64, f64, f64) = (0.0, 0.0, 0.0);
    for (cam, img) in [&mem.left, &mem.right].into_iter().enumerate() {
        let c = if cam == 0 { &lens.left } else { &lens.right };
        for d in &dots {
            let got = dark_centroid(img, *d, 6);
            worst_dot = worst_dot.max((got[0] - d[0]).hypot(got[1] - d[1]));
            let p = exact_raw(c, &r, d[0], d[1]);
            raw_shift = raw_shift.max((p[0] - d[0]).hypot(p[1] - d[1]));
        }
        // Vertical line x = 100.3: centroid of the darkening per row, away from the dots and
        // the horizontal line.
        for y in (20..460).filter(|y| (*y as f64 - 400.6).abs() > 8.0) {
            let (mut sw, mut sx) = (0.0, 0.0);
            for x in 94..=106 {
                let w = (160.0 - f64::from(img[y * W + x])).max(0.0);
                sw += w;
                sx += w * x as f64;
            }
            worst_line = worst_line.max((sx / sw - 100.3).abs());
        }
        for x in (20..620).filter(|x| (*x as f64 - 100.3).abs() > 8.0) {
            let (mut sw, mut sy) = (0.0, 0.0);
            for y in 395..=406 {
                let w = (160.0 - f64::from(img[y * W + x])).max(0.0);
                sw += w;
                sy += w * y as f64;
            }
            worst_line = worst_line.max((sy / sw - 400.6).abs());
        }
    }
    println!(
        "RECT-1 worst dot {worst_dot:.3} px, worst line {worst_line:.3} px (raw displacement up \
         to {raw_shift:.1} px)"
    );
    assert!(raw_shift > 20.0, "{raw_shift}");
    assert!(worst_dot < 0.3, "{worst_dot}");
    assert!(worst_line < 0.3, "{worst_line}");
}

/// RECT-3: NaN and absurd calibrations are refused at initialisation (the map stays invalid
/// and every pair is refused), as is memory that is too small.
#[test]
fn rect_3_bad_calibrations_are_refused() {
    let r = rect();
    type Spoil = fn(&mut LensCalibration);
    let cases: [(Spoil, RectifyError); 9] = [
        (|l| l.left.k1 = f64::NAN, RectifyError::BadCalibration),
        (|l| l.right.p2 = f64::INFINITY, RectifyError::BadCalibration),
        (|l| l.left.fx_px = -390.0, RectifyError::BadCalibration),
        (|l| l.right.k2 = 1.0e6, RectifyError::BadCalibration),
        (
            |l| l.left.rot_raw_from_rect[0][0] = 2.0,
            RectifyError::BadCalibration,
        ),
        // Strong barrel: the radial map turns back inside the field.
        (|l| l.left.k1 = -0.9, RectifyError::Folded),
        // Stronger: folded twice at the corner (the Jacobian is positive again there), the
        // inverse finds another point.
        (|l| l.left.k1 = -1.5, RectifyError::NotConverged),
        // Strong pincushion: the rectified field leaves the raw image.
        (|l| l.right.k1 = 0.4, RectifyError::FieldNotCovered),
        (|l| l.left.cx_px = 900.0, RectifyError::FieldNotCovered),
    ];
    for (n, (spoil, want)) in cases.iter().enumerate() {
        let mut l = lens();
        spoil(&mut l);
        let mut mem = memory();
        let mut rectifier = Rectifier::new(RectifyConfig::default());
        assert_eq!(rectifier.build(&l, &r, &mut mem), Err(*want), "case {n}");
        assert!(!rectifier.has_map());
        let img = vec![0u8; IMAGE_PIXELS];
        let frame = StereoFrame {
            left: &img,
            right: &img,
            capture_t_us: 1,
            sequence: 1,
        };
        assert_eq!(rectifier.start(&frame), Err(RectifyError::NoMap));
    }
    let mut bad_rect = r;
    bad_rect.fx_px = f64::NAN;
    let mut rectifier = Rectifier::new(RectifyConfig::default());
    assert_eq!(
        rectifier.build(&lens(), &bad_rect, &mut memory()),
        Err(RectifyError::BadCalibration)
    );
    let mut small = ImageMemory {
        map: vec![MapNode::default(); MAP_NODES - 1],
        left: vec![0u8; IMAGE_PIXELS],
        right: vec![0u8; IMAGE_PIXELS],
    };
    assert_eq!(
        rectifier.build(&lens(), &r, &mut small),
        Err(RectifyError::Memory)
    );
}

/// RECT-4: the undistortion is bounded: over a grid of distorted points of a folding lens
/// (k1 = -1.5) every answer distorts back to its input within 1e-12 and took at most
/// `UNDISTORT_ITERATIONS` steps, and some points are reported as not converged instead of
/// being looped on; NaN input gives `None`; the nominal-class lens inverts everywhere in its
/// field.
#[test]
fn rect_4_undistort_is_bounded() {
    let mut c = lens_camera(0.0, 0.0);
    assert!(undistort(&c, 0.5, -0.3).is_some());
    assert!(undistort(&c, f64::NAN, 0.0).is_none());
    assert!(undistort(&c, 0.0, f64::INFINITY).is_none());
    c.k1 = -1.5;
    let (mut solved, mut refused) = (0, 0);
    for i in -30..=30 {
        for j in -30..=30 {
            let (xd, yd) = (f64::from(i) * 0.1, f64::from(j) * 0.1);
            match undistort(&c, xd, yd) {
                Some(([x, y], n)) => {
                    let [u, v] = distort(&c, x, y);
                    assert!((u - xd).abs().max((v - yd).abs()) < 1e-12);
                    assert!(n as usize <= UNDISTORT_ITERATIONS);
                    solved += 1;
                }
                None => refused += 1,
            }
        }
    }
    println!("RECT-4 folding lens: {solved} inverted, {refused} refused");
    assert!(solved > 0 && refused > 0);
}

/// RECT-5: the result does not depend on the work quantum (bit-identical for 1, 7 and 1000
/// units per call), a changed frame abandons the pair, and a second start while busy is
/// refused.
#[test]
fn rect_5_items_are_quantum_independent() {
    let (l, r) = (lens(), rect());
    let raw: Vec<u8> = (0..IMAGE_PIXELS)
        .map(|i| ((i * 2_654_435_761) >> 13) as u8)
        .collect();
    let frame = StereoFrame {
        left: &raw,
        right: &raw,
        capture_t_us: 10,
        sequence: 1,
    };
    let mut outputs = Vec::new();
    for quantum in [1u32, 7, 1000] {
        let mut mem = memory();
        let mut rectifier = Rectifier::new(RectifyConfig::default());
        rectifier.build(&l, &r, &mut mem).unwrap();
        rectifier.start(&frame).unwrap();
        assert_eq!(rectifier.start(&frame), Err(RectifyError::Busy));
        let mut items = 0;
        for _ in 0..2000 {
            match rectifier.step(&frame, &mut mem, quantum) {
                RectifyProgress::Working { items: n } => items = n,
                RectifyProgress::Finished(result) => {
                    result.unwrap();
                    break;
                }
            }
        }
        assert!(items < Rectifier::ITEMS_PER_PAIR);
        assert!(!rectifier.is_busy());
        outputs.push((mem.left.clone(), mem.right.clone()));
    }
    assert!(outputs.windows(2).all(|w| w[0] == w[1]));
    assert!(outputs[0].0.iter().filter(|&&p| p == 0).count() < 1000);
    let mut mem = memory();
    let mut rectifier = Rectifier::new(RectifyConfig::default());
    rectifier.build(&l, &r, &mut mem).unwrap();
    rectifier.start(&frame).unwrap();
    let other = StereoFrame {
        sequence: 2,
        ..frame
    };
    assert_eq!(
        rectifier.step(&other, &mut mem, 10),
        RectifyProgress::Finished(Err(RectifyError::FrameChanged))
    );
}

/// The per-pixel row kernel of the module doc's formula, without the cell fast path: the oracle
/// of RECT-7 (checked arithmetic: the test maps stay far from i32 overflow).
fn reference_row(nodes: &[MapNode], row: usize, raw: &[u8], out: &mut [u8]) {
    let step = LATTICE_STEP_PX as i32;
    let j = row / LATTICE_STEP_PX;
    let b = (row % LATTICE_STEP_PX) as i32;
    let lattice_row = |jj: usize| nodes.get(jj * LATTICE_COLS..(jj + 1) * LATTICE_COLS);
    let (Some(upper), Some(lower)) = (lattice_row(j), lattice_row(j + 1)) else {
        out.fill(0);
        return;
    };
    for (cell, out_cell) in out.chunks_mut(LATTICE_STEP_PX).enumerate() {
        let corners = (upper.get(cell..cell + 2), lower.get(cell..cell + 2));
        let (Some(&[p00, p10]), Some(&[p01, p11])) = corners else {
            out_cell.fill(0);
            continue;
        };
        let lu = p00.u * (step - b) + p01.u * b;
        let lv = p00.v * (step - b) + p01.v * b;
        let ru = p10.u * (step - b) + p11.u * b;
        let rv = p10.v * (step - b) + p11.v * b;
        let (mut qu, mut qv) = (lu * step, lv * step);
        let (du, dv) = (ru - lu, rv - lv);
        for px in out_cell.iter_mut() {
            *px = reference_sample(raw, qu, qv);
            qu += du;
            qv += dv;
        }
    }
}

/// The per-pixel sample of [`reference_row`] (verbatim).
fn reference_sample(raw: &[u8], qu: i32, qv: i32) -> u8 {
    if qu < 0 || qv < 0 {
        return 0;
    }
    let (x, y) = ((qu >> Q_FRAC_BITS) as usize, (qv >> Q_FRAC_BITS) as usize);
    if x + 1 >= W || y + 1 >= H {
        return 0;
    }
    let wx = ((qu >> (Q_FRAC_BITS - 8)) & 0xff) as u32;
    let wy = ((qv >> (Q_FRAC_BITS - 8)) & 0xff) as u32;
    let top = y * W + x;
    let Some(window) = raw.get(top..top + W + 2) else {
        return 0;
    };
    let (Some(&i00), Some(&i10), Some(&i01), Some(&i11)) = (
        window.first(),
        window.get(1),
        window.get(W),
        window.get(W + 1),
    ) else {
        return 0;
    };
    let (wx, wy) = (wx as i32, wy as i32);
    let upper = (i32::from(i00) << 8) + (i32::from(i10) - i32::from(i00)) * wx;
    let lower = (i32::from(i01) << 8) + (i32::from(i11) - i32::from(i01)) * wx;
    (((upper << 8) + (lower - upper) * wy + (1 << 15)) >> 16) as u8
}

/// A random map of one camera for RECT-7: `kind` 0 a smooth lens-like map well inside the
/// raw image, 1 the same shifted and scaled so that parts of the field leave the image (any
/// side, near the borders and far out), 2 every node uniform in +-2^23 (1/256 px).
fn random_map(rng: &mut impl rand::Rng, kind: u32) -> Vec<MapNode> {
    let mut map = vec![MapNode::default(); LATTICE_NODES];
    let (su, sv) = (rng.random_range(0.8..1.2), rng.random_range(0.8..1.2));
    let (ou, ov) = match kind {
        0 => (rng.random_range(-4.0..4.0), rng.random_range(-4.0..4.0)),
        _ => (rng.random_range(-60.0..60.0), rng.random_range(-60.0..60.0)),
    };
    let (shear, k1) = (rng.random_range(-0.1..0.1), rng.random_range(-0.3..0.05));
    for (n, node) in map.iter_mut().enumerate() {
        let x = ((n % LATTICE_COLS) * LATTICE_STEP_PX) as f64;
        let y = ((n / LATTICE_COLS) * LATTICE_STEP_PX) as f64;
        *node = if kind == 2 {
            MapNode {
                u: rng.random_range(-(1 << 23)..1 << 23),
                v: rng.random_range(-(1 << 23)..1 << 23),
            }
        } else {
            // Barrel-like: positions pulled towards the centre, scaled, sheared, shifted.
            let (dx, dy) = ((x - 319.5) / 320.0, (y - 239.5) / 320.0);
            let g = 1.0 + k1 * (dx * dx + dy * dy);
            let u = 319.5 + su * 300.0 * dx * g + shear * 300.0 * dy * g + ou;
            let v = 239.5 + sv * 300.0 * dy * g + ov;
            let jitter = rng.random_range(-64..64);
            MapNode {
                u: (u * 256.0) as i32 + jitter,
                v: (v * 256.0) as i32 - jitter,
            }
        };
    }
    map
}

/// RECT-7: the row kernel with the cell fast path is bit-identical to the per-pixel
/// reference for random maps (inside the image, partly outside, random nodes anywhere), random
/// raw images and every row (including rows past the lattice), and for short or long raw and
/// output buffers.
#[test]
fn rect_7_row_kernel_matches_per_pixel_reference() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(18);
    let (mut fast_like, mut zeros, mut compared) = (0usize, 0usize, 0usize);
    for case in 0..24u32 {
        let kind = case % 3;
        let map = random_map(&mut rng, kind);
        let raw: Vec<u8> = (0..IMAGE_PIXELS).map(|_| rng.random()).collect();
        let rows: Vec<usize> = if case < 3 {
            (0..=H + 1).collect()
        } else {
            (0..40).map(|_| rng.random_range(0..=H + 1)).collect()
        };
        for row in rows {
            let mut want = [0u8; W];
            let mut got = [0xa5u8; W];
            reference_row(&map, row, &raw, &mut want);
            rectify_row(&map, row, &raw, &mut got);
            assert_eq!(got, want, "case {case} kind {kind} row {row}");
            compared += W;
            zeros += want.iter().filter(|&&p| p == 0).count();
            fast_like += usize::from(kind == 0);
        }
        // Odd buffers: a raw image cut short, an output row shorter or longer than W, a map
        // cut short.
        let row = rng.random_range(0..H);
        let cut = rng.random_range(0..IMAGE_PIXELS);
        for (raw_len, out_len, map_len) in [
            (cut, W, LATTICE_NODES),
            (IMAGE_PIXELS, rng.random_range(0..W), LATTICE_NODES),
            (IMAGE_PIXELS, W + rng.random_range(1..20), LATTICE_NODES),
            (IMAGE_PIXELS + 7, W, rng.random_range(0..LATTICE_NODES)),
        ] {
            let raw_long: Vec<u8> = raw.iter().copied().chain([9u8; 7]).collect();
            let raw = &raw_long[..raw_len];
            let map = &map[..map_len];
            let mut want = vec![0u8; out_len];
            let mut got = vec![0x5au8; out_len];
            reference_row(map, row, raw, &mut want);
            rectify_row(map, row, raw, &mut got);
            assert_eq!(
                got, want,
                "case {case} row {row} raw {raw_len} out {out_len}"
            );
        }
    }
    // Maps at the raw image's borders: every node (or a steep run of nodes) at the last
    // columns and rows that still have a 2 x 2 neighbourhood, and just past them.
    let raw: Vec<u8> = (0..IMAGE_PIXELS).map(|_| rng.random()).collect();
    let edge = |x: f64, y: f64| MapNode {
        u: (x * 256.0) as i32,
        v: (y * 256.0) as i32,
    };
    let mut edge_maps: Vec<Vec<MapNode>> = Vec::new();
    for (x, y) in [
        (638.5, 477.5),
        (638.99, 477.99),
        (639.0, 477.5),
        (638.5, 478.0),
        (0.0, 0.0),
        (-0.01, 0.5),
        (0.5, -0.01),
        (631.3, 476.7),
        (632.7, 477.2),
    ] {
        edge_maps.push(vec![edge(x, y); LATTICE_NODES]);
        // Rows and columns running into the corner: 1 px per lattice step across.
        edge_maps.push(
            (0..LATTICE_NODES)
                .map(|n| {
                    let (i, j) = ((n % LATTICE_COLS) as f64, (n / LATTICE_COLS) as f64);
                    edge(x - 0.13 * (80.0 - i), y - 0.11 * (60.0 - j))
                })
                .collect(),
        );
    }
    for (m, map) in edge_maps.iter().enumerate() {
        for row in [0, 1, 7, 8, 240, 471, 472, 478, 479] {
            let mut want = [0u8; W];
            let mut got = [0xa5u8; W];
            reference_row(map, row, &raw, &mut want);
            rectify_row(map, row, &raw, &mut got);
            assert_eq!(got, want, "edge map {m} row {row}");
            compared += W;
            zeros += want.iter().filter(|&&p| p == 0).count();
        }
    }
    println!("RECT-7 {compared} pixels compared, {zeros} outside (0), {fast_like} lens-like rows");
    // The maps really left the image somewhere, and most pixels were inside.
    assert!(
        zeros > compared / 50 && zeros < compared / 2,
        "{zeros} of {compared}"
    );
}
