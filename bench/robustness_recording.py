"""Kill a real recorder at random moments and count what survives.

A child process records at ~1 kHz with :class:`SessionWriter` (default settings: 256-tick
chunks, 50 ms flush interval, fsync), stamping each tick with its CLOCK_MONOTONIC time and a
known position, and logging each append. The driver kills it at a random moment (SIGKILL, or
SIGTERM / SIGINT with ``handle_signals=True``) and reads the session back
(``load_session(..., allow_incomplete=True)``, the journal for a killed recorder). Per trial:
ticks appended (logged), ticks recovered, ticks lost, the age at the kill of the oldest lost
tick (the flush guarantee is 100 ms) and whether the recovered ticks are exactly the first ones
appended.

Usage: ``python bench/robustness_recording.py [--kills 25] [--terms 5] [--ints 3]``. Prints one
JSON document.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
from _timing import emit  # noqa: E402
from test_session_recording import RECORDER, meta, position  # noqa: E402

from arsurf.errors import SessionError  # noqa: E402
from arsurf.sessions.journal import journal_path  # noqa: E402
from arsurf.sessions.reader import load_session  # noqa: E402


def trial(d: Path, sig: signal.Signals, delay: float) -> dict:
    path, log = d / "run.h5", d / "log.txt"
    for p in (path, log, journal_path(path)):
        p.unlink(missing_ok=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    handle = sig != signal.SIGKILL
    proc = subprocess.Popen([sys.executable, "-c", RECORDER, str(path), str(log), json.dumps(meta()),
                             "1" if handle else "0"], env=env, stderr=subprocess.DEVNULL)
    while not (log.exists() and log.read_text().startswith("ready")):
        time.sleep(0.005)
    time.sleep(delay)
    t_kill = time.monotonic()
    proc.send_signal(sig)
    proc.wait()
    logged, final = {}, None
    for line in log.read_text().splitlines()[1:]:
        parts = line.split()
        if parts[0] == "final":
            final = int(parts[1])
        elif len(parts) == 2:
            logged[int(parts[0])] = float(parts[1])
    t0 = time.perf_counter()
    try:
        s = load_session(path, allow_incomplete=True)
    except SessionError as exc:
        return {"signal": sig.name, "run_s": round(delay, 3), "unreadable": str(exc), "appended": len(logged),
                "recovered": 0, "lost": len(logged), "oldest_lost_age_ms": 0.0, "lost_older_than_100ms": len(logged),
                "prefix_exact": False}
    t_load = time.perf_counter() - t0
    n = s.n_ticks
    appended = max(final or 0, max(logged) + 1)
    exact = bool(np.array_equal(s.ticks["probe_position"], np.array([position(k) for k in range(n)]).reshape(n, 3)))
    lost = [k for k in logged if k >= n]
    oldest_lost_age = max((t_kill - logged[k] for k in lost), default=0.0)
    return {"signal": sig.name, "run_s": round(delay, 3), "appended": appended, "recovered": n,
            "lost": max(0, appended - n), "oldest_lost_age_ms": round(oldest_lost_age * 1e3, 2),
            "lost_older_than_100ms": sum(1 for k in lost if t_kill - logged[k] > 0.100),
            "prefix_exact": exact, "recovered_from_journal": s.recovered, "load_s": round(t_load, 4)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--kills", type=int, default=25)
    ap.add_argument("--terms", type=int, default=5)
    ap.add_argument("--ints", type=int, default=3)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    d = Path(tempfile.mkdtemp(prefix="arsurf-kill-"))
    runs = []
    for sig, count in ((signal.SIGKILL, args.kills), (signal.SIGTERM, args.terms), (signal.SIGINT, args.ints)):
        for _ in range(count):
            runs.append(trial(d, sig, rng.uniform(0.1, 3.0)))

    def agg(rs):
        if not rs:
            return {}
        lost = np.array([r["lost"] for r in rs])
        return {"trials": len(rs), "ticks_appended_total": int(sum(r["appended"] for r in rs)),
                "ticks_lost_median": float(np.median(lost)), "ticks_lost_max": int(lost.max()),
                "oldest_lost_age_ms_max": max(r["oldest_lost_age_ms"] for r in rs),
                "lost_older_than_100ms_total": int(sum(r["lost_older_than_100ms"] for r in rs)),
                "all_prefixes_exact": all(r["prefix_exact"] for r in rs),
                "unreadable": sum(1 for r in rs if "unreadable" in r)}

    emit("robustness_recording", {
        "rate_hz": 1000, "flush_interval_ms": 50,
        "sigkill": agg([r for r in runs if r["signal"] == "SIGKILL"]),
        "sigterm": agg([r for r in runs if r["signal"] == "SIGTERM"]),
        "sigint": agg([r for r in runs if r["signal"] == "SIGINT"]),
        "trials": runs,
    })


if __name__ == "__main__":
    main()
