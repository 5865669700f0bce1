r"""The energy of the whole tip on the surface: a local law summed over every surface element.

:mod:`arsurf.contact.multi_contact` gives each local minimum of the tip-surface distance its own
Maugis-Dugdale contact and gates the loads with weights. Its force is not the gradient of an
energy: a weight that gates a load without its stored energy makes the force circulate, and a
contact that enters or leaves steps it (docs/feel.rst, "What still fails, and why"). This module
is the building block of the other way, which has no contacts to find and no gates: the tip sphere
(centre T, radius R, rigid) interacts with every element of the surface through a law of energy
per unit area :math:`\varphi(g)` of the gap :math:`g = \lVert S - T\rVert - R` along the line to
the centre (the Derjaguin approximation: Derjaguin, "Untersuchungen über die Reibung und
Adhäsion, IV. Theorie des Anhaftens kleiner Teilchen", Kolloid-Z. 69, 155-164, 1934, the force
between curved bodies from the energy per area of flat ones):

.. math::

    E(T) = \sum_k A_k\,\varphi(g_k), \qquad
    F = -\nabla_T E = \sum_k A_k\,p(g_k)\,\frac{T - S_k}{\lVert T - S_k\rVert}, \qquad p = -\varphi',

over samples :math:`S_k` fixed on a uniform (u, v) lattice of the rest surface, :math:`A_k =
\lVert S_u \times S_v\rVert\,h_u h_v` the area each stands for (:func:`surface_lattice`). The force
is the gradient of E by construction (the samples do not move with T): no work round a closed
path, and continuous wherever p is; several asperities under a wide tip push at once, each with
its own share, and no event of the contact set exists to step the force.

**The law.** On a flat pressed :math:`\delta` deep, the ring of the flat between gaps g and
g + dg has area :math:`2\pi (R + g)\,dg` and pushes along the line to the centre, whose normal
component is :math:`(R - \delta)/(R + g)`, so a rigid sphere summing p feels exactly

.. math:: P(\delta) = 2\pi (R - \delta) \int_{-\delta}^{\infty} p(g)\,dg = 2\pi (R - \delta)\,\varphi(-\delta) .

The repulsion :math:`p_r(g) = E^*\sqrt{-g}/(\pi\sqrt R)` for g < 0 gives Hertz,
:math:`\tfrac43 E^* \sqrt R\,\delta^{3/2}`; the adhesion is a Dugdale stress spread over the
interaction range :math:`h_0 = w/\sigma_0` as a smooth bump, :math:`p_a(g) = -2\sigma_0
\sin^2(\pi g/h_0)` for 0 < g < :math:`h_0` (the box of Maugis 1992 with continuous edges, the
same work w), which adds :math:`-2\pi R w` once the gap closes. So on a flat the load is, to
order :math:`\delta/R`, the Derjaguin-Muller-Toporov limit of Maugis-Dugdale with the law's own
E*, w and :math:`\sigma_0`: :math:`P(\delta) = \tfrac43 E^*\sqrt R\,\delta^{3/2} - 2\pi R w` for
:math:`\delta \ge 0`. A Johnson-Kendall-Roberts-like law (large Maugis parameter) has a
hysteresis loop, which no energy has; this law is its conservative limit with the same
constants, and its pull-off is :math:`2\pi R w` (JKR: :math:`1.5\pi R w`).

The energy per area is :math:`\varphi = \varphi_r + \varphi_a`, :math:`\varphi_r =
2E^*(-g)^{3/2}/(3\pi\sqrt R)` for g < 0, :math:`\varphi_a = -w` for g <= 0,
:math:`-\sigma_0 (h_0 - g) - \sigma_0 h_0 \sin(2\pi g/h_0)/(2\pi)` on (0, :math:`h_0`) and 0
beyond: continuous with its derivative, so the force is continuous in T.

Not wired into :class:`~arsurf.model.ARModel` yet: ``bench/zone_energy.py`` measures it against
the model on the surfaces where the feel still fails, and ``bench/zone_feel.py`` judges those runs
with it as the loop's contact (docs/feel.rst, "The next step").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf._layout import Layout
from arsurf.errors import ContactError, SurfaceError
from arsurf.spline.basis import surface_points

__all__ = ["SurfaceLattice", "ZONE_OUT", "ZoneLaw", "surface_lattice", "zone_energy", "zone_energy_kernel", "zone_law_kernel",
           "zone_proxy_kernel"]

#: what :func:`zone_energy_kernel` writes: the energy E (J) and the force F on the tip (N)
ZONE_OUT = Layout("zone energy output", [("energy", 1), ("force", 3)])
Z_ENERGY, Z_FORCE, Z_SIZE = ZONE_OUT.offset("energy"), ZONE_OUT.offset("force"), ZONE_OUT.size

#: lattice samples per block side: a block is skipped when its bounding box lies beyond reach
BLOCK = 8
#: the repulsion's gap in its stiffness is held at least this fraction of the range (:func:`zone_energy_kernel`)
HESSIAN_FLOOR = 1e-3
#: the proxy's step is at most this fraction of the tip radius (:func:`zone_proxy_kernel`)
PROXY_STEP = 0.05
#: the proxy has converged when the gradient of f is below this fraction of k R
PROXY_TOL = 1e-6
#: and gives up after this many steps
PROXY_ITERATIONS = 200
#: largest number of lattice samples :func:`surface_lattice` builds (about 1.6 GB while it is built)
MAX_SAMPLES = 20_000_000


@dataclass(frozen=True)
class ZoneLaw:
    """The local law of the module docstring: ``tip_radius`` R (m), ``effective_modulus`` E* (Pa),
    ``work_of_adhesion`` w (J/m^2), ``dugdale_stress`` sigma0 (Pa); the range h0 = w / sigma0."""

    tip_radius: float
    effective_modulus: float
    work_of_adhesion: float
    dugdale_stress: float

    def __post_init__(self):
        for name in ("tip_radius", "effective_modulus", "dugdale_stress"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ContactError(f"`{name}` must be a finite number > 0 (got {value!r})")
        w = self.work_of_adhesion
        if not (isinstance(w, (int, float)) and math.isfinite(w) and w >= 0.0):
            raise ContactError(f"`work_of_adhesion` must be a finite number >= 0 J/m^2 (got {w!r})")

    @classmethod
    def from_law(cls, law) -> "ZoneLaw":
        """The zone law with the constants of a :class:`~arsurf.contact.maugis_dugdale.MaugisDugdale`."""
        return cls(float(law.tip_radius), float(law.effective_modulus), float(law.work_of_adhesion),
                   float(law.dugdale_stress))

    @property
    def interaction_range(self) -> float:
        """h0 = w / sigma0 (m)."""
        return self.work_of_adhesion / self.dugdale_stress

    def flat_load(self, depth: float) -> float:
        r"""The load (N, > 0 compressive) the law gives a rigid sphere pressed ``depth`` (m; < 0: a
        gap) into a flat: :math:`2\pi (R - \delta)\,\varphi(-\delta)` (module docstring), exact
        for a depth below R."""
        phi = zone_law_kernel(-float(depth), *self.args)[0]
        return 2.0 * math.pi * (self.tip_radius - depth) * phi

    @property
    def args(self) -> tuple[float, float, float, float]:
        """``(R, E*, sigma0, h0)`` for :func:`zone_energy_kernel`."""
        return (self.tip_radius, self.effective_modulus, self.dugdale_stress, self.interaction_range)


@njit(cache=True)
def zone_law_kernel(g, radius, e_star, sigma0, h0):
    r"""``(phi, p)``: the energy per area (J/m^2) and the pressure (Pa, > 0 repulsive) at gap ``g``
    (m) of the module docstring's law."""
    phi = p = 0.0
    if g < 0.0:
        s = math.sqrt(-g)
        k = e_star / (math.pi * math.sqrt(radius))
        phi = 2.0 / 3.0 * k * s * s * s - sigma0 * h0
        p = k * s
    elif g < h0:
        x = math.pi * g / h0
        phi = -sigma0 * (h0 - g) - sigma0 * h0 * math.sin(2.0 * x) / (2.0 * math.pi)
        p = -2.0 * sigma0 * math.sin(x) ** 2
    return phi, p


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
def zone_energy_kernel(points, areas, xs, ys, boxes, tx, ty, tz, radius, e_star, sigma0, h0, out, hess) -> int:
    r"""E(T) and F(T) of the module docstring at T = (tx, ty, tz) (m) over the lattice ``points``
    (nu, nv, 3) m, ``areas`` (nu, nv) m^2, its rows' x and columns' y (``xs``, ``ys``, sorted: a
    height-field net) and its blocks' bounding boxes ``boxes`` (nbu, nbv, 6: x, y, z lows then
    highs). Writes ``out`` (:data:`ZONE_OUT`): E (J) and F (N); returns the number of samples within
    reach (g < h0). ``hess`` (3, 3), unless empty, gets E's Hessian (N/m),
    :math:`\sum_k A_k [-p'(g_k)\,u u^T - p(g_k)/d_k\,(I - u u^T)]`, u the unit vector from the
    sample to T, with :math:`-g` held at least :data:`HESSIAN_FLOOR` h0 in the repulsion's
    :math:`p' \propto 1/\sqrt{-g}` (a sample at the contact's edge: an infinite but integrable
    stiffness; :func:`zone_proxy_kernel` uses the Hessian only for its step)."""
    want = hess.shape[0] == 3
    if want:
        hess[:, :] = 0.0
    reach = radius + h0
    i0 = max(_first_at_least(xs, tx - reach) - 1, 0)
    i1 = min(_first_at_least(xs, tx + reach) + 1, xs.shape[0])
    j0 = max(_first_at_least(ys, ty - reach) - 1, 0)
    j1 = min(_first_at_least(ys, ty + reach) + 1, ys.shape[0])
    energy = fx = fy = fz = 0.0
    n = 0
    for bi in range(i0 // BLOCK, (i1 + BLOCK - 1) // BLOCK):
        for bj in range(j0 // BLOCK, (j1 + BLOCK - 1) // BLOCK):
            b = boxes[bi, bj]
            dx = max(b[0] - tx, 0.0, tx - b[3])
            dy = max(b[1] - ty, 0.0, ty - b[4])
            dz = max(b[2] - tz, 0.0, tz - b[5])
            if dx * dx + dy * dy + dz * dz >= reach * reach:
                continue
            for i in range(max(bi * BLOCK, i0), min((bi + 1) * BLOCK, i1)):
                for j in range(max(bj * BLOCK, j0), min((bj + 1) * BLOCK, j1)):
                    ex = tx - points[i, j, 0]
                    ey = ty - points[i, j, 1]
                    ez = tz - points[i, j, 2]
                    d = math.sqrt(ex * ex + ey * ey + ez * ez)
                    g = d - radius
                    if g >= h0 or d == 0.0:
                        continue
                    phi, p = zone_law_kernel(g, radius, e_star, sigma0, h0)
                    a = areas[i, j]
                    energy += a * phi
                    f = a * p / d
                    fx += f * ex
                    fy += f * ey
                    fz += f * ez
                    n += 1
                    if want:  # a (-p' u u^T - p/d (I - u u^T)), u = e/d
                        radial = -a * _pressure_slope(g, radius, e_star, sigma0, h0) / (d * d)
                        hess[0, 0] -= f
                        hess[1, 1] -= f
                        hess[2, 2] -= f
                        c = radial + f / (d * d)
                        hess[0, 0] += c * ex * ex
                        hess[0, 1] += c * ex * ey
                        hess[0, 2] += c * ex * ez
                        hess[1, 1] += c * ey * ey
                        hess[1, 2] += c * ey * ez
                        hess[2, 2] += c * ez * ez
    out[Z_ENERGY] = energy
    out[Z_FORCE] = fx
    out[Z_FORCE + 1] = fy
    out[Z_FORCE + 2] = fz
    if want:
        hess[1, 0] = hess[0, 1]
        hess[2, 0] = hess[0, 2]
        hess[2, 1] = hess[1, 2]
    return n


@njit(cache=True)
def _pressure_slope(g, radius, e_star, sigma0, h0):
    """dp/dg (Pa/m) of the law at gap ``g`` (m), the repulsion's held finite at the contact's edge
    (:func:`zone_energy_kernel`)."""
    if g < 0.0:
        return -0.5 * e_star / (math.pi * math.sqrt(radius) * math.sqrt(max(-g, HESSIAN_FLOOR * h0)))
    if g < h0:
        return -2.0 * sigma0 * math.pi / h0 * math.sin(2.0 * math.pi * g / h0)
    return 0.0


@njit(cache=True)
def zone_proxy_kernel(points, areas, xs, ys, boxes, cx, cy, cz, stiffness, radius, e_star, sigma0, h0, tip,
                      out) -> int:
    r"""The tip behind a virtual coupling: from ``tip`` (3,) m (the last tick's, or a point above the
    surface), the nearest minimum of :math:`f(T) = E(T) + \tfrac12 k\lVert T - C\rVert^2`, C the
    target (cx, cy, cz) m and k the coupling ``stiffness`` (N/m), into ``tip`` in place: Newton's
    method on the energy's Hessian plus k, each step at most :data:`PROXY_STEP` R and halved until
    f falls (a gradient step where the Newton step does not descend), until the gradient is below
    :data:`PROXY_TOL` of the coupling's force at one tip radius. As the god-object's proxy
    (Zilles & Salisbury 1995) the tip moves from where it was and stops where the forces balance;
    on a conservative E it settles, and a snap is its minimum ending. ``out`` (:data:`ZONE_OUT`): E
    (J) and F (N) at the tip. Returns the iterations (negative: not converged in
    :data:`PROXY_ITERATIONS`)."""
    hess = np.empty((3, 3))
    trial = np.empty(Z_SIZE)
    trial_hess = np.empty((3, 3))  # each trial's Hessian: an accepted step needs no sum again
    tol = PROXY_TOL * stiffness * radius
    cap = PROXY_STEP * radius
    zone_energy_kernel(points, areas, xs, ys, boxes, tip[0], tip[1], tip[2], radius, e_star, sigma0, h0, out, hess)
    value = out[Z_ENERGY] + 0.5 * stiffness * ((tip[0] - cx) ** 2 + (tip[1] - cy) ** 2 + (tip[2] - cz) ** 2)
    for it in range(PROXY_ITERATIONS):
        gx = -out[Z_FORCE] + stiffness * (tip[0] - cx)
        gy = -out[Z_FORCE + 1] + stiffness * (tip[1] - cy)
        gz = -out[Z_FORCE + 2] + stiffness * (tip[2] - cz)
        if math.sqrt(gx * gx + gy * gy + gz * gz) <= tol:
            return it
        for q in range(3):
            hess[q, q] += stiffness
        sx, sy, sz = _solve3(hess, -gx, -gy, -gz)
        if not (sx * gx + sy * gy + sz * gz < 0.0):  # not a descent direction: down the gradient
            sx, sy, sz = -gx / stiffness, -gy / stiffness, -gz / stiffness
        size = math.sqrt(sx * sx + sy * sy + sz * sz)
        if size > cap:
            sx, sy, sz = sx * cap / size, sy * cap / size, sz * cap / size
        slope = sx * gx + sy * gy + sz * gz
        t = 1.0
        for _ in range(40):  # Armijo: halve until f falls by at least a tenth of what the slope promises
            px, py, pz = tip[0] + t * sx, tip[1] + t * sy, tip[2] + t * sz
            zone_energy_kernel(points, areas, xs, ys, boxes, px, py, pz, radius, e_star, sigma0, h0, trial,
                               trial_hess)
            f = trial[Z_ENERGY] + 0.5 * stiffness * ((px - cx) ** 2 + (py - cy) ** 2 + (pz - cz) ** 2)
            if f <= value + 0.1 * t * slope:
                break
            t *= 0.5
        else:
            return -(it + 1)  # no step lowers f: at its floating-point floor
        tip[0], tip[1], tip[2] = px, py, pz
        value = f
        out[:] = trial
        hess[:, :] = trial_hess
    return -PROXY_ITERATIONS


@njit(cache=True)
def _solve3(m, bx, by, bz):
    """x with m x = b for a 3 x 3 ``m`` (Cramer's rule); NaNs for a singular one."""
    d = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
         + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))
    if d == 0.0:
        return math.nan, math.nan, math.nan
    x = (bx * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) - m[0, 1] * (by * m[2, 2] - m[1, 2] * bz)
         + m[0, 2] * (by * m[2, 1] - m[1, 1] * bz)) / d
    y = (m[0, 0] * (by * m[2, 2] - m[1, 2] * bz) - bx * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
         + m[0, 2] * (m[1, 0] * bz - by * m[2, 0])) / d
    z = (m[0, 0] * (m[1, 1] * bz - by * m[2, 1]) - m[0, 1] * (m[1, 0] * bz - by * m[2, 0])
         + bx * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])) / d
    return x, y, z


