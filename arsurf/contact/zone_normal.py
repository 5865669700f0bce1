r"""The direction a contact pushes: the resultant over its zone, not the normal at one point.

A sphere pressed on a surface is pushed by a pressure spread over its contact zone, and the
direction of the resultant is the pressure-weighted mean of the surface normals there (Johnson,
*Contact Mechanics*, 1985: the resultant of a distributed contact). Only on a smooth patch that is
flat or curved like a sphere around the closest point is it the normal at the closest point. On a
rough scan it is not, and the closest point is a poor stand-in: where the distance from the tip
centre C to the surface is nearly the same over a patch (a hollow that fits the tip, or two walls
of a groove inside one contact zone) the closest point wanders over the patch with picometres of
travel, minima being born and dying under it, and its normal turns with it - on a power-law
surface under a 7.0 nm tip the closest point hopped 0.5 nm to and fro inside one hollow and the
normal turned by 0.15 rad each time: 15 nN steps of a 120 nN force in a 1 nm/s slide, which only the
loop's low-passed normal had hidden (:mod:`arsurf.haptics.loop`; docs/feel-log.rst).

So each contact pushes along the resultant of a distributed interaction over the patch around
its point (u_c, v_c): the elastic-foundation (Winkler) picture of the contact, in which the
pressure at a surface point grows with the local interference of the sphere (Johnson 1985), with
the interaction range added so that an adhesive contact, which may not penetrate, has a zone too,
summed over samples as a point-shell sums the penalty forces of its points in contact (McNeely,
Puterbaugh & Troy 1999, "Six degree-of-freedom haptic rendering using voxel sampling", SIGGRAPH).
Over a stencil of :data:`ZONE_NODES` x :data:`ZONE_NODES` points :math:`(u_k, v_k)` spaced evenly
over :math:`u_c \pm \rho`, :math:`v_c \pm \rho`, :math:`\rho` = :data:`ZONE_HALF_WIDTH` R,

.. math::

    N = \mathrm{unit}\Big((R - \delta_f - d)\,n_c + \sum_k w_k\,(S_u \times S_v)_k\Big), \qquad
    w_k = \big(R - \delta_f - \lVert S_k - C\rVert\big)_+\,\max(\cos\theta_k, 0)\,
          \Big(1 - \frac{r_k^2}{c^2}\Big)_+ ,

:math:`n_c` the point's own normal (the stencil's centre sample, weighed as a flat patch's, so that N
turns continuously into it as the zone shrinks to nothing; the sum runs over the other samples), d
the centre's distance to the point, :math:`(S_u \times
S_v)_k` the area-weighted normal at the sample (out of the sample), :math:`\cos\theta_k` the cosine
between it and :math:`C - S_k` (a patch facing away from the centre does not push it),
:math:`\delta_f < 0` the interaction floor (the deepest separation at which the law still acts),
:math:`r_k` the sample's distance from the point in (u, v) and c the contact's Dugdale-zone radius
at its depth under the tip. The window keeps a contact to its own zone: without it, the stencil
of one wall of a valley narrower than the tip reached the other wall, and the walls' normals,
turning with the target, passed the valley's stiffness past the virtual coupling sideways (7.7 N/m
behind a 5 N/m coupling, tests/contact/test_force_field.py). The weights vanish continuously at
the zone's edge, and the samples do not move as the depth changes (a stencil scaled with the zone
moved its samples over a rough surface as the load changed, and turned the normal by 0.57 rad in
four ticks of a 10 nm/s slide). A light touch, whose zone holds no sample but the point, pushes
along the point's normal; a deep one along its zone's mean. Where the centre comes near the
surface (d below :data:`ZONE_FADE` R; behind the patch, d < 0, when a hand presses through a thin
wall) the zone is no longer a cap under the sphere, and N turns linearly back to the point's own
normal, reached at d = 0.

Measured (``bench/feel.py``, the generated families), with the loop's low-passed normal removed
as well: on 120 surfaces of a seed the table had not been tuned on (seed 1), 732 -> 753 of 788
runs passed, tick-to-tick reversals 348 -> 198, energy below the passive store summed -400 ->
-32 E0 (docs/feel-log.rst). A 7 x 7 stencil passed 759 but cost a tick up to 1 us more.
"""
from __future__ import annotations

