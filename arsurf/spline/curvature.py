r"""A height net's curvature as a field twice continuously differentiable across the knot lines.

A bicubic spline's second derivatives are only continuous: their slopes (the third derivatives)
step where a point crosses a knot line. A quantity read from the curvature at a moving point - the
one-term contact energy's :math:`\det M` (:mod:`arsurf.contact.zone_quadric`) - then has a kink
there, and its gradient (a force) a step. This module gives the curvature a field of its own, the
variation-diminishing spline of each second derivative (Schoenberg's approximation: the control
value at :math:`(i, j)` is the derivative at the Greville abscissae :math:`(\xi_i, \eta_j)`; de
Boor, *A Practical Guide to Splines*, ch. XI) on knots :data:`REFINEMENT` times as dense as the
net's, C2 like the surface itself. It reproduces linear functions, so it is exact where the surface
is a cubic polynomial; elsewhere it is the curvature averaged over about a knot interval of the
net (:math:`O(h^2)` of the fourth derivative off the spline's own, h the field's spacing).

Beside it, a field as smooth of how fast the curvature can change nearby: at every point at least
the size of the height's third derivative anywhere within a given reach (a bound, from the net's
third differences), so that a check of the surface's Taylor remainder over a region about a moving
point varies smoothly with that point.

Kernels take the net ``(mu, mv, 4)`` of :func:`curvature_net` with its own knots, x along u and y
along v (a fitted scan's net), on the same domain as the surface's.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.lib.stride_tricks import sliding_window_view
from scipy.ndimage import maximum_filter

from arsurf.spline.basis import basis_at, surface_points_serial
from arsurf.spline.knots import clamped_uniform_knots, greville

__all__ = ["MAX_FIELD_POINTS", "REFINEMENT", "curvature_jet", "curvature_net"]

#: the field's knots are this many times as dense as the net's: the curvature averaged over about a knot interval
#: rather than three (measured against the zone energy's lattice, ``bench/zone_quadric.py --families`` and the real
#: scans' slides: docs/feel-log.rst, "The closed form that loses no run")
REFINEMENT = 2
#: but not beyond this many control points (32 bytes each: 128 MB), once as dense then
MAX_FIELD_POINTS = 1 << 22
#: the field's control values are evaluated this many at a time (the evaluation's rows: 9 MB)
CHUNK = 1 << 16


def curvature_net(ctrl: np.ndarray, ku: np.ndarray, kv: np.ndarray,
                  reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(net, knots_u, knots_v)``: four C2 fields over the height-field net (``ctrl``, ``ku``,
    ``kv``; x affine in u, y in v), on clamped uniform knots :data:`REFINEMENT` times as dense over
    the same domain (once as dense where that would pass :data:`MAX_FIELD_POINTS`), evaluated by
    :func:`curvature_jet`; ``net`` ``(mu, mv, 4)`` float64, C-ordered:

    - the height's second derivatives :math:`z_{xx}, z_{xy}, z_{yy}` (1/m) at each control point's
      Greville abscissae (module docstring);
    - a bound of the third derivative's size (1/m^2) over ``reach`` (m) about any point of the
      control point's support (:func:`_third_derivative_bound`): the field, a convex combination of
      these values, is at every point at least the size of the third derivative anywhere within
      ``reach`` of it."""
    nu, nv = ctrl.shape[:2]
    refine = REFINEMENT if ((nu - 3) * REFINEMENT + 3) * ((nv - 3) * REFINEMENT + 3) <= MAX_FIELD_POINTS else 1
    fu = clamped_uniform_knots((nu - 3) * refine + 3, ku[3], ku[nu])
    fv = clamped_uniform_knots((nv - 3) * refine + 3, kv[3], kv[nv])
    gu, gv = greville(fu), greville(fv)
    net = np.empty((gu.size, gv.size, 4))
    flat = net.reshape(-1, 4)
    points = np.ascontiguousarray(ctrl, dtype=np.float64)
    rows = np.empty((6, min(CHUNK, flat.shape[0]), 3))  # evaluated a chunk at a time: 144 bytes a point
    for k0 in range(0, flat.shape[0], CHUNK):
        k = np.arange(k0, min(k0 + CHUNK, flat.shape[0]))
        r = rows[:, :k.size]
        surface_points_serial(points, ku, kv, gu[k // gv.size], gv[k % gv.size], 2, r)
        xu, yv = r[1, :, 0], r[2, :, 1]
        flat[k0:k0 + k.size, 0] = r[3, :, 2] / (xu * xu)
        flat[k0:k0 + k.size, 1] = r[4, :, 2] / (xu * yv)
        flat[k0:k0 + k.size, 2] = r[5, :, 2] / (yv * yv)
    net[:, :, 3] = _third_derivative_bound(ctrl, ku, kv, reach, refine)
    return net, fu, fv


def _derivative_coefficients(c: np.ndarray, t: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """The coefficients and knots of a B-spline's derivative along ``axis``: :math:`Q_i = p (P_{i+1} -
    P_i)/(t_{i+p+1} - t_{i+1})`, degree p - 1 on the knots without their ends (Piegl & Tiller, eq. 3.4)."""
    n = c.shape[axis]
    p = t.size - n - 1
    shape = [1, 1]
    shape[axis] = n - 1
    return p * np.diff(c, axis=axis) / (t[p + 1:p + n] - t[1:n]).reshape(shape), t[1:-1]


def _span_max(c: np.ndarray, t: np.ndarray, axis: int) -> np.ndarray:
    """Largest |coefficient| alive on each knot span along ``axis`` (those i..i+p of span i)."""
    p = t.size - c.shape[axis] - 1
    return sliding_window_view(np.abs(c), p + 1, axis=axis).max(axis=-1)


def _third_derivative_bound(ctrl: np.ndarray, ku: np.ndarray, kv: np.ndarray, reach: float,
                            refine: int) -> np.ndarray:
    r"""For each control point of the field's net (``refine`` spans to each of the net's), a bound (1/m^2) of
    the height's third derivative
    :math:`|D^3 z|` (its Frobenius norm, :math:`\sqrt{z_{xxx}^2 + 3z_{xxy}^2 + 3z_{xyy}^2 +
    z_{yyy}^2}`, which bounds :math:`|D^3z[e,e,e]|` along any unit e) within ``reach`` (m) of its
    support. Each third derivative is a B-spline of lower degree whose coefficients are the net's
    differences (:func:`_derivative_coefficients`), a convex combination of those alive on a span:
    their largest size bounds it there; then the largest over the spans within ``reach`` (a square
    about each span), then over the 4 x 4 spans of the field each of its basis functions covers."""
    z = np.asarray(ctrl[:, :, 2], dtype=np.float64)
    nu, nv = z.shape
    xu = (ctrl[-1, 0, 0] - ctrl[0, 0, 0]) / (ku[nu] - ku[3])
    yv = (ctrl[0, -1, 1] - ctrl[0, 0, 1]) / (kv[nv] - kv[3])
    parts = []
    for along_u in range(4):
        c, tu, tv = z, ku, kv
        for _ in range(along_u):
            c, tu = _derivative_coefficients(c, tu, 0)
        for _ in range(3 - along_u):
            c, tv = _derivative_coefficients(c, tv, 1)
        parts.append(_span_max(_span_max(c, tu, 0), tv, 1) / (xu ** along_u * yv ** (3 - along_u)))
    a, b, c, d = parts  # z_yyy, z_xyy, z_xxy, z_xxx on each span, at most
    size = np.sqrt(a * a + 3.0 * b * b + 3.0 * c * c + d * d)
    ru = int(math.ceil(reach / (xu * (ku[nu] - ku[3]) / (nu - 3))))
    rv = int(math.ceil(reach / (yv * (kv[nv] - kv[3]) / (nv - 3))))
    near = maximum_filter(size, size=(2 * ru + 1, 2 * rv + 1), mode="nearest")
    near = np.repeat(np.repeat(near, refine, axis=0), refine, axis=1)  # the field's spans
    padded = np.pad(near, 3, mode="edge")  # the field's control point i covers its spans i-3..i
    return sliding_window_view(padded, (4, 4)).max(axis=(-2, -1))


@njit(cache=True)
def curvature_jet(net, ku, kv, u, v, xu, yv):
    r"""The four fields of :func:`curvature_net` and their slopes at (u, v) (clamped), x_u and y_v
    the net's (m per parameter unit): ``(h_xx, h_xy, h_yy, b, d/dx of the four, d/dy of the
    four)``, h the curvature (1/m) and b the third derivative's bound (1/m^2), slopes per m.
    One pass over the 4x4 patch; allocates nothing."""
    iu, bu = basis_at(ku, u)
    iv, bv = basis_at(kv, v)
    a = b = c = d = au = bu_ = cu = du = av = bv_ = cv = dv = 0.0
    for q in range(4):
        j = iv + q
        r0a = r0b = r0c = r0d = r1a = r1b = r1c = r1d = 0.0
        for p in range(4):
            n0, n1 = bu[p], bu[4 + p]
            ha, hb, hc, hd = net[iu + p, j, 0], net[iu + p, j, 1], net[iu + p, j, 2], net[iu + p, j, 3]
            r0a += n0 * ha
            r0b += n0 * hb
            r0c += n0 * hc
            r0d += n0 * hd
            r1a += n1 * ha
            r1b += n1 * hb
            r1c += n1 * hc
            r1d += n1 * hd
        m0, m1 = bv[q], bv[4 + q]
        a += m0 * r0a
        b += m0 * r0b
        c += m0 * r0c
        d += m0 * r0d
        au += m0 * r1a
        bu_ += m0 * r1b
        cu += m0 * r1c
        du += m0 * r1d
        av += m1 * r0a
        bv_ += m1 * r0b
        cv += m1 * r0c
        dv += m1 * r0d
    return a, b, c, d, au / xu, bu_ / xu, cu / xu, du / xu, av / yv, bv_ / yv, cv / yv, dv / yv
