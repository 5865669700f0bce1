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
face's normal :math:`n_0` is remembered and the face is *followed*, as the god-object's proxy stays
on its face: Newton's method is run from the previous closest point, within :data:`TRACK_REACH` knot
spacings, and if it ends on a face of the remembered side (:math:`n\cdot n_0 > 0`) with C still
behind it, that point is the collision answer wherever the global one is a face turned more than
60 degrees from it (:data:`FOLLOW_COS`): the force keeps pushing the hand back out the way it came,
growing with the depth until the haptic loop's saturation caps it. A global answer within 60
degrees of the face followed is taken: where a tip pressed straight down on a crest slides off
it, the crest's minimum splits into one on each flank, and the global answer picks the flank
C is nearer - a function of C, where Newton's run from the crest picked a flank by rounding, and a
1 kHz and a 10 kHz press on a generated ridge slid off opposite sides (rates 147 % apart).
The memory ends when C is out of the material again on that side (d >= 0), or when no minimum of
that side is left to follow (Newton does not converge within reach - the face has ended, at a
corner or a fold - or converges to the other side): the global answer then stands.
A tip outside the sample is never affected (no memory).

Followed, not only checked against the opposite face: a memory that let the global answer through
whenever its normal did not oppose :math:`n_0`, and remembered that face instead, was handed on
from face to face across a wall - from a flank to the top, whose normal is at less than 90 degrees
to both flanks, then to the other flank - and the target popped through after all
(tests/contact/test_side.py: a flat-topped ridge pushed through 2 nm below its top, -126 nN after
+126 nN; on a generated power-law surface under a 4 nm tip, a slide at 100 nm/s jammed by friction
against an asperity went through it at 10 kHz via a face whose normal was at 89.7 degrees to the
flank's, and at 1 kHz, whose ticks stepped over that face, 110 ms later: rates 107 % apart).
"""
from __future__ import annotations

import math

from numba import njit

from arsurf.contact import layout as ly
from arsurf.contact.newton import newton_foot

__all__ = ["keep_side_kernel"]

#: the face is followed by Newton's method from the previous tick's closest point within this many
#: knot spacings (a foot moves far less between two ticks; beyond, the face is not this one)
TRACK_REACH = 2.0
#: a followed foot within this many knot spacings of the global answer is the global answer
SAME_FOOT = 1e-6
#: the followed face is kept against a global answer whose normal is turned from it by more than
#: 60 degrees (this cosine); a global answer closer in direction is taken
FOLLOW_COS = 0.5


@njit(cache=True)
def keep_side_kernel(ctrl, ku, kv, ev, cx, cy, cz, radius, prev_u, prev_v, side, at, coll) -> None:
    """Keep the collision answer ``coll`` (:data:`~arsurf.contact.layout.COLLISION_OUT`, the global
    closest point of the rest net ``ctrl, ku, kv`` to the tip centre (cx, cy, cz) m, of radius
    ``radius`` m) on the side the tip came from (module docstring); ``prev_u, prev_v`` the previous
    tick's closest point (NaN: none), ``side[at:at + 3]`` the remembered normal (NaN: none; updated
    here), ``ev`` (>= 6, 3) scratch."""
    n0x, n0y, n0z = side[at], side[at + 1], side[at + 2]
    if math.isfinite(n0x) and math.isfinite(prev_u) and math.isfinite(prev_v):
        h = max(ku[4] - ku[3], kv[4] - kv[3])
        u, v, ax, ay, az, signed, ok = newton_foot(ctrl, ku, kv, ev, cx, cy, cz, prev_u, prev_v, h,
                                                   TRACK_REACH * h)
        moved = max(abs(u - coll[ly.OUT_U]), abs(v - coll[ly.OUT_V]))
        turn = ax * coll[ly.OUT_NX] + ay * coll[ly.OUT_NY] + az * coll[ly.OUT_NZ]
        if ok and signed < 0.0 and ax * n0x + ay * n0y + az * n0z > 0.0 and moved > SAME_FOOT * h \
                and turn < FOLLOW_COS:
            # the face followed is still in front of C; the global answer is another face, turned away
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
