"""arsurf_viewer: the pyvista view of the live arsurf model (interactive and offscreen).

The engine (``arsurf``) never imports this package. Names are imported lazily, so
``from arsurf_viewer.state import SceneState`` works without pyvista; pyvista/VTK load with the
first :class:`SurfaceView`.

- :class:`SceneState` (state.py) - what one frame shows, in SI units;
- :class:`SurfaceView` (view.py) - the scene, updated in place; ``screenshot``, ``world_to_pixel``;
- :func:`render_frames` (frames.py) - PNG frames and an mp4 from a sequence of states;
- :func:`run_interactive` (interactive.py) - keyboard/mouse or a pose callable drive the tip;
- :func:`view_scan` (interactive.py) - what ``arsurf view [SCAN]`` runs;
- :func:`show` (notebook.py) - the (deformed) surface or a scene in a Jupyter notebook;
- :func:`choose_backend`, :func:`probe` (backend.py) - how an OpenGL context is made here.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "SceneState": "arsurf_viewer.state",
    "Tube": "arsurf_viewer.state",
    "ViewerError": "arsurf_viewer.state",
    "SurfaceView": "arsurf_viewer.view",
    "LAYERS": "arsurf_viewer.view",
    "render_frames": "arsurf_viewer.frames",
    "Frames": "arsurf_viewer.frames",
    "run_interactive": "arsurf_viewer.interactive",
    "StylusController": "arsurf_viewer.interactive",
    "ContactPhysics": "arsurf_viewer.interactive",
    "view_scan": "arsurf_viewer.interactive",
    "show": "arsurf_viewer.notebook",
    "Picture": "arsurf_viewer.notebook",
    "choose_backend": "arsurf_viewer.backend",
    "probe": "arsurf_viewer.backend",
    "has_display": "arsurf_viewer.backend",
    "RenderingUnavailable": "arsurf_viewer.backend",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'arsurf_viewer' has no attribute {name!r}")


def __dir__():
    return __all__
