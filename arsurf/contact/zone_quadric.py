r"""The zone law in closed form over a smooth contact: one term where the lattice sums a thousand.

:mod:`arsurf.contact.zone_energy` sums the zone law (:mod:`arsurf.contact.zone_law`) over ~1000
lattice samples under a contact 1-3 nm deep, whatever the surface. Where the surface is smooth at
the scale of the contact the vertical gap between the tip and the surface about its minimum
:math:`g_0` (at :math:`x^*`) is nearly quadratic, :math:`G(x) \approx g_0 + \tfrac12 (x -
x^*)^T M (x - x^*)`, M the gap's Hessian there (the sphere's curvature less the surface's), so
the area within a gap g grows linearly, :math:`dA = 2\pi\,dg/\sqrt{\det M}`. Keeping the sphere's
own shape to the next order (over a flat the area within s = g - g0 of the minimum is
:math:`\pi(2Rs - s^2)`), the energy of the whole tip is one term,

.. math::

    E(T) = \frac{2\pi}{\sqrt{\det M}}\,J(g_0), \qquad
    J(g_0) = \int_{g_0}^{h_0} \varphi(g) \left(1 - \frac{g - g_0}{R}\right) dg
           = \left(1 + \frac{g_0}{R}\right) I_0 - \frac{I_1}{R},

:math:`I_0 = \int_{g_0}^{h_0} \varphi\,dg` and :math:`I_1 = \int_{g_0}^{h_0} g\,\varphi\,dg` in
closed form for the law (:func:`law_moments`). ``bench/zone_quadric.py`` measured it against the
lattice: the load within 0.9-2.1 % on the smooth scans (the lattice's own error on a flat is
0.8-1.7 %), 43-53 % off where the surface is rough under the tip.

**The force** is its exact gradient. The gap :math:`G(x; T) = T_z - \sqrt{R^2 - |x - T_{xy}|^2}
- z(x)` is least at :math:`x^*(T)`, where :math:`(x^* - T_{xy})/\rho = \nabla z`
(:math:`\rho = \sqrt{R^2 - |x^* - T_{xy}|^2}`), so by the envelope theorem :math:`\nabla_T g_0
= n = (-\nabla z(x^*), 1)`; the minimum moves as :math:`dx^*/dT_{xy} = M^{-1} S`, S the sphere's
Hessian :math:`\delta_{ab}/\rho + d_a d_b/\rho^3` (:math:`d = x^* - T_{xy}`), not with
:math:`T_z`; and with :math:`M = S(d) - H_z(x^*)`,

.. math::

    \frac{dM}{dT_k} = \sum_l \Big(\frac{\partial S}{\partial d_l} - \frac{\partial H_z}{\partial x_l}\Big)
        \Big(M^{-1} S\Big)_{lk} - \frac{\partial S}{\partial d_k}, \qquad
    \frac{\partial S_{ab}}{\partial d_c} = \frac{\delta_{ab} d_c + \delta_{ac} d_b + \delta_{bc} d_a}{\rho^3}
        + \frac{3 d_a d_b d_c}{\rho^5},

:math:`\partial \det M/\partial T_k = \mathrm{tr}(\mathrm{adj}(M)\,dM/dT_k)`, which needs the
slope of the surface's curvature :math:`\partial H_z/\partial x`; then

.. math::

    F = -\nabla_T E = -2\pi\left(\frac{J'(g_0)}{\sqrt{\det M}}\,n
        - \frac{J(g_0)}{2 (\det M)^{3/2}}\,\nabla_T \det M\right), \qquad
    J' = -\varphi(g_0) + \frac{I_0}{R}, \quad J'' = p(g_0) - \frac{\varphi(g_0)}{R}.

A bicubic spline's curvature is only continuous: its slope steps where :math:`x^*` crosses a knot
line, and E would have a kink there, F a step (2.9 nN, 160 times its change over a 2 pm step
elsewhere, on a surface rough at its 0.5 nm knots under a 10 nm tip). So in :math:`\det M` (and
only there) :math:`H_z` is the curvature's own C2 field (:mod:`arsurf.spline.curvature`: the
variation-diminishing spline of each second derivative on knots twice as dense), the curvature
averaged over about a knot interval, and :math:`\partial H_z/\partial x` its slope; the minimum
and its motion :math:`M^{-1}S` keep the spline's own. The force is then continuous, and still the
exact gradient of the E it belongs to.

**The Hessian** (for a proxy's Newton step) keeps the terms of first order in
:math:`\nabla\det M` and leaves out its second derivatives (the surface's fourth):
:math:`\nabla^2 E \approx \frac{2\pi}{\sqrt{\det M}}(J'' n n^T + J' \nabla n) - \frac{\pi
J'}{(\det M)^{3/2}}(n \nabla\det M^T + \nabla\det M\,n^T) + \frac{3\pi J}{2 (\det
M)^{5/2}}\nabla\det M\,\nabla\det M^T`, with :math:`\nabla n` the value function's Hessian
:math:`S - S M^{-1} S` across (zero along :math:`T_z`).

The term holds where the gap is near its model over the whole zone of interaction (a single
smooth contact, on the tip's sphere): :func:`quadric_contact_kernel` says when it cannot find that
minimum (no minimum, M not positive definite, or the minimum past the sphere onto the cone), and
how far it can be trusted, a weight whose gradient in T is exact (:func:`_fit_weight`); the caller
joins it to a lattice's sum by that weight (:func:`~arsurf.contact.zone_energy.tip_energy_kernel`).
Its checks look at 24 points, and beyond them at a bound of the surface's third derivative over the
tip's reach, which says where a second minimum of the gap could hide inside the zone between those
points (:func:`_remainder_weight`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf.contact.zone_law import _COS_CONE, Z_ENERGY, Z_FORCE, ZONE_OUT, _cone, _law, _rise
from arsurf.errors import ContactError
from arsurf.spline.basis import height_jet, height_slope
from arsurf.spline.curvature import curvature_jet, curvature_net

__all__ = ["QUADRIC_OUT", "law_moments", "quadric_contact", "quadric_contact_kernel"]

#: what :func:`quadric_contact_kernel` writes: E (J) and F (N) as :data:`~arsurf.contact.zone_law.ZONE_OUT`,
#: then the least gap g0 (m), where it lies (u, v: the net's parameters, also where the next call starts),
#: det M (m^-2), the minimum x* (m), its motion X = dx*/dT_xy (row-major), the surface's slope there, the check
#: circle's radius (m) and the weight with its gradient in T (1/m; :func:`_fit_weight`)
QUADRIC_OUT = ZONE_OUT.extended("quadric contact output", [
    ("gap", 1), ("uv", 2), ("curvature", 1), ("point", 2), ("motion", 4), ("slope", 2), ("check_radius", 1),
    ("weight", 4)])
(Q_GAP, Q_UV, Q_DET, Q_POINT, Q_MOTION, Q_SLOPE, Q_CHECK, Q_WEIGHT) = (QUADRIC_OUT.offset(f)
                                                                       for f in QUADRIC_OUT.fields[2:])
#: the check circle about the minimum, where the gap must stay clear of h0 and beyond which a lattice is asked the
#: same (zone_energy.isolation_kernel), in units of the zone's radius on a flat at the same least gap,
#: :math:`\sqrt{2R(h_0 - g_0)}` (the zone within it while the gap's smaller curvature is at least 1/(c^2 R), 0.44/R)
CHECK_RADIUS = 1.5
#: points on each of the two circles checked (the zone's edge and the check circle)
RING_POINTS = 12
#: beyond the check circle a ring this fraction of it wide, where a lattice's samples fade into view (zone_energy)
RING_WIDTH = 0.25
#: the gap's deviation from the one term's model on the zone's edge, over the gap's range h0 - g0 (its even part's
#: rms plus the square of its odd part's: :func:`_ring_fit`), below which the one term is trusted wholly (not at
#: all above twice it)
FIT_TOLERANCE = 0.03
#: the measure of a second minimum inside the zone (:func:`_remainder_weight`) up to which the one term is trusted
#: wholly (not at all above twice it)
REMAINDER_TOLERANCE = 2.0
#: the gap (a fraction of h0) above h0 that every point of the check circle keeps for the one term to be
#: trusted wholly (it fades to nothing as one reaches h0)
CLEAR_MARGIN = 1.0
#: the margins (fractions of R) over which the one term fades as its circle nears the tip's cone or the scan's edge
ROOM_MARGIN = 0.1
#: Newton's method for the gap's minimum stops when its step is below this fraction of R (g0 then to ~1e-18 R)
MINIMUM_TOL = 1e-9
#: and fails after this many steps
MINIMUM_ITERATIONS = 30
#: a step of Newton's method for the minimum is at most this fraction of R
MINIMUM_STEP = 0.25
#: what :func:`quadric_contact_kernel` returns when it finds no minimum: M not positive definite on the way,
#: the minimum not reached in MINIMUM_ITERATIONS steps, or past the sphere onto the cone
NO_MINIMUM, NOT_CONVERGED, ON_THE_CONE = -1, -2, -3


@njit(cache=True)
def law_moments(g0, radius, e_star, sigma0, h0):
    r"""``(I0, I1)``: :math:`\int_{g_0}^{h_0} \varphi(g)\,dg` (J/m) and :math:`\int_{g_0}^{h_0}
    g\,\varphi(g)\,dg` (J) of the zone law (:mod:`arsurf.contact.zone_law`: :math:`\varphi =
    \tfrac23 k(-g)^{3/2} - w` below 0, :math:`k = E^*/\pi\sqrt R`; :math:`-\sigma_0(h_0 - g) -
    \sigma_0 h_0 \sin(2\pi g/h_0)/2\pi` on (0, h0)), in closed form; 0 from h0 on."""
    stiff, w = e_star / (math.pi * math.sqrt(radius)), sigma0 * h0
    i0 = i1 = 0.0
    if g0 < 0.0:  # over [g0, 0], t = -g in [0, d]
        d = -g0
        sd = math.sqrt(d)
        i0 += 4.0 / 15.0 * stiff * d * d * sd - w * d
        i1 += -4.0 / 21.0 * stiff * d * d * d * sd + 0.5 * w * d * d
    a = max(g0, 0.0)
    if a < h0:  # over [a, h0], q = 2 pi / h0: int sin(q g) dg and int g sin(q g) dg by parts
        q = 2.0 * math.pi / h0
        s0, c0 = math.sin(q * a), math.cos(q * a)
        amp = sigma0 * h0 / (2.0 * math.pi)
        i0 += -0.5 * sigma0 * (h0 - a) ** 2 + amp * (1.0 - c0) / q
        lin = -sigma0 * (0.5 * h0 * (h0 * h0 - a * a) - (h0 ** 3 - a ** 3) / 3.0)
        gs = -h0 / q - (s0 / (q * q) - a * c0 / q)
        i1 += lin - amp * gs
    return i0, i1


@njit(cache=True, error_model="numpy")
def quadric_contact_kernel(ctrl, ku, kv, curv, curv_ku, curv_kv, tx, ty, tz, radius, e_star, sigma0, h0, out,
                           hess) -> int:
    r"""E(T) and F(T) of the module docstring at the tip centre T = (tx, ty, tz) (m) over the
    height-field net (``ctrl``, ``ku``, ``kv``; ``curv``, ``curv_ku``, ``curv_kv`` its curvature's own
    fields, :func:`~arsurf.spline.curvature.curvature_net`). The gap's minimum by Newton's method from
    ``out``'s (u, v) (:data:`QUADRIC_OUT`; NaN, or beyond the tip's reach: from under the tip),
    each step at most :data:`MINIMUM_STEP` R, down the gap's slope where M is not positive
    definite. Writes ``out`` (:data:`QUADRIC_OUT`): E (J), F (N), g0 (m), the minimum's (u, v) and
    the rest, the weight with its gradient last; ``hess`` (3, 3), unless empty, E's Hessian (N/m,
    module docstring). Returns Newton's steps, or :data:`NO_MINIMUM`, :data:`NOT_CONVERGED`,
    :data:`ON_THE_CONE` (E, F and the weight then 0, the caller's to replace)."""
    want = hess.shape[0] == 3
    out[Z_ENERGY] = out[Z_FORCE] = out[Z_FORCE + 1] = out[Z_FORCE + 2] = 0.0
    out[Q_WEIGHT] = out[Q_WEIGHT + 1] = out[Q_WEIGHT + 2] = out[Q_WEIGHT + 3] = 0.0
    if want:
        hess[:, :] = 0.0
    # from the last minimum, or from under the tip where there is none within the tip's reach (x affine in u,
    # y in v: a point's parameters are its coordinates mapped)
    u0, u1, v0, v1 = ku[3], ku[ku.shape[0] - 4], kv[3], kv[kv.shape[0] - 4]
    x0, x1 = ctrl[0, 0, 0], ctrl[ctrl.shape[0] - 1, 0, 0]
    y0, y1 = ctrl[0, 0, 1], ctrl[0, ctrl.shape[1] - 1, 1]
    u, v = out[Q_UV], out[Q_UV + 1]
    ox = x0 + (u - u0) / (u1 - u0) * (x1 - x0) - tx
    oy = y0 + (v - v0) / (v1 - v0) * (y1 - y0) - ty
    if not ox * ox + oy * oy < _COS_CONE * _COS_CONE * radius * radius:  # NaN too
        u = min(max(u0 + (tx - x0) / (x1 - x0) * (u1 - u0), u0), u1)
        v = min(max(v0 + (ty - y0) / (y1 - y0) * (v1 - v0), v0), v1)
    steps, found = 0, False
    r2 = radius * radius
    x = y = xu = yv = z = zu = zv = zuu = zuv = zvv = 0.0
    dx = dy = rho = rho2 = zx = zy = i3 = mxx = mxy = myy = det = 0.0
    for it in range(MINIMUM_ITERATIONS + 1):
        x, y, xu, yv, z, zu, zv, zuu, zuv, zvv = height_jet(ctrl, ku, kv, u, v)[:10]
        dx, dy = x - tx, y - ty
        rho2 = r2 - dx * dx - dy * dy
        if rho2 <= 0.0:
            return NO_MINIMUM
        rho = math.sqrt(rho2)
        zx, zy = zu / xu, zv / yv
        i3 = 1.0 / (rho * rho2)
        mxx = 1.0 / rho + dx * dx * i3 - zuu / (xu * xu)
        mxy = dx * dy * i3 - zuv / (xu * yv)
        myy = 1.0 / rho + dy * dy * i3 - zvv / (yv * yv)
        det = mxx * myy - mxy * mxy
        convex = det > 0.0 and mxx > 0.0
        if found:
            if not convex:
                return NO_MINIMUM  # a saddle or a maximum of the gap
            break  # the point just evaluated is the minimum, to MINIMUM_TOL
        if it == MINIMUM_ITERATIONS:
            return NOT_CONVERGED
        gx, gy = dx / rho - zx, dy / rho - zy
        if convex:
            sx, sy = -(myy * gx - mxy * gy) / det, -(mxx * gy - mxy * gx) / det
        else:  # down the gap's slope, on the scale of the sphere's curvature
            sx, sy = -rho * gx, -rho * gy
        size = math.sqrt(sx * sx + sy * sy)
        if size > MINIMUM_STEP * radius:
            sx *= MINIMUM_STEP * radius / size
            sy *= MINIMUM_STEP * radius / size
        steps += 1
        u += sx / xu
        v += sy / yv
        found = size < MINIMUM_TOL * radius
    out[Q_UV], out[Q_UV + 1] = u, v
    if dx * dx + dy * dy >= (_COS_CONE * radius) ** 2:
        return ON_THE_CONE
    g0 = tz - rho - z
    # the energy's curvature from the curvature's own C2 field (its slopes continuous across knot lines);
    # the minimum and its motion from the spline's own (exact)
    (hxx, hxy, hyy, bound, hxx_x, hxy_x, hyy_x, bound_x, hxx_y, hxy_y, hyy_y,
     bound_y) = curvature_jet(curv, curv_ku, curv_kv, u, v, xu, yv)
    sxx, sxy, syy = 1.0 / rho + dx * dx * i3, dx * dy * i3, 1.0 / rho + dy * dy * i3
    kxx, kxy, kyy = sxx - hxx, sxy - hxy, syy - hyy
    curved = kxx * kyy - kxy * kxy
    if not (curved > 0.0 and kxx > 0.0):
        return NO_MINIMUM
    out[Q_GAP], out[Q_DET] = g0, curved
    # the sphere's Hessian S and the minimum's motion X = dx*/dT_xy = M^-1 S (rows: x*, columns: T)
    ixx, ixy, iyy = myy / det, -mxy / det, mxx / det
    xxx, xxy = ixx * sxx + ixy * sxy, ixx * sxy + ixy * syy
    xyx, xyy = ixy * sxx + iyy * sxy, ixy * sxy + iyy * syy
    out[Q_POINT], out[Q_POINT + 1] = x, y
    out[Q_MOTION], out[Q_MOTION + 1], out[Q_MOTION + 2], out[Q_MOTION + 3] = xxx, xxy, xyx, xyy
    out[Q_SLOPE], out[Q_SLOPE + 1] = zx, zy
    # dS_ab/dd_c = (delta_ab d_c + delta_ac d_b + delta_bc d_a) / rho^3 + 3 d_a d_b d_c / rho^5
    i5 = 3.0 * i3 / rho2
    s_xxx = 3.0 * dx * i3 + i5 * dx * dx * dx
    s_xxy = dy * i3 + i5 * dx * dx * dy
    s_xyy = dx * i3 + i5 * dx * dy * dy
    s_yyy = 3.0 * dy * i3 + i5 * dy * dy * dy
    # dK/dx_l (l = x, y) at fixed T, K = S - H~ the energy's curvature; dK/dT_k = sum_l dK/dx_l X_lk - dS/dd_k
    axx_x, axy_x, ayy_x = s_xxx - hxx_x, s_xxy - hxy_x, s_xyy - hyy_x
    axx_y, axy_y, ayy_y = s_xxy - hxx_y, s_xyy - hxy_y, s_yyy - hyy_y
    dxx_x, dxy_x, dyy_x = axx_x * xxx + axx_y * xyx - s_xxx, axy_x * xxx + axy_y * xyx - s_xxy, \
        ayy_x * xxx + ayy_y * xyx - s_xyy
    dxx_y, dxy_y, dyy_y = axx_x * xxy + axx_y * xyy - s_xxy, axy_x * xxy + axy_y * xyy - s_xyy, \
        ayy_x * xxy + ayy_y * xyy - s_yyy
    reach = CHECK_RADIUS * math.sqrt(2.0 * radius * max(h0 - g0, 0.0))
    out[Q_CHECK] = reach
    model = (tx, ty, tz, u, v, xu, yv, x, y, zx, zy, g0, kxx, kxy, kyy, dxx_x, dxy_x, dyy_x, dxx_y, dxy_y, dyy_y,
             xxx, xxy, xyx, xyy, bound, bound_x, bound_y)
    _fit_weight(ctrl, ku, kv, model, reach, radius, h0, out)
    if g0 >= h0:
        return steps
    # d det K = tr(adj K dK)
    ddx = kyy * dxx_x - 2.0 * kxy * dxy_x + kxx * dyy_x
    ddy = kyy * dxx_y - 2.0 * kxy * dxy_y + kxx * dyy_y
    i0, i1 = law_moments(g0, radius, e_star, sigma0, h0)
    j = (1.0 + g0 / radius) * i0 - i1 / radius
    phi_r, phi_a, p, _ = _law(g0, e_star / (math.pi * math.sqrt(radius)), sigma0, h0, 0.0)
    phi = phi_r + phi_a
    j1 = -phi + i0 / radius
    root = math.sqrt(curved)
    a = 2.0 * math.pi / root  # E = a J
    b = math.pi * j / (curved * root)  # the det term: grad E = a J' n - b grad det
    nx, ny = -zx, -zy
    out[Z_ENERGY] = a * j
    out[Z_FORCE] = -(a * j1 * nx - b * ddx)
    out[Z_FORCE + 1] = -(a * j1 * ny - b * ddy)
    out[Z_FORCE + 2] = -a * j1
    if want:
        j2 = p - phi / radius
        # the value function's Hessian across: S - S M^-1 S
        vxx = sxx - (sxx * xxx + sxy * xyx)
        vxy = sxy - (sxx * xxy + sxy * xyy)
        vyy = syy - (sxy * xxy + syy * xyy)
        c = math.pi * j1 / (curved * root)
        e = 1.5 * math.pi * j / (curved * curved * root)
        n = (nx, ny, 1.0)
        gd = (ddx, ddy, 0.0)
        for r in range(3):
            for q in range(3):
                hess[r, q] = a * j2 * n[r] * n[q] - c * (n[r] * gd[q] + gd[r] * n[q]) + e * gd[r] * gd[q]
        hess[0, 0] += a * j1 * vxx
        hess[0, 1] += a * j1 * vxy
        hess[1, 0] += a * j1 * vxy
        hess[1, 1] += a * j1 * vyy
    return steps


@njit(cache=True, inline="always")
def smootherstep(t):
    """``(S(t), S'(t))``: :math:`6t^5 - 15t^4 + 10t^3` on [0, 1], 0 below and 1 above; its first and second
    derivatives vanish at both ends (Perlin 2002), so a weight made of it joins two energies with a force
    continuous and a stiffness continuous."""
    if t <= 0.0:
        return 0.0, 0.0
    if t >= 1.0:
        return 1.0, 0.0
    return t * t * t * (t * (6.0 * t - 15.0) + 10.0), 30.0 * t * t * (1.0 - t) * (1.0 - t)


@njit(cache=True)
def _fit_weight(ctrl, ku, kv, model, reach, radius, h0, out):
    r"""How far the one term can be trusted, into ``out``'s weight (1: wholly, 0: not) and its gradient
    in T (1/m): the product of smooth steps (:func:`smootherstep`), each of a quantity whose
    gradient in T is exact, so the weight's is:

    - the fit: the one term is exact for a gap :math:`G = g_0 + s(q)`, :math:`s(q) = R - \sqrt{R^2 -
      2Rq}`, :math:`q = \tfrac12 \xi^T M \xi` (elliptic contours, each as far in gap as the sphere's
      own profile over a flat: the area within s is :math:`2\pi(s - s^2/2R)/\sqrt{\det M}`, the
      factor of the module docstring); the deviation :math:`\delta = G - g_0 - s(q)` on
      :data:`RING_POINTS` points of the zone's edge, :math:`\sqrt{2R(h_0 - g_0)}` from :math:`x^*`,
      over the gap's range :math:`h_0 - g_0` (its even part's rms, its odd part's squared:
      :func:`_ring_fit`), below :data:`FIT_TOLERANCE` (1) to twice it (0);
    - nothing else near: on the check circle, :data:`CHECK_RADIUS` times as far, the gap at least
      :math:`h_0` + :data:`CLEAR_MARGIN` h0 (:func:`_ring_clear`; beyond the circle
      :func:`~arsurf.contact.zone_energy.isolation_kernel` asks the same of the lattice);
    - the sphere: the zone, from the tip's axis, within the sphere's part of the tip
      (:math:`|x^* - T_{xy}| + r_c/c < R\cos\alpha`), by a margin :data:`ROOM_MARGIN` R
      (beyond it the cone, which a lattice's samples see);
    - the scan: the check circle and its ring a margin :data:`ROOM_MARGIN` R inside the net's edges;
    - no second minimum inside the zone between the checks' points: the surface's third derivative,
      bounded over the tip's reach, too small to make one (:func:`_remainder_weight`).

    ``model``: T, the minimum's (u, v), x_u, y_v, x*, slope, g0, M, dM/dT_x, dM/dT_y, X = dx*/dT
    and the third derivative's bound B (1/m^2) with its slope in x (M the energy's: the curvature's
    own field, module docstring).
    The circles move with :math:`x^*` (X) and their radii with :math:`g_0` (:math:`\nabla r_c =
    -(c^2 R / r_c)\,n`, :math:`n = (-\nabla z, 1)`)."""
    tx, ty, tz, u, v, xu, yv, x, y, zx, zy, g0 = model[:12]
    xxx, xxy, xyx, xyy = model[21], model[22], model[23], model[24]
    nx, ny = -zx, -zy  # grad g0 = (nx, ny, 1)
    grc = -(CHECK_RADIUS * CHECK_RADIUS * radius / reach) if reach > 0.0 else 0.0  # grad r_c = grc (nx, ny, 1)
    zone = reach / CHECK_RADIUS  # the zone's radius on a flat
    # the sphere's room: |d| + r_c / c below R cos(alpha)
    dx, dy = x - tx, y - ty
    dist = math.sqrt(dx * dx + dy * dy)
    w1, s1 = smootherstep((_COS_CONE * radius - dist - zone) / (ROOM_MARGIN * radius))
    g1x = g1y = g1z = 0.0
    if s1 != 0.0:  # d|d|/dT_xy = (d / |d|)^T (X - I)
        ex, ey = (dx / dist, dy / dist) if dist > 0.0 else (0.0, 0.0)
        k = -s1 / (ROOM_MARGIN * radius)
        g1x = k * (ex * (xxx - 1.0) + ey * xyx + grc * nx / CHECK_RADIUS)
        g1y = k * (ex * xxy + ey * (xyy - 1.0) + grc * ny / CHECK_RADIUS)
        g1z = k * grc / CHECK_RADIUS
    # the scan's room: the circle inside the net's edges (x along u, y along v)
    x0, x1 = ctrl[0, 0, 0], ctrl[ctrl.shape[0] - 1, 0, 0]
    y0, y1 = ctrl[0, 0, 1], ctrl[0, ctrl.shape[1] - 1, 1]
    edge, ax, ay = x - x0, 1.0, 0.0
    if x1 - x < edge:
        edge, ax, ay = x1 - x, -1.0, 0.0
    if y - y0 < edge:
        edge, ax, ay = y - y0, 0.0, 1.0
    if y1 - y < edge:
        edge, ax, ay = y1 - y, 0.0, -1.0
    w2, s2 = smootherstep((edge - (1.0 + RING_WIDTH) * reach) / (ROOM_MARGIN * radius))
    g2x = g2y = g2z = 0.0
    if s2 != 0.0:
        k = s2 / (ROOM_MARGIN * radius)
        g2x = k * (ax * xxx + ay * xyx - (1.0 + RING_WIDTH) * grc * nx)
        g2y = k * (ax * xxy + ay * xyy - (1.0 + RING_WIDTH) * grc * ny)
        g2z = -k * (1.0 + RING_WIDTH) * grc
    w, gx, gy, gz = _product(w1, g1x, g1y, g1z, w2, g2x, g2y, g2z)
    if w > 0.0 and h0 > g0:
        # no second minimum within the zone (the surface's third derivative bounded over it), the fit within the
        # zone (its edge), and nothing else between it and the check circle
        w, gx, gy, gz = _product(w, gx, gy, gz, *_remainder_weight(model, h0))
        if w > 0.0:
            w3, g3x, g3y, g3z = _ring_fit(ctrl, ku, kv, model, radius, h0, zone, grc / CHECK_RADIUS, FIT_TOLERANCE)
            w, gx, gy, gz = _product(w, gx, gy, gz, w3, g3x, g3y, g3z)
            if w3 > 0.0:
                w, gx, gy, gz = _product(w, gx, gy, gz, *_ring_clear(ctrl, ku, kv, model, radius, h0, reach, grc))
    out[Q_WEIGHT], out[Q_WEIGHT + 1], out[Q_WEIGHT + 2], out[Q_WEIGHT + 3] = w, gx, gy, gz


@njit(cache=True)
def _product(a, ax, ay, az, b, bx, by, bz):
    """``(ab, grad(ab))`` of two weights given with their gradients in T."""
    return a * b, ax * b + a * bx, ay * b + a * by, az * b + a * bz


@njit(cache=True)
def _remainder_weight(model, h0):
    r"""``(w, dw/dT)``: 1 while the surface's third derivative, bounded by B over the tip's reach
    about :math:`x^*` (:func:`~arsurf.spline.curvature.curvature_net`), is too small to make a
    second minimum of the gap inside the zone, 0 well past that. About :math:`x^*` the gap's
    gradient is :math:`K\xi + r`, :math:`|r| \le \tfrac12 B|\xi|^2`, so it vanishes nowhere
    else within :math:`|\xi| < 2\lambda/B`, :math:`\lambda` the least curvature of the gap (of
    K); the zone reaches :math:`\sqrt{2(h_0 - g_0)/\lambda}`; the measure is their ratio,
    :math:`c = B\sqrt{(h_0 - g_0)/2}\,\lambda^{-3/2}`, no other minimum while c < 1.
    B is a bound (the third derivative's norm, the largest over the reach and the 4 x 4 spans of
    a basis function of the field), about twice the third derivative met on the real scans' maps;
    so the one term is trusted wholly to c = :data:`REMAINDER_TOLERANCE` and not at all from twice
    it. The
    least curvature is smoothed, :math:`\lambda = m - \sqrt{d^2 + K_{xy}^2 + (\epsilon m)^2}`
    (m, d the half sum and difference of the diagonal, :math:`\epsilon` = 1e-3), so that its
    gradient exists where K is isotropic (on a flat)."""
    zx, zy, g0 = model[9], model[10], model[11]
    kxx, kxy, kyy, dxx_x, dxy_x, dyy_x, dxx_y, dxy_y, dyy_y = model[12:21]
    xxx, xxy, xyx, xyy, bound, bound_x, bound_y = model[21:28]
    span = h0 - g0
    m, d = 0.5 * (kxx + kyy), 0.5 * (kxx - kyy)
    eps = 1e-3
    root = math.sqrt(d * d + kxy * kxy + eps * eps * m * m)
    lam = m - root
    if lam <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    half = math.sqrt(0.5 * span)
    c = bound * half * lam ** -1.5
    w, slope = smootherstep(2.0 - c / REMAINDER_TOLERANCE)
    if slope == 0.0:
        return w, 0.0, 0.0, 0.0
    # grad lam from dK/dT (T_z moves neither x* nor K); grad B = (B_x, B_y) X; grad span = -(nx, ny, 1)
    dm_x, dm_y = 0.5 * (dxx_x + dyy_x), 0.5 * (dxx_y + dyy_y)
    dd_x, dd_y = 0.5 * (dxx_x - dyy_x), 0.5 * (dxx_y - dyy_y)
    dlx = dm_x - (d * dd_x + kxy * dxy_x + eps * eps * m * dm_x) / root
    dly = dm_y - (d * dd_y + kxy * dxy_y + eps * eps * m * dm_y) / root
    dbx, dby = bound_x * xxx + bound_y * xyx, bound_x * xxy + bound_y * xyy
    a = half * lam ** -1.5  # dc/dB
    e = bound * lam ** -1.5 / (4.0 * half)  # dc/dspan
    f = -1.5 * c / lam  # dc/dlam
    cx = a * dbx + e * zx + f * dlx  # grad span = (zx, zy, -1)
    cy = a * dby + e * zy + f * dly
    cz = -e
    k = -slope / REMAINDER_TOLERANCE
    return w, k * cx, k * cy, k * cz


@njit(cache=True, inline="always")
def _deviation(ctrl, ku, kv, model, radius, ring, grr, angle):
    r"""``(delta, d delta/dT, G, dG/dT)``: :math:`\delta = G - g_0 - s(q)` (:func:`_fit_weight`) at
    :math:`p = x^* + \xi`, :math:`\xi = r e` on the circle of radius ``ring`` (m; its gradient
    ``grr`` (nx, ny, 1)) at ``angle``, G under the tip's own profile (its sphere, then its cone:
    :func:`~arsurf.contact.zone_law._rise`): :math:`dG(p)/dT_{xy} = \gamma^T X - s'(r)(p - T)/r`,
    :math:`dG/dT_z = 1`, :math:`\gamma = \nabla_x G(p)`, plus :math:`\gamma\cdot e\,\nabla r`;
    :math:`dq/dT = \tfrac12\xi^T (dM/dT)\xi + \xi^T M e\,\nabla r`; :math:`dg_0/dT = n`;
    :math:`s'(q) = R/\sqrt{R^2 - 2Rq}`. Where :math:`2q \ge R` (past the sphere's equator) there is
    no model: the deviation is then the whole rise, its gradient left out (the weight is 0 long before)."""
    tx, ty, tz, u, v, xu, yv, x, y, zx, zy, g0 = model[:12]
    mxx, mxy, myy, dxx_x, dxy_x, dyy_x, dxx_y, dxy_y, dyy_y = model[12:21]
    xxx, xxy, xyx, xyy = model[21], model[22], model[23], model[24]
    nx, ny = -zx, -zy
    ex, ey = math.cos(angle), math.sin(angle)
    px, py = ring * ex, ring * ey
    at = height_slope(ctrl, ku, kv, u + px / xu, v + py / yv)
    ox, oy = x + px - tx, y + py - ty
    rho0, cap, slope = _cone(radius)  # the tip's own profile: its sphere, then its cone (a check circle may reach it)
    rise, sr, _ = _rise(ox * ox + oy * oy, radius, rho0, cap, slope)
    gap = tz - radius + rise - at[0]
    cx, cy = sr * ox - at[1] / xu, sr * oy - at[2] / yv  # grad_x G at p
    mx, my = mxx * px + mxy * py, mxy * px + myy * py
    q = 0.5 * (px * mx + py * my)
    along = cx * ex + cy * ey  # dG/dr
    gx = cx * xxx + cy * xyx - sr * ox + along * grr * nx  # grad G(p)
    gy = cx * xxy + cy * xyy - sr * oy + along * grr * ny
    gz = 1.0 + along * grr
    root = radius * (radius - 2.0 * q)
    if root <= 0.0:  # past the sphere's equator in q: no model
        return gap - g0, 0.0, 0.0, 0.0, gap, gx, gy, gz
    root = math.sqrt(root)
    delta = gap - g0 - (radius - root)
    dqr = mx * ex + my * ey  # dq/dr
    f = radius / root  # s'(q)
    dqx = 0.5 * (dxx_x * px * px + 2.0 * dxy_x * px * py + dyy_x * py * py) + dqr * grr * nx
    dqy = 0.5 * (dxx_y * px * px + 2.0 * dxy_y * px * py + dyy_y * py * py) + dqr * grr * ny
    return delta, gx - nx - f * dqx, gy - ny - f * dqy, gz - 1.0 - f * dqr * grr, gap, gx, gy, gz


@njit(cache=True)
def _ring_clear(ctrl, ku, kv, model, radius, h0, ring, grr):
    r"""``(w, dw/dT)``: 1 while the gap on :data:`RING_POINTS` points of the check circle (radius
    ``ring`` m, its gradient ``grr`` (nx, ny, 1)) is at least :math:`h_0 + \Delta`, 0 where it
    reaches :math:`h_0` (:func:`smootherstep` of the least, :math:`\Delta` =
    :data:`CLEAR_MARGIN` h0): nothing else within the law's range there, as
    :func:`~arsurf.contact.zone_energy.isolation_kernel` asks of the lattice beyond it."""
    least, lx, ly, lz = math.inf, 0.0, 0.0, 0.0
    for k in range(RING_POINTS):
        _, _, _, _, gap, gx, gy, gz = _deviation(ctrl, ku, kv, model, radius, ring, grr,
                                                 2.0 * math.pi * k / RING_POINTS)
        if gap < least:
            least, lx, ly, lz = gap, gx, gy, gz
    margin = CLEAR_MARGIN * h0
    w, slope = smootherstep((least - h0) / margin)
    return w, slope / margin * lx, slope / margin * ly, slope / margin * lz


@njit(cache=True)
def _ring_fit(ctrl, ku, kv, model, radius, h0, ring, grr, tolerance):
    r"""``(w, dw/dT)``: 1 while the deviation :math:`\delta` (:func:`_deviation`) on
    :data:`RING_POINTS` points of the circle of radius ``ring`` (m; its gradient ``grr`` (nx, ny, 1))
    about the minimum, over the gap's range :math:`h_0 - g_0`, measures below ``tolerance``, 0
    above twice it. Its even part (the mean of opposite points) shifts the zone's edge at first
    order; its odd part (a cubic: the sphere's own about a minimum off its apex, on a slope) moves
    the edge as much each way and changes the area at second order: the measure is
    :math:`\nu = \mathrm{rms}(\delta_{even})/(h_0 - g_0) + (\mathrm{rms}(\delta_{odd})/(h_0 - g_0))^2`."""
    g0 = model[11]
    nx, ny, span = -model[9], -model[10], h0 - g0
    half = RING_POINTS // 2
    ee = ex_ = ey_ = ez_ = 0.0  # sum of e^2 and e grad e (even parts)
    oo = ox_ = oy_ = oz_ = 0.0  # sum of o^2 and o grad o (odd parts)
    for k in range(half):
        angle = 2.0 * math.pi * k / RING_POINTS
        a, ax, ay, az, _, _, _, _ = _deviation(ctrl, ku, kv, model, radius, ring, grr, angle)
        b, bx, by, bz, _, _, _, _ = _deviation(ctrl, ku, kv, model, radius, ring, grr, angle + math.pi)
        e, o = 0.5 * (a + b), 0.5 * (a - b)
        ee += e * e
        ex_ += e * 0.5 * (ax + bx)
        ey_ += e * 0.5 * (ay + by)
        ez_ += e * 0.5 * (az + bz)
        oo += o * o
        ox_ += o * 0.5 * (ax - bx)
        oy_ += o * 0.5 * (ay - by)
        oz_ += o * 0.5 * (az - bz)
    count = half
    rms = math.sqrt(ee / count)
    odd = oo / (count * span * span)  # (rms(odd) / span)^2
    nu = rms / span + odd
    w, slope = smootherstep(2.0 - nu / tolerance)
    if slope == 0.0:
        return w, 0.0, 0.0, 0.0
    k = -slope / tolerance
    # grad (rms / span) = (sum e grad e) / (count rms span) + (rms / span^2) n;
    # grad odd = 2 (sum o grad o) / (count span^2) + 2 odd n / span   (grad span = -n)
    c = 1.0 / (count * rms * span) if rms > 0.0 else 0.0
    c2 = 2.0 / (count * span * span)
    lin = rms / (span * span) + 2.0 * odd / span
    return (w, k * (c * ex_ + c2 * ox_ + lin * nx), k * (c * ey_ + c2 * oy_ + lin * ny),
            k * (c * ez_ + c2 * oz_ + lin))


def quadric_contact(surface, law, center, start=None) -> tuple[float, np.ndarray, int]:
    """``(E, F, status)``: the one-term energy (J) and force (N, (3,)) with the tip's centre at
    ``center`` (m) on ``surface`` (a height-field net; its rest net) with ``law`` (a
    :class:`~arsurf.contact.zone_law.ZoneLaw`), and :func:`quadric_contact_kernel`'s return
    (negative: no minimum found, E and F 0). ``start``: (u, v) to start the minimum's search
    from (default: under the tip)."""
    c = np.asarray(center, dtype=np.float64)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise ContactError(f"`center` must be 3 finite coordinates in m (got {center!r})")
    if not surface.is_height_field_net:
        raise ContactError("the one-term contact needs a height-field net (x along u, y along v): a fitted scan's")
    out = QUADRIC_OUT.full(math.nan)
    if start is not None:
        out[Q_UV:Q_UV + 2] = np.asarray(start, dtype=np.float64)
    ctrl = np.array(surface.rest_control_points, order="C")
    ku, kv = surface.knots_u, surface.knots_v
    status = quadric_contact_kernel(ctrl, ku, kv, *curvature_net(ctrl, ku, kv, law.tip_radius), c[0], c[1], c[2],
                                    *law.args, out, np.empty((0, 0)))
    return float(out[Z_ENERGY]), out[Z_FORCE:Z_FORCE + 3].copy(), int(status)
