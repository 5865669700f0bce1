"""Benchmark: force decoupling per call - numba kernel vs Python API vs an explicit numpy solve.

Peers timed in the same run, on the same 2,000 random well-posed cases:

* ``kernel_from_python``  - :func:`decouple_kernel` called from Python (dispatcher overhead included),
  parameters and output buffer prepared once (how a Python loop would call it);
* ``kernel_in_njit_loop`` - the same kernel called from compiled code (:func:`decouple_many_kernel`),
  i.e. the cost inside a numba servo step;
* ``python_api``          - :func:`arsurf.decouple` (validation + kernel + result record);
* ``motion_api``          - :func:`arsurf.decouple_by_motion`;
* ``numpy_solve``         - build the 3x3 system of docs/design.rst ("Force from the two angles") and
                            call ``numpy.linalg.solve``.

Per-call times come from batches of calls (the timer costs more than a kernel call); the
distribution over batches gives the median and p99. Prints one JSON document.

Usage: ``python bench/decoupling.py [--cases 2000] [--batch 50] [--repeats 5]``
"""
from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

import numba

from arsurf.force.cantilever import Cantilever
from arsurf.force.decoupling import (
    decouple,
    decouple_by_motion,
    decouple_kernel,
    decouple_many_kernel,
    decoupling_parameters,
)


def cases(size: int, seed: int = 7):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(size, 3))
    n[:, 2] = np.abs(n[:, 2]) + 0.3
    n /= np.linalg.norm(n, axis=1)[:, None]
    ang = rng.uniform(0, 2 * np.pi, size)
    v = 1e-6 * np.column_stack([np.cos(ang), np.sin(ang), np.zeros(size)])
    f = np.column_stack([-v[:, 0], -v[:, 1], (v[:, 0] * n[:, 0] + v[:, 1] * n[:, 1]) / n[:, 2]])
    f /= np.linalg.norm(f, axis=1)[:, None]
    forces = rng.uniform(0, 1e-7, size)[:, None] * n + rng.uniform(-5e-8, 5e-8, size)[:, None] * f
    return n, v, forces


def numpy_solve(bending, torsion, n, v, g, kappa, c):
    f = np.array([-v[0], -v[1], (v[0] * n[0] + v[1] * n[1]) / n[2]])
    p = np.cross(n, f)
    m = np.array([[0.0, c, 0.0], [g * kappa, 0.0, g], p])
    return np.linalg.solve(m, np.array([torsion, bending, 0.0]))


def stats(per_call_ns):
    a = np.asarray(per_call_ns)
    return {"median_ns": float(np.median(a)), "p99_ns": float(np.percentile(a, 99)),
            "mean_ns": float(a.mean()), "batches": int(a.size)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=2000)
    ap.add_argument("--batch", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    lever = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
    n, v, forces = cases(args.cases)
    bending, torsion = lever.angles(forces)
    params = decoupling_parameters(lever)
    g, kappa, c = lever.kernel_parameters()
    out = np.empty(4)
    bl, tl = bending.tolist(), torsion.tolist()
    nl, vl = n.tolist(), v.tolist()
    nx, ny, nz = n[:, 0].tolist(), n[:, 1].tolist(), n[:, 2].tolist()
    vx, vy = v[:, 0].tolist(), v[:, 1].tolist()

    # warm up (compile / load cache) and check the peers agree
    decouple_kernel(bl[0], tl[0], nx[0], ny[0], nz[0], vx[0], vy[0], params, out)
    forces_many = np.empty((args.cases, 3))
    cond = np.empty(args.cases)
    status = np.empty(args.cases, dtype=np.int64)
    decouple_many_kernel(bending, torsion, n, v, params, forces_many, cond, status)
    ref = np.array([numpy_solve(bl[i], tl[i], n[i], v[i], g, kappa, c) for i in range(args.cases)])
    scale = np.linalg.norm(forces, axis=1)
    well = status == 0  # flagged cases use the fallback, which numpy_solve does not model
    agreement = float(np.max(np.linalg.norm(forces_many - ref, axis=1)[well] / scale[well]))
    recovery = float(np.max(np.linalg.norm(forces_many - forces, axis=1)[well] / scale[well]))
    flagged = int((~well).sum())

    peers = {
        "kernel_from_python": lambda i: decouple_kernel(bl[i], tl[i], nx[i], ny[i], nz[i], vx[i], vy[i], params, out),
        "python_api": lambda i: decouple(bl[i], tl[i], nl[i], vl[i], lever),
        "motion_api": lambda i: decouple_by_motion(bl[i], tl[i], vl[i], lever),
        "numpy_solve": lambda i: numpy_solve(bl[i], tl[i], n[i], v[i], g, kappa, c),
    }
    samples: dict[str, list[float]] = {name: [] for name in peers}
    samples["kernel_in_njit_loop"] = []
    b = args.batch
    for _ in range(args.repeats):
        for name, fn in peers.items():
            for start in range(0, args.cases - b + 1, b):
                t0 = time.perf_counter_ns()
                for i in range(start, start + b):
                    fn(i)
                samples[name].append((time.perf_counter_ns() - t0) / b)
        for start in range(0, args.cases - b + 1, b):
            sl = slice(start, start + b)
            t0 = time.perf_counter_ns()
            decouple_many_kernel(bending[sl], torsion[sl], n[sl], v[sl], params, forces_many[sl], cond[sl], status[sl])
            samples["kernel_in_njit_loop"].append((time.perf_counter_ns() - t0) / b)
    # the whole sweep in one compiled call (no per-batch slicing overhead)
    t0 = time.perf_counter_ns()
    decouple_many_kernel(bending, torsion, n, v, params, forces_many, cond, status)
    whole = (time.perf_counter_ns() - t0) / args.cases

    results = {name: stats(x) for name, x in samples.items()}
    k = results["kernel_from_python"]["median_ns"]
    report = {
        "benchmark": "force decoupling per call",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "machine": platform.machine(),
        "cases": args.cases,
        "batch": b,
        "repeats": args.repeats,
        "results": results,
        "kernel_in_njit_loop_whole_sweep_ns": whole,
        "ratios_vs_kernel_from_python": {name: r["median_ns"] / k for name, r in results.items()},
        "numpy_solve_over_kernel_in_loop": results["numpy_solve"]["median_ns"] / results["kernel_in_njit_loop"]["median_ns"],
        "flagged_cases": flagged,
        "max_relative_difference_kernel_vs_numpy_solve": agreement,
        "max_relative_recovery_error": recovery,
        "target_kernel_ns": 1000.0,
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
