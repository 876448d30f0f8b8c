#!/usr/bin/env python3
"""Host speed of the flight visual odometry against an OpenCV sparse pipeline, on the
same real 640x480 stereo pairs, in the same run, on one core.

Data: the stereo-calibration sequence of OpenCV's sample data (Debian `opencv-doc`,
/usr/share/doc/opencv-doc/examples/data/left01..14.jpg, right01..14.jpg; no 10): 13 real 640x480
pairs from a FIXED camera pair of a hand-held 9x6 chessboard (25 mm squares, per the package's
left_intrinsics.yml) in an office. The scene is not rigid (the board and the person move, the
room is static), so this is a TIMING benchmark, not an accuracy one.

Steps:
 1. Export (into OUT_DIR, default /tmp/vo_speed): the pair is calibrated from the chessboard itself
    (cv2.calibrateCamera per camera, cv2.stereoCalibrate with the intrinsics fixed), rectified with
    cv2.stereoRectify (CALIB_ZERO_DISPARITY, alpha 0: only valid pixels, no black border, since
    the flight VO has no validity mask) and cv2.initUndistortRectifyMap/remap (bilinear) to
    640x480, written as PGM (NAME_left.pgm, NAME_right.pgm), pairs.txt (the order) and
    calibration.txt (fx_px, fy_px, cx_px, cy_px, baseline_m of the rectified pair).
 2. Alternating passes, pinned to one core (os.sched_setaffinity; children inherit it): the Rust
    benchmark `sim-host/examples/vo_speed.rs` (flight VisualOdometry<150>, flight VoConfig,
    flight quantum, no prior; one pass per call after one untimed warm-up pass), then the OpenCV
    peer (cv2.setNumThreads(1)) over the same pairs:
      keyframe: goodFeaturesToTrack (150, quality 0.01, min distance 20 px as the flight,
                block 5) on the left image, pyramidal LK left->right (11x11, 4 levels), back-check
                right->left (1 px) and row check (1.5 px, the flight's max_row_offset_px),
                3D points from the disparity (Z = f b / d);
      update:   pyramidal LK previous left -> current left of the keyframe's 3D features,
                solvePnPRansac (reprojection error 2 px, 200 iterations, confidence 0.999),
                then the keyframe step above on the current pair (the next keyframe; the
                flight also builds its next keyframe in every update).
    The time per update is time.perf_counter() around the update (images already in memory,
    as the flight's are).
 3. One table with both pipelines and the ratio.

Usage:
  taskset -c 0 python3 tools/vo_speed.py /tmp/vo_speed              # export, build, compare
  python3 tools/vo_speed.py /tmp/vo_speed --export-only
  python3 tools/vo_speed.py /tmp/vo_speed --passes 9 --cpu 0
  python3 tools/vo_speed.py /tmp/vo_speed --native    # also the flight VO built for this CPU
Needs `pip install opencv-python-headless` and `apt-get install opencv-doc` (or its .deb unpacked
and OPENCV_SAMPLES_DATA=.../usr/share/doc/opencv-doc/examples/data).
"""
import json
import os
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from middlebury_eval import read_calibration  # noqa: E402  (the `key = value` files of both tools)

WIDTH, HEIGHT = 640, 480
BOARD = (9, 6)
SQUARE_M = 0.025  # square_size of the package's left_intrinsics.yml
OPENCV_DATA_DIRS = [
    os.environ.get("OPENCV_SAMPLES_DATA", ""),
    "/usr/share/doc/opencv-doc/examples/data",
]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# The OpenCV peer's settings (see the module doc).
MAX_CORNERS = 150
GFTT = dict(maxCorners=MAX_CORNERS, qualityLevel=0.01, minDistance=20, blockSize=5)
LK_CRITERIA = (3, 30, 0.01)  # cv2.TERM_CRITERIA_EPS | COUNT, 30 iterations, 0.01 px
LK = dict(winSize=(11, 11), maxLevel=4, criteria=LK_CRITERIA)
BACK_CHECK_PX = 1.0
ROW_CHECK_PX = 1.5
MIN_DISPARITY_PX = 1.0


def write_pgm(path, image):
    with open(path, "wb") as f:
        f.write(b"P5\n%d %d\n255\n" % (image.shape[1], image.shape[0]))
        f.write(np.ascontiguousarray(image).tobytes())


