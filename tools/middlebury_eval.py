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

The images are not committed (licence and size); this tool loads them at run time. Needs
`pip install scikit-image`.
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


if __name__ == "__main__":
    main()
