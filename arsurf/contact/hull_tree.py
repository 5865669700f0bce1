r"""Candidate search for the closest point: a pyramid of oriented hull boxes over the knot cells.

Every knot cell (span pair) of a bicubic B-spline surface is a bicubic Bézier patch whose 16
Bézier control points :math:`B_{kl}` contain the patch in their convex hull. Each cell gets an
*oriented* bounding box (OBB) of those 16 points, in the frame of the patch: normal
:math:`n \propto T_u \times T_v` from the mean tangents of the Bézier net, :math:`t` along
:math:`T_u`, :math:`s = n \times t`. Each level above merges 2x2 children into one OBB (frame:
mean of the children's normals). Since the patch lies inside its box, the distance from a query
point C to the box bounds the distance to every surface point of the cell from below:

.. math:: \operatorname{dist}(C, S(\text{cell}))^2 \;\ge\; \sum_{e \in \{t, s, n\}}
          \operatorname{dist}\big(e\cdot C,\; [lo_e, hi_e]\big)^2 .

Any evaluated surface point bounds the closest distance from above, so only cells whose box is
nearer than the best distance found so far can hold the global minimum
(:mod:`arsurf.contact.closest_point` walks the pyramid nearest-first and runs Newton in them).

Why oriented boxes of Bézier points: a cell's 4x4 B-spline points span three knot intervals
sideways, its Bézier points only the cell, so hulls are ~3x tighter; and an axis-aligned box
of a sloped patch is as thick as slope x cell, while the oriented box is as thick as the patch's
deviation from its plane (~curvature x cell²/8). Over a sloped surface the axis-aligned boxes
of the cells around the foot point all reach into the ball of radius d* and each would cost a
Newton run; the oriented ones stay outside it. The B-spline-to-Bézier conversion of span
:math:`[t_i, t_{i+1}]` (width h) follows from the end values and slopes of the four basis
functions, :math:`b_0 = f(t_i)`, :math:`b_1 = f(t_i) + \tfrac{h}{3} f'(t_i)`,
:math:`b_2 = f(t_{i+1}) - \tfrac{h}{3} f'(t_{i+1})`, :math:`b_3 = f(t_{i+1})`, so the patch's
Bézier net is :math:`B = M_u P M_v^T` per coordinate (Farin, *Curves and Surfaces for CAGD*,
5th ed., §6.4; Piegl & Tiller, *The NURBS Book*, §5.6). OBB-trees: Gottschalk, Lin & Manocha,
SIGGRAPH 1996.

Locality: moving control points ``P[iu0:iu1, iv0:iv1]`` changes only the cells
``[iu0-3, iu1) x [iv0-3, iv1)`` and their ancestors; :meth:`HullTree.refresh_region` (and the
kernel :func:`refresh_region_kernel` for numba callers) recomputes exactly those, O(patch + log N).

Memory: 13 float64 per node (~17.3 per cell with the upper levels) and 10 float32 per cell:
~185 MB for a 1024x1024 scan.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf._layout import Layout
from arsurf.errors import SurfaceError
from arsurf.spline.basis import cubic_basis

#: columns of a node row: normal n, tangent t, the intervals (lo, hi) along t, s = n x t and n,
#: and the convexity radius (D is convex on the node's patches for every C within it of all of it)
NODE_COLUMNS = Layout("hull node columns", [("normal", 3), ("tangent", 3), ("t_interval", 2), ("s_interval", 2),
                                            ("n_interval", 2), ("convexity_radius", 1)])
N0, T0 = NODE_COLUMNS.offset("normal"), NODE_COLUMNS.offset("tangent")
N1, N2, T1, T2 = N0 + 1, N0 + 2, T0 + 1, T0 + 2
LO_T, LO_S = NODE_COLUMNS.offset("t_interval"), NODE_COLUMNS.offset("s_interval")
LO_N = NODE_COLUMNS.offset("n_interval")
HI_T, HI_S, HI_N = LO_T + 1, LO_S + 1, LO_N + 1
RHO = NODE_COLUMNS.offset("convexity_radius")
NODE_SIZE = NODE_COLUMNS.size
# the row after the last node holds (version, tree id): every refresh bumps the version, so a
# query's cached candidate list (arsurf.contact.closest_point) knows when the boxes changed
TREE_HEADER = Layout("hull tree header row", [("version", 1), ("tree_id", 1)])
VERSION, TREE_ID = TREE_HEADER.offset("version"), TREE_HEADER.offset("tree_id")
_TREE_IDS = iter(range(1, 2**52))


@njit(cache=True)
def bezier_matrices(knots):
    """Per-span B-spline-to-Bézier matrices ``M[s, k, m]`` (span s, Bézier index k, basis m).

    For span s (knot interval ``[t[s+3], t[s+4]]``) the Bézier ordinates of the curve
    :math:`\\sum_m N_{s+m} P_{s+m}` are :math:`b_k = \\sum_m M[s, k, m] P_{s+m}`.
    """
    n = knots.size - 4
    nspan = n - 3
    out = np.empty((nspan, 4, 4))
    for s in range(nspan):
        i = s + 3
        h3 = (knots[i + 1] - knots[i]) / 3.0
        left = cubic_basis(knots, i, knots[i])
        right = cubic_basis(knots, i, knots[i + 1])  # span-i polynomial at its right end
        for m in range(4):
            out[s, 0, m] = left[m]
            out[s, 1, m] = left[m] + h3 * left[4 + m]
            out[s, 2, m] = right[m] - h3 * right[4 + m]
            out[s, 3, m] = right[m]
    return out


def pyramid_levels(ni: int, nj: int) -> np.ndarray:
    """Level table (L, 3) int64 rows (offset, ni, nj): level 0 = the cells, each level halves."""
    rows = []
    offset = 0
    while True:
        rows.append((offset, ni, nj))
        offset += ni * nj
        if ni == 1 and nj == 1:
            break
        ni = (ni + 1) // 2
        nj = (nj + 1) // 2
    return np.array(rows, dtype=np.int64)


@njit(cache=True, inline="always")
def _frame(nodes, node, nx, ny, nz, tx, ty, tz):
    """Store a right-handed orthonormal frame (n, t) from an approximate normal and tangent.

    Falls back to the coordinate axes when they are degenerate or not finite."""
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    ok = nn > 0.0 and nn - nn == 0.0
    if ok:
        nx /= nn
        ny /= nn
        nz /= nn
        dot = tx * nx + ty * ny + tz * nz
        tx -= dot * nx
        ty -= dot * ny
        tz -= dot * nz
        tn = math.sqrt(tx * tx + ty * ty + tz * tz)
        if tn > 1e-6 * math.sqrt(1.0 + dot * dot) and tn - tn == 0.0:
            tx /= tn
            ty /= tn
            tz /= tn
        else:  # any unit vector orthogonal to n
            if abs(nx) < 0.9:
                tx, ty, tz = 1.0 - nx * nx, -nx * ny, -nx * nz
            else:
                tx, ty, tz = -ny * nx, 1.0 - ny * ny, -ny * nz
            tn = math.sqrt(tx * tx + ty * ty + tz * tz)
            tx /= tn
            ty /= tn
            tz /= tn
    else:
        nx, ny, nz, tx, ty, tz = 0.0, 0.0, 1.0, 1.0, 0.0, 0.0
    nodes[node, N0] = nx
    nodes[node, N1] = ny
    nodes[node, N2] = nz
    nodes[node, T0] = tx
    nodes[node, T1] = ty
    nodes[node, T2] = tz


@njit(cache=True, inline="always")
def _axes(nodes, node):
    """(n, t, s) of a node as 9 scalars, s = n x t."""
    nx, ny, nz = nodes[node, N0], nodes[node, N1], nodes[node, N2]
    tx, ty, tz = nodes[node, T0], nodes[node, T1], nodes[node, T2]
    return nx, ny, nz, tx, ty, tz, ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx


@njit(cache=True)
def cell_net(ctrl, mu, mv, a, b, net):
    """Bézier net of knot cell (a, b) into ``net`` (16, 3), row k*4 + m (k along u, m along v)."""
    for k in range(4):
        for c in range(3):
            q0 = mu[a, k, 0] * ctrl[a, b, c] + mu[a, k, 1] * ctrl[a + 1, b, c] + mu[a, k, 2] * ctrl[a + 2, b, c] \
                + mu[a, k, 3] * ctrl[a + 3, b, c]
            q1 = mu[a, k, 0] * ctrl[a, b + 1, c] + mu[a, k, 1] * ctrl[a + 1, b + 1, c] \
                + mu[a, k, 2] * ctrl[a + 2, b + 1, c] + mu[a, k, 3] * ctrl[a + 3, b + 1, c]
            q2 = mu[a, k, 0] * ctrl[a, b + 2, c] + mu[a, k, 1] * ctrl[a + 1, b + 2, c] \
                + mu[a, k, 2] * ctrl[a + 2, b + 2, c] + mu[a, k, 3] * ctrl[a + 3, b + 2, c]
            q3 = mu[a, k, 0] * ctrl[a, b + 3, c] + mu[a, k, 1] * ctrl[a + 1, b + 3, c] \
                + mu[a, k, 2] * ctrl[a + 2, b + 3, c] + mu[a, k, 3] * ctrl[a + 3, b + 3, c]
            for m in range(4):
                net[k * 4 + m, c] = mv[b, m, 0] * q0 + mv[b, m, 1] * q1 + mv[b, m, 2] * q2 + mv[b, m, 3] * q3


@njit(cache=True)
def net_sigma(net, hu, hv):
    """Lower bound σ_lb of the smallest singular value of J = [S_u S_v] over a Bézier patch.

    Weyl's inequality about the mean tangents: σ_min(J(x)) ≥ σ_min(J̄) - ||J(x) - J̄||_F, the
    spread bounded by the Bézier nets of S_u and S_v (convex hull); computed for J and for its
    x-y block (J^TJ ⪰ J_xy^T J_xy; on an undeformed surface J_xy = I exactly), the larger kept.
    ``net`` (16, 3) spans a (hu, hv) parameter rectangle. Returns 0 when no bound > 0 exists.
    """
    mux = muy = muz = mvx = mvy = mvz = 0.0
    for k in range(3):
        for m in range(4):
            mux += net[(k + 1) * 4 + m, 0] - net[k * 4 + m, 0]
            muy += net[(k + 1) * 4 + m, 1] - net[k * 4 + m, 1]
            muz += net[(k + 1) * 4 + m, 2] - net[k * 4 + m, 2]
            mvx += net[m * 4 + k + 1, 0] - net[m * 4 + k, 0]
            mvy += net[m * 4 + k + 1, 1] - net[m * 4 + k, 1]
            mvz += net[m * 4 + k + 1, 2] - net[m * 4 + k, 2]
    su = 3.0 / (12.0 * hu)
    sv = 3.0 / (12.0 * hv)
    mux *= su
    muy *= su
    muz *= su
    mvx *= sv
    mvy *= sv
    mvz *= sv
    spu3 = spu2 = spv3 = spv2 = 0.0
    for k in range(3):
        for m in range(4):
            dx = 3.0 * (net[(k + 1) * 4 + m, 0] - net[k * 4 + m, 0]) / hu - mux
            dy = 3.0 * (net[(k + 1) * 4 + m, 1] - net[k * 4 + m, 1]) / hu - muy
            dz = 3.0 * (net[(k + 1) * 4 + m, 2] - net[k * 4 + m, 2]) / hu - muz
            spu2 = max(spu2, dx * dx + dy * dy)
            spu3 = max(spu3, dx * dx + dy * dy + dz * dz)
            dx = 3.0 * (net[m * 4 + k + 1, 0] - net[m * 4 + k, 0]) / hv - mvx
            dy = 3.0 * (net[m * 4 + k + 1, 1] - net[m * 4 + k, 1]) / hv - mvy
            dz = 3.0 * (net[m * 4 + k + 1, 2] - net[m * 4 + k, 2]) / hv - mvz
            spv2 = max(spv2, dx * dx + dy * dy)
            spv3 = max(spv3, dx * dx + dy * dy + dz * dz)
    # smallest singular value of the mean Jacobian (2x2 Gram eigenvalue), minus the spread
    a = mux * mux + muy * muy + muz * muz
    b = mux * mvx + muy * mvy + muz * mvz
    c = mvx * mvx + mvy * mvy + mvz * mvz
    lam = 0.5 * (a + c) - math.sqrt(0.25 * (a - c) * (a - c) + b * b)
    s3 = math.sqrt(max(lam, 0.0)) - math.sqrt(spu3 + spv3)
    a = mux * mux + muy * muy
    b = mux * mvx + muy * mvy
    c = mvx * mvx + mvy * mvy
    lam = 0.5 * (a + c) - math.sqrt(0.25 * (a - c) * (a - c) + b * b)
    s2 = math.sqrt(max(lam, 0.0)) - math.sqrt(spu2 + spv2)
    sig = max(s2, s3)
    # a relative margin of 1e-9 covers the rounding in the differences above
    return sig * (1.0 - 1e-9) if sig > 0.0 else 0.0


@njit(cache=True, inline="always")
def _fold(lo, hi, t2max, nx, ny, nz, x, y, z):
    """Running (min, max) of n·w and max |w - (n·w) n|² over the points w of a derivative net."""
    p = nx * x + ny * y + nz * z
    qx = x - p * nx
    qy = y - p * ny
    qz = z - p * nz
    return min(lo, p), max(hi, p), max(t2max, qx * qx + qy * qy + qz * qz)


@njit(cache=True)
def net_curvature(net, hu, hv, nx, ny, nz):
    """Signed curvature bounds of a patch along a unit direction n (the box normal).

    Returns ``(kuu_lo, kuu_hi, kuv_lo, kuv_hi, kvv_lo, kvv_hi, tuu, tuv, tvv, sigma2)``: the
    ranges of n·S_uu, n·S_uv, n·S_vv, bounds of the norms of their parts orthogonal to n, and
    σ_lb² (:func:`net_sigma`). With r = S - C = α n + r_⊥,

    .. math:: r\\cdot S_{uu} \\ge \\min(\\alpha\\,[k_{uu}]) - |r_\\perp|\\, t_{uu}, \\quad
              \\lambda_{min}(H) \\ge \\sigma_{lb}^2 + \\lambda_{min}\\begin{pmatrix} M_{11}^- & |M_{12}|^+ \\\\
              |M_{12}|^+ & M_{22}^- \\end{pmatrix}

    (:func:`signed_convex`): far above a cap (α < 0, n·S_uu < 0) D stays convex however far C
    is, where the unsigned radius of :func:`curvature_radius` gives up.
    """
    kuu_lo = kuv_lo = kvv_lo = np.inf
    kuu_hi = kuv_hi = kvv_hi = -np.inf
    tuu = tuv = tvv = 0.0
    for k in range(2):
        for m in range(4):
            i0 = k * 4 + m
            kuu_lo, kuu_hi, tuu = _fold(
                kuu_lo, kuu_hi, tuu, nx, ny, nz,
                net[i0 + 8, 0] - 2.0 * net[i0 + 4, 0] + net[i0, 0],
                net[i0 + 8, 1] - 2.0 * net[i0 + 4, 1] + net[i0, 1],
                net[i0 + 8, 2] - 2.0 * net[i0 + 4, 2] + net[i0, 2])
    for k in range(4):
        for m in range(2):
            i0 = k * 4 + m
            kvv_lo, kvv_hi, tvv = _fold(
                kvv_lo, kvv_hi, tvv, nx, ny, nz,
                net[i0 + 2, 0] - 2.0 * net[i0 + 1, 0] + net[i0, 0],
                net[i0 + 2, 1] - 2.0 * net[i0 + 1, 1] + net[i0, 1],
                net[i0 + 2, 2] - 2.0 * net[i0 + 1, 2] + net[i0, 2])
    for k in range(3):
        for m in range(3):
            i0 = k * 4 + m
            kuv_lo, kuv_hi, tuv = _fold(
                kuv_lo, kuv_hi, tuv, nx, ny, nz,
                net[i0 + 5, 0] - net[i0 + 4, 0] - net[i0 + 1, 0] + net[i0, 0],
                net[i0 + 5, 1] - net[i0 + 4, 1] - net[i0 + 1, 1] + net[i0, 1],
                net[i0 + 5, 2] - net[i0 + 4, 2] - net[i0 + 1, 2] + net[i0, 2])
    fuu = 6.0 / (hu * hu)
    fvv = 6.0 / (hv * hv)
    fuv = 9.0 / (hu * hv)
    sig = net_sigma(net, hu, hv)
    # widen by a relative 1e-9 for the rounding of the differences and products above
    lo = 1.0 - 1e-9
    hi = 1.0 + 1e-9
    return (min(kuu_lo * lo, kuu_lo * hi) * fuu, max(kuu_hi * lo, kuu_hi * hi) * fuu,
            min(kuv_lo * lo, kuv_lo * hi) * fuv, max(kuv_hi * lo, kuv_hi * hi) * fuv,
            min(kvv_lo * lo, kvv_lo * hi) * fvv, max(kvv_hi * lo, kvv_hi * hi) * fvv,
            math.sqrt(tuu) * fuu * hi, math.sqrt(tuv) * fuv * hi, math.sqrt(tvv) * fvv * hi, sig * sig)


@njit(cache=True, inline="always")
def curvature_radius(kuu_lo, kuu_hi, kuv_lo, kuv_hi, kvv_lo, kvv_hi, tuu, tuv, tvv, sigma2):
    """Unsigned convexity radius ρ = σ_lb² / ρ_s from :func:`net_curvature`, ρ_s the spectral
    radius of [[|S_uu|, |S_uv|], [|S_uv|, |S_vv|]] (|S_uu|² ≤ max(n·S_uu)² + |S_uu,⊥|², ...), which
    bounds |λ(Σ r_c ∇²S_c)| / |r|: D is convex on the patch for every C closer than ρ to all of it."""
    suu = math.sqrt(max(kuu_lo * kuu_lo, kuu_hi * kuu_hi) + tuu * tuu)
    svv = math.sqrt(max(kvv_lo * kvv_lo, kvv_hi * kvv_hi) + tvv * tvv)
    suv = math.sqrt(max(kuv_lo * kuv_lo, kuv_hi * kuv_hi) + tuv * tuv)
    # spectral radius of [[|S_uu|, |S_uv|], [|S_uv|, |S_vv|]] bounds |lambda(M)| / |r|
    bound = 0.5 * (suu + svv) + math.sqrt(0.25 * (suu - svv) ** 2 + suv * suv)
    if not (sigma2 > 0.0):
        return 0.0
    if bound == 0.0:
        return np.inf
    return sigma2 / bound * (1.0 - 1e-9)


@njit(cache=True, inline="always")
def box_offsets(lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, x, y, z):
    """(α_lo, α_hi, r_max) of a point C against an oriented box (frame n, t, s = n x t): the range
    [ln - n·C, hn - n·C] of α = n·(S - C) over the box, and the largest in-plane distance
    |r_⊥| from C to a corner of its (t, s) rectangle."""
    sx = ny * tz - nz * ty
    sy = nz * tx - nx * tz
    sz = nx * ty - ny * tx
    pn = nx * x + ny * y + nz * z
    pt = tx * x + ty * y + tz * z
    ps = sx * x + sy * y + sz * z
    rp = math.sqrt(max((lt - pt) ** 2, (ht - pt) ** 2) + max((ls - ps) ** 2, (hs - ps) ** 2))
    return ln - pn, hn - pn, rp


@njit(cache=True, inline="always")
def signed_convex(kuu_lo, kuu_hi, kuv_lo, kuv_hi, kvv_lo, kvv_hi, tuu, tuv, tvv, sigma2,
                  lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, x, y, z):
    """True if the Hessian of D is certified positive definite on a patch for the point (x, y, z).

    Inputs: :func:`net_curvature` of the patch along the box normal n, and the patch's oriented
    box (intervals along t, s = n x t, n). α = n·(S - C) ranges over [ln - n·C, hn - n·C];
    |r_⊥| is bounded by the farthest corner of the box's (t, s) rectangle; then Weyl and
    Gershgorin as in :func:`net_curvature`.
    """
    a0, a1, rp = box_offsets(lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, x, y, z)
    m11 = min(a0 * kuu_lo, a0 * kuu_hi, a1 * kuu_lo, a1 * kuu_hi) - rp * tuu
    m22 = min(a0 * kvv_lo, a0 * kvv_hi, a1 * kvv_lo, a1 * kvv_hi) - rp * tvv
    m12 = max(abs(a0 * kuv_lo), abs(a0 * kuv_hi), abs(a1 * kuv_lo), abs(a1 * kuv_hi)) + rp * tuv
    # smallest eigenvalue of [[m11, m12], [m12, m22]]: it grows with m11 and m22 and falls with
    # |m12|, so the lower bounds of the diagonal and the upper bound of |m12| bound it from below
    # (tighter than Gershgorin near the focal points of concave regions, where H is nearly singular)
    lam = sigma2 + 0.5 * (m11 + m22) - math.sqrt(0.25 * (m11 - m22) ** 2 + m12 * m12)
    return lam > 1e-9 * sigma2 and sigma2 > 0.0


@njit(cache=True, inline="always")
def _halve(b0, b1, b2, b3):
    """de Casteljau at 1/2 of a cubic Bézier segment: the 7 points of the two halves."""
    l1 = 0.5 * (b0 + b1)
    mid = 0.5 * (b1 + b2)
    r2 = 0.5 * (b2 + b3)
    l2 = 0.5 * (l1 + mid)
    r1 = 0.5 * (mid + r2)
    return l1, l2, 0.5 * (l2 + r1), r1, r2


@njit(cache=True)
def net_split(src, s0, dst, d0, d1, d2, d3):
    """de Casteljau split of the net ``src[s0:s0+16]`` (16, 3) at the parameter midpoints into the
    quarter nets ``dst[d0:d0+16]`` (low u, low v), ``d1`` (high u, low v), ``d2`` (low u, high v)
    and ``d3`` (high u, high v). The source must not overlap the destinations."""
    for m in range(4):  # along u: column m (fixed v index), rows k = 0..3
        for c in range(3):
            b0 = src[s0 + m, c]
            b3 = src[s0 + 12 + m, c]
            l1, l2, l3, r1, r2 = _halve(b0, src[s0 + 4 + m, c], src[s0 + 8 + m, c], b3)
            dst[d0 + m, c] = b0
            dst[d0 + 4 + m, c] = l1
            dst[d0 + 8 + m, c] = l2
            dst[d0 + 12 + m, c] = l3
            dst[d1 + m, c] = l3
            dst[d1 + 4 + m, c] = r1
            dst[d1 + 8 + m, c] = r2
            dst[d1 + 12 + m, c] = b3
    for lo, hi in ((d0, d2), (d1, d3)):  # along v: row k, columns m = 0..3 (lo is read, then rewritten)
        for k in range(4):
            for c in range(3):
                b0 = dst[lo + k * 4, c]
                b3 = dst[lo + k * 4 + 3, c]
                l1, l2, l3, r1, r2 = _halve(b0, dst[lo + k * 4 + 1, c], dst[lo + k * 4 + 2, c], b3)
                dst[lo + k * 4 + 1, c] = l1
                dst[lo + k * 4 + 2, c] = l2
                dst[lo + k * 4 + 3, c] = l3
                dst[hi + k * 4, c] = l3
                dst[hi + k * 4 + 1, c] = r1
                dst[hi + k * 4 + 2, c] = r2
                dst[hi + k * 4 + 3, c] = b3


@njit(cache=True)
def net_extents(net, n0, nrows, nx, ny, nz, tx, ty, tz):
    """Intervals (lo_t, hi_t, lo_s, hi_s, lo_n, hi_n) of ``net[n0:n0+nrows]`` along t, s = n x t, n."""
    sx = ny * tz - nz * ty
    sy = nz * tx - nx * tz
    sz = nx * ty - ny * tx
    lt = ls = ln = np.inf
    ht = hs = hn = -np.inf
    big = 0.0
    for r in range(n0, n0 + nrows):
        x = net[r, 0]
        y = net[r, 1]
        z = net[r, 2]
        big = max(big, abs(x), abs(y), abs(z))
        pt = tx * x + ty * y + tz * z
        ps = sx * x + sy * y + sz * z
        pn = nx * x + ny * y + nz * z
        lt = min(lt, pt)
        ht = max(ht, pt)
        ls = min(ls, ps)
        hs = max(hs, ps)
        ln = min(ln, pn)
        hn = max(hn, pn)
    # widen by a few ulps of the coordinates so rounding in the projections never cuts the hull
    pad = 2e-15 * big
    return lt - pad, ht + pad, ls - pad, hs + pad, ln - pad, hn + pad


CURV_SIZE = 10   # columns of HullTree.curv: net_curvature of each cell along its box normal
_ULP32 = 2.0 ** -20  # outward rounding margin for float32 storage (float32 rounds within 2^-24)


@njit(cache=True, inline="always")
def _lower32(x):
    return np.float32(x - abs(x) * _ULP32 - 1e-37)


@njit(cache=True, inline="always")
def _upper32(x):
    return np.float32(x + abs(x) * _ULP32 + 1e-37)


@njit(cache=True)
def _store_curvature(curv, node, vals):
    """Store :func:`net_curvature` values in float32, rounded outwards (lower bounds down, upper
    bounds and norms up, σ² down), so the certificate stays conservative."""
    curv[node, 0] = _lower32(vals[0])
    curv[node, 1] = _upper32(vals[1])
    curv[node, 2] = _lower32(vals[2])
    curv[node, 3] = _upper32(vals[3])
    curv[node, 4] = _lower32(vals[4])
    curv[node, 5] = _upper32(vals[5])
    curv[node, 6] = _upper32(vals[6])
    curv[node, 7] = _upper32(vals[7])
    curv[node, 8] = _upper32(vals[8])
    curv[node, 9] = max(_lower32(vals[9]), np.float32(0.0))


@njit(cache=True, inline="always")
def cell_certified(nodes, curv, node, far2, x, y, z):
    """D certified convex on cell ``node`` for the point (x, y, z): within its convexity radius
    (``far2`` = squared distance to the farthest point of its box) or by the signed test."""
    rho = nodes[node, RHO]
    if far2 < rho * rho:
        return True
    return signed_convex(np.float64(curv[node, 0]), np.float64(curv[node, 1]), np.float64(curv[node, 2]),
                         np.float64(curv[node, 3]), np.float64(curv[node, 4]), np.float64(curv[node, 5]),
                         np.float64(curv[node, 6]), np.float64(curv[node, 7]), np.float64(curv[node, 8]),
                         np.float64(curv[node, 9]),
                         nodes[node, LO_T], nodes[node, HI_T], nodes[node, LO_S], nodes[node, HI_S],
                         nodes[node, LO_N], nodes[node, HI_N], nodes[node, N0], nodes[node, N1], nodes[node, N2],
                         nodes[node, T0], nodes[node, T1], nodes[node, T2], x, y, z)


@njit(cache=True)
def _leaf_nodes(ctrl, ku, kv, mu, mv, nodes, curv, nj0, a0, a1, b0, b1, rows, bez):
    """Oriented Bézier hull boxes of cells [a0, a1) x [b0, b1); returns the number of non-finite cells.

    ``rows`` (4, >= b1 - b0 + 3, 3) scratch: the u-converted control columns of one cell row;
    ``bez`` (16, 3) scratch: the Bézier net of one cell (row k*4 + m).
    """
    bad = 0
    for a in range(a0, a1):
        hu = ku[a + 4] - ku[a + 3]
        # rows[k, j - b0] = sum_m mu[a, k, m] P[a + m, j] for the columns this cell row needs
        for jj in range(b1 - b0 + 3):
            j = b0 + jj
            for c in range(3):
                p0 = ctrl[a, j, c]
                p1 = ctrl[a + 1, j, c]
                p2 = ctrl[a + 2, j, c]
                p3 = ctrl[a + 3, j, c]
                for k in range(4):
                    rows[k, jj, c] = mu[a, k, 0] * p0 + mu[a, k, 1] * p1 + mu[a, k, 2] * p2 + mu[a, k, 3] * p3
        for b in range(b0, b1):
            jj = b - b0
            node = a * nj0 + b
            finite = True
            for k in range(4):
                for m in range(4):
                    for c in range(3):
                        x = (mv[b, m, 0] * rows[k, jj, c] + mv[b, m, 1] * rows[k, jj + 1, c]
                             + mv[b, m, 2] * rows[k, jj + 2, c] + mv[b, m, 3] * rows[k, jj + 3, c])
                        bez[k * 4 + m, c] = x
                        if not (x - x == 0.0):
                            finite = False
            if not finite:
                bad += 1
                _frame(nodes, node, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0)
                for e in range(3):  # a box that is never pruned: the query meets the NaN and says so
                    nodes[node, LO_T + 2 * e] = -np.inf
                    nodes[node, HI_T + 2 * e] = np.inf
                nodes[node, RHO] = 0.0
                for q in range(CURV_SIZE):
                    curv[node, q] = 0.0  # sigma2 = 0: never certified
                continue
            # mean tangents of the Bézier net: T_u = sum_m (B[3, m] - B[0, m]), T_v likewise
            tux = tuy = tuz = tvx = tvy = tvz = 0.0
            for m in range(4):
                tux += bez[12 + m, 0] - bez[m, 0]
                tuy += bez[12 + m, 1] - bez[m, 1]
                tuz += bez[12 + m, 2] - bez[m, 2]
                tvx += bez[m * 4 + 3, 0] - bez[m * 4, 0]
                tvy += bez[m * 4 + 3, 1] - bez[m * 4, 1]
                tvz += bez[m * 4 + 3, 2] - bez[m * 4, 2]
            _frame(nodes, node, tuy * tvz - tuz * tvy, tuz * tvx - tux * tvz, tux * tvy - tuy * tvx,
                   tux, tuy, tuz)
            lt, ht, ls, hs, ln, hn = net_extents(bez, 0, 16, nodes[node, N0], nodes[node, N1], nodes[node, N2],
                                                 nodes[node, T0], nodes[node, T1], nodes[node, T2])
            nodes[node, LO_T] = lt
            nodes[node, HI_T] = ht
            nodes[node, LO_S] = ls
            nodes[node, HI_S] = hs
            nodes[node, LO_N] = ln
            nodes[node, HI_N] = hn
            vals = net_curvature(bez, hu, kv[b + 4] - kv[b + 3], nodes[node, N0], nodes[node, N1], nodes[node, N2])
            nodes[node, RHO] = curvature_radius(vals[0], vals[1], vals[2], vals[3], vals[4], vals[5], vals[6],
                                                vals[7], vals[8], vals[9])
            _store_curvature(curv, node, vals)
    return bad


@njit(cache=True)
def _parent_nodes(nodes, levels, a0, a1, b0, b1):
    """Recompute the ancestors of the leaf range [a0, a1) x [b0, b1) from their children.

    Parent frame: normal = mean of the children's normals; each child box maps into it by
    interval arithmetic (the image of a box under a linear map, bounded coordinate-wise)."""
    for lev in range(1, levels.shape[0]):
        a0 = a0 // 2
        a1 = (a1 + 1) // 2
        b0 = b0 // 2
        b1 = (b1 + 1) // 2
        off = levels[lev, 0]
        ni = levels[lev, 1]
        nj = levels[lev, 2]
        coff = levels[lev - 1, 0]
        cni = levels[lev - 1, 1]
        cnj = levels[lev - 1, 2]
        for i in range(a0, min(a1, ni)):
            for j in range(b0, min(b1, nj)):
                node = off + i * nj + j
                snx = sny = snz = stx = sty = stz = 0.0
                for ci in range(2 * i, min(2 * i + 2, cni)):
                    for cj in range(2 * j, min(2 * j + 2, cnj)):
                        child = coff + ci * cnj + cj
                        snx += nodes[child, N0]
                        sny += nodes[child, N1]
                        snz += nodes[child, N2]
                        stx += nodes[child, T0]
                        sty += nodes[child, T1]
                        stz += nodes[child, T2]
                _frame(nodes, node, snx, sny, snz, stx, sty, stz)
                pnx, pny, pnz, ptx, pty, ptz, psx, psy, psz = _axes(nodes, node)
                lt = ls = ln = np.inf
                ht = hs = hn = -np.inf
                big = 0.0
                finite = True
                for ci in range(2 * i, min(2 * i + 2, cni)):
                    for cj in range(2 * j, min(2 * j + 2, cnj)):
                        child = coff + ci * cnj + cj
                        nx, ny, nz, tx, ty, tz, sx, sy, sz = _axes(nodes, child)
                        clt, cht = nodes[child, LO_T], nodes[child, HI_T]
                        cls, chs = nodes[child, LO_S], nodes[child, HI_S]
                        cln, chn = nodes[child, LO_N], nodes[child, HI_N]
                        big = max(big, abs(clt), abs(cht), abs(cls), abs(chs), abs(cln), abs(chn))
                        if not (big - big == 0.0):
                            finite = False
                        for e in range(3):
                            if e == 0:
                                ex, ey, ez = ptx, pty, ptz
                            elif e == 1:
                                ex, ey, ez = psx, psy, psz
                            else:
                                ex, ey, ez = pnx, pny, pnz
                            mt = ex * tx + ey * ty + ez * tz
                            ms = ex * sx + ey * sy + ez * sz
                            mn = ex * nx + ey * ny + ez * nz
                            lo = min(mt * clt, mt * cht) + min(ms * cls, ms * chs) + min(mn * cln, mn * chn)
                            hi = max(mt * clt, mt * cht) + max(ms * cls, ms * chs) + max(mn * cln, mn * chn)
                            if e == 0:
                                lt = min(lt, lo)
                                ht = max(ht, hi)
                            elif e == 1:
                                ls = min(ls, lo)
                                hs = max(hs, hi)
                            else:
                                ln = min(ln, lo)
                                hn = max(hn, hi)
                pad = 4e-15 * big
                if not finite:  # a non-finite child: never prune
                    lt = ls = ln = -np.inf
                    ht = hs = hn = np.inf
                    pad = 0.0
                rho = np.inf
                for ci in range(2 * i, min(2 * i + 2, cni)):
                    for cj in range(2 * j, min(2 * j + 2, cnj)):
                        rho = min(rho, nodes[coff + ci * cnj + cj, RHO])
                nodes[node, RHO] = rho
                nodes[node, LO_T] = lt - pad
                nodes[node, HI_T] = ht + pad
                nodes[node, LO_S] = ls - pad
                nodes[node, HI_S] = hs + pad
                nodes[node, LO_N] = ln - pad
                nodes[node, HI_N] = hn + pad


@njit(cache=True)
def refresh_region_kernel(ctrl, ku, kv, mu, mv, nodes, curv, levels, rows, bez, iu0, iu1, iv0, iv1):
    """Recompute the boxes touched by control points ``ctrl[iu0:iu1, iv0:iv1]`` (half-open).

    For numba callers (the deformation kernel): no allocation, O(patch + log N). ``rows`` and
    ``bez`` are the scratch arrays of :class:`HullTree`. Returns the number of non-finite cells
    (> 0 means the net holds NaN/inf there).
    """
    ni0 = levels[0, 1]
    nj0 = levels[0, 2]
    a0 = max(iu0 - 3, 0)
    a1 = min(iu1, ni0)
    b0 = max(iv0 - 3, 0)
    b1 = min(iv1, nj0)
    nodes[nodes.shape[0] - 1, VERSION] += 1.0  # invalidates the candidate caches of the queries
    if a0 >= a1 or b0 >= b1:
        return 0
    bad = _leaf_nodes(ctrl, ku, kv, mu, mv, nodes, curv, nj0, a0, a1, b0, b1, rows, bez)
    _parent_nodes(nodes, levels, a0, a1, b0, b1)
    return bad


@njit(cache=True, inline="always")
def node_distance2(nodes, node, x, y, z):
    """Squared distance from (x, y, z) to the oriented box ``node`` (0 inside)."""
    nx, ny, nz, tx, ty, tz, sx, sy, sz = _axes(nodes, node)
    d2 = 0.0
    p = tx * x + ty * y + tz * z
    q = nodes[node, LO_T] - p
    if q > 0.0:
        d2 += q * q
    else:
        q = p - nodes[node, HI_T]
        if q > 0.0:
            d2 += q * q
    p = sx * x + sy * y + sz * z
    q = nodes[node, LO_S] - p
    if q > 0.0:
        d2 += q * q
    else:
        q = p - nodes[node, HI_S]
        if q > 0.0:
            d2 += q * q
    p = nx * x + ny * y + nz * z
    q = nodes[node, LO_N] - p
    if q > 0.0:
        d2 += q * q
    else:
        q = p - nodes[node, HI_N]
        if q > 0.0:
            d2 += q * q
    return d2


@njit(cache=True, inline="always")
def extents_bounds2(lt, ht, ls, hs, ln, hn, nx, ny, nz, tx, ty, tz, x, y, z):
    """(near², far², lift): squared distances from (x, y, z) to the nearest and the farthest point
    of the oriented box with frame (n, t, s = n x t) and the given intervals, and the height of
    the point above the box's mid-plane along n."""
    sx = ny * tz - nz * ty
    sy = nz * tx - nx * tz
    sz = nx * ty - ny * tx
    near2 = 0.0
    far2 = 0.0
    p = tx * x + ty * y + tz * z
    a = lt - p
    b = p - ht
    if a > 0.0:
        near2 += a * a
    elif b > 0.0:
        near2 += b * b
    far2 += max(a * a, b * b)
    p = sx * x + sy * y + sz * z
    a = ls - p
    b = p - hs
    if a > 0.0:
        near2 += a * a
    elif b > 0.0:
        near2 += b * b
    far2 += max(a * a, b * b)
    p = nx * x + ny * y + nz * z
    a = ln - p
    b = p - hn
    if a > 0.0:
        near2 += a * a
    elif b > 0.0:
        near2 += b * b
    far2 += max(a * a, b * b)
    return near2, far2, p - 0.5 * (ln + hn)


