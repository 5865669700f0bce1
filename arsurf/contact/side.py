r"""A tip pressed into a thin wall stays on the side it came from.

The collision answer is the *global* closest point of the surface to the tip centre C. While C is
outside the sample that is the point the sphere touches. A hand that presses harder than the
coupling and the law can hold drives C behind the surface (signed distance
:math:`d = (C - S)\cdot n < 0`, the depth :math:`\delta = R - d` beyond the tip radius); in a wall
thinner than twice that depth, C then crosses the wall's middle, where the closest point of the
*other* face becomes the global one, and the force, :math:`P(\delta)\,n` with the other face's
normal, flips in one tick: the pop-through of penalty rendering (on a 19 nm high ridge 3.8 nm wide
under a 3.1 nm tip, a slide pressed 3.9 nm into the flank and the hand's 17 mN flipped to -17 mN).
The god-object exists to prevent it: its proxy never crosses a surface, so the user feels a wall
stay a wall however far the hand pushes (Zilles & Salisbury 1995, "A constraint-based god-object
method for haptic display", IROS; Ruspini, Kolarov & Khatib 1997).

The same memory here (:func:`keep_side_kernel`): while C is behind the closest point's face, that
face's normal :math:`n_0` is remembered; when the global answer turns to a face whose normal
opposes it (:math:`n\cdot n_0 < 0`), Newton's method is run from the previous closest point, and
if it ends on a face of the remembered side (:math:`n\cdot n_0 > 0`) with C still behind it, that
point is the collision answer: the force keeps pushing the hand back out the way it came, growing
with the depth until the haptic loop's saturation caps it. The memory ends when C is out of the
material again on that side (d >= 0), or when no minimum of that side is left to follow (Newton
does not converge there, or converges to the other side): the global answer then stands.
A tip outside the sample is never affected (no memory), nor is a tip pressed deep into a single
face (the global answer keeps its side: no opposing normal).
"""
from __future__ import annotations

import math

from numba import njit

from arsurf.contact import layout as ly
from arsurf.contact.newton import newton_foot

__all__ = ["keep_side_kernel"]


@njit(cache=True)
def keep_side_kernel(ctrl, ku, kv, ev, cx, cy, cz, radius, prev_u, prev_v, side, at, coll) -> None:
    """Keep the collision answer ``coll`` (:data:`~arsurf.contact.layout.COLLISION_OUT`, the global
    closest point of the rest net ``ctrl, ku, kv`` to the tip centre (cx, cy, cz) m, of radius
    ``radius`` m) on the side the tip came from (module docstring); ``prev_u, prev_v`` the previous
    tick's closest point (NaN: none), ``side[at:at + 3]`` the remembered normal (NaN: none; updated
    here), ``ev`` (>= 6, 3) scratch."""
    n0x, n0y, n0z = side[at], side[at + 1], side[at + 2]
    if (math.isfinite(n0x) and math.isfinite(prev_u) and math.isfinite(prev_v)
            and coll[ly.OUT_NX] * n0x + coll[ly.OUT_NY] * n0y + coll[ly.OUT_NZ] * n0z < 0.0):
        h = max(ku[4] - ku[3], kv[4] - kv[3])
        u, v, ax, ay, az, signed, ok = newton_foot(ctrl, ku, kv, ev, cx, cy, cz, prev_u, prev_v, h)
        if ok and signed < 0.0 and ax * n0x + ay * n0y + az * n0z > 0.0:  # still behind a face of that side
            coll[ly.OUT_U] = u
            coll[ly.OUT_V] = v
            coll[ly.OUT_WARM_U] = u  # where Newton from the previous point ends: no jump
            coll[ly.OUT_WARM_V] = v
            for j in range(3):
                coll[ly.OUT_PX + j] = ev[0, j]
            coll[ly.OUT_NX] = ax
            coll[ly.OUT_NY] = ay
            coll[ly.OUT_NZ] = az
            coll[ly.OUT_DISTANCE] = signed
            coll[ly.OUT_DEPTH] = radius - signed
    inside = coll[ly.OUT_DISTANCE] < 0.0
    for j in range(3):
        side[at + j] = coll[ly.OUT_NX + j] if inside else math.nan
