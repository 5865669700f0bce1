r"""Tip-surface collision: the global closest point of a B-spline surface to the tip centre.

The tip is a sphere (centre C, radius R). The closest surface point minimises

.. math:: D(u, v) = \tfrac12\,|S(u, v) - C|^2, \qquad r = S - C,

.. math:: g = \begin{pmatrix} S_u\cdot r \\ S_v\cdot r \end{pmatrix}, \qquad
          H = \begin{pmatrix} S_u\cdot S_u + S_{uu}\cdot r & S_u\cdot S_v + S_{uv}\cdot r \\
                              S_u\cdot S_v + S_{uv}\cdot r & S_v\cdot S_v + S_{vv}\cdot r \end{pmatrix}

(DESIGN.md, "Closest point (Newton)"; seed 002). At the minimum :math:`r \parallel n`, the
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

Example
-------
>>> import numpy as np
>>> from arsurf.spline.surface import BSplineSurface
>>> flat = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
>>> c = collide(flat, (20e-9, 30e-9, 8e-9), radius=10e-9)
>>> round(c.depth * 1e9, 9), c.in_contact, c.normal.tolist()
(2.0, True, [0.0, 0.0, 1.0])
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, types
from numba.experimental import structref

from arsurf.contact.hull_tree import (
    HI_N, LO_N, LO_T, RHO, TREE_ID, VERSION, HullTree, box_offsets, cell_certified, cell_net, curvature_radius, extents_bounds2,
    net_curvature,
    net_extents, net_split, node_bounds2, node_distance2, signed_convex,
)
from arsurf import status
from arsurf.errors import ContactError, PositionError, SurfaceError
from arsurf.spline.basis import find_span, surface_point
from arsurf.spline.surface import BSplineSurface

# --- kernel constants ---------------------------------------------------------------------------
# layout of the output vector written by the kernels (float64, OUT_SIZE)
OUT_U, OUT_V = 0, 1
OUT_PX, OUT_PY, OUT_PZ = 2, 3, 4
OUT_NX, OUT_NY, OUT_NZ = 5, 6, 7
OUT_DISTANCE = 8      # signed distance of C, metres (> 0 above)
OUT_DEPTH = 9         # R - distance (collide only), metres
OUT_ITERATIONS = 10   # Newton iterations summed over all runs of the query
OUT_CELLS = 11        # knot cells whose hull box survived the bound (Newton-checked or skipped)
OUT_CONVERGED = 12    # 1.0 if the Newton run that produced the answer converged
OUT_BOUNDARY = 13     # 1.0 if the closest point lies on the domain boundary
OUT_STATUS = 14
OUT_CACHED = 15       # 1.0 if the warm-start candidate list was used instead of the pyramid
OUT_SIZE = 16

# status codes (returned by the kernels and stored at OUT_STATUS; the table is arsurf.status)
STATUS_OK = status.OK
STATUS_NOT_CONVERGED = status.ITERATION_LIMIT  # iteration limit hit: the answer is the best point found
STATUS_DEGENERATE = status.DEGENERATE  # S_u x S_v vanishes at the answer: normal taken along C - S (or +z)
STATUS_NON_FINITE = status.NON_FINITE  # NaN/inf met in the control net: no answer
STATUS_BAD_INPUT = status.BAD_INPUT  # non-finite query point or radius <= 0 (kernel-level check)

STATUS_TEXT = {
    STATUS_OK: "converged",
    STATUS_NOT_CONVERGED: "iteration limit reached; best point found returned",
    STATUS_DEGENERATE: "surface normal undefined (S_u x S_v = 0) at the closest point",
    STATUS_NON_FINITE: "the control net holds NaN/inf",
    STATUS_BAD_INPUT: "non-finite query point or non-positive radius",
}

# Tolerances (relative to the knot spacing h). Newton converges quadratically, so stopping on a
# step below 1e-9 h leaves a parameter error ~1e-18 h: far below the 1e-12 m distance target.
STEP_TOL = 1e-9
# Once a full, positive-definite Newton step is below QUAD_TOL h, quadratic convergence puts the
# remaining error near K QUAD_TOL^2 h (K h ~ 1e-2 on scans: ~1e-12 h, far below 1e-20 m for nm
# knots; the distance error is second order in it): stop one step early.
QUAD_TOL = 1e-5
# ... or once the free gradient components are below GRAD_TOL |r| max(|S_u|, |S_v|): rounding
# noise (~1e-16 relative), e.g. along a degenerate edge where S_v = 0
GRAD_TOL = 1e-13
# A box must beat the best squared distance by this factor to be searched: a cell that could
# only be closer by a relative 5e-13 (< 1e-20 m at nm distances) is not worth a Newton run, and
# exact ties (a flat or tilted plane, whose boxes touch the ball of radius d*) are pruned.
TIE = 1.0 - 1e-12
MAX_ITER_DOMAIN = 40   # unrestricted Newton (from the seed, and polishing a cell minimum)
MAX_ITER_CELL = 16     # Newton restricted to one knot cell
MAX_HALVINGS = 40      # backtracking line search
ARMIJO = 1e-4
# Cells whose convexity certificate fails (C farther from them than their convexity radius) are
# split into Bézier quarters, each pruned by its own box and certificate, down to this depth.
MAX_SUBDIVISION = 3
# work array rows: 0..5 the (6, 3) evaluation block; 6..8 S, S_u, S_v of the best point; 9..11
# the cache header; 12..27 a Bézier net being split; the subdivision stack (16 net rows + 2 rows
# (u0, u1, v0), (v1, depth, -) per entry); the cache list; the pyramid search stack.
# Warm queries keep the cells within d* + CACHE_MARGIN h of the tip centre in a list (at most
# CACHE_CAP cells) and reuse it while the tip stays inside that margin (project_kernel, Notes).
CACHE_MARGIN = 0.5
CACHE_CAP = 512
BEST_ROW = 6
CACHE_ROW = 9     # (version, tree id, count), (C0), (R0, -, -)
NET_TMP = 12
SUB_BASE = NET_TMP + 16
SUB_ENTRY = 18
SUB_CAP = 3 * MAX_SUBDIVISION + 1
CACHE_LIST = SUB_BASE + SUB_ENTRY * SUB_CAP   # rows (cell, distance from C0, -)
STACK_ROWS = CACHE_LIST + CACHE_CAP           # then the pyramid stack, one (level, i, j) per row


# --- Newton -------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _clip(x, lo, hi):
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@njit(cache=True)
def newton_box(ctrl, ku, kv, ev, cx, cy, cz, u, v, lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h, maxit):
    """Safeguarded projected Newton for min D(u, v) on the box [lo_u, hi_u] x [lo_v, hi_v].

    Parameters
    ----------
    ctrl, ku, kv : the surface arrays (:meth:`BSplineSurface.kernel_arrays`).
    ev : (>= 6, 3) float64 scratch; on return ``ev[:6]`` holds S and its derivatives at the answer.
    cx, cy, cz : query point, metres.
    u, v : start, metres (clipped to the box).
    tol_u, tol_v : step length below which the iteration has converged, metres.
    h : knot spacing used in the trust length 2 (|r| + h), metres.
    maxit : iteration limit.

    Returns
    -------
    (u, v, d2, iterations, converged) ; d2 = |S - C|^2 (NaN if the net holds NaN).
    """
    u = _clip(u, lo_u, hi_u)
    v = _clip(v, lo_v, hi_v)
    surface_point(ctrl, ku, kv, u, v, 2, ev)
    rx = ev[0, 0] - cx
    ry = ev[0, 1] - cy
    rz = ev[0, 2] - cz
    d2 = rx * rx + ry * ry + rz * rz
    if not (d2 - d2 == 0.0):
        return u, v, d2, 0, False
    converged = False
    it = 0
    while it < maxit:
        it += 1
        sux, suy, suz = ev[1, 0], ev[1, 1], ev[1, 2]
        svx, svy, svz = ev[2, 0], ev[2, 1], ev[2, 2]
        gu = sux * rx + suy * ry + suz * rz
        gv = svx * rx + svy * ry + svz * rz
        a = sux * sux + suy * suy + suz * suz
        b = sux * svx + suy * svy + suz * svz
        c = svx * svx + svy * svy + svz * svz
        huu = a + ev[3, 0] * rx + ev[3, 1] * ry + ev[3, 2] * rz
        huv = b + ev[4, 0] * rx + ev[4, 1] * ry + ev[4, 2] * rz
        hvv = c + ev[5, 0] * rx + ev[5, 1] * ry + ev[5, 2] * rz
        free_u = hi_u > lo_u and not ((u <= lo_u and gu > 0.0) or (u >= hi_u and gu < 0.0))
        free_v = hi_v > lo_v and not ((v <= lo_v and gv > 0.0) or (v >= hi_v and gv < 0.0))
        # stationary to rounding: the free gradient is noise next to |r| |S_u|, |r| |S_v|
        gtol = GRAD_TOL * math.sqrt(d2 * max(a, c))
        if (not free_u or abs(gu) <= gtol) and (not free_v or abs(gv) <= gtol):
            converged = True
            break
        du = 0.0
        dv = 0.0
        if free_u and free_v:
            det = huu * hvv - huv * huv
            if huu > 0.0 and det > 1e-10 * huu * hvv:
                du = (huv * gv - hvv * gu) / det
                dv = (huv * gu - huu * gv) / det
            else:
                detg = a * c - b * b
                if detg > 1e-14 * a * c:
                    du = (b * gv - c * gu) / detg
                    dv = (b * gu - a * gv) / detg
                elif a + c > 0.0:
                    du = -gu / (a + c)
                    dv = -gv / (a + c)
        elif free_u:
            if huu > 0.0:
                du = -gu / huu
            elif a > 0.0:
                du = -gu / a
        elif free_v:
            if hvv > 0.0:
                dv = -gv / hvv
            elif c > 0.0:
                dv = -gv / c
        else:  # both bounds active with outward gradients: a KKT corner
            converged = True
            break
        if du == 0.0 and dv == 0.0:
            converged = True
            break
        # trust length: the minimiser is within |r| of S in space, ~|r| + h in parameters
        cap = 2.0 * (math.sqrt(d2) + h)
        big = max(abs(du), abs(dv))
        if big > cap:
            du *= cap / big
            dv *= cap / big
        newton = free_u and free_v and huu > 0.0 and huu * hvv - huv * huv > 1e-10 * huu * hvv
        alpha = 1.0
        accepted = False
        small = False
        un = u
        vn = v
        for _ in range(MAX_HALVINGS):
            un = _clip(u + alpha * du, lo_u, hi_u)
            vn = _clip(v + alpha * dv, lo_v, hi_v)
            su = un - u
            sv = vn - v
            small = abs(su) <= tol_u and abs(sv) <= tol_v
            surface_point(ctrl, ku, kv, un, vn, 2, ev)
            qx = ev[0, 0] - cx
            qy = ev[0, 1] - cy
            qz = ev[0, 2] - cz
            d2n = qx * qx + qy * qy + qz * qz
            if d2n <= d2 + 2.0 * ARMIJO * (gu * su + gv * sv) or (small and d2n <= d2):
                accepted = True
                rx, ry, rz, d2 = qx, qy, qz, d2n
                break
            if small or not (d2n - d2n == 0.0):
                break
            alpha *= 0.5
        if not accepted:
            # no decrease even with a step below tolerance: stationary to rounding
            surface_point(ctrl, ku, kv, u, v, 2, ev)
            converged = small
            break
        u = un
        v = vn
        # a full Newton step below QUADRATIC_TOL h leaves an error ~ (QUADRATIC_TOL)^2 h
        if small or (newton and alpha == 1.0 and abs(du) <= QUAD_TOL * h and abs(dv) <= QUAD_TOL * h):
            converged = True
            break
    return u, v, d2, it, converged


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
    du = u1 - u0
    dv = v1 - v0
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
    su = 3.0 * math.sqrt(su2) / du * (1.0 + 1e-9)
    sv = 3.0 * math.sqrt(sv2) / dv * (1.0 + 1e-9)
    suu = math.sqrt(max(kuu0 * kuu0, kuu1 * kuu1) + tuu * tuu)
    svv = math.sqrt(max(kvv0 * kvv0, kvv1 * kvv1) + tvv * tvv)
    suv = math.sqrt(max(kuv0 * kuv0, kuv1 * kuv1) + tuv * tuv)
    rmax = math.sqrt(far2)
    surface_point(ctrl, ku, kv, 0.5 * (u0 + u1), 0.5 * (v0 + v1), 2, ev)
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


@njit(cache=True)
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
        kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv, sig2 = net_curvature(work[e:e + 16], u1 - u0, v1 - v0,
                                                                                nx, ny, nz)
        # unsigned radius (Gershgorin with norms) or the signed test along the cell's normal
        rho = curvature_radius(kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv, sig2)
        convex = far2 < rho * rho or signed_convex(
            kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv, sig2, lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz,
            cx, cy, cz)
        if not convex and lo_u < u0 and u1 < hi_u and lo_v < v0 and v1 < hi_v and _no_local_minimum(
                ctrl, ku, kv, ev, work, e, u0, u1, v0, v1, kuu0, kuu1, kuv0, kuv1, kvv0, kvv1, tuu, tuv, tvv,
                lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, far2, cx, cy, cz):
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
    status = STATUS_OK
    if nn > 1e-12 * scale and nn > 0.0:
        nx /= nn
        ny /= nn
        nz /= nn
        signed = dist if (wx * nx + wy * ny + wz * nz) >= 0.0 else -dist
    else:
        status = STATUS_DEGENERATE
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
        return STATUS_NON_FINITE
    return status


@njit(cache=True)
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


@njit(cache=True)
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
    """
    if not (cx - cx == 0.0 and cy - cy == 0.0 and cz - cz == 0.0):
        out[OUT_STATUS] = STATUS_BAD_INPUT
        return STATUS_BAD_INPUT
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
        build = warm and not nonfinite
        reach = d0 + CACHE_MARGIN * h if build else 0.0
        reach2 = reach * reach
        count = 0
        overflow = False
        nlev = levels.shape[0]
        cap = work.shape[0]
        sp = STACK_ROWS
        work[sp, 0] = nlev - 1
        work[sp, 1] = 0.0
        work[sp, 2] = 0.0
        sp += 1
        while sp > STACK_ROWS:
            sp -= 1
            lev = int(work[sp, 0])
            i = int(work[sp, 1])
            j = int(work[sp, 2])
            if lev == 0:
                node = i * nj0 + j
                near2, far2, lift = node_bounds2(nodes, node, cx, cy, cz)
                if build and near2 < reach2:
                    if count < CACHE_CAP:
                        work[CACHE_LIST + count, 0] = node
                        work[CACHE_LIST + count, 1] = math.sqrt(near2)
                        count += 1
                    else:
                        overflow = True
                if not (near2 < bd2 * TIE):
                    continue
                bu, bv, bd2, bconv, bi, bj, it, searched, nf = _visit_leaf(
                    ctrl, ku, kv, mu, mv, nodes, curv, nj0, work, node, near2, far2, lift, cx, cy, cz, bu, bv, bd2,
                    bconv, bi, bj, lo_u, hi_u, lo_v, hi_v, tol_u, tol_v, h)
                iters += it
                cells += searched
                nonfinite = nonfinite or nf
                continue
            if not build and bconv and (bi >> lev) == i and (bj >> lev) == j:
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
                    work[sp, 0] = clev
                    work[sp, 1] = 2 * i + (kk >> 1)
                    work[sp, 2] = 2 * j + (kk & 1)
                    sp += 1
        if build and not overflow and count > 0:
            # insertion sort of the list by distance (short lists; rebuilt every ~m/|step| ticks)
            for a in range(CACHE_LIST + 1, CACHE_LIST + count):
                kn = work[a, 0]
                kd = work[a, 1]
                b = a - 1
                while b >= CACHE_LIST and work[b, 1] > kd:
                    work[b + 1, 0] = work[b, 0]
                    work[b + 1, 1] = work[b, 1]
                    b -= 1
                work[b + 1, 0] = kn
                work[b + 1, 1] = kd
            work[CACHE_ROW, 0] = version
            work[CACHE_ROW, 1] = tree_id
            work[CACHE_ROW, 2] = count
            work[CACHE_ROW + 1, 0] = cx
            work[CACHE_ROW + 1, 1] = cy
            work[CACHE_ROW + 1, 2] = cz
            work[CACHE_ROW + 2, 0] = reach
        elif build:
            work[CACHE_ROW, 2] = 0.0
    out[OUT_ITERATIONS] = iters
    out[OUT_CELLS] = cells
    out[OUT_CACHED] = 1.0 if use_cache else 0.0
    out[OUT_CONVERGED] = 1.0 if bconv else 0.0
    out[OUT_BOUNDARY] = 1.0 if (bu <= lo_u or bu >= hi_u or bv <= lo_v or bv >= hi_v) else 0.0
    status = _finish(work[BEST_ROW:BEST_ROW + 3], cx, cy, cz, bu, bv, out)
    if nonfinite:
        status = STATUS_NON_FINITE
    elif status == STATUS_OK and not bconv:
        status = STATUS_NOT_CONVERGED
    out[OUT_STATUS] = status
    return status


