#!/usr/bin/env python3
"""Export the Middlebury 2014 "motorcycle" stereo pair (shipped with scikit-image) for the VO
stereo check (requirement VO-14).

Writes into OUT_DIR (default /tmp/middlebury):
  left.pgm, right.pgm   640x480 8-bit grey crops of the rectified pair (P5 PGM)
  disparity.f32         640x480 little-endian float32 ground-truth disparity of the left image,
                        x_left - x_right in pixels, NaN where unknown
  calibration.txt       key = value lines: fx_px, fy_px, cx_px, cy_px (left camera, in the crop),
                        doffs_px (principal point x of the right camera minus the left's),
                        baseline_m, crop_x0, crop_y0

Then run the ignored Rust test that matches Forstner features along the rows and compares their
disparity with the ground truth:
  VO_MIDDLEBURY_DIR=/tmp/middlebury cargo test -p fsw --release vo_14 -- --ignored --nocapture

If Debian's opencv-doc package is installed (`apt-get install opencv-doc`, or its .deb unpacked
with `dpkg-deb -x` and OPENCV_SAMPLES_DATA pointing at .../examples/data), the Middlebury 2006
"Aloe" pair that ships in OpenCV's sample data (aloeL.jpg, aloeR.jpg, aloeGT.png: full-size
1282x1110, ground-truth disparity in grey levels, 0 = unknown) is exported too, into OUT_DIR/aloe,
down-sampled by 2 (area average; disparity halved) and cropped to 640x480. It has no published
calibration, so it is used for the disparity check only. Its images are JPEG-compressed.

Side by side with an OpenCV peer (`--compare`, needs `pip install opencv-python-headless`):
  python3 tools/middlebury_eval.py /tmp/middlebury --compare
exports the pairs, runs the ignored Rust tests (VO-14 real disparity, VO-16 real feature geometry
with SYNTHETIC known motions; they write flight_matches.csv) with cargo, then runs OpenCV on the
same images in the same run and prints both:
  - stereo at the flight matcher's features: pyramidal Lucas-Kanade left->right with a
    right->left back-check (1 px), and StereoSGBM (left-right check 1 px) sampled there;
  - motion on the motorcycle geometry: good features to track, LK left->right (back-checked),
    3D points from the measured disparity, then the ground-truth points moved by the same kind
    of known random rigid motions as VO-16 and projected into the left image with 0.3 px noise,
    solved by solvePnPRansac. This part is synthetic (no real image sequence with known motion
    ships in the registries this project can reach, see docs/vo.md).

The images are not committed (licence and size); this tool loads them at run time. Needs
`pip install scikit-image` (and opencv-python-headless for Aloe).
"""
import os
import sys

import numpy as np
from skimage import color, data

WIDTH, HEIGHT = 640, 480
# Calibration of the 4x down-sampled images, from skimage.data.stereo_motorcycle's docstring.
FOCAL_PX = 994.978
CX_PX, CY_PX = 311.193, 254.877
DOFFS_PX = 31.086
BASELINE_M = 0.193001


def to_grey_u8(rgb):
    return np.clip(np.rint(color.rgb2gray(rgb) * 255.0), 0, 255).astype(np.uint8)


def write_pgm(path, image):
    with open(path, "wb") as f:
        f.write(b"P5\n%d %d\n255\n" % (image.shape[1], image.shape[0]))
        f.write(np.ascontiguousarray(image).tobytes())


