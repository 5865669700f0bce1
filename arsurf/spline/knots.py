"""Clamped uniform cubic knot vectors and Greville abscissae.

A clamped cubic knot vector on [a, b] with n control points has n - 3 equal spans of width
h = (b - a)/(n - 3) and the end knots repeated four times:

.. math:: t = (a, a, a, a, a + h, \\dots, b - h, b, b, b, b), \\qquad \\text{len}(t) = n + 4.

Uniform spans make the span lookup O(1) (:func:`arsurf.spline.basis.find_span`). Control points
placed on the Greville abscissae :math:`\\xi_i = (t_{i+1} + t_{i+2} + t_{i+3})/3` reproduce the
identity, :math:`\\sum_i \\xi_i N_i(u) = u` (linear precision), which is why x(u) = u on the
undeformed surface (Piegl & Tiller, *The NURBS Book*, 2nd ed., §2.2; de Boor 1978, ch. IX).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from arsurf.errors import SurfaceError

DEGREE = 3


def clamped_uniform_knots(n: int, a: float, b: float) -> np.ndarray:
    """Clamped uniform cubic knot vector with ``n`` control points on ``[a, b]``.

    Parameters
    ----------
    n : int
        Number of control points along the axis (>= 4).
    a, b : float
        Parameter domain, metres (a < b).

    Returns
    -------
    (n + 4,) float64

    Examples
    --------
    >>> clamped_uniform_knots(5, 0.0, 2.0)
    array([0., 0., 0., 0., 1., 2., 2., 2., 2.])
    """
    n = int(n)
    if n < DEGREE + 1:
        raise SurfaceError(
            f"a cubic B-spline needs at least 4 control points per axis (got {n}); "
            "use a scan with at least 4 pixels along each axis"
        )
    if not (np.isfinite(a) and np.isfinite(b) and b > a):
        raise SurfaceError(f"the knot domain must satisfy a < b, both finite (got a={a!r}, b={b!r})")
    interior = np.linspace(a, b, n - DEGREE + 1)
    return np.concatenate([np.full(DEGREE, a), interior, np.full(DEGREE, b)]).astype(np.float64)


@njit(cache=True)
def greville_at(knots, i):
    """The Greville abscissa of control point ``i`` of a cubic knot vector (:func:`greville`), for
    kernels."""
    return (knots[i + 1] + knots[i + 2] + knots[i + 3]) / 3.0


def greville(knots: np.ndarray) -> np.ndarray:
    """Greville abscissae :math:`\\xi_i = (t_{i+1} + t_{i+2} + t_{i+3})/3` of a cubic knot vector.

    Examples
    --------
    >>> greville(clamped_uniform_knots(4, 0.0, 3.0))
    array([0., 1., 2., 3.])
    """
    t = np.asarray(knots, dtype=np.float64)
    return (t[1:-3] + t[2:-2] + t[3:-1]) / 3.0


def check_clamped_uniform(knots: np.ndarray, name: str) -> np.ndarray:
    """Validate a clamped uniform cubic knot vector; return it as a float64 C array."""
    t = np.ascontiguousarray(knots, dtype=np.float64)
    if t.ndim != 1 or t.size < 2 * (DEGREE + 1):
        raise SurfaceError(f"{name} must be a 1-D knot vector of length >= 8 (got shape {t.shape})")
    expected = clamped_uniform_knots(t.size - DEGREE - 1, t[0], t[-1])
    if not np.allclose(t, expected, rtol=0.0, atol=1e-9 * (t[-1] - t[0])):
        raise SurfaceError(
            f"{name} is not a clamped uniform cubic knot vector on [{t[0]!r}, {t[-1]!r}]; "
            "build it with arsurf.spline.knots.clamped_uniform_knots"
        )
    return t
