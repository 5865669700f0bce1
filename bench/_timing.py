"""Small timing helpers shared by the benchmark scripts (not a test: prints, never asserts)."""
from __future__ import annotations

import json
import platform
import sys
import time

import numpy as np


def time_calls(fn, repeat: int, warmup: int = 3) -> np.ndarray:
    """Wall time of each of ``repeat`` calls of ``fn()``, in seconds (after ``warmup`` calls)."""
    for _ in range(warmup):
        fn()
    out = np.empty(repeat)
    clock = time.perf_counter_ns
    for i in range(repeat):
        t0 = clock()
        fn()
        out[i] = clock() - t0
    return out * 1e-9


def stats(samples_s: np.ndarray, per: int = 1) -> dict:
    """Median and p99 in microseconds (divided by ``per`` items per call)."""
    s = np.asarray(samples_s) / per * 1e6
    return {"median_us": float(np.median(s)), "p99_us": float(np.percentile(s, 99)), "n": int(s.size)}


def best_round(rounds: list) -> dict:
    """Statistics of the round with the lowest median (as :func:`stats`), plus every round's median.

    A shared machine has slow phases longer than one round; the quietest round is the figure
    that repeats (``timeit``'s advice), and the spread of the medians shows the noise."""
    medians = [float(np.median(r)) for r in rounds]
    best = rounds[int(np.argmin(medians))]
    return {**stats(best), "round_medians_us": [round(m * 1e6, 2) for m in medians]}


def round_ratio(slow: list, fast: list) -> float:
    """Median over rounds of median(slow round) / median(fast round), the rounds interleaved
    so that each pair saw the same state of the machine."""
    return round(float(np.median([np.median(a) / np.median(b) for a, b in zip(slow, fast)])), 2)


def emit(name: str, results: dict) -> None:
    """Print the benchmark's JSON document (one per script) on stdout."""
    doc = {
        "benchmark": name,
        "python": sys.version.split()[0],
        "machine": platform.machine(),
        "note": "medians and ratios measured in the same run; the machine is shared and noisy",
        "results": results,
    }
    print(json.dumps(doc, indent=2, sort_keys=False))