def main():
    out_dir = sys.argv[1] if len(sys.argv) > 1 else "/tmp/middlebury"
    os.makedirs(out_dir, exist_ok=True)
    left, right, disparity = data.stereo_motorcycle()
    height, width = disparity.shape
    # Keep the right part of the left image: its left columns have no match in the right image.
    x0 = width - WIDTH
    y0 = (height - HEIGHT) // 2
    crop = (slice(y0, y0 + HEIGHT), slice(x0, x0 + WIDTH))
    write_pgm(os.path.join(out_dir, "left.pgm"), to_grey_u8(left)[crop])
    write_pgm(os.path.join(out_dir, "right.pgm"), to_grey_u8(right)[crop])
    d = disparity[crop].astype("<f4")
    d[~np.isfinite(d)] = np.nan
    d.tofile(os.path.join(out_dir, "disparity.f32"))
    with open(os.path.join(out_dir, "calibration.txt"), "w") as f:
        f.write(f"fx_px = {FOCAL_PX}\nfy_px = {FOCAL_PX}\n")
        f.write(f"cx_px = {CX_PX - x0}\ncy_px = {CY_PX - y0}\n")
        f.write(f"doffs_px = {DOFFS_PX}\nbaseline_m = {BASELINE_M}\n")
        f.write(f"crop_x0 = {x0}\ncrop_y0 = {y0}\n")
    valid = np.isfinite(d)
    print(f"wrote {out_dir}: {WIDTH}x{HEIGHT}, crop at ({x0}, {y0}), "
          f"ground truth on {valid.mean() * 100:.1f} % of pixels, "
          f"disparity {np.nanmin(d):.1f}..{np.nanmax(d):.1f} px")


OPENCV_DATA_DIRS = [
    os.environ.get("OPENCV_SAMPLES_DATA", ""),
    "/usr/share/doc/opencv-doc/examples/data",
]


