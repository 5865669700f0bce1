"""Benchmark of scan preprocessing: level (every method) and smooth, against direct peers.

Prints one JSON document: for each size (256^2, 512^2, 1024^2) and operation the median and p99
wall time in milliseconds, and the ratio to its peer timed in the same run:

- level "plane"       vs numpy.linalg.lstsq on an (N, 3) design matrix
- level "polynomial"  (order 3) vs numpy.linalg.lstsq on an (N, 10) monomial design matrix
- level "rows-median" vs numpy: median of np.diff along y, cumulative sum (no NaN handling)
- smooth              vs scipy.ndimage.gaussian_filter (the same kernel, no NaN handling)
- smooth with 1 % NaN (normalised convolution) vs the same peer
"plane-robust", "polynomial-robust", "rows-trimmed" and "scars" have no direct peer in the
Python stack; their ratio is given against least-squares "plane" instead.

Run: python bench/preprocess.py [--quick]
On a loaded machine, OpenBLAS threads fight for the cores and the thin matrix products of the
least-squares fits slow down several times; OPENBLAS_NUM_THREADS=1 gives steadier numbers (the
peers run under the same setting, so the ratios stay fair).
"""
from __future__ import annotations

import json
import platform
import sys
import time

import numpy as np
import scipy
from scipy import ndimage

from arsurf.scan.level import level
from arsurf.scan.scan import Scan
from arsurf.scan.smooth import smooth
from arsurf.scan.synthetic import nanoparticles, rough


def timeit(fn, budget=0.6, min_runs=3, max_runs=30):
    fn()  # warm-up
    times = []
    start = time.perf_counter()
    while len(times) < min_runs or (time.perf_counter() - start < budget and len(times) < max_runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    t = np.array(times) * 1e3
    return {"median_ms": float(np.median(t)), "p99_ms": float(np.percentile(t, 99)), "runs": len(t)}


def _blas_info():
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return "unknown (threadpoolctl not installed)"
    return [{k: d.get(k) for k in ("internal_api", "num_threads")} for d in threadpool_info()]


def make_scan(n: int, rng: np.random.Generator) -> Scan:
    px = 4e-9
    base = rough((n, n), px, rms=1e-9, correlation_length=20e-9, seed=1).heights
    parts = nanoparticles((n, n), px, radius=12e-9, count=n // 16, seed=2).heights
    y, x = np.mgrid[0:n, 0:n] * px
    z = base + parts + 2e-3 * x - 1e-3 * y + rng.normal(0, 3e-9, n)[:, None]
    for _ in range(n // 64):  # scars
        r, c = rng.integers(2, n - 3), rng.integers(0, n - 40)
        z[r, c : c + 40] += 5e-9
    return Scan(z, dx=px, dy=px)


def lstsq_poly(z, order):
    ny, nx = z.shape
    y, x = np.mgrid[0:ny, 0:nx]
    xs = (x.ravel() - nx / 2) / nx
    ys = (y.ravel() - ny / 2) / ny
    A = np.stack([xs**i * ys**j for j in range(order + 1) for i in range(order + 1) if i + j <= order], axis=1)
    c, *_ = np.linalg.lstsq(A, z.ravel(), rcond=None)
    return z - (A @ c).reshape(z.shape)


def rows_median_numpy(z):
    off = np.concatenate([[0.0], np.cumsum(np.median(np.diff(z, axis=0), axis=1))])
    return z - (off - off.mean())[:, None]


def main(sizes=(256, 512, 1024)) -> dict:
    rng = np.random.default_rng(0)
    report = {
        "benchmark": "arsurf scan preprocessing",
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "machine": platform.machine(),
        "blas": _blas_info(),
        "results": {},
    }
    for n in sizes:
        scan = make_scan(n, rng)
        z = scan.heights
        holed = z.copy()
        holed[rng.random(z.shape) < 0.01] = np.nan
        holed_scan = Scan(holed, dx=scan.dx, dy=scan.dy)
        sigma = 2 * scan.dx
        res: dict = {}
        peers = {
            "lstsq_plane": timeit(lambda: lstsq_poly(z, 1)),
            "lstsq_poly3": timeit(lambda: lstsq_poly(z, 3)),
            "numpy_rows_median": timeit(lambda: rows_median_numpy(z)),
            "scipy_gaussian_filter": timeit(lambda: ndimage.gaussian_filter(z, 2.0, mode="reflect")),
        }
        cases = {
            "level_plane": (lambda: level(scan, "plane"), "lstsq_plane"),
            "level_polynomial3": (lambda: level(scan, "polynomial", order=3), "lstsq_poly3"),
            "level_rows_median": (lambda: level(scan, "rows-median"), "numpy_rows_median"),
            "level_rows_trimmed": (lambda: level(scan, "rows-trimmed"), "lstsq_plane"),
            "level_plane_robust": (lambda: level(scan, "plane-robust"), "lstsq_plane"),
            "level_polynomial3_robust": (lambda: level(scan, "polynomial-robust", order=3), "lstsq_poly3"),
            "level_scars": (lambda: level(scan, "scars"), "lstsq_plane"),
            "smooth": (lambda: smooth(scan, sigma), "scipy_gaussian_filter"),
            "smooth_nan_1pct": (lambda: smooth(holed_scan, sigma), "scipy_gaussian_filter"),
        }
        for name, (fn, peer) in cases.items():
            r = timeit(fn)
            r["peer"] = peer
            r["ratio_to_peer"] = r["median_ms"] / peers[peer]["median_ms"]
            res[name] = r
        res["peers"] = peers
        report["results"][f"{n}x{n}"] = res
    return report


if __name__ == "__main__":
    quick = "--quick" in sys.argv
    print(json.dumps(main((256,) if quick else (256, 512, 1024)), indent=2))