@njit(cache=True)
def collide_kernel(ctrl, ku, kv, mu, mv, nodes, curv, levels, work, cx, cy, cz, radius, hint_u, hint_v, out):
    """Tip sphere (centre, radius) against the surface: :func:`project_kernel` plus the depth.

    Writes ``out[OUT_DEPTH] = radius - out[OUT_DISTANCE]`` (> 0: penetration). Returns the status
    (``STATUS_BAD_INPUT`` for a non-finite centre or radius <= 0). For the haptic-loop kernel:
    call it with the arrays of :meth:`Projector.kernel_args` and the last ``out[OUT_U]``,
    ``out[OUT_V]`` as the hint.
    """
    if not (radius > 0.0 and radius - radius == 0.0):
        out[OUT_STATUS] = STATUS_BAD_INPUT
        return STATUS_BAD_INPUT
    status = project_kernel(ctrl, ku, kv, mu, mv, nodes, curv, levels, work, cx, cy, cz, hint_u, hint_v, out)
    out[OUT_DEPTH] = radius - out[OUT_DISTANCE]
    return status


@njit(cache=True)
def project_batch_kernel(ctrl, ku, kv, mu, mv, nodes, curv, levels, work, points, hints, chain, radius, out):
    """Many queries: ``points`` (n, 3); ``hints`` (n, 2) (NaN rows = cold) or (0, 2);
    ``chain`` warm-starts each query from the previous answer (trajectories). ``radius`` > 0
    fills the depth column. ``out`` (n, OUT_SIZE). Returns the worst (lowest) status."""
    worst = STATUS_OK
    hu = np.nan
    hv = np.nan
    for k in range(points.shape[0]):
        if hints.shape[0] > 0:
            hu = hints[k, 0]
            hv = hints[k, 1]
        row = out[k]
        st = project_kernel(ctrl, ku, kv, mu, mv, nodes, curv, levels, work, points[k, 0], points[k, 1], points[k, 2],
                            hu, hv, row)
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