def export_aloe(out_dir):
    """Middlebury 2006 Aloe from OpenCV's sample data, if present; returns True if exported."""
    src = next((d for d in OPENCV_DATA_DIRS
                if d and os.path.exists(os.path.join(d, "aloeGT.png"))), None)
    if src is None:
        print("Aloe: OpenCV sample data not found (apt-get install opencv-doc); skipped")
        return False
    import cv2
    left = cv2.imread(os.path.join(src, "aloeL.jpg"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(os.path.join(src, "aloeR.jpg"), cv2.IMREAD_GRAYSCALE)
    gt = cv2.imread(os.path.join(src, "aloeGT.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    h, w = left.shape
    size = (w // 2, h // 2)
    left = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
    right = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
    # Ground truth at the half-size pixel centres: the 2x2 block must agree (no edge), halved.
    blocks = gt[:size[1] * 2, :size[0] * 2].reshape(size[1], 2, size[0], 2)
    lo, hi = blocks.min(axis=(1, 3)), blocks.max(axis=(1, 3))
    disparity = np.where((lo > 0) & (hi - lo <= 1.0), blocks.mean(axis=(1, 3)) / 2.0, np.nan)
    x0 = size[0] - WIDTH
    y0 = (size[1] - HEIGHT) // 2
    crop = (slice(y0, y0 + HEIGHT), slice(x0, x0 + WIDTH))
    aloe = os.path.join(out_dir, "aloe")
    os.makedirs(aloe, exist_ok=True)
    write_pgm(os.path.join(aloe, "left.pgm"), left[crop])
    write_pgm(os.path.join(aloe, "right.pgm"), right[crop])
    d = disparity[crop].astype("<f4")
    d.tofile(os.path.join(aloe, "disparity.f32"))
    with open(os.path.join(aloe, "calibration.txt"), "w") as f:
        f.write(f"crop_x0 = {x0}\ncrop_y0 = {y0}\nscale = 0.5\n")
    valid = np.isfinite(d)
    print(f"wrote {aloe}: {WIDTH}x{HEIGHT}, crop at ({x0}, {y0}) of the half-size pair, "
          f"ground truth on {valid.mean() * 100:.1f} % of pixels, "
          f"disparity {np.nanmin(d):.1f}..{np.nanmax(d):.1f} px")
    return True


def read_pgm(path):
    with open(path, "rb") as f:
        data = f.read()
    return np.frombuffer(data[-WIDTH * HEIGHT:], np.uint8).reshape(HEIGHT, WIDTH)


def read_calibration(path):
    out = {}
    with open(path) as f:
        for line in f:
            if "=" in line:
                k, v = line.split("=", 1)
                out[k.strip()] = float(v)
    return out


def disparity_stats(name, method, xl, d_meas, truth, features):
    """One table row: matched, evaluated, median |error|, gross (> 2 px) count and shares."""
    ok = np.isfinite(d_meas)
    ev = ok & np.isfinite(truth)
    err = np.abs(d_meas[ev] - truth[ev])
    gross = int((err > 2.0).sum())
    print(f"  {name:10s} {method:26s} {features:4d} {int(ok.sum()):8d} {int(ev.sum()):10d} "
          f"{np.median(err) if err.size else float('nan'):11.3f} {gross:6d} "
          f"{gross / max(ok.sum(), 1) * 100:9.2f} {gross / max(ev.sum(), 1) * 100:9.2f}")


def compare_stereo(name, pair_dir):
    import cv2
    left, right = read_pgm(os.path.join(pair_dir, "left.pgm")), read_pgm(
        os.path.join(pair_dir, "right.pgm"))
    truth_map = np.fromfile(os.path.join(pair_dir, "disparity.f32"), "<f4").reshape(HEIGHT, WIDTH)
    rows = np.genfromtxt(os.path.join(pair_dir, "flight_matches.csv"), delimiter=",", names=True)
    xl, yl, xr = rows["xl"], rows["yl"], rows["xr"]
    truth = truth_map[yl.astype(int), xl.astype(int)].astype(float)
    n = len(xl)
    disparity_stats(name, "flight (NCC + rules)", xl, xl - xr, truth, n)
    # Pyramidal LK left->right at the same features, back-checked right->left.
    pts = np.stack([xl, yl], axis=1).astype(np.float32).reshape(-1, 1, 2)
    lk = dict(winSize=(11, 11), maxLevel=4,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    fwd, st1, _ = cv2.calcOpticalFlowPyrLK(left, right, pts, None, **lk)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(right, left, fwd, None, **lk)
    fwd, back = fwd.reshape(-1, 2), back.reshape(-1, 2)
    good = (st1.ravel() == 1) & (st2.ravel() == 1) \
        & (np.hypot(*(back - pts.reshape(-1, 2)).T) <= 1.0) & (np.abs(fwd[:, 1] - yl) <= 1.5)
    d_lk = np.where(good, xl - fwd[:, 0], np.nan)
    disparity_stats(name, "OpenCV LK (11x11, back 1px)", xl, d_lk, truth, n)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=128, blockSize=5,
                                 P1=8 * 25, P2=32 * 25, disp12MaxDiff=1, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=2)
    dmap = sgbm.compute(left, right).astype(np.float32) / 16.0
    d_sgbm = dmap[yl.astype(int), xl.astype(int)].astype(float)
    d_sgbm[d_sgbm < 0.5] = np.nan
    disparity_stats(name, "OpenCV StereoSGBM (LR 1px)", xl, d_sgbm, truth, n)


def compare_motion(pair_dir, trials=300, seed=16):
    """OpenCV peer of VO-16: real features and stereo, synthetic known motions."""
    import cv2
    left, right = read_pgm(os.path.join(pair_dir, "left.pgm")), read_pgm(
        os.path.join(pair_dir, "right.pgm"))
    truth_map = np.fromfile(os.path.join(pair_dir, "disparity.f32"), "<f4").reshape(HEIGHT, WIDTH)
    cal = read_calibration(os.path.join(pair_dir, "calibration.txt"))
    f, cx, cy, b, doffs = cal["fx_px"], cal["cx_px"], cal["cy_px"], cal["baseline_m"], cal["doffs_px"]
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]], float)
    corners = cv2.goodFeaturesToTrack(left, maxCorners=200, qualityLevel=0.01, minDistance=20,
                                      blockSize=5)
    lk = dict(winSize=(11, 11), maxLevel=4,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    fwd, st1, _ = cv2.calcOpticalFlowPyrLK(left, right, corners, None, **lk)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(right, left, fwd, None, **lk)
    p0, p1, pb = corners.reshape(-1, 2), fwd.reshape(-1, 2), back.reshape(-1, 2)
    good = (st1.ravel() == 1) & (st2.ravel() == 1) & (np.hypot(*(pb - p0).T) <= 1.0)
    xl, yl = p0[good, 0], p0[good, 1]
    d_meas = xl - p1[good, 0]
    d_true = truth_map[np.rint(yl).astype(int).clip(0, HEIGHT - 1),
                       np.rint(xl).astype(int).clip(0, WIDTH - 1)].astype(float)
    keep = np.isfinite(d_true) & (d_meas > 0)
    xl, yl, d_meas, d_true = xl[keep], yl[keep], d_meas[keep], d_true[keep]

    def points(d):
        z = f * b / (d + doffs)
        return np.stack([(xl - cx) * z / f, (yl - cy) * z / f, z], axis=1)

    measured, true = points(d_meas), points(d_true)
    rng = np.random.default_rng(seed)
    ok, errs, failures = 0, [], 0
    for _ in range(trials):
        axis = rng.uniform(-1, 1, 3)
        angle = np.radians(rng.uniform(0, 3))
        rvec = axis / np.linalg.norm(axis) * angle
        R, _ = cv2.Rodrigues(rvec)
        T = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.05, 0.05), rng.uniform(-0.15, 0.15)])
        q = true @ R.T + T
        px = q[:, :2] / q[:, 2:3] * f + np.array([cx, cy]) + rng.normal(0, 0.3, (len(q), 2))
        inside = (px[:, 0] > 5) & (px[:, 0] < WIDTH - 5) & (px[:, 1] > 5) & (px[:, 1] < HEIGHT - 5)
        found, rv, tv, inl = cv2.solvePnPRansac(measured[inside], px[inside], K, None,
                                                reprojectionError=2.0, iterationsCount=200,
                                                confidence=0.999)
        if not found or inl is None or len(inl) < 6:
            failures += 1
            continue
        ok += 1
        errs.append(np.linalg.norm(tv.ravel() - T))
    errs = np.sort(np.array(errs))
    print(f"  OpenCV GFTT + LK stereo + solvePnPRansac: {len(xl)} features with truth; {ok} of "
          f"{trials} solved; translation error median {np.median(errs) * 1e3:.2f} mm, "
          f"max {errs[-1] * 1e3:.2f} mm")


