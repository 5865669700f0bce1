"""The view of a live loop: its latest snapshot drawn as a scene.

The loop itself (:class:`arsurf.haptics.live_loop.LiveLoop`: device, 1 kHz scheduler, recording
hook) lives in the engine and runs without this package; the view only reads the small snapshot
the loop thread publishes at 60 Hz. :func:`live_scene` is the per-frame ``physics`` hook of
:func:`~arsurf_viewer.interactive.run_interactive` (``physics=partial(live_scene, live)``,
``pose_source=live.pose``).
"""
from __future__ import annotations

import math

import numpy as np

from .state import SceneState

__all__ = ["live_scene"]


def live_scene(live, tip_center, dt: float) -> SceneState:
    """The last snapshot of the :class:`~arsurf.haptics.live_loop.LiveLoop` ``live`` as a scene.

    ``tip_center`` ((3,) m) and ``dt`` (s) are the viewer's per-frame hook arguments; the loop owns
    the tip, so ``tip_center`` is drawn only before the first snapshot. The status line names the
    device, the loop rate so far (ticks / elapsed s) and the safety flags of the last tick.
    """
    snap = live.scheduler.snapshot()
    m = live.loop.model
    if snap is None:
        return SceneState(m.surface, np.asarray(tip_center, dtype=np.float64), m.tip_radius,
                          device_status=f"{live.device_name} · waiting for the loop")
    v = snap.values
    depth, radius, flags = v["scalars"]
    elapsed = live.scheduler.elapsed()
    rate = live.scheduler.ticks / elapsed if elapsed > 0 else math.nan
    status = live.device_name + (" · flagged" if int(flags) else " · ok")  # the HUD names the flags
    return SceneState(m.surface, v["tip"], m.tip_radius, contact_point=v["point"], contact_normal=v["normal"],
                      depth=float(depth), contact_radius=float(radius), force=v["force"],
                      maugis_lambda=m.contact.maugis_parameter, loop_rate_hz=rate, device_status=status,
                      time=snap.time, flags=int(flags))
