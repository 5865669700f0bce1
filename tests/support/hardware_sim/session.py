"""The full 1 kHz loop through a hardware adapter, recorded: what every simulated-device test runs.

An AR model on a flat surface (the device's home maps 5 nm above it), the direct coupling
(1 mm of stylus -> 10 nm of probe, ``force_gain`` N per N), arsurf's safety layer and
:class:`~arsurf.haptics.scheduler.Scheduler` at 1 kHz with the device's ``read_state`` as source and
``command_force`` as sink, every tick appended to a session file. ``events`` are ``(time s,
callable)`` run from the test thread while the loop runs (e.g. unplugging the device).

The safety layer is the one every loop has, with one setting changed: its deadline watchdog
counts a tick as missed only after a 50 ms gap (``miss_factor=50``), because the test machine is
shared and a 1 kHz Python thread there misses 1.5 ms deadlines by the hundred; the watchdog itself
is tested in ``tests/haptics/test_safety.py``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from arsurf.assembly import make_model, session_metadata
from arsurf.errors import LoopError
from arsurf.haptics.loop import LOOP_OUT, HapticLoop, LoopConfig
from arsurf.haptics.scheduler import Scheduler
from arsurf.sessions.reader import load_session
from arsurf.sessions.writer import SessionWriter
from arsurf.spline.surface import BSplineSurface

R = 20e-9
SIDE = 460e-9
ORIGIN = (SIDE / 2, SIDE / 2, R + 5e-9)
SCAN = {"path": "flat.npz", "sha256": "00" * 32, "channel": None,
        "processing": {"level": "none", "sigma": 0.0, "inpaint": False}}
CONTACT = {"effective_modulus": 10e9, "work_of_adhesion": 0.05, "dugdale_stress": None}


@dataclass
class Run:
    """What a recorded run gave: the session ticks, the stop error (None: clean), the timing stats,
    and ``t0``, the device-clock time of the session's t = 0."""

    ticks: dict
    complete: bool
    error: BaseException | None
    stats: object
    loop: HapticLoop
    t0: float


def run(device, path, seconds: float, *, force_gain: float = 1e5, events=(), ramp_time: float = 0.05) -> Run:
    from arsurf.assembly import LEVER, loop_metadata

    surface = BSplineSurface.from_heights(np.zeros((24, 24)), (0.0, SIDE), (0.0, SIDE))
    model = make_model(surface, tip_radius=R, effective_modulus=CONTACT["effective_modulus"],
                       work_of_adhesion=CONTACT["work_of_adhesion"])
    loop = HapticLoop.direct(model, device.info, ORIGIN, scale=1e-5, force_gain=force_gain,
                             config=LoopConfig(rate=1000.0, filter_cutoff=200.0), ramp_time=ramp_time,
                             miss_factor=50.0)
    loop.warm_up()
    meta = loop_metadata(session_metadata(
        scan=SCAN, tip_radius=R, contact=CONTACT, cantilever=dict(LEVER), friction=0.2,
        haptics={"device": device.info.name, "scale": 1e-5, "force_gain": force_gain}, loop_rate=1000.0), loop)
    writer = SessionWriter(path, meta)
    get = LOOP_OUT.get
    t0 = device.now()

    def step(state, inputs, dt):
        f = loop.step(inputs, device.now())
        o = loop.out
        writer.append(t=device.now() - t0, stylus_position=inputs.position, stylus_velocity=inputs.velocity,
                      buttons=inputs.buttons, probe_position=get(o, "probe"), force=get(o, "probe_force"),
                      device_force=f)
        return f

    def zero():
        if device.is_open:
            device.command_force(np.zeros(3))

    sched = Scheduler(step, loop, rate=1000.0, source=device.read_state, sink=device.command_force, on_stop=zero)
    error = None
    pending = sorted(events, key=lambda e: e[0])
    sched.start()
    try:
        start = time.perf_counter()
        while time.perf_counter() - start < seconds and sched.is_running:
            while pending and time.perf_counter() - start >= pending[0][0]:
                pending.pop(0)[1]()
            time.sleep(0.005)
    finally:
        try:
            stats = sched.stop()
        except LoopError as exc:
            error, stats = exc, sched.stats()
        writer.close(complete=error is None, reason="" if error is None else str(error))
    s = load_session(path, allow_incomplete=True)
    return Run(s.ticks, s.complete, error, stats, loop, t0)