@dataclass(frozen=True)
class SurfaceLattice:
    """Samples of a surface on a uniform (u, v) lattice (:func:`surface_lattice`): ``points``
    (nu, nv, 3) m, ``areas`` (nu, nv) m^2, ``xs`` (nu,) and ``ys`` (nv,) m the rows' x and the
    columns' y, ``boxes`` (nbu, nbv, 6) m the blocks' bounding boxes, ``spacing`` (hu, hv) m."""

    points: np.ndarray
    areas: np.ndarray
    xs: np.ndarray
    ys: np.ndarray
    boxes: np.ndarray
    spacing: tuple[float, float]

    def kernel_args(self) -> tuple:
        """``(points, areas, xs, ys, boxes)`` for :func:`zone_energy_kernel`."""
        return (self.points, self.areas, self.xs, self.ys, self.boxes)


def surface_lattice(surface, per_knot: int = 4) -> SurfaceLattice:
    """The rest surface of ``surface`` (a height-field :class:`~arsurf.spline.surface.BSplineSurface`)
    sampled ``per_knot`` times per knot interval along u and v (spacing h), each sample standing for
    the area :math:`\\lVert S_u \\times S_v\\rVert h_u h_v` (the lattice's edge samples for half of
    it along that edge, the trapezoidal rule)."""
    if not (isinstance(per_knot, (int, np.integer)) and not isinstance(per_knot, bool) and 1 <= per_knot <= 64):
        raise SurfaceError(f"`per_knot` must be an integer in [1, 64] (got {per_knot!r})")
    if not surface.is_height_field_net:
        raise SurfaceError("the zone energy needs a height-field net (x along u, y along v): a fitted scan's")
    ctrl = surface.rest_control_points
    ku, kv = surface.knots_u, surface.knots_v
    (u0, u1), (v0, v1) = surface.domain
    nu = (ctrl.shape[0] - 3) * per_knot + 1
    nv = (ctrl.shape[1] - 3) * per_knot + 1
    if nu * nv > MAX_SAMPLES:
        raise SurfaceError(f"a lattice of {nu} x {nv} samples is beyond {MAX_SAMPLES}: lower `per_knot`")
    us, vs = np.linspace(u0, u1, nu), np.linspace(v0, v1, nv)
    uu, vv = (a.ravel() for a in np.meshgrid(us, vs, indexing="ij"))
    ev = np.empty((3, uu.size, 3))
    surface_points(np.ascontiguousarray(ctrl), ku, kv, uu, vv, 1, ev)
    points = np.ascontiguousarray(ev[0].reshape(nu, nv, 3))
    hu, hv = (u1 - u0) / (nu - 1), (v1 - v0) / (nv - 1)
    areas = np.linalg.norm(np.cross(ev[1], ev[2]), axis=1).reshape(nu, nv) * hu * hv
    areas[[0, -1], :] *= 0.5
    areas[:, [0, -1]] *= 0.5
    nbu, nbv = -(-nu // BLOCK), -(-nv // BLOCK)
    boxes = np.empty((nbu, nbv, 6))
    for bi in range(nbu):
        for bj in range(nbv):
            block = points[bi * BLOCK:(bi + 1) * BLOCK, bj * BLOCK:(bj + 1) * BLOCK].reshape(-1, 3)
            boxes[bi, bj, :3] = block.min(axis=0)
            boxes[bi, bj, 3:] = block.max(axis=0)
    return SurfaceLattice(points, areas, np.ascontiguousarray(points[:, 0, 0]), np.ascontiguousarray(points[0, :, 1]),
                          boxes, (float(points[1, 0, 0] - points[0, 0, 0]), float(points[0, 1, 1] - points[0, 0, 1])))


def zone_energy(lattice: SurfaceLattice, law: ZoneLaw, center) -> tuple[float, np.ndarray]:
    """``(E, F)``: the tip's energy (J) and the force on it (N, (3,)) with its centre at ``center``
    (m) over ``lattice`` (module docstring)."""
    c = np.asarray(center, dtype=np.float64)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise ContactError(f"`center` must be 3 finite coordinates in m (got {center!r})")
    out = ZONE_OUT.zeros()
    zone_energy_kernel(*lattice.kernel_args(), c[0], c[1], c[2], *law.args, out, np.empty((0, 0)))
    return float(out[Z_ENERGY]), out[Z_FORCE:Z_FORCE + 3].copy()