def read_pgm(path):
    with open(path, "rb") as f:
        data = f.read()
    return np.frombuffer(data[-WIDTH * HEIGHT:], np.uint8).reshape(HEIGHT, WIDTH).copy()


def export_chessboard(out_dir):
    """Calibrates and rectifies the chessboard pairs; writes the PGMs and the calibration."""
    import cv2
    src = next((d for d in OPENCV_DATA_DIRS
                if d and os.path.exists(os.path.join(d, "left01.jpg"))), None)
    if src is None:
        sys.exit("OpenCV sample data not found: apt-get install opencv-doc "
                 "(or set OPENCV_SAMPLES_DATA)")
    names = [f"{i:02d}" for i in range(1, 15)
             if os.path.exists(os.path.join(src, f"left{i:02d}.jpg"))]
    objp = np.zeros((BOARD[0] * BOARD[1], 3), np.float32)
    objp[:, :2] = np.mgrid[0:BOARD[0], 0:BOARD[1]].T.reshape(-1, 2) * SQUARE_M
    raw, obj, cl, cr = [], [], [], []
    term = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    for n in names:
        left = cv2.imread(os.path.join(src, f"left{n}.jpg"), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(os.path.join(src, f"right{n}.jpg"), cv2.IMREAD_GRAYSCALE)
        if left.shape != (HEIGHT, WIDTH) or right.shape != (HEIGHT, WIDTH):
            sys.exit(f"pair {n}: not 640x480")
        raw.append((left, right))
        fl, pl = cv2.findChessboardCorners(left, BOARD)
        fr, pr = cv2.findChessboardCorners(right, BOARD)
        if fl and fr:
            obj.append(objp)
            cl.append(cv2.cornerSubPix(left, pl, (11, 11), (-1, -1), term))
            cr.append(cv2.cornerSubPix(right, pr, (11, 11), (-1, -1), term))
    size = (WIDTH, HEIGHT)
    rms_l, k1, d1, _, _ = cv2.calibrateCamera(obj, cl, size, None, None)
    rms_r, k2, d2, _, _ = cv2.calibrateCamera(obj, cr, size, None, None)
    rms, k1, d1, k2, d2, rot, trans, _, _ = cv2.stereoCalibrate(
        obj, cl, cr, k1, d1, k2, d2, size, flags=cv2.CALIB_FIX_INTRINSIC,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-6))
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(k1, d1, k2, d2, size, rot, trans,
                                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0)
    maps = [cv2.initUndistortRectifyMap(k, d, r, p, size, cv2.CV_32FC1)
            for k, d, r, p in [(k1, d1, r1, p1), (k2, d2, r2, p2)]]
    fx, fy, cx, cy = (float(v) for v in (p1[0, 0], p1[1, 1], p1[0, 2], p1[1, 2]))
    baseline = float(-p2[0, 3] / p2[0, 0])
    os.makedirs(out_dir, exist_ok=True)
    rect = []
    for n, (left, right) in zip(names, raw):
        rl = cv2.remap(left, maps[0][0], maps[0][1], cv2.INTER_LINEAR)
        rr = cv2.remap(right, maps[1][0], maps[1][1], cv2.INTER_LINEAR)
        write_pgm(os.path.join(out_dir, f"{n}_left.pgm"), rl)
        write_pgm(os.path.join(out_dir, f"{n}_right.pgm"), rr)
        rect.append((rl, rr))
    with open(os.path.join(out_dir, "pairs.txt"), "w") as f:
        f.write("\n".join(names) + "\n")
    with open(os.path.join(out_dir, "calibration.txt"), "w") as f:
        f.write(f"fx_px = {fx!r}\nfy_px = {fy!r}\ncx_px = {cx!r}\ncy_px = {cy!r}\n"
                f"baseline_m = {baseline!r}\n")
    # Rectification check: the chessboard corners of each rectified pair on the same rows.
    dy = []
    for rl, rr in rect:
        fl, pl = cv2.findChessboardCorners(rl, BOARD)
        fr, pr = cv2.findChessboardCorners(rr, BOARD)
        if fl and fr:
            pl = cv2.cornerSubPix(rl, pl, (11, 11), (-1, -1), term)
            pr = cv2.cornerSubPix(rr, pr, (11, 11), (-1, -1), term)
            pl, pr = pl.reshape(-1, 2), pr.reshape(-1, 2)
            dy.extend(np.abs(pl[:, 1] - pr[:, 1]).tolist())
    dy = np.array(dy)
    black = max(int((rl == 0).sum() + (rr == 0).sum()) for rl, rr in rect)
    print(f"chessboard: {len(names)} pairs ({', '.join(names)}) in {out_dir}: calibration RMS "
          f"left {rms_l:.3f} px, right {rms_r:.3f} px, stereo {rms:.3f} px; rectified "
          f"fx {fx:.1f} fy {fy:.1f} cx {cx:.1f} cy {cy:.1f} px, baseline {baseline * 1e3:.1f} mm; "
          f"row difference of the board corners after rectification: median {np.median(dy):.3f} "
          f"px, max {dy.max():.3f} px ({dy.size} corners); most zero pixels in a pair: {black}")
    return names


