r"""The energy of the whole tip on the surface: a local law summed over every surface element.

:mod:`arsurf.contact.multi_contact` gives each local minimum of the tip-surface distance its own
Maugis-Dugdale contact and gates the loads with weights. Its force is not the gradient of an
energy: a weight that gates a load without its stored energy makes the force circulate, and a
contact that enters or leaves steps it (docs/feel.rst, "What still fails, and why"). This module
is the building block of the other way, which has no contacts to find and no gates: the rigid
tip interacts with every element of the surface through a law of energy per unit area
:math:`\varphi(g)` of the gap between them (the Derjaguin approximation: Derjaguin,
"Untersuchungen über die Reibung und Adhäsion, IV. Theorie des Anhaftens kleiner Teilchen",
Kolloid-Z. 69, 155-164, 1934, the force between curved bodies from the energy per area of flat
ones). The gap is the height between the tip's surface and the surface element below it: the tip
is its sphere (centre T, radius R) continued, where the sphere's slope reaches it, into the cone
of half-angle :data:`CONE_HALF_ANGLE` a silicon tip's sphere sits on; so a tip rises
:math:`s(r) = R - \sqrt{R^2 - r^2}` above its apex at a distance r across for
:math:`r < r_0 = R\cos\alpha`, and :math:`s(r_0) + (r - r_0)\cot\alpha` beyond:

.. math::

    g_k = T_z - R + s(r_k) - S_{k,z}, \quad r_k = \lVert (T - S_k)_{xy}\rVert, \qquad
    E(T) = \sum_k A_k\,\varphi(g_k), \qquad
    F = -\nabla_T E = \sum_k A_k\,p(g_k) \begin{pmatrix} s'(r_k)\,(T - S_k)_{xy}/r_k \\ 1 \end{pmatrix},
    \qquad p = -\varphi',

over samples :math:`S_k` fixed on a uniform (u, v) lattice of the rest surface, :math:`A_k =
|x_u y_v - x_v y_u|\,h_u h_v` the projected area each stands for (:func:`surface_lattice`;
sampled a tile at a time where the tip reaches, so a lattice finer than the scan costs memory
only where the tip has been). Each element pushes along the tip's normal above it, whose tilt
the cone bounds (a gap along the line to the centre loses the load as the cap reaches the
equator, :math:`P \propto R - \delta`: a 2 nm tip pressed by the hand's load went through the
surface; a paraboloid keeps Hertz's load at any depth but is wider than the sphere and touches
asperities beside it that the sphere does not, so a hand started clear of the sphere started in
contact). The force is the gradient of E by construction (the samples do not move with T): no
work round a closed path, and continuous wherever p is; several asperities under a wide tip push
at once, each with its own share, and no event of the contact set exists to step the force.

**The law** and the tip's profile s(r) are :mod:`arsurf.contact.zone_law`'s: Hertz's repulsion and a
smoothed Dugdale adhesion, the Derjaguin-Muller-Toporov limit of Maugis-Dugdale on a flat.

**Its closed form.** On a lattice made with ``closed_form`` (``ARModel(zone_closed_form=True)``)
:func:`tip_energy_kernel` takes, where the contact is smooth and alone, the law integrated in
closed form over the quadratic gap about its minimum (:mod:`arsurf.contact.zone_quadric`), joined
to the lattice's sum in one energy by a weight whose gradient is exact; :func:`isolation_kernel`
asks the lattice beyond the one term's check circle whether any other point of the surface comes
near the tip. Not yet the default (docs/feel.rst, "The energy of the whole tip in one term").

**Material maps.** With a map (:mod:`arsurf.contact.material_map`) each element sums its own
law, the map's E* and w where it lies: the repulsion is linear in E* and the adhesion in
:math:`\sigma_0` at a fixed range :math:`h_0` (as the map's laws keep it), so a sample's
repulsion and adhesion are the reference law's scaled by :math:`E^*/E^*_{ref}` and
:math:`w/w_{ref}`, read once when its tile is sampled (:func:`surface_lattice`). A uniform map
is the model without one to the bit, and the force is still the gradient of one energy across a
boundary of materials.

:class:`~arsurf.model.ARModel` takes it as its contact with ``zone_energy=True`` (not yet the
default); ``bench/zone_energy.py`` measures it against the model on the surfaces where the feel
still fails, and ``bench/feel.py --zone-energy`` judges the feel tables with it (docs/feel.rst,
"The energy of the whole tip").
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf.contact.material_map import C_BODY, H_ON, local_ratios_kernel
from arsurf.contact.zone_law import (CONE_HALF_ANGLE, Z_ENERGY, Z_FORCE, Z_SIZE, ZONE_OUT, ZoneLaw, _across, _cone,
                                     _law, _rise, zone_law_kernel)
from arsurf.contact.zone_quadric import (CHECK_RADIUS, CLEAR_MARGIN, Q_CHECK, Q_GAP, Q_MOTION, Q_POINT, Q_SLOPE,
                                         Q_WEIGHT, QUADRIC_OUT, RING_WIDTH, quadric_contact_kernel, smootherstep)
from arsurf.errors import ContactError, SurfaceError
from arsurf.spline.basis import basis_matrix_rows, surface_point, surface_points_serial
from arsurf.spline.curvature import curvature_net

log = logging.getLogger(__name__)

__all__ = ["CONE_HALF_ANGLE", "SurfaceLattice", "TILE", "TRACKING_REDUCTION", "ZONE_OUT", "ZoneLaw", "isolation_kernel",
           "lattice_for", "surface_lattice", "tip_energy_kernel",
           "zone_energy", "zone_energy_kernel", "zone_law_kernel", "zone_proxy_kernel"]

#: where the proxy's memo (``L_MEMO``: the summed point, its E and F) keeps the point it published
_PUBLISHED = 3 + Z_SIZE

#: lattice samples per tile side: a tile is sampled the first time the tip reaches it
TILE = 16
#: samples per block side within a tile: a block is skipped when its bounding box lies beyond reach
BLOCK = 8
#: the relative margin of a block's reach (and of the tip's coordinates) when its rows and columns are read
#: from the lattice's x and y (a sample's own are the same to rounding, ~1e-16 relative)
WINDOW_SLACK = 1e-9
#: the repulsion's gap in its stiffness is held at least this fraction of the range (:func:`zone_energy_kernel`)
HESSIAN_FLOOR = 1e-3
#: the proxy's step is at most this fraction of the tip radius (:func:`zone_proxy_kernel`)
PROXY_STEP = 0.05
#: the proxy has converged when the gradient of f is below this fraction of k R
PROXY_TOL = 1e-6
#: and gives up after this many steps
PROXY_ITERATIONS = 200
#: a haptic tick's proxy returns once a whole Newton step leaves this fraction of the gradient it
#: started from (:func:`zone_proxy_kernel`)
TRACKING_REDUCTION = 0.01
#: ... or once the Newton step its residual gradient asks for is at most this share of the step
#: just taken (the Hessian barely changed along it), taking that last step on the quadratic model
CORRECTION_SHARE = 0.1
#: the lattice a tip is summed over is at most this fraction of its radius apart (:func:`lattice_for`)
SPACING_PER_RADIUS = 1.0 / 8.0
#: and this fraction of its zone of interaction at zero load: the law's load on a flat within ~2 % for tips of
#: 2-50 nm (h0 0.29 nm, pixels of 0.25-4 nm, bench/zone_quadrature.py; at R/8 alone 5-147 % off, the adhesive
#: ring unresolved)
SPACING_PER_ZONE = 1.0 / 8.0
#: samples per knot interval at most (:func:`lattice_for`; a scan's pixels wider than 64 spacings get a coarser lattice)
MAX_PER_KNOT = 64.0
#: tiles the pool of :func:`surface_lattice` holds by default (8.4 kB each)
DEFAULT_POOL = 512
#: and at most
MAX_POOL = 65_536
#: largest number of tiles a lattice has (24 bytes each: 96 MB, a billion samples)
MAX_TILES = 4_000_000
#: the indices of the kernels' ``lat`` (:attr:`SurfaceLattice.arrays`)
(L_CTRL, L_KU, L_KV, L_US, L_VS, L_XS, L_YS, L_WU, L_WV, L_ZLO, L_ZHI, L_SLOT_OF, L_TILE_OF, L_STAMP, L_PTS, L_AR,
 L_ADH, L_BOX, L_CLOCK, L_TOP, L_MEMO, L_WORK, L_TRIAL, L_EV, L_MAP, L_QUAD, L_JOIN, L_JOIN_WORK,
 L_JOIN_OUT, L_CURV, L_CURV_KU, L_CURV_KV) = range(32)


@njit(cache=True)
def _first_at_least(xs, x):
    """The first index of the sorted ``xs`` with ``xs[i] >= x`` (len(xs) if none)."""
    lo, hi = 0, xs.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if xs[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _window(xs, ys, tx, ty, reach):
    """``(i0, i1, j0, j1)``: the lattice's rows and columns within ``reach`` (m) of (tx, ty), one more each side."""
    i0 = max(_first_at_least(xs, tx - reach) - 1, 0)
    i1 = min(_first_at_least(xs, tx + reach) + 1, xs.shape[0])
    j0 = max(_first_at_least(ys, ty - reach) - 1, 0)
    j1 = min(_first_at_least(ys, ty + reach) + 1, ys.shape[0])
    return i0, i1, j0, j1


