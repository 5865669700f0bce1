r"""Fitting a bicubic B-spline to a height map (interpolation or penalised least squares).

With Z (ny, nx) the heights at the pixel centres x = ix·dx, y = iy·dy, the control heights P
(nu, nv) solve one of two tensor-product problems, each as two sets of banded solves, O(N) for
N pixels:

* **interpolation** (the default): knots at the pixel centres (knot spacing = pixel spacing,
  so the span lookup is exact and O(1)), nu = nx + 2 and nv = ny + 2 control points; the two
  extra conditions per axis are *not-a-knot* (S''' continuous across the first and last
  interior knots, as in scipy's ``make_interp_spline``), so cubics are reproduced exactly:

  .. math:: A_u P A_v^T = \tilde Z^T, \qquad A = \begin{bmatrix} c_0^T \\ B \\ c_1^T \end{bmatrix}

  with B the collocation matrix, c the not-a-knot rows and Z̃ the heights padded with zeros.
* **approximation** (fewer control points and/or a smoothing penalty λ):

  .. math:: P = (B_u^T B_u + λ D_u^T D_u)^{-1} B_u^T Z^T B_v (B_v^T B_v + λ D_v^T D_v)^{-1}

  the tensor-product ("sandwich") P-spline with second-difference penalties D (Eilers & Marx
  1996, *Stat. Sci.* 11, 89; Xiao, Li & Ruppert 2013, *J. R. Stat. Soc. B* 75, 577).

Why knots at the pixels: interpolating N sites with N control points on clamped uniform knots
is also well posed, but its condition number grows exponentially with N (~1e9 at N = 128)
because the sites drift away from the Greville abscissae; with knots at the sites it stays < 10.
"""
from __future__ import annotations

import numpy as np
from numba import njit
from scipy.linalg import lapack, solveh_banded

from arsurf import _validation
from arsurf._logging import progress
from arsurf.errors import InvalidHeights, SurfaceError
from arsurf.scan.scan import Scan
from arsurf.spline.basis import basis_matrix_rows, cubic_basis
from arsurf.spline.knots import clamped_uniform_knots, greville
from arsurf.spline.surface import BSplineSurface


def _not_a_knot_row(knots: np.ndarray, first_span: int) -> np.ndarray:
    """Coefficients (5,) on P[first_span-3 .. first_span+1] of S'''(span) - S'''(span+1) = 0.

    S'' is linear on a span, so S''' there is (S''(right end) - S''(left end)) / h.
    """
    row = np.zeros(5)
    for offset, sign in ((0, 1.0), (1, -1.0)):
        i = first_span + offset
        h = knots[i + 1] - knots[i]
        left = np.array(cubic_basis(knots, i, knots[i])[8:12])
        right = np.array(cubic_basis(knots, i, knots[i + 1])[8:12])
        row[offset:offset + 4] += sign * (right - left) / h
    h = knots[first_span + 1] - knots[first_span]
    return row * h**3  # scaled to O(1), like the collocation rows


_KL = _KU = 4  # band of the interpolation matrix (the not-a-knot rows reach 4 off the diagonal)


def _interpolation_banded(knots: np.ndarray, sites: np.ndarray) -> np.ndarray:
    """LAPACK gbtrf storage (13, N+2), ab[4 + 4 + i - j, j] = A[i, j], of A = [not-a-knot; B; not-a-knot]."""
    n = sites.size + 2
    cols, vals = basis_matrix_rows(knots, sites)
    ab = np.zeros((2 * _KL + _KU + 1, n))
    ab_view = ab[_KL:]  # rows kl.. hold A in ordinary band storage ab_view[ku + i - j, j]
    jj = cols[:, None] + np.arange(4)[None, :]
    ii = np.broadcast_to(np.arange(1, n - 1)[:, None], jj.shape)
    nz = vals != 0.0
    ab_view[_KU + ii[nz] - jj[nz], jj[nz]] = vals[nz]
    first = _not_a_knot_row(knots, 3)       # spans 3, 4: P[0..4]
    last = _not_a_knot_row(knots, n - 2)    # spans n-2, n-1: P[n-5..n-1]
    for j in range(5):
        ab_view[_KU - j, j] = first[j]
        col = n - 5 + j
        ab_view[_KU + (n - 1) - col, col] = last[j]
    return ab


@njit(cache=True)
def _lu_solve_rows(lu, piv, kl, ku, b):
    """Solve A X = B in place for a banded LU (LAPACK gbtrf layout), B (n, m) row by row.

    The same elimination as LAPACK's gbtrs, but each step updates a whole contiguous row of B
    (all m right-hand sides at once), which vectorises where gbtrs walks column by column.
    """
    n, m = b.shape
    kd = kl + ku
    for j in range(n - 1):  # forward: row interchanges and L multipliers
        p = piv[j]
        if p != j:
            for c in range(m):
                t = b[j, c]
                b[j, c] = b[p, c]
                b[p, c] = t
        for r in range(1, min(kl, n - 1 - j) + 1):
            f = lu[kd + r, j]
            if f != 0.0:
                for c in range(m):
                    b[j + r, c] -= f * b[j, c]
    for i in range(n - 1, -1, -1):  # backward: U has kl + ku superdiagonals
        for k in range(1, min(kd, n - 1 - i) + 1):
            f = lu[kd - k, i + k]
            if f != 0.0:
                for c in range(m):
                    b[i, c] -= f * b[i + k, c]
        d = 1.0 / lu[kd, i]
        for c in range(m):
            b[i, c] *= d