# Motorcycle (Middlebury 2014, scikit-image, 4x down-sampled: 741x500), calibration from the
# docstring of skimage.data.stereo_motorcycle (as tools/middlebury_eval.py).
MOTO_F_PX, MOTO_CX_PX, MOTO_CY_PX = 994.978, 311.193, 254.877
MOTO_DOFFS_PX, MOTO_BASELINE_M = 31.086, 0.193001
TILT_STEP_DEG = 0.15
TILT_PATTERN = [0, 1, 2, 3, 2, 1, 0, -1, -2, -3, -2, -1] * 2 + [0]


def export_tilt(out_dir):
    """Real motorcycle pair, SYNTHETIC motion: the rig turned about its baseline (the left
    camera's x axis) by TILT_STEP_DEG x TILT_PATTERN. A rotation about the line through both
    optical centres keeps the pair rectified and moves no centre, so each image is exactly the
    homography K R K^-1 of the original (bilinear resampling, like a rectification); the crop
    windows put both principal points at the same column (disparity offset removed)."""
    import cv2
    from skimage import color, data
    left, right, _ = data.stereo_motorcycle()
    grey = [np.clip(np.rint(color.rgb2gray(im) * 255.0), 0, 255).astype(np.uint8)
            for im in (left, right)]
    # Output principal point: left crop at column 69, row 10 of the left image.
    cx, cy = MOTO_CX_PX - 69.0, MOTO_CY_PX - 10.0
    k_out = np.array([[MOTO_F_PX, 0, cx], [0, MOTO_F_PX, cy], [0, 0, 1]])
    k_src = [np.array([[MOTO_F_PX, 0, MOTO_CX_PX + off], [0, MOTO_F_PX, MOTO_CY_PX], [0, 0, 1]])
             for off in (0.0, MOTO_DOFFS_PX)]
    os.makedirs(out_dir, exist_ok=True)
    names = []
    for k, step in enumerate(TILT_PATTERN):
        a = np.radians(TILT_STEP_DEG * step)
        rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        name = f"{k:02d}"
        for side, img, ks in zip(("left", "right"), grey, k_src):
            h = ks @ rot @ np.linalg.inv(k_out)  # output pixel -> source pixel
            out = cv2.warpPerspective(img, h, (WIDTH, HEIGHT),
                                      flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                      borderMode=cv2.BORDER_REPLICATE)
            write_pgm(os.path.join(out_dir, f"{name}_{side}.pgm"), out)
        names.append(name)
    with open(os.path.join(out_dir, "pairs.txt"), "w") as f:
        f.write("\n".join(names) + "\n")
    with open(os.path.join(out_dir, "calibration.txt"), "w") as f:
        f.write(f"fx_px = {MOTO_F_PX!r}\nfy_px = {MOTO_F_PX!r}\ncx_px = {cx!r}\ncy_px = {cy!r}\n"
                f"baseline_m = {MOTO_BASELINE_M!r}\n")
    print(f"motorcycle-tilt: {len(names)} pairs in {out_dir} (real images, SYNTHETIC rig rotation "
          f"of {TILT_STEP_DEG} deg about the baseline per update, zig-zag)")
    return names


class Clock:
    """Host time per stage of the OpenCV peer (ms, summed)."""

    def __init__(self):
        self.ms = {}
        self.t = time.perf_counter()

    def lap(self, stage):
        now = time.perf_counter()
        self.ms[stage] = self.ms.get(stage, 0.0) + (now - self.t) * 1e3
        self.t = now


