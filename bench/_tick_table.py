"""The tick table shared by bench/deformation.py and bench/haptic_loop.py (issue 28).

One rough surface in physical units - Gaussian roughness correlated over 6 nm (or 3 pixels
where the pixels are coarser), 0.5 nm rms: slopes ~0.1 - scanned on 256 x 256 pixels at each
pitch and fitted (:func:`arsurf.scan.synthetic.rough`); a tip of radius R pressed ``depth`` below touching
the surface slides 0.01 nm per tick, dent on.
"""
from __future__ import annotations

import numpy as np

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.force.cantilever import Cantilever
from arsurf.model import ARModel
from arsurf.scan.synthetic import rough
from arsurf.spline.fit import fit_surface

SIZE = 256
#: the coarse default grid (each run well under 2 min on a shared 2-core machine) and --full
PITCHES_NM = (0.1, 0.25, 0.5, 2.0, 8.0)
TIPS_NM = (2.0, 20.0, 50.0)
DEPTHS_NM = (0.3, 1.0)
FULL_PITCHES_NM = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
FULL_TIPS_NM = (2.0, 5.0, 10.0, 20.0, 50.0)
FULL_DEPTHS_NM = (0.1, 0.3, 1.0, 2.0)
STEP = 0.01e-9  # tip slide per tick, m


def rough_surface(pitch: float, seed: int = 0):
    """The 256 x 256 scan at ``pitch`` (m per pixel), fitted (:func:`arsurf.scan.synthetic.rough`)."""
    return fit_surface(rough((SIZE, SIZE), pitch, rms=0.5e-9, correlation_length=max(6e-9, 3.0 * pitch), seed=seed))


def model_on(surface, tip: float, deform: bool = True) -> ARModel:
    """A polystyrene-like sample (E* 5 GPa) under a tip of radius ``tip``, w = 0.05 J/m^2."""
    return ARModel(surface, tip, MaugisDugdale(tip, 5e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27),
                   deform=deform)


def start(surface, tip: float, depth: float) -> np.ndarray:
    """The tip centre ``depth`` below touching the highest rest point within R of the middle."""
    (u0, u1), (v0, v1) = surface.domain
    x, y = 0.5 * (u0 + u1) - 40 * STEP, 0.5 * (v0 + v1)
    g = np.linspace(-tip, tip, 41)
    dx, dy = np.meshgrid(g, g)
    d2 = dx * dx + dy * dy
    near = d2 < tip * tip
    z = surface.evaluate(x + dx[near], y + dy[near])[:, 2]
    top = np.max(z + np.sqrt(tip * tip - d2[near]))
    return np.array([x, y, top - depth])


def parse_cells(text: str | None, default: tuple) -> tuple:
    """A comma-separated list of numbers from the command line (``--pitches 0.1,2``), or ``default``."""
    if not text:
        return default
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise SystemExit(f"expected comma-separated numbers (got {text!r}), e.g. --pitches 0.25,2")
    if not values or not all(v > 0 for v in values):
        raise SystemExit(f"expected positive numbers (got {text!r})")
    return values