# --- the single-query entries of the Python API --------------------------------------------------
@structref.register
class _KernelArraysType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class KernelArrays(structref.StructRefProxy):
    """The nine arrays of :meth:`Projector.kernel_args` and an ``out`` scratch as one numba struct:
    a Python call passes one reference instead of ten arrays (~85 ns of unboxing each)."""


structref.define_proxy(KernelArrays, _KernelArraysType,
                       ["ctrl", "ku", "kv", "mu", "mv", "nodes", "curv", "levels", "work", "out"])


@njit(cache=True)
def _project_packed(a, cx, cy, cz, hint_u, hint_v, warm, point_normal):
    """:func:`project_kernel` for :func:`project`: ``point_normal`` (6,) gets S* and n*; returns
    ``((u, v), distance, converged, iterations, on_boundary, status, cells)``, the remaining
    fields of :class:`Projection` in order. ``warm``: a hint was given, and it must be finite."""
    out = a.out
    if warm and not (hint_u - hint_u == 0.0 and hint_v - hint_v == 0.0):
        status = STATUS_BAD_INPUT
    else:
        status = project_kernel(a.ctrl, a.ku, a.kv, a.mu, a.mv, a.nodes, a.curv, a.levels, a.work,
                                cx, cy, cz, hint_u if warm else np.nan, hint_v if warm else np.nan, out)
    for k in range(6):
        point_normal[k] = out[OUT_PX + k]
    return ((out[OUT_U], out[OUT_V]), out[OUT_DISTANCE], out[OUT_CONVERGED] > 0.0, int(out[OUT_ITERATIONS]),
            out[OUT_BOUNDARY] > 0.0, status, int(out[OUT_CELLS]))


