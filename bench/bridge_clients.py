"""Benchmark: the C++ bridge client against the Python reference client, and the cost of recording a live tick.

Peers timed in the same run:

* ``round_trip``   - the C++ client (examples/cpp, built here with the README's command) and the
  Python reference client (``python -m arsurf.haptics.client``), each sending poses at 1 kHz
  for ``--seconds`` to the same bridge (a thread answering every POSE at once with a spring
  force): round-trip time (POSE sent -> its FORCE checked), ticks later than one period, invalid
  replies; rounds alternate between the clients;
* ``tick``         - one tick of the bridge loop (``HapticLoop.step``) alone (the peer) and followed
  by :func:`arsurf.sessions.writer.record_loop_tick` (what ``arsurf view --record`` adds per
  tick), interleaved rounds of ticks paced at 1 kHz on the bundled scan, with the GIL switch
  interval the Scheduler sets (a quarter period): the p99 includes the journal writer thread
  taking the GIL between ticks.

Usage: ``python bench/bridge_clients.py [--seconds 3] [--rounds 3]``. Prints one JSON document.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import best_round, emit, round_ratio  # noqa: E402

from arsurf.haptics.udp_bridge import UdpBridgeDevice, save_key  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def build_cpp(out: Path) -> str | None:
    cxx = os.environ.get("CXX") or next((c for c in ("c++", "g++", "clang++") if shutil.which(c)), None)
    if cxx is None:
        return None
    line = next(x for x in (ROOT / "examples/cpp/README.md").read_text().splitlines() if x.startswith("g++ "))
    cmd = [*shlex.split(cxx), *shlex.split(line)[1:]]
    cmd[cmd.index("-o") + 1] = str(out)
    subprocess.run(cmd, cwd=ROOT / "examples/cpp", check=True)
    return str(out)


def serve(dev: UdpBridgeDevice, stop: threading.Event) -> None:
    while not stop.is_set():
        if dev.poll():
            s = dev.read_state()
            dev.command_force(-100.0 * s.position)
        else:
            time.sleep(2e-5)


def round_trips(cpp: str | None, seconds: float, rounds: int) -> dict:
    out: dict = {}
    with tempfile.TemporaryDirectory() as d, UdpBridgeDevice("127.0.0.1", 0) as dev:
        kf = save_key(os.path.join(d, "k"), dev.key)
        stop = threading.Event()
        th = threading.Thread(target=serve, args=(dev, stop), daemon=True)
        th.start()
        args = ["--port", str(dev.address[1]), "--key-file", kf, "--duration", str(seconds), "--radius", "0.01"]
        clients = {"python_reference": [sys.executable, "-m", "arsurf.haptics.client", *args]}
        if cpp:
            clients["cpp"] = [cpp, *args]
        try:
            for _ in range(rounds):
                for name, cmd in clients.items():
                    r = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)
                    late = r.get("late_ticks")
                    out.setdefault(name, []).append({
                        "rtt_median_us": r["rtt_median_s"] * 1e6, "rtt_p99_us": r["rtt_p99_s"] * 1e6,
                        "replies": r["replies_with_rtt"], "invalid_replies": r["invalid_replies"],
                        "late_ticks": late})
                    time.sleep(0.2)  # the bridge's peer is released
        finally:
            stop.set()
            th.join(5)
    summary = {}
    for name, runs in out.items():
        best = min(runs, key=lambda x: x["rtt_median_us"])
        summary[name] = {**best, "round_medians_us": [round(x["rtt_median_us"], 1) for x in runs]}
    if "cpp" in summary:
        summary["python_over_cpp_rtt_median"] = round(float(np.median(
            [p["rtt_median_us"] / c["rtt_median_us"] for p, c in zip(out["python_reference"], out["cpp"])])), 2)
    else:
        summary["cpp"] = "no C++ compiler: not measured"
    return summary


def tick_costs(rounds: int, n: int = 2000) -> dict:
    from arsurf.assembly import BUNDLED_SCAN, build_loop, build_model, preset_metadata
    from arsurf.haptics.device import TOUCH_X, DeviceState
    from arsurf.sessions.writer import SessionWriter, record_loop_tick
    from arsurf.assembly import BRIDGE_HAPTICS
    from arsurf.haptics.live_loop import bridge_start

    meta = preset_metadata(BUNDLED_SCAN, "viewer", haptics=dict(BRIDGE_HAPTICS))
    setup = build_model(meta)
    loop = build_loop(setup.model, meta["haptics"], TOUCH_X, bridge_start(setup.surface, setup.model.tip_radius))
    st = DeviceState(np.zeros(3), np.zeros(3), 0, 0.0)
    clock = time.perf_counter_ns
    bare, recorded = [], []
    k = 0
    old_switch = sys.getswitchinterval()
    sys.setswitchinterval(2.5e-4)  # as the Scheduler runs the loop: the writer thread yields the GIL soon
    with tempfile.TemporaryDirectory() as d:
        writer = SessionWriter(os.path.join(d, "s.h5"), meta)
        for r in range(rounds + 1):  # round 0 warms up (compilation, caches)
            for rec, samples in ((False, bare), (True, recorded)):
                s = np.empty(n)
                for i in range(n):
                    st.position[:] = (2e-3 * math.cos(k * 1e-3), 2e-3 * math.sin(k * 1e-3), -4e-3 * (k % 2000) / 2000)
                    st.timestamp = k * 1e-3
                    t0 = clock()
                    loop.step(st, st.timestamp)
                    if rec:
                        record_loop_tick(writer, loop, st.timestamp, st)
                    s[i] = clock() - t0
                    k += 1
                    while clock() - t0 < 1_000_000:  # paced at 1 kHz, as live: the writer thread runs between ticks
                        time.sleep(2e-4)
                if r:
                    samples.append(s * 1e-9)
        writer.close()
    sys.setswitchinterval(old_switch)
    return {"step_peer": best_round(bare), "step_and_record": best_round(recorded),
            "record_over_step": round_ratio(recorded, bare)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        cpp = build_cpp(Path(d) / "arsurf_client")
        emit("bridge_clients", {"round_trip_1kHz": round_trips(cpp, args.seconds, args.rounds),
                                "tick": tick_costs(args.rounds)})


if __name__ == "__main__":
    main()
