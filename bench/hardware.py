"""Benchmark: round trip and jitter of the 1 kHz loop through each hardware adapter, on the
simulated devices of the tests (tests/support/hardware_sim), with the virtual device as the peer.

For each backend the Scheduler runs at 1 kHz for ``--seconds`` with the device's ``read_state`` as
source and ``command_force`` as sink (a constant 0.1 N, so every tick talks to the device both
ways). Per tick: ``io`` is the time spent in the adapter (read + command: the vendor library; for
Haply the link thread's mailboxes, the serial exchange is that thread's), ``sample_age`` how old the sample was when the loop used it (the OpenHaptics
servo thread samples on its own clock); then the scheduler's period jitter (|period - 1 ms|),
overruns and achieved rate. Every device runs with its shipped defaults (no max_force: the
first-connection 1 N; Haply's 1 ms read timeout and 5 ms sample timeout; OpenHaptics' 5 ms sample
timeout). A lost reply is injected halfway where the simulator models one (Haply: ``lose``):
``lost_reply`` is the longest tick spent in the adapter after it, against the 1 ms period, and
for Haply the force of the command the device got after it (``retry_after_lost_reply_N``: zero)
and its link thread's counts (exchanges per second, lost replies, zero retries). Force Dimension:
not modelled (its SDK's calls are synchronous USB transfers whose timeout the vendor does not
document); OpenHaptics: none (arsurf reads shared memory, the servo thread's misses never block
the loop). The simulated devices are not the real ones: a real USB device adds
its bus latency (~0.1-1 ms) to ``io``; what this measures is arsurf's side of the round trip.

BENCHMARKS maps a section name to a function returning its JSON dict; the ``nanonis`` section is
the AFM controller link through the simulated Nanonis server (:mod:`hardware_nanonis`, its own
peers: a bare TCP echo and the vendor's client). Run:
.venv/bin/python bench/hardware.py [--seconds 3] [--only forcedimension,haply]   (prints JSON)
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests" / "support"))
from _timing import emit, stats  # noqa: E402

import hardware_sim  # noqa: E402
from hardware_nanonis import bench_nanonis  # noqa: E402

from arsurf.haptics.scheduler import Scheduler  # noqa: E402

FORCE = np.array([0.0, 0.0, 0.1])
WORK = Path(tempfile.mkdtemp(prefix="arsurf-bench-hw-"))


def loop_through(dev, seconds: float, halfway=None) -> dict:
    """The 1 kHz Scheduler through ``dev`` (open): io and sample-age statistics, and the timing;
    ``halfway()`` is called once, in the first tick at half the run's time (e.g. to lose a reply)."""
    n = int(seconds * 1000 * 1.2) + 100
    io = np.zeros(n)
    age = np.zeros(n)
    starts = np.zeros(n, dtype=np.int64)  # ns, each tick's read: the loop's own periods
    k = [0]
    clock = time.perf_counter_ns
    t_read = [0]

    half = [n]  # the tick of halfway(): the first at half the run's time (a slow loop has fewer ticks)
    t_half = [math.inf]

    def source():
        if halfway is not None and half[0] == n and time.perf_counter() >= t_half[0]:
            half[0] = k[0]
            halfway()
        t0 = clock()
        s = dev.read_state()
        t_read[0] = clock() - t0
        i = k[0]
        if i < n:
            age[i] = dev.now() - s.timestamp
            starts[i] = t0
        return s

    def sink(f):
        t0 = clock()
        dev.command_force(f)
        i = k[0]
        if i < n:
            io[i] = (t_read[0] + clock() - t0) * 1e-9
        k[0] = i + 1

    for _ in range(200):  # warm-up (kernels compiled or loaded, buffers filled), not timed
        dev.read_state()
        dev.command_force(FORCE)
    sched = Scheduler(lambda st, inputs, dt: FORCE, None, rate=1000.0, source=source, sink=sink)
    t_half[0] = time.perf_counter() + seconds / 2
    st = sched.run_for(seconds)
    m = min(k[0], n)
    ok = np.isfinite(age[:m])
    lost = {}
    if halfway is not None:
        after = io[half[0]:min(m, half[0] + 50)]
        lost = {"lost_reply": {"worst_tick_in_adapter_ms": float(after.max() * 1e3) if after.size else None,
                               "read_timeout_ms": getattr(dev, "read_timeout", math.nan) * 1e3}}
    periods = np.diff(starts[:m]) * 1e-6  # ms
    return {
        **lost,
        "period_p99_ms": float(np.percentile(periods, 99)) if periods.size else None,
        "io": stats(io[:m]),
        "sample_age": stats(age[:m][ok]),
        "missed_samples": int(getattr(dev, "missed_samples", 0)),
        "period_jitter_p99_us": st.jitter_p99 * 1e6,
        "period_jitter_max_us": st.jitter_max * 1e6,
        "achieved_rate_hz": st.rate,
        "overruns": st.overruns,
        "ticks": st.ticks,
    }


