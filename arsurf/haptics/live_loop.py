"""The live loop: a haptic loop in its own real-time thread, on a device, with a recording hook.

:class:`LiveLoop` runs a :class:`~arsurf.haptics.loop.HapticLoop` with a
:class:`~arsurf.haptics.scheduler.Scheduler` (1 kHz by default) against a device (the UDP bridge
for real hardware, a virtual or vendor device otherwise). After every tick it calls an optional
recorder (the session writer, :func:`arsurf.sessions.writer.record_loop_tick`), and it
publishes a small snapshot (tip, contact, force, safety flags) at 60 Hz for whoever watches:
:meth:`LiveLoop.pose`, and the view's :func:`arsurf_viewer.live.live_scene`, which reads it at
its own 30-60 Hz. The surface is the loop's live (dented) surface, read while the loop may be
writing a patch of it: a frame can show a dent one tick old, never a corrupt one (each control
point is written whole). Nothing here draws: ``arsurf live`` runs headless without pyvista.

:func:`bridge_start` is where the probe starts when the stylus is at its origin.
"""
from __future__ import annotations

import numpy as np

from arsurf.errors import HapticsError
from arsurf.haptics.loop import L_SAFETY_FLAGS, LOOP_OUT
from arsurf.haptics.scheduler import Scheduler
from arsurf.model import M_DEPTH, M_RADIUS, MODEL_OUT

__all__ = ["LiveLoop", "bridge_start"]


class LiveLoop:
    """A haptic loop stepping a device in a real-time thread, recorded and watched through snapshots.

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
        the haptics layer does not import the sessions layer); the attribute :attr:`record` may be set
        until :meth:`start`. A recorder that raises is a fault of the tick: zero force, the loop
        stops.
    priority : int
        ``SCHED_FIFO`` priority of the loop thread where the OS grants it, 0: the ordinary policy
        (:class:`~arsurf.haptics.scheduler.Scheduler`).

    Examples
    --------
    >>> # live = LiveLoop(loop, UdpBridgeDevice(port=47474)).start()
    >>> # run_interactive(loop.model.surface, physics=partial(live_scene, live), pose_source=live.pose)
    """

    def __init__(self, loop, device, snapshot_rate: float = 60.0, record=None, priority: int = 0):
        if record is not None and not callable(record):
            raise HapticsError(f"record must be a callable record(loop, t, state) or None (got {type(record).__name__})")
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
        #: the device's name, for status lines
        self.device_name = getattr(device.info, "name", type(device).__name__)

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


def bridge_start(surface, tip_radius: float) -> tuple[float, float, float]:
    """Where the probe is when the stylus is at its origin: 2.5 R above the middle of ``surface`` (m)."""
    (u0, u1), (v0, v1) = surface.domain
    cx, cy = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    return (cx, cy, float(surface.evaluate(cx, cy)[2]) + 2.5 * tip_radius)
