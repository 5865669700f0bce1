"""Slow, obviously-right references for every fast kernel, in one place.

Each is written for clarity, not speed: the textbook formula, a dense sampling, a plain root
finder, an explicit matrix solve. The fast code is checked against them on random inputs
(tests/model/test_reference.py and the module tests).

* B-spline: Cox-de Boor recursion and a sum over every basis function (no span logic);
* closest point: the surface sampled densely, the nearest samples polished by plain projected
  Newton (:func:`brute_force`);
* Maugis-Dugdale: Maugis' equations as printed, solved with scipy's brentq (:func:`ref_load_depth`,
  :func:`ref_radius_from_depth`, :func:`ref_radius_from_load`);
* decoupling: the 3 x 3 system of docs/design.rst ("Force from the two angles") written literally and
  solved with ``numpy.linalg.solve``
  (:func:`reference_decouple`);
* the model tick: the four references chained (:func:`reference_model_tick`);
* the surface around a contact: Boussinesq's point-load solution summed over rings of Maugis'
  traction (Hertz pressure plus Dugdale stress) by adaptive quadrature
  (:func:`ref_surface_displacement`, :func:`ref_md_traction`);
* a model's indentation at a given load: plain bisection on the tip height, a fresh tip each
  time (:func:`ref_tick_at_load`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq, minimize_scalar
from scipy.spatial import cKDTree


# ---------------------------------------------------------------------------------------------
# B-spline
def cox_de_boor(knots, i, p, u):
    """N_{i,p}(u) by the textbook recursion (right-continuous; the last span closed at its end)."""
    t = knots
    if p == 0:
        if t[i] <= u < t[i + 1]:
            return 1.0
        # close the last non-empty span so the basis is a partition of unity at u = b
        if u == t[-1] and t[i] < t[i + 1] == t[-1]:
            return 1.0
        return 0.0
    left = 0.0 if t[i + p] == t[i] else (u - t[i]) / (t[i + p] - t[i]) * cox_de_boor(t, i, p - 1, u)
    right = 0.0 if t[i + p + 1] == t[i + 1] else (t[i + p + 1] - u) / (t[i + p + 1] - t[i + 1]) * cox_de_boor(t, i + 1, p - 1, u)
    return left + right


def cox_de_boor_derivative(knots, i, p, u, order):
    """d^order N_{i,p} / du^order by the recursive derivative formula."""
    if order == 0:
        return cox_de_boor(knots, i, p, u)
    t = knots
    a = 0.0 if t[i + p] == t[i] else p / (t[i + p] - t[i]) * cox_de_boor_derivative(t, i, p - 1, u, order - 1)
    b = 0.0 if t[i + p + 1] == t[i + 1] else p / (t[i + p + 1] - t[i + 1]) * cox_de_boor_derivative(t, i + 1, p - 1, u, order - 1)
    return a - b


def surface_reference(ctrl, ku, kv, u, v, du=0, dv=0):
    """S (or a partial derivative) by summing every basis function (no span logic at all)."""
    nu, nv = ctrl.shape[:2]
    bu = np.array([cox_de_boor_derivative(ku, i, 3, u, du) for i in range(nu)])
    bv = np.array([cox_de_boor_derivative(kv, j, 3, v, dv) for j in range(nv)])
    return np.einsum("i,j,ijc->c", bu, bv, ctrl)


# ---------------------------------------------------------------------------------------------
# closest point

def polish(surface, points, u, v, iters=60):
    """Plain projected Newton on D = |S - C|^2 / 2 from (u, v), vectorised over the points; a
    step is halved until D does not increase (no other safeguard). Points stop once their step
    is below 1e-10 of the knot spacing."""
    (u0, u1), (v0, v1) = surface.domain
    tol = 1e-10 * max(surface.spacing)
    u = np.array(u, dtype=float)
    v = np.array(v, dtype=float)
    d2 = ((surface.evaluate(u, v) - points) ** 2).sum(axis=1)
    act = np.arange(u.size)
    for _ in range(iters):
        if act.size == 0:
            break
        ua, va, ca, da = u[act], v[act], points[act], d2[act]
        s, su, sv, suu, suv, svv = surface.evaluate(ua, va, 2)
        r = s - ca
        gu = (su * r).sum(1)
        gv = (sv * r).sum(1)
        a = (su * su).sum(1)
        b = (su * sv).sum(1)
        c = (sv * sv).sum(1)
        huu = a + (suu * r).sum(1)
        huv = b + (suv * r).sum(1)
        hvv = c + (svv * r).sum(1)
        # one free variable (the other on a bound): 1-D Newton, Gauss-Newton if its curvature is <= 0
        du1 = -gu / np.where(huu > 0, huu, a)
        dv1 = -gv / np.where(hvv > 0, hvv, c)
        # both free: Newton, Gauss-Newton where H is not positive definite
        pd = (huu > 0) & (huu * hvv - huv * huv > 0)
        huu, huv, hvv = np.where(pd, huu, a), np.where(pd, huv, b), np.where(pd, hvv, c)
        det = huu * hvv - huv * huv
        du = (huv * gv - hvv * gu) / det
        dv = (huv * gu - huu * gv) / det
        fix_u = ((ua <= u0) & (gu > 0)) | ((ua >= u1) & (gu < 0))
        fix_v = ((va <= v0) & (gv > 0)) | ((va >= v1) & (gv < 0))
        du, dv = np.where(fix_u, 0.0, np.where(fix_v, du1, du)), np.where(fix_v, 0.0, np.where(fix_u, dv1, dv))
        alpha = np.ones_like(ua)
        done = np.zeros(ua.size, bool)
        moved = np.zeros(ua.size)
        for _ in range(40):
            ut = np.clip(ua + alpha * du, u0, u1)
            vt = np.clip(va + alpha * dv, v0, v1)
            dt = ((surface.evaluate(ut, vt) - ca) ** 2).sum(1)
            ok = ~done & (dt <= da)
            moved = np.where(ok, np.maximum(np.abs(ut - ua), np.abs(vt - va)), moved)
            ua, va, da = np.where(ok, ut, ua), np.where(ok, vt, va), np.where(ok, dt, da)
            done |= ok
            if done.all():
                break
            alpha = np.where(done, alpha, 0.5 * alpha)
        u[act], v[act], d2[act] = ua, va, da
        act = act[done & (moved > tol)]
    return u, v, np.sqrt(d2)


class DenseSampling:
    """The surface sampled ``per_cell`` x ``per_cell`` times per knot cell, in a KD-tree."""

    def __init__(self, surface, per_cell=8):
        (u0, u1), (v0, v1) = surface.domain
        nu, nv = surface.shape
        uu, vv = np.meshgrid(np.linspace(u0, u1, (nu - 3) * per_cell + 1),
                             np.linspace(v0, v1, (nv - 3) * per_cell + 1), indexing="ij")
        self.surface = surface
        self.u = uu.ravel()
        self.v = vv.ravel()
        self.points = surface.evaluate(self.u, self.v)
        self.tree = cKDTree(self.points)
        self.cell = max(surface.spacing)

    def nearest(self, points, k=1):
        return self.tree.query(points, k=k)

    def reference(self, points, k=8):
        """Brute-force closest points: the nearest sample polished by Newton, and the other k-1
        nearest samples too wherever one of them lies more than a cell away from the nearest
        (another basin may be there); the best polished point is kept."""
        dist, idx = self.nearest(points, k=k)
        u, v, d = polish(self.surface, points, self.u[idx[:, 0]], self.v[idx[:, 0]])
        far = ((np.abs(self.u[idx] - self.u[idx[:, :1]]) > self.cell)
               | (np.abs(self.v[idx] - self.v[idx[:, :1]]) > self.cell))
        rows, cols = np.nonzero(far)
        if rows.size:
            pu, pv, pd = polish(self.surface, points[rows], self.u[idx[rows, cols]], self.v[idx[rows, cols]])
            order = np.argsort(pd)[::-1]  # so the best per row is written last
            rows, pu, pv, pd = rows[order], pu[order], pv[order], pd[order]
            better = pd < d[rows]
            u[rows[better]], v[rows[better]], d[rows[better]] = pu[better], pv[better], pd[better]
        return u, v, d, dist[:, 0]


def brute_force(surface, points, per_cell=8, k=8):
    """(u, v, distance, nearest-sample distance) of the closest points, by brute force."""
    return DenseSampling(surface, per_cell).reference(np.asarray(points, dtype=float), k=k)



# ---------------------------------------------------------------------------------------------
# Maugis-Dugdale: Maugis' equations as printed, solved with plain brentq

def ref_m(A: float, lam: float) -> float:
    """m = c/a from the first MD equation at fixed A (brentq on ln(m - 1))."""
    def f(u):
        m = 1.0 + u
        s = math.sqrt(u * (2.0 + u))          # sqrt(m^2 - 1) without cancellation
        at = math.atan(s)
        return (lam * A * A / 2.0 * (s + (m * m - 2.0) * at)
                + 4.0 * lam * lam * A / 3.0 * (s * at - m + 1.0) - 1.0)
    v = brentq(lambda v: f(math.exp(v)), -600.0, 40.0, xtol=1e-14, rtol=1e-15, maxiter=1000)
    return 1.0 + math.exp(v)


def ref_load_depth(A: float, lam: float) -> tuple[float, float]:
    """(P-bar, Delta-bar) at contact radius A."""
    m = ref_m(A, lam)
    s = math.sqrt((m - 1.0) * (m + 1.0))
    at = math.atan(s)
    return A ** 3 - lam * A * A * (s + m * m * at), A * A - 4.0 / 3.0 * lam * A * s


def ref_min(fun, lo=1e-3, hi=20.0):
    """Interior minimum of fun(A) by a log grid + bounded Brent; None if the minimum is at the edge."""
    grid = np.geomspace(lo, hi, 200)
    vals = [fun(a) for a in grid]
    i = int(np.argmin(vals))
    if i == 0:
        return None
    res = minimize_scalar(lambda x: fun(math.exp(x)), bounds=(math.log(grid[i - 1]), math.log(grid[i + 1])),
                          method="bounded", options={"xatol": 1e-12})
    return math.exp(res.x), float(res.fun)


def ref_radius_from_depth(D: float, lam: float) -> float:
    """Stable-branch A at depth D: brentq on Delta(A) - D between the fold (or 0) and a large A."""
    fold = ref_min(lambda a: ref_load_depth(a, lam)[1])
    lo = fold[0] if fold else 1e-6
    return brentq(lambda a: ref_load_depth(a, lam)[1] - D, lo, 1e3, xtol=1e-15, rtol=1e-14)


def ref_radius_from_load(P: float, lam: float) -> float:
    A_pull, _ = ref_min(lambda a: ref_load_depth(a, lam)[0])
    return brentq(lambda a: ref_load_depth(a, lam)[0] - P, A_pull, 1e3, xtol=1e-15, rtol=1e-14)


# ---------------------------------------------------------------------------------------------
# decoupling

def reference_matrix(n, v, lever):
    """The system of docs/design.rst ("Force from the two angles"), written literally (division by n_z),
    in physical units."""
    g, c = lever.bending_compliance, lever.torsion_compliance
    kappa = 2 * lever.lever_arm / lever.length
    f = np.array([-v[0], -v[1], (v[0] * n[0] + v[1] * n[1]) / n[2]])
    p = np.cross(n, f)
    return np.array([[0.0, c, 0.0], [g * kappa, 0.0, g], p]), p, kappa


def reference_decouple(bending, torsion, n, v, lever):
    m, _, _ = reference_matrix(n, v, lever)
    return np.linalg.solve(m, np.array([torsion, bending, 0.0]))


def reference_condition(n, v, lever):
    """1-norm condition number of the row-scaled system (rows: tau, beta, unit p)."""
    _, p, kappa = reference_matrix(n, v, lever)
    p = p / np.linalg.norm(p)
    return np.linalg.cond(np.array([[0.0, 1.0, 0.0], [kappa, 0.0, 1.0], p]), 1)


# ---------------------------------------------------------------------------------------------
# the model tick


def ref_zone_normal(surface, center, u, v, normal, tip_radius, floor, depth, zone):
    """The direction a contact at (u, v) pushes (:mod:`arsurf.contact.zone_normal`), written out: the
    point's normal weighed by the interference R - floor - d, plus the area-weighted normals of the
    other samples of a square stencil of ZONE_NODES^2 over +-ZONE_HALF_WIDTH R in u and v, each weighed by its
    interference R - floor - |S - C| (> 0), the cosine between its normal and C - S (> 0) and the
    window 1 - r^2/zone^2 (> 0) of its distance r from (u, v); turned back towards the point's normal
    over the last ZONE_FADE R of the centre's distance d to the surface."""
    from arsurf.contact.zone_normal import ZONE_FADE, ZONE_HALF_WIDTH, ZONE_NODES

    c = np.asarray(center, dtype=float)
    reach, d = tip_radius - floor, tip_radius - depth
    if not (reach > 0.0 and 0.0 < d < reach and zone > 0.0):
        return normal
    (u0, u1), (v0, v1) = surface.domain
    total = (reach - d) * np.asarray(normal, dtype=float)
    offsets = np.linspace(-ZONE_HALF_WIDTH * tip_radius, ZONE_HALF_WIDTH * tip_radius, ZONE_NODES)
    for i, du in enumerate(offsets):
        for j, dv in enumerate(offsets):
            window = 1.0 - (du * du + dv * dv) / zone ** 2
            if window <= 0.0 or i == j == ZONE_NODES // 2:  # the centre: the point's own term above
                continue
            s, su, sv = surface.evaluate(min(max(u + du, u0), u1), min(max(v + dv, v0), v1), 1)
            r = c - s
            dist = float(np.linalg.norm(r))
            area = np.cross(su, sv)
            cos = float(r @ area) / (dist * float(np.linalg.norm(area)))
            if reach - dist > 0.0 and cos > 0.0:
                total = total + (reach - dist) * window * cos * area
    t = min(d / (ZONE_FADE * tip_radius), 1.0)
    m = (1.0 - t) * np.asarray(normal, dtype=float) + t * total / np.linalg.norm(total)
    return m / np.linalg.norm(m)


