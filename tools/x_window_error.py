#!/usr/bin/env python3
"""X-distance error of the planar (kin2d) and 3D (kin3d) kinematic odometry over short windows of
travel, as H04 Fig. 17 plots it ("X distance of rover in world frame" over a short, extreme
kinematic simulation: more than 30 % for 2D kinematics).

For every truth sample i, the window ends at the first sample j where the true x has advanced by
W; the error is (dx_est - dx_true) / dx_true of each estimate over [i, j] (estimates interpolated
to the truth's times). Prints, per window length, the largest 2D error with the 3D error of the
same window, the largest |3D| error, and the medians; the whole run first. The largest window is
a worst case picked after the fact: report it as such, not as a pass criterion.

Usage: python3 tools/x_window_error.py OUT_DIR [W ...]   (OUT_DIR of `sim-host run`; default
W = 0.15 0.3 0.5 1.0 m). Needs numpy.
"""
import sys

import numpy as np


def main():
    out = sys.argv[1]
    windows = [float(w) for w in sys.argv[2:]] or [0.15, 0.3, 0.5, 1.0]
    truth = np.loadtxt(f"{out}/truth.tum")
    k2 = np.loadtxt(f"{out}/kin2d.tum")
    k3 = np.loadtxt(f"{out}/kin3d.tum")
    t, x = truth[:, 0], truth[:, 1]
    x2, x3 = np.interp(t, k2[:, 0], k2[:, 1]), np.interp(t, k3[:, 0], k3[:, 1])
    dx = x[-1] - x[0]
    print(f"whole run ({dx:.2f} m of x): 2D x error {100 * (x2[-1] - x2[0] - dx) / dx:+.1f} %, "
          f"3D {100 * (x3[-1] - x3[0] - dx) / dx:+.1f} %")
    for w in windows:
        rows = []
        for i in range(len(t)):
            j = np.searchsorted(x, x[i] + w)  # x is monotonic on a straight forward drive
            if j >= len(t):
                break
            d = x[j] - x[i]
            rows.append((x[i], 100 * (x2[j] - x2[i] - d) / d, 100 * (x3[j] - x3[i] - d) / d))
        if not rows:
            continue
        r = np.array(rows)
        k = int(np.argmax(r[:, 1]))
        print(f"W = {w} m: largest 2D x error {r[k, 1]:+.1f} % from x = {r[k, 0]:.2f} m "
              f"(3D there {r[k, 2]:+.1f} %); largest |3D| {np.abs(r[:, 2]).max():.1f} %; "
              f"median 2D {np.median(r[:, 1]):+.1f} %, 3D {np.median(r[:, 2]):+.1f} %")


if __name__ == "__main__":
    main()
