"""The live system: the haptic loop in its own real-time thread, the view reading its snapshots.

:class:`LiveLoop` runs a :class:`~arsurf.haptics.loop.HapticLoop` with a
:class:`~arsurf.haptics.scheduler.Scheduler` (1 kHz by default) against a device (the UDP bridge
for real hardware, a virtual device otherwise). The loop thread publishes a small snapshot
(tip, contact, force, safety flags) at 60 Hz; the viewer polls it at its own 30-60 Hz through
:meth:`LiveLoop.physics` / :meth:`LiveLoop.pose`, the hooks of
:func:`~arsurf_viewer.interactive.run_interactive`. The surface is the loop's live (dented)
surface, read while the loop may be writing a patch of it: a frame can show a dent one tick
old, never a corrupt one (each control point is written whole).
"""
from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

from arsurf.haptics.scheduler import Scheduler
from arsurf.haptics.loop import L_SAFETY_FLAGS, LOOP_OUT
from arsurf.model import M_DEPTH, M_RADIUS, MODEL_OUT

from .state import SceneState, ViewerError


class LiveLoop:
    """A haptic loop stepping a device in a real-time thread, seen by the viewer.

    Parameters
    ----------
    loop : HapticLoop
    device : Device
        Opened here if it is not open yet (and closed by :meth:`stop`).
    snapshot_rate : float, Hz
        How often the loop thread publishes what the view shows.
    record : callable, optional
        ``record(loop, t, state)``, called in the loop thread after every tick with the loop time
        ``t`` (s, the device's clock) and the device sample ``state`` the tick ran on: the
        session recorder (``functools.partial(arsurf.sessions.writer.record_loop_tick, writer)``;
        the viewer does not import the sessions layer); the attribute :attr:`record` may be set
        until :meth:`start`. A recorder that raises is a fault of the tick: zero force, the loop
        stops.
    priority : int
        ``SCHED_FIFO`` priority of the loop thread where the OS grants it, 0: the ordinary policy
        (:class:`~arsurf.haptics.scheduler.Scheduler`).

    Examples
    --------
    >>> # live = LiveLoop(loop, UdpBridgeDevice(port=47474)).start()
    >>> # run_interactive(loop.model.surface, physics=live.physics, pose_source=live.pose)
    """

    def __init__(self, loop, device, snapshot_rate: float = 60.0, record=None, priority: int = 0):
        if record is not None and not callable(record):
            raise ViewerError(f"record must be a callable record(loop, t, state) or None (got {type(record).__name__})")
        self.loop = loop
        self.device = device
        now = device.now  # the safety watchdog runs on the device's clock (a bridge sample's
        # timestamp is its arrival time, which stops when packets stop: that is what ages it)
        self.record = record

        def tick(state, inputs, dt):
            t = now()
            force = loop.step(inputs, t)
            rec = self.record
            if rec is not None:
                rec(loop, t, inputs)
            return force

        self.scheduler = Scheduler(tick, loop, rate=loop.config.rate, source=device.read_state,
                                   sink=device.command_force, snapshot=self._snapshot, snapshot_rate=snapshot_rate,
                                   on_stop=self._zero_force, priority=priority)
        self._status = getattr(device.info, "name", type(device).__name__)

    def _snapshot(self, state, inputs, output) -> dict:
        """Runs in the loop thread: only small copies."""
        o, mo = self.loop.out, self.loop.model.out
        return {"tip": o[LOOP_OUT.slice("probe")], "force": o[LOOP_OUT.slice("probe_force")],
                "point": mo[MODEL_OUT.slice("point")], "normal": mo[MODEL_OUT.slice("normal")],
                "scalars": np.array([mo[M_DEPTH], mo[M_RADIUS], o[L_SAFETY_FLAGS]])}

    def start(self) -> "LiveLoop":
        self.loop.warm_up()  # compile before the thread starts: a cold first tick takes seconds
        if not self.device.is_open:
            self.device.open()
        self.scheduler.start()
        return self

    def _zero_force(self) -> None:
        """Runs in the loop thread when it ends, normally or on a fault: the hand gets zero force
        at once, not the last force computed."""
        if self.device.is_open:
            self.device.command_force(np.zeros(3))

    def stop(self):
        """Stop the thread and close the device (whatever happened in the thread: a fault is
        raised as :class:`~arsurf.errors.LoopError` after the device is closed); return the
        timing stats."""
        try:
            return self.scheduler.stop()
        finally:
            self.device.close()

    def pose(self):
        """The loop's current tip centre (3,) m, or None before the first tick."""
        snap = self.scheduler.snapshot()
        return None if snap is None else snap.values["tip"]

    def physics(self, tip_center, dt: float) -> SceneState:
        """The viewer's per-frame hook: the last snapshot as a scene (``tip_center`` is ignored:
        the loop owns the tip)."""
        snap = self.scheduler.snapshot()
        m = self.loop.model
        if snap is None:
            return SceneState(m.surface, np.asarray(tip_center, dtype=np.float64), m.tip_radius,
                              device_status=f"{self._status} · waiting for the loop")
        v = snap.values
        depth, radius, flags = v["scalars"]
        elapsed = self.scheduler.elapsed()
        rate = self.scheduler.ticks / elapsed if elapsed > 0 else math.nan
        status = self._status + (f" · safety flags {int(flags)}" if int(flags) else " · ok")
        return SceneState(m.surface, v["tip"], m.tip_radius, contact_point=v["point"], contact_normal=v["normal"],
                          depth=float(depth), contact_radius=float(radius), force=v["force"],
                          maugis_lambda=m.contact.maugis_parameter, loop_rate_hz=rate, device_status=status,
                          time=snap.time)


