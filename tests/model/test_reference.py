"""The fast model tick against the references chained (tests/support/reference.py), on random inputs.

The module tests compare each kernel with its own reference (spline, closest point,
Maugis-Dugdale, decoupling); here the whole compiled tick of :class:`arsurf.model.ARModel` -
collision, contact mechanics, simulated force, signals, decoupling - is compared with
:func:`reference.reference_model_tick` on random smooth surfaces, tip positions and motions.
"""
from __future__ import annotations

import numpy as np
import pytest
from tests.support.reference import reference_model_tick

from arsurf.assembly import LEVER, make_model
from arsurf.force.cantilever import Cantilever
from arsurf.spline.surface import BSplineSurface

R = 20e-9


def _surface(rng):
    n = 12
    z = rng.normal(scale=1.5e-9, size=(n, n))
    z = z - z.mean()
    return BSplineSurface.from_heights(z, (0.0, (n - 1) * 8e-9), (0.0, (n - 1) * 8e-9))


@pytest.mark.parametrize("seed", range(6))
def test_model_tick_equals_the_chained_references(seed):
    rng = np.random.default_rng(seed)
    surface = _surface(rng)
    e_star, w = rng.uniform(2e9, 60e9), rng.uniform(0.02, 0.3)
    lever = Cantilever(**LEVER)
    for _ in range(5):
        model = make_model(surface.copy(), tip_radius=R, effective_modulus=e_star, work_of_adhesion=w,
                           friction=0.0, deform=False)
        x, y = rng.uniform(30e-9, 60e-9, 2)
        depth = rng.uniform(0.5e-9, 3e-9)
        foot = surface.evaluate(x, y)
        centre = foot + np.array([0.0, 0.0, R - depth])
        velocity = np.array([*rng.normal(scale=1e-6, size=2), 0.0])
        ref = reference_model_tick(surface, centre, R, e_star, w, model.contact.dugdale_stress, lever, velocity,
                                   model.contact.jump_out_depth())
        tick = model.step(centre, signals=(ref["bending"], ref["torsion"]))  # first touch: stuck, no direction
        assert tick.md_status == 0 and tick.in_contact
        np.testing.assert_allclose(tick.point, ref["point"], rtol=0, atol=1e-15)
        np.testing.assert_allclose(tick.normal, ref["normal"], rtol=0, atol=1e-7)  # a 1e-15 m point error over R
        assert tick.depth == pytest.approx(ref["depth"], rel=0, abs=1e-15)
        assert tick.contact_radius == pytest.approx(ref["radius"], rel=1e-8)
        assert tick.load == pytest.approx(ref["load"], rel=1e-8, abs=1e-8 * abs(ref["load"]) + 1e-18)
        np.testing.assert_allclose(tick.simulated_force, ref["force"], rtol=1e-6, atol=1e-6 * abs(ref["load"]))
        if np.isfinite(ref["measured"]).all():
            np.testing.assert_allclose(tick.measured_force, ref["measured"], rtol=1e-6,
                                       atol=1e-6 * abs(ref["load"]))