def keyframe(cv2, left, right, cal, clock):
    """Features of the left image with stereo 3D points (the OpenCV peer's keyframe)."""
    corners = cv2.goodFeaturesToTrack(left, **GFTT)
    clock.lap("goodFeaturesToTrack")
    if corners is None:
        return np.zeros((0, 1, 2), np.float32), np.zeros((0, 3))
    fwd, st1, _ = cv2.calcOpticalFlowPyrLK(left, right, corners, None, **LK)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(right, left, fwd, None, **LK)
    clock.lap("LK stereo + back-check")
    p0, p1, pb = corners.reshape(-1, 2), fwd.reshape(-1, 2), back.reshape(-1, 2)
    disparity = p0[:, 0] - p1[:, 0]
    good = (st1.ravel() == 1) & (st2.ravel() == 1) \
        & (np.hypot(*(pb - p0).T) <= BACK_CHECK_PX) \
        & (np.abs(p1[:, 1] - p0[:, 1]) <= ROW_CHECK_PX) & (disparity >= MIN_DISPARITY_PX)
    p0, disparity = p0[good], disparity[good]
    z = cal["fx_px"] * cal["baseline_m"] / disparity
    points = np.stack([(p0[:, 0] - cal["cx_px"]) * z / cal["fx_px"],
                       (p0[:, 1] - cal["cy_px"]) * z / cal["fy_px"], z], axis=1)
    clock.lap("numpy (checks, triangulation)")
    return p0.reshape(-1, 1, 2).astype(np.float32), points


def opencv_pass(cv2, pairs, cal):
    """One pass of the OpenCV peer; returns (per-update dicts, stage ms summed over updates)."""
    k_mat = np.array([[cal["fx_px"], 0, cal["cx_px"]], [0, cal["fy_px"], cal["cy_px"]],
                      [0, 0, 1]], float)
    key_px, key_pts = keyframe(cv2, *pairs[0], cal, Clock())
    prev_left = pairs[0][0]
    out, stages = [], Clock()
    for left, right in pairs[1:]:
        t = time.perf_counter()
        stages.t = t
        tracked, inliers, ok, moved, turned = 0, 0, False, -1.0, -1.0
        if len(key_px) >= 6:
            cur, st, _ = cv2.calcOpticalFlowPyrLK(prev_left, left, key_px, None, **LK)
            stages.lap("LK temporal")
            sel = st.ravel() == 1
            tracked = int(sel.sum())
            if tracked >= 6:
                found, rvec, tvec, inl = cv2.solvePnPRansac(
                    key_pts[sel], cur.reshape(-1, 2)[sel].astype(np.float64), k_mat, None,
                    reprojectionError=2.0, iterationsCount=200, confidence=0.999)
                if found and inl is not None and len(inl) >= 6:
                    ok, inliers = True, len(inl)
                    moved = float(np.linalg.norm(tvec)) * 1e3
                    turned = float(np.degrees(np.linalg.norm(rvec)))
            stages.lap("solvePnPRansac")
        stereo_px, stereo_pts = keyframe(cv2, left, right, cal, stages)
        ms = (time.perf_counter() - t) * 1e3
        out.append(dict(ms=ms, ok=ok, error="" if ok else "failed", features=int(len(key_px)),
                        tracked=tracked, inliers=inliers, stereo_matches=int(len(stereo_px)),
                        translation_mm=moved, rotation_deg=turned))
        key_px, key_pts, prev_left = stereo_px, stereo_pts, left
    return out, stages.ms


def build_rust(native=False):
    """The benchmark binary. `native`: built for this machine's CPU (`-C target-cpu=native`, in
    its own target directory), as OpenCV's wheels dispatch their kernels to the CPU's SSE4/AVX2
    at run time; the flight code has no fast-math, so the results must stay bit-identical
    (checked by `compare_sequence`)."""
    cmd = ["cargo", "build", "--release", "-j", "1", "-p", "sim-host", "--example", "vo_speed"]
    env = dict(os.environ)
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target"))
    if native:
        target = os.path.join(target, "vo-speed-native")
        env["CARGO_TARGET_DIR"] = target
        env["RUSTFLAGS"] = (env.get("RUSTFLAGS", "") + " -C target-cpu=native").strip()
    print("building:", " ".join(cmd), "(target-cpu=native)" if native else "", flush=True)
    subprocess.run(cmd, cwd=ROOT, check=True, env=env)
    return os.path.join(target, "release", "examples", "vo_speed")


