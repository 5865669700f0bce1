r"""The tip behind a virtual coupling: the indentation at which the contact balances the coupling.

A haptic device renders a contact stably only up to a stiffness set by its own damping and the
loop period (Colgate & Schenkel 1997: :math:`b > K T / 2`). A sample's contact stiffness seen
through the position and force scales (:math:`K_f\,s\,dP/d\delta`) easily exceeds it, so the
contact is rendered through a *virtual coupling* (Colgate, Stanley & Brown 1995; Adams &
Hannaford 1999): a spring :math:`k_c` (N/m, at the probe's scale) between the target - where the
scaled stylus puts the tip - and the tip itself, which sits where the contact load balances the
spring. Along the contact normal, with :math:`\delta_t` the indentation the target would make,

.. math:: P(\delta) = k_c\,(\delta_t - \delta),

one equation in :math:`\delta`, solved by Newton's method from the previous tick's answer (the
tip moves along the normal of its closest point, which keeps that closest point, so no second
collision is needed). Where the target and the equilibrium lie on the contact branch (a > 0), the
equation is solved along the branch's own parameter :math:`t = \ln s` of the explicit
Maugis-Dugdale curve (:func:`~arsurf.contact.maugis_dugdale.md_curve`: depth, load and their
derivatives in closed form), :math:`g(t) = P(t) - k_c(\delta_t - \delta(t))`,
:math:`g'(t) = P'(t) + k_c\,\delta'(t)`: one evaluation of the curve per Newton step and no
Maugis-Dugdale solve, warm-started from the previous tick's :math:`t`; elsewhere (the cohesive neck
of a fold-free law, a target off the branch, a material map's law whose fold is not computed) by
Newton's method in :math:`\delta` on the law's solves with a finite-difference slope. Both stop at
:math:`|g| \le 10^{-9} P_s` (:math:`P_s` the law's load scale), so they agree to that residual
(``tests/contact/test_proxy.py``: depth, load and radius within :data:`BRANCH_TOLERANCE` of the
law's scales). The hand then feels the series stiffness
:math:`(1/k_c + 1/(dP/d\delta))^{-1} \le k_c`, and at rest exactly the contact load: the
coupling costs no transparency in the steady state. Where no equilibrium near the previous one
exists (the contact's own snap-off, :math:`dP/d\delta < -k_c`), the tip follows the target for
that tick (``coupled`` = False): the contact snaps as it would without the coupling.
"""
from __future__ import annotations

import math

from numba import njit

from arsurf._layout import Layout
from arsurf.contact.maugis_dugdale import (T_RANGE, md_branch_parameter, md_contact_hysteresis_kernel, md_curve,
                                           md_zero_radius_limit)
from arsurf.status import CONTACT, SEPARATED
_MAX_ITER = 60
#: the last Maugis-Dugdale answer of the coupling's Newton run: the depth (m) it was evaluated
#: at, the answer (status, radius m, load N) and the law's ``kernel_args`` it was made with. The
#: run ends on that depth and the next tick's run starts from it: looked up instead of solved
#: again (one of the ~6 solves of a tick), the same bits as the solve; and the contact branch's
#: parameter t = ln s where the last solve along the branch ended (the next one starts there)
MD_MEMO = Layout("coupling memo", [("depth", 1), ("answer", 3), ("law", 6), ("branch_t", 1)])
_M_DEPTH, _M_ANSWER, _M_LAW = MD_MEMO.offset("depth"), MD_MEMO.offset("answer"), MD_MEMO.offset("law")
_M_T = MD_MEMO.offset("branch_t")
MEMO_SIZE = MD_MEMO.size
#: the largest difference of the solve along the branch from the solve in depth (the law's solves
#: and a finite-difference slope), in the law's scales: depth / depth scale, load / load scale,
#: radius / radius scale (both stop at a residual of 1e-9 load scales; tests/contact/test_proxy.py)
BRANCH_TOLERANCE = 1e-8