import math

from numba import njit

from arsurf.spline.basis import surface_point

#: samples of the stencil along u and along v
ZONE_NODES = 5
#: the stencil reaches this many tip radii from the contact's point in u and in v
ZONE_HALF_WIDTH = 0.75
#: below this distance of the centre from the surface (in tip radii) the zone's direction fades to
#: the point's own normal
ZONE_FADE = 0.25


@njit(cache=True)
def zone_normal_kernel(ctrl, ku, kv, ev, cx, cy, cz, radius, floor, depth, zone, uc, vc, n) -> None:
    r"""Turn the unit normal ``n`` (3,) of a contact at (``uc``, ``vc``) into the resultant direction
    over its zone (module docstring), in place. ``ctrl, ku, kv`` the net; (cx, cy, cz) the tip centre
    and ``radius`` its radius (m); ``floor`` the interaction floor (m, a depth); ``depth`` the
    contact's depth :math:`R - d` (m); ``zone`` the radius (m) of its zone; ``ev`` (>= 3, 3) scratch.
    ``n`` is left as it is where the zone is empty (out of reach, ``zone`` <= 0) or the centre is
    behind the patch."""
    reach = radius - floor
    d = radius - depth
    if not (reach > 0.0 and 0.0 < d < reach and zone > 0.0):
        return
    rho = ZONE_HALF_WIDTH * radius
    step = 2.0 * rho / (ZONE_NODES - 1)
    lo_u, hi_u = ku[3], ku[ku.shape[0] - 4]
    lo_v, hi_v = kv[3], kv[kv.shape[0] - 4]
    w0 = reach - d  # the contact's own point, the stencil's centre: its normal, weighed as a sample there
    sx, sy, sz = w0 * n[0], w0 * n[1], w0 * n[2]
    for a in range(ZONE_NODES):
        du = -rho + a * step
        for b in range(ZONE_NODES):
            dv = -rho + b * step
            window = 1.0 - (du * du + dv * dv) / (zone * zone)
            if window <= 0.0 or (a == b == ZONE_NODES // 2):  # outside the zone; the point itself: counted
                continue
            u = min(max(uc + du, lo_u), hi_u)
            v = min(max(vc + dv, lo_v), hi_v)
            surface_point(ctrl, ku, kv, u, v, 1, ev)
            dx, dy, dz = cx - ev[0, 0], cy - ev[0, 1], cz - ev[0, 2]
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            w = reach - dist
            if not (w > 0.0 and dist > 0.0):
                continue
            ax = ev[1, 1] * ev[2, 2] - ev[1, 2] * ev[2, 1]
            ay = ev[1, 2] * ev[2, 0] - ev[1, 0] * ev[2, 2]
            az = ev[1, 0] * ev[2, 1] - ev[1, 1] * ev[2, 0]
            an = math.sqrt(ax * ax + ay * ay + az * az)
            c = (dx * ax + dy * ay + dz * az) / dist if an > 0.0 else 0.0
            if c > 0.0:  # the area-weighted normal times the cosine, the window and the interference
                f = w * window * c / an
                sx += f * ax
                sy += f * ay
                sz += f * az
    s = math.sqrt(sx * sx + sy * sy + sz * sz)
    if not (s > 0.0 and math.isfinite(s)):
        return
    t = min(d / (ZONE_FADE * radius), 1.0)
    mx = (1.0 - t) * n[0] + t * sx / s
    my = (1.0 - t) * n[1] + t * sy / s
    mz = (1.0 - t) * n[2] + t * sz / s
    m = math.sqrt(mx * mx + my * my + mz * mz)
    if m > 0.0:
        n[0] = mx / m
        n[1] = my / m
        n[2] = mz / m
