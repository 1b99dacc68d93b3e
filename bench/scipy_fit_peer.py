#!/usr/bin/python3
"""SciPy peer of bench/fit_default_bench.cc: fits z(x, y) to the bench's scattered points with
scipy.interpolate.LSQBivariateSpline (FITPACK surfit, cubic, uniform interior knots) and prints one JSON line
(seconds and CPU seconds of the fit call alone, the truth RMS on the bench's grid).

    /usr/bin/python3 bench/scipy_fit_peer.py POINTS.csv GRID.csv POLES [POLES ...]

POINTS.csv: x,y,z per line (mm), no header. GRID.csv: x,y,f per line, f the true surface there.
POLES: coefficients per direction (POLES - 4 uniform interior knots over the points' box); one line each.
Needs Debian's python3-scipy (the interpreter at /usr/bin/python3).
"""
import json
import sys
import time

import numpy as np
import scipy
from scipy.interpolate import LSQBivariateSpline


def main():
    pts = np.loadtxt(sys.argv[1], delimiter=",")
    grid = np.loadtxt(sys.argv[2], delimiter=",")
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    for poles in (int(a) for a in sys.argv[3:]):
        tx = np.linspace(x.min(), x.max(), poles - 2)[1:-1]
        ty = np.linspace(y.min(), y.max(), poles - 2)[1:-1]
        start = time.perf_counter()
        cpu = time.process_time()
        spline = LSQBivariateSpline(x, y, z, tx, ty, kx=3, ky=3)
        seconds = time.perf_counter() - start
        cpu = time.process_time() - cpu
        err = spline.ev(grid[:, 0], grid[:, 1]) - grid[:, 2]
        fit = spline.ev(x, y) - z
        print(json.dumps({"poles": poles, "seconds": seconds, "cpu_s": cpu,
                          "truth_rms_um": float(np.sqrt(np.mean(err ** 2)) * 1e3),
                          "truth_max_um": float(np.max(np.abs(err)) * 1e3),
                          "residual_rms_um": float(np.sqrt(np.mean(fit ** 2)) * 1e3),
                          "scipy": scipy.__version__}), flush=True)


if __name__ == "__main__":
    main()
