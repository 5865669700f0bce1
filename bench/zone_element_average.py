"""Benchmark (diagnostic): could the zone energy's lattice be coarser if each sample stood for its
element's average of the law?

:mod:`arsurf.contact.zone_energy` sums the law at one point per lattice sample, and needs samples
an eighth of the interaction zone :math:`\\sqrt{2Rh_0}` apart to sum it within ~1 % on a flat
(``bench/zone_quadrature.py``): the adhesive ring is :math:`h_0` over the tip's slope wide. Here,
on a flat and outside the engine, each sample's value is replaced by the law's mean over its
element with the gap taken linear across it (slope G, spacing h), three ways:

- ``point``: the law at the sample (what the engine does);
- ``box``: the mean over a gap range of width :math:`h\\lVert G\\rVert` (the element's variance),
  :math:`(\\Phi(g + \\Delta/2) - \\Phi(g - \\Delta/2))/\\Delta`, :math:`\\Phi' = \\varphi`;
- ``trapezoid``: the exact mean over the square, whose gap is the sum of two uniform ranges,
  :math:`\\sum \\pm \\Phi_2(g \\pm a \\pm b)/4ab`, :math:`\\Phi_2'' = \\varphi`;

each with the midpoint rule's second-order term, the element's mean gap
:math:`g + h^2 \\nabla^2 g / 24` (``curvature``). The load is the energy's difference across
1e-3 h0 of height. Printed per tip radius and spacing (an eighth, a quarter and half the zone,
and R/8): the worst error over the load, or over the pull-off where the load is smaller, from the
law's tail to the small-contact limit at 4 positions of the axis in a cell, as
``bench/zone_quadrature.py``.

Run: .venv/bin/python bench/zone_element_average.py [--radii-nm 5 20 50] (prints JSON lines)
"""
from __future__ import annotations

import argparse
import json
import math

import numpy as np
from numba import njit

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import ZoneLaw, _cone, _law, _rise

OFFSETS = ((0.0, 0.0), (0.5, 0.5), (0.3, 0.17), (0.77, 0.21))
POINT, BOX, TRAPEZOID = 0, 1, 2


@njit
def _phi(g, stiff, sig, h0):
    """The zone law's energy per area at gap g: the engine's own (:func:`~arsurf.contact.zone_energy._law`)."""
    rep, adh, _, _ = _law(g, stiff, sig, h0, 0.0)
    return rep + adh


@njit
def _antiderivatives(g, stiff, sig, h0):
    """(Phi2, Phi): the zone law's second and first antiderivative in g, both 0 beyond h0."""
    pi = math.pi
    if g < 0.0:
        s = math.sqrt(-g)
        s5 = s * s * s * s * s
        p2 = 8.0 / 105.0 * stiff * s5 * s * s - sig * h0 ** 3 * (1.0 / 6.0 - 1.0 / (4 * pi * pi)) \
            + sig * h0 * h0 * g / 2 - sig * h0 * g * g / 2
        return p2, -4.0 / 15.0 * stiff * s5 + sig * h0 * h0 / 2 - sig * h0 * g
    if g < h0:
        x = pi * g / h0
        sn, cs = math.sin(x), math.cos(x)
        p2 = -(sig * (h0 - g) ** 3 / 6 - sig * h0 * h0 * (h0 - g) / (4 * pi * pi) - sig * h0 ** 3 * 2 * sn * cs / (8 * pi ** 3))
        return p2, sig * (h0 - g) ** 2 / 2 - sig * h0 * h0 * 2 * sn * sn / (4 * pi * pi)
    return 0.0, 0.0


@njit
def _mean(g, a, b, stiff, sig, h0):
    """Mean of phi(g + s + t), |s| <= a, |t| <= b."""
    if a < b:
        a, b = b, a
    if a < 1e-3 * h0:
        return _phi(g, stiff, sig, h0)
    if b < 1e-3 * h0:
        return (_antiderivatives(g + a, stiff, sig, h0)[1] - _antiderivatives(g - a, stiff, sig, h0)[1]) / (2 * a)
    p2 = _antiderivatives
    return (p2(g + a + b, stiff, sig, h0)[0] - p2(g + a - b, stiff, sig, h0)[0]
            - p2(g - a + b, stiff, sig, h0)[0] + p2(g - a - b, stiff, sig, h0)[0]) / (4 * a * b)


@njit
def _energy(tx, ty, tz, radius, stiff, sig, h0, h, n, mode, curvature):
    rho0, cap, slope = _cone(radius)
    e = 0.0
    for i in range(n):
        for j in range(n):
            dx, dy = tx - i * h, ty - j * h
            rise, q, q1 = _rise(dx * dx + dy * dy, radius, rho0, cap, slope)
            g = tz - radius + rise
            if curvature:
                g += h * h / 24.0 * (2 * q + q1 * (dx * dx + dy * dy))
            gx, gy = q * dx, q * dy
            if mode == POINT:
                e += h * h * _phi(g, stiff, sig, h0)
            elif mode == BOX:
                e += h * h * _mean(g, 0.5 * h * math.sqrt(gx * gx + gy * gy), 0.0, stiff, sig, h0)
            else:
                e += h * h * _mean(g, 0.5 * abs(gx) * h, 0.5 * abs(gy) * h, stiff, sig, h0)
    return e


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--radii-nm", type=float, nargs="+", default=[5.0, 20.0, 50.0])
    a = p.parse_args(argv)
    for radius in np.array(a.radii_nm) * 1e-9:
        law = ZoneLaw.from_law(MaugisDugdale(radius, 10e9, 0.1))
        stiff, sig, h0 = law.effective_modulus / (math.pi * math.sqrt(radius)), law.dugdale_stress, law.interaction_range
        zone = math.sqrt(2 * radius * h0)
        for label, h in (("zone_over_8", zone / 8), ("zone_over_4", zone / 4), ("zone_over_2", zone / 2),
                         ("radius_over_8", radius / 8)):
            n = int(2.2 * radius / h) + 8
            c, d = (n // 2) * h, 1e-3 * h0
            row = {"tip_radius_m": radius, "spacing": label, "spacing_m": h}
            for name, mode, curvature in (("point", POINT, False), ("box_curvature", BOX, True),
                                          ("trapezoid", TRAPEZOID, False), ("trapezoid_curvature", TRAPEZOID, True)):
                worst = 0.0
                for depth in np.linspace(-0.8 * h0, radius * (1.0 - math.sqrt(0.84)), 12):
                    exact = law.flat_load(depth)
                    for fx, fy in OFFSETS:
                        x, y, z = c + fx * h, c + fy * h, radius - depth
                        load = -(_energy(x, y, z + d, radius, stiff, sig, h0, h, n, mode, curvature)
                                 - _energy(x, y, z - d, radius, stiff, sig, h0, h, n, mode, curvature)) / (2 * d)
                        worst = max(worst, abs(load - exact) / max(abs(exact), law.pull_off_force()))
                row[name + "_worst_error_percent"] = round(100 * worst, 2)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
