#!/usr/bin/python3
"""numpy + SciPy peer of bench/moran_bench.cc --knn: k-nearest-neighbour weights by scipy.spatial.cKDTree
(row-standardised, as a scipy.sparse CSR matrix) and the global Moran's I with its normality and
randomisation variances (Cliff & Ord; the formulas of PySAL's esda.Moran) in numpy, on the points the bench
wrote. Prints one JSON line: wall and CPU seconds of the weights and of Moran's I (best of `repeat`), I, E[I], the two
variances, and the neighbour lists' SHA-256; the lists themselves (n × k little-endian int32, each row
ascending) go to POINTS.bin.rows for the bench to compare with formloop's.

    /usr/bin/python3 bench/knn_moran_peer.py POINTS.bin N K REPEAT WORKERS

WORKERS: cKDTree.query's workers (1 = one thread, -1 = all cores).

POINTS.bin: n rows of (u, v, y) as little-endian float64. Needs Debian's python3-scipy.
"""
import hashlib
import json
import sys
import time

import numpy as np
import scipy.sparse
from scipy.spatial import cKDTree


def weights(uv, k, workers):
    n = uv.shape[0]
    _, idx = cKDTree(uv).query(uv, k=k + 1, workers=workers)
    if (idx[:, 0] == np.arange(n)).all():
        cols = idx[:, 1:]
    else:  # a coincident point came before the point itself: drop the point wherever it is
        keep = idx != np.arange(n)[:, None]
        keep[keep.sum(axis=1) > k, -1] = False
        cols = idx[keep].reshape(n, k)
    indptr = np.arange(0, n * k + 1, k)
    w = scipy.sparse.csr_matrix((np.full(n * k, 1.0 / k), cols.ravel(), indptr), shape=(n, n))
    return w, cols


def moran(y, w):
    n = y.shape[0]
    z = y - y.mean()
    m2 = z @ z
    s0 = w.sum()
    wt = w.T.tocsr()
    s1 = 0.5 * ((w + wt).power(2)).sum()
    rs = np.asarray(w.sum(axis=1)).ravel()
    cs = np.asarray(w.sum(axis=0)).ravel()
    s2 = ((rs + cs) ** 2).sum()
    i = n / s0 * (z @ (w @ z)) / m2
    ei = -1.0 / (n - 1)
    vn = (n * n * s1 - n * s2 + 3 * s0 * s0) / ((n * n - 1) * s0 * s0) - ei * ei
    b2 = n * (z ** 4).sum() / (m2 * m2)
    vr = (n * ((n * n - 3 * n + 3) * s1 - n * s2 + 3 * s0 * s0) - b2 * ((n * n - n) * s1 - 2 * n * s2 + 6 * s0 * s0)) / (
        (n - 1) * (n - 2) * (n - 3) * s0 * s0) - ei * ei
    return i, ei, vn, vr


def main():
    path, n, k, repeat, workers = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
    data = np.fromfile(path, dtype="<f8").reshape(n, 3)
    uv, y = np.ascontiguousarray(data[:, :2]), data[:, 2].copy()
    best_w = best_i = cpu_w = cpu_i = float("inf")
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        w, cols = weights(uv, k, workers)
        t1, c1 = time.perf_counter(), time.process_time()
        i, ei, vn, vr = moran(y, w)
        t2, c2 = time.perf_counter(), time.process_time()
        best_w, best_i = min(best_w, t1 - t0), min(best_i, t2 - t1)
        cpu_w, cpu_i = min(cpu_w, c1 - c0), min(cpu_i, c2 - c1)
    rows = np.sort(cols, axis=1).astype("<i4")
    rows.tofile(path + ".rows")
    print(json.dumps({"weights_s": best_w, "moran_s": best_i, "weights_cpu_s": cpu_w, "moran_cpu_s": cpu_i, "i": i, "expected": ei, "variance_normality": vn,
                      "variance_randomisation": vr,
                      "neighbours_sha256": hashlib.sha256(rows.tobytes()).hexdigest()}))


if __name__ == "__main__":
    main()
