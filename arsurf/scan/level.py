"""Levelling of AFM height maps: background removal, row alignment and scar removal.

One entry point, :func:`level`, with one method per kind of artefact:

==================  ==========================================================================
``"plane"``         least-squares plane :math:`z = a + b x + c y`
``"plane-robust"``  the same plane by iteratively reweighted least squares (Huber, then Tukey's
                    biweight): pits, particles and spikes get zero weight
``"polynomial"``    2-D polynomial background of total degree ``order`` (or degrees
                    ``(order_x, order_y)``), least squares
``"polynomial-robust"`` the same, reweighted like ``"plane-robust"``
``"rows-median"``   row alignment: each row is shifted by the median of its differences with the
                    previous row (Gwyddion's *Align rows / median of differences*)
``"rows-trimmed"``  the same with a trimmed mean of the differences
``"scars"``         detection of short streaks along the fast axis (x) that differ strongly from
                    the rows above and below, replaced by linear interpolation along y
==================  ==========================================================================

Every method ignores NaN pixels in its fit (they stay NaN), accepts a boolean ``mask`` of pixels
to EXCLUDE from the fit (particles, pits...), returns a new :class:`~arsurf.scan.scan.Scan`, and
appends what it did (method, parameters, fitted coefficients in SI units) to
``metadata["history"]``.

Fits are done in a Legendre basis of the centred, scaled coordinates (well conditioned at any
order), by the tensor-product normal equations, which cost O(N q^2) for N pixels and q basis
functions per axis and never build an (N, terms) design matrix. The coefficients are converted
back to plain monomials in metres for the history.
"""
from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from numpy.polynomial import legendre as _leg
from numpy.polynomial import polynomial as _poly
from scipy import ndimage

from arsurf import _validation
from arsurf.errors import LevelingError
from arsurf.scan.scan import Scan

__all__ = ["level", "LevelingError", "METHODS"]


#: Options each method accepts (besides ``mask``); any other option given is an error.
METHODS: dict[str, tuple[str, ...]] = {
    "plane": (),
    "plane-robust": ("loss", "tuning", "max_iter"),
    "polynomial": ("order",),
    "polynomial-robust": ("order", "loss", "tuning", "max_iter"),
    "rows-median": (),
    "rows-trimmed": ("trim",),
    "scars": ("threshold", "threshold_low", "min_length", "max_width"),
}

# Tuning constants of the M-estimators in units of the robust residual scale: 95 % asymptotic
# efficiency under Gaussian noise (Holland & Welsch 1977; Huber 1981, "Robust Statistics").
_TUNING = {"huber": 1.345, "tukey": 4.685}
# MAD -> standard deviation of a Gaussian: 1 / Phi^-1(3/4).
_MAD_TO_SIGMA = 1.482602218505602
# Defaults of the other options (Gwyddion's align-rows trimmed mean uses 1/4 per side as well).
_DEFAULTS: dict[str, Any] = {
    "order": 2,
    "loss": "tukey",
    "tuning": None,
    "max_iter": 50,
    "trim": 0.25,
    # scars: min_length is Gwyddion's default; max_width 3 (Gwyddion: 4) and the thresholds in
    # robust sigmas were chosen on the real test scans (shared/scans-real): they remove the
    # Veeco and PMMA-wedge scars and leave the other seven scans untouched, except features
    # that are themselves <= 3 rows thin along x (slits, lithographic lines)
    "threshold": 6.0,
    "threshold_low": 3.0,
    "min_length": 16,
    "max_width": 3,
}
# A reweighting loop has converged when the background moved by less than this fraction of the
# residual scale (or by less than _CONV_ABS of the height range, the float64 floor).
_CONV_REL = 1e-6
_CONV_ABS = 1e-13