@njit(cache=True)
def _md_interacting(depth, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold, memo):
    """``md_contact_hysteresis_kernel(depth, True, law...)``, a pure function of its arguments,
    looked up in ``memo`` (:data:`MD_MEMO`) when it holds exactly these arguments (never for NaN
    ones), else solved and kept there."""
    law = memo[_M_LAW:_M_LAW + 6]
    if (memo[_M_DEPTH] == depth and law[0] == depth_scale and law[1] == radius_scale and law[2] == load_scale
            and law[3] == lam and law[4] == t_fold and law[5] == delta_fold):
        return int(memo[_M_ANSWER]), memo[_M_ANSWER + 1], memo[_M_ANSWER + 2]
    s, r, p = md_contact_hysteresis_kernel(depth, True, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold)
    memo[_M_DEPTH] = depth
    memo[_M_ANSWER] = s
    memo[_M_ANSWER + 1] = r
    memo[_M_ANSWER + 2] = p
    law[0] = depth_scale
    law[1] = radius_scale
    law[2] = load_scale
    law[3] = lam
    law[4] = t_fold
    law[5] = delta_fold
    return s, r, p


@njit(cache=True)
def coupled_depth_kernel(target_depth, start_depth, interacting, k_couple, jump_out_depth, zero_load_depth,
                         depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold, memo):
    r"""Depth of the tip behind a coupling of stiffness ``k_couple`` (N/m; ``inf``: none).

    ``target_depth`` δ_t (m), ``start_depth`` the previous tick's tip depth (NaN: none),
    ``interacting`` the hysteresis state, ``jump_out_depth`` and ``zero_load_depth`` (m) of the
    contact law, then ``MaugisDugdale.kernel_args``.

    The root of :math:`g(\delta) = P(\delta) - k_c(\delta_t - \delta)` is bracketed -
    :math:`[\delta_{out}, \delta_t]` when :math:`P(\delta_t) > 0` (g < 0 at the jump-out depth,
    where the load is tensile), else :math:`[\delta_t, \delta_0]` (g >= 0 at the zero-load
    depth) - and found by Newton's method from the previous depth, falling back to bisection
    whenever a step leaves the bracket: it always converges. ``memo`` (:data:`MD_MEMO`, kept
    between ticks; NaN: empty) holds the last answer at a Newton iterate: the run that starts
    where the last one ended finds its first answer there.

    Where the target is on the contact branch, the equilibrium is first sought along the branch
    (:func:`_branch_coupled`, module docstring), and the run in depth only when it is not there.

    Returns ``(status, radius, load, depth, coupled)``: the Maugis-Dugdale answer at the tip's
    depth (:func:`~arsurf.contact.maugis_dugdale.md_contact_hysteresis_kernel`) and whether the
    coupling equation was solved (False: no coupling, no contact or invalid input; the tip is at
    the target)."""
    if k_couple < math.inf and _on_contact_branch(target_depth / depth_scale, interacting, lam, t_fold, delta_fold):
        if target_depth > zero_load_depth:  # a compressive load at the target: the tip is shallower
            lo, hi = jump_out_depth, target_depth
        else:
            lo, hi = target_depth, max(zero_load_depth, target_depth)
        ok, a, load, depth = _branch_coupled(target_depth, start_depth, lo, hi, k_couple, depth_scale, radius_scale,
                                             load_scale, lam, t_fold, delta_fold, memo)
        if ok:
            return CONTACT, a, load, depth, True
    return _depth_coupled(target_depth, start_depth, interacting, k_couple, jump_out_depth, zero_load_depth,
                          depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold, memo)


@njit(cache=True)
def _on_contact_branch(delta_bar, interacting, lam, t_fold, delta_fold):
    """Whether :func:`~arsurf.contact.maugis_dugdale.md_contact_hysteresis_kernel` answers
    contact at the non-dimensional depth ``delta_bar`` by the contact branch's solve (its tests,
    without the solve): finite, reached (interacting, or at or past the jump-in depth
    :math:`-2/\\lambda\\pi`) and above the branch's shallow end (the fold, or the a = 0 end of a
    fold-free law; a fold not computed yet: no)."""
    return (math.isfinite(delta_bar) and not math.isnan(t_fold) and delta_bar > delta_fold
            and (interacting or delta_bar >= -2.0 / (lam * math.pi)))