@njit(cache=True, inline="always")
def node_bounds2(nodes, node, x, y, z):
    """:func:`extents_bounds2` for pyramid node ``node``."""
    return extents_bounds2(nodes[node, LO_T], nodes[node, HI_T], nodes[node, LO_S], nodes[node, HI_S],
                           nodes[node, LO_N], nodes[node, HI_N], nodes[node, N0], nodes[node, N1],
                           nodes[node, N2], nodes[node, T0], nodes[node, T1], nodes[node, T2], x, y, z)


class HullTree:
    """Oriented Bézier hull-box pyramid of a control net (the projection's acceleration structure).

    Parameters
    ----------
    ctrl : (nu, nv, 3) float64 C array, metres
        The live control net (read at build and at every refresh, never written).
    knots_u, knots_v : (nu + 4,), (nv + 4,) float64
        Clamped uniform cubic knots.

    Attributes
    ----------
    nodes : (n_nodes + 1, 13) float64
        Per node: unit normal n, unit tangent t (s = n x t), the intervals
        ``lo_t, hi_t, lo_s, hi_s, lo_n, hi_n`` (metres) of the hull along t, s, n, and the
        convexity radius ρ (metres; min over the subtree). The last row holds (version, tree id).
    levels : (L, 3) int64
        ``(offset, ni, nj)`` of each level; level 0 holds the (nu-3) x (nv-3) knot cells, cell
        (a, b) = span [t_u[a+3], t_u[a+4]] x [t_v[b+3], t_v[b+4]].
    curv : (n_cells, 10) float32
        :func:`net_curvature` of each cell along its box normal, rounded outwards: the signed
        convexity certificate (:func:`cell_certified`).
    mu, mv : (nu-3, 4, 4), (nv-3, 4, 4) float64
        B-spline-to-Bézier matrices per span.
    rows, bez : scratch arrays of the refresh kernel.

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((6, 6)), (0.0, 3e-9), (0.0, 3e-9))
    >>> ctrl, _, ku, kv = s.kernel_arrays()
    >>> tree = HullTree(ctrl, ku, kv)
    >>> tree.levels.tolist()
    [[0, 3, 3], [9, 2, 2], [13, 1, 1]]
    """

    def __init__(self, ctrl: np.ndarray, knots_u: np.ndarray, knots_v: np.ndarray):
        self.ctrl = ctrl
        self.ku = knots_u
        self.kv = knots_v
        self.mu = bezier_matrices(knots_u)
        self.mv = bezier_matrices(knots_v)
        nu, nv = ctrl.shape[0], ctrl.shape[1]
        self.levels = pyramid_levels(nu - 3, nv - 3)
        last = self.levels[-1]
        self.nodes = np.zeros((int(last[0] + last[1] * last[2]) + 1, NODE_SIZE))
        self.nodes[-1, TREE_ID] = float(next(_TREE_IDS))
        self.curv = np.zeros((int(self.levels[0, 1] * self.levels[0, 2]), CURV_SIZE), dtype=np.float32)
        self.rows = np.empty((4, nv, 3))
        self.bez = np.empty((16, 3))
        self.refresh()

    def kernel_args(self) -> tuple:
        """``(ctrl, ku, kv, mu, mv, nodes, curv, levels, rows, bez)``: the leading arguments of
        :func:`refresh_region_kernel`."""
        return self.ctrl, self.ku, self.kv, self.mu, self.mv, self.nodes, self.curv, self.levels, self.rows, self.bez

    def refresh(self) -> None:
        """Rebuild every box from the current net (after :meth:`BSplineSurface.reset`), O(N)."""
        nu, nv = self.ctrl.shape[0], self.ctrl.shape[1]
        self.refresh_region(0, nu, 0, nv)

    def refresh_region(self, iu0: int, iu1: int, iv0: int, iv1: int) -> None:
        """Recompute the boxes after control points ``ctrl[iu0:iu1, iv0:iv1]`` moved, O(patch).

        Raises
        ------
        SurfaceError
            If the region is outside the net, or the net holds NaN/inf there.
        """
        nu, nv = self.ctrl.shape[0], self.ctrl.shape[1]
        iu0, iu1, iv0, iv1 = int(iu0), int(iu1), int(iv0), int(iv1)
        if not (0 <= iu0 <= iu1 <= nu and 0 <= iv0 <= iv1 <= nv):
            raise SurfaceError(
                f"refresh region [{iu0}:{iu1}, {iv0}:{iv1}] is not inside the {nu}x{nv} control net; "
                "pass half-open index ranges 0 <= i0 <= i1 <= n"
            )
        bad = refresh_region_kernel(*self.kernel_args(), iu0, iu1, iv0, iv1)
        if bad:
            raise SurfaceError(
                f"the control net has non-finite (NaN/inf) points in {bad} knot cells of the region "
                f"[{iu0}:{iu1}, {iv0}:{iv1}]; refit from a scan without NaN (arsurf.inpaint) or reset() "
                "the surface"
            )