def rust_pass(binary, seq_dir, profile=False):
    cmd = [binary, seq_dir, "--passes", "1", "--warmup", "1", "--json"]
    run = subprocess.run(cmd + (["--profile"] if profile else []),
                         capture_output=True, text=True, check=True)
    rows = [json.loads(line) for line in run.stdout.splitlines() if line.startswith("{")]
    return [r for r in rows if "profile" not in r], next(
        (r["profile"] for r in rows if "profile" in r), None)


def median_p90(rows):
    ms = np.array([r["ms"] for r in rows])
    return float(np.median(ms)), float(np.percentile(ms, 90))


def mean(rows, key):
    return float(np.mean([r[key] for r in rows if r["ok"]] or [0.0]))


def compare_sequence(cv2, binary, name, seq_dir, passes, native=None):
    """Alternating passes of both pipelines on one sequence; prints its tables."""
    names = [n.strip() for n in open(os.path.join(seq_dir, "pairs.txt")) if n.strip()]
    pairs = [(read_pgm(os.path.join(seq_dir, f"{n}_left.pgm")),
              read_pgm(os.path.join(seq_dir, f"{n}_right.pgm"))) for n in names]
    cal = read_calibration(os.path.join(seq_dir, "calibration.txt"))
    print(f"\n== {name}: {passes} alternating passes of {len(pairs) - 1} updates each", flush=True)
    opencv_pass(cv2, pairs, cal)  # warm-up (the Rust binary warms up in each call)
    flight, peer, per_pass, stage_ms = [], [], [], {}
    flight_native, per_pass_native = [], []
    for p in range(passes):
        f_rows, _ = rust_pass(binary, seq_dir)
        if native:
            n_rows, _ = rust_pass(native, seq_dir)
            flight_native += n_rows
            per_pass_native.append(median_p90(n_rows)[0])
        o_rows, o_stages = opencv_pass(cv2, pairs, cal)
        flight += f_rows
        peer += o_rows
        for k, v in o_stages.items():
            stage_ms[k] = stage_ms.get(k, 0.0) + v / len(o_rows) / passes
        per_pass.append((median_p90(f_rows)[0], median_p90(o_rows)[0]))
        print(f"  pass {p}: flight median {per_pass[-1][0]:.2f} ms, OpenCV median "
              f"{per_pass[-1][1]:.2f} ms", flush=True)
    _, profile = rust_pass(binary, seq_dir, profile=True)
    n = len(pairs) - 1
    print(f"  per update (pass 0): flight | OpenCV  (stereo = matched features of the new "
          f"keyframe; tracked / inliers of the previous keyframe's; angle = rotation found)")
    print(f"  {'pair':>4s} | {'ms':>6s} {'stereo':>6s} {'tracked':>7s} {'inliers':>7s} "
          f"{'angle':>6s} {'result':>24s} | {'ms':>6s} {'stereo':>6s} {'tracked':>7s} "
          f"{'inliers':>7s} {'angle':>6s}")
    for f, o, pair in zip(flight[:n], peer[:n], names[1:]):
        res = "ok" if f["ok"] else f["error"]
        fs = (f"{f['stereo_matches']:6d} {f['tracked']:7d} {f['inliers']:7d} "
              f"{f['rotation_deg']:6.3f}" if f["ok"] else f"{'-':>6s} {'-':>7s} {'-':>7s} {'-':>6s}")
        os_ = (f"{o['stereo_matches']:6d} {o['tracked']:7d} {o['inliers']:7d} "
               f"{o['rotation_deg']:6.3f}")
        print(f"  {pair:>4s} | {f['ms']:6.2f} {fs} {res[:24]:>24s} | {o['ms']:6.2f} {os_}")
    fm, f90 = median_p90(flight)
    om, o90 = median_p90(peer)
    ratios = [o / f for f, o in per_pass]
    print(f"  summary ({len(flight)} updates per pipeline; counts are means over the "
          f"successful updates):")
    print(f"  {'pipeline':44s} {'median ms':>9s} {'p90 ms':>7s} {'success':>8s} "
          f"{'stereo':>6s} {'tracked':>7s} {'inliers':>7s}")
    pipelines = [("flight VO (fsw::vo <150>, flight config)", flight, fm, f90)]
    nm = None
    if native:
        nm, n90 = median_p90(flight_native)
        pipelines.append(("flight VO, built target-cpu=native", flight_native, nm, n90))
    pipelines.append(("OpenCV GFTT+LK+solvePnPRansac (1 thread)", peer, om, o90))
    for label, rows, m, p90 in pipelines:
        print(f"  {label:44s} {m:9.2f} {p90:7.2f} {sum(r['ok'] for r in rows):4d}/{len(rows):<3d} "
              f"{mean(rows, 'stereo_matches'):6.1f} {mean(rows, 'tracked'):7.1f} "
              f"{mean(rows, 'inliers'):7.1f}")
    print(f"  ratio OpenCV / flight (median): {om / fm:.2f}x (per pass {min(ratios):.2f}-"
          f"{max(ratios):.2f}x); issue-18 goals: flight median <= 10 ms "
          f"{'met' if fm <= 10.0 else 'NOT met'}, >= 2x OpenCV {'met' if om / fm >= 2.0 else 'NOT met'}")
    if native:
        strip = [{k: v for k, v in r.items() if k != "ms"} for r in flight]
        same = strip == [{k: v for k, v in r.items() if k != "ms"} for r in flight_native]
        ratios_n = [o / f for f, (_, o) in zip(per_pass_native, per_pass)]
        print(f"  ratio OpenCV / flight built for this CPU (median): {om / nm:.2f}x (per pass "
              f"{min(ratios_n):.2f}-{max(ratios_n):.2f}x), >= 2x OpenCV "
              f"{'met' if om / nm >= 2.0 else 'NOT met'}; results of the two builds "
              f"{'bit-identical' if same else 'DIFFERENT'} (every field but the time)")
        if not same:
            raise SystemExit("the native build changed the flight VO's results")
    if profile:
        print("  flight host time per update by work kind (extra pass, one item per step): " +
              ", ".join(f"{k} {v['ms_per_update']:.2f} ms ({v['items_per_update']:.0f})"
                        for k, v in profile.items()))
    print("  OpenCV host time per update by stage: " +
          ", ".join(f"{k} {v:.2f} ms" for k, v in stage_ms.items()))
    return fm, f90, om, o90, nm


