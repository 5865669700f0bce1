"""Fill missing pixels of a scan by harmonic (Laplace) interpolation: :func:`inpaint`.

Real scans have holes: the unscanned NaN lines of an aborted scan, dropout pixels where the
controller wrote ~0 (the aborted nanoFTIR ``.gsf`` in SOURCES.md has 311 NaN and ~1600
``|z| < 1e-12 m`` dropouts), or regions a user masks. The B-spline fit needs every pixel, so
the holes are filled with the smoothest surface that meets the known pixels: the solution of
Laplace's equation on the holes with the known pixels as Dirichlet data,

.. math:: \\frac{\\partial^2 z}{\\partial x^2} + \\frac{\\partial^2 z}{\\partial y^2} = 0
          \\quad\\text{on the holes}, \\qquad z = z_\\text{known} \\text{ elsewhere},

discretised with the 5-point stencil on the (possibly non-square) pixel grid,

.. math:: \\sum_{n \\in N(p)} w_n (z_n - z_p) = 0, \\qquad w = 1/dx^2 \\text{ (left/right)},\\;
          1/dy^2 \\text{ (up/down)},

where N(p) holds the neighbours inside the image (so the image border is a zero-flux,
Neumann, boundary). One sparse linear system over the missing pixels only, solved directly
(scipy SuperLU): O(holes) memory, no iteration count to tune. A plane, and any quadratic
harmonic such as x^2 - y^2, is reproduced exactly inside interior holes.

Source: the standard harmonic inpainting (e.g. MATLAB's ``regionfill``, Gwyddion's "Laplace"
data-correction); nothing is taken from the seed documents.
"""
from __future__ import annotations

import numpy as np

from arsurf.errors import InvalidHeights

__all__ = ["inpaint", "dropout_mask", "require_finite", "DROPOUT_THRESHOLD"]

#: |z| below this (metres) is a controller dropout, not a height: real heights of a scan are
#: offsets of nm to um from the piezo zero, while dropouts in the neaspec export are ~1e-19 m.
DROPOUT_THRESHOLD = 1e-12


def dropout_mask(scan, threshold: float = DROPOUT_THRESHOLD) -> np.ndarray:
    """Boolean mask of dropout pixels: finite values with ``|z| < threshold``.

    Parameters
    ----------
    scan : Scan
        Heights in metres.
    threshold : float, metres
        Pixels with ``|z|`` below it are dropouts (default 1e-12 m). Use it on raw (not
        levelled) data only: levelling moves real pixels through zero.

    Returns
    -------
    (ny, nx) bool

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.scan.scan import Scan
    >>> s = Scan(np.array([[1e-7, 1e-19], [2e-7, 3e-7]]), dx=1e-8, dy=1e-8)
    >>> dropout_mask(s).tolist()
    [[False, True], [False, False]]
    """
    t = float(threshold)
    if not (np.isfinite(t) and t > 0.0):
        raise InvalidHeights(f"dropout threshold must be a positive length in metres (got {threshold!r})")
    h = scan.heights
    with np.errstate(invalid="ignore"):
        return np.isfinite(h) & (np.abs(h) < t)


def require_finite(scan, operation: str) -> None:
    """Raise :class:`InvalidHeights` if ``scan`` has NaN pixels, saying how to fill them.

    For downstream steps (fitting, smoothing) that need every pixel.
    """
    n = int(np.isnan(scan.heights).sum())
    if n:
        raise InvalidHeights(
            f"{operation} needs every pixel, but {scan.source or 'the scan'} has {n} missing (NaN) pixels "
            f"of {scan.heights.size}; fill them first with arsurf.inpaint(scan) "
            f"(and arsurf.scan.inpaint.dropout_mask for ~0 dropouts), or crop them away"
        )


