r"""The tip behind a virtual coupling: the indentation at which the contact balances the coupling.

A haptic device renders a contact stably only up to a stiffness set by its own damping and the
loop period (Colgate & Schenkel 1997: :math:`b > K T / 2`). A sample's contact stiffness seen
through the position and force scales (:math:`K_f\,s\,dP/d\delta`) easily exceeds it, so the
contact is rendered through a *virtual coupling* (Colgate, Stanley & Brown 1995; Adams &
Hannaford 1999): a spring :math:`k_c` (N/m, at the probe's scale) between the target - where the
scaled stylus puts the tip - and the tip itself, which sits where the contact load balances the
spring. Along the contact normal, with :math:`\delta_t` the indentation the target would make,

.. math:: P(\delta) = k_c\,(\delta_t - \delta),

one equation in :math:`\delta`, solved by Newton's method from the previous tick's depth (the
tip moves along the normal of its closest point, which keeps that closest point, so no second
collision is needed). The hand then feels the series stiffness
:math:`(1/k_c + 1/(dP/d\delta))^{-1} \le k_c`, and at rest exactly the contact load: the
coupling costs no transparency in the steady state. Where no equilibrium near the previous one
exists (the contact's own snap-off, :math:`dP/d\delta < -k_c`), the tip follows the target for
that tick (``coupled`` = False): the contact snaps as it would without the coupling.
"""
from __future__ import annotations

import math

from numba import njit

from arsurf._layout import Layout
from arsurf.contact.maugis_dugdale import md_contact_hysteresis_kernel
from arsurf.status import SEPARATED
_MAX_ITER = 60
#: the last Maugis-Dugdale answer of the coupling's Newton run: the depth (m) it was evaluated
#: at, the answer (status, radius m, load N) and the law's ``kernel_args`` it was made with. The
#: run ends on that depth and the next tick's run starts from it: looked up instead of solved
#: again (one of the ~6 solves of a tick), the same bits as the solve
MD_MEMO = Layout("coupling memo", [("depth", 1), ("answer", 3), ("law", 6)])
_M_DEPTH, _M_ANSWER, _M_LAW = MD_MEMO.offset("depth"), MD_MEMO.offset("answer"), MD_MEMO.offset("law")
MEMO_SIZE = MD_MEMO.size


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

    Returns ``(status, radius, load, depth, coupled)``: the Maugis-Dugdale answer at the tip's
    depth (:func:`~arsurf.contact.maugis_dugdale.md_contact_hysteresis_kernel`) and whether the
    coupling equation was solved (False: no coupling, no contact or invalid input; the tip is at
    the target)."""
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
