r"""A second contact point: the tip sphere in a valley narrower than itself touches two slopes.

Where the tip centre C is (nearly) equidistant from two parts of the surface - a valley or pit
narrower than the sphere, common on real scans - the closest point jumps from one slope to the
other as C crosses the valley's medial axis, and it can alternate tick after tick while the hand
holds the tip there: the contact normal, hence the force direction, flips back and forth (a buzz
the hand feels; found on real scans at 10-100 nm/s). A rigid sphere there rests on both slopes,
and the force it feels is the sum of two contact forces.

Every tick, Newton's method (:func:`~arsurf.contact.newton.newton_box`) is run from the previous
closest point: when it converges to another local minimum of the distance than the global search
found (the closest point jumped basins), that point is a *second contact*, and it is followed the
same way while it lasts. When the closest point jumps into the basin of the second contact
being followed (the second became the deepest), Newton from that second finds the closest point
itself: the two swap roles, and the point the closest point left - found by Newton from the
previous closest point - is the second contact now (without the swap the normal fell back to
:math:`n_1` alone for that tick, a step back and forth the hand felt on a rough scan).

Newton from the previous closest point ending at another local minimum than the closest point
is also the one exact test that the closest point *jumped* (changed basins) this tick, whatever
the sizes of the moves; the kernel reports it for the friction proxy
(:func:`~arsurf.contact.friction.stick_slip_kernel`), which carries its anchor along a jump.
(The global search starts with that same run over the same domain, ``OUT_WARM_U``/``OUT_WARM_V``
of its answer: when it ended at the closest point there is no second run.)

While its depth :math:`\delta_2` is within ``margin`` of the deepest :math:`\delta_1`, the normal
is the weighted sum

.. math:: n = \frac{n_1 + w\,n_2}{\lVert n_1 + w\,n_2 \rVert}, \qquad
          w = \max\!\left(0,\ 1 - \frac{\delta_1 - \delta_2}{\text{margin}}\right),

symmetric in the two points at equal depth (so the alternation of the closest point no longer
changes the normal) and fading to :math:`n_1` as the second contact lifts off; it is then
forgotten. The load stays that of the deepest point: this is a regularisation of the direction,
not a two-contact mechanics.

State (2 floats of the model state): the second contact's (u, v), NaN when there is none.
"""
from __future__ import annotations

import math

from numba import njit

from arsurf.contact import layout as ly
from arsurf.contact.newton import MAX_ITER_DOMAIN, STEP_TOL, newton_box

#: two converged Newton answers closer than this (in knot spacings) are the same point (Newton
#: stops at 1e-9 of a knot spacing)
SAME_POINT = 1e-6


@njit(cache=True)
def second_contact_kernel(ctrl, ku, kv, ev, cx, cy, cz, radius, prev_u, prev_v, margin, state, at, coll):
    """Blend the normal ``coll[OUT_NX:OUT_NZ + 1]`` (a collision answer, :mod:`~arsurf.contact.layout`)
    with the second contact's, in place; ``state[at:at + 2]`` is the second contact (updated);
    ``prev_u, prev_v`` the previous tick's closest point (NaN: none). ``ev`` (>= 6, 3) scratch.
    Returns the weight w of the second contact (0: none) and whether the closest point jumped
    basins this tick (Newton from the previous closest point ended at another local minimum)."""
    u1 = coll[ly.OUT_U]
    v1 = coll[ly.OUT_V]
    h = max(ku[4] - ku[3], kv[4] - kv[3])
    ua = state[at]
    va = state[at + 1]
    tracked = math.isfinite(ua) and math.isfinite(va)
    state[at] = math.nan
    state[at + 1] = math.nan
    if not tracked:
        # the point the closest point was at: if it jumped basins, that one is the second. When
        # the collision query's own Newton run from there (over the same domain) converged to the
        # closest point, this one would too: one contact, no jump, no second run
        if math.hypot(coll[ly.OUT_WARM_U] - u1, coll[ly.OUT_WARM_V] - v1) <= SAME_POINT * h:
            return 0.0, False
        ua = prev_u
        va = prev_v
    if not (math.isfinite(ua) and math.isfinite(va)):
        return 0.0, False
    nu = ku.shape[0]
    nv = kv.shape[0]
    ua, va, d2, it, conv = newton_box(ctrl, ku, kv, ev, cx, cy, cz, ua, va, ku[3], ku[nu - 4], kv[3], kv[nv - 4],
                                      STEP_TOL * h, STEP_TOL * h, h, MAX_ITER_DOMAIN)
    if (not conv or math.hypot(ua - u1, va - v1) <= SAME_POINT * h) and tracked \
            and math.isfinite(prev_u) and math.isfinite(prev_v):
        # the second contact became the deepest (the closest point jumped into its basin): the
        # point the closest point left is the second now, the two swap roles
        tracked = False
        ua, va, d2, it, conv = newton_box(ctrl, ku, kv, ev, cx, cy, cz, prev_u, prev_v, ku[3], ku[nu - 4], kv[3],
                                          kv[nv - 4], STEP_TOL * h, STEP_TOL * h, h, MAX_ITER_DOMAIN)
    if not conv or math.hypot(ua - u1, va - v1) <= SAME_POINT * h:
        return 0.0, False  # Newton from there finds the closest point itself: one contact
    jumped = not tracked  # Newton from the previous closest point ends in another basin
    ax = ev[1, 1] * ev[2, 2] - ev[1, 2] * ev[2, 1]
    ay = ev[1, 2] * ev[2, 0] - ev[1, 0] * ev[2, 2]
    az = ev[1, 0] * ev[2, 1] - ev[1, 1] * ev[2, 0]
    an = math.sqrt(ax * ax + ay * ay + az * az)
    if not an > 0.0:
        return 0.0, jumped
    n1x = coll[ly.OUT_NX]
    n1y = coll[ly.OUT_NY]
    n1z = coll[ly.OUT_NZ]
    if ax * n1x + ay * n1y + az * n1z < 0.0:
        an = -an
    ax /= an
    ay /= an
    az /= an
    depth2 = radius - ((cx - ev[0, 0]) * ax + (cy - ev[0, 1]) * ay + (cz - ev[0, 2]) * az)
    w = 1.0 - (coll[ly.OUT_DEPTH] - depth2) / margin
    if not w > 0.0:
        return 0.0, jumped
    w = min(w, 1.0)
    state[at] = ua
    state[at + 1] = va
    bx = n1x + w * ax
    by = n1y + w * ay
    bz = n1z + w * az
    bn = math.sqrt(bx * bx + by * by + bz * bz)
    coll[ly.OUT_NX] = bx / bn
    coll[ly.OUT_NY] = by / bn
    coll[ly.OUT_NZ] = bz / bn
    return w, jumped
