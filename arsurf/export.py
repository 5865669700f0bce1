r"""The (deformed) B-spline surface as a triangle mesh, and as STL / PLY / GLB files.

:func:`surface_mesh` samples S(u, v) on a regular (u, v) grid and splits every grid cell into
two triangles oriented with their normals on the +z side (out of the sample). With
``solid=True`` the sheet is closed into a watertight solid: vertical-ish side walls from the
boundary of the sheet down to a flat bottom at ``base`` (a fan around the centre of the
parameter rectangle), all faces oriented outwards, so the volume is

.. math:: V = \iint_{\Omega} (z(x, y) - z_{\mathrm{base}})\,dx\,dy

for a height-field surface (exact for a plane; second order in the sample spacing otherwise).

:func:`export_surface` writes the mesh by extension (``.stl``, ``.ply``, ``.glb``) through
trimesh. **Files are in nanometres** by default (``unit="nm"``): STL and PLY carry no unit,
and viewers, slicers and 3D printers handle coordinates of order 1-10⁴ but not 10⁻⁹-sized ones;
glTF nominally means metres, so a GLB viewer shows a 500 nm scan as 500 units across. Pass
``unit="m"`` for SI coordinates (and read such files with ``process=False``).

The :class:`trimesh.Trimesh` objects are in nanometres as well (``mesh.units ==
"nanometers"``; ``mesh.convert_units("meters")`` gives SI): trimesh's tolerances are absolute
(``tol.zero`` = 1e-12, ``tol.merge`` = 1e-8), so a nanometre surface in metres would have zero
face normals and collapsing vertices. Everything passed in (``base``) is in metres.

Examples
--------
>>> import numpy as np
>>> from arsurf.spline.surface import BSplineSurface
>>> s = BSplineSurface.from_heights(np.full((6, 5), 2e-9), (0.0, 30e-9), (0.0, 20e-9))
>>> m = surface_mesh(s, 11, solid=True, base=0.0)
>>> bool(m.is_watertight), round(float(m.volume), 6)   # 30 x 20 x 2 nm^3
(True, 1200.0)
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from arsurf._files import write_bytes
from arsurf.errors import ExportError, require
from arsurf.spline.surface import BSplineSurface

__all__ = ["ExportError", "EXPORT_FORMATS", "UNITS", "MESH_SCALE", "surface_mesh", "export_surface", "grid_faces"]

#: File extensions :func:`export_surface` writes, with trimesh's file type.
EXPORT_FORMATS = {".stl": "stl", ".ply": "ply", ".glb": "glb"}
#: File units: name -> coordinates per metre.
UNITS = {"nm": 1e9, "m": 1.0}
#: Coordinates of the returned Trimesh per metre (nanometres, see the module notes).
MESH_SCALE = 1e9
#: Largest grid per axis (a 4096^2 grid is already 33 M triangles, ~1.6 GB of STL).
MAX_RESOLUTION = 4096
# Default depth of the solid below the lowest point, as a fraction of the height range, and
# at least this fraction of the larger lateral extent (so a flat surface still has a body).
_BASE_MARGIN = 0.1
_BASE_MARGIN_LATERAL = 0.05


def _resolution(surface: BSplineSurface, resolution) -> tuple[int, int]:
    if resolution is None:
        nu, nv = surface.shape
        return min(nu, MAX_RESOLUTION), min(nv, MAX_RESOLUTION)
    vals = (resolution, resolution) if np.ndim(resolution) == 0 else tuple(resolution)
    if len(vals) != 2:
        raise ExportError(f"`resolution` must be an int or (nu, nv) (got {resolution!r})")
    out = []
    for r in vals:
        if isinstance(r, (bool, np.bool_)) or int(r) != r or not 2 <= int(r) <= MAX_RESOLUTION:
            raise ExportError(
                f"`resolution` must be integers in 2..{MAX_RESOLUTION} samples per axis (got {resolution!r}); "
                "it is the number of surface samples along u and v"
            )
        out.append(int(r))
    return out[0], out[1]


def grid_faces(nu: int, nv: int) -> np.ndarray:
    """Triangles (2 (nu-1)(nv-1), 3) of a row-major (nv, nu) vertex grid (vertex j*nu + i),
    counter-clockwise seen from +z when x grows with i and y with j."""
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1))
    v00 = (j * nu + i).ravel()
    v10, v01 = v00 + 1, v00 + nu
    v11 = v01 + 1
    return np.concatenate([np.column_stack([v00, v10, v11]), np.column_stack([v00, v11, v01])]).astype(np.int64)


def _boundary_loop(nu: int, nv: int) -> np.ndarray:
    """Indices of the grid's boundary vertices, counter-clockwise seen from +z, no repeats."""
    bottom = np.arange(nu)
    right = (np.arange(1, nv) * nu) + (nu - 1)
    top = (nv - 1) * nu + np.arange(nu - 2, -1, -1)
    left = np.arange(nv - 2, 0, -1) * nu
    return np.concatenate([bottom, right, top, left])