def main():
    args = sys.argv[1:]
    out_dir = next((a for i, a in enumerate(args) if not a.startswith("--")
                    and (i == 0 or args[i - 1] not in ("--passes", "--cpu"))), "/tmp/vo_speed")
    passes = int(args[args.index("--passes") + 1]) if "--passes" in args else 5
    cpu = int(args[args.index("--cpu") + 1]) if "--cpu" in args else 0
    sequences = [("chessboard (real pairs, fixed camera, moving board)",
                  os.path.join(out_dir, "chessboard"), export_chessboard),
                 ("motorcycle-tilt (real pair, SYNTHETIC rig rotation)",
                  os.path.join(out_dir, "motorcycle-tilt"), export_tilt)]
    for _, seq_dir, export in sequences:
        export(seq_dir)
    if "--export-only" in args:
        return
    binary = build_rust()
    native = build_rust(native=True) if "--native" in args else None
    os.sched_setaffinity(0, {cpu})
    import cv2
    cv2.setNumThreads(1)
    print(f"pinned to CPU {cpu} (children inherit); OpenCV {cv2.__version__}, "
          f"{cv2.getNumThreads()} thread(s)", flush=True)
    results = [(name,) + compare_sequence(cv2, binary, name, seq_dir, passes, native)
               for name, seq_dir, _ in sequences]
    print("\n== summary: time per update, one core")
    print(f"  {'sequence':52s} {'flight med/p90 ms':>17s} {'OpenCV med/p90 ms':>17s} {'ratio':>6s}"
          + (f" {'native med ms':>13s} {'ratio':>6s}" if native else ""))
    for name, fm, f90, om, o90, nm in results:
        print(f"  {name:52s} {fm:8.2f}/{f90:<8.2f} {om:8.2f}/{o90:<8.2f} {om / fm:5.2f}x"
              + (f" {nm:13.2f} {om / nm:5.2f}x" if nm else ""))


if __name__ == "__main__":
    main()
