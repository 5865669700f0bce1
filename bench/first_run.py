"""Benchmark: the first run on a fresh machine - where numba's compile time goes (issue 28).

Each figure is a fresh process with ``NUMBA_CACHE_DIR`` set to a new, empty folder, and carries
its CPU time (the figure that repeats on a shared machine), its wall time and the load average
before and after it:

* ``demo_empty_cache``: ``arsurf demo --no-images`` on an empty cache, with numba's compilations
  (``numba:compile`` events, which fire only on a cache miss): kernels, specialisations, the
  compile CPU time (exclusive times summed) and the top kernels as [specialisations, CPU s with
  the callees each one compiles, CPU s of its own], and the signatures of every kernel compiled
  more than once;
* ``warmup_empty_cache``: ``python -m arsurf.warmup`` on an empty cache (what ``make setup`` runs once);
* ``demo_after_warmup``: the demo again on that cache (what a user waits for after install), with
  what it still compiled (0 kernels when the warm-up covers the demo);
* ``model_and_1000_ticks_{256,4096}_{after_warmup,empty_cache}``: a 256 x 256 and a 4096 x 4096
  scan's fit + model + first 1000 loop ticks, on the warm-up's cache and on an empty one, and
  the ratios 4096 / 256 of the model and its ticks (CPU and wall; the issue's goal: <= 2, cold
  cache included) and of the whole process (with the scan's synthesis and fit).

Run: .venv/bin/python bench/first_run.py [--skip-4096] [--quick] [--after-warmup]   (prints JSON;
several minutes: every figure compiles from nothing)
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable

_PROFILE = r"""
import json, os, sys, time
from numba.core import event
totals = {}
class Timer(event.Listener):
    # numba:compile fires only on a cache miss; nested events are the callees a kernel compiles:
    # inclusive time counts them, exclusive time does not
    def __init__(self):
        self.stack = []
    def on_start(self, ev):
        self.stack.append([time.process_time(), 0.0])
    def on_end(self, ev):
        t0, inner = self.stack.pop()
        t = time.process_time() - t0
        if self.stack:
            self.stack[-1][1] += t
        d = ev.data["dispatcher"]
        name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
        n, s, x, sigs = totals.get(name, (0, 0.0, 0.0, []))
        totals[name] = (n + 1, s + t, x + t - inner, sigs + [str(ev.data["args"])[:400]])
event.register("numba:compile", Timer())  # (install_listener is a context manager)
from arsurf.cli import main
t0 = time.perf_counter()
main(sys.argv[1:])
print("##" + json.dumps({"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time(), "compiles": totals,
                         "loadavg_1min": os.getloadavg()[0]}), file=sys.stderr)
