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

``--read``: the cost of one read of the dented net per pitch x tip (the tiled sync, as shipped)
against the reference full dent of the guard box (``sync_dent_kernel`` on a copy, same dents,
interleaved), and the two nets compared bitwise.

The tick column traces its ticks (bench/_tick_table.py ``traced``: CPU time, preemption, GC,
syncs inside the tick). ``--pitches/--tips/--depths`` pick a subset of cells (runs < 2 min).

Run: .venv/bin/python bench/deformation.py [--full] [--reader] [--read] [--pitches 0.25,2] [--tips 20]
     [--depths 1]   (prints JSON; default a coarse grid)
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
        row[name] = tt.traced(one, n, model._deformer if name == "tick" else None, model=model)
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


def read_table(pitches, tips, depth: float, reads: int) -> list:
    """The cost of one read of the dented net (``surface.sync()`` after a tick, what a frame
    pays: the tiled sync, hull boxes and watchers told, Python included) and its kernel alone
    (:func:`~arsurf.contact.deformation.sync_dent_tiled_kernel`), against the reference full
    dent of the guard box (:func:`~arsurf.contact.deformation.sync_dent_kernel`), each on its
    own copy of the net with the same recorded dents, interleaved, per pitch x tip; the nets
    compared bitwise."""
    import time

    from arsurf.contact.deformation import (DENT_SIZE, PROFILE_SIZE, TILE, sync_dent_kernel, sync_dent_tiled_kernel,
                                            tile_heights_kernel)

    rows = []
    clock = time.perf_counter_ns
    for p in pitches:
        s = tt.rough_surface(p * 1e-9)
        for r in tips:
            model = tt.model_on(s, r * 1e-9)
            c = tt.start(s, r * 1e-9, depth * 1e-9)
            ctrl, rest, ku, kv = s.raw_arrays()
            ref, profile, patch = rest.copy(), np.zeros(PROFILE_SIZE), np.zeros(4, dtype=np.int64)
            tiled = (rest.copy(), np.zeros(DENT_SIZE), np.zeros(PROFILE_SIZE), np.zeros(4, dtype=np.int64))
            tiles = (np.empty(((rest.shape[0] + TILE - 1) // TILE, (rest.shape[1] + TILE - 1) // TILE)),) * 2
            tiles = (tiles[0], tiles[0].copy())
            tile_heights_kernel(rest, *tiles)
            written = np.zeros(8, dtype=np.int64)
            deformer = model._deformer
            shipped, reference, kernel, moved, area = [], [], [], 0, 0
            for k in range(reads + 3):
                model.tick((c[0] + tt.STEP * (k % 80), c[1], c[2]))
                dents = deformer.dent.copy()
                t0 = clock()
                sync_dent_kernel(ref, rest, ku, kv, dents, profile, patch)
                t1 = clock()
                sync_dent_tiled_kernel(tiled[0], rest, ku, kv, dents, tiled[1], tiled[2], tiled[3], *tiles, written)
                t2 = clock()
                moved = deformer.sync()
                t3 = clock()
                tiled[1][:] = dents
                if k >= 3:
                    reference.append((t1 - t0) * 1e-9)
                    kernel.append((t2 - t1) * 1e-9)
                    shipped.append((t3 - t2) * 1e-9)
                    w = written.reshape(-1, 4)
                    area = max(area, int(np.sum(np.maximum(w[:, 1] - w[:, 0], 0) * np.maximum(w[:, 3] - w[:, 2], 0))))
            rows.append({"pitch_nm": p, "tip_radius_nm": r, "depth_nm": depth,
                         "guard_box_points": int((patch[1] - patch[0]) * (patch[3] - patch[2])),
                         "tiles_written_points_max": area, "dented_points": int(moved),
                         "same_net_bitwise": bool(np.array_equal(ctrl, ref) and np.array_equal(tiled[0], ref)),
                         "reference_full_dent_kernel": stats(np.array(reference)),
                         "tiled_kernel": stats(np.array(kernel)), "read": stats(np.array(shipped))})
            x = rows[-1]
            print(f"pitch {p} nm, R {r} nm: reference kernel {x['reference_full_dent_kernel']['median_us']:.0f} us, "
                  f"tiled {x['tiled_kernel']['median_us']:.0f} us, whole read {x['read']['median_us']:.0f} us "
                  f"({x['guard_box_points']} box points, <= {area} in the tiles written, {moved} dented; "
                  f"same {x['same_net_bitwise']})", file=sys.stderr)
            model.reset()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="the whole table (several minutes)")
    ap.add_argument("--ticks", type=int, default=3000)
    ap.add_argument("--reader", action="store_true", help="only the ticks with a 60 Hz reader in another thread")
    ap.add_argument("--read", action="store_true", help="only the cost of a read of the dented net vs pitch "
                    "(the tiled sync against the reference full dent)")
    ap.add_argument("--pitches", help="cells: pitches in nm, comma-separated (default the grid's)")
    ap.add_argument("--tips", help="cells: tip radii in nm, comma-separated")
    ap.add_argument("--depths", help="cells: depths in nm, comma-separated")
    args = ap.parse_args()
    if args.reader:
        emit("deformation_reader", {"rows": reader_table(max(args.ticks, 20000))})
        return
    pitches = tt.parse_cells(args.pitches, tt.FULL_PITCHES_NM if args.full else tt.PITCHES_NM)
    tips = tt.parse_cells(args.tips, tt.FULL_TIPS_NM if args.full else tt.TIPS_NM)
    depths = tt.parse_cells(args.depths, tt.FULL_DEPTHS_NM if args.full else tt.DEPTHS_NM)
    if args.read:
        emit("deformation_read", {"unit_note": "times per read, us; points are control points",
                                  "rows": read_table(pitches, tips, depths[-1], max(args.ticks // 100, 30))})
        return
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
               "cells_over_40us_median": sum(m > 40 for m in med), "cells_over_100us_p99": sum(m > 100 for m in p99),
               "max_cpu_p99_us": max(r["tick"]["cpu_p99_us"] for r in rows),
               "ticks_with_net_sync": sum(r["tick"]["ticks_with_net_sync"] for r in rows)}
    if 20.0 in tips and 0.25 in pitches and 2.0 in pitches:
        summary["R20_median_0.25nm_over_2nm"] = at(0.25, 20.0) / at(2.0, 20.0)
    emit("deformation", {"summary": summary, "surface": f"{tt.SIZE}x{tt.SIZE} px, 0.5 nm rms, correlated over max(6 nm, 3 px)", "rows": rows})


if __name__ == "__main__":
    main()