def level(
    scan: Scan,
    method: str = "plane",
    *,
    mask: np.ndarray | None = None,
    order: int | tuple[int, int] | None = None,
    loss: str | None = None,
    tuning: float | None = None,
    max_iter: int | None = None,
    trim: float | None = None,
    threshold: float | None = None,
    threshold_low: float | None = None,
    min_length: int | None = None,
    max_width: int | None = None,
) -> Scan:
    r"""Remove a background, align rows or remove scars; return a new levelled Scan.

    Background methods fit, to the valid pixels (finite and not in ``mask``), a polynomial

    .. math::

        b(x, y) = \sum_{i + j \le p} c_{ij}\, x^i y^j, \qquad x = i_x\,dx,\; y = i_y\,dy,

    (``p = 1`` for the planes) by minimising :math:`\sum w_k\,(z_k - b(x_k, y_k))^2` with
    :math:`w_k = 1` (least squares) or, for the robust methods, by iteratively reweighted least
    squares with weights from the residuals :math:`u = r / s`, :math:`s = 1.4826\,\mathrm{MAD}(r)`:
    Huber :math:`w = \min(1, k/|u|)`, :math:`k = 1.345`, until converged, then (``loss="tukey"``)
    Tukey's biweight :math:`w = (1 - (u/c)^2)^2` for :math:`|u| < c`, else 0, :math:`c = 4.685`.
    The plane start is the median of the pixel-to-pixel slopes, so outliers never steer it.
    The fitted background is subtracted from every pixel, masked ones included.

    Row alignment (``"rows-median"``, ``"rows-trimmed"``) estimates the offset between adjacent
    rows as a robust location of the differences :math:`z_{i+1,j} - z_{i,j}` over the columns j
    where both pixels are valid, accumulates the offsets down the image and subtracts them
    (their mean is zero, so the mean height is kept; Gwyddion also removes their linear trend,
    which keeps a y tilt for a later plane fit: here the y tilt goes with the row offsets). Rows
    that share no valid column with the previous usable row are tied to it by the difference of
    the row medians; rows without any valid pixel get interpolated offsets.

    Scar removal (``"scars"``) looks, in every column, for bands of k <= ``max_width`` rows lying
    entirely above (or entirely below) both rows that bracket them,

    .. math::

        e = \frac{\min_{band} z - \max(z_{above}, z_{below})}{s_v} \quad\text{(or the
        mirror for a dip)}, \qquad s_v = 1.4826\,\mathrm{MAD}(z_{i+1,j} - z_{i,j}),

    as Gwyddion's *Mark scars* does, but sign-agnostic and with a robust scale. Pixels with
    :math:`e \ge` ``threshold`` seed a streak, which extends along x over pixels with
    :math:`e \ge` ``threshold_low`` (gaps of one or two pixels, where a streak crosses the level
    of its neighbours, are bridged); streaks shorter than ``min_length`` pixels are dropped. The
    rest are replaced by linear interpolation along y between the nearest unmarked pixels above
    and below, and detection repeats on the result (at most 4 passes) until nothing new is
    found. Apply it after row alignment (an unaligned row is one long scar). A real feature
    thinner than ``max_width`` rows and lying along x (a thin tube) looks exactly like a scar:
    protect it with ``mask``.

    Parameters
    ----------
    scan : Scan
        Height map, metres; NaN pixels are ignored and stay NaN.
    method : str
        One of ``"plane"``, ``"plane-robust"``, ``"polynomial"``, ``"polynomial-robust"``,
        ``"rows-median"``, ``"rows-trimmed"``, ``"scars"``.
    mask : (ny, nx) bool, optional
        True for pixels to EXCLUDE from the fit (particles, pits). They are still corrected;
        ``"scars"`` never marks or modifies them.
    order : int or (int, int), optional
        Polynomial methods only: total degree (default 2), or ``(order_x, order_y)`` for a full
        tensor-product background.
    loss : {"tukey", "huber"}, optional
        Robust methods only (default ``"tukey"``).
    tuning : float, optional
        Robust methods only: tuning constant in robust standard deviations (default 4.685 for
        Tukey, 1.345 for Huber).
    max_iter : int, optional
        Robust methods only: iteration limit of each reweighting phase (default 50).
    trim : float, optional
        ``"rows-trimmed"`` only: fraction cut from EACH end of the sorted differences,
        0 <= trim < 0.5 (default 0.25; 0 is the mean, -> 0.5 the median).
    threshold, threshold_low : float, optional
        ``"scars"`` only: detection and extension thresholds, in robust standard deviations
        :math:`s_v` of the row-to-row differences (defaults 6 and 3).
    min_length : int, optional
        ``"scars"`` only: shortest streak along x, pixels (default 16).
    max_width : int, optional
        ``"scars"`` only: widest streak across y, rows (default 3).

    Returns
    -------
    Scan
        New scan with the same spacing; ``metadata["history"]`` gains one entry: a dict with
        ``operation="level"``, ``method``, the parameters and the result (``coefficients`` as
        ``{"x_power", "y_power", "coefficient"}`` terms in metres, ``row_offsets`` in metres,
        or the number of scar pixels replaced).

    Raises
    ------
    LevelingError
        Unknown method, option not used by the method, bad option value, mask of the wrong
        shape, or too few valid pixels to determine the background.

    Notes
    -----
    The source ([SplineAR]) smooths the scan before the B-spline fit; levelling first is the
    usual AFM practice (Gwyddion: Nečas & Klapetek 2012, Cent. Eur. J. Phys. 10, 181).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.scan.scan import Scan
    >>> y, x = np.mgrid[0:8, 0:10] * 1e-9
    >>> s = level(Scan(2e-9 + 0.1 * x - 0.05 * y, dx=1e-9, dy=1e-9))
    >>> bool(np.abs(s.heights).max() < 1e-20)
    True
    >>> round(s.history[-1]["coefficients"]["slope_x"], 12)
    0.1
    """
    if not isinstance(scan, Scan):
        raise LevelingError(
            f"level() needs an arsurf Scan (got {type(scan).__name__}); "
            "wrap a height array as Scan(heights, dx=..., dy=...)"
        )
    if method not in METHODS:
        raise LevelingError(
            f"unknown levelling method {method!r}; use one of {', '.join(repr(m) for m in METHODS)}"
        )
    given = {
        "order": order, "loss": loss, "tuning": tuning, "max_iter": max_iter, "trim": trim,
        "threshold": threshold, "threshold_low": threshold_low, "min_length": min_length,
        "max_width": max_width,
    }
    allowed = METHODS[method]
    for name, value in given.items():
        if value is not None and name not in allowed:
            users = [m for m, opts in METHODS.items() if name in opts]
            raise LevelingError(
                f"option `{name}` does not apply to method {method!r} (got {value!r}); "
                f"it is used by {', '.join(repr(m) for m in users)}"
            )
    opts = {name: (given[name] if given[name] is not None else _DEFAULTS[name]) for name in allowed}
    excluded = _check_mask(mask, scan.shape)
    z = scan.heights
    valid = np.isfinite(z)
    if excluded is not None:
        valid &= ~excluded
    if not valid.any():
        raise LevelingError(
            f"no valid pixel to level in {scan.source or 'scan'}: all {z.size} pixels are NaN or masked; "
            "mask fewer pixels"
        )

    step: dict[str, Any] = {"operation": "level", "method": method}
    step["masked_pixels"] = int(excluded.sum()) if excluded is not None else 0

    if method in ("plane", "plane-robust", "polynomial", "polynomial-robust"):
        degrees = (1, 1, 1) if method.startswith("plane") else _check_order(opts["order"])
        robust = method.endswith("-robust")
        if robust:
            loss_name = _check_loss(opts["loss"])
            tune = _check_positive("tuning", opts["tuning"]) if opts["tuning"] is not None else None
            iters = _check_int("max_iter", opts["max_iter"], 1)
        model = _Background(scan.shape, scan.dx, scan.dy, degrees)
        if robust:
            coef, info = model.fit_robust(z, valid, loss_name, tune, iters)
            step.update(loss=loss_name, tuning=info.pop("tuning"), **info)
        else:
            coef = model.fit(z, valid, valid.astype(np.float64))
        background = model.evaluate(coef)
        new = z - background
        terms = model.monomials(coef)
        if method.startswith("plane"):
            step["coefficients"] = {
                "offset": terms.get((0, 0), 0.0),
                "slope_x": terms.get((1, 0), 0.0),
                "slope_y": terms.get((0, 1), 0.0),
            }
        else:
            step["order"] = list(opts["order"]) if isinstance(opts["order"], tuple) else int(opts["order"])
            step["coefficients"] = [
                {"x_power": i, "y_power": j, "coefficient": c} for (i, j), c in sorted(terms.items())
            ]
        step["origin"] = "centre of pixel (0, 0); x = ix*dx, y = iy*dy, metres"
    elif method in ("rows-median", "rows-trimmed"):
        if method == "rows-trimmed":
            frac = float(opts["trim"])
            if not (0.0 <= frac < 0.5):
                raise LevelingError(
                    f"`trim` must be in [0, 0.5) (got {opts['trim']!r}); it is the fraction cut from "
                    "each end of the sorted row differences"
                )
            step["trim"] = frac
        else:
            frac = None
        offsets = _row_offsets(z, valid, frac)
        new = z - offsets[:, None]
        step["row_offsets"] = [float(v) for v in offsets]
    else:  # scars
        thr = _check_positive("threshold", opts["threshold"])
        thr_low = _check_positive("threshold_low", opts["threshold_low"])
        if thr_low > thr:
            raise LevelingError(
                f"`threshold_low` ({thr_low}) must not exceed `threshold` ({thr}); the low threshold "
                "only extends streaks found with the high one"
            )
        min_len = _check_int("min_length", opts["min_length"], 1)
        width = _check_int("max_width", opts["max_width"], 1)
        new, marked, streaks = _remove_scars(z, valid, thr, thr_low, min_len, width)
        step.update(
            threshold=thr, threshold_low=thr_low, min_length=min_len, max_width=width,
            scar_pixels=int(marked.sum()), scars=int(streaks),
        )
    nan = np.isnan(z)
    if nan.any():
        new = np.where(nan, np.nan, new)
    return scan.with_heights(new, step=step)


