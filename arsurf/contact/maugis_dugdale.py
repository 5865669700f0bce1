"""Maugis-Dugdale (MD) adhesive contact of a sphere on a flat, from DMT to JKR, at haptic rates.

Units and equations (Maugis 1992; Johnson & Greenwood 1997; docs/design.rst, "Contact mechanics (Maugis-Dugdale)"). With
:math:`K = 4E^*/3` (:math:`1/E^* = (1-\\nu_1^2)/E_1 + (1-\\nu_2^2)/E_2`), work of adhesion *w*,
Dugdale stress :math:`\\sigma_0` (range :math:`h_0 = w/\\sigma_0`):

.. math::
    A = a\\left(\\frac{K}{\\pi w R^2}\\right)^{1/3},\\quad
    \\bar P = \\frac{P}{\\pi w R},\\quad
    \\bar\\Delta = \\delta\\left(\\frac{K^2}{\\pi^2 w^2 R}\\right)^{1/3},\\quad
    \\lambda = 2\\sigma_0\\left(\\frac{R}{\\pi w K^2}\\right)^{1/3},\\quad m = c/a \\ge 1

.. math::
    \\frac{\\lambda A^2}{2}\\Big[\\sqrt{m^2-1} + (m^2-2)\\arctan\\sqrt{m^2-1}\\Big]
    + \\frac{4\\lambda^2 A}{3}\\Big[\\sqrt{m^2-1}\\arctan\\sqrt{m^2-1} - m + 1\\Big] = 1

.. math::
    \\bar P = A^3 - \\lambda A^2\\Big[\\sqrt{m^2-1} + m^2\\arctan\\sqrt{m^2-1}\\Big],\\qquad
    \\bar\\Delta = A^2 - \\tfrac{4}{3}\\lambda A\\sqrt{m^2-1}

How it is solved
----------------
*Parametrisation.* With :math:`s = \\sqrt{m^2-1}` the first equation reads
:math:`\\alpha(s) A^2 + \\beta(s) A = 1` with :math:`\\alpha = \\tfrac{\\lambda}{2}[s + (s^2-1)\\arctan s]`,
:math:`\\beta = \\tfrac{4\\lambda^2}{3}[s\\arctan s - m + 1]`. Both are positive and strictly increasing
for s > 0, so :math:`A(s) = 2/(\\beta + \\sqrt{\\beta^2 + 4\\alpha})` is the unique positive root and
decreases strictly from :math:`\\infty` (s -> 0) to 0 (s -> :math:`\\infty`): the whole contact branch is
the explicit curve :math:`s \\mapsto (A, \\bar P, \\bar\\Delta)`, with analytic derivatives. (The
cancellation in :math:`s - \\arctan s` is removed by its series for s < 0.05.)

*Shape of the curve* (checked over :math:`\\lambda \\in [10^{-3}, 10^3]`): :math:`\\bar P(A)` has exactly
one minimum (the pull-off under load control); :math:`\\bar\\Delta(A)` is monotone for
:math:`\\lambda \\le \\lambda_t` and has exactly one minimum (a fold) for :math:`\\lambda > \\lambda_t`, where

.. math:: \\lambda_t = \\left(\\frac{9\\pi}{16(\\pi - 1)}\\right)^{1/3} = 0.93795\\ldots

is Maugis' transition (derived below). So the stable branch of each control mode is the part
of the curve on the large-radius side of its fold.

*At a = 0* the contact branch ends with a finite adhesive zone :math:`\\bar c_0 = mA` solving
:math:`\\tfrac{\\lambda\\pi}{4}\\bar c_0^2 + \\tfrac{4\\lambda^2}{3}(\\tfrac{\\pi}{2} - 1)\\bar c_0 = 1`
(:math:`\\bar c = c (K/\\pi w R^2)^{1/3}`), load :math:`\\bar P_0 = -\\lambda\\pi\\bar c_0^2/2`, depth
:math:`\\bar\\Delta_0 = -\\tfrac43\\lambda\\bar c_0`. It continues as the *cohesive, no-contact* branch:
the Dugdale stress acts on a disk of radius *c* while the surfaces do not touch. From the
displacement of a uniformly loaded disk (Johnson 1985, Eq. 3.29) and the gap condition
:math:`h(c) = h_0`:

.. math:: \\bar\\Delta = \\frac{\\bar c^2}{2} - \\frac{8\\lambda}{3\\pi}\\bar c - \\frac{2}{\\lambda\\pi},
          \\qquad \\bar P = -\\frac{\\lambda\\pi}{2}\\bar c^2, \\qquad 0 \\le \\bar c \\le \\bar c_0,

which meets the contact branch exactly at :math:`\\bar c_0` (a check of both). It is stable under
displacement control where :math:`\\bar c > \\bar c_* = 8\\lambda/3\\pi`; :math:`\\bar c_0 > \\bar c_*` is
exactly :math:`\\lambda < \\lambda_t`. Hence Maugis' transition for a retracting tip under
displacement control:

* :math:`\\lambda > \\lambda_t`: the contact jumps out at the fold of :math:`\\bar\\Delta(A)`, from a finite
  radius, straight to separation (the JKR-like behaviour);
* :math:`\\lambda < \\lambda_t`: the contact radius shrinks continuously to 0 at :math:`\\bar\\Delta_0`, the
  cohesive neck holds, and snaps at :math:`\\bar\\Delta = -2/\\lambda\\pi - \\bar c_*^2/2` (DMT-like).

Approaching, the tip first feels the adhesion at a gap :math:`h_0`
(:math:`\\bar\\Delta = -2/\\lambda\\pi`) and jumps onto the stable branch (the hysteresis).

*Fast path.* :func:`md_radius_from_depth_kernel` solves for :math:`t = \\ln s` with a safeguarded
Newton iteration (bracket + bisection fallback) on
:math:`\\operatorname{asinh}\\sqrt{\\bar\\Delta(t) - \\bar\\Delta_f}` when the branch has a fold and on
:math:`\\ln(\\bar\\Delta(t) - \\bar\\Delta_0)` when it does not. Both are close to linear in *t* at both ends
(:math:`\\bar\\Delta \\sim A^2 \\sim s^{-3}` for large contacts, a square-root fold or
:math:`A^2 \\sim s^{-2}` at the other end), so a cold start from the large-contact asymptote
converges in 3 evaluations on average (rarely 5; no table to build or to trust). The stopping
rule is a Newton step below 1e-5 in *t* (or below the rounding noise of the residual); the error
left is O(step^2), and the last step is applied to A to first order. The fold location is
precomputed once per model (scipy brentq on :math:`d\\bar\\Delta/dt = 0`) and passed in as a scalar.

Measured (bench/contact_mechanics.py, on a shared 2-core machine): 0.3-0.8 us median per solve
inside an ``@njit`` loop for :math:`\\lambda` = 0.01 ... 100, about 1500-5000 times faster than a plain
nested scipy brentq; relative error of the radius <= 3e-10 against that reference over
:math:`\\lambda \\in [0.01, 100]` (and <= 3e-10 against a 40-digit mpmath solution). Errors grow only
where the problem itself is ill-conditioned: A < 1e-4 at the a -> 0 end of a fold-free branch,
where :math:`dA/d\\bar\\Delta \\sim 1/A` amplifies the rounding of :math:`\\bar\\Delta` itself.

Sources: D. Maugis, J. Colloid Interface Sci. 150, 243 (1992); K. L. Johnson & J. A. Greenwood,
J. Colloid Interface Sci. 192, 326 (1997) (adhesion map, the notation above);
K. L. Johnson, *Contact Mechanics* (1985) Eq. 3.29; [SplineAR] (MD drives the contact radius).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf.contact.mechanics import (
    ContactModel,
    ContactState,
    _finite_array,
    _positive,
)
from arsurf._layout import Layout
from arsurf.errors import ContactError
from arsurf.status import COHESIVE, CONTACT, NON_FINITE, NOT_CONVERGED, SEPARATED

__all__ = [
    "LAMBDA_TRANSITION",
    "MD_ARGS",
    "MDCriticalPoints",
    "MDState",
    "MaugisDugdale",
    "T_RANGE",
    "md_branch_parameter",
    "md_contact_from_depth_kernel",
    "md_contact_hysteresis_kernel",
    "md_critical_point_kernel",
    "md_curve",
    "md_load_from_depth_kernel",
    "md_radius_from_depth_kernel",
    "md_solve_depth",
    "md_solve_load",
    "md_zero_radius_limit",
    "md_zone_from_depth_kernel",
    "md_zone_radius",
]

#: Maugis' transition: above it a retracting contact jumps out from a finite radius under
#: displacement control; below it the radius shrinks continuously to zero (derived in the
#: module docstring; Maugis 1992 quotes 0.938).
LAMBDA_TRANSITION = (9.0 * math.pi / (16.0 * (math.pi - 1.0))) ** (1.0 / 3.0)

#: the law's kernel arguments as a vector (:attr:`MaugisDugdale.kernel_args`, in that order; the
#: contact vector of :mod:`arsurf.contact.material_map` holds it): depth, radius and load scales
#: (m, m, N), Maugis' lambda, ln s at the fold (inf: none; NaN: not computed), the fold's depth
#: (in depth scales)
MD_ARGS = Layout("Maugis-Dugdale kernel arguments", [
    ("depth_scale", 1), ("radius_scale", 1), ("load_scale", 1), ("maugis_parameter", 1), ("t_fold", 1),
    ("delta_fold", 1)])
# the offsets as the kernels use them
A_DEPTH_SCALE, A_RADIUS_SCALE, A_LOAD_SCALE = (MD_ARGS.offset("depth_scale"), MD_ARGS.offset("radius_scale"),
                                               MD_ARGS.offset("load_scale"))
A_LAMBDA, A_T_FOLD, A_DELTA_FOLD = (MD_ARGS.offset("maugis_parameter"), MD_ARGS.offset("t_fold"),
                                    MD_ARGS.offset("delta_fold"))

_T_MIN = -60.0      # s = e^-60: A ~ 1e39, far beyond any physical query
_T_MAX = 60.0       # s = e^60:  A ~ 1e-26
#: the range of the contact branch's parameter t = ln s the solvers search (s = sqrt(m^2 - 1))
T_RANGE = (_T_MIN, _T_MAX)
_MAXIT = 100
_STEP_TOL = 1e-5    # Newton step in t = ln s at which the iteration stops (then error ~ step^2)
_EPS = 1.1102230246251565e-16


# ---------------------------------------------------------------------------------------------
# the explicit curve
# ---------------------------------------------------------------------------------------------

@njit(cache=True)
def _s_minus_atan(s):
    """s - arctan(s) without cancellation (series for s < 0.05, truncation < 1e-19 relative)."""
    if s < 0.05:
        s2 = s * s
        return s * s2 * (1.0 / 3.0 - s2 * (1.0 / 5.0 - s2 * (1.0 / 7.0 - s2 * (1.0 / 9.0 - s2 * (
            1.0 / 11.0 - s2 * (1.0 / 13.0 - s2 / 15.0))))))
    return s - math.atan(s)


@njit(cache=True)
def md_curve(s, lam):
    """Point of the MD contact branch at :math:`s = \\sqrt{m^2-1}` and its derivatives.

    Parameters
    ----------
    s : float > 0
        :math:`\\sqrt{m^2 - 1}`, m = c/a.
    lam : float > 0
        Maugis parameter :math:`\\lambda`.

    Returns
    -------
    (A, P, D, dA, dP, dD) : floats
        Non-dimensional radius, load and depth, and their derivatives with respect to s.
    """
    at = math.atan(s)
    s2 = s * s
    m2 = 1.0 + s2
    m = math.sqrt(m2)
    f1 = _s_minus_atan(s) + s2 * at                    # s + (m^2-2) atan s
    f2 = s * at - s2 / (m + 1.0)                       # s atan s - m + 1
    df1 = 2.0 * s2 / m2 + 2.0 * s * at
    df2 = at + s / m2 - s / m
    al = 0.5 * lam * f1
    be = (4.0 / 3.0) * lam * lam * f2
    dal = 0.5 * lam * df1
    dbe = (4.0 / 3.0) * lam * lam * df2
    A = 2.0 / (be + math.sqrt(be * be + 4.0 * al))
    dA = -(dal * A * A + dbe * A) / (2.0 * al * A + be)
    g = s + m2 * at
    dg = 2.0 + 2.0 * s * at
    P = A * A * A - lam * A * A * g
    dP = 3.0 * A * A * dA - lam * (2.0 * A * dA * g + A * A * dg)
    D = A * A - (4.0 / 3.0) * lam * A * s
    dD = 2.0 * A * dA - (4.0 / 3.0) * lam * (dA * s + A)
    return A, P, D, dA, dP, dD


@njit(cache=True)
def md_zero_radius_limit(lam):
    """End of the contact branch at a -> 0: (c0_bar, Delta0_bar, P0_bar).

    :math:`\\tfrac{\\lambda\\pi}{4}\\bar c_0^2 + \\tfrac{4\\lambda^2}{3}(\\tfrac{\\pi}{2}-1)\\bar c_0 = 1`,
    :math:`\\bar\\Delta_0 = -\\tfrac43\\lambda\\bar c_0`, :math:`\\bar P_0 = -\\tfrac{\\lambda\\pi}{2}\\bar c_0^2`.
    """
    qa = 0.25 * lam * math.pi
    qb = (4.0 / 3.0) * lam * lam * (0.5 * math.pi - 1.0)
    c0 = 2.0 / (qb + math.sqrt(qb * qb + 4.0 * qa))
    return c0, -(4.0 / 3.0) * lam * c0, -0.5 * lam * math.pi * c0 * c0


@njit(cache=True)
def _branch_solve(target, lam, which, t_end, v_end, fold):
    """Find t = ln s on the stable side of the branch where value(t) = target.

    which: 0 for depth, 1 for load. value(t) decreases from +inf (t -> -inf) to v_end at
    t_end (a fold, fold=True) or asymptotically as t -> inf (fold=False). Requires target > v_end.
    Returns (status, A, P, D, t).
    """
    diff_t = target - v_end
    if fold:
        r = math.asinh(math.sqrt(diff_t))
    else:
        r = math.log(diff_t)
    # cold start from the large-contact asymptote A ~ sqrt(3/(2 lam)) s^-3/2
    if which == 0:
        t = (math.log(1.5 / lam) - math.log(diff_t)) / 3.0
    else:
        t = (1.5 * math.log(1.5 / lam) - math.log(diff_t)) / 4.5
    t_lo = _T_MIN
    t_hi = t_end if fold else _T_MAX
    if t > t_hi - 0.5:
        t = t_hi - 0.5
    if t < t_lo + 0.5:
        t = t_lo + 0.5
    A = 0.0
    P = 0.0
    D = 0.0
    for _ in range(_MAXIT):
        s = math.exp(t)
        A, P, D, dA, dP, dD = md_curve(s, lam)
        if which == 0:
            v = D
            dv = dD * s
        else:
            v = P
            dv = dP * s
        diff = v - v_end
        if diff <= 0.0:           # past the end of the branch (rounding next to the fold)
            t_hi = t
            tn = 0.5 * (t_lo + t_hi)
            if t_hi - t_lo < 1e-13:
                return CONTACT, A, P, D, t
            t = tn
            continue
        if fold:
            w = math.sqrt(diff)
            dphi_ddiff = 1.0 / (2.0 * w * math.sqrt(1.0 + w * w))
            phi = math.asinh(w) - r
        else:
            dphi_ddiff = 1.0 / diff
            phi = math.log(diff) - r
        if phi == 0.0:
            return CONTACT, A, P, D, t
        dphi = dv * dphi_ddiff
        if phi > 0.0:
            t_lo = t
        else:
            t_hi = t
        newton = dphi < 0.0
        if newton:
            tn = t - phi / dphi
            if not (t_lo <= tn <= t_hi):
                tn = 0.5 * (t_lo + t_hi)
                newton = False
        else:
            tn = 0.5 * (t_lo + t_hi)
        step = tn - t
        if newton:
            noise = 8.0 * _EPS * (abs(v) + abs(v_end)) * dphi_ddiff / abs(dphi)
            if abs(step) <= max(_STEP_TOL, 4.0 * noise):
                ds = s * math.expm1(step)
                return CONTACT, A + dA * ds, P + dP * ds, D + dD * ds, tn
        elif t_hi - t_lo < 1e-13:
            return CONTACT, A, P, D, tn
        t = tn
    return NOT_CONVERGED, A, P, D, t


@njit(cache=True)
def md_solve_depth(delta_bar, lam, t_fold, delta_fold):
    """Non-dimensional MD state at depth :math:`\\bar\\Delta` on the branch connected to contact.

    Parameters
    ----------
    delta_bar : float
        :math:`\\bar\\Delta`.
    lam : float
        Maugis parameter.
    t_fold, delta_fold : float
        ln s and :math:`\\bar\\Delta` at the fold of :math:`\\bar\\Delta(A)` (:math:`\\lambda > \\lambda_t`);
        ``t_fold = inf`` and ``delta_fold`` = :math:`\\bar\\Delta_0` when there is none. Precomputed by
        :class:`MaugisDugdale` (``kernel_args``). ``t_fold = NaN`` with ``delta_fold`` =
        :math:`\\bar\\Delta_0`: the fold exists but was not computed (a local contact law of a
        material map); it is then found (:func:`md_critical_point_kernel`) only when
        :math:`\\bar\\Delta \\le \\bar\\Delta_0` needs it.

    Returns
    -------
    (status, A, P, c) : (int, float, float, float)
        status 0 contact, 1 cohesive (A = 0, adhesive zone of radius c still loaded),
        2 separated (all 0), -1 NaN/inf input, -3 not converged (:mod:`arsurf.status`). c is :math:`\\bar c = mA`.
    """
    if not math.isfinite(delta_bar):
        return NON_FINITE, 0.0, 0.0, 0.0
    if math.isnan(t_fold):
        # a contact law made on the fly (a material map, lambda > lambda_t): the fold is found only
        # for a depth that needs it. delta_fold then holds Delta0 (the depth at a = 0), above the
        # fold: on the unstable side past the fold Delta < Delta0, so for delta_bar > Delta0 the
        # fold-free solve (bracket up to t = +inf, Delta0 as the branch's end) finds the same root
        if delta_bar > delta_fold:
            st, A, P, D, t = _branch_solve(delta_bar, lam, 0, math.inf, delta_fold, False)
            s = math.exp(t)
            return st, A, P, A * math.sqrt(1.0 + s * s)
        t_fold, delta_fold = md_critical_point_kernel(lam, 0)
    has_fold = math.isfinite(t_fold)
    if delta_bar > delta_fold:
        st, A, P, D, t = _branch_solve(delta_bar, lam, 0, t_fold, delta_fold, has_fold)
        s = math.exp(t)
        return st, A, P, A * math.sqrt(1.0 + s * s)
    if has_fold:
        if delta_bar == delta_fold:
            s = math.exp(t_fold)
            A, P, D, dA, dP, dD = md_curve(s, lam)
            return CONTACT, A, P, A * math.sqrt(1.0 + s * s)
        return SEPARATED, 0.0, 0.0, 0.0
    # no fold: the contact radius has shrunk to 0; the cohesive neck may still hold
    c0, d0, p0 = md_zero_radius_limit(lam)
    cs = 8.0 * lam / (3.0 * math.pi)
    if cs < c0:
        d_snap = -2.0 / (lam * math.pi) - 0.5 * cs * cs
        if delta_bar >= d_snap:
            c = cs + math.sqrt(max(cs * cs + 2.0 * (delta_bar + 2.0 / (lam * math.pi)), 0.0))
            c = min(c, c0)
            return COHESIVE, 0.0, -0.5 * lam * math.pi * c * c, c
    return SEPARATED, 0.0, 0.0, 0.0


@njit(cache=True)
def md_branch_parameter(delta_bar, lam, t_fold, delta_fold):
    """:math:`t = \\ln s` of the contact branch's point at depth :math:`\\bar\\Delta` (the solve of
    :func:`md_solve_depth`), for a caller that walks the explicit curve :func:`md_curve` from there;
    NaN where that depth is not on the contact branch (at or past its shallow end
    :math:`\\bar\\Delta_f`, a fold not yet computed, a solve that did not converge).

    Examples
    --------
    >>> md = MaugisDugdale(20e-9, 10e9, 0.1)
    >>> ds, rs, ps, lam, t_fold, delta_fold = md.kernel_args
    >>> t = md_branch_parameter(1e-9 / ds, lam, t_fold, delta_fold)
    >>> A, P, D = md_curve(math.exp(t), lam)[:3]
    >>> abs(D * ds - 1e-9) < 1e-18, abs(A * rs - md.contact_radius(depth=1e-9)) < 1e-17
    (True, True)
    """
    if not (math.isfinite(delta_bar) and delta_bar > delta_fold) or math.isnan(t_fold):
        return math.nan
    st, A, P, D, t = _branch_solve(delta_bar, lam, 0, t_fold, delta_fold, math.isfinite(t_fold))
    return t if st == CONTACT else math.nan


@njit(cache=True)
def md_solve_load(p_bar, lam, t_pull, p_pull):
    """Non-dimensional MD state at load :math:`\\bar P` on the load-control stable branch.

    ``t_pull``, ``p_pull``: ln s and :math:`\\bar P` at the pull-off point (minimum of
    :math:`\\bar P(A)`), precomputed by :class:`MaugisDugdale`.

    Returns
    -------
    (status, A, D, c) : status 0 contact, 2 separated (below pull-off: A = 0, D = -inf),
    -1 invalid input, -3 not converged (:mod:`arsurf.status`).
    """
    if not math.isfinite(p_bar):
        return NON_FINITE, 0.0, 0.0, 0.0
    if p_bar < p_pull:
        return SEPARATED, 0.0, -math.inf, 0.0
    if p_bar == p_pull:
        s = math.exp(t_pull)
        A, P, D, dA, dP, dD = md_curve(s, lam)
        return CONTACT, A, D, A * math.sqrt(1.0 + s * s)
    st, A, P, D, t = _branch_solve(p_bar, lam, 1, t_pull, p_pull, True)
    s = math.exp(t)
    return st, A, D, A * math.sqrt(1.0 + s * s)


@njit(cache=True)
def md_contact_from_depth_kernel(depth, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold):
    """Contact radius (m) and load (N) from depth (m): the haptic-loop fast path.

    All arguments are scalars; the last six are ``MaugisDugdale.kernel_args`` (computed once).
    No allocation, no exception: NaN/inf depth gives status -1.

    Returns
    -------
    (status, radius, load) : (int, float, float)
        status 0 contact, 1 cohesive (no contact, adhesive load), 2 separated (radius 0, load 0),
        -1 invalid input, -3 not converged (:mod:`arsurf.status`).
    """
    st, A, P, c = md_solve_depth(depth / depth_scale, lam, t_fold, delta_fold)
    return st, A * radius_scale, P * load_scale


@njit(cache=True)
def md_contact_hysteresis_kernel(depth, interacting, depth_scale, radius_scale, load_scale, lam, t_fold,
                                 delta_fold):
    """One tick of a displacement-controlled tip with approach/retract hysteresis.

    ``interacting`` is the state of the previous tick (True if its status was 0 contact or 1
    cohesive). A tip that was not interacting stays separated until the jump-in depth
    :math:`-h_0` (:math:`\\bar\\Delta = -2/\\lambda\\pi`); an interacting one follows the branch connected
    to contact down to the jump-out depth. Feed the returned status back:
    ``interacting = status == 0 or status == 1``.

    Returns
    -------
    (status, radius, load) : as :func:`md_contact_from_depth_kernel`.

    Examples
    --------
    >>> md = MaugisDugdale(20e-9, 50e9, 0.1, 2e9)
    >>> d = 0.5 * (md.jump_out_depth() + md.jump_in_depth())      # inside the hysteresis loop
    >>> md_contact_hysteresis_kernel(d, False, *md.kernel_args)[0], md_contact_hysteresis_kernel(d, True, *md.kernel_args)[0]
    (2, 0)
    """
    if not math.isfinite(depth):
        return NON_FINITE, 0.0, 0.0
    db = depth / depth_scale
    if not interacting and db < -2.0 / (lam * math.pi):
        return SEPARATED, 0.0, 0.0
    st, A, P, c = md_solve_depth(db, lam, t_fold, delta_fold)
    return st, A * radius_scale, P * load_scale


@njit(cache=True)
def md_radius_from_depth_kernel(depth, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold):
    """Contact radius (m) from depth (m); ``(status, radius)``. See :func:`md_contact_from_depth_kernel`.

    Examples
    --------
    >>> md = MaugisDugdale(20e-9, 50e9, 0.1, 1e9)
    >>> status, a = md_radius_from_depth_kernel(1e-9, *md.kernel_args)
    >>> status, round(a * 1e9, 6) == round(md.contact_radius(depth=1e-9) * 1e9, 6)
    (0, True)
    """
    st, A, P, c = md_solve_depth(depth / depth_scale, lam, t_fold, delta_fold)
    return st, A * radius_scale


@njit(cache=True)
def md_zone_from_depth_kernel(depth, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold):
    r"""Outer radius *c* (m) of the Dugdale zone at depth (m) on the branch connected to contact
    (:func:`md_solve_depth`: in contact and in the cohesive state, where A = 0 but the adhesive
    zone is still loaded; 0 once separated). Continuous where the contact radius reaches 0: *c*
    follows the cohesive zone down to the fold (:func:`md_zone_radius` of a contact radius gives 0
    there, a step of the zone from ~ :math:`3|\bar\Delta| / 4\lambda` radius scales to 0).

    Examples
    --------
    >>> md = MaugisDugdale(20e-9, 50e9, 0.1, 1e9)
    >>> ka = md.kernel_args
    >>> st = md.contact_state(depth=1e-9)
    >>> round(md_zone_from_depth_kernel(1e-9, *ka) / st.cohesive_radius, 9)
    1.0
    >>> d0 = md.at_radius(1e-12).depth                    # where the contact radius reaches 0
    >>> below, above = md_zone_from_depth_kernel(d0 - 1e-13, *ka), md_zone_from_depth_kernel(d0 + 1e-13, *ka)
    >>> below > 0.0 and abs(above - below) < 1e-2 * above
    True
    """
    st, A, P, c = md_solve_depth(depth / depth_scale, lam, t_fold, delta_fold)
    return c * radius_scale if st == CONTACT or st == COHESIVE else 0.0


@njit(cache=True)
def md_load_from_depth_kernel(depth, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold):
    """Load (N) from depth (m); ``(status, load)``. See :func:`md_contact_from_depth_kernel`."""
    st, A, P, c = md_solve_depth(depth / depth_scale, lam, t_fold, delta_fold)
    return st, P * load_scale


@njit(cache=True)
def _depth_many(delta_bar, lam, t_fold, delta_fold, out_a, out_p, out_c, out_status):
    for i in range(delta_bar.size):
        st, A, P, c = md_solve_depth(delta_bar[i], lam, t_fold, delta_fold)
        out_a[i] = A
        out_p[i] = P
        out_c[i] = c
        out_status[i] = st


@njit(cache=True)
def _load_many(p_bar, lam, t_pull, p_pull, out_a, out_d, out_c, out_status):
    for i in range(p_bar.size):
        st, A, D, c = md_solve_load(p_bar[i], lam, t_pull, p_pull)
        out_a[i] = A
        out_d[i] = D
        out_c[i] = c
        out_status[i] = st


@njit(cache=True)
def _radius_solve(a_bar, lam):
    """t = ln s with A(t) = a_bar (A decreases in t; ln A is nearly linear in t). (status, t)."""
    r = math.log(a_bar)
    t = (0.5 * math.log(1.5 / lam) - r) / 1.5
    t_lo = _T_MIN
    t_hi = _T_MAX
    t = min(max(t, t_lo + 0.5), t_hi - 0.5)
    for _ in range(_MAXIT):
        s = math.exp(t)
        A, P, D, dA, dP, dD = md_curve(s, lam)
        phi = math.log(A) - r
        dphi = dA * s / A
        if phi == 0.0:
            return CONTACT, t
        if phi > 0.0:
            t_lo = t
        else:
            t_hi = t
        tn = t - phi / dphi if dphi < 0.0 else 0.5 * (t_lo + t_hi)
        newton = t_lo <= tn <= t_hi and dphi < 0.0
        if not newton:
            tn = 0.5 * (t_lo + t_hi)
        if (newton and abs(tn - t) <= 1e-9) or t_hi - t_lo < 1e-13:
            return CONTACT, tn
        t = tn
    return NOT_CONVERGED, t


# ---------------------------------------------------------------------------------------------
# critical points (computed once per model)
# ---------------------------------------------------------------------------------------------

@njit(cache=True)
def _slope(t, lam, which):
    """d(value)/dt on the contact branch at t = ln s: depth (which 0) or load (which 1)."""
    s = math.exp(t)
    A, P, D, dA, dP, dD = md_curve(s, lam)
    return (dD if which == 0 else dP) * s


@njit(cache=True)
def md_critical_point_kernel(lam, which):
    """The minimum of the contact branch: the fold of :math:`\\bar\\Delta(A)` (``which`` 0) or the
    pull-off point, minimum of :math:`\\bar P(A)` (``which`` 1); ``(t, value)`` with t = ln s.

    The slope of the value along the branch is negative on the stable (large-radius) side and
    positive past the minimum (module docstring, *Shape of the curve*). It is bracketed from a
    first guess fitted to the curve (:math:`t \\approx \\max(-1.5\\ln\\lambda - 0.6,\\; 0.14 - \\ln\\lambda)`
    for the pull-off, :math:`0.5 - \\ln\\lambda` for the fold), stepping out by steps growing from 0.25
    to at most 1 (beyond the minimum the slope soon drowns in rounding: a longer step could land
    there), and its root found by the Illinois false-position method to :math:`|\\Delta t| \\le 10^{-13}`: about 15
    evaluations of :func:`md_curve` (~1 us), so it can run inside a tick.

    Returns ``(inf, Delta0)`` for the depth when :math:`\\lambda \\le \\lambda_t` (no fold) or when the
    fold lies beyond t = 40 (:math:`A < 10^{-13}`: a hair above the transition, the fold is at
    a = 0); ``(nan, nan)`` if no pull-off point is found in t = [-40, 40] (never for
    :math:`\\lambda \\in [10^{-6}, 10^6]`).

    Examples
    --------
    >>> t, p = md_critical_point_kernel(1.0, 1)
    >>> round(p, 6)        # the pull-off load in units of pi w R, between DMT (-2) and JKR (-1.5)
    -1.600735
    """
    if which == 0 and lam <= LAMBDA_TRANSITION:
        c0, d0, p0 = md_zero_radius_limit(lam)
        return math.inf, d0
    ln = math.log(lam)
    if which == 0:
        t = 0.5 - ln
    else:
        t = max(-1.5 * ln - 0.6, 0.14 - ln)
    t = min(max(t, -40.0), 40.0)
    g = _slope(t, lam, which)
    step = 0.25
    lo = hi = t
    g_lo = g_hi = g
    if g < 0.0:          # still on the stable side: the minimum lies at larger t
        while True:
            hi = min(lo + step, 40.0)
            g_hi = _slope(hi, lam, which)
            if g_hi >= 0.0:
                break
            if hi >= 40.0:
                if which == 0:
                    c0, d0, p0 = md_zero_radius_limit(lam)
                    return math.inf, d0
                return math.nan, math.nan
            lo, g_lo = hi, g_hi
            step = min(1.6 * step, 1.0)  # not past the far side, where the slope is rounding noise
    else:
        while True:
            lo = max(hi - step, -40.0)
            g_lo = _slope(lo, lam, which)
            if g_lo < 0.0:
                break
            if lo <= -40.0:
                return math.nan, math.nan
            hi, g_hi = lo, g_lo
            step = min(1.6 * step, 1.0)
    # Illinois false position on [lo, hi]: g_lo < 0 <= g_hi
    side = 0
    t = 0.5 * (lo + hi)
    for _ in range(200):
        if hi - lo <= 1e-13 * max(1.0, abs(lo)):
            break
        t = hi - g_hi * (hi - lo) / (g_hi - g_lo)
        if not (lo < t < hi):
            t = 0.5 * (lo + hi)
        g = _slope(t, lam, which)
        if g < 0.0:
            lo, g_lo = t, g
            if side == -1:
                g_hi *= 0.5
            side = -1
        else:
            hi, g_hi = t, g
            if side == 1:
                g_lo *= 0.5
            side = 1
        if g == 0.0:
            break
    A, P, D, dA, dP, dD = md_curve(math.exp(t), lam)
    return t, (D if which == 0 else P)


def _fold(lam: float, which: int) -> tuple[float, float]:
    """(t, value) at the minimum of value(t) on the contact branch; (inf, value at a=0) if none."""
    t, value = md_critical_point_kernel(float(lam), int(which))
    if math.isnan(t):
        raise ContactError(f"Maugis-Dugdale: no pull-off point found for lambda = {lam!r} in ln s = [-40, 40]; "
                           "this should not happen for lambda in [1e-6, 1e6], please report these numbers")
    return float(t), float(value)


@njit(cache=True)
def md_zone_radius(radius, depth, depth_scale, radius_scale, lam):
    """Outer radius *c* (m) of the Dugdale zone of a contact of radius *a* > 0 at depth :math:`\\delta`.

    From :math:`\\bar\\Delta = A^2 - \\tfrac43\\lambda A\\sqrt{m^2-1}`:
    :math:`\\sqrt{m^2-1} = 3(A^2 - \\bar\\Delta)/(4\\lambda A)`, :math:`c = a\\sqrt{1 + (m^2-1)}` (the
    dimensional form :math:`\\sqrt{c^2-a^2} = (a^2/R - \\delta)E^*/2\\sigma_0`). Arguments in metres
    and the first, second and fourth of ``kernel_args``; returns *a* when :math:`a \\le 0`.

    Examples
    --------
    >>> md = MaugisDugdale(20e-9, 50e9, 0.1, 1e9)
    >>> st = md.contact_state(depth=1e-9)
    >>> ds, rs, ls, lam, tf, df = md.kernel_args
    >>> round(md_zone_radius(st.radius, 1e-9, ds, rs, lam) / st.cohesive_radius, 9)
    1.0
    """
    if not radius > 0.0:
        return radius
    A = radius / radius_scale
    sm = 3.0 * (A * A - depth / depth_scale) / (4.0 * lam * A)
    if not sm > 0.0:
        return radius
    return radius * math.sqrt(1.0 + sm * sm)


@dataclass(frozen=True)
class MDCriticalPoints:
    """Where a Maugis-Dugdale contact forms and breaks (SI units; non-dimensional in ``*_bar``).

    Attributes
    ----------
    pull_off_force, pull_off_radius, pull_off_depth : float
        Load control: the minimum load of the contact branch, and where it occurs.
    jump_out_depth, jump_out_radius, jump_out_load : float
        Displacement control, retracting: the last stable state before the interaction snaps
        (radius 0 and a cohesive load for :math:`\\lambda < \\lambda_t`).
    contact_loss_depth : float
        Depth at which the contact radius reaches 0 (the fold depth for :math:`\\lambda > \\lambda_t`,
        where the contact is lost by a jump; :math:`\\bar\\Delta_0` otherwise).
    jump_in_depth : float
        Displacement control, approaching: the adhesion is first felt at a gap :math:`h_0` = w/sigma0.
    maugis_parameter : float
    """

    pull_off_force: float
    pull_off_radius: float
    pull_off_depth: float
    jump_out_depth: float
    jump_out_radius: float
    jump_out_load: float
    contact_loss_depth: float
    jump_in_depth: float
    maugis_parameter: float


@dataclass(frozen=True)
class MDState(ContactState):
    """A Maugis-Dugdale equilibrium: :class:`~arsurf.contact.mechanics.ContactState` plus the
    adhesive zone.

    Attributes
    ----------
    cohesive_radius : float, metres
        Outer radius *c* of the Dugdale zone (0 when separated).
    m : float
        c / a (``inf`` when a = 0).
    """

    cohesive_radius: float | np.ndarray = 0.0
    m: float | np.ndarray = math.inf


# ---------------------------------------------------------------------------------------------
# the model
# ---------------------------------------------------------------------------------------------

class MaugisDugdale(ContactModel):
    """Maugis-Dugdale adhesive contact, valid from the DMT (:math:`\\lambda \\to 0`) to the JKR
    (:math:`\\lambda \\to \\infty`) limit; Hertz as :math:`w \\to 0`.

    The equations, the branch structure and the solver are described in the module docstring
    (:mod:`arsurf.contact.maugis_dugdale`).

    Which branch is returned
        *Depth control* (``contact_radius(depth=)``, ``load(depth)``, ``contact_state(depth=)``):
        the state connected to contact, stable under displacement control - the large-radius
        side of the fold of :math:`\\bar\\Delta(A)`; for :math:`\\lambda < \\lambda_t` it continues as the
        cohesive no-contact state (radius 0, tensile load) down to the jump-out depth; below
        it, separation (radius 0, load 0). ``approach=True`` gives the approaching tip
        instead: separated until the jump-in depth :math:`-h_0`.
        *Load control* (``contact_radius(load=)``, ``depth(load)``): the large-radius side of the
        pull-off point; below the pull-off force there is no equilibrium.
        :meth:`equilibria` lists every equilibrium with its stability flag.

    Parameters
    ----------
    tip_radius : float, metres
        Tip radius R.
    effective_modulus : float, pascals
        :math:`E^*` with :math:`1/E^* = (1-\\nu_1^2)/E_1 + (1-\\nu_2^2)/E_2` (K = 4E*/3 is the other
        convention; the class converts).
    work_of_adhesion : float, J/m^2
        w > 0 (for w = 0 use :class:`~arsurf.contact.mechanics.Hertz`).
    dugdale_stress : float, pascals, optional
        :math:`\\sigma_0`; default :func:`arsurf.contact.materials.default_dugdale_stress` (w),
        the Lennard-Jones-matched :math:`16w/(9\\sqrt3 z_0)`.

    Examples
    --------
    >>> md = MaugisDugdale(20e-9, 50e9, 0.1, 1e9)
    >>> round(md.maugis_parameter, 4)
    0.4857
    >>> round(md.pull_off_force() / (3.141592653589793 * 0.1 * 20e-9), 4)
    -1.7239
    >>> md.contact_state(depth=-5e-9).branch       # far away: no interaction
    'separated'
    """

    name = "Maugis-Dugdale"

    def __init__(self, tip_radius: float, effective_modulus: float, work_of_adhesion: float,
                 dugdale_stress: float | None = None):
        super().__init__(tip_radius, effective_modulus, work_of_adhesion)
        if self._w == 0.0:
            raise ContactError(
                "`work_of_adhesion` must be > 0 for Maugis-Dugdale (got 0.0 J/m^2): without adhesion "
                "the Dugdale zone and lambda are undefined; use arsurf.Hertz for a non-adhesive contact"
            )
        if dugdale_stress is None:
            from arsurf.contact.materials import default_dugdale_stress

            dugdale_stress = default_dugdale_stress(self._w)
        self._sigma0 = _positive(dugdale_stress, "dugdale_stress", "Pa",
                                 "the Dugdale (cohesive) stress sigma0 in pascals, about w / z0")
        K = self.K
        self.radius_scale = (math.pi * self._w * self._R ** 2 / K) ** (1.0 / 3.0)
        self.depth_scale = self.radius_scale ** 2 / self._R
        self.load_scale = math.pi * self._w * self._R
        lam = 2.0 * self._sigma0 * (self._R / (math.pi * self._w * K * K)) ** (1.0 / 3.0)
        if not (1e-6 <= lam <= 1e6):
            raise ContactError(
                f"Maugis parameter lambda = {lam!r} is outside [1e-6, 1e6] (R={self._R!r} m, E*={self._E!r} Pa, "
                f"w={self._w!r} J/m^2, sigma0={self._sigma0!r} Pa); use DMT (lambda -> 0) or JKR (lambda -> inf)"
            )
        self._lam = lam
        self._t_fold, self._d_fold = _fold(lam, 0)
        self._t_pull, self._p_pull = _fold(lam, 1)

    def __repr__(self) -> str:
        return (f"MaugisDugdale(tip_radius={self._R!r}, effective_modulus={self._E!r}, "
                f"work_of_adhesion={self._w!r}, dugdale_stress={self._sigma0!r})")

    # -- parameters -----------------------------------------------------------------------
    @property
    def maugis_parameter(self) -> float:
        """:math:`\\lambda = 2\\sigma_0 (R/\\pi w K^2)^{1/3}` (Tabor's :math:`\\mu \\approx \\lambda/1.157`)."""
        return self._lam

    @property
    def dugdale_stress(self) -> float:
        """:math:`\\sigma_0` in pascals."""
        return self._sigma0

    @property
    def interaction_range(self) -> float:
        """Dugdale range :math:`h_0 = w/\\sigma_0` in metres."""
        return self._w / self._sigma0

    @property
    def kernel_args(self) -> tuple[float, float, float, float, float, float]:
        """``(depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold)`` for the kernels.

        ``md_radius_from_depth_kernel(depth, *md.kernel_args)`` inside an ``@njit`` loop.
        """
        return (self.depth_scale, self.radius_scale, self.load_scale, self._lam,
                self._t_fold, self._d_fold)

    # -- hooks ----------------------------------------------------------------------------
    def _solve_depth_full(self, depth: np.ndarray):
        db = np.ascontiguousarray(depth / self.depth_scale, dtype=np.float64)
        A = np.empty_like(db)
        P = np.empty_like(db)
        c = np.empty_like(db)
        st = np.empty(db.shape, np.int64)
        _depth_many(db, self._lam, self._t_fold, self._d_fold, A, P, c, st)
        self._check(st, depth, "depth")
        return A * self.radius_scale, P * self.load_scale, st, c * self.radius_scale

    def _solve_depth(self, depth):
        r, p, st, _ = self._solve_depth_full(depth)
        return r, p, st

    def _solve_load_full(self, load: np.ndarray):
        pb = np.ascontiguousarray(load / self.load_scale, dtype=np.float64)
        A = np.empty_like(pb)
        D = np.empty_like(pb)
        c = np.empty_like(pb)
        st = np.empty(pb.shape, np.int64)
        _load_many(pb, self._lam, self._t_pull, self._p_pull, A, D, c, st)
        self._check(st, load, "load")
        return A * self.radius_scale, D * self.depth_scale, c * self.radius_scale

    def _solve_load(self, load):
        r, d, _ = self._solve_load_full(load)
        return r, d

    def _check(self, status, query, what):
        bad = status < 0
        if bad.any():
            i = int(np.argmax(bad))
            raise ContactError(
                f"Maugis-Dugdale solver failed (status {int(status.ravel()[i])}) for {what} "
                f"{float(np.ravel(query)[i])!r} with lambda = {self._lam!r}; this is a bug, please report it "
                "with these numbers"
            )

    # -- critical points ------------------------------------------------------------------
    def pull_off_force(self) -> float:
        """Pull-off force under load control (N, negative): :math:`-2\\pi wR` (DMT) ... :math:`-1.5\\pi wR` (JKR)."""
        return self._p_pull * self.load_scale

    def jump_out_depth(self) -> float:
        """Depth (m) at which a retracting tip loses all interaction under displacement control."""
        if math.isfinite(self._t_fold):
            return self._d_fold * self.depth_scale
        c0, d0, p0 = md_zero_radius_limit(self._lam)
        cs = 8.0 * self._lam / (3.0 * math.pi)
        if cs < c0:
            return (-2.0 / (self._lam * math.pi) - 0.5 * cs * cs) * self.depth_scale
        return d0 * self.depth_scale

    def jump_in_depth(self) -> float:
        """Depth (m) at which an approaching tip first feels the adhesion: :math:`-h_0 = -w/\\sigma_0`."""
        return -self.interaction_range

    def critical_points(self) -> MDCriticalPoints:
        """Pull-off (load control), jump-out and jump-in (displacement control) in one record."""
        sp = math.exp(self._t_pull)
        A_p, P_p, D_p, *_ = md_curve(sp, self._lam)
        c0, d0, p0 = md_zero_radius_limit(self._lam)
        if math.isfinite(self._t_fold):
            A_f, P_f, D_f, *_ = md_curve(math.exp(self._t_fold), self._lam)
            jo_r, jo_p, loss = A_f * self.radius_scale, P_f * self.load_scale, D_f * self.depth_scale
        else:
            cs = 8.0 * self._lam / (3.0 * math.pi)
            c = max(cs, 0.0) if cs < c0 else c0
            jo_r, jo_p, loss = 0.0, -0.5 * self._lam * math.pi * c * c * self.load_scale, d0 * self.depth_scale
        return MDCriticalPoints(
            pull_off_force=P_p * self.load_scale,
            pull_off_radius=A_p * self.radius_scale,
            pull_off_depth=D_p * self.depth_scale,
            jump_out_depth=self.jump_out_depth(),
            jump_out_radius=jo_r,
            jump_out_load=jo_p,
            contact_loss_depth=loss,
            jump_in_depth=self.jump_in_depth(),
            maugis_parameter=self._lam,
        )

    # -- records --------------------------------------------------------------------------
    def contact_state(self, depth=None, *, load=None, approach: bool = False) -> MDState:
        """The stable equilibrium as an :class:`MDState` (radius, load, depth, flags, zone c, m).

        Exactly one of ``depth`` (displacement control; ``approach`` as in
        :meth:`~arsurf.contact.mechanics.ContactModel.contact_radius`) or ``load`` (load control).

        Examples
        --------
        >>> md = MaugisDugdale(20e-9, 50e9, 0.1, 3e8)      # lambda < 0.938: DMT-like
        >>> st = md.contact_state(depth=md.critical_points().contact_loss_depth - 1e-11)
        >>> st.branch, st.in_contact, st.radius, st.load < 0
        ('cohesive', False, 0.0, True)
        """
        if (depth is None) == (load is None):
            raise ContactError("contact_state needs exactly one of depth=... (m) or load=... (N)")
        if depth is not None:
            d, scalar = _finite_array(depth, "depth", "depth is the indentation in metres (R - signed distance of the tip centre)")
            flat = np.atleast_1d(d).ravel()
            radius, ld, code, c = self._solve_depth_full(flat)
            if approach:
                out = flat < self.jump_in_depth()
                radius = np.where(out, 0.0, radius)
                ld = np.where(out, 0.0, ld)
                c = np.where(out, 0.0, c)
                code = np.where(out, SEPARATED, code)
            dep = flat
        else:
            p, scalar = _finite_array(load, "load", "load is the normal force in newtons (negative = tensile)")
            flat = np.atleast_1d(p).ravel()
            radius, dep, c = self._solve_load_full(flat)
            below = flat < self.pull_off_force()
            code = np.where(below, SEPARATED, CONTACT)
            ld = np.where(below, 0.0, flat)
            d = p
        shape = d.shape
        with np.errstate(divide="ignore", invalid="ignore"):
            m = np.where(radius > 0.0, c / np.where(radius > 0.0, radius, 1.0), math.inf)
        return self._md_record(radius.reshape(shape), ld.reshape(shape), dep.reshape(shape),
                               (code == CONTACT).reshape(shape), np.ones(shape, bool),
                               code.reshape(shape), c.reshape(shape), m.reshape(shape), scalar)

    @staticmethod
    def _md_record(radius, load, depth, in_contact, stable, code, c, m, scalar) -> MDState:
        names = np.array(["contact", "cohesive", "separated"])[np.asarray(code, np.int64)]
        if scalar:
            return MDState(float(radius), float(load), float(depth), bool(in_contact), bool(stable),
                           str(names), float(c), float(m))
        return MDState(radius, load, depth, in_contact, stable, names, c, m)

    def _state_at_t(self, t: float, stable: bool, depth=None, load=None) -> MDState:
        s = math.exp(t)
        A, P, D, *_ = md_curve(s, self._lam)
        m = math.sqrt(1.0 + s * s)
        return MDState(A * self.radius_scale, P * self.load_scale if load is None else float(load),
                       D * self.depth_scale if depth is None else float(depth), True, stable, "contact",
                       m * A * self.radius_scale, m)

    def at_radius(self, radius) -> MDState:
        """The equilibrium with contact radius *a* (m): load, depth, zone; the forward map A -> (P, Delta).

        ``stable`` is the stability under displacement control (False on the small-radius side
        of the fold, :math:`\\lambda > \\lambda_t`). Scalar input only.
        """
        a = _positive(radius, "radius", "m", "the contact radius in metres")
        st, t = _radius_solve(a / self.radius_scale, self._lam)
        if st < 0:
            raise ContactError(f"Maugis-Dugdale: radius {a!r} m could not be placed on the curve (lambda {self._lam!r})")
        return self._state_at_t(t, stable=bool(t <= self._t_fold))

    def equilibria(self, depth=None, *, load=None) -> list[MDState]:
        """Every equilibrium at one scalar depth or load, with its stability flag.

        Displacement control: the stable contact state, the unstable small-contact state
        (:math:`\\lambda > \\lambda_t`, between the fold and :math:`\\bar\\Delta_0`), the cohesive
        no-contact states (stable where :math:`\\bar c > 8\\lambda/3\\pi`) and the separated state
        (when the gap exceeds :math:`h_0`). Load control: the stable and unstable contact states
        and the (always unstable) cohesive state. Sorted by decreasing contact/zone radius.
        """
        from scipy.optimize import brentq

        if (depth is None) == (load is None):
            raise ContactError("equilibria needs exactly one of depth=... (m) or load=... (N)")
        q = depth if depth is not None else load
        if np.ndim(q) != 0:
            raise ContactError("equilibria() takes one scalar depth or load (got an array)")
        lam = self._lam
        c0, d0, p0 = md_zero_radius_limit(lam)
        cs = 8.0 * lam / (3.0 * math.pi)
        out: list[MDState] = []
        if depth is not None:
            d_arr, _ = _finite_array(depth, "depth", "depth is the indentation in metres")
            dval = float(d_arr)
            db = dval / self.depth_scale
            if db > self._d_fold or (math.isfinite(self._t_fold) and db == self._d_fold):
                st = self.contact_state(depth=dval)
                out.append(st)
            if math.isfinite(self._t_fold) and self._d_fold < db < d0:
                f = lambda t: md_curve(math.exp(t), lam)[2] - db   # noqa: E731  increasing past the fold
                hi = self._t_fold + 1.0
                while f(hi) < 0.0 and hi < _T_MAX:
                    hi += 1.0
                if f(hi) >= 0.0:
                    t = brentq(f, self._t_fold, hi, xtol=1e-14, rtol=1e-15)
                    out.append(self._state_at_t(t, stable=False, depth=dval))
            disc = cs * cs + 2.0 * (db + 2.0 / (lam * math.pi))
            if disc >= 0.0:
                for sign in (1.0, -1.0):
                    c = cs + sign * math.sqrt(disc)
                    if 0.0 < c <= c0 and not (sign < 0 and disc == 0.0):
                        out.append(MDState(0.0, -0.5 * lam * math.pi * c * c * self.load_scale, dval, False,
                                           bool(c > cs), "cohesive", c * self.radius_scale, math.inf))
            if db <= -2.0 / (lam * math.pi):
                out.append(MDState(0.0, 0.0, dval, False, True, "separated", 0.0, math.inf))
            # the stable cohesive state is already in the list when contact_state returned it
            seen, unique = set(), []
            for st in out:
                key = (st.branch, round(st.cohesive_radius / self.radius_scale, 12), st.stable)
                if key not in seen:
                    seen.add(key)
                    unique.append(st)
            out = unique
        else:
            p_arr, _ = _finite_array(load, "load", "load is the normal force in newtons")
            pval = float(p_arr)
            pb = pval / self.load_scale
            if pb >= self._p_pull:
                out.append(self.contact_state(load=pval))
            if self._p_pull < pb < p0:
                f = lambda t: md_curve(math.exp(t), lam)[1] - pb   # noqa: E731
                hi = self._t_pull + 1.0
                while f(hi) < 0.0 and hi < _T_MAX:
                    hi += 1.0
                if f(hi) >= 0.0:
                    t = brentq(f, self._t_pull, hi, xtol=1e-14, rtol=1e-15)
                    out.append(self._state_at_t(t, stable=False, load=pval))
            if p0 <= pb < 0.0:
                c = math.sqrt(-2.0 * pb / (lam * math.pi))
                dd = 0.5 * c * c - cs * c - 2.0 / (lam * math.pi)
                out.append(MDState(0.0, pval, dd * self.depth_scale, False, False, "cohesive",
                                   c * self.radius_scale, math.inf))
        out.sort(key=lambda st: (st.radius, st.cohesive_radius), reverse=True)
        return out
