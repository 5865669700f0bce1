"""What the two demos share: the demo preset (tip, rate, scaling), one recorded tick of a scripted
session, the viewer's snapshot of the loop, and the viewer itself when the extra is installed.

The demos are :mod:`arsurf.demo.nanotubes` (``arsurf demo``) and :mod:`arsurf.demo.material`
(``arsurf demo --material``); the command is :mod:`arsurf.demo.command`.
"""
from __future__ import annotations

import logging
import time

from arsurf.assembly import PRESETS
from arsurf.haptics.loop import LOOP_OUT
from arsurf.model import MODEL_OUT
from arsurf.sessions.writer import record_loop_tick

log = logging.getLogger("arsurf.demo")

__all__ = ["DEMO", "TIP_RADIUS", "RATE", "SCALE", "session_tick", "scene_snapshot", "viewer_or_none"]

#: the demo's model and haptic settings (tip, sample, lever, scaling, filter): one named preset
DEMO = PRESETS["demo"]
TIP_RADIUS = DEMO.tip_radius
RATE = DEMO.haptics["rate"]
SCALE = DEMO.haptics["scale"]  # probe metres per stylus metre (1 mm -> 10 nm)


def session_tick(dev, loop, model, writer, scene=None):
    """One tick of a scripted session: read the device, step the loop, command the force, record
    the tick (stylus, probe, tip, energy, signals, forces, contact, and the tube poses after this
    tick's push); ``(state, force, compute ns)``."""
    st = dev.read_state()
    t0 = time.perf_counter_ns()
    f = loop.step(st, st.timestamp)
    compute = time.perf_counter_ns() - t0
    dev.command_force(f)
    record_loop_tick(writer, loop, st.timestamp, st)
    return st, f, compute


def scene_snapshot(model, loop, contact, rate, scene=None):
    """A snapshot for the viewer (copies: the live net keeps changing, so do the tube poses)."""
    o, m = LOOP_OUT.record(loop.out), MODEL_OUT.record(model.out)
    return dict(surface=model.surface.copy(), tip_center=o["probe"], tip_radius=model.tip_radius,
                contact_point=m["point"], contact_normal=m["normal"],
                depth=m["depth"], contact_radius=m["contact_radius"], force=o["probe_force"],
                maugis_lambda=contact.maugis_parameter, loop_rate_hz=rate, device_status="virtual device (demo)",
                tubes=scene.viewer_tubes() if scene is not None else ())


def viewer_or_none():
    """The viewer with a rendering backend chosen; None (and a warning) when the extra is not installed.

    Raises :class:`~arsurf.errors.RenderingUnavailable` (what to install) when nothing can render.
    """
    try:
        import arsurf_viewer
    except ImportError as exc:
        log.warning("no PNG views: the viewer is not installed (%s); pip install 'arsurf[viewer]', or --no-images", exc)
        return None
    arsurf_viewer.choose_backend()
    return arsurf_viewer


