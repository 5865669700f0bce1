"""How VTK gets an OpenGL context here: a display, EGL, OSMesa or Xvfb, chosen automatically.

VTK >= 9.4 wheels link no GL library; they ``dlopen`` one at run time and pick the render window
class from ``VTK_DEFAULT_OPENGL_WINDOW``:

================  ==========================  ===================================================
backend           VTK render window           needs (Debian packages)
================  ==========================  ===================================================
``native``        Win32 / Cocoa               a desktop (Windows, macOS)
``x11``           vtkXOpenGLRenderWindow      a reachable X server ($DISPLAY): libgl1,
                                              libglx-mesa0, libx11-6, libxcursor1
``egl``           vtkEGLRenderWindow          headless, no X: libegl1, libegl-mesa0,
                                              libgl1-mesa-dri (Mesa's llvmpipe software
                                              renderer, or a GPU driver's EGL)
``osmesa``        vtkOSOpenGLRenderWindow     headless fallback: libosmesa6
``xvfb``          vtkXOpenGLRenderWindow      a virtual X server: xvfb (+ the x11 packages)
================  ==========================  ===================================================

:func:`choose_backend` looks for them in that order with cheap checks (``ctypes`` loads the
libraries, ``XOpenDisplay`` tries the display) and sets the environment before the first render
window exists; ``ARSURF_VIEWER_BACKEND`` forces one. When a check passes but VTK still cannot
make a context, VTK may abort the process, so :func:`probe` tries the chosen backend in a child
process and reports (once per process) whether a real picture came out; the viewer tests skip
on its answer and only on it. In a source checkout ``tools/install-system-deps.sh`` installs the
``egl`` packages (the ones CI and headless servers need) and the ``x11`` ones for desktops; the
docs/install.rst ("Offscreen rendering") says how to get OSMesa without root.

Examples
--------
>>> from arsurf_viewer.backend import choose_backend
>>> choose_backend().name in {"native", "x11", "egl", "osmesa", "xvfb"}
True
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import glob
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass

from arsurf.errors import RENDERING_HINT, RenderingUnavailable

__all__ = ["RenderingUnavailable", "Backend", "Probe", "BACKENDS", "choose_backend", "has_display", "probe"]

#: Backends in order of preference, with the VTK render window class each selects.
BACKENDS = {
    "native": None,
    "x11": "vtkXOpenGLRenderWindow",
    "egl": "vtkEGLRenderWindow",
    "osmesa": "vtkOSOpenGLRenderWindow",
    "xvfb": "vtkXOpenGLRenderWindow",
}
_ENV = "ARSURF_VIEWER_BACKEND"
_INSTALL_HINT = RENDERING_HINT


@dataclass(frozen=True)
class Backend:
    """The backend chosen: its name, whether windows can appear on screen, and why it was chosen."""

    name: str
    interactive: bool
    reason: str


@dataclass(frozen=True)
class Probe:
    """Result of :func:`probe`: could a picture be rendered, with which backend and renderer."""

    ok: bool
    backend: str
    detail: str


def _loadable(*names: str) -> bool:
    for name in names:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def _x_display_opens() -> bool:
    """True when $DISPLAY is set and an X connection can actually be opened."""
    if not os.environ.get("DISPLAY"):
        return False
    path = ctypes.util.find_library("X11")
    if path is None:
        return False
    try:
        x11 = ctypes.CDLL(path)
    except OSError:
        return False
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = x11.XOpenDisplay(None)
    if not handle:
        return False
    x11.XCloseDisplay(handle)
    return True


def _egl_available() -> bool:
    """libEGL (glvnd or vendor) and at least one EGL vendor implementation are loadable."""
    if not _loadable("libEGL.so.1", "libEGL.so"):
        return False
    vendors = glob.glob("/usr/share/glvnd/egl_vendor.d/*.json") + glob.glob("/etc/glvnd/egl_vendor.d/*.json")
    return bool(vendors) or _loadable("libEGL_mesa.so.0", "libEGL_nvidia.so.0")


def has_display() -> bool:
    """Can a window appear on screen? (Windows/macOS: yes; Linux: a reachable X server.)"""
    if sys.platform.startswith(("win", "darwin")):
        return True
    return _x_display_opens()


def _candidates() -> list[tuple[str, str]]:
    if sys.platform.startswith(("win", "darwin")):
        return [("native", f"{sys.platform} has a native OpenGL window")]
    found = []
    if _x_display_opens():
        found.append(("x11", f"X display {os.environ.get('DISPLAY')!r} is reachable"))
    if _egl_available():
        found.append(("egl", "libEGL and an EGL vendor library are installed"))
    if _loadable("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so"):
        found.append(("osmesa", "libOSMesa is installed"))
    if shutil.which("Xvfb"):
        found.append(("xvfb", "Xvfb is installed"))
    return found


def _apply(name: str) -> None:
    window = BACKENDS[name]
    if name == "xvfb":
        import pyvista

        os.environ.pop("VTK_DEFAULT_OPENGL_WINDOW", None)
        pyvista.start_xvfb()
    elif window is not None:
        os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = window


@functools.lru_cache(maxsize=None)
def _choose(forced: str | None) -> Backend:
    if forced:
        if forced not in BACKENDS:
            raise RenderingUnavailable(
                f"{_ENV}={forced!r} is not a backend; use one of {', '.join(BACKENDS)} or unset it"
            )
        _apply(forced)
        return Backend(forced, forced in ("native", "x11"), f"forced by {_ENV}")
    found = _candidates()
    if not found:
        raise RenderingUnavailable(
            "no OpenGL context can be made: no display ($DISPLAY unset or unreachable), no EGL, no "
            f"OSMesa and no Xvfb; {_INSTALL_HINT}"
        )
    name, reason = found[0]
    _apply(name)
    return Backend(name, name in ("native", "x11"), reason)


def choose_backend() -> Backend:
    """Pick the rendering backend, configure VTK for it (once per process) and return it.

    Must run before the first VTK render window is created; :class:`arsurf_viewer.SurfaceView`
    calls it. Raises :class:`RenderingUnavailable` naming the packages to install when nothing
    can render.
    """
    return _choose(os.environ.get(_ENV) or None)


_PROBE_SCRIPT = r"""
import json
from arsurf_viewer.backend import choose_backend
b = choose_backend()
import pyvista as pv
p = pv.Plotter(off_screen=True, window_size=(64, 48))
p.set_background("black")
p.add_mesh(pv.Sphere(radius=1.0), color="white")
img = p.screenshot(return_img=True)
caps = p.render_window.ReportCapabilities() or ""
renderer = next((l.split(":", 1)[1].strip() for l in caps.splitlines() if "renderer string" in l), "?")
lit = int((img.max(axis=2) > 64).sum())
p.close()
print(json.dumps({"backend": b.name, "lit": lit, "renderer": renderer}))
"""


@functools.lru_cache(maxsize=1)
def probe(timeout: float = 120.0) -> Probe:
    """Render a white sphere offscreen in a child process; ok when it shows (once per process).

    The child inherits the environment, so ``ARSURF_VIEWER_BACKEND`` applies to it too.
    """
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    try:
        run = subprocess.run([sys.executable, "-c", _PROBE_SCRIPT], capture_output=True, text=True,
                             timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return Probe(False, "?", f"the rendering probe did not finish in {timeout:g} s")
    last = run.stdout.strip().splitlines()[-1:] if run.stdout.strip() else []
    if run.returncode != 0 or not last:
        err = re.sub(r"\x1b\[[0-9;]*m", "", (run.stderr.strip().splitlines() or ["no output"])[-1]).strip()
        return Probe(False, "?", f"rendering probe failed (exit {run.returncode}): {err}; {_INSTALL_HINT}")
    info = json.loads(last[0])
    # the sphere covers ~ pi/4 * 48^2 * (fraction of the view) pixels; a blank picture has none
    if info["lit"] < 100:
        return Probe(False, info["backend"], f"the probe rendered a blank picture with {info['renderer']}")
    return Probe(True, info["backend"], f"{info['backend']} via {info['renderer']}")