def surface_mesh(surface: BSplineSurface, resolution=None, *, solid: bool = False, base: float | None = None):
    r"""Triangle mesh of the current (deformed) surface, in nanometres.

    Parameters
    ----------
    surface : BSplineSurface
    resolution : int or (nu, nv), optional
        Samples along u and v (the grid includes the domain edges). Default: one sample per
        control point (about one per scan pixel for an interpolating fit).
    solid : bool
        Close the sheet into a watertight solid with side walls and a flat bottom.
    base : float, metres, optional
        Height of the bottom (solid only); must lie below the lowest point of the surface.
        Default: 10 % of the height range (at least 5 % of the lateral size) below it.

    Returns
    -------
    trimesh.Trimesh
        Vertices in nanometres (``units = "nanometers"``); the first nu*nv vertices are the
        surface samples (row-major, row = v); ``metadata`` holds ``resolution``, ``solid`` and
        ``base`` (metres, or None for a sheet).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((5, 5)), (0.0, 10e-9), (0.0, 10e-9))
    >>> round(float(surface_mesh(s, 8).area), 9)   # nm^2
    100.0
    """
    trimesh = require("trimesh", "mesh", "exporting the surface as a mesh")
    if not isinstance(surface, BSplineSurface):
        raise ExportError(f"`surface` must be a BSplineSurface (got {type(surface).__name__}); fit one with arsurf.fit_surface")
    nu, nv = _resolution(surface, resolution)
    top = surface.evaluate_grid(nu, nv).reshape(-1, 3)
    faces = grid_faces(nu, nv)
    zb = None
    if solid:
        zmin, zmax = float(top[:, 2].min()), float(top[:, 2].max())
        (u0, u1), (v0, v1) = surface.domain
        if base is None:
            zb = zmin - max(_BASE_MARGIN * (zmax - zmin), _BASE_MARGIN_LATERAL * max(u1 - u0, v1 - v0))
        else:
            try:
                zb = float(base)
            except (TypeError, ValueError):
                raise ExportError(f"`base` must be a height in metres (got {base!r})") from None
            if not (math.isfinite(zb) and zb < zmin):
                raise ExportError(
                    f"`base` must lie below the lowest point of the surface ({zmin:.6g} m) (got {base!r} m); "
                    "lower it or leave it out for an automatic base"
                )
        loop = _boundary_loop(nu, nv)
        m = loop.size
        n_top = nu * nv
        # bottom ring under the boundary at the (u, v) parameter positions: a rectangle, so the
        # fan from its centre is always valid, even if a dent moved boundary points sideways
        u = np.linspace(u0, u1, nu)
        v = np.linspace(v0, v1, nv)
        ring = np.column_stack([u[loop % nu], v[loop // nu], np.full(m, zb)])
        centre = np.array([[0.5 * (u0 + u1), 0.5 * (v0 + v1), zb]])
        t = loop
        t1 = np.roll(loop, -1)
        b = n_top + np.arange(m)
        b1 = np.roll(b, -1)
        c = np.full(m, n_top + m)
        walls = np.concatenate([np.column_stack([t, b, b1]), np.column_stack([t, b1, t1])])
        bottom = np.column_stack([c, b1, b])
        top = np.vstack([top, ring, centre])
        faces = np.vstack([faces, walls, bottom])
    mesh = trimesh.Trimesh(vertices=top * MESH_SCALE, faces=faces, process=False, validate=False)
    mesh.units = "nanometers"
    mesh.metadata.update(resolution=(nu, nv), solid=bool(solid), base=zb)
    return mesh


def _afmhot(t: np.ndarray) -> np.ndarray:
    """Gwyddion/matplotlib 'afmhot' colours (n, 4) uint8 for t in [0, 1] (an analytic map)."""
    t = np.clip(t, 0.0, 1.0)[:, None]
    rgb = np.clip(np.hstack([2.0 * t, 2.0 * t - 0.5, 2.0 * t - 1.0]), 0.0, 1.0)
    return np.hstack([np.round(255 * rgb), np.full((t.shape[0], 1), 255.0)]).astype(np.uint8)


def export_surface(surface: BSplineSurface, path: str | os.PathLike, resolution=None, *, solid: bool = False,
                   base: float | None = None, unit: str = "nm", colors: bool = True) -> Path:
    """Write the current (deformed) surface as STL, PLY or GLB (chosen by the extension).

    Parameters
    ----------
    surface : BSplineSurface
    path : path-like
        Ends in ``.stl``, ``.ply`` or ``.glb``. Written to a temporary name and renamed, so an
        interrupted export never leaves a partial file.
    resolution, solid, base
        As in :func:`surface_mesh` (``base`` in metres).
    unit : {"nm", "m"}
        Units of the coordinates in the file (default nanometres; see the module notes).
    colors : bool
        PLY/GLB: vertex colours by height ('afmhot', the AFM convention). STL has none.

    Returns
    -------
    pathlib.Path of the file written.

    Examples
    --------
    >>> import tempfile, numpy as np, trimesh
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((5, 5)), (0.0, 10e-9), (0.0, 10e-9))
    >>> p = export_surface(s, tempfile.mkdtemp() + "/flat.stl", 4)
    >>> trimesh.load(p).bounds[1].tolist()   # nanometres
    [10.0, 10.0, 0.0]
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in EXPORT_FORMATS:
        raise ExportError(
            f"cannot export to {p.name!r}: unknown extension {p.suffix or '(none)'!r}; use one of "
            f"{', '.join(EXPORT_FORMATS)}"
        )
    if unit not in UNITS:
        raise ExportError(f"`unit` must be one of {sorted(UNITS)} (got {unit!r})")
    if not p.parent.is_dir():
        raise ExportError(f"cannot write {str(p)!r}: the folder {str(p.parent)!r} does not exist")
    mesh = surface_mesh(surface, resolution, solid=solid, base=base)
    z = np.array(mesh.vertices[:, 2])
    if unit != "nm":
        mesh.apply_scale(UNITS[unit] / MESH_SCALE)
        mesh.units = "meters"
    if colors and ext != ".stl":
        span = float(np.ptp(z))
        mesh.visual.vertex_colors = _afmhot((z - z.min()) / span if span > 0 else np.zeros_like(z))
    data = mesh.export(file_type=EXPORT_FORMATS[ext])
    write_bytes(p, data if isinstance(data, bytes) else data.encode(), what="mesh file", error=ExportError)
    return p