@njit(cache=True)
def _collide_packed(a, cx, cy, cz, radius, hint_u, hint_v, warm, point_normal):
    """:func:`collide_kernel` for :func:`collide`, like :func:`_project_packed`; returns
    ``((u, v), depth, in_contact, distance, radius, converged, iterations, on_boundary, status,
    cells)``, the fields of :class:`Contact` after ``point`` and ``normal``."""
    out = a.out
    if warm and not (hint_u - hint_u == 0.0 and hint_v - hint_v == 0.0):
        status = STATUS_BAD_INPUT
    else:
        status = collide_kernel(a.ctrl, a.ku, a.kv, a.mu, a.mv, a.nodes, a.curv, a.levels, a.work,
                                cx, cy, cz, radius, hint_u if warm else np.nan, hint_v if warm else np.nan, out)
    for k in range(6):
        point_normal[k] = out[OUT_PX + k]
    depth = out[OUT_DEPTH]
    return ((out[OUT_U], out[OUT_V]), depth, depth > 0.0, out[OUT_DISTANCE], radius, out[OUT_CONVERGED] > 0.0,
            int(out[OUT_ITERATIONS]), out[OUT_BOUNDARY] > 0.0, status, int(out[OUT_CELLS]))


# --- Python side --------------------------------------------------------------------------------
class Projection(NamedTuple):
    """Closest point of a surface to a query point.

    Attributes
    ----------
    uv : (u, v) tuple of floats, metres — surface parameters of the closest point (the next
        query's ``hint``).
    point : (3,) float64, metres — the closest surface point S(u, v).
    normal : (3,) float64 — unit normal there, out of the sample (orientation of S_u x S_v).
    distance : float, metres — signed distance of the query point (> 0 above the surface).
    converged : bool — the Newton run that produced the answer met the step tolerance.
    iterations : int — Newton iterations over all runs of this query.
    on_boundary : bool — the closest point lies on the edge of the parameter domain.
    status : int — ``STATUS_*`` code (0 ok, 1 not converged, 2 degenerate normal).
    cells : int — knot cells whose hull box survived the distance bound.
    """

    uv: tuple
    point: np.ndarray
    normal: np.ndarray
    distance: float
    converged: bool
    iterations: int
    on_boundary: bool
    status: int
    cells: int


