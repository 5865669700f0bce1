r"""The global closest point of a B-spline surface to the tip centre: the search kernels.

The tip is a sphere (centre C, radius R). The closest surface point minimises

.. math:: D(u, v) = \tfrac12\,|S(u, v) - C|^2, \qquad r = S - C,

.. math:: g = \begin{pmatrix} S_u\cdot r \\ S_v\cdot r \end{pmatrix}, \qquad
          H = \begin{pmatrix} S_u\cdot S_u + S_{uu}\cdot r & S_u\cdot S_v + S_{uv}\cdot r \\
                              S_u\cdot S_v + S_{uv}\cdot r & S_v\cdot S_v + S_{vv}\cdot r \end{pmatrix}

(docs/design.rst, "Closest point (Newton)"; [SplineAR]). At the minimum :math:`r \parallel n`, the
signed distance is :math:`d = (C - S)\cdot n` with the unit normal
:math:`n = S_u \times S_v / |S_u \times S_v|` (out of the sample: +z on a height field) and the
indentation depth is :math:`\delta = R - d` (> 0: the sphere penetrates).

Global, not local. Newton finds *a* local minimum; the global one is found by bounds and
certificates:

1. Newton from the hint (last tick's (u, v)) or, cold, from the foot of C on the mid-plane of
   the cell below it gives a surface point, hence an upper bound :math:`d^*` of the distance.
2. The oriented hull-box pyramid of :mod:`arsurf.contact.hull_tree` is walked nearest-first; a
   box farther than :math:`d^*` cannot hold a closer point and is pruned with its subtree. A
   hint only tightens the first bound, so warm starting never hides a closer basin.
3. A knot cell that survives is *certified convex* for this C when the Hessian of D is
   positive definite on all of it: :math:`\lambda_{min}(H) \ge \sigma_{min}(J)^2 +
   \lambda_{min}(\sum_c r_c \nabla^2 S_c) > 0`, bounded from the Bézier nets of the
   derivatives (Weyl, Gershgorin), either through the cell's convexity radius or through the
   signed curvature along its box normal (far above a cap D stays convex however far C is).
   D convex on a cell: one Newton run restricted to the cell finds its minimum, and the cell is
   skipped outright when it and the best point's cell span a certified rectangle (the best
   point, a local minimum there, is that rectangle's minimum). Not certified (C farther than
   the curvature radius, e.g. over a trench or a valley): the cell's Bézier patch is split into
   quarters (de Casteljau) down to 3 levels, each quarter pruned by its own box and
   certificate, Newton in the survivors.
4. Every cell minimum that beats :math:`d^*` is polished by an unrestricted Newton run and
   becomes the best.

Safeguards of every Newton run: Newton step when H is positive definite, else the
Gauss-Newton step :math:`-(J^TJ)^{-1} g` (always a descent direction), else a gradient step;
the step is capped (trust length :math:`2(|r| + h)`), projected onto the parameter box (active
set: a bound variable with an outward gradient is frozen) and backtracked until the Armijo
condition :math:`D_{new} \le D + 10^{-4}\, g\cdot\Delta` holds; iterations and halvings are
bounded, so no loop can run forever. The answer carries a status code.

Warm start. A warm query also keeps in its work array the list of cells within
:math:`d^* + h/2` of C (sorted by distance); later queries reuse it, without walking the
pyramid, while :math:`|C - C_0| + d^*(C) \le R_0` guarantees it still holds every candidate
(:func:`project_kernel`, Notes). A refresh of the pyramid (deformation) invalidates it.
The subdivided search also keeps, per Bézier piece it met, what does not depend on C (curvature
bounds, speed bounds, the surface at the piece's centre) in a small memo (:func:`_piece_memo`),
so the next queries near C read them back instead of recomputing: the same numbers, the same
answers bit for bit.

Cost (bench/collision.py). In contact, warm: one Newton run (2-3 iterations), a short list
scan and 1-2 certified cells, ~1 us in a kernel loop. Cold: the pyramid walk (~4 box tests per
level) plus 2-3 Newton iterations, 2-4 us. Far above the surface the admissible region is the
set of cells within d* of C: over smooth surfaces it stays a few cells (the boxes are thin and
the caps certified), over rough ones it grows with the height (more valley cells to subdivide):
on the 5 nm rms bench surface, median 2.5 / 4.5 / 8 / 13 us at 1 / 5 / 25 / 125 tip radii above
it, p99 up to ~0.1-0.2 ms. At worst it is bounded by the cells of the whole surface.

Kernels (numba, ``cache=True``) take plain arrays, allocate nothing and return status codes;
:func:`collide_kernel` is the entry point for the haptic-loop kernel. The Python functions
validate once and turn the status into exceptions or flags.

The Newton iteration is :mod:`arsurf.contact.newton`, the output and work-array layouts
:mod:`arsurf.contact.layout`, the Python API (validation, records, the per-surface projector)
:mod:`arsurf.contact.projection`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import overload

from arsurf._layout import Layout
from arsurf.contact.hull_tree import (
    HI_N, LO_N, LO_T, RHO, TREE_ID, VERSION, refresh_region_kernel, box_offsets, cell_certified, cell_net, curvature_radius,
    extents_bounds2, net_curvature, net_extents, net_split, node_bounds2, node_distance2, signed_convex,
)
from arsurf.contact.layout import (
    BEST_ROW, CACHE_BACKOFF, CACHE_CAP, CACHE_LIST, CACHE_MARGIN, CACHE_ROW, CACHE_SORT, MEMO_BASE, MEMO_ROWS, PIECE_MEMO,
    MAX_SUBDIVISION, NET_TMP, OUT_BOUNDARY, OUT_CACHED, OUT_CELLS, OUT_CONVERGED, OUT_DEPTH, OUT_DISTANCE, OUT_ITERATIONS,
    OUT_NX, OUT_NY, OUT_NZ,
    OUT_PX, OUT_PY, OUT_PZ, OUT_SIZE, OUT_STATUS, OUT_U, OUT_V, OUT_WARM_U, OUT_WARM_V, STACK_ROWS, SUB_BASE,
    SUB_CAP, SUB_ENTRY,
)
from arsurf.contact.newton import MAX_ITER_CELL, MAX_ITER_DOMAIN, STEP_TOL, _clip, newton_box
from arsurf.spline.basis import find_span, surface_point
from arsurf.status import BAD_INPUT, DEGENERATE, ITERATION_LIMIT, NON_FINITE, OK

# A box must beat the best squared distance by this factor to be searched: a cell that could
# only be closer by a relative 5e-13 (< 1e-20 m at nm distances) is not worth a Newton run, and
# exact ties (a flat or tilted plane, whose boxes touch the ball of radius d*) are pruned.
TIE = 1.0 - 1e-12


# --- global search ------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _keep(work):
    """Copy S, S_u, S_v of the last Newton answer (rows 0..2) to the best-point rows."""
    for r in range(3):
        for c in range(3):
            work[BEST_ROW + r, c] = work[r, c]


@njit(cache=True, inline="always")
def _cell_of(ku, kv, u, v):
    """Knot cell (a, b) holding the parameters (u, v)."""
    return find_span(ku, u) - 3, find_span(kv, v) - 3


@njit(cache=True)
def _convex_block(nodes, curv, nj0, i, j, bi, bj, cx, cy, cz):
    """True if D is certified convex on every cell of the rectangle spanned by cells (i, j) and
    (bi, bj) (at most 3x3 cells): then the best point, a local minimum lying in that convex
    rectangle, is its minimum, and cell (i, j) cannot hold a closer point."""
    i0 = min(i, bi)
    i1 = max(i, bi)
    j0 = min(j, bj)
    j1 = max(j, bj)
    if i1 - i0 > 2 or j1 - j0 > 2:
        return False
    for a in range(i0, i1 + 1):
        for b in range(j0, j1 + 1):
            node = a * nj0 + b
            near2, far2, lift = node_bounds2(nodes, node, cx, cy, cz)
            if not cell_certified(nodes, curv, node, far2, cx, cy, cz):
                return False
    return True


@njit(cache=True)
def _no_local_minimum(ctrl, ku, kv, ev, net, e, u0, u1, v0, v1, kuu0, kuu1, kuv0, kuv1, kvv0, kvv1,
                      tuu, tuv, tvv, lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, far2, cx, cy, cz):
    r"""True if D provably has no local minimum on the closed piece [u0, u1] x [v0, v1].

    Two exclusion tests around one evaluation at the centre :math:`x_c` (order 2):

    * no stationary point: :math:`|g_u(x_c)| > \max|H_{uu}|\,\Delta u/2 + \max|H_{uv}|\,\Delta v/2`
      (or the same for :math:`g_v`), with :math:`|H_{uu}| \le |S_u|^2 + |S_{uu}|\,|r|`, ...;
    * negative curvature everywhere: along the eigenvector w of the smallest eigenvalue of
      :math:`H(x_c)`, :math:`w^THw = |Jw|^2 + r\cdot S_{ww} \le (|w_u||S_u| + |w_v||S_v|)^2
      + \max(\alpha\,[n\cdot S_{ww}]) + |r_\perp|\,|S_{ww,\perp}| < 0` on the whole piece
      (valleys and saddles seen from far above).

    The norms come from the piece's Bézier derivative nets (``net[e:e+16]``) and the curvature
    bounds of :func:`net_curvature` along the cell normal n; α = n·r and |r_⊥| from the piece's
    oriented box. A piece inside the domain without a local minimum cannot hold the global one
    (an interior minimum has g = 0 and H ⪰ 0), not even on its edges: it is pruned.
    """
    su, sv = _piece_speeds(net, e, u1 - u0, v1 - v0)
    surface_point(ctrl, ku, kv, 0.5 * (u0 + u1), 0.5 * (v0 + v1), 2, ev)
    return _no_local_minimum_at(ev, su, sv, u1 - u0, v1 - v0, kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv,
                                lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, far2, cx, cy, cz)


@njit(cache=True, inline="always")
def _piece_speeds(net, e, du, dv):
    """Bounds of |S_u| and |S_v| on a piece from its Bézier net ``net[e:e+16]`` (the largest
    difference of neighbouring control points, times 3 over the piece's width), widened 1e-9."""
    su2 = 0.0
    sv2 = 0.0
    for k in range(3):
        for m in range(4):
            qx = net[e + (k + 1) * 4 + m, 0] - net[e + k * 4 + m, 0]
            qy = net[e + (k + 1) * 4 + m, 1] - net[e + k * 4 + m, 1]
            qz = net[e + (k + 1) * 4 + m, 2] - net[e + k * 4 + m, 2]
            su2 = max(su2, qx * qx + qy * qy + qz * qz)
            qx = net[e + m * 4 + k + 1, 0] - net[e + m * 4 + k, 0]
            qy = net[e + m * 4 + k + 1, 1] - net[e + m * 4 + k, 1]
            qz = net[e + m * 4 + k + 1, 2] - net[e + m * 4 + k, 2]
            sv2 = max(sv2, qx * qx + qy * qy + qz * qz)
    return 3.0 * math.sqrt(su2) / du * (1.0 + 1e-9), 3.0 * math.sqrt(sv2) / dv * (1.0 + 1e-9)


@njit(cache=True)
def _no_local_minimum_at(ev, su, sv, du, dv, kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv,
                         lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, far2, cx, cy, cz):
    """:func:`_no_local_minimum` from its parts that do not depend on C: ``ev`` the evaluation
    (order 2) at the piece's centre, ``su``, ``sv`` of :func:`_piece_speeds`, the piece's widths."""
    suu = math.sqrt(max(kuu0 * kuu0, kuu1 * kuu1) + tuu * tuu)
    svv = math.sqrt(max(kvv0 * kvv0, kvv1 * kvv1) + tvv * tvv)
    suv = math.sqrt(max(kuv0 * kuv0, kuv1 * kuv1) + tuv * tuv)
    rmax = math.sqrt(far2)
    rx = ev[0, 0] - cx
    ry = ev[0, 1] - cy
    rz = ev[0, 2] - cz
    gu = ev[1, 0] * rx + ev[1, 1] * ry + ev[1, 2] * rz
    gv = ev[2, 0] * rx + ev[2, 1] * ry + ev[2, 2] * rz
    # margins: relative 1e-9 on the bounds, and the rounding of g itself (~1e-15 |S_u| |r|)
    noise = 1e-14 * math.sqrt(rx * rx + ry * ry + rz * rz) * (su + sv)
    huu = su * su + suu * rmax
    huv = su * sv + suv * rmax
    hvv = sv * sv + svv * rmax
    if abs(gu) > (huu * 0.5 * du + huv * 0.5 * dv) * (1.0 + 1e-9) + noise:
        return True
    if abs(gv) > (huv * 0.5 * du + hvv * 0.5 * dv) * (1.0 + 1e-9) + noise:
        return True
    # Hessian at the centre and its most negative direction
    a = ev[1, 0] * ev[1, 0] + ev[1, 1] * ev[1, 1] + ev[1, 2] * ev[1, 2] + ev[3, 0] * rx + ev[3, 1] * ry + ev[3, 2] * rz
    b = ev[1, 0] * ev[2, 0] + ev[1, 1] * ev[2, 1] + ev[1, 2] * ev[2, 2] + ev[4, 0] * rx + ev[4, 1] * ry + ev[4, 2] * rz
    c = ev[2, 0] * ev[2, 0] + ev[2, 1] * ev[2, 1] + ev[2, 2] * ev[2, 2] + ev[5, 0] * rx + ev[5, 1] * ry + ev[5, 2] * rz
    lam = 0.5 * (a + c) - math.sqrt(0.25 * (a - c) * (a - c) + b * b)
    if not (lam < 0.0):
        return False
    # eigenvector of lam: (b, lam - a) or (lam - c, b), the better conditioned one
    wu, wv = b, lam - a
    if abs(lam - c) + abs(b) > abs(wu) + abs(wv):
        wu, wv = lam - c, b
    wn = math.sqrt(wu * wu + wv * wv)
    if not (wn > 0.0):
        return False
    wu /= wn
    wv /= wn
    jw = abs(wu) * su + abs(wv) * sv
    cuv = 2.0 * wu * wv
    k_lo = wu * wu * kuu0 + wv * wv * kvv0 + min(cuv * kuv0, cuv * kuv1)
    k_hi = wu * wu * kuu1 + wv * wv * kvv1 + max(cuv * kuv0, cuv * kuv1)
    tw = wu * wu * tuu + abs(cuv) * tuv + wv * wv * tvv
    a0, a1, rp = box_offsets(lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, cx, cy, cz)
    bound = jw * jw + max(a0 * k_lo, a0 * k_hi, a1 * k_lo, a1 * k_hi) + rp * tw
    return bound < -1e-9 * jw * jw


@njit(cache=True, _nrt=False)
def _piece_memo(ctrl, ku, kv, work, e, node, pid, version, tree_id, nx, ny, nz, u0, u1, v0, v1):
    """The row of piece ``pid`` of cell ``node`` in the piece memo of ``work`` (layout.py), filled
    first if absent: :func:`net_curvature` of its net ``work[e:e+16]`` along the cell normal n,
    :func:`_piece_speeds`, and the surface (order 2) at its centre. None of it depends on the tip
    centre, so the same piece met by the next ticks' searches reads it back: the same numbers,
    hence the same decisions, as computing them again. The key carries the pyramid's version and
    tree id (a refreshed net or another tile's pyramid never reads a stale entry)."""
    piece = node * 85 + pid  # pid < 85: one number per piece of the pyramid's cells
    key = float(piece + 1)  # never 0, the value of an empty row
    # Fibonacci hashing: neighbouring cells and pieces spread over the whole memo
    m = MEMO_BASE + (((piece * 2654435761) & 0xFFFFFFFF) * PIECE_MEMO >> 32) * MEMO_ROWS
    if work[m, 0] == key and work[m, 1] == version and work[m, 2] == tree_id:
        return m
    kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv, sig2 = net_curvature(work[e:e + 16], u1 - u0, v1 - v0,
                                                                            nx, ny, nz)
    su, sv = _piece_speeds(work, e, u1 - u0, v1 - v0)
    surface_point(ctrl, ku, kv, 0.5 * (u0 + u1), 0.5 * (v0 + v1), 2, work[m + 5:m + 11])
    work[m, 0] = key
    work[m, 1] = version
    work[m, 2] = tree_id
    work[m + 1, 0], work[m + 1, 1], work[m + 1, 2] = kuu0, kuu1, kuv0
    work[m + 2, 0], work[m + 2, 1], work[m + 2, 2] = kuv1, kvv0, kvv1
    work[m + 3, 0], work[m + 3, 1], work[m + 3, 2] = tuu, tuv, tvv
    work[m + 4, 0], work[m + 4, 1], work[m + 4, 2] = sig2, su, sv
    return m


@njit(cache=True, _nrt=False)
def _search_subdivided(ctrl, ku, kv, mu, mv, nodes, node, work, a, b, cx, cy, cz, bu, bv, bd2, bconv,
                       lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h):
    """Closest point in knot cell (a, b) when D is not certified convex there.

    The cell's Bézier net is split into quarters (de Casteljau) down to ``MAX_SUBDIVISION``; each
    piece is pruned by the distance to its box (in the cell's frame) and, once certified convex
    or at the depth limit, searched by Newton restricted to its parameter rectangle. Returns the
    updated best ``(bu, bv, bd2, bconv, iterations, nonfinite)``.
    """
    nx, ny, nz = nodes[node, 0], nodes[node, 1], nodes[node, 2]
    tx, ty, tz = nodes[node, 3], nodes[node, 4], nodes[node, 5]
    ev = work[0:6]
    e = SUB_BASE
    cell_net(ctrl, mu, mv, a, b, work[e:e + 16])
    work[e + 16, 0] = ku[a + 3]
    work[e + 16, 1] = ku[a + 4]
    work[e + 16, 2] = kv[b + 3]
    work[e + 17, 0] = kv[b + 4]
    work[e + 17, 1] = 0.0
    work[e + 17, 2] = 0.0  # piece id: the cell 0, the children of piece p 4p + 1 .. 4p + 4
    vrow = nodes.shape[0] - 1
    version = nodes[vrow, VERSION]
    tree_id = nodes[vrow, TREE_ID]
    sp = 1
    iters = 0
    nonfinite = False
    while sp > 0:
        sp -= 1
        e = SUB_BASE + sp * SUB_ENTRY
        u0 = work[e + 16, 0]
        u1 = work[e + 16, 1]
        v0 = work[e + 16, 2]
        v1 = work[e + 17, 0]
        depth = int(work[e + 17, 1])
        lt, ht, ls, hs, ln, hn = net_extents(work, e, 16, nx, ny, nz, tx, ty, tz)
        near2, far2, lift = extents_bounds2(lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, cx, cy, cz)
        if not (near2 < bd2 * TIE):
            continue
        m = _piece_memo(ctrl, ku, kv, work, e, node, int(work[e + 17, 2]), version, tree_id, nx, ny, nz,
                        u0, u1, v0, v1)
        kuu0, kuu1, kuv0 = work[m + 1, 0], work[m + 1, 1], work[m + 1, 2]
        kuv1, kvv0, kvv1 = work[m + 2, 0], work[m + 2, 1], work[m + 2, 2]
        tuu, tuv, tvv = work[m + 3, 0], work[m + 3, 1], work[m + 3, 2]
        sig2 = work[m + 4, 0]
        # unsigned radius (Gershgorin with norms) or the signed test along the cell's normal
        rho = curvature_radius(kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv, sig2)
        convex = far2 < rho * rho or signed_convex(
            kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv, sig2, lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz,
            cx, cy, cz)
        if not convex and lo_u < u0 and u1 < hi_u and lo_v < v0 and v1 < hi_v and _no_local_minimum_at(
                work[m + 5:m + 11], work[m + 4, 1], work[m + 4, 2], u1 - u0, v1 - v0, kuu0, kuu1, kuv0, kuv1,
                kvv0, kvv1, tuu, tuv, tvv, lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, far2, cx, cy, cz):
            continue  # inside the domain and provably no local minimum of D on the piece
        if convex or depth >= MAX_SUBDIVISION or sp + 4 > SUB_CAP:
            if convex and u0 <= bu <= u1 and v0 <= bv <= v1:
                continue  # convex piece holding the best point: that point is its minimum
            su = _clip(cx - lift * nx, u0, u1)
            sv = _clip(cy - lift * ny, v0, v1)
            u, v, d2, it, conv = newton_box(ctrl, ku, kv, ev, cx, cy, cz, su, sv, u0, u1, v0, v1,
                                            tol_u, tol_v, h, MAX_ITER_CELL)
            iters += it
            if not (d2 - d2 == 0.0):
                nonfinite = True
                continue
            if d2 < bd2:
                u, v, d2, it, conv = newton_box(ctrl, ku, kv, ev, cx, cy, cz, u, v, lo_u, hi_u, lo_v, hi_v,
                                                tol_u, tol_v, h, MAX_ITER_DOMAIN)
                iters += it
                if d2 < bd2:
                    bu, bv, bd2, bconv = u, v, d2, conv
                    _keep(work)
            continue
        # split into quarters: the parent's slot becomes the first child
        pid = work[e + 17, 2]
        for r in range(16):
            for c in range(3):
                work[NET_TMP + r, c] = work[e + r, c]
        um = 0.5 * (u0 + u1)
        vm = 0.5 * (v0 + v1)
        e0 = e
        e1 = e + SUB_ENTRY
        e2 = e + 2 * SUB_ENTRY
        e3 = e + 3 * SUB_ENTRY
        net_split(work, NET_TMP, work, e0, e1, e2, e3)
        for q in range(4):
            eq = e + q * SUB_ENTRY
            work[eq + 16, 0] = u0 if (q & 1) == 0 else um
            work[eq + 16, 1] = um if (q & 1) == 0 else u1
            work[eq + 16, 2] = v0 if q < 2 else vm
            work[eq + 17, 0] = vm if q < 2 else v1
            work[eq + 17, 1] = depth + 1
            work[eq + 17, 2] = 4.0 * pid + 1.0 + q
        sp += 4
    return bu, bv, bd2, bconv, iters, nonfinite


@njit(cache=True)
def _finish(ev, cx, cy, cz, u, v, out):
    """Point, unit normal and signed distance from S, S_u, S_v in ``ev[:3]`` into ``out``; returns a status."""
    px, py, pz = ev[0, 0], ev[0, 1], ev[0, 2]
    sux, suy, suz = ev[1, 0], ev[1, 1], ev[1, 2]
    svx, svy, svz = ev[2, 0], ev[2, 1], ev[2, 2]
    nx = suy * svz - suz * svy
    ny = suz * svx - sux * svz
    nz = sux * svy - suy * svx
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    wx = cx - px
    wy = cy - py
    wz = cz - pz
    dist = math.sqrt(wx * wx + wy * wy + wz * wz)
    # degenerate when |S_u x S_v| is rounding noise next to the longer tangent (a collapsed edge)
    scale = max(sux * sux + suy * suy + suz * suz, svx * svx + svy * svy + svz * svz)
    status = OK
    if nn > 1e-12 * scale and nn > 0.0:
        nx /= nn
        ny /= nn
        nz /= nn
        signed = dist if (wx * nx + wy * ny + wz * nz) >= 0.0 else -dist
    else:
        status = DEGENERATE
        signed = dist
        if dist > 0.0:
            nx, ny, nz = wx / dist, wy / dist, wz / dist
        else:
            nx, ny, nz = 0.0, 0.0, 1.0
    out[OUT_U] = u
    out[OUT_V] = v
    out[OUT_PX] = px
    out[OUT_PY] = py
    out[OUT_PZ] = pz
    out[OUT_NX] = nx
    out[OUT_NY] = ny
    out[OUT_NZ] = nz
    out[OUT_DISTANCE] = signed
    if not (signed - signed == 0.0 and nx - nx == 0.0 and ny - ny == 0.0 and nz - nz == 0.0):
        return NON_FINITE
    return status


@njit(cache=True, _nrt=False)
def _visit_leaf(ctrl, ku, kv, mu, mv, nodes, curv, nj0, work, node, near2, far2, lift, cx, cy, cz,
                bu, bv, bd2, bconv, bi, bj, lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h):
    """Search knot cell ``node`` (a leaf of the pyramid) for a point closer than the best.

    Skipped when its box is not nearer than the best distance, or when D is certified convex on
    the rectangle spanned by the cell and the best point's cell (the best point, a local minimum,
    is then the minimum there). A certified cell gets one Newton run restricted to it (convex:
    its minimum is found from any seed); an uncertified one is subdivided
    (:func:`_search_subdivided`). ``near2, far2, lift`` are :func:`node_bounds2` of the cell.
    Returns ``(bu, bv, bd2, bconv, bi, bj, iterations, searched, nonfinite)``.
    """
    if not (near2 < bd2 * TIE):
        return bu, bv, bd2, bconv, bi, bj, 0, 0, False
    if nodes[node, LO_T] == -np.inf:  # a cell whose Bézier net is not finite (see candidates)
        return bu, bv, bd2, bconv, bi, bj, 0, 1, True
    i = node // nj0
    j = node - i * nj0
    iters = 0
    if not cell_certified(nodes, curv, node, far2, cx, cy, cz):  # no convexity certificate: subdivide
        bu, bv, bd2, bconv, iters, nf = _search_subdivided(ctrl, ku, kv, mu, mv, nodes, node, work, i, j,
                                                           cx, cy, cz, bu, bv, bd2, bconv,
                                                           lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h)
        bi, bj = _cell_of(ku, kv, bu, bv)
        return bu, bv, bd2, bconv, bi, bj, iters, 1, nf
    if bconv and _convex_block(nodes, curv, nj0, i, j, bi, bj, cx, cy, cz):
        return bu, bv, bd2, bconv, bi, bj, 0, 1, False
    cu0 = ku[i + 3]
    cu1 = ku[i + 4]
    cv0 = kv[j + 3]
    cv1 = kv[j + 4]
    # seed: the foot of C on the mid-plane of the cell's box, clamped to the cell
    su = _clip(cx - lift * nodes[node, 0], cu0, cu1)
    sv = _clip(cy - lift * nodes[node, 1], cv0, cv1)
    ev = work[0:6]
    u, v, d2, it, conv = newton_box(ctrl, ku, kv, ev, cx, cy, cz, su, sv, cu0, cu1, cv0, cv1,
                                    tol_u, tol_v, h, MAX_ITER_CELL)
    iters += it
    if not (d2 - d2 == 0.0):
        return bu, bv, bd2, bconv, bi, bj, iters, 1, True
    if d2 < bd2:
        u, v, d2, it, conv = newton_box(ctrl, ku, kv, ev, cx, cy, cz, u, v,
                                        lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h, MAX_ITER_DOMAIN)
        iters += it
        if d2 < bd2:
            bu, bv, bd2, bconv = u, v, d2, conv
            bi, bj = _cell_of(ku, kv, bu, bv)
            _keep(work)
    return bu, bv, bd2, bconv, bi, bj, iters, 1, False


@njit(cache=True, inline="always")
def _push(work, sp, lev, i, j):
    """Push pyramid node (level, i, j) on the search stack in ``work`` (rows from STACK_ROWS);
    returns the new stack pointer."""
    work[sp, 0] = lev
    work[sp, 1] = i
    work[sp, 2] = j
    return sp + 1


@njit(cache=True, inline="always")
def _pop(work, sp):
    """Pop the search stack: (new stack pointer, level, i, j)."""
    sp -= 1
    return sp, int(work[sp, 0]), int(work[sp, 1]), int(work[sp, 2])


# the cache header's row after C0: (R0, queries left to wait (-1: a list gathered, not used yet), back-off)
_GATHER_ROW, _WAIT, _BACKOFF = CACHE_ROW + 2, 1, 2


@njit(cache=True, inline="always")
def _back_off(work):
    """A wasted gathering: wait twice as long as after the last one (1 the first time, at most
    CACHE_BACKOFF queries) before the next (project_kernel, Notes)."""
    wait = min(max(2.0 * work[_GATHER_ROW, _BACKOFF], 1.0), CACHE_BACKOFF)
    work[_GATHER_ROW, _BACKOFF] = wait
    work[_GATHER_ROW, _WAIT] = wait


@njit(cache=True, inline="always")
def _may_gather(work):
    """Whether a warm walk gathers a candidate list: not while a back-off lasts (one query of it
    counted off); a list gathered and never used is a waste, which starts one."""
    if work[_GATHER_ROW, _WAIT] == -1.0:
        _back_off(work)
    left = work[_GATHER_ROW, _WAIT]
    if left > 0.0:
        work[_GATHER_ROW, _WAIT] = left - 1.0
        return False
    return True


@njit(cache=True)
def sort_candidates(work, first, n, scratch):
    """Sort rows ``first .. first + n - 1`` of ``work`` (cell, distance, -) by distance, ties in
    their present order (a stable sort), in O(n) for spread distances: a counting sort into n
    buckets of equal width between the least and the largest distance (rows from ``scratch``
    of ``work`` hold the buckets' counts and the sorted rows, n <= CACHE_CAP), then an insertion
    sort, which only meets the few rows sharing a bucket.

    The candidate list of a warm query is rebuilt every few ticks, inside a tick, and its walk
    emits the cells depth-first, far from sorted: an insertion sort alone of the ~480 cells at
    0.1 nm pitch under a 50 nm tip cost ~45 us (bench/haptic_loop.py's table)."""
    if n < 2:
        return
    lo = work[first, 1]
    hi = lo
    for r in range(first + 1, first + n):
        lo = min(lo, work[r, 1])
        hi = max(hi, work[r, 1])
    if hi > lo:
        scale = n / (hi - lo)  # bucket = int((d - lo) scale): non-decreasing in d
        for k in range(n):
            scratch_row = scratch + k
            work[scratch_row, 2] = 0.0
        for r in range(first, first + n):
            k = min(int((work[r, 1] - lo) * scale), n - 1)
            work[scratch + k, 2] += 1.0
        start = 0.0
        for k in range(n):  # counts -> first row of each bucket
            c = work[scratch + k, 2]
            work[scratch + k, 2] = start
            start += c
        for r in range(first, first + n):  # stable placement, then back
            k = min(int((work[r, 1] - lo) * scale), n - 1)
            at = scratch + int(work[scratch + k, 2])
            work[scratch + k, 2] += 1.0
            work[at, 0] = work[r, 0]
            work[at, 1] = work[r, 1]
        for k in range(n):
            work[first + k, 0] = work[scratch + k, 0]
            work[first + k, 1] = work[scratch + k, 1]
    for a in range(first + 1, first + n):  # insertion sort: stable, ~O(n) after the buckets
        kn = work[a, 0]
        kd = work[a, 1]
        b = a - 1
        while b >= first and work[b, 1] > kd:
            work[b + 1, 0] = work[b, 0]
            work[b + 1, 1] = work[b, 1]
            b -= 1
        work[b + 1, 0] = kn
        work[b + 1, 1] = kd


@njit(cache=True, _nrt=False)
def project_kernel(ctrl, ku, kv, mu, mv, nodes, curv, levels, work, cx, cy, cz, hint_u, hint_v, out):
    """Global closest point of the surface to (cx, cy, cz); writes ``out`` (OUT_SIZE,), returns a status.

    Parameters
    ----------
    ctrl, ku, kv : (nu, nv, 3), (nu+4,), (nv+4,) float64
        Live control net and knots (:meth:`BSplineSurface.kernel_arrays`).
    mu, mv, nodes, levels : the hull pyramid (:class:`arsurf.contact.hull_tree.HullTree`),
        current with ``ctrl`` (refreshed after every change of the net).
    work : (WORK_ROWS + 4 L, 3) float64
        Scratch and the warm-start candidate cache; one per thread (and per surface).
    cx, cy, cz : float, metres
        Query point (tip centre).
    hint_u, hint_v : float, metres
        Warm start (last answer); NaN for a cold start from (cx, cy).
    out : (OUT_SIZE,) float64
        Result, see the ``OUT_*`` indices.

    Notes
    -----
    Warm queries keep a candidate list in ``work``: every cell whose box is within
    :math:`R_0 = d^*(C_0) + m` of the point :math:`C_0` where it was built (m = CACHE_MARGIN x
    knot spacing), sorted by that distance. A later query at C with first bound d (from Newton at
    the hint) may use it while :math:`|C - C_0| + d \\le R_0`: any cell nearer to C than d is then
    nearer to :math:`C_0` than :math:`R_0`, so it is in the list, and the scan stops at the first
    entry farther than :math:`d + |C - C_0|`. A refresh of the pyramid (deformation) bumps its
    version and invalidates the list.

    Gathering a list makes the walk visit every cell within the reach, not only those that may
    hold the closest point. Where the list is wasted - more than CACHE_CAP cells within the reach
    (a scan much finer than the tip: 0.015 nm pixels under a 20 nm tip), where the gathering
    stops at the cap and the walk goes on as a plain query's, or a list never used because the
    tip moves farther than the margin between two queries - the next 1, 2, 4 ... CACHE_BACKOFF
    warm queries walk without gathering (doubled at each waste in a row, reset when a list is
    used). Without it the 4 nm STM scan of ../shared/scans-real gathered at every tick: ~150 us
    a tick in contact (overflowing), ~16 us sliding off its edge (lists never used), against
    ~1 us for the plain walk.
    """
    if not (cx - cx == 0.0 and cy - cy == 0.0 and cz - cz == 0.0):
        out[OUT_STATUS] = BAD_INPUT
        return BAD_INPUT
    nu = ctrl.shape[0]
    nv = ctrl.shape[1]
    lo_u = ku[3]
    hi_u = ku[nu]
    lo_v = kv[3]
    hi_v = kv[nv]
    hu = (hi_u - lo_u) / (nu - 3)
    hv = (hi_v - lo_v) / (nv - 3)
    h = max(hu, hv)
    tol_u = STEP_TOL * hu
    tol_v = STEP_TOL * hv
    ev = work[0:6]
    warm = hint_u - hint_u == 0.0 and hint_v - hint_v == 0.0
    nj0 = levels[0, 2]
    if warm:
        su, sv = hint_u, hint_v
    else:
        # cold: the foot of C on the mid-plane of the cell below it (on the undeformed surface
        # u = x, v = y), one or two Newton steps closer than the point straight below
        i, j = _cell_of(ku, kv, cx, cy)
        node = i * nj0 + j
        lift = (nodes[node, 0] * cx + nodes[node, 1] * cy + nodes[node, 2] * cz
                - 0.5 * (nodes[node, LO_N] + nodes[node, HI_N]))
        su, sv = cx - lift * nodes[node, 0], cy - lift * nodes[node, 1]
        if not (su - su == 0.0 and sv - sv == 0.0):  # a non-finite cell
            su, sv = cx, cy
    bu, bv, bd2, iters, bconv = newton_box(ctrl, ku, kv, ev, cx, cy, cz, su, sv,
                                           lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h, MAX_ITER_DOMAIN)
    warm_u = bu if warm and bconv else np.nan
    warm_v = bv if warm and bconv else np.nan
    _keep(work)
    nonfinite = not (bd2 - bd2 == 0.0)
    if nonfinite:
        bd2 = np.inf
    bi, bj = _cell_of(ku, kv, bu, bv)
    cells = 0
    # --- the candidate cache of warm queries
    vrow = nodes.shape[0] - 1
    version = nodes[vrow, VERSION]
    tree_id = nodes[vrow, TREE_ID]
    count = int(work[CACHE_ROW, 2])
    d0 = math.sqrt(bd2)
    dc = 0.0
    use_cache = False
    if count > 0 and work[CACHE_ROW, 0] == version and work[CACHE_ROW, 1] == tree_id:
        ddx = cx - work[CACHE_ROW + 1, 0]
        ddy = cy - work[CACHE_ROW + 1, 1]
        ddz = cz - work[CACHE_ROW + 1, 2]
        dc = math.sqrt(ddx * ddx + ddy * ddy + ddz * ddz)
        use_cache = dc + d0 <= work[CACHE_ROW + 2, 0]
    if use_cache:
        work[_GATHER_ROW, _WAIT] = 0.0  # the lists are used: no back-off
        work[_GATHER_ROW, _BACKOFF] = 0.0
        for k in range(count):
            row = CACHE_LIST + k
            if work[row, 1] - dc >= math.sqrt(bd2):
                break  # sorted: no later entry can be nearer than the best
            node = int(work[row, 0])
            near2, far2, lift = node_bounds2(nodes, node, cx, cy, cz)
            if not (near2 < bd2 * TIE):
                continue
            bu, bv, bd2, bconv, bi, bj, it, searched, nf = _visit_leaf(
                ctrl, ku, kv, mu, mv, nodes, curv, nj0, work, node, near2, far2, lift, cx, cy, cz, bu, bv, bd2,
                bconv, bi, bj, lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h)
            iters += it
            cells += searched
            nonfinite = nonfinite or nf
    else:
        # --- the pyramid, nearest child first; a warm query also records the candidate list
        # (unless a back-off lasts)
        build = warm and not nonfinite and _may_gather(work)
        gather = build
        reach = d0 + CACHE_MARGIN * h if build else 0.0
        reach2 = reach * reach
        count = 0
        overflow = False
        nlev = levels.shape[0]
        cap = work.shape[0]
        sp = _push(work, STACK_ROWS, nlev - 1, 0, 0)
        while sp > STACK_ROWS:
            sp, lev, i, j = _pop(work, sp)
            if lev == 0:
                node = i * nj0 + j
                near2, far2, lift = node_bounds2(nodes, node, cx, cy, cz)
                if gather and near2 < reach2:
                    if count < CACHE_CAP:
                        work[CACHE_LIST + count, 0] = node
                        work[CACHE_LIST + count, 1] = math.sqrt(near2)
                        count += 1
                    else:  # too many cells for a list: the rest of the walk is a plain query's
                        overflow = True
                        gather = False
                        reach2 = 0.0
                if not (near2 < bd2 * TIE):
                    continue
                bu, bv, bd2, bconv, bi, bj, it, searched, nf = _visit_leaf(
                    ctrl, ku, kv, mu, mv, nodes, curv, nj0, work, node, near2, far2, lift, cx, cy, cz, bu, bv, bd2,
                    bconv, bi, bj, lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h)
                iters += it
                cells += searched
                nonfinite = nonfinite or nf
                continue
            if not gather and bconv and (bi >> lev) == i and (bj >> lev) == j:
                # the best point (a local minimum) lies in this node: if D is certified convex on all
                # of its cells (C within their smallest convexity radius), it is their minimum
                node = levels[lev, 0] + i * levels[lev, 2] + j
                near2, far2, lift = node_bounds2(nodes, node, cx, cy, cz)
                rho = nodes[node, RHO]
                if far2 < rho * rho:
                    continue
            # children on level lev - 1, pushed farthest first so the nearest is searched first
            limit = max(bd2 * TIE, reach2)
            clev = lev - 1
            coff = levels[clev, 0]
            cni = levels[clev, 1]
            cnj = levels[clev, 2]
            k0 = k1 = k2 = k3 = -1
            e0 = e1 = e2 = e3 = np.inf
            for k in range(4):
                ci = 2 * i + (k >> 1)
                cj = 2 * j + (k & 1)
                if ci >= cni or cj >= cnj:
                    continue
                d = node_distance2(nodes, coff + ci * cnj + cj, cx, cy, cz)
                if not (d < limit):
                    continue
                # insertion into the sorted quadruple (e0 <= e1 <= e2 <= e3)
                if d < e3:
                    e3, k3 = d, k
                    if e3 < e2:
                        e2, e3, k2, k3 = e3, e2, k3, k2
                        if e2 < e1:
                            e1, e2, k1, k2 = e2, e1, k2, k1
                            if e1 < e0:
                                e0, e1, k0, k1 = e1, e0, k1, k0
            for kk in (k3, k2, k1, k0):
                if kk >= 0 and sp < cap:
                    sp = _push(work, sp, clev, 2 * i + (kk >> 1), 2 * j + (kk & 1))
        if build and not overflow and count > 0:
            sort_candidates(work, CACHE_LIST, count, CACHE_SORT)
            work[CACHE_ROW, 0] = version
            work[CACHE_ROW, 1] = tree_id
            work[CACHE_ROW, 2] = count
            work[CACHE_ROW + 1, 0] = cx
            work[CACHE_ROW + 1, 1] = cy
            work[CACHE_ROW + 1, 2] = cz
            work[CACHE_ROW + 2, 0] = reach
        elif build:
            work[CACHE_ROW, 2] = 0.0
        if build and overflow:
            _back_off(work)
        elif build:
            work[_GATHER_ROW, _WAIT] = -1.0  # a list not used yet
    out[OUT_ITERATIONS] = iters
    out[OUT_CELLS] = cells
    out[OUT_CACHED] = 1.0 if use_cache else 0.0
    out[OUT_WARM_U] = warm_u
    out[OUT_WARM_V] = warm_v
    out[OUT_CONVERGED] = 1.0 if bconv else 0.0
    out[OUT_BOUNDARY] = 1.0 if (bu <= lo_u or bu >= hi_u or bv <= lo_v or bv >= hi_v) else 0.0
    status = _finish(work[BEST_ROW:BEST_ROW + 3], cx, cy, cz, bu, bv, out)
    if nonfinite:
        status = NON_FINITE
    elif status == OK and not bconv:
        status = ITERATION_LIMIT
    out[OUT_STATUS] = status
    return status


@njit(cache=True, _nrt=False)
def collide_kernel(ctrl, ku, kv, mu, mv, nodes, curv, levels, work, cx, cy, cz, radius, hint_u, hint_v, out):
    """Tip sphere (centre, radius) against the surface: :func:`project_kernel` plus the depth.

    Writes ``out[OUT_DEPTH] = radius - out[OUT_DISTANCE]`` (> 0: penetration). Returns the status
    (``BAD_INPUT`` for a non-finite centre or radius <= 0). For the haptic-loop kernel:
    call it with the arrays of :meth:`Projector.kernel_args` and the last ``out[OUT_U]``,
    ``out[OUT_V]`` as the hint.
    """
    if not (radius > 0.0 and radius - radius == 0.0):
        out[OUT_STATUS] = BAD_INPUT
        return BAD_INPUT
    status = project_kernel(ctrl, ku, kv, mu, mv, nodes, curv, levels, work, cx, cy, cz, hint_u, hint_v, out)
    out[OUT_DEPTH] = radius - out[OUT_DISTANCE]
    return status


# --- tiles: the hull-box pyramid built lazily, tile by tile ------------------------------------
#: the grid (int64) of a tiled projector: the tile size (cells), the tiles along u and v, the cells
#: along u and v, the slots, the slots in use, the use clock, the tile builds so far
TILE_GRID = Layout("tile grid", [("tile", 1), ("tiles_u", 1), ("tiles_v", 1), ("cells_u", 1), ("cells_v", 1),
                                 ("slots", 1), ("used", 1), ("clock", 1), ("builds", 1)])
G_TILE, G_NTI, G_NTJ, G_NCU, G_NCV, G_SLOTS, G_USED, G_CLOCK, G_BUILDS = (TILE_GRID.offset(f) for f in TILE_GRID.fields)
G_SIZE = TILE_GRID.size
#: slot_info (int64) columns: the tile a slot holds (i, j), its pyramid depth, when it was last used
SLOT_INFO = Layout("tile slot columns", [("tile", 2), ("levels", 1), ("used", 1)])
SI_TI, SI_LEVELS, SI_USED = SLOT_INFO.offset("tile"), SLOT_INFO.offset("levels"), SLOT_INFO.offset("used")
SI_TJ = SI_TI + 1


@njit(cache=True)
def tile_levels(ni, nj, levels):
    """:func:`arsurf.contact.hull_tree.pyramid_levels` into ``levels`` (L, 3); returns (L, nodes)."""
    k = 0
    offset = 0
    while True:
        levels[k, 0] = offset
        levels[k, 1] = ni
        levels[k, 2] = nj
        offset += ni * nj
        k += 1
        if ni == 1 and nj == 1:
            break
        ni = (ni + 1) // 2
        nj = (nj + 1) // 2
    return k, offset


@njit(cache=True, inline="always")
def _tile_span(grid, ti, tj):
    """(i0, j0, ni, nj): first cell and cell counts of tile (ti, tj)."""
    t = grid[G_TILE]
    i0 = ti * t
    j0 = tj * t
    return i0, j0, min(t, grid[G_NCU] - i0), min(t, grid[G_NCV] - j0)


@njit(cache=True, nogil=True, _nrt=False)
def build_tile(ctrl, ku, kv, mu, mv, pnodes, pcurv, plevels, pwork, prows, bez, grid, tile_slot, slot_info, ti, tj):
    """Build the hull pyramid of tile (ti, tj) into a slot of the pool (the least recently used
    one when the pool is full, whose tile is forgotten); returns the slot, or -1 - slot when the
    tile's control net holds NaN/inf (the slot then stays empty). Cost O(tile cells)."""
    if grid[G_USED] < grid[G_SLOTS]:
        s = grid[G_USED]
        grid[G_USED] += 1
    else:
        s = 0
        for k in range(1, grid[G_SLOTS]):
            if slot_info[k, SI_USED] < slot_info[s, SI_USED]:
                s = k
        tile_slot[slot_info[s, SI_TI], slot_info[s, SI_TJ]] = -1
    i0, j0, ni, nj = _tile_span(grid, ti, tj)
    nlev, nn = tile_levels(ni, nj, plevels[s])
    nodes = pnodes[s, :nn + 1]
    grid[G_BUILDS] += 1
    nodes[nn, VERSION] = 0.0
    nodes[nn, TREE_ID] = -float(grid[G_BUILDS])  # unique per build: stale caches are never reused
    pwork[s, CACHE_ROW, 0] = -1.0  # no candidate list yet
    bad = refresh_region_kernel(ctrl[i0:i0 + ni + 3, j0:j0 + nj + 3], ku[i0:i0 + ni + 7], kv[j0:j0 + nj + 7],
                                mu[i0:i0 + ni], mv[j0:j0 + nj], nodes, pcurv[s, :ni * nj], plevels[s, :nlev],
                                prows[s, :, :nj + 3], bez, 0, ni + 3, 0, nj + 3)
    slot_info[s, SI_TI] = ti
    slot_info[s, SI_TJ] = tj
    slot_info[s, SI_LEVELS] = nlev
    slot_info[s, SI_USED] = grid[G_CLOCK]
    if bad:
        slot_info[s, SI_USED] = -1  # reused first
        return -1 - s
    tile_slot[ti, tj] = s
    return s


@njit(cache=True)
def _may_hold_closer(nodes, levels, work, cx, cy, cz, best2):
    """True if some knot cell's hull box of this pyramid is nearer to C than ``best2`` (squared):
    the walk of :func:`project_kernel` without its Newton runs, stopping at the first such cell."""
    sp = _push(work, STACK_ROWS, levels.shape[0] - 1, 0, 0)
    while sp > STACK_ROWS:
        sp, lev, i, j = _pop(work, sp)
        node = levels[lev, 0] + i * levels[lev, 2] + j
        if not (node_distance2(nodes, node, cx, cy, cz) < best2 * TIE):
            continue
        if lev == 0:
            return True
        cni = levels[lev - 1, 1]
        cnj = levels[lev - 1, 2]
        for ci in range(2 * i, min(2 * i + 2, cni)):
            for cj in range(2 * j, min(2 * j + 2, cnj)):
                sp = _push(work, sp, lev - 1, ci, cj)
    return False


@njit(cache=True, inline="always")
def _lateral2(ku, kv, grid, ti, tj, slack, cx, cy):
    """Squared horizontal distance from (cx, cy) to tile (ti, tj), less the slack: a lower bound
    of the distance to every surface point of the tile (x(u) = u within ``slack``)."""
    i0, j0, ni, nj = _tile_span(grid, ti, tj)
    dx = max(ku[i0 + 3] - cx, cx - ku[i0 + ni + 3], 0.0) - slack
    dy = max(kv[j0 + 3] - cy, cy - kv[j0 + nj + 3], 0.0) - slack
    dx = max(dx, 0.0)
    dy = max(dy, 0.0)
    return dx * dx + dy * dy


@njit(cache=True, _nrt=False)
def tiled_project_kernel(ctrl, ku, kv, mu, mv, pnodes, pcurv, plevels, pwork, prows, bez, grid, slack, tile_slot,
                         slot_info, tmp, cx, cy, cz, hint_u, hint_v, out):
    """:func:`project_kernel` over a surface cut into tiles whose pyramids are built on demand.

    Tiles of ``grid[G_TILE]`` x ``grid[G_TILE]`` knot cells are visited in rings around the tile
    under C. Every surface point of a tile lies horizontally within ``slack[0]`` of the tile's
    parameter rectangle (x(u) = u on an undeformed surface; a deformation moves control points by
    at most the slack, and by the partition of unity the surface moves no more), so the
    horizontal distance from C to the rectangle, less the slack, bounds the distance to the
    tile from below. A tile is searched (:func:`project_kernel` on its own pyramid, exact over
    its closed parameter rectangle) only when that bound beats the best distance so far, and
    ring r, whose tiles are at least (r - 1) tile widths away, ends the walk once that width
    exceeds it: the minimum over the tiles searched is the global minimum. A tile not built
    yet is built first (O(tile)); after the answer, at most one more unbuilt tile within half a
    tile of C's reach is built ahead into a free slot, so a tip moving across tiles rarely waits
    for two.

    ``tmp`` (OUT_SIZE,) is scratch; the other arrays are :class:`TiledProjector`'s pool. The
    result is ``out`` as for :func:`project_kernel` (iterations and cells summed over tiles).
    """
    if not (cx - cx == 0.0 and cy - cy == 0.0 and cz - cz == 0.0):
        out[OUT_STATUS] = BAD_INPUT
        return BAD_INPUT
    grid[G_CLOCK] += 1
    t = grid[G_TILE]
    nti = grid[G_NTI]
    ntj = grid[G_NTJ]
    ncu = grid[G_NCU]
    ncv = grid[G_NCV]
    sl = slack[0]
    width = min((ku[ncu + 3] - ku[3]) / ncu, (kv[ncv + 3] - kv[3]) / ncv) * t
    ci, cj = _cell_of(ku, kv, cx, cy)
    ti0 = ci // t
    tj0 = cj // t
    best = np.inf
    status = OK
    iters = 0.0
    cells = 0.0
    r = 0
    while r <= max(nti, ntj):
        if best < np.inf and (r - 1) * width - sl > best:
            break
        for ti in range(max(ti0 - r, 0), min(ti0 + r, nti - 1) + 1):
            for tj in range(max(tj0 - r, 0), min(tj0 + r, ntj - 1) + 1):
                if max(abs(ti - ti0), abs(tj - tj0)) != r:
                    continue
                if _lateral2(ku, kv, grid, ti, tj, sl, cx, cy) >= best * best:
                    continue
                s = tile_slot[ti, tj]
                if s < 0:
                    s = build_tile(ctrl, ku, kv, mu, mv, pnodes, pcurv, plevels, pwork, prows, bez, grid,
                                   tile_slot, slot_info, ti, tj)
                    if s < 0:
                        out[OUT_STATUS] = NON_FINITE
                        return NON_FINITE
                slot_info[s, SI_USED] = grid[G_CLOCK]
                nlev = slot_info[s, SI_LEVELS]
                nn = plevels[s, nlev - 1, 0] + 1
                if best < np.inf and not _may_hold_closer(pnodes[s, :nn + 1], plevels[s, :nlev], pwork[s],
                                                          cx, cy, cz, best * best):
                    continue  # every hull box of the tile is farther than the answer so far
                i0, j0, ni, nj = _tile_span(grid, ti, tj)
                hu = hint_u
                hv = hint_v
                if not (ku[i0 + 3] <= hint_u <= ku[i0 + ni + 3] and kv[j0 + 3] <= hint_v <= kv[j0 + nj + 3]):
                    hu = np.nan
                    hv = np.nan
                st = project_kernel(ctrl[i0:i0 + ni + 3, j0:j0 + nj + 3], ku[i0:i0 + ni + 7], kv[j0:j0 + nj + 7],
                                    mu[i0:i0 + ni], mv[j0:j0 + nj], pnodes[s, :nn + 1], pcurv[s, :ni * nj],
                                    plevels[s, :nlev], pwork[s], cx, cy, cz, hu, hv, tmp)
                iters += tmp[OUT_ITERATIONS]
                cells += tmp[OUT_CELLS]
                if st < 0:
                    out[OUT_STATUS] = st
                    return st
                d = abs(tmp[OUT_DISTANCE])
                if d < best:
                    best = d
                    status = st
                    for k in range(OUT_SIZE):
                        out[k] = tmp[k]
                    if not _inside_tile(ku, kv, i0, j0, ni, nj, ncu, ncv, tmp[OUT_WARM_U], tmp[OUT_WARM_V]):
                        out[OUT_WARM_U] = np.nan  # the tile's box stopped that Newton run: not the
                        out[OUT_WARM_V] = np.nan  # whole domain's
        r += 1
    out[OUT_ITERATIONS] = iters
    out[OUT_CELLS] = cells
    bu = out[OUT_U]
    bv = out[OUT_V]
    out[OUT_BOUNDARY] = 1.0 if (bu <= ku[3] or bu >= ku[ncu + 3] or bv <= kv[3] or bv >= kv[ncv + 3]) else 0.0
    out[OUT_STATUS] = status
    # build ahead: one unbuilt neighbour within half a tile of the sphere of radius best
    reach = best + 0.5 * width
    for ti in range(max(ti0 - 1, 0), min(ti0 + 1, nti - 1) + 1):
        for tj in range(max(tj0 - 1, 0), min(tj0 + 1, ntj - 1) + 1):
            if tile_slot[ti, tj] < 0 and _lateral2(ku, kv, grid, ti, tj, sl, cx, cy) < reach * reach:
                if grid[G_USED] < grid[G_SLOTS]:  # only into a free slot: building ahead never evicts
                    build_tile(ctrl, ku, kv, mu, mv, pnodes, pcurv, plevels, pwork, prows, bez, grid, tile_slot,
                               slot_info, ti, tj)
                return status
    return status


@njit(cache=True, inline="always")
def _inside_tile(ku, kv, i0, j0, ni, nj, ncu, ncv, u, v) -> bool:
    """(u, v) strictly inside the parameter rectangle of the tile (cells i0..i0+ni, j0..j0+nj),
    or on a side that is the domain's own: where a Newton run boxed in the tile ended on a
    point that a run over the whole domain also reaches (False for NaN)."""
    lo_u = ku[i0 + 3]
    hi_u = ku[i0 + ni + 3]
    lo_v = kv[j0 + 3]
    hi_v = kv[j0 + nj + 3]
    return ((lo_u < u or (i0 == 0 and lo_u <= u)) and (u < hi_u or (i0 + ni == ncu and u <= hi_u))
            and (lo_v < v or (j0 == 0 and lo_v <= v)) and (v < hi_v or (j0 + nj == ncv and v <= hi_v)))


@njit(cache=True, _nrt=False)
def tiled_collide_kernel(ctrl, ku, kv, mu, mv, pnodes, pcurv, plevels, pwork, prows, bez, grid, slack, tile_slot,
                         slot_info, tmp, cx, cy, cz, radius, hint_u, hint_v, out):
    """:func:`collide_kernel` on a tiled projector (:func:`tiled_project_kernel`)."""
    if not (radius > 0.0 and radius - radius == 0.0):
        out[OUT_STATUS] = BAD_INPUT
        return BAD_INPUT
    status = tiled_project_kernel(ctrl, ku, kv, mu, mv, pnodes, pcurv, plevels, pwork, prows, bez, grid, slack,
                                  tile_slot, slot_info, tmp, cx, cy, cz, hint_u, hint_v, out)
    out[OUT_DEPTH] = radius - out[OUT_DISTANCE]
    return status


def collide_any(proj, cx, cy, cz, radius, hint_u, hint_v, out):
    """:func:`collide_kernel` or :func:`tiled_collide_kernel`, chosen by the projector's
    ``kernel_args()`` tuple (9 arrays: one pyramid; 16: tiles); compiled into numba callers."""
    if len(proj) == 9:
        return collide_kernel(*proj, cx, cy, cz, radius, hint_u, hint_v, out)
    return tiled_collide_kernel(*proj, cx, cy, cz, radius, hint_u, hint_v, out)


@overload(collide_any, jit_options={"cache": True, "_nrt": False})
def _collide_any(proj, cx, cy, cz, radius, hint_u, hint_v, out):
    if len(proj) == 9:
        def one(proj, cx, cy, cz, radius, hint_u, hint_v, out):
            return collide_kernel(*proj, cx, cy, cz, radius, hint_u, hint_v, out)
        return one

    def tiled(proj, cx, cy, cz, radius, hint_u, hint_v, out):
        return tiled_collide_kernel(*proj, cx, cy, cz, radius, hint_u, hint_v, out)
    return tiled


def project_any(proj, cx, cy, cz, hint_u, hint_v, out):
    """:func:`project_kernel` or :func:`tiled_project_kernel`, chosen by the projector's
    ``kernel_args()`` tuple, like :func:`collide_any`."""
    if len(proj) == 9:
        return project_kernel(*proj, cx, cy, cz, hint_u, hint_v, out)
    return tiled_project_kernel(*proj, cx, cy, cz, hint_u, hint_v, out)


@overload(project_any, jit_options={"cache": True, "_nrt": False})
def _project_any(proj, cx, cy, cz, hint_u, hint_v, out):
    if len(proj) == 9:
        def one(proj, cx, cy, cz, hint_u, hint_v, out):
            return project_kernel(*proj, cx, cy, cz, hint_u, hint_v, out)
        return one

    def tiled(proj, cx, cy, cz, hint_u, hint_v, out):
        return tiled_project_kernel(*proj, cx, cy, cz, hint_u, hint_v, out)
    return tiled


@njit(cache=True)
def project_batch_kernel(proj, points, hints, chain, radius, out):
    """Many queries on a projector (its ``kernel_args()`` tuple, one pyramid or tiles):
    ``points`` (n, 3); ``hints`` (n, 2) (NaN rows = cold) or (0, 2); ``chain`` warm-starts each
    query from the previous answer (trajectories). ``radius`` > 0 fills the depth column.
    ``out`` (n, OUT_SIZE). Returns the worst (lowest) status."""
    worst = OK
    hu = np.nan
    hv = np.nan
    for k in range(points.shape[0]):
        if hints.shape[0] > 0:
            hu = hints[k, 0]
            hv = hints[k, 1]
        row = out[k]
        st = project_any(proj, points[k, 0], points[k, 1], points[k, 2], hu, hv, row)
        row[OUT_DEPTH] = radius - row[OUT_DISTANCE]
        if chain:
            if st >= 0:
                hu = row[OUT_U]
                hv = row[OUT_V]
            else:
                hu = np.nan
                hv = np.nan
        if st < 0 and st < worst:
            worst = st
    return worst
