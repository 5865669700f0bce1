"""Benchmark: what the machine itself takes from a real-time loop, with no arsurf in it.

A thread that only reads the monotonic clock in a tight loop records every gap between two
reads longer than ``--min-gap-us``; a gap is time the process did not run (the kernel or the
hypervisor ran something else). From the gaps follows a floor for any loop in this process:
a loop at rate f loses at least floor(g f) - 1 slots in a gap g (the slot it was in when the
gap began may still be served late), and its longest gap between two ticks is at least the
longest gap here. The hypervisor's share is read from the ``steal`` column of /proc/stat
(Linux proc(5): time spent in other operating systems when running in a virtualised
environment), before and after, in ms over all cores.

If this floor is above a loop's goal (issue 28: <= 0.1 % lost slots and no gap > 1 ms at
10 kHz), the goal cannot be met on this machine by any code in the loop.
Run: .venv/bin/python bench/machine_stalls.py [--seconds 30] [--min-gap-us 50]   (prints JSON)
"""
from __future__ import annotations

import argparse
import gc
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit  # noqa: E402


def steal_ms() -> float | None:
    """The hypervisor's stolen time summed over all cores (ms), from /proc/stat; None elsewhere."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
        return int(fields[8]) * 1000.0 / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def clock_gaps(seconds: float, min_gap_s: float) -> np.ndarray:
    """Every gap (s) longer than ``min_gap_s`` between two reads of the monotonic clock, busy for ``seconds``."""
    clock = time.perf_counter
    gaps = []
    gc.disable()
    try:
        t_end = clock() + seconds
        last = clock()
        while last < t_end:
            now = clock()
            if now - last > min_gap_s:
                gaps.append(now - last)
            last = now
    finally:
        gc.enable()
    return np.asarray(gaps)


def floor_for_rate(gaps: np.ndarray, seconds: float, rate_hz: float) -> dict:
    """The slots a loop at ``rate_hz`` must lose in these gaps, as a share of its nominal ticks."""
    lost = np.maximum(np.floor(gaps * rate_hz) - 1, 0).sum()
    return {"rate_Hz": rate_hz, "lost_slots_floor": int(lost),
            "lost_share_floor_percent": round(100.0 * lost / (seconds * rate_hz), 4)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--min-gap-us", type=float, default=50.0)
    a = ap.parse_args(argv)
    s0, t0 = steal_ms(), time.perf_counter()
    gaps = clock_gaps(a.seconds, a.min_gap_us * 1e-6)
    wall = time.perf_counter() - t0
    s1 = steal_ms()
    emit("machine_stalls", {
        "seconds": round(wall, 3),
        "gaps_over_min": int(gaps.size),
        "min_gap_us": a.min_gap_us,
        "gaps_over_1ms": int((gaps > 1e-3).sum()),
        "gaps_over_10ms": int((gaps > 1e-2).sum()),
        "longest_gap_ms": round(float(gaps.max()) * 1e3, 3) if gaps.size else 0.0,
        "time_in_gaps_percent": round(100.0 * float(gaps.sum()) / wall, 3),
        "steal_ms_all_cores": None if s0 is None else round(s1 - s0, 1),
        "floor": [floor_for_rate(gaps, wall, r) for r in (1000.0, 10000.0)],
    })


if __name__ == "__main__":
    main()