# ---------------------------------------------------------------------------------------------
# validation helpers


def _check_mask(mask, shape) -> np.ndarray | None:
    if mask is None:
        return None
    m = np.asarray(mask)
    if m.shape != tuple(shape):
        raise LevelingError(
            f"`mask` must have the scan's shape {tuple(shape)} (got {m.shape}); "
            "it marks with True the pixels to exclude from the fit"
        )
    if m.dtype != np.bool_:
        if m.dtype.kind in "iuf" and np.isin(m, (0, 1)).all():
            m = m.astype(bool)
        else:
            raise LevelingError(
                f"`mask` must be boolean (got dtype {m.dtype}); True excludes a pixel from the fit"
            )
    return m


def _check_order(order) -> tuple[int, int, int]:
    """(max x degree, max y degree, max total degree) of the allowed terms."""
    if isinstance(order, (tuple, list)):
        if len(order) != 2:
            raise LevelingError(f"`order` must be an int or a pair (order_x, order_y) (got {order!r})")
        ox = _check_int("order_x", order[0], 0)
        oy = _check_int("order_y", order[1], 0)
        return ox, oy, ox + oy
    p = _check_int("order", order, 0)
    return p, p, p


def _check_int(name: str, value, lowest: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < lowest:
        raise LevelingError(f"`{name}` must be an integer >= {lowest} (got {value!r})")
    return int(value)


def _check_positive(name: str, value) -> float:
    return _validation.positive(value, name, LevelingError)


def _check_loss(loss) -> str:
    if loss not in _TUNING:
        raise LevelingError(f"`loss` must be 'tukey' or 'huber' (got {loss!r})")
    return loss


# ---------------------------------------------------------------------------------------------
# polynomial backgrounds


class _Background:
    """Polynomial background on the pixel grid in a tensor Legendre basis.

    Terms are P_i(xn) P_j(yn) with xn = (x - cx)/hx in [-1, 1]; allowed (i, j): i <= ox,
    j <= oy, i + j <= total, and no x (y) terms when the scan has a single column (row).
    """

    def __init__(self, shape, dx: float, dy: float, degrees: tuple[int, int, int]) -> None:
        ny, nx = shape
        ox, oy, total = degrees
        ox = min(ox, nx - 1)
        oy = min(oy, ny - 1)
        self.terms = [(i, j) for j in range(oy + 1) for i in range(ox + 1) if i + j <= total]
        self.qx, self.qy = ox + 1, oy + 1
        self.dx, self.dy = dx, dy
        self.cx, self.hx = 0.5 * (nx - 1) * dx, max(0.5 * (nx - 1) * dx, dx)
        self.cy, self.hy = 0.5 * (ny - 1) * dy, max(0.5 * (ny - 1) * dy, dy)
        xn = (np.arange(nx) * dx - self.cx) / self.hx
        yn = (np.arange(ny) * dy - self.cy) / self.hy
        self.vx = _leg.legvander(xn, ox)  # (nx, qx)
        self.vy = _leg.legvander(yn, oy)  # (ny, qy)
        self.ti = np.array([t[0] for t in self.terms])
        self.tj = np.array([t[1] for t in self.terms])

    def fit(self, z: np.ndarray, valid: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Weighted least squares coefficients C[j, i] (zero outside the allowed terms)."""
        qx, qy = self.qx, self.qy
        ax = (self.vx[:, :, None] * self.vx[:, None, :]).reshape(-1, qx * qx)
        ay = (self.vy[:, :, None] * self.vy[:, None, :]).reshape(-1, qy * qy)
        moments = (ay.T @ (w @ ax)).reshape(qy, qy, qx, qx)  # [j, l, i, k]
        ti, tj = self.ti, self.tj
        gram = moments[tj[:, None], tj[None, :], ti[:, None], ti[None, :]]
        wz = np.where(valid, z, 0.0) * w
        rhs_full = self.vy.T @ wz @ self.vx  # [j, i]
        rhs = rhs_full[tj, ti]
        scale = np.sqrt(np.clip(np.diag(gram), 1e-300, None))
        g = gram / scale[:, None] / scale[None, :]
        sol, _, rank, sv = np.linalg.lstsq(g, rhs / scale, rcond=1e-10)
        if rank < len(self.terms):
            n = int(np.count_nonzero(w))
            raise LevelingError(
                f"the {n} pixels left for the fit do not determine a background with "
                f"{len(self.terms)} terms (rank {rank}): too few valid pixels, or all on one line; "
                "mask fewer pixels or lower `order`"
            )
        coef = np.zeros((qy, qx))
        coef[tj, ti] = sol / scale
        return coef

    def evaluate(self, coef: np.ndarray) -> np.ndarray:
        return self.vy @ coef @ self.vx.T

    def fit_robust(self, z, valid, loss: str, tuning: float | None, max_iter: int):
        """IRLS: start (median slopes for a plane, least squares otherwise), Huber, then Tukey."""
        zv = z[valid]
        zscale = float(np.max(np.abs(zv - np.median(zv)))) or 1.0
        floor = 1e-12 * zscale
        w = valid.astype(np.float64)
        if len(self.terms) == 3 and self.qx == 2 and self.qy == 2:
            coef = self._median_plane(z, valid)
        else:
            coef = self.fit(z, valid, w)
        phases = ["huber"] + (["tukey"] if loss == "tukey" else [])
        total_iter = 0
        converged = False
        scale = floor
        for phase in phases:
            k = tuning if (tuning is not None and phase == loss) else _TUNING[phase]
            converged = False
            for _ in range(max_iter):
                total_iter += 1
                r = z - self.evaluate(coef)
                rv = r[valid]
                scale = max(_MAD_TO_SIGMA * float(np.median(np.abs(rv - np.median(rv)))), floor)
                u = np.abs(np.where(valid, r, 0.0)) / (k * scale)
                if phase == "huber":
                    w = np.where(valid, 1.0 / np.maximum(u, 1.0), 0.0)
                else:
                    w = np.where(valid & (u < 1.0), (1.0 - u * u) ** 2, 0.0)
                new = self.fit(z, valid, w)
                step = float(np.abs(new - coef).sum())
                coef = new
                if step <= max(_CONV_REL * scale, _CONV_ABS * zscale):
                    converged = True
                    break
        if not converged:
            warnings.warn(
                f"robust levelling did not converge in {max_iter} iterations per phase; the "
                "background may be off by a fraction of the noise; raise `max_iter`",
                RuntimeWarning,
                stacklevel=3,
            )
        info = {
            "tuning": float(tuning if tuning is not None else _TUNING[loss]),
            "iterations": total_iter,
            "converged": converged,
            "residual_scale": float(scale),
            "outlier_pixels": int(np.count_nonzero(valid & (w == 0.0))) if loss == "tukey" else 0,
        }
        return coef, info

    def _median_plane(self, z, valid) -> np.ndarray:
        """Plane from the medians of the pixel-to-pixel slopes and of the remaining offsets."""
        coef = np.zeros((self.qy, self.qx))
        gx = np.where(valid[:, 1:] & valid[:, :-1], z[:, 1:] - z[:, :-1], np.nan)
        gy = np.where(valid[1:, :] & valid[:-1, :], z[1:, :] - z[:-1, :], np.nan)
        # slope per normalised coordinate: dz/dxn = (dz per pixel) * hx / dx
        sx = float(np.nanmedian(gx)) * self.hx / self.dx if np.isfinite(gx).any() else 0.0
        sy = float(np.nanmedian(gy)) * self.hy / self.dy if np.isfinite(gy).any() else 0.0
        if self.qx > 1:
            coef[0, 1] = sx
        if self.qy > 1:
            coef[1, 0] = sy
        rest = z - self.evaluate(coef)
        coef[0, 0] = float(np.median(rest[valid]))
        return coef

    def monomials(self, coef: np.ndarray) -> dict[tuple[int, int], float]:
        """Coefficients of x**i * y**j (x, y in metres from pixel (0, 0)) for the allowed terms."""
        mx = self._to_power(self.qx, self.cx, self.hx)  # [i, a]
        my = self._to_power(self.qy, self.cy, self.hy)  # [j, b]
        d = my.T @ coef @ mx  # [b, a]
        return {(int(a), int(b)): float(d[b, a]) for (a, b) in self.terms}

    @staticmethod
    def _to_power(q: int, c: float, h: float) -> np.ndarray:
        out = np.zeros((q, q))
        sub = _poly.Polynomial([-c / h, 1.0 / h])
        for i in range(q):
            e = np.zeros(i + 1)
            e[i] = 1.0
            p = _poly.Polynomial(_leg.leg2poly(e))(sub).coef
            out[i, : len(p)] = p
        return out


# ---------------------------------------------------------------------------------------------
# row alignment


def _row_offsets(z: np.ndarray, valid: np.ndarray, trim: float | None) -> np.ndarray:
    """Offset of every row (zero mean over usable rows), metres."""
    ny = z.shape[0]
    if ny >= 2 and valid.all():  # fast path: every difference is usable
        d = z[1:] - z[:-1]
        step = _trimmed_mean(d, trim) if trim is not None else np.median(d, axis=1)
        cum = np.concatenate([[0.0], np.cumsum(step)])
        return cum - cum.mean()
    usable = np.flatnonzero(valid.any(axis=1))
    offsets = np.zeros(ny)
    if usable.size >= 2:
        zu = z[usable]
        vu = valid[usable]
        both = vu[1:] & vu[:-1]
        diff = np.where(both, zu[1:] - zu[:-1], np.nan)
        has = both.any(axis=1)
        step = np.zeros(usable.size - 1)
        if has.any():
            d = diff[has]
            step[has] = _trimmed_mean(d, trim) if trim is not None else _nan_median_rows(d)
        if not has.all():
            med = _nan_median_rows(np.where(vu, zu, np.nan))
            step[~has] = (med[1:] - med[:-1])[~has]
        cum = np.concatenate([[0.0], np.cumsum(step)])
        cum -= cum.mean()
        offsets = np.interp(np.arange(ny), usable, cum)
    return offsets


def _nan_median_rows(a: np.ndarray) -> np.ndarray:
    """Median of each row ignoring NaN; every row has at least one finite value.

    Vectorised: np.median (a partition) without NaN, else a row sort (NaN last) and the middle
    of the finite part (np.nanmedian loops over the rows in Python).
    """
    if np.isfinite(a).all():
        return np.median(a, axis=1)
    s = np.sort(a, axis=1)
    n = np.isfinite(s).sum(axis=1)
    rows = np.arange(s.shape[0])
    return 0.5 * (s[rows, (n - 1) // 2] + s[rows, n // 2])


def _trimmed_mean(a: np.ndarray, trim: float) -> np.ndarray:
    """Mean of each row after cutting floor(trim*n) values from each end (NaN ignored)."""
    s = np.sort(a, axis=1)  # NaN sorted last
    n = np.isfinite(s).sum(axis=1)
    k = np.floor(trim * n).astype(np.int64)
    k = np.minimum(k, (n - 1) // 2)
    cs = np.concatenate([np.zeros((s.shape[0], 1)), np.cumsum(np.nan_to_num(s), axis=1)], axis=1)
    rows = np.arange(s.shape[0])
    total = cs[rows, n - k] - cs[rows, k]
    return total / (n - 2 * k)


# ---------------------------------------------------------------------------------------------
# scars


# Scar removal repeats detection on its own output (a streak only partly replaced can stand out
# of the interpolated rows next to it) until nothing new is found, at most this many times.
_SCAR_PASSES = 4
# Longest gap (pixels along x) inside one streak: where it crosses its neighbours' level, or
# where NaN pixels leave its score unknown.
_SCAR_GAP = 2


def _remove_scars(z, valid, thr, thr_low, min_len, width):
    """Detect streaks along x that stand out of the rows above and below; interpolate along y.

    Returns (new heights, replaced-pixel mask, number of streaks = connected marked regions).
    """
    out = z.copy()
    replaced = np.zeros(z.shape, bool)
    sigma = None
    for _ in range(_SCAR_PASSES):
        out, marked, sigma = _scar_pass(out, valid, thr, thr_low, min_len, width, sigma)
        if not marked.any():
            break
        replaced |= marked
    streaks = ndimage.label(replaced)[1] if replaced.any() else 0
    return out, replaced, int(streaks)


def _scar_pass(z, valid, thr, thr_low, min_len, width, sigma):
    """One detection + interpolation pass; `sigma` (None on the first pass) is kept across passes."""
    ny, nx = z.shape
    nothing = (z, np.zeros(z.shape, bool), sigma)
    if ny < 3:
        return nothing
    finite = np.isfinite(z)
    if sigma is None:
        both = finite[1:] & finite[:-1]
        vdiff = (z[1:] - z[:-1])[both]
        if vdiff.size == 0:
            return nothing
        zv = z[finite]
        span = float(np.percentile(zv, 99) - np.percentile(zv, 1))
        sigma = _MAD_TO_SIGMA * float(np.median(np.abs(vdiff - np.median(vdiff))))
        sigma = max(sigma, 1e-9 * span, 1e-300)
    # score: how far (in sigma) the band of k <= width rows containing a pixel lies entirely
    # above (or entirely below) both rows bracketing it
    zz = np.where(finite, z, np.nan)
    score = np.zeros(z.shape)
    with np.errstate(invalid="ignore"):
        for k in range(1, min(width, ny - 2) + 1):
            n_band = ny - k - 1  # band rows i..i+k-1 for i = 1..ny-k-1
            bmin = zz[1 : 1 + n_band].copy()
            bmax = bmin.copy()
            for m in range(1, k):
                bmin = np.minimum(bmin, zz[1 + m : 1 + m + n_band])
                bmax = np.maximum(bmax, zz[1 + m : 1 + m + n_band])
            za = zz[0:n_band]
            zb = zz[1 + k : 1 + k + n_band]
            excess = np.maximum(bmin - np.maximum(za, zb), np.minimum(za, zb) - bmax) / sigma
            excess = np.nan_to_num(excess, nan=0.0)
            for m in range(k):
                rows = slice(1 + m, 1 + m + n_band)
                np.maximum(score[rows], excess, out=score[rows])
    eligible = valid  # never mark masked or NaN pixels
    high = (score >= thr) & eligible
    low = (score >= thr_low) & eligible
    # pixels whose score is unknown (NaN themselves, or next to a NaN row pixel) may link the
    # parts of a streak when they form short gaps; gaps of one or two pixels are bridged too
    # (a streak that crosses the level of its neighbours)
    unknown = ~finite
    unknown[1:-1] |= ~finite[:-2] | ~finite[2:]
    link = low | (unknown & (_run_length_x(unknown) <= _SCAR_GAP))
    link |= ndimage.binary_closing(link, structure=np.ones((1, _SCAR_GAP + 1), bool))
    row = np.zeros((3, 3), bool)
    row[1, :] = True
    labels, n = ndimage.label(link, structure=row)
    if n == 0:
        return nothing
    idx = np.arange(1, n + 1)
    lengths = ndimage.sum_labels(np.ones(z.shape), labels, idx)
    seeded = ndimage.maximum(high.astype(np.float64), labels, idx) > 0
    keep = np.concatenate([[False], (lengths >= min_len) & seeded])
    marked = keep[labels] & eligible
    if not marked.any():
        return nothing
    good = finite & ~marked
    iy = np.arange(ny)[:, None]
    above = np.maximum.accumulate(np.where(good, iy, -1), axis=0)
    below = np.minimum.accumulate(np.where(good, iy, ny)[::-1], axis=0)[::-1]
    cols = np.broadcast_to(np.arange(nx), z.shape)
    has_a = above >= 0
    has_b = below < ny
    za = z[np.clip(above, 0, ny - 1), cols]
    zb = z[np.clip(below, 0, ny - 1), cols]
    t = np.where(has_a & has_b, (iy - above) / np.maximum(below - above, 1), 0.0)
    fill = np.where(has_a & has_b, za + t * (zb - za), np.where(has_a, za, zb))
    ok = marked & (has_a | has_b)
    return np.where(ok, fill, z), ok, sigma


def _run_length_x(m: np.ndarray) -> np.ndarray:
    """For each True pixel, the length of its run of True along x (0 elsewhere)."""
    row = np.zeros((3, 3), bool)
    row[1, :] = True
    labels, n = ndimage.label(m, structure=row)
    if n == 0:
        return np.zeros(m.shape, np.int64)
    sizes = np.concatenate([[0], ndimage.sum_labels(np.ones(m.shape), labels, np.arange(1, n + 1))])
    return sizes[labels].astype(np.int64)
