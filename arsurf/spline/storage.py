"""Save and load a :class:`BSplineSurface` (``.npz``: current net, rest net, knots; bit-exact)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from arsurf._files import atomic_write
from arsurf.errors import SurfaceError
from arsurf.spline.surface import BSplineSurface

__all__ = ["FORMAT_VERSION", "is_surface_file", "load_surface", "save_surface", "surface_summary"]

FORMAT_VERSION = 1


def save_surface(surface: BSplineSurface, path: str | os.PathLike, metadata: dict | None = None) -> Path:
    """Write ``surface`` to ``path`` (.npz): control_points, rest_control_points, knots_u,
    knots_v (metres) and ``metadata_json``. The round trip is bit-exact.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> s = BSplineSurface.from_heights(np.zeros((4, 4)), (0, 1e-9), (0, 1e-9))
    >>> p = save_surface(s, tempfile.mkdtemp() + "/s.npz")
    >>> load_surface(p).shape
    (4, 4)
    """
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise SurfaceError(f"surfaces are saved as .npz (got {str(path)!r}); use a name ending in .npz")
    ctrl, rest, ku, kv = surface.kernel_arrays()
    meta = {"format": "arsurf-surface", "version": FORMAT_VERSION, **(metadata or {})}
    with atomic_write(path, what="surface file", error=SurfaceError) as fh:
        np.savez(fh, control_points=ctrl, rest_control_points=rest, knots_u=ku, knots_v=kv,
                 metadata_json=np.str_(json.dumps(meta, default=str)))
    return path


def is_surface_file(path: str | os.PathLike) -> bool:
    """True when ``path`` is a ``.npz`` written by :func:`save_surface` (its entries say so; nothing
    else is read). False for anything else, unreadable files included."""
    try:
        with np.load(Path(path), allow_pickle=False) as f:
            return {"control_points", "knots_u", "knots_v", "metadata_json"} <= set(f.files)
    except Exception:  # noqa: BLE001 - not a zip, not numpy, not there: not a surface
        return False


def surface_summary(surface: BSplineSurface) -> dict:
    """What ``arsurf info`` shows of a fitted surface: control net, domain and height range (nm),
    whether it is dented (its net differs from its rest net)."""
    (u0, u1), (v0, v1) = surface.domain
    ctrl, rest, _, _ = surface.kernel_arrays()
    xs, ys = np.meshgrid(np.linspace(u0, u1, 64), np.linspace(v0, v1, 64))
    z = surface.evaluate(xs, ys)[..., 2]
    nu, nv = surface.shape
    return {"kind": "fitted B-spline surface (arsurf fit); not a scan", "control_points": f"{nu} x {nv}",
            "domain_nm": [(u1 - u0) * 1e9, (v1 - v0) * 1e9], "z_min_nm": float(z.min() * 1e9),
            "z_max_nm": float(z.max() * 1e9), "deformed": bool(not np.array_equal(ctrl, rest))}


def load_surface(path: str | os.PathLike) -> BSplineSurface:
    """Read a surface written by :func:`save_surface` (validated like a new surface)."""
    path = Path(path)
    if not path.is_file():
        raise SurfaceError(f"surface file {str(path)!r} does not exist; write one with `arsurf fit SCAN -o FILE.npz`")
    if path.suffix.lower() != ".npz":
        raise SurfaceError(f"{path} is not a fitted surface (.npz from `arsurf fit`); if it is a scan, run "
                           f"`arsurf fit {path} -o surface.npz` first")
    try:
        with np.load(path, allow_pickle=False) as f:
            meta = json.loads(str(f["metadata_json"]))
            if meta.get("format") != "arsurf-surface" or meta.get("version") != FORMAT_VERSION:
                raise SurfaceError(f"{path}: not an arsurf surface file of version {FORMAT_VERSION} (got {meta})")
            surface = BSplineSurface(f["control_points"], f["knots_u"], f["knots_v"])
            rest = BSplineSurface(f["rest_control_points"], f["knots_u"], f["knots_v"])
    except SurfaceError:
        raise
    except (OSError, KeyError, ValueError) as exc:
        raise SurfaceError(f"{path} is not an arsurf surface file (a scan saved as .npz? run `arsurf fit` on it "
                           f"first): {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") from exc
    surface.kernel_arrays()[1][...] = rest.kernel_arrays()[0]
    return surface
