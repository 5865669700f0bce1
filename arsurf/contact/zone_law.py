r"""The zone law: the energy per unit area between the tip and a surface element at gap g, and the tip's profile.

The energy of the whole tip (:mod:`arsurf.contact.zone_energy`, over a lattice of the surface) and
its closed form over a smooth contact (:mod:`arsurf.contact.zone_quadric`) sum this law; the tip
rises :math:`s(r) = R - \sqrt{R^2 - r^2}` above its apex at a distance r across on its sphere
(:math:`r < r_0 = R\cos\alpha`) and continues into the cone of half-angle
:data:`CONE_HALF_ANGLE` a silicon tip's sphere sits on (:func:`_rise`).

**The law.** On a flat pressed :math:`\delta` deep the rings at r have the gap
:math:`-\delta + s(r)`, push straight up (their lateral pushes cancel), and the tip feels
:math:`P(\delta) = 2\pi \int_0^\infty r\,p(-\delta + s(r))\,dr` (:meth:`ZoneLaw.flat_load`);
under the sphere :math:`r\,dr = (R - \delta - g)\,dg`, so to order :math:`\delta/R` it is
:math:`2\pi R\,\varphi(-\delta)`. The repulsion :math:`p_r(g) = E^*\sqrt{-g}/(\pi\sqrt R)` for
g < 0 gives Hertz, :math:`\tfrac43 E^* \sqrt R\,\delta^{3/2}`; the adhesion is a Dugdale stress
spread over the interaction range :math:`h_0 = w/\sigma_0` as a smooth bump, :math:`p_a(g) =
-2\sigma_0 \sin^2(\pi g/h_0)` for 0 < g < :math:`h_0` (the box of Maugis 1992 with continuous
edges, the same work w), which adds :math:`-2\pi R w` once the gap closes. So on a flat the load
is, to order :math:`\delta/R`, the Derjaguin-Muller-Toporov limit of Maugis-Dugdale with the
law's own E*, w and :math:`\sigma_0`: :math:`P(\delta) = \tfrac43 E^*\sqrt R\,\delta^{3/2} -
2\pi R w` for :math:`\delta \ge 0`. A Johnson-Kendall-Roberts-like law (large Maugis parameter)
has a hysteresis loop, which no energy has; this law is its conservative limit with the same
constants, and its pull-off is :math:`2\pi R w` (JKR: :math:`1.5\pi R w`).

The energy per area is :math:`\varphi = \varphi_r + \varphi_a`, :math:`\varphi_r =
2E^*(-g)^{3/2}/(3\pi\sqrt R)` for g < 0, :math:`\varphi_a = -w` for g <= 0,
:math:`-\sigma_0 (h_0 - g) - \sigma_0 h_0 \sin(2\pi g/h_0)/(2\pi)` on (0, :math:`h_0`) and 0
beyond: continuous with its derivative, so the force is continuous in T.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf._layout import Layout
from arsurf.errors import ContactError

__all__ = ["CONE_HALF_ANGLE", "ZONE_OUT", "ZoneLaw", "zone_law_kernel"]

#: what the zone energy's kernels write (:mod:`arsurf.contact.zone_energy`, :mod:`arsurf.contact.zone_quadric`): the
#: energy E (J) and the force F on the tip (N)
ZONE_OUT = Layout("zone energy output", [("energy", 1), ("force", 3)])
Z_ENERGY, Z_FORCE, Z_SIZE = ZONE_OUT.offset("energy"), ZONE_OUT.offset("force"), ZONE_OUT.size

#: the half-angle (rad) of the cone the tip's sphere continues into (module docstring): 15 degrees
CONE_HALF_ANGLE = math.radians(15.0)
_COS_CONE, _SIN_CONE = math.cos(CONE_HALF_ANGLE), math.sin(CONE_HALF_ANGLE)

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
        r"""The load (N, > 0 compressive) the law gives the tip pressed ``depth`` (m; < 0: a gap)
        into a flat: :math:`2\pi \int_0^\infty r\,p(-\delta + s(r))\,dr` (module docstring), by
        quadrature to 1e-10."""
        from scipy.integrate import quad

        rho0, cap, slope = _cone(self.tip_radius)
        depth, h0 = float(depth), self.interaction_range
        if depth + h0 <= 0.0:
            return 0.0

        def ring(r):
            rise = _rise(r * r, self.tip_radius, rho0, cap, slope)[0]
            return 2.0 * math.pi * r * zone_law_kernel(rise - depth, *self.args)[1]

        reach = _across(depth + h0, self.tip_radius, rho0, cap, slope)
        kinks = [r for r in (_across(depth, self.tip_radius, rho0, cap, slope) if depth > 0 else 0.0, rho0)
                 if 0.0 < r < reach]
        return quad(ring, 0.0, reach, points=kinks or None, limit=400, epsabs=0.0, epsrel=1e-10)[0]

    def flat_depth(self, load: float) -> float:
        r"""The depth (m, >= 0) at which the tip pressed into a flat feels ``load`` (N; from the
        load at depth 0, about :math:`-2\pi R w`, up): :meth:`flat_load` inverted (Brent's method,
        to 1e-12 of the depth)."""
        from scipy.optimize import brentq

        if not (isinstance(load, (int, float, np.integer, np.floating)) and not isinstance(load, bool)
                and math.isfinite(load) and load >= self.flat_load(0.0)):
            raise ContactError(f"`load` must be a finite load >= {self.flat_load(0.0)!r} N, the law's at depth 0 "
                               f"(got {load!r})")
        hi = max(self.zero_load_depth(), 1e-3 * self.tip_radius)
        while self.flat_load(hi) < load:
            hi *= 2.0
        return brentq(lambda d: self.flat_load(d) - float(load), 0.0, hi, xtol=1e-12 * hi, rtol=1e-12)

    def pull_off_force(self) -> float:
        r"""The largest pull of the law on a flat (N, > 0): :math:`2\pi R w` (module docstring)."""
        return 2.0 * math.pi * self.tip_radius * self.work_of_adhesion

    def zero_load_depth(self) -> float:
        r"""The depth (m) at which the law's load on a flat is 0, where Hertz's repulsion balances
        :math:`2\pi R w`: :math:`(3\pi w \sqrt R / 2E^*)^{2/3}`."""
        return (1.5 * math.pi * self.work_of_adhesion * math.sqrt(self.tip_radius) / self.effective_modulus) ** (2 / 3)

    @property
    def args(self) -> tuple[float, float, float, float]:
        """``(R, E*, sigma0, h0)`` for :func:`zone_energy_kernel`."""
        return (self.tip_radius, self.effective_modulus, self.dugdale_stress, self.interaction_range)


@njit(cache=True)
def zone_law_kernel(g, radius, e_star, sigma0, h0):
    r"""``(phi, p)``: the energy per area (J/m^2) and the pressure (Pa, > 0 repulsive) at gap ``g``
    (m) of the module docstring's law."""
    rep, adh, p, _ = _law(g, e_star / (math.pi * math.sqrt(radius)), sigma0, h0, 0.0)
    return rep + adh, p