def bench_virtual(seconds: float) -> dict:
    """The peer: the virtual device (a simulation stepped in the call, no I/O)."""
    from arsurf.haptics.virtual_device import VirtualDevice

    with VirtualDevice(dt=1e-3) as dev:
        return loop_through(dev, seconds)


def _needs(module: str, compiler: bool = True) -> str | None:
    if importlib.util.find_spec(module) is None:
        return f"{module} is not installed (pip install 'arsurf[hardware]')"
    if compiler and hardware_sim.CC is None:
        return hardware_sim.NO_COMPILER
    return None


def bench_forcedimension(seconds: float) -> dict:
    """Through forcedimension-core into the simulated SDK (ctypes calls into a C library)."""
    why = _needs("forcedimension_core")
    if why:
        return {"skipped": why}
    sdk, lib = hardware_sim.build_fdsdk(WORK / "fd")
    os.environ["FDSDK"] = str(sdk)
    from arsurf.haptics.forcedimension import ForceDimensionDevice

    sim = hardware_sim.load(str(lib))
    sim.sim_reset(33, 1, 1, 1)
    with ForceDimensionDevice() as dev:
        return {"device": dev.info.name, **loop_through(dev, seconds)}


def bench_openhaptics(seconds: float) -> dict:
    """Through pyopenhaptics into the simulated libHD (its 1 kHz servo thread runs the callback)."""
    why = _needs("pyOpenHaptics")
    if why:
        return {"skipped": why}
    sim = hardware_sim.load(hardware_sim.build_libhd(WORK / "hd"))
    sim.sim_reset(0x5000, 4)
    from arsurf.haptics.openhaptics import OpenHapticsDevice

    try:
        with OpenHapticsDevice() as dev:
            return {"device": dev.info.name, "servo_errors": dev.servo_errors, **loop_through(dev, seconds)}
    finally:
        sim.sim_reset(0x5000, 4)


