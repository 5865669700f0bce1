"""A surface sampled back onto a height map (for Gwyddion and other scan tools).

The live (possibly deformed) net is evaluated on a regular grid over the surface's domain:
:math:`z_{ij} = S_z(u_i, v_j)`, :math:`u_i = u_0 + i (u_1 - u_0)/(n_u - 1)`. For an undeformed
fit on the default grid (one sample per original pixel) this gives back the levelled, smoothed
scan the surface interpolates.
"""
from __future__ import annotations

import numpy as np

from arsurf.errors import SurfaceError
from arsurf.scan.scan import Scan


def surface_to_scan(surface, resolution: tuple[int, int] | None = None, *, source: str | None = None) -> Scan:
    """The heights of ``surface`` on a ``(nu, nv)`` grid (default: the fitted pixels) as a Scan.

    Examples
    --------
    >>> from arsurf.spline.fit import fit_surface
    >>> y, x = np.mgrid[0:6, 0:8] * 1e-9
    >>> s = fit_surface(Scan(2 * x + y, dx=1e-9, dy=1e-9))
    >>> back = surface_to_scan(s)
    >>> back.shape, bool(np.allclose(back.heights, 2 * x + y, atol=1e-21))
    ((6, 8), True)
    >>> y, x = np.mgrid[0:7, 0:7] * 1e-9
    >>> sq = surface_to_scan(fit_surface(Scan(3 * x + y, dx=1e-9, dy=1e-9)))
    >>> bool(np.allclose(sq.heights, 3 * x + y, atol=1e-21))
    True
    """
    nu, nv = surface.shape
    nx, ny = (nu - 2, nv - 2) if resolution is None else (int(resolution[0]), int(resolution[1]))
    if nx < 2 or ny < 2:
        raise SurfaceError(f"the sampling grid needs at least 2 x 2 points (got {nx} x {ny})")
    (u0, u1), (v0, v1) = surface.domain
    z = np.ascontiguousarray(surface.evaluate_grid(nx, ny)[..., 2])  # (ny, nx): heights[iy, ix]
    return Scan(z, dx=(u1 - u0) / (nx - 1), dy=(v1 - v0) / (ny - 1), channel="Height (surface)",
                metadata={"z_unit": "m", "history": [{"operation": "sampled from a B-spline surface"}]},
                source=source)