@njit(cache=True)
def _tile_in_reach(xs, ys, zhi, slot_of, stamp, clock, ti, tj, tx, ty, base, radius) -> int:
    """The pool slot of tile (``ti``, ``tj``) when a sample of it may lie within reach of the tip at
    (tx, ty) (a sample of height z is where the tip's surface rises ``base`` + z: :func:`zone_energy_kernel`);
    -1 when the tile's heights, bound by its control points' (the convex hull), keep it beyond reach:
    then it is never sampled; -2 when the pool does not hold it yet (the caller samples it,
    :func:`_take_slot`: the whole ``lat`` passed to a call costs an atomic reference count an array,
    so only then). A tile is the same whenever it is sampled, so the energy does not depend on what
    the pool holds."""
    rho0, cap, slope = _cone(radius)
    nu, nv = xs.shape[0], ys.shape[0]
    a0, a1 = ti * TILE, min((ti + 1) * TILE, nu) - 1
    b0, b1 = tj * TILE, min((tj + 1) * TILE, nv) - 1
    dx = max(xs[a0] - tx, 0.0, tx - xs[a1])
    dy = max(ys[b0] - ty, 0.0, ty - ys[b1])
    if base + zhi[ti, tj] <= 0.0 or dx * dx + dy * dy >= _across(base + zhi[ti, tj], radius, rho0, cap, slope) ** 2:
        return -1
    s = _held_slot(slot_of, stamp, clock, ti, tj)
    return s if s >= 0 else -2


@njit(cache=True)
def _block_reach(box, s, qa, qb, tx, ty, base, radius):
    """How far across (m) from (tx, ty) a sample of block (``qa``, ``qb``) of pool slot ``s`` may lie
    within reach, by the block's highest sample (with :data:`WINDOW_SLACK`: a sample's x, y are its
    row's and column's); -1 when none of the block can."""
    if base + box[s, qa, qb, 5] <= 0.0:
        return -1.0
    rho0, cap, slope = _cone(radius)
    near = _across(base + box[s, qa, qb, 5], radius, rho0, cap, slope)
    dx = max(box[s, qa, qb, 0] - tx, 0.0, tx - box[s, qa, qb, 3])
    dy = max(box[s, qa, qb, 1] - ty, 0.0, ty - box[s, qa, qb, 4])
    if dx * dx + dy * dy >= near * near:
        return -1.0
    return near + WINDOW_SLACK * (near + abs(tx) + abs(ty))


