r"""A multi-walled carbon nanotube (MWCNT) lying on the sample, and how an AFM tip pushes it.

The tube is a rigid rod ([MWCNT], Sec. 3): the set of points within ``diameter / 2`` of an axis
segment of length ``length`` that lies horizontally on the substrate (a capsule; the caps are
hemispherical, like a closed MWCNT). Its pose is the axis centre (x, y) and the axis angle.

Pushing ([MWCNT], Eq. 9, corrected)
------------------------------------
A tip touching the tube at arc-length :math:`l` from end A (``0 <= l <= L``) and moving sideways
exerts a force :math:`F` perpendicular to the axis (the tip-tube contact is frictionless, so the
force is along the contact normal). The substrate resists with a uniform force :math:`f` per unit
length, opposite to the local velocity. The tube slides by rotating about a point S on its axis
at arc-length :math:`s`; for a push beyond the middle (:math:`l > L/2`) the segment ``[s, L]``
moves with the tip and ``[0, s]`` moves backwards, so force and moment (about S) balance read

.. math::

    F + f s = f (L - s), \qquad F (l - s) = \tfrac12 f (L - s)^2 + \tfrac12 f s^2 .

The first gives :math:`F = f (L - 2 s)`; substituting into the second,
:math:`(L - 2s)(l - s) = \tfrac12 (L - s)^2 + \tfrac12 s^2`, i.e.
:math:`s^2 - 2 l s + l L - L^2/2 = 0`, whose root with :math:`F > 0` (:math:`s < L/2`) is

.. math::

    s = l - \sqrt{l^2 - l L + L^2/2} = \frac{L (l - L/2)}{l + \sqrt{l^2 - l L + L^2/2}} .

(The printed Eq. 10 of [MWCNT] has :math:`L^2` instead of :math:`L^2/2`; it violates its own
Eq. 9 - docs/design.rst, "Known errors in the sources".) The second form avoids cancellation near the middle.
Pushing at the end, :math:`l = L`, gives :math:`s = L (1 - 1/\sqrt2)`, the classical pivot of a
rod pushed at its end. The same root minimises the force :math:`F(s) = f[(L-s)^2 + s^2] / (2(l-s))`
that the moment balance alone requires, so S is the pivot that needs the least push ("minimal
force" in [MWCNT]). The mirror case (push before the middle, :math:`l < L/2`) is
:math:`s = l + \sqrt{l^2 - l L + L^2/2}`, i.e. ``L - s(L - l)``.

At :math:`l = L/2` exactly no pivot inside the tube balances the moment (the root reaches the far
end, :math:`s \to 0` as :math:`l \to L/2^+`), and any pivot outside the tube does, since uniform
friction then has no moment about the centre: the tube translates. :func:`push` translates it for
contacts within ``middle_band * L`` of the middle (a modelling band; the default is 1 % of L).

Contact at a cap (tip beyond an end) has a normal with an axial part; the tube then rotates about
S by the perpendicular part and slides along its axis by the axial part, so that the contact
point moves along the contact normal (an extension of [MWCNT] for end-on pushes).

Scene integration: which one the live loop uses
-----------------------------------------------
The tube offers both ways of joining the scene, and they have different jobs:

* :meth:`Nanotube.tip_overlap` + :func:`push` (an object): the live loop should use this. The test
  is analytic (distance from the tip-sphere centre to the axis segment, O(1): about 1 us per
  call from Python, and a push in contact about 6 us per 1 kHz tick, bench/manipulation.py),
  the tube's edges stay sharp, and moving the tube changes only its
  pose - no refit of the B-spline surface, whose smoothing would round the tube off and whose
  local refit at the old and new positions would cost O(patch) per haptic step. The viewer draws
  the tube as its own actor and moves it with :meth:`Nanotube.transform` each frame.
* :meth:`Nanotube.height_map` / :meth:`Nanotube.add_to_heights` (part of the height map): for
  building synthetic scans with tubes, for the predicted rescan after a manipulation (optionally
  dilated by the tip sphere, as an AFM would image it), and for comparison with a real rescan.

Examples
--------
>>> tube = Nanotube(length=1e-6, diameter=20e-9, x=0.0, y=0.0, angle=0.0)
>>> round(float(rotation_centre(1e-6, 1e-6)) / 1e-6, 6)    # push at end B: s = L(1 - 1/sqrt(2))
0.292893
>>> r = push(tube, tip_center=(0.45e-6, -40e-9, tube.axis_height), tip_displacement=(0.0, 60e-9),
...          tip_radius=10e-9)
>>> r.touched, r.tube.tip_overlap((0.45e-6, 20e-9, tube.axis_height), 10e-9) <= 1e-18
(True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from arsurf import _validation
from arsurf.errors import ManipulationError
from arsurf.scan.scan import Scan
from arsurf.status import PUSH_FALLBACK, PUSH_NAMES, PUSH_OK, PUSH_SUBSTEP_CAP  # noqa: F401 (re-exported)

# ------------------------------------------------------------------------------------------------
# kernels (plain floats, no allocation, status codes)
# ------------------------------------------------------------------------------------------------

# the push's status codes: PUSH_OK, PUSH_SUBSTEP_CAP, PUSH_FALLBACK (arsurf.status)


@njit(cache=True)
def _centre(l, L):
    """Arc-length of the rotation centre for a push at arc-length l (inf at the exact middle)."""
    h = l - 0.5 * L
    root = math.sqrt(h * h + 0.25 * L * L)  # = sqrt(l^2 - l L + L^2/2)
    if h > 0.0:
        return L * h / (l + root)  # = l - root without cancellation
    if h < 0.0:
        return l + root
    return math.inf


@njit(cache=True)
def _seg_dist(px, py, ax, ay, ux, uy, L):
    """Distance from (px, py) to the segment A + t u, t in [0, L]; returns (t, qx, qy, d)."""
    t = (px - ax) * ux + (py - ay) * uy
    if t < 0.0:
        t = 0.0
    elif t > L:
        t = L
    qx = ax + t * ux
    qy = ay + t * uy
    dx = qx - px
    dy = qy - py
    return t, qx, qy, math.sqrt(dx * dx + dy * dy)


@njit(cache=True)
def _deepest(ax_, ay_, ex, ey, sx, sy, ux, uy, L):
    """Point of the tip path a + tau e (tau in [0, 1]) closest to the segment S + t u.

    In 2D the minimum distance between two segments is at an intersection or at an endpoint of one
    of them, so five candidates suffice; ties go to the smallest tau (the first occurrence).
    """
    best_tau = 0.0
    best_d = _seg_dist(ax_, ay_, sx, sy, ux, uy, L)[3]
    ee = ex * ex + ey * ey
    for k in range(4):
        if k == 0:
            tau = 1.0
        elif k == 1 or k == 2:
            if ee == 0.0:
                continue
            px = sx + (L if k == 2 else 0.0) * ux
            py = sy + (L if k == 2 else 0.0) * uy
            tau = ((px - ax_) * ex + (py - ay_) * ey) / ee
            tau = min(max(tau, 0.0), 1.0)
        else:
            den = ex * uy - ey * ux
            if den == 0.0:
                continue
            wx = sx - ax_
            wy = sy - ay_
            tau = (wx * uy - wy * ux) / den
            t = (wx * ey - wy * ex) / den
            if tau < 0.0 or tau > 1.0 or t < 0.0 or t > L:
                continue
        d = _seg_dist(ax_ + tau * ex, ay_ + tau * ey, sx, sy, ux, uy, L)[3]
        if d < best_d or (d == best_d and tau < best_tau):
            best_d = d
            best_tau = tau
    return best_tau, best_d


@njit(cache=True)
def _moved(cx, cy, th, L, l, nx, ny, lam, band):
    """Pose after the contact point at arc-length l moved by lam along the normal (nx, ny)."""
    c = math.cos(th)
    s_ = math.sin(th)
    if abs(l - 0.5 * L) <= band * L:
        return cx + lam * nx, cy + lam * ny, th
    n_perp = -s_ * nx + c * ny
    n_ax = c * nx + s_ * ny
    sc = _centre(l, L)
    phi = lam * n_perp / (l - sc)
    # pivot S = A + sc u = centre + (sc - L/2) u
    px = cx + (sc - 0.5 * L) * c
    py = cy + (sc - 0.5 * L) * s_
    rx = cx - px
    ry = cy - py
    cp = math.cos(phi)
    sp = math.sin(phi)
    ncx = px + cp * rx - sp * ry + lam * n_ax * c
    ncy = py + sp * rx + cp * ry + lam * n_ax * s_
    return ncx, ncy, th + phi


@njit(cache=True)
def _gap(cx, cy, th, L, mx, my):
    """Distance from (mx, my) to the axis segment of the pose (cx, cy, th)."""
    ux = math.cos(th)
    uy = math.sin(th)
    return _seg_dist(mx, my, cx - 0.5 * L * ux, cy - 0.5 * L * uy, ux, uy, L)[3]


@njit(cache=True)
def _resolve(cx, cy, th, L, l, nx, ny, mx, my, rho, band):
    """Smallest motion of the family (_moved) that puts (mx, my) at distance >= rho (bisection).

    Returns (cx, cy, th, ok). The upper bracket is returned, so the gap is >= rho as computed.
    """
    g0 = _gap(cx, cy, th, L, mx, my)
    if g0 >= rho:
        return cx, cy, th, True
    hi = 2.0 * (rho - g0) + 1e-6 * rho
    ok = False
    for _ in range(64):
        ax_, ay_, at = _moved(cx, cy, th, L, l, nx, ny, hi, band)
        if _gap(ax_, ay_, at, L, mx, my) >= rho:
            ok = True
            break
        hi *= 2.0
        if hi > 4.0 * L + 4.0 * rho:
            break
    if not ok:
        return cx, cy, th, False
    lo = 0.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        ax_, ay_, at = _moved(cx, cy, th, L, l, nx, ny, mid, band)
        if _gap(ax_, ay_, at, L, mx, my) >= rho:
            hi = mid
        else:
            lo = mid
    ax_, ay_, at = _moved(cx, cy, th, L, l, nx, ny, hi, band)
    return ax_, ay_, at, True


@njit(cache=True)
def _translate_clear(cx, cy, th, L, mx, my, rho, nx, ny):
    """Fallback: translate along (nx, ny) until (mx, my) is at distance >= rho (always possible)."""
    g0 = _gap(cx, cy, th, L, mx, my)
    if g0 >= rho:
        return cx, cy
    hi = 2.0 * rho + 1e-6 * rho
    while _gap(cx + hi * nx, cy + hi * ny, th, L, mx, my) < rho:
        hi *= 2.0
    lo = 0.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if _gap(cx + mid * nx, cy + mid * ny, th, L, mx, my) >= rho:
            hi = mid
        else:
            lo = mid
    return cx + hi * nx, cy + hi * ny


@njit(cache=True)
def _rho_max(za, zb, zaxis, reach):
    """Largest in-plane contact radius sqrt(reach^2 - dz^2) over tip heights between za and zb."""
    lo = min(za, zb)
    hi = max(za, zb)
    if lo <= zaxis <= hi:
        dz = 0.0
    else:
        dz = min(abs(za - zaxis), abs(zb - zaxis))
    q = reach * reach - dz * dz
    return math.sqrt(q) if q > 0.0 else 0.0


@njit(cache=True)
def push_kernel(cx, cy, th, L, radius, zaxis, px, py, pz, ex, ey, ez, tip_radius, max_substep, band,
                max_substeps):
    """Move the tube pose (cx, cy, th) for a tip sphere moving from p by e (all SI, plain floats).

    Returns ``(cx, cy, th, status, contacts, last_l, last_s, substeps)``; ``last_l``/``last_s``
    are NaN when the tip never touched the tube. See :func:`push` for the model.
    """
    reach = tip_radius + radius
    elen = math.sqrt(ex * ex + ey * ey + ez * ez)
    # sub-steps no longer than max_substep nor half the in-plane contact radius (so the tip cannot
    # cross the axis within one sub-step); h_floor bounds their number when the tip grazes the top
    h_floor = 0.01 * reach if reach > 0.0 else max_substep
    status = PUSH_OK
    contacts = 0
    last_l = math.nan
    last_s = math.nan
    n = 0
    f1 = 0.0
    while f1 < 1.0:
        f0 = f1
        if elen == 0.0 or n >= max_substeps - 1:
            if elen > 0.0:
                status = PUSH_SUBSTEP_CAP
            f1 = 1.0
        else:
            h = max_substep
            f1 = min(1.0, f0 + h / elen)
            r0 = _rho_max(pz + f0 * ez, pz + f0 * ez, zaxis, reach)
            r1 = _rho_max(pz + f1 * ez, pz + f1 * ez, zaxis, reach)
            rmax = _rho_max(pz + f0 * ez, pz + f1 * ez, zaxis, reach)
            if rmax > 0.0:
                h = min(h, max(0.5 * min(r0, r1), h_floor))
                f1 = min(1.0, f0 + h / elen)
        n += 1
        ax_ = px + f0 * ex
        ay_ = py + f0 * ey
        bx = px + f1 * ex
        by = py + f1 * ey
        rho = _rho_max(pz + f0 * ez, pz + f1 * ez, zaxis, reach)
        if rho <= 0.0:
            continue
        for _ in range(16):
            dx = bx - ax_
            dy = by - ay_
            ux = math.cos(th)
            uy = math.sin(th)
            sx = cx - 0.5 * L * ux
            sy = cy - 0.5 * L * uy
            tau_m, d_m = _deepest(ax_, ay_, dx, dy, sx, sy, ux, uy, L)
            if d_m >= rho:
                break
            mx = ax_ + tau_m * dx
            my = ay_ + tau_m * dy
            # first touch on [a, m]: the distance along a straight path is convex, one crossing
            if _seg_dist(ax_, ay_, sx, sy, ux, uy, L)[3] <= rho:
                tau_c = 0.0
            else:
                lo = 0.0
                hi = tau_m
                for _ in range(100):
                    mid = 0.5 * (lo + hi)
                    if mid <= lo or mid >= hi:
                        break
                    if _seg_dist(ax_ + mid * dx, ay_ + mid * dy, sx, sy, ux, uy, L)[3] <= rho:
                        hi = mid
                    else:
                        lo = mid
                tau_c = hi
            tcx = ax_ + tau_c * dx
            tcy = ay_ + tau_c * dy
            l, qx, qy, dq = _seg_dist(tcx, tcy, sx, sy, ux, uy, L)
            if dq > 0.0:
                nx = (qx - tcx) / dq
                ny = (qy - tcy) / dq
            else:  # tip centre on the axis (it started inside): push along the motion side
                side = -uy * dx + ux * dy
                sgn = 1.0 if side >= 0.0 else -1.0
                nx = -uy * sgn
                ny = ux * sgn
            contacts += 1
            last_l = l
            last_s = _centre(l, L) if abs(l - 0.5 * L) > band * L else math.inf
            ncx, ncy, nth, ok = _resolve(cx, cy, th, L, l, nx, ny, mx, my, rho, band)
            if not ok:
                status = PUSH_FALLBACK
                ncx, ncy = _translate_clear(cx, cy, th, L, mx, my, rho, nx, ny)
                nth = th
            cx = ncx
            cy = ncy
            th = nth
            ax_ = mx
            ay_ = my
        # guarantee: the tip at the end of the sub-step is clear of the tube
        ux = math.cos(th)
        uy = math.sin(th)
        rho_b = _rho_max(pz + f1 * ez, pz + f1 * ez, zaxis, reach)
        l, qx, qy, dq = _seg_dist(bx, by, cx - 0.5 * L * ux, cy - 0.5 * L * uy, ux, uy, L)
        if dq < rho_b:
            status = PUSH_FALLBACK
            if dq > 0.0:
                nx = (qx - bx) / dq
                ny = (qy - by) / dq
            else:
                nx = -uy
                ny = ux
            cx, cy = _translate_clear(cx, cy, th, L, bx, by, rho_b, nx, ny)
    th = math.atan2(math.sin(th), math.cos(th))
    return cx, cy, th, status, contacts, last_l, last_s, n


@njit(cache=True)
def overlap_kernel(cx, cy, th, L, radius, zaxis, qx, qy, qz, tip_radius):
    """(tip_radius + radius) - distance from (qx, qy, qz) to the axis segment (> 0: overlap)."""
    ux = math.cos(th)
    uy = math.sin(th)
    d2 = _seg_dist(qx, qy, cx - 0.5 * L * ux, cy - 0.5 * L * uy, ux, uy, L)[3]
    dz = qz - zaxis
    return tip_radius + radius - math.sqrt(d2 * d2 + dz * dz)


# ------------------------------------------------------------------------------------------------
# Python API
# ------------------------------------------------------------------------------------------------


def _finite(name: str, value, what: str) -> float:
    return _validation.finite(value, name, ManipulationError, hint=f"it is {what}")


def _positive(name: str, value, what: str) -> float:
    return _validation.positive(value, name, ManipulationError, hint=f"it is {what}")


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


def rotation_centre(contact, length):
    r"""Arc-length ``s`` (from end A) of the pivot of a tube pushed at arc-length ``contact``.

    .. math::

        s = l - \sqrt{l^2 - l L + L^2/2}\ \ (l > L/2), \qquad
        s = l + \sqrt{l^2 - l L + L^2/2}\ \ (l < L/2)

    the solution of [MWCNT]'s Eq. 9 (force and moment balance with uniform resistance), not its
    printed Eq. 10 (see the module docstring for the derivation). At the exact middle the tube
    translates: the pivot is at infinity and ``inf`` is returned.

    Parameters
    ----------
    contact : float or array, metres
        Arc-length ``l`` of the contact point from end A, ``0 <= l <= L``.
    length : float, metres
        Tube (axis) length ``L``.

    Returns
    -------
    float or ndarray, metres : the pivot's arc-length from end A, in ``[0, L(1-1/sqrt 2)]`` for
    ``l > L/2`` and in ``[L/sqrt 2, L]`` for ``l < L/2``; ``inf`` at ``l = L/2``.

    Examples
    --------
    >>> round(float(rotation_centre(2.0, 2.0)), 12), round(float(rotation_centre(0.0, 2.0)), 12)
    (0.585786437627, 1.414213562373)
    """
    L = _positive("length", length, "the tube length in metres")
    l = np.asarray(contact, dtype=np.float64)
    if not np.isfinite(l).all() or (l < 0.0).any() or (l > L).any():
        bad = l[~(np.isfinite(l) & (l >= 0.0) & (l <= L))].ravel()[0]
        raise ManipulationError(
            f"contact arc-length must lie on the tube, 0 <= l <= L = {L!r} m (got {float(bad)!r}); "
            "measure it from end A along the axis"
        )
    h = l - 0.5 * L
    root = np.sqrt(h * h + 0.25 * L * L)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(h > 0.0, L * h / (l + root), np.where(h < 0.0, l + root, np.inf))
    return s[()] if s.ndim == 0 else s


@dataclass(frozen=True)
class Nanotube:
    """A rigid nanotube (capsule) lying on the substrate.

    Parameters
    ----------
    length : float, metres
        Length ``L`` of the axis segment (end A to end B; the caps add ``diameter/2`` at each end).
    diameter : float, metres
        Outer diameter; the axis lies ``diameter/2`` above ``base``.
    x, y : float, metres
        Centre of the axis.
    angle : float, radians
        Direction of the axis (from end A to end B), counter-clockwise from +x; wrapped to (-pi, pi].
    base : float, metres
        Height of the substrate the tube rests on (see :meth:`resting_on`).

    Examples
    --------
    >>> t = Nanotube(1e-6, 20e-9, x=2e-6, y=1e-6, angle=0.5)
    >>> t.axis_height, t.pose
    (1e-08, (2e-06, 1e-06, 0.5))
    """

    length: float
    diameter: float
    x: float = 0.0
    y: float = 0.0
    angle: float = 0.0
    base: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "length", _positive("length", self.length, "the tube axis length in metres"))
        object.__setattr__(self, "diameter", _positive("diameter", self.diameter, "the tube diameter in metres"))
        object.__setattr__(self, "x", _finite("x", self.x, "the tube centre in metres"))
        object.__setattr__(self, "y", _finite("y", self.y, "the tube centre in metres"))
        object.__setattr__(self, "angle", _wrap(_finite("angle", self.angle, "the axis angle in radians")))
        object.__setattr__(self, "base", _finite("base", self.base, "the substrate height in metres"))

    # -- geometry ---------------------------------------------------------------------------------
    @property
    def radius(self) -> float:
        """Outer radius, metres."""
        return 0.5 * self.diameter

    @property
    def axis_height(self) -> float:
        """Height of the axis, ``base + diameter/2`` (metres)."""
        return self.base + 0.5 * self.diameter

    @property
    def pose(self) -> tuple[float, float, float]:
        """(x, y, angle): centre in metres, axis angle in radians."""
        return (self.x, self.y, self.angle)

    @property
    def direction(self) -> np.ndarray:
        """(2,) unit vector from end A to end B."""
        return np.array([math.cos(self.angle), math.sin(self.angle)])

    @property
    def endpoints(self) -> np.ndarray:
        """(2, 3) centres of the caps: row 0 is end A, row 1 end B, at the axis height (metres)."""
        u = self.direction * 0.5 * self.length
        z = self.axis_height
        return np.array([[self.x - u[0], self.y - u[1], z], [self.x + u[0], self.y + u[1], z]])

    def point_at(self, arc_length: float) -> np.ndarray:
        """(3,) point on the axis at ``arc_length`` from end A (metres)."""
        l = _finite("arc_length", arc_length, "metres from end A")
        a = self.endpoints[0]
        u = self.direction
        return np.array([a[0] + l * u[0], a[1] + l * u[1], a[2]])

    def with_pose(self, x: float, y: float, angle: float) -> "Nanotube":
        """The same tube at another pose."""
        return replace(self, x=x, y=y, angle=angle)

    def transform(self) -> np.ndarray:
        """(4, 4) homogeneous matrix placing a canonical tube (axis along +x, centred at the
        origin, axis at z = 0) at this pose; for a viewer actor's ``user_matrix``."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        m = np.eye(4)
        m[:2, :2] = [[c, -s], [s, c]]
        m[:3, 3] = [self.x, self.y, self.axis_height]
        return m

    def resting_on(self, scan: Scan) -> "Nanotube":
        """The tube with ``base`` set to the highest scan point under its axis (a rigid rod rests
        on the tallest asperities), sampled bilinearly every half pixel along the axis."""
        if not isinstance(scan, Scan):
            raise ManipulationError(f"resting_on needs an arsurf Scan (got {type(scan).__name__})")
        step = 0.5 * min(scan.dx, scan.dy)
        n = max(2, int(math.ceil(self.length / step)) + 1)
        a, b = self.endpoints
        t = np.linspace(0.0, 1.0, n)
        z = _bilinear(scan, a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
        if not np.isfinite(z).any():
            raise ManipulationError(
                f"the tube axis from ({a[0]:.4g}, {a[1]:.4g}) to ({b[0]:.4g}, {b[1]:.4g}) m lies outside "
                f"the scan or over NaN pixels only; place it inside the scanned area"
            )
        return replace(self, base=float(np.nanmax(z)))

    # -- height map -------------------------------------------------------------------------------
    def height_map(self, x, y, tip_radius: float = 0.0) -> np.ndarray:
        r"""Height of the tube's top surface at (x, y), NaN where the tube is not.

        .. math::

            z(d) = z_{axis} + \sqrt{(r + R)^2 - d^2} - R, \qquad d < r + R

        with ``d`` the horizontal distance to the axis segment, ``r`` the tube radius and ``R`` the
        tip radius: ``R = 0`` is the true shape; ``R > 0`` is the image a spherical tip records
        (the tube dilated by the tip).

        Parameters
        ----------
        x, y : array_like, metres (broadcast together)
        tip_radius : float, metres, >= 0

        Returns
        -------
        ndarray of the broadcast shape, metres; NaN outside the footprint.
        """
        R = _finite("tip_radius", tip_radius, "metres")
        if R < 0.0:
            raise ManipulationError(f"tip_radius must be >= 0 m (got {R!r}); use 0 for the true shape")
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        a = self.endpoints[0]
        u = self.direction
        t = np.clip((x - a[0]) * u[0] + (y - a[1]) * u[1], 0.0, self.length)
        d2 = (x - a[0] - t * u[0]) ** 2 + (y - a[1] - t * u[1]) ** 2
        reach2 = (self.radius + R) ** 2
        with np.errstate(invalid="ignore"):
            z = np.where(d2 < reach2, self.axis_height + np.sqrt(reach2 - d2) - R, np.nan)
        return z

    def add_to_heights(self, scan, tip_radius: float = 0.0, dx: float | None = None, dy: float | None = None):
        """The scan with the tube on it: ``fmax(surface, tube top)`` pixel by pixel.

        Parameters
        ----------
        scan : Scan, or (ny, nx) float array of heights in metres (then give ``dx`` and ``dy``)
            Pixel (ix, iy) sits at x = ix*dx, y = iy*dy (the Scan convention).
        tip_radius : float, metres
            0 for the true shape, the tip radius for the image the AFM would record.

        Returns
        -------
        Scan (with a history step) or ndarray, like the input.

        Examples
        --------
        >>> s = Scan(np.zeros((8, 8)), dx=10e-9, dy=10e-9)
        >>> out = Nanotube(40e-9, 20e-9, x=30e-9, y=30e-9).add_to_heights(s)
        >>> round(float(out.heights[3, 3]) * 1e9, 6), float(out.heights[0, 0])   # on the axis; far
        (20.0, 0.0)
        """
        if isinstance(scan, Scan):
            h, sdx, sdy = scan.heights, scan.dx, scan.dy
        else:
            h = np.asarray(scan, dtype=np.float64)
            if h.ndim != 2:
                raise ManipulationError(f"heights must be a 2-D (ny, nx) array (got shape {h.shape})")
            if dx is None or dy is None:
                raise ManipulationError("give dx and dy (pixel spacing in metres) with a bare height array")
            sdx = _positive("dx", dx, "pixel spacing in metres")
            sdy = _positive("dy", dy, "pixel spacing in metres")
        ny, nx = h.shape
        xx, yy = np.meshgrid(np.arange(nx) * sdx, np.arange(ny) * sdy)
        out = np.fmax(h, self.height_map(xx, yy, tip_radius))
        if isinstance(scan, Scan):
            step = {"step": "add_nanotube", "length": self.length, "diameter": self.diameter,
                    "pose": list(self.pose), "base": self.base, "tip_radius": float(tip_radius)}
            return scan.with_heights(out, step=step)
        return out

    # -- collision --------------------------------------------------------------------------------
    def tip_overlap(self, center, radius: float):
        """Penetration depth of a tip sphere into the tube: ``R + r - dist(C, axis segment)``.

        Positive means overlap, zero touching, negative is the gap (metres). ``center`` may be
        (3,) or (n, 3); the result is a float or an (n,) array.
        """
        R = _finite("radius", radius, "the tip radius in metres")
        if R < 0.0:
            raise ManipulationError(f"radius must be >= 0 m (got {R!r}); it is the tip-sphere radius")
        c = np.asarray(center, dtype=np.float64)
        if c.shape[-1:] != (3,) or c.ndim > 2:
            raise ManipulationError(f"center must have shape (3,) or (n, 3) in metres (got {c.shape})")
        a = self.endpoints[0]
        u = self.direction
        t = np.clip((c[..., 0] - a[0]) * u[0] + (c[..., 1] - a[1]) * u[1], 0.0, self.length)
        d = np.sqrt((c[..., 0] - a[0] - t * u[0]) ** 2 + (c[..., 1] - a[1] - t * u[1]) ** 2
                    + (c[..., 2] - a[2]) ** 2)
        out = R + self.radius - d
        return float(out) if out.ndim == 0 else out


def _bilinear(scan: Scan, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear height of ``scan`` at (x, y); NaN outside the scan."""
    ny, nx = scan.shape
    fx = x / scan.dx
    fy = y / scan.dy
    inside = (fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1)
    ix = np.clip(np.floor(fx).astype(np.int64), 0, max(nx - 2, 0))
    iy = np.clip(np.floor(fy).astype(np.int64), 0, max(ny - 2, 0))
    tx = fx - ix
    ty = fy - iy
    h = scan.heights
    ix1 = np.minimum(ix + 1, nx - 1)
    iy1 = np.minimum(iy + 1, ny - 1)
    z = ((1 - tx) * (1 - ty) * h[iy, ix] + tx * (1 - ty) * h[iy, ix1]
         + (1 - tx) * ty * h[iy1, ix] + tx * ty * h[iy1, ix1])
    return np.where(inside, z, np.nan)


@dataclass(frozen=True)
class PushResult:
    """What :func:`push` did.

    Attributes
    ----------
    tube : Nanotube
        The tube after the push (the input tube if the tip never touched it).
    touched : bool
        Whether the tip touched the tube during the move.
    contacts : int
        Number of contact resolutions (one per sub-step in which the tip pressed on the tube).
    contact : float, metres
        Arc-length (from end A) of the last contact; NaN if never touched.
    pivot : float, metres
        Arc-length of the last rotation centre; ``inf`` for a translation, NaN if never touched.
    substeps : int
        Sub-steps the displacement was split into.
    status : str
        ``"ok"``; ``"substep_cap"`` (the move was longer than ``max_substeps * max_substep``: it
        was split more coarsely, still without overlap); ``"fallback"`` (the model's motion could
        not clear the tip and the tube was translated along the contact normal instead).
    """

    tube: Nanotube
    touched: bool
    contacts: int
    contact: float
    pivot: float
    substeps: int
    status: str

    @property
    def pose(self) -> tuple[float, float, float]:
        """The new pose (x, y, angle)."""
        return self.tube.pose




def _vec3(name: str, value, pad_z: float | None) -> tuple[float, float, float]:
    v = np.asarray(value, dtype=np.float64).ravel()
    if v.size == 2 and pad_z is not None:
        v = np.array([v[0], v[1], pad_z])
    if v.size != 3 or not np.isfinite(v).all():
        raise ManipulationError(
            f"{name} must be 3 finite coordinates in metres{' (or 2 for a sideways move)' if pad_z is not None else ''} "
            f"(got {np.asarray(value).tolist()!r})"
        )
    return float(v[0]), float(v[1]), float(v[2])


def push(tube: Nanotube, tip_center, tip_displacement, tip_radius: float = 0.0, *,
         max_substep: float | None = None, middle_band: float = 0.01,
         max_substeps: int = 100_000) -> PushResult:
    """Move a tip sphere by ``tip_displacement`` from ``tip_center`` and push the tube out of its way.

    The tip path is split into sub-steps, at most ``max_substep`` long (default L/50: the pivot
    follows the contact as it slides) and at most half the in-plane contact radius (so that the
    tip cannot cross the axis within one sub-step; a floor of 1 % of ``R + r`` bounds their number
    when the tip grazes the very top of the tube). In each, the
    deepest point of the tip path into the tube (the point closest to the axis) is found; if the
    tip sphere would overlap the tube there, the contact point and normal are taken where the tip
    first touches, and the tube moves by the Eq. 9 motion (rotation about
    :func:`rotation_centre`, translation within ``middle_band`` of the middle, axial slide for cap
    contacts) just far enough that the tip is clear. The tube therefore never passes through the
    tip: it always stays on the side the tip approached from, and after the push the tip sphere
    does not overlap it (``tube.tip_overlap(end, R) <= 0`` up to rounding).

    The vertical geometry is exact: a tip whose centre is ``dz`` above or below the axis reaches
    the axis segment within ``sqrt((R + r)^2 - dz^2)`` horizontally; a tip higher than
    ``R + r`` above the axis passes over the tube.

    Parameters
    ----------
    tube : Nanotube
    tip_center : (3,) float, metres
        Tip-sphere centre at the start of the move (x, y, z).
    tip_displacement : (3,) or (2,) float, metres
        Move of the tip centre; a 2-vector is a sideways move at constant height.
    tip_radius : float, metres, >= 0
    max_substep : float, metres, optional
        Longest sub-step (accuracy of the pivot, which follows the sliding contact); default L/50.
    middle_band : float, >= 0
        Contacts within ``middle_band * L`` of the middle translate the tube.
    max_substeps : int
        Cap on the number of sub-steps (status ``"substep_cap"`` when reached).

    Returns
    -------
    PushResult

    Examples
    --------
    >>> t = Nanotube(1e-6, 10e-9)
    >>> r = push(t, (0.5e-6, -20e-9, t.axis_height), (0.0, 50e-9), tip_radius=5e-9)
    >>> r.touched, r.status, round(r.pivot / 1e-6, 4)   # pushed at end B: turns about s = 0.29 L
    (True, 'ok', 0.2929)
    >>> round(r.tube.angle, 3)    # the contact moved 40 nm at a lever of L/sqrt(2)
    0.056
    """
    if not isinstance(tube, Nanotube):
        raise ManipulationError(f"tube must be a Nanotube (got {type(tube).__name__})")
    px, py, pz = _vec3("tip_center", tip_center, None)
    ex, ey, ez = _vec3("tip_displacement", tip_displacement, 0.0)
    R = _finite("tip_radius", tip_radius, "the tip-sphere radius in metres")
    if R < 0.0:
        raise ManipulationError(f"tip_radius must be >= 0 m (got {R!r}); 0 is a point tip")
    step = tube.length / 50.0 if max_substep is None else _positive("max_substep", max_substep, "metres")
    band = _finite("middle_band", middle_band, "a fraction of the tube length")
    if not 0.0 <= band < 0.5:
        raise ManipulationError(f"middle_band must be in [0, 0.5) (got {band!r}); it is a fraction of L")
    if int(max_substeps) < 1:
        raise ManipulationError(f"max_substeps must be >= 1 (got {max_substeps!r})")
    cx, cy, th, status, contacts, last_l, last_s, n = push_kernel(
        tube.x, tube.y, tube.angle, tube.length, tube.radius, tube.axis_height,
        px, py, pz, ex, ey, ez, R, step, band, int(max_substeps))
    new = tube.with_pose(cx, cy, th) if contacts else tube
    return PushResult(new, bool(contacts), int(contacts), float(last_l), float(last_s), int(n), PUSH_NAMES[int(status)])


#: Alias of :func:`push` for the top-level API, where a bare ``push`` would be ambiguous.
push_tube = push
