#!/usr/bin/python3
"""SciPy peer of bench/tuning_bench.cc: solves the bench's bounded least-squares problems with
scipy.optimize.lsq_linear and prints one JSON line per method (seconds of the solve call alone, cost, status,
iterations).

    /usr/bin/python3 bench/scipy_lsq_peer.py PROBLEM.json METHOD [METHOD ...]

PROBLEM.json: {"shape": [m, n], "a_triplets": [[row, col, value], ...], "b": [...], "lb": [...], "ub": [...]}
METHOD: trf (dense A, lsq_solver='exact', tol=1e-12, as spec §4.4.3), bvls (dense A, tol=1e-12),
        trf-lsmr (scipy.sparse A, lsq_solver='lsmr', tol=1e-12),
        parts (where trf's time goes: numpy.linalg.lstsq for the unconstrained start, the pivoted QR of A it
        factors once, and one regularised solve through that QR as each iteration does).
Needs Debian's python3-scipy (the interpreter at /usr/bin/python3).
"""
import json
import sys
import time

import numpy as np
import scipy
import scipy.sparse
from scipy.optimize import lsq_linear


def main():
    with open(sys.argv[1]) as f:
        p = json.load(f)
    m, n = p["shape"]
    t = np.array(p["a_triplets"])
    rows, cols, vals = t[:, 0].astype(int), t[:, 1].astype(int), t[:, 2]
    b, lb, ub = np.array(p["b"]), np.array(p["lb"]), np.array(p["ub"])
    sparse = scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(m, n))
    dense = sparse.toarray()
    for method in sys.argv[2:]:
        if method == "parts":
            from scipy.linalg import qr
            from scipy.optimize._lsq.trf_linear import regularized_lsq_with_qr
            out = {"method": "parts"}
            start = time.perf_counter()
            np.linalg.lstsq(dense, b, rcond=-1)
            out["lstsq_s"] = time.perf_counter() - start
            start = time.perf_counter()
            q, r, perm = qr(dense, mode="economic", pivoting=True)
            out["qr_s"] = time.perf_counter() - start
            start = time.perf_counter()
            regularized_lsq_with_qr(m, n, r * np.ones(n)[perm], q.T.dot(b), perm, np.full(n, 0.1), copy_R=False)
            out["iteration_solve_s"] = time.perf_counter() - start
            print(json.dumps(out), flush=True)
            continue
        start = time.perf_counter()
        cpu = time.process_time()
        if method == "trf":
            r = lsq_linear(dense, b, bounds=(lb, ub), method="trf", tol=1e-12, lsq_solver="exact")
        elif method == "bvls":
            r = lsq_linear(dense, b, bounds=(lb, ub), method="bvls", tol=1e-12)
        elif method == "trf-lsmr":
            r = lsq_linear(sparse, b, bounds=(lb, ub), method="trf", tol=1e-12, lsq_solver="lsmr")
        else:
            raise SystemExit("unknown method " + method)
        seconds = time.perf_counter() - start
        cpu = time.process_time() - cpu
        print(json.dumps({"method": method, "seconds": seconds, "cpu_s": cpu, "cost": float(r.cost), "status": int(r.status),
                          "nit": int(r.nit), "scipy": scipy.__version__}), flush=True)


if __name__ == "__main__":
    main()