@njit(cache=True, error_model="numpy")
def zone_energy_kernel(lat, tx, ty, tz, radius, e_star, sigma0, h0, out, hess) -> int:
    r"""E(T) and F(T) of the module docstring at T = (tx, ty, tz) (m) over the lattice ``lat``
    (:attr:`SurfaceLattice.arrays`: its tiles in reach are sampled the first time they are needed,
    :func:`_held_slot`, :func:`_take_slot`). Writes ``out`` (:data:`ZONE_OUT`): E (J) and F (N); returns the number of
    samples within reach (g < h0). ``hess`` (3, 3), unless empty, gets E's Hessian (N/m),
    :math:`\sum_k A_k [-p'(g_k)\,\nabla g_k \nabla g_k^T - p(g_k)\,\nabla^2 g_k]`,
    with :math:`-g` held at least :data:`HESSIAN_FLOOR` h0 in the repulsion's
    :math:`p' \propto 1/\sqrt{-g}` (a sample at the contact's edge: an infinite but integrable
    stiffness; :func:`zone_proxy_kernel` uses the Hessian only for its step). A sample of height z is
    in reach where the gap is below h0: within :func:`_across` of :math:`h_0 + R - T_z + z` of T."""
    # every array taken from the tuple once: an array view made in a loop costs two atomic reference counts
    xs, ys, zhi, pts, ar, adh, box = lat[L_XS], lat[L_YS], lat[L_ZHI], lat[L_PTS], lat[L_AR], lat[L_ADH], lat[L_BOX]
    slot_of, stamp, clock = lat[L_SLOT_OF], lat[L_STAMP], lat[L_CLOCK]
    want = hess.shape[0] == 3
    if want:
        hess[:, :] = 0.0
    energy = fx = fy = fz = 0.0
    n = 0
    rho0, cap, slope = _cone(radius)
    stiff, floor = e_star / (math.pi * math.sqrt(radius)), math.sqrt(HESSIAN_FLOOR * h0)
    base = h0 + radius - tz  # a sample of height z is in reach within _across(base + z) of T
    if base + lat[L_TOP][0] > 0.0:
        i0, i1, j0, j1 = _window(xs, ys, tx, ty, _across(base + lat[L_TOP][0], radius, rho0, cap, slope))
        for ti in range(i0 // TILE, (i1 + TILE - 1) // TILE):
            for tj in range(j0 // TILE, (j1 + TILE - 1) // TILE):
                s = _tile_in_reach(xs, ys, zhi, slot_of, stamp, clock, ti, tj, tx, ty, base, radius)
                if s == -2:  # sampled the first time it is needed
                    s = _take_slot(lat, ti, tj)
                    stamp[s] = clock[0]
                elif s < 0:
                    continue
                a0, b0 = ti * TILE, tj * TILE
                for qa in range(2):
                    for qb in range(2):
                        near = _block_reach(box, s, qa, qb, tx, ty, base, radius)
                        if near < 0.0:
                            continue
                        jb0, jb1 = max(b0 + qb * BLOCK, j0), min(b0 + (qb + 1) * BLOCK, j1)
                        for i in range(max(a0 + qa * BLOCK, i0), min(a0 + (qa + 1) * BLOCK, i1)):
                            dx = abs(tx - xs[i])
                            if dx >= near:
                                continue
                            half = math.sqrt(near * near - dx * dx)  # the row's samples within reach: |y - ty| < half
                            ja, jz = jb0, jb1
                            while ja < jz and ys[ja] <= ty - half:
                                ja += 1
                            while jz > ja and ys[jz - 1] >= ty + half:
                                jz -= 1
                            row = (s * TILE + i - a0) * TILE - b0  # the pool's flat index of sample (i, j): row + j
                            for j in range(ja, jz):
                                k = row + j
                                dx = tx - pts[k, 0]
                                dy = ty - pts[k, 1]
                                rise, q, q1 = _rise(dx * dx + dy * dy, radius, rho0, cap, slope)
                                g = tz - radius + rise - pts[k, 2]
                                if g >= h0:
                                    continue
                                ex, ey = q * dx, q * dy  # the gap's gradient: (ex, ey, 1)
                                phi_r, phi_a, pr, dp = _law(g, stiff, sigma0, h0, floor)
                                area, ra = ar[k], adh[k]  # the repulsion's area, the adhesion's per it
                                energy += area * (phi_r + ra * phi_a)
                                if g >= 0.0:  # the pressure is the adhesion's
                                    area *= ra
                                f = area * pr
                                fx += f * ex
                                fy += f * ey
                                fz += f
                                n += 1
                                if want:  # a (-p' grad g grad g^T - p hess g), hess g = q I + q1 d d^T across
                                    c = -area * dp
                                    hess[0, 0] += c * ex * ex - f * (q + q1 * dx * dx)
                                    hess[0, 1] += c * ex * ey - f * q1 * dx * dy
                                    hess[0, 2] += c * ex
                                    hess[1, 1] += c * ey * ey - f * (q + q1 * dy * dy)
                                    hess[1, 2] += c * ey
                                    hess[2, 2] += c
    out[Z_ENERGY] = energy
    out[Z_FORCE] = fx
    out[Z_FORCE + 1] = fy
    out[Z_FORCE + 2] = fz
    if want:
        hess[1, 0] = hess[0, 1]
        hess[2, 0] = hess[0, 2]
        hess[2, 1] = hess[1, 2]
    return n


@njit(cache=True, error_model="numpy")
def isolation_kernel(lat, tx, ty, tz, radius, h0, quad, grad) -> float:
    r"""How far the one-term contact of ``quad`` (:data:`~arsurf.contact.zone_quadric.QUADRIC_OUT`, at
    the tip centre T = (tx, ty, tz) m) is from any other: the least, over the lattice's samples, of
    :math:`f_k = g_k + \Lambda\,\chi(r_k)`, :math:`g_k` the sample's gap, :math:`r_k` its distance
    from the minimum :math:`x^*`, :math:`\chi` 1 within the check circle :math:`r_c` and fading to 0
    over :data:`~arsurf.contact.zone_quadric.RING_WIDTH` of it beyond (a smooth step), and
    :math:`\Lambda = 2 h_0 + \Delta - g_0` (:math:`\Delta` = :data:`CLEAR_MARGIN` h0) so that a
    sample within the circle, whose gap is at least :math:`g_0`, is never the least below
    :math:`h_0 + \Delta`. Returns it (m), capped at :math:`h_0 + \Delta` (nothing else within that gap),
    with its gradient in T into ``grad`` (its first 3): the least sample's
    :math:`\nabla g_k + \chi\nabla\Lambda + \Lambda\chi'\nabla r_k`-terms, the circle moving with
    :math:`x^*` and :math:`g_0`. Continuous in T (the least of continuous functions), it visits only
    the samples in reach of that gap outside the circle: for a lone contact, a thin ring."""
    xs, ys, zhi, pts, box = lat[L_XS], lat[L_YS], lat[L_ZHI], lat[L_PTS], lat[L_BOX]
    slot_of, stamp, clock = lat[L_SLOT_OF], lat[L_STAMP], lat[L_CLOCK]
    margin = CLEAR_MARGIN * h0
    best = h0 + margin
    grad[0] = grad[1] = grad[2] = 0.0
    px, py, g0, check = quad[Q_POINT], quad[Q_POINT + 1], quad[Q_GAP], quad[Q_CHECK]
    mxx, mxy, myx, myy = quad[Q_MOTION], quad[Q_MOTION + 1], quad[Q_MOTION + 2], quad[Q_MOTION + 3]
    nx, ny = -quad[Q_SLOPE], -quad[Q_SLOPE + 1]  # grad g0 = (nx, ny, 1)
    lam = 2.0 * h0 + margin - g0 if check > 0.0 else 0.0
    grc = -(CHECK_RADIUS * CHECK_RADIUS * radius / check) if check > 0.0 else 0.0  # grad r_c = grc (nx, ny, 1)
    inner = check * check
    rho0, cap, slope = _cone(radius)
    base = best + radius - tz  # a sample of height z may be below the gap `best` within _across(base + z) of T
    if base + lat[L_TOP][0] <= 0.0:
        return best
    i0, i1, j0, j1 = _window(xs, ys, tx, ty, _across(base + lat[L_TOP][0], radius, rho0, cap, slope))
    # the tiles and blocks as zone_energy_kernel visits them (not a shared helper: one that took the whole
    # lattice to sample a tile would cost a reference count an array on every tile)
    for ti in range(i0 // TILE, (i1 + TILE - 1) // TILE):
        for tj in range(j0 // TILE, (j1 + TILE - 1) // TILE):
            s = _tile_in_reach(xs, ys, zhi, slot_of, stamp, clock, ti, tj, tx, ty, base, radius)
            if s == -2:  # sampled the first time it is needed
                s = _take_slot(lat, ti, tj)
                stamp[s] = clock[0]
            elif s < 0:
                continue
            a0, b0 = ti * TILE, tj * TILE
            for qa in range(2):
                for qb in range(2):
                    near = _block_reach(box, s, qa, qb, tx, ty, base, radius)
                    if near < 0.0:
                        continue
                    fx = max(abs(box[s, qa, qb, 0] - px), abs(box[s, qa, qb, 3] - px))
                    fy = max(abs(box[s, qa, qb, 1] - py), abs(box[s, qa, qb, 4] - py))
                    if fx * fx + fy * fy < inner:
                        continue  # the whole block within the circle
                    for i in range(max(a0 + qa * BLOCK, i0), min(a0 + (qa + 1) * BLOCK, i1)):
                        if abs(tx - xs[i]) >= near:
                            continue
                        row = (s * TILE + i - a0) * TILE - b0
                        for j in range(max(b0 + qb * BLOCK, j0), min(b0 + (qb + 1) * BLOCK, j1)):
                            k = row + j
                            ox, oy = pts[k, 0] - px, pts[k, 1] - py
                            r2 = ox * ox + oy * oy
                            if r2 < inner:
                                continue
                            dx, dy = tx - pts[k, 0], ty - pts[k, 1]
                            rise, q, _ = _rise(dx * dx + dy * dy, radius, rho0, cap, slope)
                            g = tz - radius + rise - pts[k, 2]
                            if g >= best:  # f >= g
                                continue
                            chi, t = 0.0, 0.0
                            if check > 0.0:
                                r = math.sqrt(r2)
                                t = (r - check) / (RING_WIDTH * check)
                                chi = 1.0 - smootherstep(t)[0]
                            f = g + lam * chi
                            if f >= best:
                                continue
                            best = f
                            gx, gy, gz = q * dx, q * dy, 1.0  # grad g
                            if chi > 0.0:
                                # chi grad lam, grad lam = -(nx, ny, 1); lam chi' grad t,
                                # grad t = (grad r r_c - r grad r_c) / (RING_WIDTH r_c^2), grad r_xy = -(u^T X)
                                r = math.sqrt(r2)
                                ux, uy = ox / r, oy / r
                                c = -lam * smootherstep(t)[1] / (RING_WIDTH * check * check)
                                grx = -(ux * mxx + uy * myx)
                                gry = -(ux * mxy + uy * myy)
                                gx += -chi * nx + c * (grx * check - r * grc * nx)
                                gy += -chi * ny + c * (gry * check - r * grc * ny)
                                gz += -chi + c * (-r * grc)
                            grad[0], grad[1], grad[2] = gx, gy, gz
    return best


@njit(cache=True, error_model="numpy")
def tip_energy_kernel(lat, tx, ty, tz, radius, e_star, sigma0, h0, out, hess) -> int:
    r"""The energy of the whole tip E (J) and the force F (N) at T = (tx, ty, tz) (m) into ``out``
    (:data:`ZONE_OUT`; ``hess`` as :func:`zone_energy_kernel`'s): the lattice's sum
    (:func:`zone_energy_kernel`), or, on a lattice made with ``closed_form``, the one term of
    :mod:`arsurf.contact.zone_quadric` where it can be trusted, joined to the sum by a weight
    :math:`w(T)`,

    .. math::

        E = w E_1 + (1 - w) E_\Sigma, \qquad
        F = w F_1 + (1 - w) F_\Sigma - (E_1 - E_\Sigma)\nabla w,

    w the one term's own (its fit on two circles, the room on the sphere and the scan) times the smooth
    step of :func:`isolation_kernel`'s least gap elsewhere from :math:`h_0` (0) to :math:`h_0 +
    \Delta` (1): one energy, its force its gradient; the sum is taken only where w < 1. The
    Hessian is joined with the weight's first derivatives, :math:`w H_1 + (1 - w) H_\Sigma +
    \nabla w\,\nabla(E_1 - E_\Sigma)^T + \nabla(E_1 - E_\Sigma)\,\nabla w^T`, not its second (it steers a
    proxy's step and its quadratic model of the last step: :func:`zone_proxy_kernel`). Returns the
    lattice's samples in reach, or -1 where the one term alone was used."""
    quad, work, part = lat[L_QUAD], lat[L_JOIN_WORK], lat[L_JOIN_OUT]
    if lat[L_JOIN][0] == 0:
        return zone_energy_kernel(lat, tx, ty, tz, radius, e_star, sigma0, h0, out, hess)
    want = hess.shape[0] == 3
    qh = work[0] if want else hess
    w, gwx, gwy, gwz = 0.0, 0.0, 0.0, 0.0
    if quadric_contact_kernel(lat[L_CTRL], lat[L_KU], lat[L_KV], lat[L_CURV], lat[L_CURV_KU], lat[L_CURV_KV],
                              tx, ty, tz, radius, e_star, sigma0, h0, quad, qh) >= 0 and quad[Q_WEIGHT] > 0.0:
        margin = CLEAR_MARGIN * h0
        least = isolation_kernel(lat, tx, ty, tz, radius, h0, quad, part)  # its gradient into part[:3]
        wi, si = smootherstep((least - h0) / margin)
        wq = quad[Q_WEIGHT]
        w = wq * wi
        gwx = quad[Q_WEIGHT + 1] * wi + wq * si / margin * part[0]
        gwy = quad[Q_WEIGHT + 2] * wi + wq * si / margin * part[1]
        gwz = quad[Q_WEIGHT + 3] * wi + wq * si / margin * part[2]
    if w >= 1.0:
        for q in range(Z_SIZE):
            out[q] = quad[q]
        if want:
            for a in range(3):
                for b in range(3):
                    hess[a, b] = qh[a, b]
        return -1
    n = zone_energy_kernel(lat, tx, ty, tz, radius, e_star, sigma0, h0, out, hess)
    if w <= 0.0:
        return n
    diff = quad[Z_ENERGY] - out[Z_ENERGY]
    fx, fy = quad[Z_FORCE] - out[Z_FORCE], quad[Z_FORCE + 1] - out[Z_FORCE + 1]
    fz = quad[Z_FORCE + 2] - out[Z_FORCE + 2]
    out[Z_ENERGY] += w * diff
    out[Z_FORCE] += w * fx - diff * gwx
    out[Z_FORCE + 1] += w * fy - diff * gwy
    out[Z_FORCE + 2] += w * fz - diff * gwz
    if want:  # + grad w grad(E1 - E_sum)^T and its transpose, grad(E1 - E_sum) = -(F1 - F_sum)
        gw, df = (gwx, gwy, gwz), (fx, fy, fz)
        for a in range(3):
            for b in range(3):
                hess[a, b] += w * (qh[a, b] - hess[a, b]) - (gw[a] * df[b] + df[a] * gw[b])
    return n


@njit(cache=True, inline="always")
def _held_slot(slot_of, stamp, clock, ti, tj) -> int:
    """The pool slot holding tile (``ti``, ``tj``), marked used now; -1 when the pool does not hold
    it (:func:`_take_slot` samples it). ``slot_of``, ``stamp``, ``clock``: the lattice's arrays of
    those names, passed alone (the whole ``lat`` passed costs an atomic reference count an array)."""
    clock[0] += 1
    s = slot_of[ti, tj]
    if s >= 0:
        stamp[s] = clock[0]
    return s


@njit(cache=True)
def _take_slot(lat, ti, tj) -> int:
    """Tile (``ti``, ``tj``) sampled (:func:`_sample_tile`) into the pool's least recently used slot."""
    slot_of, tile_of, stamp = lat[L_SLOT_OF], lat[L_TILE_OF], lat[L_STAMP]
    s = 0
    for q in range(1, stamp.shape[0]):
        if stamp[q] < stamp[s]:
            s = q
    if tile_of[s, 0] >= 0:
        slot_of[tile_of[s, 0], tile_of[s, 1]] = -1
    _sample_tile(lat, ti, tj, s)
    slot_of[ti, tj] = s
    tile_of[s, 0], tile_of[s, 1] = ti, tj
    return s


@njit(cache=True)
def _sample_tile(lat, ti, tj, s):
    r"""Tile (``ti``, ``tj``)'s samples of the rest surface, their areas (module docstring; with a
    material map the repulsion's area :math:`A\,E^*/E^*_{ref}` and the adhesion's per it,
    :math:`(w/w_{ref})/(E^*/E^*_{ref})`, else A and 1) and its blocks' bounding boxes into pool
    slot ``s`` (a block past the lattice's edge gets an empty box)."""
    ctrl, ku, kv, us, vs = lat[L_CTRL], lat[L_KU], lat[L_KV], lat[L_US], lat[L_VS]
    wu, wv, pts, ar, adh, box = lat[L_WU], lat[L_WV], lat[L_PTS], lat[L_AR], lat[L_ADH], lat[L_BOX]
    ev, cv = lat[L_EV], lat[L_MAP]
    box[s, :, :, :3] = math.inf
    box[s, :, :, 3:] = -math.inf
    for a in range(TILE):
        i = ti * TILE + a
        if i >= us.shape[0]:
            break
        for b in range(TILE):
            j = tj * TILE + b
            if j >= vs.shape[0]:
                break
            surface_point(ctrl, ku, kv, us[i], vs[j], 1, ev)
            k = (s * TILE + a) * TILE + b
            le, lw = local_ratios_kernel(cv, ev[0, 0], ev[0, 1])
            ar[k] = abs(ev[1, 0] * ev[2, 1] - ev[1, 1] * ev[2, 0]) * wu[i] * wv[j] * math.exp(le)  # projected
            adh[k] = math.exp(lw - le)
            q = box[s, a // BLOCK, b // BLOCK]
            for c in range(3):
                pts[k, c] = ev[0, c]
                q[c] = min(q[c], ev[0, c])
                q[3 + c] = max(q[3 + c], ev[0, c])


@njit(cache=True)
def zone_proxy_kernel(lat, cx, cy, cz, stiffness, radius, e_star, sigma0, h0, tip, out,
                      reduction=0.0) -> int:
    r"""The tip behind a virtual coupling: from ``tip`` (3,) m (the last tick's, or a point above the
    surface), the nearest minimum of :math:`f(T) = E(T) + \tfrac12 k\lVert T - C\rVert^2`, C the
    target (cx, cy, cz) m and k the coupling ``stiffness`` (N/m), into ``tip`` in place: Newton's
    method on the energy's Hessian plus k, each step at most :data:`PROXY_STEP` R and halved until
    f falls (a gradient step where the Newton step does not descend), until the gradient is below
    :data:`PROXY_TOL` of the coupling's force at one tip radius. As the god-object's proxy
    (Zilles & Salisbury 1995) the tip moves from where it was and stops where the forces balance;
    on a conservative E it settles, and a snap is its minimum ending. ``out`` (:data:`ZONE_OUT`): E
    (J) and F (N) at the tip. Returns the iterations (negative: not converged in
    :data:`PROXY_ITERATIONS`).

    ``reduction`` > 0: it also returns, unconverged, once a whole Newton step (neither capped nor
    halved) has brought the gradient below ``reduction`` of its size at the start, or has left a
    gradient r whose own Newton step :math:`s = -(H + kI)^{-1} r` on the Hessian summed at the
    step's end descends and is at most :data:`CORRECTION_SHARE` of the step: the tip is then
    published at P + s, where the quadratic model of f about the summed point P is at its minimum,
    with that model's energy and force, :math:`E - F\cdot s + \tfrac12 s^T H s` and
    :math:`F - H s` (which balance the coupling there exactly), and no second sum is taken. The
    memo keeps P with its exact E, F and Hessian and the published point: a call that starts from
    the published point starts from P (the quadratic model's Newton step from P + s and from P
    land on the same point). A haptic loop passes :data:`TRACKING_REDUCTION`: the tip tracks its
    minimum, a target moving less than a step a tick costs one sum a tick (the one at the step's
    end: the start's is remembered), the published tip is off the minimum by the quadratic model's
    error (second order in the step's residual), and the next tick takes the rest of the way; an
    approach, a snap or a jump of the target still runs within the tick. Every step lowers f."""
    work, memo, trial = lat[L_WORK], lat[L_MEMO], lat[L_TRIAL]
    hess, trial_hess = work[0], work[1]  # each trial's Hessian: an accepted step needs no sum again
    tol = PROXY_TOL * stiffness * radius
    cap = PROXY_STEP * radius
    if ((tip[0] == memo[0] and tip[1] == memo[1] and tip[2] == memo[2])
            or (tip[0] == memo[_PUBLISHED] and tip[1] == memo[_PUBLISHED + 1] and tip[2] == memo[_PUBLISHED + 2])):
        tip[0], tip[1], tip[2] = memo[0], memo[1], memo[2]  # where the last call ended (or its summed point): E is known
        for q in range(Z_SIZE):
            out[q] = memo[3 + q]
        for q in range(3):
            for r in range(3):
                hess[q, r] = work[2, q, r]
    else:
        tip_energy_kernel(lat, tip[0], tip[1], tip[2], radius, e_star, sigma0, h0, out, hess)
        _remember(memo, work, tip, out, hess)
    value = out[Z_ENERGY] + 0.5 * stiffness * ((tip[0] - cx) ** 2 + (tip[1] - cy) ** 2 + (tip[2] - cz) ** 2)
    start = math.nan
    for it in range(PROXY_ITERATIONS):
        gx = -out[Z_FORCE] + stiffness * (tip[0] - cx)
        gy = -out[Z_FORCE + 1] + stiffness * (tip[1] - cy)
        gz = -out[Z_FORCE + 2] + stiffness * (tip[2] - cz)
        norm = math.sqrt(gx * gx + gy * gy + gz * gz)
        if norm <= tol:
            return it
        if it == 0:
            start = norm
        sx, sy, sz = _solve3(hess, stiffness, -gx, -gy, -gz)
        newton = sx * gx + sy * gy + sz * gz < 0.0
        if not newton:  # not a descent direction: down the gradient
            sx, sy, sz = -gx / stiffness, -gy / stiffness, -gz / stiffness
        size = math.sqrt(sx * sx + sy * sy + sz * sz)
        if size > cap:
            sx, sy, sz = sx * cap / size, sy * cap / size, sz * cap / size
        slope = sx * gx + sy * gy + sz * gz
        t = 1.0
        for _ in range(40):  # Armijo: halve until f falls by at least a tenth of what the slope promises
            px, py, pz = tip[0] + t * sx, tip[1] + t * sy, tip[2] + t * sz
            tip_energy_kernel(lat, px, py, pz, radius, e_star, sigma0, h0, trial,
                               trial_hess)
            f = trial[Z_ENERGY] + 0.5 * stiffness * ((px - cx) ** 2 + (py - cy) ** 2 + (pz - cz) ** 2)
            if f <= value + 0.1 * t * slope:
                break
            t *= 0.5
        else:
            return -(it + 1)  # no step lowers f: at its floating-point floor
        tip[0], tip[1], tip[2] = px, py, pz
        value = f
        for q in range(Z_SIZE):
            out[q] = trial[q]
        _remember(memo, work, tip, out, trial_hess)
        for q in range(3):
            for r in range(3):
                hess[q, r] = trial_hess[q, r]
        if newton and t == 1.0 and size <= cap and reduction > 0.0:
            gx = -out[Z_FORCE] + stiffness * (tip[0] - cx)
            gy = -out[Z_FORCE + 1] + stiffness * (tip[1] - cy)
            gz = -out[Z_FORCE + 2] + stiffness * (tip[2] - cz)
            if gx * gx + gy * gy + gz * gz <= (reduction * start) ** 2:
                return it + 1
            if _publish_model_minimum(memo, trial_hess, stiffness, gx, gy, gz, size, tip, out):
                return it + 1
    return -PROXY_ITERATIONS


@njit(cache=True, inline="always")
def _publish_model_minimum(memo, h, stiffness, gx, gy, gz, step, tip, out) -> bool:
    r"""The tracking proxy's last step taken on the quadratic model of f about ``tip`` (P, just
    summed: ``out`` its E and F, ``h`` its Hessian, g = (gx, gy, gz) f's gradient there), when it
    can be trusted: :math:`s = -(h + kI)^{-1} g` descends and is at most :data:`CORRECTION_SHARE`
    of the ``step`` (m) that led to P. Then ``tip`` becomes P + s and ``out`` the model's
    :math:`E - F\cdot s + \tfrac12 s^T h s` and :math:`F - h s`, the memo records P + s as the
    point published from P, and it returns True (:func:`zone_proxy_kernel`)."""
    sx, sy, sz = _solve3(h, stiffness, -gx, -gy, -gz)
    size = math.sqrt(sx * sx + sy * sy + sz * sz)
    if not (sx * gx + sy * gy + sz * gz < 0.0 and size <= CORRECTION_SHARE * step):
        return False
    hx = h[0, 0] * sx + h[0, 1] * sy + h[0, 2] * sz
    hy = h[1, 0] * sx + h[1, 1] * sy + h[1, 2] * sz
    hz = h[2, 0] * sx + h[2, 1] * sy + h[2, 2] * sz
    out[Z_ENERGY] += -(out[Z_FORCE] * sx + out[Z_FORCE + 1] * sy + out[Z_FORCE + 2] * sz) \
        + 0.5 * (sx * hx + sy * hy + sz * hz)
    out[Z_FORCE] -= hx
    out[Z_FORCE + 1] -= hy
    out[Z_FORCE + 2] -= hz
    tip[0] += sx
    tip[1] += sy
    tip[2] += sz
    memo[_PUBLISHED], memo[_PUBLISHED + 1], memo[_PUBLISHED + 2] = tip[0], tip[1], tip[2]
    return True


@njit(cache=True, inline="always")
def _remember(memo, work, tip, out, hess):
    """E, F and the Hessian at ``tip`` kept in the lattice's ``memo`` (``L_MEMO``) and the third
    matrix of its ``work`` (``L_WORK``): the next :func:`zone_proxy_kernel` call that starts there
    needs no sum. Exact: the energy is one function of the tip (the lattice's samples never change)."""
    memo[0], memo[1], memo[2] = tip[0], tip[1], tip[2]
    for q in range(Z_SIZE):
        memo[3 + q] = out[q]
    memo[_PUBLISHED], memo[_PUBLISHED + 1], memo[_PUBLISHED + 2] = math.nan, math.nan, math.nan
    for q in range(3):
        for r in range(3):
            work[2, q, r] = hess[q, r]


@njit(cache=True)
def _solve3(m, shift, bx, by, bz):
    """x with (m + shift I) x = b for a 3 x 3 ``m`` (Cramer's rule); NaNs for a singular one."""
    m00, m11, m22 = m[0, 0] + shift, m[1, 1] + shift, m[2, 2] + shift
    d = (m00 * (m11 * m22 - m[1, 2] * m[2, 1]) - m[0, 1] * (m[1, 0] * m22 - m[1, 2] * m[2, 0])
         + m[0, 2] * (m[1, 0] * m[2, 1] - m11 * m[2, 0]))
    if d == 0.0:
        return math.nan, math.nan, math.nan
    x = (bx * (m11 * m22 - m[1, 2] * m[2, 1]) - m[0, 1] * (by * m22 - m[1, 2] * bz)
         + m[0, 2] * (by * m[2, 1] - m11 * bz)) / d
    y = (m00 * (by * m22 - m[1, 2] * bz) - bx * (m[1, 0] * m22 - m[1, 2] * m[2, 0])
         + m[0, 2] * (m[1, 0] * bz - by * m[2, 0])) / d
    z = (m00 * (m11 * bz - by * m[2, 1]) - m[0, 1] * (m[1, 0] * bz - by * m[2, 0])
         + bx * (m[1, 0] * m[2, 1] - m11 * m[2, 0])) / d
    return x, y, z


@dataclass(frozen=True)
class SurfaceLattice:
    """Samples of a surface on a uniform (u, v) lattice (:func:`surface_lattice`), sampled a tile
    at a time where the tip reaches. ``arrays`` is what the kernels take (their ``lat``; the
    ``L_*`` indices): the rest net and its knots, the lattice's u and v, its rows' x and columns' y
    (m), the trapezoidal weights along u and v, each tile's height bounds (m), the pool of
    sampled tiles (points m, the repulsion's areas m^2 and the adhesion's per them, blocks' boxes
    m) with its bookkeeping, the highest bound (m), the proxy's memo and scratch
    (:func:`_remember`), the sampling's (a tile is sampled without allocating, in the tick), the
    contact vector of a material map (:func:`surface_lattice`), and the closed form's: its output
    and state (:data:`~arsurf.contact.zone_quadric.QUADRIC_OUT`), whether it is on, and its scratch
    (:func:`tip_energy_kernel`). ``shape`` is the
    lattice's (nu, nv), ``spacing`` (hu, hv) m its rows' and columns' spacing at the first sample."""

    arrays: tuple
    shape: tuple[int, int]
    spacing: tuple[float, float]

    def kernel_args(self) -> tuple:
        """``(arrays,)``: the ``lat`` argument of :func:`zone_energy_kernel` and :func:`zone_proxy_kernel`."""
        return (self.arrays,)

    @property
    def sampled_tiles(self) -> int:
        """How many tiles the pool holds now."""
        return int((self.arrays[L_TILE_OF][:, 0] >= 0).sum())


def surface_lattice(surface, per_knot: int = 4, pool: int = DEFAULT_POOL, material=None,
                    closed_form: bool = False, reach: float | None = None) -> SurfaceLattice:
    """The rest surface of ``surface`` (a height-field :class:`~arsurf.spline.surface.BSplineSurface`)
    sampled ``per_knot`` times per knot interval along u and v (a number: 0.5 is a sample every
    second knot; spacing h), each sample standing for
    the projected area :math:`|x_u y_v - x_v y_u|\\,h_u h_v` (the lattice's edge samples for half of
    it along that edge, the trapezoidal rule). The samples are taken a tile of
    :data:`TILE` x :data:`TILE` at a time, the first time the tip reaches the tile, into a pool of
    ``pool`` tiles (the least recently used one given up for a new one): the memory is the pool's,
    whatever the scan's size, and a tile is sampled the same every time, so the energy is one
    function of the tip wherever the pool stands. ``material``: a contact vector with a material
    map (:func:`~arsurf.contact.material_map.contact_vector`; kept, read-only): each sample then
    sums its own law, the reference law's repulsion scaled by the local :math:`E^*/E^*_{ref}` and
    its adhesion by :math:`w/w_{ref}` (the range h0 the same, as the map's laws keep it).
    ``closed_form``: where the contact is smooth and alone, the energy in closed form over it
    (:func:`tip_energy_kernel`, :mod:`arsurf.contact.zone_quadric`) instead of the lattice's sum;
    not with a material map. ``reach`` (m; with ``closed_form``): the tip's radius, over which its
    check bounds the surface's third derivative (:func:`~arsurf.spline.curvature.curvature_net`)."""
    if not isinstance(closed_form, bool):
        raise SurfaceError(f"`closed_form` must be True or False (got {closed_form!r})")
    if closed_form and not (isinstance(reach, (int, float)) and not isinstance(reach, bool) and math.isfinite(reach)
                            and reach > 0.0):
        raise SurfaceError(f"the closed form needs `reach`, the tip's radius, a finite number > 0 m (got {reach!r})")
    if not (isinstance(per_knot, (int, float, np.integer, np.floating)) and not isinstance(per_knot, bool)
            and 0.0 < per_knot <= MAX_PER_KNOT):
        raise SurfaceError(f"`per_knot` must be a number in (0, {MAX_PER_KNOT:g}] (got {per_knot!r})")
    if not (isinstance(pool, (int, np.integer)) and not isinstance(pool, bool) and 1 <= pool <= MAX_POOL):
        raise SurfaceError(f"`pool` must be an integer in [1, {MAX_POOL}] tiles (got {pool!r})")
    if not surface.is_height_field_net:
        raise SurfaceError("the zone energy needs a height-field net (x along u, y along v): a fitted scan's")
    ctrl = np.array(surface.rest_control_points, order="C")  # a writable copy: a read-only one is another numba type
    ku, kv = surface.knots_u, surface.knots_v
    (u0, u1), (v0, v1) = surface.domain
    nu, nv, ntu, ntv = _lattice_size(ctrl.shape[0], ctrl.shape[1], per_knot)
    if ntu * ntv > MAX_TILES:
        raise SurfaceError(f"a lattice of {nu} x {nv} samples has {ntu * ntv} tiles, beyond {MAX_TILES}: "
                           "lower `per_knot`")
    us, vs = np.linspace(u0, u1, nu), np.linspace(v0, v1, nv)
    hu, hv = (u1 - u0) / (nu - 1), (v1 - v0) / (nv - 1)
    wu, wv = np.full(nu, hu), np.full(nv, hv)
    wu[[0, -1]] *= 0.5
    wv[[0, -1]] *= 0.5
    cv = _map_vector(material)
    joined = closed_form and cv[H_ON] == 0.0
    ev = np.empty((1, nu + nv, 3))
    surface_points_serial(ctrl, ku, kv, np.concatenate([us, np.full(nv, u0)]), np.concatenate([np.full(nu, v0), vs]),
                          0, ev)
    xs, ys = np.ascontiguousarray(ev[0, :nu, 0]), np.ascontiguousarray(ev[0, nu:, 1])
    zlo, zhi = np.empty((ntu, ntv)), np.empty((ntu, ntv))
    _tile_heights(np.ascontiguousarray(ctrl[:, :, 2]), basis_matrix_rows(ku, us)[0], basis_matrix_rows(kv, vs)[0],
                  zlo, zhi)
    arrays = (ctrl, ku, kv, us, vs, xs, ys, wu, wv, zlo, zhi,
              np.full((ntu, ntv), -1, np.int64), np.full((pool, 2), -1, np.int64), np.zeros(pool, np.int64),
              np.empty((pool * TILE * TILE, 3)), np.empty(pool * TILE * TILE), np.empty(pool * TILE * TILE),
              np.empty((pool, 2, 2, 6)), np.zeros(1, np.int64), np.array([zhi.max()]), np.full(_PUBLISHED + 3, math.nan),
              np.empty((3, 3, 3)), np.empty(Z_SIZE), np.empty((6, 3)), cv, QUADRIC_OUT.full(math.nan),
              np.array([int(joined)]), np.empty((2, 3, 3)), np.empty(Z_SIZE),
              *(curvature_net(ctrl, ku, kv, reach) if joined else (np.zeros((0, 0, 4)), ku, kv)))
    return SurfaceLattice(arrays, (nu, nv), (float(xs[1] - xs[0]), float(ys[1] - ys[0])))


def _lattice_size(cu: int, cv: int, per_knot: float) -> tuple[int, int, int, int]:
    """``(nu, nv, ntu, ntv)``: the samples and tiles along u and v of a lattice of ``per_knot``
    samples a knot interval over a net of ``cu`` x ``cv`` control points (a whole number of
    intervals, at least ``per_knot`` a knot interval)."""
    nu = max(math.ceil((cu - 3) * per_knot - 1e-9), 2) + 1
    nv = max(math.ceil((cv - 3) * per_knot - 1e-9), 2) + 1
    return nu, nv, -(-nu // TILE), -(-nv // TILE)


def _map_vector(material) -> np.ndarray:
    """The lattice's copy of a contact vector (``material``), or one that says "no map"."""
    if material is None:
        return np.zeros(C_BODY)
    cv = np.asarray(material)
    if cv.dtype != np.float64 or cv.ndim != 1 or cv.size < C_BODY:
        raise ContactError("`material` must be a contact vector (arsurf.contact.material_map.contact_vector)")
    return np.array(cv, order="C")  # a writable copy: a read-only one is another numba type


@njit(cache=True)
def _tile_heights(z, cols_u, cols_v, zlo, zhi):
    """Each tile's lowest and highest control point over the 4 x 4 patches its samples lie on
    (``cols_u``, ``cols_v``: the first control row and column of each lattice row and column), one
    row and column wider each side: the tile lies within their heights (the convex hull)."""
    nu, nv = cols_u.shape[0], cols_v.shape[0]
    for ti in range(zlo.shape[0]):
        r0 = max(cols_u[ti * TILE] - 1, 0)
        r1 = min(cols_u[min((ti + 1) * TILE, nu) - 1] + 4, z.shape[0] - 1)
        for tj in range(zlo.shape[1]):
            c0 = max(cols_v[tj * TILE] - 1, 0)
            c1 = min(cols_v[min((tj + 1) * TILE, nv) - 1] + 4, z.shape[1] - 1)
            lo, hi = math.inf, -math.inf
            for r in range(r0, r1 + 1):
                for c in range(c0, c1 + 1):
                    lo = min(lo, z[r, c])
                    hi = max(hi, z[r, c])
            zlo[ti, tj] = lo
            zhi[ti, tj] = hi


def lattice_for(surface, tip_radius: float, interaction_range: float = 0.0, per_knot: int = 2,
                pool: int = DEFAULT_POOL, material=None, closed_form: bool = False) -> SurfaceLattice:
    r"""The lattice of ``surface`` a tip of ``tip_radius`` R (m) with a law of ``interaction_range``
    h0 (m) is summed over: samples h apart, at most :data:`SPACING_PER_RADIUS` R and
    :data:`SPACING_PER_ZONE` of the zone where a flat at zero load interacts,
    :math:`\sqrt{2 R h_0}`, whatever the scan's pixels: the adhesion's ring is that narrow
    (``bench/zone_quadrature.py``), and a 20 nm tip on a 0.016 nm-pixel STM image would sum 260 000
    samples where 400 resolve its contact; at most :data:`MAX_PER_KNOT` per knot interval and
    :data:`MAX_TILES` tiles, coarser beyond them with a warning (``per_knot`` without adhesion, h0
    = 0). ``material``, ``closed_form``: as :func:`surface_lattice`'s."""
    if not (isinstance(tip_radius, (int, float)) and math.isfinite(tip_radius) and tip_radius > 0.0):
        raise ContactError(f"`tip_radius` must be a finite number > 0 m (got {tip_radius!r})")
    if not (isinstance(interaction_range, (int, float)) and math.isfinite(interaction_range)
            and interaction_range >= 0.0):
        raise ContactError(f"`interaction_range` must be a finite number >= 0 m (got {interaction_range!r})")
    pixel = min(surface.spacing)
    zone = math.sqrt(2.0 * tip_radius * interaction_range)
    spacing = min(SPACING_PER_RADIUS * tip_radius, SPACING_PER_ZONE * zone if zone > 0.0 else pixel / per_knot)
    cu, cv = surface.control_points.shape[:2]
    cap, why = MAX_PER_KNOT, f"knots {pixel * 1e9:.3g} nm apart take at most {MAX_PER_KNOT:g} samples"
    most = 0.999 * TILE * math.sqrt(MAX_TILES / ((cu - 3) * (cv - 3)))  # the samples a knot within MAX_TILES
    while math.prod(_lattice_size(cu, cv, most)[2:]) > MAX_TILES:
        most *= 0.99
    if most < cap:
        cap, why = most, f"{cu - 3} x {cv - 3} knot intervals take at most {MAX_TILES} tiles of samples"
    lattice = surface_lattice(surface, min(pixel / spacing, cap), pool, material, closed_form, tip_radius)
    if pixel / spacing > cap:
        log.warning("the zone energy's lattice is %.3g nm apart, not %.3g nm: %s; the law is summed less well "
                    "(docs/feel.rst, \"The lattice's quadrature\")", lattice.spacing[0] * 1e9, spacing * 1e9, why)
    return lattice


def zone_energy(lattice: SurfaceLattice, law: ZoneLaw, center) -> tuple[float, np.ndarray]:
    """``(E, F)``: the tip's energy (J) and the force on it (N, (3,)) with its centre at ``center``
    (m) over ``lattice`` (module docstring)."""
    c = np.asarray(center, dtype=np.float64)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise ContactError(f"`center` must be 3 finite coordinates in m (got {center!r})")
    out = ZONE_OUT.zeros()
    tip_energy_kernel(*lattice.kernel_args(), c[0], c[1], c[2], *law.args, out, np.empty((0, 0)))
    return float(out[Z_ENERGY]), out[Z_FORCE:Z_FORCE + 3].copy()
