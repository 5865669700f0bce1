r"""Safeguarded Newton iteration for the closest point on a bicubic B-spline surface.

Minimises :math:`D(u, v) = \tfrac12 |S(u, v) - C|^2` in a parameter box (a knot cell, a
sub-cell or the whole domain): Newton step when the Hessian is positive definite, else
Gauss-Newton, else the gradient; step capped, projected onto the box (active set) and
backtracked to the Armijo condition; iterations and halvings bounded (docs/design.rst, "Closest
point (Newton)"). The global search that calls it is :mod:`arsurf.contact.closest_point`.
"""
from __future__ import annotations

import math

from numba import njit

from arsurf.spline.basis import DERIVATIVE_ROWS, surface_point

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
MAX_ITER_DOMAIN = 40   # unrestricted Newton (from the seed, and polishing a cell minimum)
MAX_ITER_CELL = 16     # Newton restricted to one knot cell
MAX_HALVINGS = 40      # backtracking line search
#: rows of the evaluation block Newton works in (:func:`~arsurf.spline.basis.surface_point` to
#: second order, :data:`~arsurf.spline.basis.DERIVATIVE_ROWS`)
EVALUATION_ROWS = DERIVATIVE_ROWS.size
ARMIJO = 1e-4


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


@njit(cache=True)
def newton_foot(ctrl, ku, kv, ev, cx, cy, cz, u, v, h, reach=math.inf):
    r"""The local minimum of the distance to C = (cx, cy, cz) that Newton's method reaches from
    (u, v) over the whole domain (:func:`newton_box`, knot spacing ``h`` m), with its unit normal
    :math:`n = S_u \times S_v / \lVert\cdot\rVert` (out of the sample) and the signed distance
    :math:`d = (C - S)\cdot n` (< 0: C behind the patch). With a finite ``reach`` (m) only within
    ``reach`` of the start in u and in v: a minimum farther away is not this start's (``ok`` False).

    Returns ``(u, v, nx, ny, nz, d, ok)``; ``ok`` False when Newton did not converge or the normal
    is degenerate (the other values are then meaningless). ``ev[0]`` holds the point S."""
    nu = ku.shape[0]
    nv = kv.shape[0]
    lo_u, hi_u = max(ku[3], u - reach), min(ku[nu - 4], u + reach)
    lo_v, hi_v = max(kv[3], v - reach), min(kv[nv - 4], v + reach)
    u, v, d2, it, conv = newton_box(ctrl, ku, kv, ev, cx, cy, cz, u, v, lo_u, hi_u, lo_v, hi_v,
                                    STEP_TOL * h, STEP_TOL * h, h, MAX_ITER_DOMAIN)
    if (u <= lo_u and lo_u > ku[3]) or (u >= hi_u and hi_u < ku[nu - 4]) or \
            (v <= lo_v and lo_v > kv[3]) or (v >= hi_v and hi_v < kv[nv - 4]):
        return u, v, 0.0, 0.0, 1.0, math.nan, False  # held at the edge of the reach: a minimum beyond it
    ax = ev[1, 1] * ev[2, 2] - ev[1, 2] * ev[2, 1]
    ay = ev[1, 2] * ev[2, 0] - ev[1, 0] * ev[2, 2]
    az = ev[1, 0] * ev[2, 1] - ev[1, 1] * ev[2, 0]
    an = math.sqrt(ax * ax + ay * ay + az * az)
    if not (conv and an > 0.0):
        return u, v, 0.0, 0.0, 1.0, math.nan, False
    ax /= an
    ay /= an
    az /= an
    return u, v, ax, ay, az, (cx - ev[0, 0]) * ax + (cy - ev[0, 1]) * ay + (cz - ev[0, 2]) * az, True
