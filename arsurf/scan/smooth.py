"""Gaussian low-pass filtering of a height map before the B-spline fit ([SplineAR]).

The width is given in metres and converted per axis, so non-square pixels are filtered
isotropically in physical space. Missing pixels (NaN) are handled by normalised convolution
(Knutsson & Westin 1993): the data and the validity mask are filtered with the same kernel and
divided, so a hole neither spreads NaN nor pulls its neighbours towards zero.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

from arsurf.errors import SigmaTooWide, SmoothingError
from arsurf.scan.scan import Scan

__all__ = ["smooth", "SmoothingError"]


# Kernel half-width in standard deviations (scipy.ndimage's default): the truncated tail holds
# erfc(4/sqrt(2)) = 6.3e-5 of the weight per axis, and the kernel is renormalised to unit sum.
_TRUNCATE = 4.0
# Normalised convolution: a pixel is filled (fill_holes=True) only if the valid pixels around
# it carry at least this fraction of the kernel weight; below it the estimate is extrapolation.
_MIN_WEIGHT = 1e-3


def smooth(
    scan: Scan,
    sigma: float | tuple[float, float],
    *,
    truncate: float = _TRUNCATE,
    fill_holes: bool = False,
) -> Scan:
    r"""Gaussian low-pass filter with a width in metres, NaN-aware, edges by reflection.

    .. math::

        \tilde z(x, y) = \frac{(g * (v\,z))(x, y)}{(g * v)(x, y)}, \qquad
        g(x, y) \propto \exp\!\left(-\frac{x^2}{2\sigma_x^2} - \frac{y^2}{2\sigma_y^2}\right),

    where :math:`v` is 1 on valid pixels and 0 on NaN, and :math:`g` is sampled with widths
    :math:`\sigma_x/dx` and :math:`\sigma_y/dy` pixels, truncated at ``truncate`` widths and
    normalised. Without NaN, :math:`g * v = 1` and this is a plain Gaussian filter: a sinusoid
    of wavelength :math:`L` is multiplied by :math:`\exp(-2\pi^2\sigma^2/L^2)` and the sum of the
    heights is conserved (symmetric reflection at the borders, scipy mode ``"reflect"``).

    Parameters
    ----------
    scan : Scan
        Height map, metres; NaN pixels are missing data.
    sigma : float or (float, float), metres
        Standard deviation of the Gaussian, the same in x and y, or ``(sigma_x, sigma_y)``.
        Must be positive and at most as many pixels as the scan's longer side (a width meant in
        nanometres or pixels but passed as metres is caught here). Along an axis of one pixel
        there is nothing to smooth.
    truncate : float
        Kernel half-width in standard deviations (default 4).
    fill_holes : bool
        False (default): NaN pixels stay NaN. True: they get the normalised-convolution
        estimate where the valid pixels carry at least 0.1 % of the kernel weight.

    Returns
    -------
    Scan
        New scan; ``metadata["history"]`` gains ``{"operation": "smooth", "method": "gaussian",
        "sigma_x", "sigma_y" (m), "sigma_px" ([x, y] pixels), "truncate", "edges": "reflect"}``.

    Raises
    ------
    SmoothingError
        ``sigma`` not positive, not finite, of the wrong length, or wider than the scan;
        ``truncate`` not positive.

    Notes
    -----
    [SplineAR] smooths the scan "with a Gaussian low-pass filter to remove noise" before fitting
    the bicubic B-spline; the width is not given there: choose it from the noise scale, a few
    pixels.

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.scan.scan import Scan
    >>> x = np.arange(64) * 1e-9
    >>> s = Scan(np.tile(np.cos(2 * np.pi * (x + 0.5e-9) / 16e-9), (8, 1)) * 1e-9, dx=1e-9, dy=1e-9)
    >>> out = smooth(s, 2e-9)
    >>> ratio = out.heights.max() / s.heights.max()
    >>> bool(abs(ratio - np.exp(-2 * np.pi**2 * 2.0**2 / 16.0**2)) < 1e-3)
    True
    """
    if not isinstance(scan, Scan):
        raise SmoothingError(
            f"smooth() needs an arsurf Scan (got {type(scan).__name__}); "
            "wrap a height array as Scan(heights, dx=..., dy=...)"
        )
    sx, sy = _check_sigma(sigma)
    t = _finite_float(truncate)
    if not (t is not None and t > 0.0):
        raise SmoothingError(
            f"`truncate` must be positive (got {truncate!r}); it is the kernel half-width in sigmas"
        )
    ny, nx = scan.shape
    px = sx / scan.dx if nx > 1 else 0.0
    py = sy / scan.dy if ny > 1 else 0.0
    widest = max(nx, ny)
    for name, value, width, spacing in (("x", px, sx, scan.dx), ("y", py, sy, scan.dy)):
        if value > widest:
            raise SigmaTooWide(
                f"`sigma` along {name} is {width:g} m = {value:.4g} pixels, wider than the scan "
                f"({widest} pixels); sigma is in metres (e.g. 2e-9 for 2 nm)",
                axis=name, sigma=width, spacing=spacing, pixels=value, widest=widest,
            )
    z = scan.heights
    valid = np.isfinite(z)
    filt = dict(sigma=(py, px), mode="reflect", truncate=t)
    if valid.all():
        out = ndimage.gaussian_filter(z, **filt)
    elif not valid.any():
        out = z.copy()
    else:
        num = ndimage.gaussian_filter(np.where(valid, z, 0.0), **filt)
        den = ndimage.gaussian_filter(valid.astype(np.float64), **filt)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = num / den
        keep = valid | (fill_holes & (den >= _MIN_WEIGHT))
        out = np.where(keep, out, np.nan)
    step: dict[str, Any] = {
        "operation": "smooth",
        "method": "gaussian",
        "sigma_x": sx,
        "sigma_y": sy,
        "sigma_px": [px, py],
        "truncate": t,
        "edges": "reflect",
        "fill_holes": bool(fill_holes),
    }
    return scan.with_heights(out, step=step)


def _finite_float(value) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _check_sigma(sigma) -> tuple[float, float]:
    if isinstance(sigma, (str, bytes)):
        raise SmoothingError(f"`sigma` must be a number or a pair of numbers in metres (got {sigma!r})")
    values = np.ravel(np.asarray(sigma, dtype=object))
    if values.size == 1:
        values = np.array([values[0], values[0]], dtype=object)
    if values.size != 2:
        raise SmoothingError(
            f"`sigma` must be one width or a pair (sigma_x, sigma_y) in metres (got {values.size} values: "
            f"{sigma!r})"
        )
    out = []
    for v in values:
        f = _finite_float(v)
        if f is None or f <= 0.0:
            shown = str(v) if isinstance(v, (int, float, np.number)) else repr(v)
            raise SmoothingError(
                f"`sigma` must be positive (got {shown} m); it is the Gaussian width in metres"
            )
        out.append(f)
    return out[0], out[1]
