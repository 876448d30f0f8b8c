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


if __name__ == "__main__":
    main()
    export_aloe(sys.argv[1] if len(sys.argv) > 1 else "/tmp/middlebury")
