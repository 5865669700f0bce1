"""Benchmark: the model tick with the dent on over pitch x tip radius x depth (issue 28).

Table: for every pixel pitch (0.1-8 nm) x tip radius (2-50 nm) x depth, the compiled model
tick (``ARModel.tick``, collision + Maugis-Dugdale + dent + force) sliding 0.01 nm per tick on
a rough 256 x 256 surface (bench/_tick_table.py): median and p99. The tick records its dent
(O(1)); the net is moved to it when read (``surface.sync()``). Peers, same run, same cell:
the tick without the dent, today's eager dent (the net moved every tick: tick + sync), and
the cost of one read of the net after ticks (what a 60 Hz view pays per frame).

``--reader``: the ticks while a second thread reads the net at 60 Hz (a view), on the fine
nets where a read is dearest: the longest and the p99 interval between two ticks, with the
read as it is (the net written without the GIL) and, the peer in the same run, the same read
holding the GIL (``deform_kernel``, the same work on a copy of the net), which stalls the ticks
for its whole duration.

Run: .venv/bin/python bench/deformation.py [--full] [--reader]   (prints JSON; default a coarse grid, ~1 min)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _tick_table as tt  # noqa: E402
from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.model import M_IN_CONTACT, M_MOVED  # noqa: E402

READER_CELLS = ((0.1, 50.0), (0.25, 20.0), (0.25, 50.0), (0.5, 50.0))  # (pitch nm, tip nm): the dearest reads


def cell(surface, tip: float, depth: float, ticks: int) -> dict:
    """One cell of the table: the tick with the dent, without it, eager, and a read of the net."""
    row = {}
    for name, deform, eager in (("tick", True, False), ("tick_no_dent", False, False),
                                ("tick_eager_dent", True, True)):
        model = tt.model_on(surface, tip, deform)
        c = tt.start(surface, tip, depth)
        k = [0]
        tick, sync = model.tick, surface.sync

        def one():
            k[0] += 1
            tick((c[0] + tt.STEP * (k[0] % 80), c[1], c[2]))
            if eager:
                sync()

        n = ticks if not eager else max(ticks // 10, 50)
        row[name] = stats(time_calls(one, n, warmup=20))
        if name == "tick":
            row["in_contact"] = bool(model.out[M_IN_CONTACT])
            row["dent_box_points"] = int(model.out[M_MOVED])

            def read():  # a frame's read of the net after 160 ticks (the view at 60 Hz, the loop at 10 kHz)
                one()
                sync()

            row["read_after_ticks"] = stats(time_calls(read, 30, warmup=2))
        model.reset()
    return row


def tick_intervals_with_reader(surface, tip: float, depth: float, ticks: int, gil: bool) -> dict:
    """The model ticking in this thread while another reads the net at 60 Hz: intervals between
    tick starts (what a haptic thread sees), and the reads' own times. ``gil``: the reader runs
    the same dent kernel holding the GIL, on a copy of the net (the peer)."""
    import threading
    import time

    from arsurf.contact.deformation import D_A, D_CX, D_CY, D_CZ, D_DEPTH, D_NX, D_NY, D_NZ, D_RADIUS, D_ZONE, \
        PROFILE_SIZE, deform_kernel

    model = tt.model_on(surface, tip)
    c = tt.start(surface, tip, depth)
    deformer = model._deformer
    ctrl, rest, ku, kv = (a.copy() for a in surface.raw_arrays())
    profile, patch = np.zeros(PROFILE_SIZE), np.zeros(4, dtype=np.int64)
    stop, reads = threading.Event(), []

    def read():
        while not stop.wait(1.0 / 60.0):
            t0 = time.perf_counter_ns()
            if gil:
                d = deformer.dent
                deform_kernel(ctrl, rest, ku, kv, d[D_CX], d[D_CY], d[D_CZ], d[D_RADIUS], d[D_NX], d[D_NY], d[D_NZ],
                              d[D_A], d[D_DEPTH], d[D_ZONE], profile, patch)
            else:
                surface.sync()
            reads.append(time.perf_counter_ns() - t0)

    tick = model.tick
    for k in range(50):
        tick((c[0] + tt.STEP * (k % 80), c[1], c[2]))
    surface.sync()
    d = deformer.dent   # the peer's kernel compiled (or loaded) before the timing
    deform_kernel(ctrl, rest, ku, kv, d[D_CX], d[D_CY], d[D_CZ], d[D_RADIUS], d[D_NX], d[D_NY], d[D_NZ], d[D_A],
                  d[D_DEPTH], d[D_ZONE], profile, patch)
    starts = np.empty(ticks, dtype=np.int64)
    clock = time.perf_counter_ns
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    for k in range(ticks):
        starts[k] = clock()
        tick((c[0] + tt.STEP * (k % 80), c[1], c[2]))
    stop.set()
    reader.join()
    model.reset()
    gaps = np.diff(starts) * 1e-3
    return {"tick_interval_median_us": float(np.median(gaps)), "tick_interval_p99_us": float(np.percentile(gaps, 99)),
            "longest_tick_interval_us": float(gaps.max()), "reads": len(reads),
            "read_median_us": float(np.median(reads)) * 1e-3 if reads else None}


def reader_table(ticks: int) -> list:
    """:func:`tick_intervals_with_reader` on the fine nets, the read without and with the GIL, interleaved."""
    rows = []
    for p, r in READER_CELLS:
        s = tt.rough_surface(p * 1e-9)
        row = {"pitch_nm": p, "tip_radius_nm": r, "depth_nm": 1.0}
        for gil in (False, True):
            row["reader_holding_gil" if gil else "reader_without_gil"] = tick_intervals_with_reader(
                s, r * 1e-9, 1e-9, ticks, gil)
        rows.append(row)
        print(f"pitch {p} nm, R {r} nm: longest tick interval {row['reader_without_gil']['longest_tick_interval_us']:.0f} "
              f"us (GIL-holding read: {row['reader_holding_gil']['longest_tick_interval_us']:.0f} us)", file=sys.stderr)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="the whole table (several minutes)")
    ap.add_argument("--ticks", type=int, default=3000)
    ap.add_argument("--reader", action="store_true", help="only the ticks with a 60 Hz reader in another thread")
    args = ap.parse_args()
    if args.reader:
        emit("deformation_reader", {"rows": reader_table(max(args.ticks, 20000))})
        return
    pitches = tt.FULL_PITCHES_NM if args.full else tt.PITCHES_NM
    tips = tt.FULL_TIPS_NM if args.full else tt.TIPS_NM
    depths = tt.FULL_DEPTHS_NM if args.full else tt.DEPTHS_NM
    rows = []
    for p in pitches:
        s = tt.rough_surface(p * 1e-9)
        for r in tips:
            for d in depths:
                rows.append({"pitch_nm": p, "tip_radius_nm": r, "depth_nm": d,
                             **cell(s, r * 1e-9, d * 1e-9, args.ticks)})
                print(f"pitch {p} nm, R {r} nm, depth {d} nm: tick {rows[-1]['tick']['median_us']:.1f} us "
                      f"(eager {rows[-1]['tick_eager_dent']['median_us']:.1f} us)", file=sys.stderr)
    med = [r["tick"]["median_us"] for r in rows]
    p99 = [r["tick"]["p99_us"] for r in rows]

    def at(p, r):
        return float(np.median([x["tick"]["median_us"] for x in rows if x["pitch_nm"] == p and x["tip_radius_nm"] == r]))

    summary = {"cells": len(rows), "max_median_us": max(med), "max_p99_us": max(p99),
               "cells_over_40us_median": sum(m > 40 for m in med), "cells_over_100us_p99": sum(m > 100 for m in p99)}
    if 20.0 in tips and 0.25 in pitches and 2.0 in pitches:
        summary["R20_median_0.25nm_over_2nm"] = at(0.25, 20.0) / at(2.0, 20.0)
    emit("deformation", {"summary": summary, "surface": f"{tt.SIZE}x{tt.SIZE} px, 0.5 nm rms, correlated over max(6 nm, 3 px)", "rows": rows})


if __name__ == "__main__":
    main()
