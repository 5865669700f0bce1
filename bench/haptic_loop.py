"""Benchmark: the full haptic tick on a 512x512 surface, and the real-time scheduler with it.

Tick compute time (median, p99 after warm-up) of HapticLoop.step, then the achieved rate,
jitter and overruns of the Scheduler running that tick (the device read into one reused sample)
at 1 kHz and 10 kHz under the ordinary policy (the default), and at 10 kHz with the loop thread
under SCHED_FIFO priority 40 (where granted: ``realtime_priority`` says) as the alternative.
Overruns <= 0.1 % at 10 kHz is the target (issue #13).
Run: .venv/bin/python bench/haptic_loop.py [--seconds 10]   (prints JSON)
"""
from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.contact.maugis_dugdale import MaugisDugdale  # noqa: E402
from arsurf.force.cantilever import Cantilever  # noqa: E402
from arsurf.haptics.device import DeviceState  # noqa: E402
from arsurf.haptics.loop import L_F_PROBE, HapticLoop, LoopConfig  # noqa: E402
from arsurf.haptics.scheduler import Scheduler  # noqa: E402
from arsurf.haptics.virtual_device import HandModel, VirtualDevice  # noqa: E402
from arsurf.model import ARModel  # noqa: E402
from arsurf.scan.synthetic import sinusoid  # noqa: E402
from arsurf.spline.fit import fit_surface  # noqa: E402

R = 20e-9


def build(rate: float):
    s = fit_surface(sinusoid((512, 512), 4e-9, 5e-9, 160e-9))
    model = ARModel(s, R, MaugisDugdale(R, 50e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
    c = (1000e-9, 1000e-9)
    origin = (*c, s.evaluate(*c)[2] + R + 3e-9)
    # the hand presses 8 nm in and slides 40 nm in circles: contact most of the time
    def traj(t):
        return np.array([2e-3 * np.cos(3 * t), 2e-3 * np.sin(3 * t), -0.8e-3])
    dev = VirtualDevice(dt=1.0 / rate, hand=HandModel(traj)).open()
    loop = HapticLoop.direct(model, dev.info, origin, config=LoopConfig(rate=rate, source="blended", signal_noise=1e-8))
    return dev, loop


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    dev, loop = build(1000.0)
    st = dev.read_state()

    def tick():
        loop.step(st, st.timestamp)

    for _ in range(3000):  # warm-up on the real trajectory
        s = dev.read_state()
        dev.command_force(loop.step(s, s.timestamp))
    st = dev.read_state()
    results = {"tick_512x512_python_call": stats(time_calls(tick, 20000)),
               "in_contact_during_timing": bool(loop.out[L_F_PROBE + 2] > 0)}
    for rate, priority in ((1000.0, 0), (10000.0, 0), (10000.0, 40)):
        dev, loop = build(rate)
        loop.warm_up()
        sched = Scheduler(loop.scheduler_step, loop, rate=rate, source=partial(dev.read_state, DeviceState()),
                          sink=dev.command_force, priority=priority)
        d = sched.run_for(args.seconds).as_dict()
        for k in list(d):
            if k.startswith(("compute", "period", "jitter")):
                d[k + "_us"] = d.pop(k) * 1e6
        d["overrun_fraction"] = d["overruns"] / max(d["ticks"], 1)
        policy = "fifo" if priority else "ordinary"
        results[f"scheduler_{int(rate)}Hz_{args.seconds:g}s_{policy}"] = d
    emit("haptic_loop", results)


if __name__ == "__main__":
    main()
