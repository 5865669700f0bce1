"""The deformed surface in a Jupyter notebook: a static picture anywhere, interactive with trame.

:func:`show` draws a :class:`~arsurf.spline.surface.BSplineSurface` (its dent included) or a whole
:class:`~arsurf_viewer.state.SceneState` (tip, contact normal, force arrow, HUD, tubes) with the
same :class:`~arsurf_viewer.view.SurfaceView` as the application and ``arsurf view``:

``backend="static"`` (default)
    rendered offscreen (EGL or OSMesa where there is no display, :mod:`arsurf_viewer.backend`) and
    returned as a :class:`Picture`, which a notebook shows as a PNG (``_repr_png_``) and keeps in the
    saved ``.ipynb``: it works on a headless server, in CI, and in a notebook exported to HTML. No
    Jupyter package is needed (the viewer extra is).
``backend="trame"``
    pyvista's interactive widget (rotate and zoom in the browser), served by trame from the
    running kernel on localhost; needs the optional packages of ``pip install 'arsurf[notebook]'``
    (trame, trame-vtk, trame-vuetify, trame-pyvista, ipywidgets) and a Jupyter front end. Tested
    by hand only (a kernel gets the widget); the test suite checks the message without the extra,
    because trame's local-rendering module fetches its WebAssembly from the internet at start.

Examples
--------
>>> import numpy as np
>>> from arsurf.spline.surface import BSplineSurface
>>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 100e-9), (0.0, 100e-9))
>>> picture = show(s, window_size=(320, 240))
>>> picture.shape, picture._repr_png_()[:4]
((240, 320, 3), b'\\x89PNG')
"""
from __future__ import annotations

import importlib.util
import io
from pathlib import Path

import numpy as np

from arsurf._files import write_bytes
from arsurf.errors import MissingDependency, ViewerError, require
from arsurf.spline.surface import BSplineSurface

from .state import SceneState
from .view import SurfaceView

__all__ = ["Picture", "show", "BACKENDS", "TRAME_PACKAGES"]

BACKENDS = ("static", "trame")
#: the modules pyvista's trame backend imports (the ``notebook`` extra; pyvista >= 0.49 moved its
#: trame support into trame_pyvista)
TRAME_PACKAGES = ("trame", "trame_vtk", "trame_vuetify", "trame_pyvista", "ipywidgets")


class Picture:
    """A rendered view: ``array`` (height, width, 3) uint8 and its PNG bytes; notebooks display it.

    Parameters
    ----------
    array : (height, width, 3) uint8
        The pixels (a :meth:`SurfaceView.screenshot`).
    """

    def __init__(self, array: np.ndarray):
        a = np.asarray(array)
        if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
            raise ViewerError(f"a picture is an (height, width, 3) uint8 array (got {a.dtype} {a.shape})")
        self.array = a
        image = require("PIL.Image", "viewer", "PNG pictures in notebooks")
        buf = io.BytesIO()
        image.fromarray(np.ascontiguousarray(a)).save(buf, format="PNG")
        self.png = buf.getvalue()

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.array.shape  # type: ignore[return-value]

    def _repr_png_(self) -> bytes:
        return self.png

    def save(self, path) -> Path:
        """Write the PNG to ``path`` (a ``.png`` name)."""
        p = Path(path)
        if p.suffix.lower() != ".png":
            raise ViewerError(f"pictures are PNG files (got {p.name!r}); use a .png name")
        write_bytes(p, self.png, what="picture", error=ViewerError)
        return p

    def __repr__(self) -> str:
        return f"Picture({self.shape[1]}x{self.shape[0]} px)"


def _scene(scene) -> tuple[BSplineSurface, SceneState | None]:
    if isinstance(scene, SceneState):
        return scene.surface, scene
    if isinstance(scene, BSplineSurface):
        return scene, None
    raise ViewerError(f"show() takes a BSplineSurface or a SceneState (got {type(scene).__name__})")


def show(scene, *, backend: str = "static", color_by: str = "height", camera: str = "oblique",
         window_size=(800, 600), close_up: float | None = None, **view_options):
    """Draw a surface or a scene in a notebook.

    Parameters
    ----------
    scene : BSplineSurface or SceneState
        What to draw: a (deformed) surface alone, or a state with the tip, contact and force.
    backend : {"static", "trame"}
        ``"static"``: a :class:`Picture` rendered offscreen (works headless); ``"trame"``: an
        interactive pyvista widget (needs ``arsurf[notebook]``).
    color_by : {"height", "deformation"}
        Colour of the surface: height z (nm) or the dent :math:`|S - S_{rest}|` (nm).
    camera : {"oblique", "top"}
    window_size : (width, height) pixels
    close_up : float, metres, optional
        With a SceneState: frame about this width around the tip (e.g. ``8 * tip_radius``).
    **view_options
        Passed to :class:`~arsurf_viewer.view.SurfaceView` (``resolution``, ``layers``...).

    Returns
    -------
    Picture or widget
        The static picture, or the widget pyvista's trame backend returns.

    Raises
    ------
    ViewerError
        A bad argument.
    MissingDependency
        ``backend="trame"`` without the trame packages (names ``pip install 'arsurf[notebook]'``).
    RenderingUnavailable
        No OpenGL context can be made here (says what to install).
    """
    if backend not in BACKENDS:
        raise ViewerError(f"backend must be one of {', '.join(BACKENDS)} (got {backend!r})")
    surface, state = _scene(scene)
    if close_up is not None and state is None:
        raise ViewerError("close_up frames the tip: pass a SceneState (with the tip), not a bare surface")
    if backend == "trame":
        missing = [m for m in TRAME_PACKAGES if importlib.util.find_spec(m) is None]
        if missing:
            raise MissingDependency(f"the interactive notebook view needs {', '.join(missing)}: "
                                    "pip install 'arsurf[notebook]' (or use backend='static')")
    view = SurfaceView(surface, off_screen=True, window_size=window_size, camera=camera, color_by=color_by,
                       **view_options)
    if state is not None:
        view.update(state, render=False)
        if close_up is not None:
            view.close_up(state.tip_center, close_up)
    else:
        view.set_layer("hud", False)  # nothing to report without a tip
    if backend == "trame":
        return view.plotter.show(jupyter_backend="trame", return_viewer=True)
    try:
        return Picture(view.screenshot())
    finally:
        view.close()