"""

_TICKS = r"""
import sys, time
t0 = time.perf_counter()
import numpy as np
from arsurf.assembly import PRESETS, build_loop
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.force.cantilever import Cantilever
from arsurf.haptics.device import DeviceState
from arsurf.haptics.virtual_device import VirtualDevice
from arsurf.model import ARModel
from arsurf.scan.synthetic import rough
from arsurf.spline.fit import fit_surface
n = int(sys.argv[1])
scan = rough((n, n), 4e-9, rms=1e-9, correlation_length=20e-9, seed=1)
t_scan = time.perf_counter()
surface = fit_surface(scan)
t_fit = time.perf_counter()
cpu_fit = time.process_time()
tip = 20e-9
model = ARModel(surface, tip, MaugisDugdale(tip, 5e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
(u0, u1), (v0, v1) = surface.domain
x, y = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
haptics = PRESETS["demo"].haptics
dev = VirtualDevice(dt=1.0 / haptics["rate"]).open()
loop = build_loop(model, haptics, dev.info, (x, y, float(surface.evaluate(x, y)[2]) + tip - 1e-9))
state = DeviceState()
for k in range(1000):
    state.timestamp = k / haptics["rate"]
    state.position[0] = 1e-4 * (k % 100)
    loop.step(state, state.timestamp)
t_end = time.perf_counter()
dev.close()
print("##" + __import__("json").dumps({"total_s": t_end - t0, "scan_s": t_scan - t0, "fit_s": t_fit - t_scan,
                                       "model_and_ticks_s": t_end - t_fit,
                                       "model_and_ticks_cpu_s": time.process_time() - cpu_fit}), file=sys.stderr)
"""


def _run(args, cache: str, timeout: float = 3600.0) -> tuple[dict, dict | None]:
    """Wall and CPU time (user + system, s) of ``args`` in a fresh process on ``cache``, the load
    average before it, and its ``##`` JSON line if any. On a shared machine the CPU time is the
    figure that repeats: the wall time adds the waits for a core."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = {"wall_s": round(time.perf_counter() - t0, 2),
            "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 2),
            "loadavg_1min_before": round(load, 2), "loadavg_1min_after": round(os.getloadavg()[0], 2)}
    if r.returncode != 0:
        raise RuntimeError(f"{args} failed ({r.returncode}): {r.stderr[-2000:]}")
    line = next((x for x in r.stderr.splitlines() if x.startswith("##")), None)
    return wall, json.loads(line[2:]) if line else None


def _compiles(prof: dict, top: int = 20) -> dict:
    """numba's compilations in a profiled run: kernels, specialisations, the compile CPU time
    (the sum of the exclusive times) and the ``top`` kernels by exclusive time, each as
    ``[specialisations, inclusive s, exclusive s]``."""
    rows = sorted(prof["compiles"].items(), key=lambda kv: -kv[1][2])
    return {"kernels_compiled": len(rows), "specialisations": sum(v[0] for _, v in rows),
            "compile_cpu_s": round(sum(v[2] for _, v in rows), 2),
            "top_compiles_specialisations_inclusive_exclusive_cpu_s": {
                k: [v[0], round(v[1], 2), round(v[2], 2)] for k, v in rows[:top]},
            "kernels_with_several_specialisations": {k: v[3] for k, v in rows if v[0] > 1}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-4096", action="store_true", help="no 4096 x 4096 figure")
    ap.add_argument("--quick", action="store_true", help="only the demo on an empty cache and after the warm-up")
    ap.add_argument("--after-warmup", action="store_true",
                    help="only the warm-up and the demo after it (the compilations left to the demo)")
    args = ap.parse_args()
    results = {}
    with tempfile.TemporaryDirectory(prefix="arsurf-first-run-") as tmp:
        demo = [PY, "-c", _PROFILE, "demo", "--no-images", "--out"]
        if not args.after_warmup:
            wall, prof = _run([*demo, str(Path(tmp) / "demo1")], str(Path(tmp) / "empty"))
            results["demo_empty_cache"] = {**wall, **_compiles(prof)}
        warm = str(Path(tmp) / "warm")
        results["warmup_empty_cache"] = _run([PY, "-m", "arsurf.warmup", "--quiet"], warm)[0]
        wall, prof = _run([*demo, str(Path(tmp) / "demo2")], warm)
        results["demo_after_warmup"] = {**wall, **_compiles(prof, top=5)}
        if not (args.quick or args.after_warmup):
            sizes = (256,) if args.skip_4096 else (256, 4096)
            for n in sizes:
                wall, parts = _run([PY, "-c", _TICKS, str(n)], warm)
                results[f"model_and_1000_ticks_{n}_after_warmup"] = {**wall, **parts}
            for n in sizes:
                wall, parts = _run([PY, "-c", _TICKS, str(n)], str(Path(tmp) / f"empty{n}"))
                results[f"model_and_1000_ticks_{n}_empty_cache"] = {**wall, **parts}
            if not args.skip_4096:
                for when in ("after_warmup", "empty_cache"):  # the model and its ticks (the figure), the whole process
                    big, small = results[f"model_and_1000_ticks_4096_{when}"], results[f"model_and_1000_ticks_256_{when}"]
                    results[f"ratio_4096_over_256_{when}"] = {
                        "model_and_ticks_cpu": round(big["model_and_ticks_cpu_s"] / small["model_and_ticks_cpu_s"], 2),
                        "model_and_ticks_wall": round(big["model_and_ticks_s"] / small["model_and_ticks_s"], 2),
                        "process_cpu_with_scan_and_fit": round(big["cpu_s"] / small["cpu_s"], 2)}
    emit("first_run", results)


if __name__ == "__main__":
    main()
