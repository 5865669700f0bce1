"""Benchmark: Maugis-Dugdale contact radius from depth, per call, and its accuracy.

Timed in the same run, for lambda = 0.01 ... 100:
  kernel          md_radius_from_depth_kernel inside an @njit loop (the haptic-loop path)
  python_scalar   MaugisDugdale.contact_radius(depth=d), one float per call
  python_array    MaugisDugdale.contact_radius(depth=array), per element
  scipy_brentq    the plain way: brentq on Delta(A) with m from Maugis' first equation by brentq
  adhesion_brentq ContactEngineering's Adhesion MD (A -> P, Delta) inside a brentq on A, if installed
Accuracy: max relative error of the kernel's radius against scipy_brentq over the stable branch.

Run: .venv/bin/python bench/contact_mechanics.py   (prints JSON)
"""
from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit
from scipy.optimize import brentq, minimize_scalar

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.contact.maugis_dugdale import MaugisDugdale, md_radius_from_depth_kernel  # noqa: E402

R, E_STAR, W = 20e-9, 50e9, 0.1
LAMBDAS = (0.01, 0.1, 1.0, 10.0, 100.0)
N_BATCH = 20000


def model(lam: float) -> MaugisDugdale:
    k = 4.0 * E_STAR / 3.0
    return MaugisDugdale(R, E_STAR, W, 0.5 * lam / (R / (math.pi * W * k * k)) ** (1.0 / 3.0))


@njit(cache=True)
def kernel_loop(depths, out, ds, rs, ls, lam, tf, df):
    for i in range(depths.size):
        st, a = md_radius_from_depth_kernel(depths[i], ds, rs, ls, lam, tf, df)
        out[i] = a
    return out


# --- the plain reference (as in tests/contact/test_maugis_dugdale.py) ---------------------------------
def ref_m(A, lam):
    def f(u):
        m = 1.0 + u
        s = math.sqrt(u * (2.0 + u))
        at = math.atan(s)
        return lam * A * A / 2 * (s + (m * m - 2) * at) + 4 * lam * lam * A / 3 * (s * at - m + 1) - 1
    return 1.0 + math.exp(brentq(lambda v: f(math.exp(v)), -600.0, 40.0, xtol=1e-14, rtol=1e-15))


def ref_depth(A, lam):
    m = ref_m(A, lam)
    return A * A - 4.0 / 3.0 * lam * A * math.sqrt((m - 1) * (m + 1))


def ref_fold(lam):
    grid = np.geomspace(1e-3, 20.0, 120)
    vals = [ref_depth(a, lam) for a in grid]
    i = int(np.argmin(vals))
    if i == 0:
        return 1e-6
    r = minimize_scalar(lambda x: ref_depth(math.exp(x), lam), method="bounded",
                        bounds=(math.log(grid[i - 1]), math.log(grid[i + 1])), options={"xatol": 1e-12})
    return math.exp(r.x)


def ref_radius(D, lam, a_fold):
    return brentq(lambda a: ref_depth(a, lam) - D, a_fold, 1e3, xtol=1e-15, rtol=1e-14)


def main() -> None:
    rng = np.random.default_rng(7)
    results: dict = {"per_call": {}, "accuracy": {}}
    try:
        from Adhesion.ReferenceSolutions import MaugisDugdale as AMD
    except ImportError:  # optional peer
        AMD = None
    for lam in LAMBDAS:
        md = model(lam)
        args = md.kernel_args
        lo = md.critical_points().contact_loss_depth
        depths = lo + (3e-9 - lo) * rng.random(N_BATCH) ** 2     # denser near the fold / a -> 0 end
        out = np.empty_like(depths)
        kernel_loop(depths[:4], out[:4], *args)
        k = stats(time_calls(lambda: kernel_loop(depths, out, *args), 40), per=N_BATCH)
        d_iter = iter(np.resize(depths, 200000))
        py = stats(time_calls(lambda: md.contact_radius(depth=next(d_iter)), 3000))
        arr = stats(time_calls(lambda: md.contact_radius(depth=depths), 20), per=N_BATCH)
        a_fold = ref_fold(lam)
        sub = depths[:25]
        it = iter(np.resize(sub, 1000))
        sp = stats(time_calls(lambda: ref_radius(next(it) / md.depth_scale, lam, a_fold), 25, warmup=1))
        entry = {"kernel": k, "python_scalar": py, "python_array": arr, "scipy_brentq": sp}
        entry["ratio_scipy_over_kernel"] = sp["median_us"] / k["median_us"]
        entry["ratio_python_scalar_over_kernel"] = py["median_us"] / k["median_us"]
        if AMD is not None:
            it2 = iter(np.resize(sub, 1000))

            def adhesion_solve():
                D = next(it2) / md.depth_scale
                return brentq(lambda a: float(AMD._load_and_displacement(np.array([a]), lam)[1][0]) - D,
                              a_fold, 1e3, xtol=1e-12)

            ad = stats(time_calls(adhesion_solve, 10, warmup=1))
            entry["adhesion_brentq"] = ad
            entry["ratio_adhesion_over_kernel"] = ad["median_us"] / k["median_us"]
        results["per_call"][f"lambda={lam:g}"] = entry

    # accuracy: kernel vs the plain reference over lambda in [0.01, 100]
    worst_all = 0.0
    for lam in np.geomspace(0.01, 100.0, 9):
        md = model(lam)
        a_fold = ref_fold(lam)
        a_lo = max(a_fold * 1.001, 1e-2)
        errs = []
        for A in np.geomspace(a_lo, 30.0, 16):
            D = ref_depth(A, lam)
            a_ref = ref_radius(D, lam, a_fold if a_fold > 1e-5 else 1e-6)
            st, a = md_radius_from_depth_kernel(D * md.depth_scale, *md.kernel_args)
            errs.append(abs(a / md.radius_scale / a_ref - 1.0))
        worst = float(max(errs))
        worst_all = max(worst_all, worst)
        results["accuracy"][f"lambda={lam:.3g}"] = {"max_rel_err_radius": worst, "n": len(errs)}
    results["accuracy"]["max_rel_err_all"] = worst_all
    results["accuracy"]["note"] = ("kernel radius vs plain nested brentq on Maugis' equations, A from just above "
                                   "the fold (or 1e-2) to 30; spec <= 1e-6")
    results["timestamp"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    emit("contact_mechanics", results)


if __name__ == "__main__":
    main()
