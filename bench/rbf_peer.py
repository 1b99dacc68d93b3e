#!/usr/bin/python3
"""SciPy peer of bench/compensate_field_bench.cc: the thin-plate deviation field by
scipy.interpolate.RBFInterpolator(kernel='thin_plate_spline', degree=1, smoothing=0) fitted to the bench's
samples and evaluated at its query points. Prints one JSON line: wall and CPU seconds of the fit and of the
evaluation; the values go to QUERIES.bin.values (little-endian float64) for the bench to compare.

    /usr/bin/python3 bench/rbf_peer.py SAMPLES.bin N_SAMPLES QUERIES.bin N_QUERIES

SAMPLES.bin: rows (u, v, ds_um); QUERIES.bin: rows (u, v); little-endian float64. Needs python3-scipy.
"""
import json
import sys
import time

import numpy as np
from scipy.interpolate import RBFInterpolator


def main():
    samples = np.fromfile(sys.argv[1], dtype="<f8").reshape(int(sys.argv[2]), 3)
    queries = np.fromfile(sys.argv[3], dtype="<f8").reshape(int(sys.argv[4]), 2)
    t0, c0 = time.perf_counter(), time.process_time()
    rbf = RBFInterpolator(samples[:, :2], samples[:, 2], kernel="thin_plate_spline", degree=1, smoothing=0.0)
    t1, c1 = time.perf_counter(), time.process_time()
    values = rbf(queries)
    t2, c2 = time.perf_counter(), time.process_time()
    values.astype("<f8").tofile(sys.argv[3] + ".values")
    print(json.dumps({"fit_s": t1 - t0, "fit_cpu_s": c1 - c0, "evaluate_s": t2 - t1, "evaluate_cpu_s": c2 - c1}))


if __name__ == "__main__":
    main()