def reference_model_tick(surface, center, tip_radius, effective_modulus, work_of_adhesion, dugdale_stress,
                         lever, velocity, jump_out):
    """One rigid, frictionless tick of the AR model from the references alone (first touch).

    Closest point by brute force; signed distance along the normal :math:`n = S_u \\times S_v /
    |S_u \\times S_v|`; depth :math:`\\delta = R - d`; Maugis-Dugdale radius and load from the
    depth (stable branch, :func:`ref_radius_from_depth`, then :func:`ref_load_depth`) when the tip
    penetrates; simulated force :math:`P n`; the two angles it bends and twists the lever by
    (docs/design.rst, "Force from the two angles": :math:`\\Delta\\theta = c F_y`, :math:`\\Delta\\alpha = g (F_z +
    \\kappa F_x)`), decoupled again with :func:`reference_decouple`. The normal is the contact's
    direction over its zone (:func:`ref_zone_normal`, the Dugdale radius c as the zone, the
    interaction floor the law's ``jump_out`` depth (m) less the model's contact margin).

    Returns a dict: ``point``, ``normal``, ``depth``, ``radius``, ``load``, ``force``,
    ``bending``, ``torsion``, ``measured`` (the decoupled force; NaN when the tip stands still).
    """
    c = np.asarray(center, dtype=float)
    u, v, dist = brute_force(surface, c[None, :])[:3]
    s, su, sv = surface.evaluate(u[0], v[0], 1)
    n = np.cross(su, sv)
    n /= np.linalg.norm(n)
    signed = float(np.dot(c - s, n))
    assert abs(abs(signed) - dist[0]) <= 1e-12, "brute-force point is not a foot of the normal"
    depth = tip_radius - signed
    k = 4.0 * effective_modulus / 3.0
    w = work_of_adhesion
    lam = 2.0 * dugdale_stress * (tip_radius / (math.pi * w * k * k)) ** (1.0 / 3.0)
    radius_scale = (math.pi * w * tip_radius ** 2 / k) ** (1.0 / 3.0)
    depth_scale = (math.pi ** 2 * w ** 2 * tip_radius / k ** 2) ** (1.0 / 3.0)
    load_scale = math.pi * w * tip_radius
    radius = load = 0.0
    if depth > 0.0:
        A = ref_radius_from_depth(depth / depth_scale, lam)
        radius = A * radius_scale
        load = ref_load_depth(A, lam)[0] * load_scale
        from arsurf.model import CONTACT_MARGIN

        floor = jump_out - CONTACT_MARGIN * depth_scale
        n = ref_zone_normal(surface, c, u[0], v[0], n, tip_radius, floor, depth, ref_m(A, lam) * radius)
    force = load * n
    g, tc = lever.bending_compliance, lever.torsion_compliance
    kappa = 2 * lever.lever_arm / lever.length
    bending = g * (force[2] + kappa * force[0])
    torsion = tc * force[1]
    vel = np.asarray(velocity, dtype=float)
    measured = (reference_decouple(bending, torsion, n, vel, lever) if load > 0.0 and np.hypot(*vel[:2]) > 0
                else np.full(3, np.nan))
    return {"point": s, "normal": n, "depth": depth, "radius": radius, "load": load, "force": force,
            "bending": bending, "torsion": torsion, "measured": measured}