class Contact(NamedTuple):
    """Tip sphere against the surface.

    Attributes
    ----------
    point, normal, uv : as in :class:`Projection`.
    depth : float, metres — indentation R - distance (> 0: the sphere penetrates).
    in_contact : bool — depth > 0.
    distance : float, metres — signed distance of the centre.
    radius : float, metres — the tip radius used.
    converged, iterations, on_boundary, status, cells : as in :class:`Projection`.
    """

    point: np.ndarray
    normal: np.ndarray
    uv: tuple
    depth: float
    in_contact: bool
    distance: float
    radius: float
    converged: bool
    iterations: int
    on_boundary: bool
    status: int
    cells: int


class ProjectionBatch(NamedTuple):
    """Closest points of many query points (arrays over the n queries; fields of :class:`Projection`)."""

    uv: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    distance: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    on_boundary: np.ndarray
    status: np.ndarray
    cells: np.ndarray


class ContactBatch(NamedTuple):
    """Contacts of many tip positions (arrays over the n queries; fields of :class:`Contact`)."""

    point: np.ndarray
    normal: np.ndarray
    uv: np.ndarray
    depth: np.ndarray
    in_contact: np.ndarray
    distance: np.ndarray
    radius: float
    converged: np.ndarray
    iterations: np.ndarray
    on_boundary: np.ndarray
    status: np.ndarray
    cells: np.ndarray


