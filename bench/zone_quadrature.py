"""Benchmark (accuracy): how well the zone energy's lattice sums its law on a flat.

The energy of the whole tip (:mod:`arsurf.contact.zone_energy`) sums its law over a uniform
lattice of the surface. On a flat the exact load is known (:meth:`ZoneLaw.flat_load`, the ring
integral by quadrature to 1e-10), so the lattice's error is measured directly: for each tip radius
and pixel pitch, the tip pressed from the law's tail (-0.8 h0) to the small-contact limit (contact
radius 0.4 R) at 12 depths, at 4 positions against the lattice, the worst |F_z - P(depth)| over
|P(depth)|, or over the law's pull-off 2 pi R w where the load is smaller (%). For each the lattice of :func:`~arsurf.contact.zone_energy.lattice_for`
(what the model uses) and lattices at R/8 and at the interaction zone's sqrt(2 R h0) / 4 and / 8
whatever the pixels, with the samples each sums where the tip is deepest (what the tick's sum
costs grows with them).

Run: .venv/bin/python bench/zone_quadrature.py [--radii-nm 2 5 20 50] [--pixels-nm 0.25 1 4]
[--modulus-gpa 10] [--work 0.1] (prints JSON, one line per tip and pixel)
"""
from __future__ import annotations

import argparse
import json
import math

import numpy as np

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import Z_FORCE, ZONE_OUT, ZoneLaw, lattice_for, surface_lattice, zone_energy_kernel
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface

#: the positions of the tip's axis within a lattice cell (fractions of the spacing)
OFFSETS = ((0.0, 0.0), (0.5, 0.5), (0.3, 0.17), (0.77, 0.21))


def worst_error(lattice, law: ZoneLaw, centre: float) -> tuple[float, int]:
    """(worst error over the load or the pull-off, samples summed at the deepest press) on ``lattice``."""
    r = law.tip_radius
    deepest = r - math.sqrt(r * r - (0.4 * r) ** 2)
    worst, n = 0.0, 0
    out = ZONE_OUT.zeros()
    for depth in np.linspace(-0.8 * law.interaction_range, deepest, 12):
        exact = law.flat_load(depth)
        for fx, fy in OFFSETS:
            n = zone_energy_kernel(*lattice.kernel_args(), centre + fx * lattice.spacing[0],
                                   centre + fy * lattice.spacing[1], r - depth, *law.args, out, np.empty((0, 0)))
            worst = max(worst, abs(out[Z_FORCE + 2] - exact) / max(abs(exact), law.pull_off_force()))
    return worst, n


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--radii-nm", type=float, nargs="+", default=[2.0, 5.0, 20.0, 50.0])
    p.add_argument("--pixels-nm", type=float, nargs="+", default=[0.25, 1.0, 4.0])
    p.add_argument("--modulus-gpa", type=float, default=10.0, help="E* (GPa; the demo law's)")
    p.add_argument("--work", type=float, default=0.1, help="w (J/m^2; the demo law's; h0 the default range)")
    a = p.parse_args(argv)
    for radius in np.array(a.radii_nm) * 1e-9:
        law = ZoneLaw.from_law(MaugisDugdale(radius, a.modulus_gpa * 1e9, a.work))
        zone = math.sqrt(2.0 * radius * law.interaction_range)
        for pixel in np.array(a.pixels_nm) * 1e-9:
            n = int(min(max(4.0 * radius / pixel + 16, 40), 400))
            surface = fit_surface(Scan(np.zeros((n, n)), pixel, pixel))
            centre = 0.5 * (n - 1) * pixel
            row = {"tip_radius_m": radius, "pixel_m": pixel, "interaction_range_m": law.interaction_range}
            lattices = {"lattice_for": lattice_for(surface, radius, law.interaction_range)}
            for name, spacing in (("radius_over_8", radius / 8.0), ("zone_over_4", zone / 4.0),
                                  ("zone_over_8", zone / 8.0)):
                lattices[name] = surface_lattice(surface, per_knot=min(pixel / spacing, 64.0))
            for name, lattice in lattices.items():
                worst, samples = worst_error(lattice, law, centre)
                row[name] = {"spacing_m": lattice.spacing[0], "worst_error_percent": round(100 * worst, 2),
                             "samples_at_the_deepest_press": samples}
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
