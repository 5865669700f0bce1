"""Benchmark: session recording and offline replay.

Peers timed in the same run:

* ``append``            - :meth:`SessionWriter.append` with the 17 fields a live loop gives, per tick
  (default settings: streamed to the journal by the writer thread, never blocking);
* ``append_list_peer``  - the naive alternative: a Python list of per-tick dicts (no file format);
* ``close`` / ``load``  - merging the journal into the HDF5 file (gzip, checksums, seal, atomic) and
  reading + checking it back (seal, schema, checksums);
* ``replay_loop``       - the replay's model loop per tick (``ARModel.tick``, the unchecked path);
* ``step_peer``         - the validated :meth:`ARModel.step` per tick, which a naive replay would call;
* ``replay_total``      - :func:`replay` end to end (model loop, replay.h5, forces.csv, the figures).

Usage: ``python bench/session_replay.py [--ticks 20000]``. Prints one JSON document.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit, stats  # noqa: E402

from arsurf.contact.maugis_dugdale import MaugisDugdale  # noqa: E402
from arsurf.force.cantilever import Cantilever  # noqa: E402
from arsurf.replay.replay import replay  # noqa: E402
from arsurf.assembly import build_model, session_metadata  # noqa: E402
from arsurf.sessions.reader import load_session  # noqa: E402
from arsurf.sessions.schema import contact_fields  # noqa: E402
from arsurf.sessions.writer import SessionWriter  # noqa: E402
from arsurf.scan import synthetic  # noqa: E402
from arsurf.scan.io import save_scan  # noqa: E402

R = 20e-9


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=20000)
    n = ap.parse_args().ticks
    d = Path(tempfile.mkdtemp(prefix="arsurf-bench-"))
    scan_path = save_scan(synthetic.sinusoid(shape=(128, 128), pixel=4e-9, amplitude=3e-9, period=160e-9), d / "s.npz")
    lever = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
    meta = session_metadata(scan=scan_path, tip_radius=R, contact=MaugisDugdale(R, 50e9, 0.1), cantilever=lever,
                            friction=0.3, loop_rate=1000.0)
    setup = build_model(meta)
    m, s = setup.model, setup.surface
    k = np.arange(n)
    x = 100e-9 + 300e-9 * (k / n)
    y = 250e-9 + 50e-9 * np.sin(k / n * 6.0)
    h = s.evaluate(x, y)[..., 2]
    depth = 1.5e-9 * np.sin(np.pi * k / n * 8.0) - 0.5e-9
    pos = np.column_stack([x, y, h + R - depth])
    vel = np.gradient(pos, 1e-3, axis=0)

    ticks = [m.step(pos[i]) for i in range(n)]
    sig = [lever.angles(t.simulated_force) for t in ticks]
    m.reset()

    w = SessionWriter(d / "session.h5", meta)
    t_append = np.empty(n)
    naive = []
    t_naive = np.empty(n)
    clock = time.perf_counter_ns
    for i, t in enumerate(ticks):
        fields = dict(t=i * 1e-3, probe_position=pos[i], probe_velocity=vel[i], signals=sig[i],
                      force=t.simulated_force, device_force=t.simulated_force * 1e6, stylus_position=pos[i] * 1e5,
                      stylus_velocity=vel[i] * 1e5, buttons=1, **contact_fields(t))
        t0 = clock()
        w.append(**fields)
        t_append[i] = clock() - t0
        t0 = clock()
        naive.append(fields)
        t_naive[i] = clock() - t0
    t0 = time.perf_counter()
    w.close()
    t_close = time.perf_counter() - t0
    t0 = time.perf_counter()
    sess = load_session(d / "session.h5")
    t_load = time.perf_counter() - t0

    t_tick = np.empty(n)
    for i in range(n):
        t0 = clock()
        m.tick(pos[i], (sig[i][0], sig[i][1]))
        t_tick[i] = clock() - t0
    m.reset()
    t_step = np.empty(n)
    for i in range(n):
        t0 = clock()
        m.step(pos[i], signals=sig[i])
        t_step[i] = clock() - t0

    t0 = time.perf_counter()
    res = replay(d / "session.h5", scan_path, d / "out", progress=False)
    t_total = time.perf_counter() - t0
    a, nv = stats(t_append * 1e-9), stats(t_naive * 1e-9)
    lp, sp = stats(t_tick * 1e-9), stats(t_step * 1e-9)
    emit("session_replay", {
        "ticks": n,
        "append": a, "append_list_peer": nv, "append_over_list_peer": a["median_us"] / nv["median_us"],
        "dropped_ticks": w.dropped_ticks, "close_s": t_close, "load_s": t_load, "file_bytes": (d / "session.h5").stat().st_size,
        "bytes_per_tick": (d / "session.h5").stat().st_size / n, "loaded_ticks": sess.n_ticks,
        "replay_loop": lp, "step_peer": sp, "loop_over_step_peer": lp["median_us"] / sp["median_us"],
        "replay_total_s": t_total, "replay_ticks_per_s": n / t_total,
        "replay_depth_difference": res.depth_difference, "replay_contact_mismatches": res.contact_mismatches,
    })


if __name__ == "__main__":
    main()