class Projector:
    """Per-surface state of the projection: the hull-box pyramid and the kernel workspace.

    Created once per surface by :func:`projector` (kept on the surface as an instance attribute,
    built lazily at the first query, O(N)). When control points move, call :meth:`refresh_region` with the index range
    that moved (O(patch)); after :meth:`BSplineSurface.reset` call :meth:`refresh`.
    The workspace makes a projector single-threaded: use one per thread.

    Example
    -------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> p = projector(s)
    >>> out = np.empty(OUT_SIZE)
    >>> collide_kernel(*p.kernel_args(), 25e-9, 25e-9, 5e-9, 10e-9, np.nan, np.nan, out)
    0
    >>> round(float(out[OUT_DEPTH]) * 1e9, 9)
    5.0
    """

    def __init__(self, surface):
        ctrl, _, ku, kv = surface.kernel_arrays()
        if not np.isfinite(ctrl).all():
            raise SurfaceError(
                f"the surface has {int((~np.isfinite(ctrl)).any(axis=2).sum())} non-finite (NaN/inf) control "
                "points; refit from a scan without NaN (arsurf.inpaint) or reset() the surface"
            )
        self.ctrl = ctrl
        self.ku = ku
        self.kv = kv
        self.tree = HullTree(ctrl, ku, kv)
        self.work = np.zeros((STACK_ROWS + 4 * self.tree.levels.shape[0] + 8, 3))
        self.work[CACHE_ROW, 0] = -1.0  # no candidate list yet
        self._args = (self.ctrl, self.ku, self.kv, self.tree.mu, self.tree.mv, self.tree.nodes, self.tree.curv,
                      self.tree.levels, self.work)
        self._packed = KernelArrays(*self._args, np.empty(OUT_SIZE))
        self._project = _entry_point(_project_packed, self._packed, 5)
        self._collide = _entry_point(_collide_packed, self._packed, 6)

    def __reduce__(self):
        # a pickled or deep-copied surface drops its projector (compiled entry points do not
        # pickle): the copy builds its own at its first query
        return _no_projector, ()

    def kernel_args(self) -> tuple:
        """``(ctrl, ku, kv, mu, mv, nodes, curv, levels, work)``: the leading arguments of the kernels
        (:func:`collide_kernel`, :func:`project_kernel`, :func:`project_batch_kernel`)."""
        return self._args

    def refresh_region(self, iu0: int, iu1: int, iv0: int, iv1: int) -> None:
        """Update after control points ``ctrl[iu0:iu1, iv0:iv1]`` (half-open) moved; O(patch).

        Numba callers use :func:`arsurf.contact.hull_tree.refresh_region_kernel` with
        ``(ctrl, tree.mu, tree.mv, tree.boxes, tree.levels, tree.rows, iu0, iu1, iv0, iv1)``.
        """
        self.tree.refresh_region(iu0, iu1, iv0, iv1)

    def refresh(self) -> None:
        """Rebuild everything from the current net, O(N) (after ``surface.reset()``)."""
        self.tree.refresh()


def _entry_point(kernel, arrays, nscalars):
    """The compiled entry of ``kernel(arrays, *scalars, warm, point_normal)`` for exactly these
    argument types.

    Calling it skips the dispatcher's per-call type resolution (~0.3-1 us of a few-us call);
    the Python API always passes these same types. Falls back to the dispatcher."""
    args = (arrays, *(1.0,) * nscalars, False, np.empty(6))
    kernel(*args)  # compiles (or loads from the cache) this signature
    try:
        sig = tuple(numba.typeof(a) for a in args)
        return kernel.overloads[sig].entry_point
    except (KeyError, AttributeError):  # pragma: no cover - numba internals changed
        return kernel


_ATTR = "_arsurf_projector"  # where a surface keeps its Projector (an instance attribute)


def _no_projector() -> None:
    """What an unpickled projector becomes (see :meth:`Projector.__reduce__`)."""
    return None


def projector(surface) -> Projector:
    """The :class:`Projector` of ``surface`` (built at the first call, then cached per surface)."""
    if not isinstance(surface, BSplineSurface):
        raise SurfaceError(f"expected an arsurf BSplineSurface (got {type(surface).__name__})")
    proj = surface.__dict__.get(_ATTR)
    if proj is None or proj.ctrl is not surface.kernel_arrays()[0]:
        proj = Projector(surface)
        setattr(surface, _ATTR, proj)
        surface.attach(proj)  # reset() refreshes the boxes
    return proj


