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
surface's third derivatives (:func:`~arsurf.spline.basis.height_jet`); then

.. math::

    F = -\nabla_T E = -2\pi\left(\frac{J'(g_0)}{\sqrt{\det M}}\,n
        - \frac{J(g_0)}{2 (\det M)^{3/2}}\,\nabla_T \det M\right), \qquad
    J' = -\varphi(g_0) + \frac{I_0}{R}, \quad J'' = p(g_0) - \frac{\varphi(g_0)}{R}.

A bicubic spline's third derivatives step where :math:`x^*` crosses a knot line, and so does the
second term: by the change of the surface's third derivative over a knot interval, which on a
scan smoothed over several pixels is small against the first term's.

**The Hessian** (for a proxy's Newton step) keeps the terms of first order in
:math:`\nabla\det M` and leaves out its second derivatives (the surface's fourth):
:math:`\nabla^2 E \approx \frac{2\pi}{\sqrt{\det M}}(J'' n n^T + J' \nabla n) - \frac{\pi
J'}{(\det M)^{3/2}}(n \nabla\det M^T + \nabla\det M\,n^T) + \frac{3\pi J}{2 (\det
M)^{5/2}}\nabla\det M\,\nabla\det M^T`, with :math:`\nabla n` the value function's Hessian
:math:`S - S M^{-1} S` across (zero along :math:`T_z`).

The term holds where the gap is near its quadratic over the whole zone of interaction (a single
smooth contact, on the tip's sphere): :func:`quadric_contact_kernel` says when it cannot find that
minimum (no minimum, M not positive definite, or the minimum past the sphere onto the cone), and
the caller keeps the lattice there.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf.contact.zone_energy import ZONE_OUT, Z_ENERGY, Z_FORCE
from arsurf.contact.zone_law import _COS_CONE, _law
from arsurf.errors import ContactError
from arsurf.spline.basis import height_jet

__all__ = ["QUADRIC_OUT", "law_moments", "quadric_contact", "quadric_contact_kernel"]

#: what :func:`quadric_contact_kernel` writes: E (J) and F (N) as :data:`~arsurf.contact.zone_energy.ZONE_OUT`,
#: then the least gap g0 (m), where it lies (u, v: the net's parameters, also where the next call starts) and
#: det M (m^-2)
QUADRIC_OUT = ZONE_OUT.extended("quadric contact output", [("gap", 1), ("uv", 2), ("curvature", 1)])
Q_GAP, Q_UV, Q_DET = QUADRIC_OUT.offset("gap"), QUADRIC_OUT.offset("uv"), QUADRIC_OUT.offset("curvature")
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
def quadric_contact_kernel(ctrl, ku, kv, tx, ty, tz, radius, e_star, sigma0, h0, out, hess) -> int:
    r"""E(T) and F(T) of the module docstring at the tip centre T = (tx, ty, tz) (m) over the
    height-field net (``ctrl``, ``ku``, ``kv``). The gap's minimum by Newton's method from
    ``out``'s (u, v) (:data:`QUADRIC_OUT`; NaN: from under the tip), each step at most
    :data:`MINIMUM_STEP` R. Writes ``out``: E (J), F (N), g0 (m), the minimum's (u, v), det M
    (m^-2); ``hess`` (3, 3), unless empty, E's Hessian (N/m, module docstring). Returns Newton's
    steps, or :data:`NO_MINIMUM`, :data:`NOT_CONVERGED`, :data:`ON_THE_CONE` (E and F then 0, the
    caller's to replace)."""
    want = hess.shape[0] == 3
    out[Z_ENERGY] = out[Z_FORCE] = out[Z_FORCE + 1] = out[Z_FORCE + 2] = 0.0
    if want:
        hess[:, :] = 0.0
    u, v = out[Q_UV], out[Q_UV + 1]
    if not (math.isfinite(u) and math.isfinite(v)):  # under the tip: x affine in u, y in v
        u0, u1, v0, v1 = ku[3], ku[ku.shape[0] - 4], kv[3], kv[kv.shape[0] - 4]
        x0, x1 = ctrl[0, 0, 0], ctrl[ctrl.shape[0] - 1, 0, 0]
        y0, y1 = ctrl[0, 0, 1], ctrl[0, ctrl.shape[1] - 1, 1]
        u = min(max(u0 + (tx - x0) / (x1 - x0) * (u1 - u0), u0), u1)
        v = min(max(v0 + (ty - y0) / (y1 - y0) * (v1 - v0), v0), v1)
    steps, found = 0, False
    r2 = radius * radius
    while steps < MINIMUM_ITERATIONS:
        x, y, xu, yv, z, zu, zv, zuu, zuv, zvv, zuuu, zuuv, zuvv, zvvv = height_jet(ctrl, ku, kv, u, v)
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
        if not (det > 0.0 and mxx > 0.0):
            return NO_MINIMUM
        gx, gy = dx / rho - zx, dy / rho - zy
        sx, sy = -(myy * gx - mxy * gy) / det, -(mxx * gy - mxy * gx) / det
        size = math.sqrt(sx * sx + sy * sy)
        if found:
            break  # the point just evaluated is the minimum, to MINIMUM_TOL
        if size > MINIMUM_STEP * radius:
            sx *= MINIMUM_STEP * radius / size
            sy *= MINIMUM_STEP * radius / size
        steps += 1
        u += sx / xu
        v += sy / yv
        found = size < MINIMUM_TOL * radius
    if not found:
        return NOT_CONVERGED
    out[Q_UV], out[Q_UV + 1] = u, v
    if dx * dx + dy * dy >= (_COS_CONE * radius) ** 2:
        return ON_THE_CONE
    g0 = tz - rho - z
    out[Q_GAP], out[Q_DET] = g0, det
    if g0 >= h0:
        return steps
    # the sphere's Hessian S, its derivatives dS/dd_c, and the surface's third derivatives in x, y
    sxx, sxy, syy = 1.0 / rho + dx * dx * i3, dx * dy * i3, 1.0 / rho + dy * dy * i3
    i5 = 3.0 * i3 / rho2
    # dS_ab/dd_c = (delta_ab d_c + delta_ac d_b + delta_bc d_a) / rho^3 + 3 d_a d_b d_c / rho^5
    s_xxx = 3.0 * dx * i3 + i5 * dx * dx * dx
    s_xxy = dy * i3 + i5 * dx * dx * dy
    s_xyy = dx * i3 + i5 * dx * dy * dy
    s_yyy = 3.0 * dy * i3 + i5 * dy * dy * dy
    cx, cy = 1.0 / xu, 1.0 / yv
    h_xxx, h_xxy, h_xyy, h_yyy = zuuu * cx * cx * cx, zuuv * cx * cx * cy, zuvv * cx * cy * cy, zvvv * cy * cy * cy
    # dM/dx_l (l = x, y) at fixed T, and dM/dT_k = sum_l dM/dx_l X_lk - dS/dd_k, X = M^-1 S
    axx_x, axy_x, ayy_x = s_xxx - h_xxx, s_xxy - h_xxy, s_xyy - h_xyy
    axx_y, axy_y, ayy_y = s_xxy - h_xxy, s_xyy - h_xyy, s_yyy - h_yyy
    ixx, ixy, iyy = myy / det, -mxy / det, mxx / det  # M^-1
    xxx, xxy = ixx * sxx + ixy * sxy, ixx * sxy + ixy * syy  # X = M^-1 S: rows l, columns k
    xyx, xyy = ixy * sxx + iyy * sxy, ixy * sxy + iyy * syy
    ddet = np.empty(2)  # d det M / dT_x, dT_y
    for k in range(2):
        lx = xxx if k == 0 else xxy
        ly = xyx if k == 0 else xyy
        dmxx = axx_x * lx + axx_y * ly - (s_xxx if k == 0 else s_xxy)
        dmxy = axy_x * lx + axy_y * ly - (s_xxy if k == 0 else s_xyy)
        dmyy = ayy_x * lx + ayy_y * ly - (s_xyy if k == 0 else s_yyy)
        ddet[k] = myy * dmxx - 2.0 * mxy * dmxy + mxx * dmyy
    i0, i1 = law_moments(g0, radius, e_star, sigma0, h0)
    j = (1.0 + g0 / radius) * i0 - i1 / radius
    phi_r, phi_a, p, _ = _law(g0, e_star / (math.pi * math.sqrt(radius)), sigma0, h0, 0.0)
    phi = phi_r + phi_a
    j1 = -phi + i0 / radius
    root = math.sqrt(det)
    a = 2.0 * math.pi / root  # E = a J
    b = math.pi * j / (det * root)  # the det term: grad E = a J' n - b grad det
    nx, ny = -zx, -zy
    out[Z_ENERGY] = a * j
    out[Z_FORCE] = -(a * j1 * nx - b * ddet[0])
    out[Z_FORCE + 1] = -(a * j1 * ny - b * ddet[1])
    out[Z_FORCE + 2] = -a * j1
    if want:
        j2 = p - phi / radius
        # the value function's Hessian across: S - S M^-1 S
        vxx = sxx - (sxx * xxx + sxy * xyx)
        vxy = sxy - (sxx * xxy + sxy * xyy)
        vyy = syy - (sxy * xxy + syy * xyy)
        c = math.pi * j1 / (det * root)
        e = 1.5 * math.pi * j / (det * det * root)
        n = (nx, ny, 1.0)
        gd = (ddet[0], ddet[1], 0.0)
        for r in range(3):
            for s in range(3):
                hess[r, s] = a * j2 * n[r] * n[s] - c * (n[r] * gd[s] + gd[r] * n[s]) + e * gd[r] * gd[s]
        hess[0, 0] += a * j1 * vxx
        hess[0, 1] += a * j1 * vxy
        hess[1, 0] += a * j1 * vxy
        hess[1, 1] += a * j1 * vyy
    return steps


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
    status = quadric_contact_kernel(ctrl, surface.knots_u, surface.knots_v, c[0], c[1], c[2], *law.args, out,
                                    np.empty((0, 0)))
    return float(out[Z_ENERGY]), out[Z_FORCE:Z_FORCE + 3].copy(), int(status)