@njit(cache=True, inline="always")
def _law(g, stiff, sigma0, h0, floor):
    r"""``(phi_r, phi_a, p, dp/dg)`` of the law at gap ``g`` (m): the repulsion's and the adhesion's
    energy per area (J/m^2), the pressure (Pa) and its slope (Pa/m), which are the repulsion's for
    g < 0 and the adhesion's beyond (a material map scales them apart); ``stiff`` is
    :math:`E^*/\pi\sqrt R` (the repulsion :math:`p_r = \mathrm{stiff}\,\sqrt{-g}`), and the
    repulsion's slope :math:`\propto 1/\sqrt{-g}` is held finite with :math:`\sqrt{-g}` at least
    ``floor`` (m^1/2; :func:`zone_energy_kernel`). One square root or one sine and cosine a call
    (:math:`\sin 2x = 2\sin x\cos x`)."""
    if g < 0.0:
        s = math.sqrt(-g)
        return 2.0 / 3.0 * stiff * s * s * s, -sigma0 * h0, stiff * s, -0.5 * stiff / max(s, floor)
    if g < h0:
        x = math.pi * g / h0
        sn, cs = math.sin(x), math.cos(x)
        return (0.0, -sigma0 * (h0 - g) - sigma0 * h0 * sn * cs / math.pi, -2.0 * sigma0 * sn * sn,
                -4.0 * sigma0 * math.pi / h0 * sn * cs)
    return 0.0, 0.0, 0.0, 0.0


@njit(cache=True, inline="always")
def _cone(radius):
    """``(rho0, cap, slope)``: where the tip's sphere meets its cone (m across), the sphere's rise
    there (m) and the cone's slope (:data:`CONE_HALF_ANGLE`; module docstring)."""
    return radius * _COS_CONE, radius * (1.0 - _SIN_CONE), _COS_CONE / _SIN_CONE


@njit(cache=True, inline="always")
def _rise(r2, radius, rho0, cap, slope):
    """``(s, s'/r, (s'/r)'/r)``: how far the tip's surface rises above its apex (m) at ``r2`` (m^2)
    across, under its sphere :math:`R - \\sqrt{R^2 - r^2}` or its cone (module docstring), and
    what the gap's gradient and Hessian across need of it."""
    if r2 < rho0 * rho0:
        root = math.sqrt(radius * radius - r2)
        return radius - root, 1.0 / root, 1.0 / (root * root * root)
    rho = math.sqrt(r2)
    q = slope / rho
    return cap + (rho - rho0) * slope, q, -q / r2


@njit(cache=True, inline="always")
def _across(rise, radius, rho0, cap, slope):
    """How far across (m) the tip's surface rises ``rise`` (m, > 0) above its apex."""
    if rise <= cap:
        return math.sqrt(rise * (2.0 * radius - rise))
    return rho0 + (rise - cap) / slope