def _lookup(surface) -> Projector:
    proj = getattr(surface, _ATTR, None)
    return proj if proj is not None else projector(surface)


def refresh_region(surface, iu0: int, iu1: int, iv0: int, iv1: int) -> None:
    """Tell the projection that control points ``[iu0:iu1, iv0:iv1]`` of ``surface`` moved (O(patch))."""
    if not isinstance(surface, BSplineSurface):
        raise SurfaceError(f"expected an arsurf BSplineSurface (got {type(surface).__name__})")
    proj = getattr(surface, _ATTR, None)
    if proj is not None:  # else no projector yet: it will be built from the current net
        proj.refresh_region(iu0, iu1, iv0, iv1)


_new_tuple = tuple.__new__  # builds a NamedTuple from a tuple without its keyword-parsing __new__


def _single(entry, packed, point_normal, point, hint, radius=None) -> tuple:
    """Run one query through ``entry`` (:func:`_project_packed` or :func:`_collide_packed`).

    The fast path hands the caller's numbers straight to the compiled entry (it converts them
    like ``float()``, and rejects a non-finite point, hint or radius with ``STATUS_BAD_INPUT``).
    Anything unusual takes the slow path: the exact checks, with the precise error."""
    try:
        x, y, z = point
        if hint is None:
            res = (entry(packed, x, y, z, 0.0, 0.0, False, point_normal) if radius is None else
                   entry(packed, x, y, z, radius, 0.0, 0.0, False, point_normal))
        else:
            hu, hv = hint
            res = (entry(packed, x, y, z, hu, hv, True, point_normal) if radius is None else
                   entry(packed, x, y, z, radius, hu, hv, True, point_normal))
        if res[-2] >= 0:
            return res
    except (TypeError, ValueError):
        pass
    x, y, z = _xyz(point, "point" if radius is None else "center")
    hu, hv = _hint(hint)
    res = (entry(packed, x, y, z, hu, hv, hint is not None, point_normal) if radius is None else
           entry(packed, x, y, z, _radius(radius), hu, hv, hint is not None, point_normal))
    if res[-2] < 0:
        _raise_status(res[-2], "project" if radius is None else "collide")
    return res


def _xyz(point, what: str) -> tuple[float, float, float]:
    try:
        x, y, z = point
        x, y, z = float(x), float(y), float(z)
    except (TypeError, ValueError):
        raise PositionError(f"{what} must be 3 coordinates (x, y, z) in metres (got {point!r})") from None
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise PositionError(f"{what} must be finite (got ({x!r}, {y!r}, {z!r})); check the tip position source")
    return x, y, z


def _hint(hint) -> tuple[float, float]:
    if hint is None:
        return math.nan, math.nan
    try:
        hu, hv = hint
        hu, hv = float(hu), float(hv)
    except (TypeError, ValueError):
        raise SurfaceError(f"hint must be None or (u, v) in metres (got {hint!r})") from None
    if not (math.isfinite(hu) and math.isfinite(hv)):
        raise SurfaceError(f"hint must be finite (got ({hu!r}, {hv!r})); pass None for a cold start")
    return hu, hv


def _radius(radius) -> float:
    try:
        r = float(radius)
    except (TypeError, ValueError):
        raise ContactError(f"radius must be a number in metres (got {radius!r})") from None
    if not (math.isfinite(r) and r > 0.0):
        raise ContactError(f"the tip radius must be positive and finite (got {r!r} m); it is the sphere radius R")
    return r


def _raise_status(status: int, where: str) -> None:
    if status == STATUS_NON_FINITE:
        raise SurfaceError(
            f"{where}: the surface has non-finite (NaN/inf) control points; refit from a scan without "
            "NaN (arsurf.inpaint) or reset() the surface"
        )
    raise SurfaceError(f"{where}: {STATUS_TEXT.get(status, 'unknown status')} (status {status})")


def project(surface, point, hint=None) -> Projection:
    """Global closest point of ``surface`` to ``point`` (safeguarded Newton, certified by hull bounds).

    .. math:: (u^*, v^*) = \\arg\\min_{(u, v)} \\tfrac12 |S(u, v) - C|^2

    Parameters
    ----------
    surface : BSplineSurface
    point : (3,) float, metres
        Query point C.
    hint : (u, v) float, metres, optional
        Warm start, e.g. the previous tick's ``uv``. It only speeds the search up: a closer
        basin elsewhere is still found.

    Returns
    -------
    Projection

    Raises
    ------
    SurfaceError
        Non-finite point or hint, or a surface with NaN/inf control points.

    Example
    -------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> p = project(s, (10e-9, 20e-9, -3e-9))
    >>> round(p.distance * 1e9, 9), (p.point * 1e9).round(9).tolist()
    (-3.0, [10.0, 20.0, 0.0])
    """
    proj = getattr(surface, _ATTR, None) or _lookup(surface)
    pn = np.empty(6)  # S* and n*: two views of one fresh array (slicing a (6,) array is the cheapest)
    res = _single(proj._project, proj._packed, pn, point, hint)
    return _new_tuple(Projection, (res[0], pn[:3], pn[3:]) + res[1:])


