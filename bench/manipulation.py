"""Benchmark: the nanotube in the live loop, and the offline manipulation tools.

Live loop (one call per haptic tick, the tip moving 0.5 nm per tick):
  * tip-tube overlap test: compiled kernel vs the numpy method (Nanotube.tip_overlap);
  * push while in contact: compiled kernel vs the validated Python wrapper (push()).
Offline: planning a "Z" push sequence, a 5 um engage on the virtual AFM.
Run: .venv/bin/python bench/manipulation.py   (prints JSON)
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.instrument.engage import engage  # noqa: E402
from arsurf.instrument.instrument import VirtualAFM  # noqa: E402
from arsurf.manipulation.nanotube import Nanotube, overlap_kernel, push, push_kernel  # noqa: E402
from arsurf.manipulation.z_strategy import plan_z_pushes  # noqa: E402

R_TIP = 10e-9
STEP = 0.5e-9


def main() -> None:
    results = {}
    tube = Nanotube(1e-6, 20e-9)
    z = tube.axis_height
    rho = R_TIP + tube.radius
    tip = np.array([0.45e-6, -rho - 1e-9, z])

    # -- overlap test ----------------------------------------------------------------------------
    def overlap_kernel_call():
        overlap_kernel(tube.x, tube.y, tube.angle, tube.length, tube.radius, z, tip[0], tip[1], tip[2], R_TIP)

    def overlap_numpy_call():
        tube.tip_overlap(tip, R_TIP)

    k = stats(time_calls(overlap_kernel_call, 20000))
    p = stats(time_calls(overlap_numpy_call, 5000))
    results["tip_overlap"] = {"kernel": k, "numpy_method": p, "ratio_numpy_over_kernel": p["median_us"] / k["median_us"]}

    # -- push in contact, 0.5 nm per tick --------------------------------------------------------
    state = {"pose": tube.pose, "y": -rho - 1e-9}
    L, r = tube.length, tube.radius
    step = L / 50.0

    y_reset = 100e-9  # restart every 200 ticks so that the tip stays in contact with the tube

    def push_kernel_call():
        if state["y"] > y_reset:
            state["pose"], state["y"] = tube.pose, -rho - 1e-9
        x, y, a = state["pose"]
        out = push_kernel(x, y, a, L, r, z, tip[0], state["y"], z, 0.0, STEP, 0.0, R_TIP, step, 0.01, 100000)
        state["pose"] = out[:3]
        state["y"] += STEP

    pk = stats(time_calls(push_kernel_call, 4000))
    cur = {"tube": tube, "y": -rho - 1e-9}

    def push_wrapper_call():
        if cur["y"] > y_reset:
            cur["tube"], cur["y"] = tube, -rho - 1e-9
        res = push(cur["tube"], (tip[0], cur["y"], z), (0.0, STEP), R_TIP)
        cur["tube"] = res.tube
        cur["y"] += STEP

    pw = stats(time_calls(push_wrapper_call, 4000))
    probe = push(tube, (tip[0], -rho - 1e-9, z), (0.0, y_reset + rho + 1e-9), R_TIP, max_substep=STEP)
    assert probe.touched and probe.contacts > 150  # the benchmarked ticks really push
    results["push_in_contact_per_tick"] = {
        "kernel": pk, "wrapper": pw, "ratio_wrapper_over_kernel": pw["median_us"] / pk["median_us"],
        "tick_budget_us_at_1kHz": 1000.0,
    }

    # -- offline: planner and engage -------------------------------------------------------------
    rng = np.random.default_rng(0)
    times, counts = [], []
    for _ in range(20):
        start = Nanotube(1e-6, 20e-9, *rng.uniform(-1e-6, 1e-6, 2), rng.uniform(-np.pi, np.pi))
        goal = (*rng.uniform(-1e-6, 1e-6, 2), rng.uniform(-np.pi, np.pi))
        t0 = time.perf_counter()
        plan = plan_z_pushes(start, goal, R_TIP, position_tolerance=5e-9, angle_tolerance=0.005)
        times.append(time.perf_counter() - t0)
        counts.append(len(plan.pushes))
    results["plan_z_pushes"] = {
        "median_ms": float(np.median(times) * 1e3), "p99_ms": float(np.percentile(times, 99) * 1e3),
        "median_pushes": float(np.median(counts)), "max_pushes": int(max(counts)), "n": len(times),
    }
    t0 = time.perf_counter()
    afm = VirtualAFM(surface=0.0, probe_height=5e-6, seed=1)
    res = engage(afm, setpoint=0.05, force_limit=20e-9)
    wall = time.perf_counter() - t0
    results["engage_5um"] = {
        "wall_s": wall, "simulated_s": res.duration, "samples": len(res.history),
        "fine_steps": res.fine_steps, "coarse_steps": res.coarse_steps, "max_force_nN": res.max_force * 1e9,
        "ratio_simulated_over_wall": res.duration / wall,
    }
    emit("manipulation", results)


if __name__ == "__main__":
    main()