#: the haptic settings of the bridge loop (``metadata["haptics"]`` of its sessions; ``scale``
#: is the command line's ``--scale``): the direct coupling, the simulated force (MD load +
#: friction, no synthesised signals), a 200 Hz low-pass, no virtual coupling
BRIDGE_HAPTICS = MappingProxyType({"coupling": "direct", "scale": 1e-5, "force_gain": 1e5, "rate": 1000.0,
                                   "source": "simulated", "filter_cutoff": 200.0, "signal_noise": 0.0,
                                   "passivity": True})


def bridge_start(surface, tip_radius: float) -> tuple[float, float, float]:
    """Where the probe is when the stylus is at its origin: 2.5 R above the middle of ``surface`` (m)."""
    (u0, u1), (v0, v1) = surface.domain
    cx, cy = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    return (cx, cy, float(surface.evaluate(cx, cy)[2]) + 2.5 * tip_radius)


def bridge_loop(model, haptics=None, *, host: str = "127.0.0.1", port: int = 47474, key: bytes | None = None,
                peer_timeout: float | None = None, start=None, record=None) -> LiveLoop:
    """A :class:`LiveLoop` for real hardware: the UDP bridge device on ``host``:``port`` with the
    session ``key`` (a fresh one on loopback if None; see :class:`UdpBridgeDevice`) driving the
    AR ``model`` through :func:`arsurf.assembly.build_loop` with ``haptics`` (default
    :data:`BRIDGE_HAPTICS`). The stylus origin maps to ``start`` (default :func:`bridge_start`).
    ``record(loop, t, state)``: see :class:`LiveLoop`. Nothing is opened here:
    :meth:`LiveLoop.start` (or ``live.device.open()``) binds the port.

    Build the model with :func:`arsurf.assembly.build_model` from session metadata (what
    ``arsurf view --bridge-port`` does) and a recorded session replays bit for bit."""
    from arsurf.assembly import build_loop
    from arsurf.haptics.udp_bridge import UdpBridgeDevice

    if start is None:
        start = bridge_start(model.surface, model.tip_radius)
    device = UdpBridgeDevice(host, port, key=key, peer_timeout=peer_timeout)
    loop = build_loop(model, BRIDGE_HAPTICS if haptics is None else haptics, device.info, start)
    return LiveLoop(loop, device, record=record)