def collide(surface, center, radius, hint=None) -> Contact:
    """Contact of a tip sphere (centre C, radius R) with ``surface``.

    .. math:: \\delta = R - d(C), \\qquad d(C) = (C - S^*)\\cdot n^*

    Parameters
    ----------
    surface : BSplineSurface
    center : (3,) float, metres
    radius : float, metres (> 0)
    hint : (u, v) float, metres, optional — warm start (previous ``uv``).

    Returns
    -------
    Contact

    Raises
    ------
    SurfaceError, ContactError
        Non-finite centre or hint, NaN control points (SurfaceError); radius <= 0 (ContactError).

    Example
    -------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> c = collide(s, (10e-9, 20e-9, 4e-9), 5e-9)
    >>> c.in_contact, round(c.depth * 1e9, 9)
    (True, 1.0)
    """
    proj = getattr(surface, _ATTR, None) or _lookup(surface)
    pn = np.empty(6)  # S* and n*: two views of one fresh array (slicing a (6,) array is the cheapest)
    res = _single(proj._collide, proj._packed, pn, center, hint, radius)
    return _new_tuple(Contact, (pn[:3], pn[3:]) + res)


def _batch(surface, points, hints, chain, radius, where):
    proj = _lookup(surface)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim == 1 and pts.size == 3:
        pts = pts.reshape(1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise SurfaceError(f"points must have shape (n, 3) in metres (got {np.shape(points)})")
    if not np.isfinite(pts).all():
        bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
        raise PositionError(f"points must be finite: {bad.size} rows hold NaN/inf (first: row {bad[0]})")
    if hints is None:
        hts = np.empty((0, 2))
    else:
        hts = np.ascontiguousarray(hints, dtype=np.float64)
        if hts.shape != (pts.shape[0], 2):
            raise SurfaceError(f"hints must have shape ({pts.shape[0]}, 2) (got {hts.shape}); NaN rows mean cold")
    out = np.empty((pts.shape[0], OUT_SIZE))
    worst = project_batch_kernel(*proj._args, pts, hts, bool(chain), radius, out)
    if worst < 0:
        _raise_status(int(worst), where)
    return out


def project_many(surface, points, hints=None, chain: bool = False) -> ProjectionBatch:
    """:func:`project` for an (n, 3) array of points, in one kernel call.

    Parameters
    ----------
    points : (n, 3) float, metres
    hints : (n, 2) float, metres, optional
        Per-query warm starts (NaN rows: cold).
    chain : bool
        Warm-start each query from the previous answer (a trajectory, as in replay).

    Example
    -------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> b = project_many(s, [[10e-9, 10e-9, 1e-9], [20e-9, 20e-9, 2e-9]])
    >>> (b.distance * 1e9).round(9).tolist()
    [1.0, 2.0]
    """
    out = _batch(surface, points, hints, chain, 0.0, "project_many")
    return ProjectionBatch(out[:, 0:2], out[:, 2:5], out[:, 5:8], out[:, OUT_DISTANCE].copy(),
                           out[:, OUT_CONVERGED] > 0, out[:, OUT_ITERATIONS].astype(np.int64),
                           out[:, OUT_BOUNDARY] > 0, out[:, OUT_STATUS].astype(np.int64),
                           out[:, OUT_CELLS].astype(np.int64))


def collide_many(surface, centers, radius, hints=None, chain: bool = False) -> ContactBatch:
    """:func:`collide` for an (n, 3) array of tip centres with one radius, in one kernel call.

    Example
    -------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> b = collide_many(s, [[10e-9, 10e-9, 1e-9], [20e-9, 20e-9, 9e-9]], radius=5e-9)
    >>> b.in_contact.tolist()
    [True, False]
    """
    r = _radius(radius)
    out = _batch(surface, centers, hints, chain, r, "collide_many")
    depth = out[:, OUT_DEPTH].copy()
    return ContactBatch(out[:, 2:5], out[:, 5:8], out[:, 0:2], depth, depth > 0.0, out[:, OUT_DISTANCE].copy(), r,
                        out[:, OUT_CONVERGED] > 0, out[:, OUT_ITERATIONS].astype(np.int64),
                        out[:, OUT_BOUNDARY] > 0, out[:, OUT_STATUS].astype(np.int64),
                        out[:, OUT_CELLS].astype(np.int64))