def _inverse3_child(conn) -> None:
    """Child process: the simulated Inverse3 on a pty (its own interpreter: the binding holds the
    GIL while it waits for a reply, so an in-process simulator could not answer within 1 ms)."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from hardware_sim.haply_pty import Inverse3Pty

    pty = None
    while True:
        msg = conn.recv()
        if msg == "new":  # a fresh device per case (closing the port ends the pty's server)
            if pty is not None:
                pty.close()
            pty = Inverse3Pty().start()
            conn.send(pty.path)
        elif msg == "lose":
            pty.lose(1)
        elif msg == "report":  # the forces (N) of the commands whose reply was lost, and of the one after each
            log = list(pty.commands_log)
            conn.send([(log[k][1].tolist(), log[k + 1][1].tolist() if k + 1 < len(log) else None)
                       for k in pty.lost_at])
        else:
            break
    if pty is not None:
        pty.close()


def bench_haply(seconds: float) -> dict:
    """Through haplyhardwareapi over a pseudo-terminal to the simulated Inverse3 (a child process)."""
    why = _needs("HaplyHardwareAPI", compiler=False)
    if why:
        return {"skipped": why}
    import multiprocessing as mp

    from arsurf.haptics.haply import HaplyDevice

    here, there = mp.get_context("spawn").Pipe()
    child = mp.get_context("spawn").Process(target=_inverse3_child, args=(there,), daemon=True)
    child.start()
    try:
        out = {}
        # shipped defaults, then a 20 ms read timeout: a Python simulator on a loaded machine may
        # not answer within the shipped 1 ms (a real Inverse3 answers from its firmware)
        for name, kw in (("shipped defaults", {}), ("read_timeout 20 ms", {"read_timeout": 0.02, "disconnect_after": 0.2})):
            here.send("new")
            path = here.recv()
            try:
                with HaplyDevice(path, workspace=(0.2, 0.12, 0.15), **kw) as dev:
                    t0 = time.perf_counter()
                    out[name] = {"device": dev.info.name, "read_timeout_ms": dev.read_timeout * 1e3,
                                 **loop_through(dev, seconds, halfway=lambda: here.send("lose"))}
                    link = dev.link
                    out[name]["link"] = {"exchanges_per_s": link.exchanges / (time.perf_counter() - t0),
                                         "lost_replies": link.lost_replies, "zero_retries": link.zero_retries,
                                         "stale_commands": link.stale_commands}
                here.send("report")
                lost = here.recv()  # the injected loss (and any reply later than read_timeout)
                out[name]["link"]["retry_after_lost_reply_N"] = [after for _, after in lost]
            except Exception as exc:  # noqa: BLE001 - reported in the JSON, the other cases still run
                out[name] = {"error": f"{type(exc).__name__}: {exc}"}
        return out
    finally:
        here.send("stop")
        child.join(5.0)


#: section name -> benchmark(seconds) -> dict (add a section for another simulated link here)
BENCHMARKS = {
    "virtual (peer)": bench_virtual,
    "forcedimension": bench_forcedimension,
    "openhaptics": bench_openhaptics,
    "haply": bench_haply,
    "nanonis": bench_nanonis,  # the AFM controller link (bench/hardware_nanonis.py)
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--only", default="", help="comma-separated section names (default: all)")
    args = ap.parse_args()
    wanted = [s for s in args.only.split(",") if s] or list(BENCHMARKS)
    results = {}
    for name in wanted:
        if name not in BENCHMARKS:
            raise SystemExit(f"bench/hardware.py: unknown section {name!r}; known: {', '.join(BENCHMARKS)}")
        results[name] = BENCHMARKS[name](args.seconds)
    results["summary"] = summary(results)
    emit("hardware", results)


#: why a device section has no lost-reply figure (bench docstring)
_NO_LOST_REPLY = {"forcedimension": "not modelled: the SDK's calls are synchronous USB transfers with an "
                                    "undocumented timeout",
                  "openhaptics": "none: the loop reads the servo thread's shared memory, never the device",
                  "virtual (peer)": "none: no I/O"}


def summary(results: dict) -> dict:
    """Per device (shipped defaults) and the Nanonis link, at 1 kHz: loop rate (Hz), p99 period
    (ms), p99 sample age (ms) and the worst tick spent in the adapter after a lost reply (ms,
    against the 1 ms period)."""
    out = {}
    for name, r in results.items():
        if name == "nanonis":
            link = r.get("live_link") or {}
            out[name] = {"loop_rate_hz": link.get("loop_rate_hz"), "period_p99_ms": link.get("period_p99_ms"),
                         "sample_age_p99_ms": link.get("sample_age_p99_ms"),
                         "lost_reply_worst_tick_ms": (link["tick_in_link_max_after_loss_us"] * 1e-3
                                                      if "tick_in_link_max_after_loss_us" in link else None)}
            continue
        if "haply" == name:
            r = r.get("shipped defaults", {})
        if "achieved_rate_hz" not in r:
            out[name] = {"skipped": r.get("skipped") or r.get("error")}
            continue
        lost = (r.get("lost_reply") or {}).get("worst_tick_in_adapter_ms")
        out[name] = {"loop_rate_hz": r["achieved_rate_hz"], "period_p99_ms": r["period_p99_ms"],
                     "sample_age_p99_ms": r["sample_age"]["p99_us"] * 1e-3,
                     "lost_reply_worst_tick_ms": lost if lost is not None else _NO_LOST_REPLY.get(name)}
        if "link" in r:
            out[name]["retry_after_lost_reply_N"] = r["link"].get("retry_after_lost_reply_N")
    return out


if __name__ == "__main__":
    main()