# ---------------------------------------------------------------------------------------------
# the elastic surface around a Maugis-Dugdale contact


def ref_md_traction(t, a, c, tip_radius, effective_modulus, sigma0):
    """Maugis' normal traction (Pa, compressive > 0) at radius t: the Hertz pressure of radius a,
    (2E*/pi R) sqrt(a^2 - t^2), plus the Dugdale stress, -(sigma0/pi) arccos((2a^2 - c^2 - t^2)/(c^2 - t^2))
    inside a and -sigma0 on a < t < c (Maugis 1992, as printed)."""
    p = 0.0
    if t < a:
        p += 2.0 * effective_modulus / (math.pi * tip_radius) * math.sqrt(a * a - t * t)
        if c > a:
            p -= sigma0 / math.pi * math.acos(min(max((2 * a * a - c * c - t * t) / (c * c - t * t), -1.0), 1.0))
    elif t < c:
        p -= sigma0
    return p


def ref_surface_displacement(rho, a, c, tip_radius, effective_modulus, sigma0):
    """Normal surface displacement (m, into the body) at radius rho under :func:`ref_md_traction`.

    Boussinesq: a point load P displaces the surface by P / (pi E* r); a ring of radius t carrying
    p(t) t dt dphi gives, integrated over phi, (4 / pi E*) p(t) t K(m) / (rho + t) dt with
    m = 4 rho t / (rho + t)^2 (scipy's parameter convention). The log singularity at t = rho is
    handed to quad as a break point."""
    from scipy.integrate import quad
    from scipy.special import ellipkm1

    def ring(t):
        if t == rho or rho + t == 0.0:
            return 0.0
        p = ((rho - t) / (rho + t)) ** 2      # 1 - m, accurate next to t = rho: K(m) = ellipkm1(p)
        return ref_md_traction(t, a, c, tip_radius, effective_modulus, sigma0) * t * ellipkm1(p) / (rho + t)

    breaks = sorted({x for x in (rho, a, c) if 0.0 < x < c})
    total = 0.0
    edges = [0.0, *breaks, c]
    for lo, hi in zip(edges[:-1], edges[1:]):
        if hi > lo:
            total += quad(ring, lo, hi, limit=400, epsabs=0.0, epsrel=1e-11)[0]
    return 4.0 / (math.pi * effective_modulus) * total


def ref_tick_at_load(model, x, y, z0, load, lo=-2e-9, hi=8e-9, iterations=80):
    """The tick of a fresh tip (``model.reset()`` before each try, so approaching) at (x, y) whose
    height z0 - d carries ``load`` (N), by bisection on d in [lo, hi] (m)."""
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        model.reset()
        if model.step((x, y, z0 - mid)).load < load:
            lo = mid
        else:
            hi = mid
    model.reset()
    return model.step((x, y, z0 - 0.5 * (lo + hi)))
