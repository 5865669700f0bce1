"""Offscreen frames: PNG files and an mp4 movie from a sequence of scene states.

Every frame is written as ``<prefix>_00000.png`` ... through one :class:`SurfaceView` updated in
place. The movie (H.264, ``yuv420p``, so any player opens it) needs ``imageio-ffmpeg`` (the ``movie`` extra); without
it the frames are still written and the returned :class:`Frames` says why there is no movie
(the message is also logged as a warning to ``arsurf.viewer``). Files are written under temporary names and renamed,
so an interrupted run leaves no truncated PNG or mp4 behind.

Examples
--------
>>> import numpy as np, tempfile
>>> from arsurf.spline.surface import BSplineSurface
>>> from arsurf_viewer import SceneState, render_frames
>>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 100e-9), (0.0, 100e-9))
>>> states = [SceneState(s, (50e-9, 50e-9, z), 20e-9) for z in (40e-9, 30e-9, 21e-9)]
>>> out = render_frames(states, tempfile.mkdtemp(), movie=None, window_size=(160, 120))
>>> len(out.paths)
3
"""
from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from arsurf._files import atomic_write, check_target
from arsurf.errors import require

from .state import SceneState
from arsurf.errors import ViewerError

log = logging.getLogger("arsurf.viewer")

__all__ = ["Frames", "render_frames", "movie_support"]


@dataclass(frozen=True)
class Frames:
    """What :func:`render_frames` wrote: the PNG paths, the movie (or None) and a note."""

    paths: list
    movie: Path | None
    note: str


def movie_support() -> str | None:
    """None when mp4 movies can be written, else the reason they cannot."""
    if importlib.util.find_spec("imageio_ffmpeg") is None:
        return "imageio-ffmpeg is not installed (pip install 'arsurf[movie]')"
    try:
        import imageio_ffmpeg

        imageio_ffmpeg.get_ffmpeg_exe()
    except Exception as exc:  # the package is there but its ffmpeg binary is not
        return f"imageio-ffmpeg cannot find an ffmpeg executable ({exc})"
    return None


def _even(img: np.ndarray) -> np.ndarray:
    """Pad to even width/height by repeating the last row/column (yuv420p needs even sizes)."""
    h, w = img.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return img
    return np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def render_frames(states: Iterable[SceneState], out_dir: str | os.PathLike, *, fps: float = 30.0,
                  movie: str | None = "movie.mp4", prefix: str = "frame", view=None, **view_kwargs) -> Frames:
    """Render each state offscreen to ``out_dir/<prefix>_NNNNN.png`` and (optionally) an mp4.

    Parameters
    ----------
    states : iterable of SceneState
        Frames in order (a generator is fine: states are consumed one at a time).
    out_dir : path-like
        Created if needed.
    fps : float
        Movie frame rate.
    movie : str or None
        Movie file name inside ``out_dir`` (``None``: frames only).
    prefix : str
        Frame file name prefix.
    view : SurfaceView, optional
        An existing view to draw with (left open); by default one is made from the first
        state's surface with ``view_kwargs`` (``off_screen=True``) and closed at the end.

    Returns
    -------
    Frames
    """
    from .view import SurfaceView

    if not (isinstance(fps, (int, float)) and 0 < fps <= 1000):
        raise ViewerError(f"`fps` must be in (0, 1000] frames per second (got {fps!r})")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    note = ""
    writer = None
    movie_path = movie_tmp = None
    stack = contextlib.ExitStack()
    if movie is not None:
        if not str(movie).lower().endswith(".mp4"):
            raise ViewerError(f"`movie` must be an .mp4 file name (got {movie!r})")
        reason = movie_support()
        if reason is None:
            movie_path = out / movie
            check_target(movie_path, "movie", error=ViewerError)
        else:
            note = f"no movie: {reason}; wrote PNG frames only"
            log.warning("arsurf_viewer: %s", note)
    own_view = view is None
    paths: list[Path] = []
    with stack:  # on an error the movie's temporary is removed and an old movie kept
        try:
            for k, state in enumerate(states):
                if not isinstance(state, SceneState):
                    raise ViewerError(f"state {k} is a {type(state).__name__}, not a SceneState")
                if view is None:
                    view_kwargs.setdefault("off_screen", True)
                    view = SurfaceView(state.surface, **view_kwargs)
                view.update(state, render=False)
                path = out / f"{prefix}_{k:05d}.png"
                img = view.screenshot(path)
                paths.append(path)
                if movie_path is not None:
                    if writer is None:
                        imageio = require("imageio.v2", "movie", "writing movies")
                        # ffmpeg writes by name: into the exclusive temporary atomic_write created
                        movie_tmp = stack.enter_context(atomic_write(movie_path, what="movie", error=ViewerError)).temp
                        writer = imageio.get_writer(movie_tmp, fps=float(fps), codec="libx264", quality=8,
                                                    macro_block_size=1, pixelformat="yuv420p")
                    writer.append_data(_even(img))
            if not paths:
                raise ViewerError("render_frames() got no states; pass at least one SceneState")
            if writer is not None:
                writer.close()
                writer = None
                stack.close()  # fsynced and renamed over the movie
            else:
                movie_path = None
        finally:
            if writer is not None:
                writer.close()
            if own_view and view is not None:
                view.close()
    return Frames(paths, movie_path, note)