def traced(fn, ticks: int, deformer=None, warmup: int = 20, model=None) -> dict:
    """Time ``ticks`` calls of ``fn`` (a tick) with a per-tick trace, to tell where a slow tick's
    time went: wall and thread-CPU time of each tick (a tick whose CPU time is far below its
    wall time was preempted: the machine, not the tick's work), the ticks during which the
    garbage collector ran (``gc.callbacks``), the ticks whose collision rebuilt its warm list
    of candidate cells (``model``'s collision output ``OUT_CACHED`` = 0: a pyramid walk), the
    ticks during which the thread was switched out involuntarily (``getrusage`` RUSAGE_THREAD
    ``ru_nivcsw``: another process took the core), the ticks that moved the net
    (``deformer``'s syncs: a read inside the tick, O((R/h)^2)), the Python blocks allocated
    per tick, and the collision's work (``OUT_CELLS``: knot cells whose box beat the bound, each
    a certificate, a Newton run or a Bézier subdivision; ``OUT_ITERATIONS``: Newton iterations).

    Returns median/p99 of wall and CPU time (us) and, over the ticks slower than 100 us wall,
    how many were preempted (CPU < half the wall, or switched out), ran the GC, rebuilt the
    collision's list, or synced the net."""
    import gc
    import sys
    import time

    for _ in range(warmup):
        fn()
    import resource

    thread_usage = getattr(resource, "RUSAGE_THREAD", resource.RUSAGE_SELF)
    usage = resource.getrusage
    wall = np.empty(ticks, dtype=np.int64)
    switched = np.zeros(ticks, dtype=bool)
    cpu = np.empty(ticks, dtype=np.int64)
    blocks = np.empty(ticks, dtype=np.int64)
    gc_in = np.zeros(ticks, dtype=bool)
    sync_in = np.zeros(ticks, dtype=bool)
    uncached = np.zeros(ticks, dtype=bool)
    cells = np.zeros(ticks)
    newton = np.zeros(ticks)
    coll = None if model is None else model._coll
    from arsurf.contact.layout import OUT_CACHED, OUT_CELLS, OUT_ITERATIONS
    state = {"gc": False, "sync": 0}

    def on_gc(phase, info):
        state["gc"] = True

    restore = None
    if deformer is not None:  # count the syncs that moved the net (an instance attribute shadows the method)
        inner = deformer.sync

        def counting_sync():
            moved = inner()
            state["sync"] += moved >= 0
            return moved

        deformer.sync = counting_sync
        restore = lambda: deformer.__dict__.pop("sync", None)  # noqa: E731
    gc.callbacks.append(on_gc)
    perf, thread, allocated = time.perf_counter_ns, time.thread_time_ns, sys.getallocatedblocks
    try:
        for k in range(ticks):
            state["gc"], state["sync"] = False, 0
            s0 = usage(thread_usage).ru_nivcsw
            b0 = allocated()
            c0 = thread()
            t0 = perf()
            fn()
            t1 = perf()
            c1 = thread()
            blocks[k] = allocated() - b0
            switched[k] = usage(thread_usage).ru_nivcsw > s0
            wall[k], cpu[k] = t1 - t0, c1 - c0
            gc_in[k], sync_in[k] = state["gc"], state["sync"] > 0
            if coll is not None:
                uncached[k] = coll[OUT_CACHED] == 0.0
                cells[k], newton[k] = coll[OUT_CELLS], coll[OUT_ITERATIONS]
    finally:
        gc.callbacks.remove(on_gc)
        if restore:
            restore()
    w, c = wall * 1e-3, cpu * 1e-3
    slow = w > 100.0
    return {"median_us": float(np.median(w)), "p99_us": float(np.percentile(w, 99)), "max_us": float(w.max()),
            "cpu_median_us": float(np.median(c)), "cpu_p99_us": float(np.percentile(c, 99)), "n": int(ticks),
            "ticks_over_100us": int(slow.sum()),
            "over_100us_preempted": int((slow & (c < 0.5 * w)).sum()),
            "over_100us_switched_out": int((slow & switched).sum()), "ticks_switched_out": int(switched.sum()),
            "over_100us_cpu_over_100us": int((slow & (c > 100.0)).sum()),
            "over_100us_with_gc": int((slow & gc_in).sum()), "ticks_with_gc": int(gc_in.sum()),
            "ticks_with_net_sync": int(sync_in.sum()),
            "over_100us_collision_rebuilt_list": int((slow & uncached).sum()),
            "ticks_collision_rebuilt_list": int(uncached.sum()),
            "collision_rebuilt_tick_median_us": float(np.median(w[uncached])) if uncached.any() else 0.0,
            "collision_rebuilt_tick_p99_us": float(np.percentile(w[uncached], 99)) if uncached.any() else 0.0,
            "python_blocks_per_tick_median": float(np.median(blocks)),
            "collision_cells_median": float(np.median(cells)), "collision_cells_p99": float(np.percentile(cells, 99)),
            "collision_newton_iterations_median": float(np.median(newton)),
            "collision_newton_iterations_p99": float(np.percentile(newton, 99)),
            "over_100us_collision_cells_median": float(np.median(cells[slow])) if slow.any() else 0.0}
