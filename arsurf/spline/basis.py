"""Cubic B-spline basis on clamped uniform knots, and surface evaluation kernels (numba).

The basis is the Cox-de Boor triangle (Piegl & Tiller, *The NURBS Book*, A2.2) unrolled for
degree 3 with scalar temporaries, so a kernel call allocates nothing. Derivatives follow

.. math:: N'_{k,p} = p\\Big(\\frac{N_{k,p-1}}{t_{k+p}-t_k} - \\frac{N_{k+1,p-1}}{t_{k+p+1}-t_{k+1}}\\Big)

applied once (first) and twice (second). A surface point is the 4x4 tensor contraction

.. math:: S(u, v) = \\sum_{a=0}^{3}\\sum_{b=0}^{3} N_{i-3+a}(u)\\,N_{j-3+b}(v)\\,P_{i-3+a,\\,j-3+b}.

Kernels take plain float64 arrays: ``ctrl`` (nu, nv, 3), ``ku`` (nu + 4,), ``kv`` (nv + 4,).
Parameters outside the domain are clamped to it.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from arsurf._layout import Layout

#: rows of the derivative block (rows, 3) written by the kernels: S and its derivatives to second order
DERIVATIVE_ROWS = Layout("surface derivative rows", [("S", 1), ("S_u", 1), ("S_v", 1), ("S_uu", 1), ("S_uv", 1),
                                                     ("S_vv", 1)])
S, SU, SV, SUU, SUV, SVV = (DERIVATIVE_ROWS.offset(f) for f in DERIVATIVE_ROWS.fields)
N_ROWS = DERIVATIVE_ROWS.size


@njit(cache=True, inline="always")
def find_span(knots, u):
    """Knot span index i with t[i] <= u < t[i+1] (O(1) on uniform knots); u clamped to the domain."""
    n = knots.size - 4  # control points
    a = knots[3]
    b = knots[n]
    m = n - 3  # spans
    k = int((u - a) / (b - a) * m) if b > a else 0
    if k < 0:
        k = 0
    elif k > m - 1:
        k = m - 1
    return k + 3


@njit(cache=True, inline="always")
def clamp(u, knots):
    n = knots.size - 4
    if u < knots[3]:
        return knots[3]
    if u > knots[n]:
        return knots[n]
    return u


@njit(cache=True, inline="always")
def locate(knots, u):
    """(span i, local coordinate s in [0, 1], 1/h, clamped u) in one division-free step per call
    (one division for 1/h)."""
    n = knots.size - 4
    a = knots[3]
    b = knots[n]
    m = n - 3
    inv_h = m / (b - a)
    if u < a:
        u = a
    elif u > b:
        u = b
    x = (u - a) * inv_h
    k = int(x)
    if k > m - 1:
        k = m - 1
    return k + 3, x - k, inv_h, u


@njit(cache=True, inline="always")
def uniform_basis(s, ih):
    """The 12-tuple of :func:`cubic_basis` on an interior span, from s = (u - t_i)/h and 1/h."""
    s2 = s * s
    s3 = s2 * s
    r = 1.0 - s
    sixth = 1.0 / 6.0
    ih2 = ih * ih
    return (r * r * r * sixth,
            (3.0 * s3 - 6.0 * s2 + 4.0) * sixth,
            (-3.0 * s3 + 3.0 * s2 + 3.0 * s + 1.0) * sixth,
            s3 * sixth,
            -0.5 * r * r * ih,
            (1.5 * s2 - 2.0 * s) * ih,
            (-1.5 * s2 + s + 0.5) * ih,
            0.5 * s2 * ih,
            r * ih2,
            (3.0 * s - 2.0) * ih2,
            (-3.0 * s + 1.0) * ih2,
            s * ih2)


@njit(cache=True, inline="always")
def basis_at(knots, u):
    """(first control index i - 3, 12-tuple of basis values and derivatives) at u (clamped)."""
    i, s, ih, u = locate(knots, u)
    n = knots.size - 4
    if 5 <= i <= n - 3:
        return i - 3, uniform_basis(s, ih)
    return i - 3, cubic_basis(knots, i, u)


@njit(cache=True)
def cubic_basis(knots, i, u):
    """Values, first and second derivatives of the 4 cubic basis functions nonzero on span i.

    Returns a 12-tuple (N0..N3, dN0..dN3, ddN0..ddN3) for N_{i-3} .. N_i at u.
    Interior spans (all six knots involved equally spaced) use the uniform closed form in
    t = (u - t_i)/h: N = ((1-t)^3, 3t^3 - 6t^2 + 4, -3t^3 + 3t^2 + 3t + 1, t^3)/6, which needs
    no division; the three spans at each clamped end use the general triangle.
    """
    t = knots
    n = knots.size - 4
    if 5 <= i <= n - 3:
        ih = 1.0 / (t[i + 1] - t[i])
        return uniform_basis((u - t[i]) * ih, ih)
    L1 = u - t[i]
    L2 = u - t[i - 1]
    L3 = u - t[i - 2]
    R1 = t[i + 1] - u
    R2 = t[i + 2] - u
    R3 = t[i + 3] - u
    # degree 1: N_{i-1,1}, N_{i,1}
    d = R1 + L1
    a0 = R1 / d
    a1 = L1 / d
    # degree 2: N_{i-2,2}, N_{i-1,2}, N_{i,2}
    d12 = R1 + L2
    d21 = R2 + L1
    tmp = a0 / d12
    b0 = R1 * tmp
    saved = L2 * tmp
    tmp = a1 / d21
    b1 = saved + R2 * tmp
    b2 = L1 * tmp
    # degree 3: N_{i-3,3} .. N_{i,3}
    d13 = R1 + L3
    d22 = R2 + L2
    d31 = R3 + L1
    tmp = b0 / d13
    c0 = R1 * tmp
    saved = L3 * tmp
    tmp = b1 / d22
    c1 = saved + R2 * tmp
    saved = L2 * tmp
    tmp = b2 / d31
    c2 = saved + R3 * tmp
    c3 = L1 * tmp
    # first derivatives from the degree-2 functions
    e0 = 3.0 * b0 / d13
    e1 = 3.0 * b1 / d22
    e2 = 3.0 * b2 / d31
    # second derivatives from the degree-1 functions
    f0 = 2.0 * a0 / d12
    f1 = 2.0 * a1 / d21
    g0 = -3.0 * f0 / d13
    g1 = 3.0 * (f0 - f1) / d22
    g2 = 3.0 * f1 / d31
    return (c0, c1, c2, c3,
            -e0, e0 - e1, e1 - e2, e2,
            -g0, g0 - g1, g1 - g2, g2)


@njit(cache=True, inline="always")
def third_derivatives(knots, i):
    """The third derivatives of the 4 cubic basis functions nonzero on span i, constant on it:
    :math:`(-1, 3, -3, 1)/h^3` on an interior span (from :func:`uniform_basis`), and on the
    clamped ends the change of the (linear) second derivatives across the span over its width."""
    n = knots.size - 4
    ih = 1.0 / (knots[i + 1] - knots[i])
    if 5 <= i <= n - 3:
        c = ih * ih * ih
        return -c, 3.0 * c, -3.0 * c, c
    a = cubic_basis(knots, i, knots[i])
    b = cubic_basis(knots, i, knots[i + 1])
    return (b[8] - a[8]) * ih, (b[9] - a[9]) * ih, (b[10] - a[10]) * ih, (b[11] - a[11]) * ih


@njit(cache=True)
def height_jet(ctrl, ku, kv, u, v):
    """A height-field net's point and height derivatives to third order at (u, v) (clamped):
    ``(x, y, x_u, y_v, z, z_u, z_v, z_uu, z_uv, z_vv, z_uuu, z_uuv, z_uvv, z_vvv)``, x depending
    on u only and y on v only (a fitted scan's net), so the height's derivatives in x and y are
    these over powers of x_u and y_v. One pass over the 4x4 patch; allocates nothing."""
    iu, bu = basis_at(ku, u)
    iv, bv = basis_at(kv, v)
    tu = third_derivatives(ku, iu + 3)
    tv = third_derivatives(kv, iv + 3)
    x = y = xu = yv = 0.0
    z = zu = zv = zuu = zuv = zvv = zuuu = zuuv = zuvv = zvvv = 0.0
    for b in range(4):
        j = iv + b
        r0 = r1 = r2 = r3 = rx = rxu = ry = 0.0  # z contracted along u to each order; x, x_u and y
        for a in range(4):
            pz = ctrl[iu + a, j, 2]
            r0 += bu[a] * pz
            r1 += bu[4 + a] * pz
            r2 += bu[8 + a] * pz
            r3 += tu[a] * pz
            rx += bu[a] * ctrl[iu + a, j, 0]
            rxu += bu[4 + a] * ctrl[iu + a, j, 0]
            ry += bu[a] * ctrl[iu + a, j, 1]
        m0, m1, m2, m3 = bv[b], bv[4 + b], bv[8 + b], tv[b]
        x += m0 * rx
        xu += m0 * rxu
        y += m0 * ry
        yv += m1 * ry
        z += m0 * r0
        zu += m0 * r1
        zv += m1 * r0
        zuu += m0 * r2
        zuv += m1 * r1
        zvv += m2 * r0
        zuuu += m0 * r3
        zuuv += m1 * r2
        zuvv += m2 * r1
        zvvv += m3 * r0
    return x, y, xu, yv, z, zu, zv, zuu, zuv, zvv, zuuu, zuuv, zuvv, zvvv


@njit(cache=True)
def height_slope(ctrl, ku, kv, u, v):
    """A height-field net's height and its parameter derivatives at (u, v) (clamped): ``(z, z_u,
    z_v)``, the first three of :func:`height_jet`'s height terms at a quarter of its work. One pass
    over the 4x4 patch; allocates nothing."""
    iu, bu = basis_at(ku, u)
    iv, bv = basis_at(kv, v)
    z = zu = zv = 0.0
    for b in range(4):
        j = iv + b
        r0 = r1 = 0.0
        for a in range(4):
            pz = ctrl[iu + a, j, 2]
            r0 += bu[a] * pz
            r1 += bu[4 + a] * pz
        z += bv[b] * r0
        zu += bv[b] * r1
        zv += bv[4 + b] * r0
    return z, zu, zv


@njit(cache=True)
def basis_row(knots, u, out):
    """Write the 4 basis values at u into ``out`` and return the first column index (span - 3)."""
    u = clamp(u, knots)
    i = find_span(knots, u)
    r = cubic_basis(knots, i, u)
    out[0] = r[0]
    out[1] = r[1]
    out[2] = r[2]
    out[3] = r[3]
    return i - 3


@njit(cache=True)
def surface_point(ctrl, ku, kv, u, v, order, out):
    """Evaluate S and its derivatives up to ``order`` (0, 1, 2) at (u, v) into ``out`` (>= rows, 3).

    Rows of ``out``: S, S_u, S_v, S_uu, S_uv, S_vv (rows beyond ``order`` are left untouched).
    Accumulates in scalars (no aliasing through ``out``), one pass over the 4x4 patch.
    """
    iu, bu = basis_at(ku, u)
    iv, bv = basis_at(kv, v)
    x0 = y0 = z0 = 0.0
    xu = yu = zu = xv = yv = zv = 0.0
    xuu = yuu = zuu = xuv = yuv = zuv = xvv = yvv = zvv = 0.0
    for b in range(4):
        j = iv + b
        # contract along u first: row sums with the u-basis, per derivative order
        r0x = r0y = r0z = r1x = r1y = r1z = r2x = r2y = r2z = 0.0
        for a in range(4):
            i = iu + a
            px = ctrl[i, j, 0]
            py = ctrl[i, j, 1]
            pz = ctrl[i, j, 2]
            n0 = bu[a]
            r0x += n0 * px
            r0y += n0 * py
            r0z += n0 * pz
            if order >= 1:
                n1 = bu[4 + a]
                r1x += n1 * px
                r1y += n1 * py
                r1z += n1 * pz
                if order >= 2:
                    n2 = bu[8 + a]
                    r2x += n2 * px
                    r2y += n2 * py
                    r2z += n2 * pz
        m0 = bv[b]
        x0 += m0 * r0x
        y0 += m0 * r0y
        z0 += m0 * r0z
        if order >= 1:
            m1 = bv[4 + b]
            xu += m0 * r1x
            yu += m0 * r1y
            zu += m0 * r1z
            xv += m1 * r0x
            yv += m1 * r0y
            zv += m1 * r0z
            if order >= 2:
                m2 = bv[8 + b]
                xuu += m0 * r2x
                yuu += m0 * r2y
                zuu += m0 * r2z
                xuv += m1 * r1x
                yuv += m1 * r1y
                zuv += m1 * r1z
                xvv += m2 * r0x
                yvv += m2 * r0y
                zvv += m2 * r0z
    out[0, 0] = x0
    out[0, 1] = y0
    out[0, 2] = z0
    if order >= 1:
        out[1, 0] = xu
        out[1, 1] = yu
        out[1, 2] = zu
        out[2, 0] = xv
        out[2, 1] = yv
        out[2, 2] = zv
        if order >= 2:
            out[3, 0] = xuu
            out[3, 1] = yuu
            out[3, 2] = zuu
            out[4, 0] = xuv
            out[4, 1] = yuv
            out[4, 2] = zuv
            out[5, 0] = xvv
            out[5, 1] = yvv
            out[5, 2] = zvv


#: batches smaller than this are evaluated in the calling thread: waking the thread pool costs
#: more than a few thousand points (and, on a loaded machine, milliseconds)
PARALLEL_MIN = 4096


@njit(cache=True)
def _points_range(ctrl, ku, kv, us, vs, order, out, k0, k1, scratch):
    """:func:`surface_point` for points k0..k1-1 of a batch into ``out``."""
    nrow = out.shape[0]
    for k in range(k0, k1):
        surface_point(ctrl, ku, kv, us[k], vs[k], order, scratch)
        for r in range(nrow):
            for c in range(3):
                out[r, k, c] = scratch[r, c]


@njit(cache=True, parallel=True)
def surface_points(ctrl, ku, kv, us, vs, order, out):
    """Batch of :func:`surface_point`: ``out`` (1, 3 or 6 rows, n, 3) for ``us``, ``vs`` (n,).

    Chunks of 256 points run in parallel threads (batches serve the viewer and replay, not the
    haptic tick, which calls :func:`surface_point`); :func:`surface_points_serial` for small ones."""
    n = us.size
    chunk = 256
    for b in prange((n + chunk - 1) // chunk):
        _points_range(ctrl, ku, kv, us, vs, order, out, b * chunk, min(n, (b + 1) * chunk),
                      np.empty((N_ROWS, 3)))


@njit(cache=True)
def surface_points_serial(ctrl, ku, kv, us, vs, order, out):
    """:func:`surface_points` in the calling thread (batches below :data:`PARALLEL_MIN`)."""
    _points_range(ctrl, ku, kv, us, vs, order, out, 0, us.size, np.empty((N_ROWS, 3)))


@njit(cache=True)
def collocation(knots, x, cols, vals):
    """Basis rows at sites ``x``: ``vals[k, :]`` are N_{cols[k]..cols[k]+3}(x[k])."""
    for k in range(x.size):
        cols[k] = basis_row(knots, x[k], vals[k])


def basis_matrix_rows(knots: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First column and the 4 nonzero basis values of each row of the collocation matrix."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    cols = np.empty(x.size, dtype=np.int64)
    vals = np.empty((x.size, 4), dtype=np.float64)
    collocation(knots, x, cols, vals)
    return cols, vals
