"""Benchmark: bicubic fit and evaluation against scipy, and numba's compile/cache cost.

Run: .venv/bin/python bench/spline.py   (prints JSON)
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import NdBSpline, RectBivariateSpline, make_interp_spline

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.scan.scan import Scan  # noqa: E402
from arsurf.spline import basis  # noqa: E402
from arsurf.spline.fit import fit_surface  # noqa: E402


def scipy_ndbspline(x, y, z):
    """Tensor-product interpolating NdBSpline built from two make_interp_spline passes."""
    sx = make_interp_spline(x, z.T, k=3)              # along x, (nx, ny) coefficients
    sy = make_interp_spline(y, sx.c.T, k=3)           # along y
    return NdBSpline((sx.t, sy.t), sy.c.T, 3)


def bench_fit(n: int, rng) -> dict:
    z = rng.normal(size=(n, n)) * 1e-9
    scan = Scan(z, dx=1e-9, dy=1e-9)
    x = y = scan.x
    rep = 15 if n <= 512 else 7
    ours = time_calls(lambda: fit_surface(scan), rep, warmup=1)
    rbs = time_calls(lambda: RectBivariateSpline(y, x, z, s=0), rep, warmup=1)
    nd = time_calls(lambda: scipy_ndbspline(x, y, z), max(3, rep // 3), warmup=1)
    return {
        "arsurf_fit_ms": float(np.median(ours) * 1e3),
        "scipy_RectBivariateSpline_s0_ms": float(np.median(rbs) * 1e3),
        "scipy_make_interp_spline_NdBSpline_ms": float(np.median(nd) * 1e3),
        "ratio_arsurf_over_RectBivariateSpline": float(np.median(ours) / np.median(rbs)),
        "ratio_arsurf_over_NdBSpline": float(np.median(ours) / np.median(nd)),
    }


def bench_eval(rng) -> dict:
    n = 512
    z = rng.normal(size=(n, n)) * 1e-9
    scan = Scan(z, dx=1e-9, dy=1e-9)
    s = fit_surface(scan)
    nd = scipy_ndbspline(scan.x, scan.y, z)
    u0, v0 = 100.3e-9, 200.7e-9
    res = {
        "single_point_python_d0": stats(time_calls(lambda: s.evaluate(u0, v0, 0), 20000)),
        "single_point_python_d1": stats(time_calls(lambda: s.evaluate(u0, v0, 1), 20000)),
        "single_point_python_d2": stats(time_calls(lambda: s.evaluate(u0, v0, 2), 20000)),
    }
    ctrl, _, ku, kv = s.kernel_arrays()
    out = np.empty((6, 3))
    res["single_point_kernel_call_d2"] = stats(
        time_calls(lambda: basis.surface_point(ctrl, ku, kv, u0, v0, 2, out), 20000))
    m = 100_000
    us = rng.uniform(0, (n - 1) * 1e-9, m)
    vs = rng.uniform(0, (n - 1) * 1e-9, m)
    for order in (0, 1, 2):
        res[f"batch_ns_per_point_d{order}"] = stats(time_calls(lambda: s.evaluate(us, vs, order), 7), per=m)
        res[f"batch_ns_per_point_d{order}"] = {k: (v * 1e3 if k.endswith("_us") else v)
                                              for k, v in res[f"batch_ns_per_point_d{order}"].items()}
    # the same on a regular grid (how the viewer and exports sample): coherent memory access
    gu, gv = (a.ravel().copy() for a in np.meshgrid(np.linspace(0, (n - 1) * 1e-9, 316),
                                                     np.linspace(0, (n - 1) * 1e-9, 316)))
    for order in (0, 1, 2):
        st = stats(time_calls(lambda: s.evaluate(gu, gv, order), 7), per=gu.size)
        res[f"grid_batch_ns_per_point_d{order}"] = {k: (v * 1e3 if k.endswith("_us") else v) for k, v in st.items()}
    # peers: NdBSpline value / derivatives (z only: 1 component, where ours gives all 3)
    pts = np.column_stack([us, vs])
    for order, nus in ((0, [(0, 0)]), (1, [(0, 0), (1, 0), (0, 1)]),
                       (2, [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)])):
        t = time_calls(lambda: [nd(pts, nu=nu) for nu in nus], 3, warmup=1)
        res[f"scipy_NdBSpline_batch_ns_per_point_d{order}"] = float(np.median(t) / m * 1e9)
        res[f"ratio_batch_d{order}_arsurf_over_NdBSpline"] = (
            res[f"batch_ns_per_point_d{order}"]["median_us"] / res[f"scipy_NdBSpline_batch_ns_per_point_d{order}"])
    t = time_calls(lambda: nd(np.array([[u0, v0]]), nu=(1, 1)), 2000)
    res["scipy_NdBSpline_single_point_one_derivative"] = stats(t)
    return res


_FIRST_CALL = """
import time, numpy as np
t0 = time.perf_counter()
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface
s = fit_surface(Scan(np.zeros((8, 8)), dx=1e-9, dy=1e-9))
s.evaluate(1e-9, 1e-9, 2); s.evaluate(np.zeros(3), np.zeros(3), 2)
print(time.perf_counter() - t0)
"""


def bench_jit() -> dict:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        runs = []
        for _ in range(2):
            out = subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, capture_output=True, text=True, check=True)
            runs.append(float(out.stdout.strip()))
    return {"first_process_import_fit_eval_s (compiles)": runs[0],
            "second_process_same_s (numba cache=True)": runs[1],
            "ratio_cached_over_cold": runs[1] / runs[0]}


def main() -> None:
    rng = np.random.default_rng(1)
    t0 = time.perf_counter()
    results = {"fit": {f"{n}x{n}": bench_fit(n, rng) for n in (256, 512, 1024)}}
    results["evaluate"] = bench_eval(rng)
    results["jit"] = bench_jit()
    results["wall_s"] = time.perf_counter() - t0
    emit("spline", results)


if __name__ == "__main__":
    main()
