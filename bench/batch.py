"""Benchmark of ``arsurf batch process`` on the real scans: items per second by executor.

The items are the scan files of ``../shared/scans-real`` (or ``$ARSURF_REAL_SCANS``), each linked
``--repeat`` times into a temporary folder so that the pool start-up does not dominate. Each
configuration runs the whole batch (load, inpaint, level "plane", smooth 1 nm, fit, save the
surface) into a fresh output folder, ``--rounds`` times; the JSON gives, per configuration, the
median wall time of ``run_batch`` (worker start-up included: what a user waits), items per second,
and the speed-up over one local worker:

- ``in-process``:   ``workers=0`` (no pool: the floor of the per-item cost)
- ``local-1``:      one worker process
- ``local-2``:      two worker processes
- ``dask-local-2``: a ``dask.distributed.LocalCluster`` of two single-threaded worker processes
  (started once, before the rounds; its start-up time is given apart)

``machine_parallel_speedup`` calibrates the figures: the speed-up of the same pure-Python loop on
two processes over one, measured in each round. On an idle 2-core machine it is ~2; on a shared
one it says how much of the second core the batch could have had.

Run: python bench/batch.py [--repeat 4] [--rounds 3]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from arsurf.batch import collect_inputs, run_batch

REAL_SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[2] / "shared" / "scans-real"))
OPTIONS = {"level": "plane", "sigma": 1e-9}


def _items(tmp: Path, repeat: int) -> tuple[Path, list[str]]:
    files = collect_inputs([REAL_SCANS]).files
    folder = tmp / "scans"
    for k in range(repeat):
        d = folder / f"rep{k}"
        d.mkdir(parents=True)
        for f in files:
            (d / f.name).symlink_to(f)
    return folder, [f.name for f in files]


def _burn(n: int) -> int:
    s = 0
    for i in range(n):
        s += i * i
    return s


def _parallel_speedup() -> float:
    """Wall time of 8 pure-Python loops on one process / on two (pools started before timing)."""
    from concurrent.futures import ProcessPoolExecutor

    times = []
    for w in (1, 2):
        with ProcessPoolExecutor(w) as ex:
            list(ex.map(_burn, [1000] * w))
            t0 = time.perf_counter()
            list(ex.map(_burn, [2_000_000] * 8))
            times.append(time.perf_counter() - t0)
    return times[0] / times[1]


def _run(folder: Path, out: Path, **kwargs) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    r = run_batch("process", [str(folder / "*" / "*")], out, options=OPTIONS, progress=False, **kwargs)
    wall = time.perf_counter() - t0
    return {"wall_s": wall, "ok": r.ok, "failed": r.failed, "errors": list(r.errors)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=4, help="copies of each scan (default 4)")
    ap.add_argument("--rounds", type=int, default=3, help="runs of each configuration (default 3)")
    args = ap.parse_args(argv)
    if not REAL_SCANS.is_dir():
        print(json.dumps({"benchmark": "batch", "skipped": f"{REAL_SCANS} is absent"}))
        return 0
    import distributed

    with tempfile.TemporaryDirectory(prefix="arsurf-bench-batch-") as tmpdir:
        tmp = Path(tmpdir)
        folder, names = _items(tmp, args.repeat)
        n = len(names) * args.repeat
        _run(folder, tmp / "warm", workers=0)  # numba caches and page cache warm for everyone
        t0 = time.perf_counter()
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        client = distributed.Client(cluster)
        cluster_start = time.perf_counter() - t0
        configs = {"in-process": {"workers": 0}, "local-1": {"workers": 1}, "local-2": {"workers": 2},
                   "dask-local-2": {"scheduler": client}}
        runs: dict[str, list] = {name: [] for name in configs}
        machine = []
        try:
            for _ in range(args.rounds):  # interleaved: each round sees the same state of the machine
                machine.append(round(_parallel_speedup(), 2))
                for name, kw in configs.items():
                    runs[name].append(_run(folder, tmp / name, **kw))
        finally:
            client.close()
            cluster.close()
    results = {}
    for name, rs in runs.items():
        walls = [r["wall_s"] for r in rs]
        med = float(np.median(walls))
        results[name] = {"median_wall_s": round(med, 3), "items_per_second": round(n / med, 2),
                         "wall_s_per_round": [round(w, 3) for w in walls], "ok": rs[-1]["ok"],
                         "failed": rs[-1]["failed"], "errors": rs[-1]["errors"]}
    base = results["local-1"]["median_wall_s"]
    for name in results:
        results[name]["speedup_vs_local_1"] = round(base / results[name]["median_wall_s"], 2)
    doc = {"benchmark": "batch", "pipeline": "process", "options": OPTIONS, "scans": names, "repeat": args.repeat,
           "items": n, "rounds": args.rounds, "machine_parallel_speedup": machine, "dask_cluster_start_s": round(cluster_start, 3), "results": results,
           "cpus": os.cpu_count(), "python": sys.version.split()[0], "platform": platform.platform(),
           "dask": distributed.__version__}
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