def inpaint(scan, mask: np.ndarray | None = None):
    """Fill the NaN pixels (and the pixels of ``mask``) by solving Laplace's equation.

    Parameters
    ----------
    scan : Scan
        Heights in metres; NaN pixels are filled.
    mask : (ny, nx) bool array, optional
        Extra pixels to replace (e.g. :func:`dropout_mask`), whatever their value.

    Returns
    -------
    Scan
        Same spacing; every pixel finite; ``metadata["history"]`` gains
        ``{"step": "inpaint", "method": "laplace", "filled": n, ...}`` and
        ``metadata["nan_count"]`` becomes 0.

    Raises
    ------
    InvalidHeights
        ``mask`` has the wrong shape, or no pixel is known (nothing to interpolate from).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.scan.scan import Scan
    >>> z = np.add.outer(np.arange(4.0), np.arange(5.0)) * 1e-9   # a plane
    >>> z[1, 2] = np.nan
    >>> out = inpaint(Scan(z, dx=1e-9, dy=1e-9))
    >>> float(round(out.heights[1, 2] * 1e9, 12))
    3.0
    """
    import scipy.sparse as sp
    import scipy.sparse.csgraph as csgraph
    import scipy.sparse.linalg as spla

    h = np.array(scan.heights, dtype=np.float64)
    ny, nx = h.shape
    holes = np.isnan(h)
    n_nan = int(holes.sum())
    n_mask = 0
    if mask is not None:
        m = np.asarray(mask)
        if m.shape != h.shape:
            raise InvalidHeights(f"inpaint mask must have the scan's shape {h.shape} (got {m.shape})")
        m = m.astype(bool)
        n_mask = int((m & ~holes).sum())
        holes = holes | m
    n = int(holes.sum())
    if n == 0:
        return scan.with_heights(h, step={"step": "inpaint", "method": "laplace", "filled": 0})
    if n == h.size:
        raise InvalidHeights(
            f"cannot inpaint {scan.source or 'the scan'}: every pixel is missing or masked, so there is "
            "nothing to interpolate from"
        )
    # number the unknowns
    index = np.full(h.shape, -1, dtype=np.int64)
    index[holes] = np.arange(n)
    iy, ix = np.nonzero(holes)
    p = index[iy, ix]
    known = np.where(holes, 0.0, h)
    wx, wy = 1.0 / scan.dx**2, 1.0 / scan.dy**2
    diag = np.zeros(n)
    rhs = np.zeros(n)
    rows, cols, vals = [], [], []
    for ddy, ddx, w in ((0, 1, wx), (0, -1, wx), (1, 0, wy), (-1, 0, wy)):
        jy, jx = iy + ddy, ix + ddx
        inside = (jy >= 0) & (jy < ny) & (jx >= 0) & (jx < nx)
        pi, qy, qx = p[inside], jy[inside], jx[inside]
        diag[pi] += w
        q = index[qy, qx]
        unknown = q >= 0
        rows.append(pi[unknown])
        cols.append(q[unknown])
        vals.append(np.full(int(unknown.sum()), -w))
        np.add.at(rhs, pi[~unknown], w * known[qy[~unknown], qx[~unknown]])
    rows.append(np.arange(n))
    cols.append(np.arange(n))
    vals.append(diag)
    A = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    # a hole region that touches no known pixel makes the system singular: find it first
    ncomp, labels = csgraph.connected_components(A, directed=False)
    touches = np.zeros(n, dtype=bool)
    for ddy, ddx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        jy, jx = iy + ddy, ix + ddx
        inside = (jy >= 0) & (jy < ny) & (jx >= 0) & (jx < nx)
        ok = np.zeros(n, dtype=bool)
        ok[inside] = ~holes[jy[inside], jx[inside]]
        touches |= ok
    grounded = np.zeros(ncomp, dtype=bool)
    grounded[labels[touches]] = True
    if not grounded.all():
        raise InvalidHeights(
            f"cannot inpaint {scan.source or 'the scan'}: {int((~grounded).sum())} hole region(s) touch no known "
            "pixel (only possible when every pixel is missing or masked)"
        )
    z = spla.splu(A).solve(rhs)
    out = h.copy()
    out[holes] = z
    meta_step = {"step": "inpaint", "method": "laplace", "filled": n, "nan_filled": n_nan,
                 "masked_filled": n_mask, "boundary": "neumann at the image border"}
    result = scan.with_heights(out, step=meta_step)
    result.metadata["nan_count"] = 0
    return result
