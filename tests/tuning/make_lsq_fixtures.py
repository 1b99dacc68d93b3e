#!/usr/bin/python3
"""Offline fixture generator for the bounded least-squares tests (spec/tuning-and-link.md §4.4.3).

Builds the §4.2 penalty form (A, b, lb, ub in µm) of the spec's examples 5-8 and of 100 seeded random
offset problems (n, k <= 30, K like real parts), solves each with SciPy's
    scipy.optimize.lsq_linear(A, b, bounds=(lb, ub), method='trf', tol=1e-12, lsq_solver='exact')
and method='bvls', and writes tests/tuning/fixtures/lsq_scipy.json (A as triplets). SciPy is not a build or
run dependency: run this by hand with Debian's interpreter (python3-scipy) and commit the JSON:

    /usr/bin/python3 tests/tuning/make_lsq_fixtures.py

The random problems are drawn with numpy's PCG64 (seed 20210930), independently of the C++ generator.
"""
import json
import os
import sys

import numpy as np
import scipy
from scipy.optimize import lsq_linear

RHO = 1e3
W_C = 1e-4


def penalty_form(K, e_mm, lo_mm, hi_mm, target_mm, weight, dmin_mm, dmax_mm):
    """The §4.2 form: x = [c; t] in µm."""
    K = np.asarray(K, float)
    n, k = K.shape
    w = np.asarray(weight, float) / np.max(weight)
    om = np.sqrt(w)
    A = np.zeros((2 * n + k, k + n))
    b = np.zeros(2 * n + k)
    A[:n, :k] = RHO * om[:, None] * K
    A[:n, k:] = RHO * np.diag(om)
    b[:n] = RHO * om * np.asarray(e_mm) * 1e3
    A[n:n + k, :k] = np.sqrt(W_C) * np.eye(k)
    A[n + k:, k:] = np.diag(om)
    b[n + k:] = om * np.asarray(target_mm) * 1e3
    lb = np.concatenate([-np.asarray(dmax_mm) * 1e3, np.asarray(lo_mm) * 1e3])
    ub = np.concatenate([-np.asarray(dmin_mm) * 1e3, np.asarray(hi_mm) * 1e3])
    return A, b, lb, ub


def spec_examples():
    out = []
    # 5: outer width K=+2 at 20.030, slot K=-2 at 9.970, both ±0.02, one radius wear.
    out.append(("example5", [[2.0], [-2.0]], [0.030, -0.030], [-0.02, -0.02], [0.02, 0.02], [0, 0], [1, 1],
                [-0.05], [0.05]))
    # 6: example 5 with δ in [-0.010, 0.010].
    out.append(("example6", [[2.0], [-2.0]], [0.030, -0.030], [-0.02, -0.02], [0.02, 0.02], [0, 0], [1, 1],
                [-0.010], [0.010]))
    # 7: two outer sizes at 30.020 (w 3) and 40.012 (w 1).
    out.append(("example7", [[2.0], [2.0]], [0.020, 0.012], [-0.02, -0.02], [0.02, 0.02], [0, 0], [3, 1],
                [-0.05], [0.05]))
    # 8: outer K=+2 and slot K=-2, both +0.030 over nominal, ±0.02: infeasible.
    out.append(("example8", [[2.0], [-2.0]], [0.030, 0.030], [-0.02, -0.02], [0.02, 0.02], [0, 0], [1, 1],
                [-0.05], [0.05]))
    return out


def random_problem(rng, index):
    n = int(rng.integers(2, 31))
    k = int(rng.integers(1, min(30, n) + 1))
    kinds = rng.choice(3, size=k, p=[0.45, 0.3, 0.25])
    kinds[0] = 0
    K = np.zeros((n, k))
    for i in range(n):
        j = i if i < k else int(rng.integers(k))
        if kinds[j] == 0:
            K[i, j] = rng.choice([2.0, -2.0, 1.0, -1.0])
        else:
            K[i, j] = rng.choice([1.0, -1.0])
        if rng.random() < 0.3 and k > 1:
            j2 = int(rng.integers(k))
            if j2 != j:
                K[i, j2] = rng.choice([1.0, -1.0])
    half = np.round(rng.uniform(0.010, 0.040, n), 3)
    shape = rng.random(n)
    lo = np.where(shape < 0.6, -half, np.where(shape < 0.8, 0.0, -2 * half))
    hi = np.where(shape < 0.6, half, np.where(shape < 0.8, 2 * half, 0.0))
    centre = rng.random(n) < 0.5
    target = np.where(centre, 0.5 * (lo + hi), 0.0)
    weight = 1.0 + np.floor(rng.uniform(0, 3, n))
    bound = np.where(kinds == 2, 0.1, 0.05)
    tight = rng.random(k) < 0.3  # some offsets with tight bounds so they end on a bound
    dmax = np.where(tight, 0.005, bound)
    dmin = -dmax
    c_true = rng.uniform(-0.6, 0.6, k) * bound
    t_true = 0.5 * (lo + hi) + rng.uniform(-0.5, 0.5, n) * 0.5 * (hi - lo)
    e = K @ c_true + t_true + rng.normal(0, 0.0003, n)
    if rng.random() < 0.2:  # some infeasible ones
        e = e + rng.normal(0, 0.03, n)
    return ("random%03d" % index, K.tolist(), e.tolist(), lo.tolist(), hi.tolist(), target.tolist(),
            weight.tolist(), dmin.tolist(), dmax.tolist())


def solve(name, K, e, lo, hi, target, weight, dmin, dmax):
    A, b, lb, ub = penalty_form(K, e, lo, hi, target, weight, dmin, dmax)
    trf = lsq_linear(A, b, bounds=(lb, ub), method='trf', tol=1e-12, lsq_solver='exact')
    bvls = lsq_linear(A, b, bounds=(lb, ub), method='bvls', tol=1e-12)
    rows, cols = np.nonzero(A)
    return {
        "name": name,
        "n": len(e), "k": len(dmin),
        "shape": list(A.shape),
        "a_triplets": [[int(r), int(c), float(A[r, c])] for r, c in zip(rows, cols)],
        "b": b.tolist(), "lb": lb.tolist(), "ub": ub.tolist(),
        "trf": {"x": trf.x.tolist(), "cost": float(trf.cost), "status": int(trf.status), "nit": int(trf.nit),
                "active_mask": [int(v) for v in trf.active_mask]},
        "bvls": {"x": bvls.x.tolist(), "cost": float(bvls.cost), "status": int(bvls.status), "nit": int(bvls.nit),
                 "active_mask": [int(v) for v in bvls.active_mask]},
    }


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    rng = np.random.Generator(np.random.PCG64(20210930))
    cases = [solve(*ex) for ex in spec_examples()]
    cases += [solve(*random_problem(rng, i)) for i in range(100)]
    out = {"generator": "tests/tuning/make_lsq_fixtures.py", "scipy": scipy.__version__, "numpy": np.__version__,
           "rho": RHO, "w_c": W_C, "cases": cases}
    os.makedirs(os.path.join(here, "fixtures"), exist_ok=True)
    path = os.path.join(here, "fixtures", "lsq_scipy.json")
    with open(path, "w") as f:
        json.dump(out, f, separators=(",", ":"))
        f.write("\n")
    print("wrote %s: %d cases" % (path, len(cases)), file=sys.stderr)


if __name__ == "__main__":
    main()