def _penalty_rows(knots: np.ndarray) -> np.ndarray:
    """Second divided differences of the control values on their Greville abscissae, (n-2, 3).

    Row k acts on P[k..k+2]; it is scaled by the knot spacing squared so that it is the plain
    second difference [1, -2, 1]/2 in the uniform interior. Its null space is exactly the linear
    functions (which the Greville net represents), so the penalty never bends planes.
    """
    g = greville(knots)
    h = knots[4] - knots[3]
    d0 = np.diff(g)[:-1]
    d1 = np.diff(g)[1:]
    span = g[2:] - g[:-2]
    return h * h * np.stack([1.0 / (d0 * span), -(1.0 / d0 + 1.0 / d1) / span, 1.0 / (d1 * span)], axis=1)


def _normal_banded(cols: np.ndarray, vals: np.ndarray, n: int, knots: np.ndarray, penalty: float) -> np.ndarray:
    """Upper band storage (4, n) of BᵀB + λ DᵀD (bandwidth 3) for solveh_banded."""
    ab = np.zeros((4, n))
    for a in range(4):  # (BᵀB)[c+a, c+b] += vals[:, a] vals[:, b]
        for b in range(a, 4):
            np.add.at(ab[3 - (b - a)], cols + b, vals[:, a] * vals[:, b])
    if penalty > 0.0:
        d = _penalty_rows(knots)
        start = np.arange(n - 2)
        for a in range(3):
            for b in range(a, 3):
                np.add.at(ab[3 - (b - a)], start + b, penalty * d[:, a] * d[:, b])
    return ab


def _bt_times(cols: np.ndarray, vals: np.ndarray, n: int, rhs: np.ndarray) -> np.ndarray:
    """Bᵀ @ rhs for a collocation matrix given by its rows (no dense B)."""
    out = np.zeros((n,) + rhs.shape[1:])
    for a in range(4):
        np.add.at(out, cols + a, vals[:, a, None] * rhs)
    return out


def _solve_axis(knots: np.ndarray, sites: np.ndarray, rhs: np.ndarray, n: int, smoothing: float) -> np.ndarray:
    """One tensor factor: interpolation (banded LU) or the penalised normal equations (Cholesky)."""
    if n == sites.size + 2 and smoothing == 0.0:
        lu, piv, info = lapack.dgbtrf(_interpolation_banded(knots, sites), _KL, _KU)
        if info != 0:  # pragma: no cover - A is nonsingular for any sites (Schoenberg-Whitney)
            raise SurfaceError(f"the interpolation matrix is singular (LAPACK gbtrf info={info})")
        padded = np.zeros((n,) + rhs.shape[1:])
        padded[1:-1] = rhs
        _lu_solve_rows(lu, piv.astype(np.int64), _KL, _KU, padded)
        return padded
    cols, vals = basis_matrix_rows(knots, sites)
    ab = _normal_banded(cols, vals, n, knots, smoothing)
    return solveh_banded(ab, _bt_times(cols, vals, n, rhs), overwrite_ab=True, check_finite=False)


@njit(cache=True)
def _transpose(a, out):
    """out = aᵀ, blocked for the cache (numpy's strided copy is ~3x slower at 1024²)."""
    n, m = a.shape
    bs = 32
    for i0 in range(0, n, bs):
        for j0 in range(0, m, bs):
            for i in range(i0, min(i0 + bs, n)):
                for j in range(j0, min(j0 + bs, m)):
                    out[j, i] = a[i, j]


#: scans from this many pixels on show a progress bar while fitting (4096² takes ~1 s here)
_PROGRESS_PIXELS = 1 << 22


def check_control_shape(nx: int, ny: int, control_shape, smoothing: float = 0.0,
                        names: tuple[str, str] = ("control_shape", "smoothing")) -> tuple[int, int]:
    """The (nu, nv) control net of a fit of an (ny, nx) scan, or :class:`SurfaceError` stating the rule.

    None gives the interpolating net (nx + 2, ny + 2); else 4 <= nu <= nx, 4 <= nv <= ny (least
    squares needs no more unknowns than pixels), or up to (nx + 2, ny + 2) when ``smoothing`` > 0
    (the penalty makes the system determined). ``names`` are the words the message uses for the
    two settings (the CLI says ``--control`` and ``--smoothing``).

    Examples
    --------
    >>> check_control_shape(256, 256, (258, 258)), check_control_shape(256, 256, (100, 80))
    ((258, 258), (100, 80))
    """
    nu, nv = (nx + 2, ny + 2) if control_shape is None else (int(control_shape[0]), int(control_shape[1]))
    interpolating = (nu, nv) == (nx + 2, ny + 2)
    limit = (nx + 2, ny + 2) if (interpolating or smoothing > 0.0) else (nx, ny)
    if not (4 <= nu <= limit[0] and 4 <= nv <= limit[1]):
        what, penalty = names
        raise SurfaceError(
            f"{what} must be ({nx + 2}, {ny + 2}) to interpolate this {nx}x{ny} scan, or between (4, 4) and "
            f"({nx}, {ny}) to approximate it by least squares (up to ({nx + 2}, {ny + 2}) with {penalty} > 0); "
            f"got ({nu}, {nv})"
        )
    return nu, nv