@njit(cache=True)
def _branch_coupled(target_depth, start_depth, lo, hi, k_couple, depth_scale, radius_scale, load_scale, lam, t_fold,
                    delta_fold, memo):
    r"""The coupling equation along the contact branch (module docstring): Newton's method in
    :math:`t = \ln s` on :math:`g(t) = P(t) - k_c(\delta_t - \delta(t))`, the root kept inside the
    depth bracket ``[lo, hi]`` (m; g <= 0 at ``lo``, >= 0 at ``hi``) and the branch's t range
    (bisection whenever a step leaves it), started at the memo's t (``memo``'s ``branch_t``, the
    last run's end) or, without one, at the branch point of ``start_depth`` (else of the target).

    Returns ``(ok, radius, load, depth)`` (m, N, m) at the root, |g| <= 1e-9 load scales, the
    memo's t updated; ``ok`` False (nothing changed) where the equilibrium is not on the branch
    (a fold-free law whose zero-radius end already pulls harder than the coupling: the cohesive
    neck) or the run did not converge."""
    t_lo, t_hi = T_RANGE  # t grows towards the shallow end: a deep iterate raises t_lo
    if t_fold < math.inf:
        t_hi = t_fold
    else:
        c0, d0, p0 = md_zero_radius_limit(lam)
        if p0 * load_scale - k_couple * (target_depth - d0 * depth_scale) >= 0.0:
            return False, 0.0, 0.0, 0.0
    t = memo[_M_T]
    if not t_lo < t < t_hi:
        start = start_depth if (math.isfinite(start_depth) and lo < start_depth < hi) else target_depth
        t = md_branch_parameter(start / depth_scale, lam, t_fold, delta_fold)
        if not t_lo < t < t_hi:
            return False, 0.0, 0.0, 0.0
    tol = 1e-9 * load_scale
    for _ in range(_MAX_ITER):
        s = math.exp(t)
        A, P, D, dA, dP, dD = md_curve(s, lam)
        depth = D * depth_scale
        load = P * load_scale
        g = load - k_couple * (target_depth - depth)
        inside = lo <= depth <= hi
        if inside and abs(g) <= tol:
            memo[_M_T] = t
            return True, A * radius_scale, load, depth
        if depth > hi or (inside and g > 0.0):
            t_lo = t
        else:
            t_hi = t
        slope = s * (dP * load_scale + k_couple * dD * depth_scale)  # dg/dt, < 0 on a stable equilibrium
        step = t - g / slope if (inside and slope < 0.0) else math.nan
        t = step if t_lo < step < t_hi else 0.5 * (t_lo + t_hi)
        if not t_hi - t_lo > 1e-15 * (1.0 + abs(t)):
            break
    return False, 0.0, 0.0, 0.0


@njit(cache=True)
def _depth_coupled(target_depth, start_depth, interacting, k_couple, jump_out_depth, zero_load_depth, depth_scale,
                   radius_scale, load_scale, lam, t_fold, delta_fold, memo):
    """The coupling equation by Newton's method in depth on the law's solves (finite-difference
    slope, :func:`coupled_depth_kernel`'s bracket, the memo of the last solve): the path for
    everything :func:`_branch_coupled` does not solve. Same arguments and answer as
    :func:`coupled_depth_kernel`."""
    st, a, load = md_contact_hysteresis_kernel(target_depth, interacting, depth_scale, radius_scale, load_scale,
                                               lam, t_fold, delta_fold)
    if not (k_couple < math.inf) or st < 0 or st == SEPARATED:
        return st, a, load, target_depth, False
    if load > 0.0:
        lo, hi = max(jump_out_depth, -math.inf), target_depth
    else:
        lo, hi = target_depth, max(zero_load_depth, target_depth)
    depth = start_depth if (math.isfinite(start_depth) and lo < start_depth < hi) else 0.5 * (lo + hi)
    h = 1e-4 * depth_scale
    tol = 1e-9 * load_scale
    s, r, p = st, a, load
    for _ in range(_MAX_ITER):
        s, r, p = _md_interacting(depth, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold, memo)
        if s == SEPARATED:  # below the jump-out depth: the bracket's floor
            lo = depth
            depth = 0.5 * (lo + hi)
            continue
        g = p - k_couple * (target_depth - depth)
        if abs(g) <= tol or hi - lo <= 1e-9 * depth_scale:
            return s, r, p, depth, True
        if g > 0.0:
            hi = depth
        else:
            lo = depth
        s2, r2, p2 = md_contact_hysteresis_kernel(depth + h, True, depth_scale, radius_scale, load_scale,
                                                  lam, t_fold, delta_fold)
        slope = (p2 - p) / h + k_couple
        step = depth - g / slope if (s2 != SEPARATED and slope > 0.0) else math.nan
        depth = step if lo < step < hi else 0.5 * (lo + hi)
    return s, r, p, depth, s != SEPARATED
