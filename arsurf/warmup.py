"""Build numba's cache once, at install: ``arsurf warmup`` (``make setup`` runs it as
``python -m arsurf.warmup``; after ``pip install`` of a wheel, run it once yourself).

arsurf's hot code is numba kernels compiled on first use and cached on disk
(``cache=True``, in a folder keyed on the sources: :func:`arsurf._configure_numba_cache`).
On an empty cache the first ``arsurf demo`` spent most of its time in the compiler. This
module compiles what a session uses before anyone waits for it: the demo pipeline itself
(scan preparation, fit, engage, the haptic loop with the nanotube scene, the session writer,
the replay and the feel scores, and the 3D views when the viewer is installed and can render) on
1.5 s of simulated stylus, the replay's threaded batch evaluation, and the loop
without a scene on a surface above :data:`~arsurf.contact.projection.TILED_ABOVE` control
cells (a large scan's tiled projector specialises every kernel that collides).

Run it again after an upgrade (the cache folder changes with the sources); a warm cache
makes it a few seconds. ``--quiet`` prints only the summary line.
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import os
import sys
import tempfile
import time


def warm_up(progress=None) -> dict:
    """Compile (or load) the kernels of the demo, the live loop and the replay; returns the wall
    time of each part in seconds (keys ``demo_s``, ``tiled_loop_s``, ``total_s``)."""
    import numpy as np

    from arsurf.assembly import PRESETS, build_loop
    from arsurf.demo import run_demo
    from arsurf.errors import RenderingUnavailable
    from arsurf.haptics.virtual_device import VirtualDevice
    from arsurf.model import ARModel
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.contact.projection import TILED_ABOVE
    from arsurf.force.cantilever import Cantilever
    from arsurf.haptics.device import DeviceState
    from arsurf.scan.synthetic import rough
    from arsurf.spline.basis import PARALLEL_MIN
    from arsurf.spline.fit import fit_surface

    say = progress or (lambda line: None)
    times = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="arsurf-warmup-") as out:
        # the demo settles 1.2 s before it scores; its views too where they can be drawn (the
        # viewer's own kernels), as `make demo` and `arsurf demo` draw them
        images = importlib.util.find_spec("arsurf_viewer") is not None
        try:
            run_demo(out, seconds=1.5, images=images, progress=say)
        except RenderingUnavailable:  # raised before the session: nothing was compiled twice
            run_demo(out, seconds=1.5, images=False, progress=say)
    times["demo_s"] = time.perf_counter() - t0
    say(f"demo pipeline compiled in {times['demo_s']:.1f} s")
    t1 = time.perf_counter()
    n = int(TILED_ABOVE ** 0.5) + 8  # just above the tiling threshold: the tiled projector's kernels
    surface = fit_surface(rough((n, n), 4e-9, rms=1e-9, correlation_length=20e-9, seed=0))
    tip = 20e-9
    model = ARModel(surface, tip, MaugisDugdale(tip, 5e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
    (u0, u1), (v0, v1) = surface.domain
    x, y = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    origin = (x, y, float(surface.evaluate(x, y)[2]) + tip - 1e-9)
    haptics = PRESETS["demo"].haptics
    dev = VirtualDevice(dt=1.0 / haptics["rate"]).open()
    try:
        loop = build_loop(model, haptics, dev.info, origin)
        state = DeviceState()
        for k in range(20):
            state.timestamp = k / haptics["rate"]
            loop.step(state, state.timestamp)
    finally:
        dev.close()
    surface.sync()
    # the threaded batch evaluation (PARALLEL_MIN points or more) of the replay's dent figure, which
    # the short demo above does not draw (its tip has not pressed yet)
    side = int(math.ceil(PARALLEL_MIN ** 0.5))
    surface.evaluate(*np.meshgrid(np.linspace(u0, u1, side), np.linspace(v0, v1, side)))
    times["tiled_loop_s"] = time.perf_counter() - t1
    times["total_s"] = time.perf_counter() - t0
    say(f"tiled loop compiled in {times['tiled_loop_s']:.1f} s")
    return times


#: the command's one-line help (``arsurf warmup`` and ``python -m arsurf.warmup``)
HELP = ("compile numba's kernels into the cache once, after installing or upgrading (the first demo or "
        "session then loads them instead of waiting on the compiler)")


def register(sub) -> None:
    """Add ``arsurf warmup`` to the CLI."""
    p = sub.add_parser("warmup", help=HELP, description=HELP[0].upper() + HELP[1:] + ".")
    p.set_defaults(func=_cmd)


def _cmd(args) -> int:
    from arsurf._logging import LOGGER

    print(_run(LOGGER.info))
    return 0


def _run(progress) -> str:
    """Warm the cache up; the one summary line the commands print."""
    times = warm_up(progress)
    return f"arsurf warm-up: numba cache built in {times['total_s']:.1f} s ({os.environ.get('NUMBA_CACHE_DIR', '')})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m arsurf.warmup", description=HELP)
    ap.add_argument("--quiet", action="store_true", help="print only the summary line")
    args = ap.parse_args(argv)
    print(_run(None if args.quiet else print))
    return 0


if __name__ == "__main__":
    sys.exit(main())