def fit_surface(scan: Scan, control_shape: tuple[int, int] | None = None, smoothing: float = 0.0) -> BSplineSurface:
    """Fit a bicubic B-spline surface to a scan's heights.

    Parameters
    ----------
    scan : Scan
        Heights (ny, nx) in metres without NaN (use :func:`arsurf.inpaint` first), at least 4x4.
    control_shape : (nu, nv), optional
        Control points along x and y. Default (nx + 2, ny + 2): the interpolating fit with knots
        at the pixel centres. Fewer (<= (nx, ny)) give a least-squares approximation.
    smoothing : float
        λ >= 0, weight of the second-difference penalty on the control heights (dimensionless;
        0 = none). λ > 0 or fewer control points select the penalised least-squares fit.

    Returns
    -------
    BSplineSurface
        Domain [0, (nx-1)dx] x [0, (ny-1)dy]; control points on the Greville abscissae.

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.scan.scan import Scan
    >>> y, x = np.mgrid[0:8, 0:8] * 1e-9
    >>> s = fit_surface(Scan(2 * x + 3 * y, dx=1e-9, dy=1e-9))
    >>> bool(abs(s.evaluate(2.5e-9, 3.5e-9)[2] - 15.5e-9) < 1e-22)
    True
    """
    if not isinstance(scan, Scan):
        raise SurfaceError(f"fit_surface takes an arsurf.Scan (got {type(scan).__name__})")
    z = scan.heights
    ny, nx = z.shape
    where = scan.source or "scan"
    if nx < 4 or ny < 4:
        raise InvalidHeights(
            f"a bicubic fit needs at least 4x4 pixels (got {nx}x{ny}) in {where}; "
            "a single scan line cannot define a surface"
        )
    unit = scan.metadata.get("z_unit") if isinstance(scan.metadata, dict) else None
    if unit not in (None, "m"):
        raise InvalidHeights(
            f"channel {scan.channel!r} of {where} holds values in {unit!r}, not heights: a surface is fitted to "
            f"a height channel (channels: {scan.metadata.get('channels')})"
        )
    if scan.metadata.get("height") is False:
        raise InvalidHeights(
            f"channel {scan.channel!r} of {where} is in metres but its name says it is not the topography "
            f"(an amplitude, a deflection, an error...): fit a height channel (channels: "
            f"{scan.metadata.get('channels')}), or, if it is a height, say so with scan.as_height() (CLI: --as-height)"
        )
    if not np.isfinite(z).all():
        raise InvalidHeights(
            f"{scan.nan_count} pixels are NaN in {where}; fill them with arsurf.inpaint(scan) "
            "(or crop them away) before fitting"
        )
    smoothing = float(smoothing)
    if not (np.isfinite(smoothing) and smoothing >= 0.0):
        raise SurfaceError(f"`smoothing` must be >= 0 (got {smoothing!r}); it is the penalty weight λ")
    nu, nv = check_control_shape(nx, ny, control_shape, smoothing)
    # the two axis solves, their transpose and the surface's (nu, nv, 3) net: ~6 float64 per point
    _validation.check_memory(48.0 * nu * nv + 16.0 * nx * ny, f"fitting this {nx}x{ny} scan", SurfaceError,
                             "crop it, or fit fewer control points (control_shape) to approximate it")
    x, y = scan.x, scan.y
    ku = clamped_uniform_knots(nu, x[0], x[-1])
    kv = clamped_uniform_knots(nv, y[0], y[-1])
    # A_v Y = Z -> Y (nv, nx);  A_u P = Yᵀ -> P (nu, nv)
    # a bar for the three steps of a fit that takes about a second or more (~4 Mpixel and up)
    bar = progress(total=3, desc="fit", unit="step", enabled=nx * ny >= _PROGRESS_PIXELS)
    yz = _solve_axis(kv, y, z, nv, smoothing)
    bar.update(1)
    yz_t = np.empty((yz.shape[1], yz.shape[0]))
    _transpose(yz, yz_t)
    bar.update(1)
    p = _solve_axis(ku, x, yz_t, nu, smoothing)
    bar.update(1)
    bar.close()
    return BSplineSurface.from_heights(p, (x[0], x[-1]), (y[0], y[-1]))