def compare(out_dir):
    import subprocess
    env = dict(os.environ, VO_MIDDLEBURY_DIR=out_dir)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cmd = ["cargo", "test", "-p", "fsw", "--release", "-j", "1", "--lib", "middlebury", "--",
           "--ignored", "--nocapture", "--test-threads", "1"]
    print("running", " ".join(cmd))
    run = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
    print("flight software (Rust, fsw::vo):")
    for line in run.stdout.splitlines():
        if line.startswith(("VO-14", "VO-16", "test result")) or "gross errors" in line:
            print("  " + line.strip())
    print("stereo at the flight features (disparity error against the ground truth):")
    print(f"  {'pair':10s} {'method':26s} {'feat':>4s} {'matched':>8s} {'with truth':>10s} "
          f"{'median px':>11s} {'gross':>6s} {'% matched':>9s} {'% truth':>9s}")
    for name, sub in [("motorcycle", out_dir), ("aloe", os.path.join(out_dir, "aloe"))]:
        if os.path.exists(os.path.join(sub, "flight_matches.csv")):
            compare_stereo(name, sub)
    print("motion on the motorcycle geometry, SYNTHETIC known motions (OpenCV peer of VO-16):")
    compare_motion(out_dir)


if __name__ == "__main__":
    out = next((a for a in sys.argv[1:] if not a.startswith("--")), "/tmp/middlebury")
    want_compare = "--compare" in sys.argv[1:]
    sys.argv = [sys.argv[0], out]
    main()
    export_aloe(out)
    if want_compare:
        compare(out)
