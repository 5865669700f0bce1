"""The energy of the whole tip over a material map (ARModel(zone_energy=True, material=...)): each
surface element sums its own local law, so away from a boundary the tip feels the local law's own
load, across a boundary the force is still the gradient of one energy and has no step, the
friction's adhesive normal is the local 2 pi R w, the passivity's reserve bounds every local well,
and a uniform map is the model without one, to the bit."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.contact.material_conversion import MaterialConversion
from arsurf.contact.material_map import build_material_map
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import ZoneLaw, zone_energy
from arsurf.model import ARModel
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface
from arsurf.status import CONTACT
from tests.support.valleys import LEVER, R

N, H = 64, 2e-9          # a flat 128 nm square, 2 nm pixels
STEP_X = 64e-9           # where the maps' fields step
Y0 = 60e-9


def _map(modulus, pull_off):
    chan = lambda v, name, unit: Scan(np.asarray(v, float), H, H, name, {"z_unit": unit})  # noqa: E731
    return build_material_map(Scan(np.zeros((N, N)), H, H), {"modulus": chan(modulus, "DMTModulus", "Pa"),
                                                             "adhesion": chan(pull_off, "Adhesion", "N")},
                              MaterialConversion(R))


X = np.arange(N) * H
#: the modulus steps 2 -> 20 GPa, the pull-off 2 -> 6 nN, both at x = 64 nm
STEPPED = (np.where(X < STEP_X, 2e9, 20e9) * np.ones((N, 1)), np.where(X < STEP_X, 2e-9, 6e-9) * np.ones((N, 1)))


@pytest.fixture(scope="module")
def flat():
    return fit_surface(Scan(np.zeros((N, N)), H, H))


@pytest.fixture(scope="module")
def stepped():
    return _map(*STEPPED)


def _local_law(material, x, y, law):
    """The Maugis-Dugdale law of the map's values at (x, y), with the model's range h0."""
    e, w = float(material.reduced_modulus(x, y)), float(material.work_of_adhesion(x, y))
    return MaugisDugdale(R, e, w, w / law.interaction_range)


def test_a_uniform_map_is_the_model_without_one_to_the_bit(flat):
    # a map is always summed over the lattice (the closed form is without one)
    material = _map(np.full((N, N), 5e9), np.full((N, N), 3e-9))
    law = material.contact_law()
    mapped = ARModel(flat, R, law, LEVER, material=material, zone_energy=True, coupling_stiffness=3.0)
    plain = ARModel(flat, R, law, LEVER, zone_energy=True, coupling_stiffness=3.0, zone_closed_form=False)
    for x in np.linspace(50e-9, 70e-9, 60):
        a, b = mapped.step((x, Y0, R - 1e-9)), plain.step((x, Y0, R - 1e-9))
        assert np.array_equal(a.simulated_force, b.simulated_force) and np.array_equal(a.tip, b.tip)
    assert mapped.adhesion_energy() == plain.adhesion_energy()


@pytest.mark.parametrize("x", [24e-9, 104e-9])
def test_away_from_the_boundary_the_tip_feels_the_local_law(flat, stepped, x):
    """30-40 nm from the step the summed law is the uniform zone model's with the local E* and w
    (the same lattice: to rounding) and, on the stiff side, the law's load on a flat within the
    lattice's quadrature (on the soft side that load is a small difference of Hertz and 2 pi R w)."""
    law = stepped.contact_law()
    mapped = ARModel(flat, R, law, LEVER, material=stepped, zone_energy=True, friction=0.0, deform=False)
    local = _local_law(stepped, x, Y0, law)
    uniform = ARModel(flat, R, local, LEVER, zone_energy=True, friction=0.0, deform=False, zone_closed_form=False)
    for depth in (0.3e-9, 1.0e-9):
        a, b = mapped.step((x, Y0, R - depth)), uniform.step((x, Y0, R - depth))
        assert a.md_status == CONTACT
        np.testing.assert_allclose(a.simulated_force, b.simulated_force, rtol=1e-9, atol=1e-9 * abs(b.load))
    if x > STEP_X:
        assert a.load == pytest.approx(ZoneLaw.from_law(local).flat_load(1.0e-9), rel=0.02)
    assert abs(a.load - ARModel(flat, R, law, LEVER, zone_energy=True, friction=0.0, deform=False)
               .step((x, Y0, R - 1.0e-9)).load) > 0.3 * abs(a.load)  # not the reference law's


def test_across_the_boundary_the_force_is_the_energy_s_gradient_without_a_step(flat, stepped):
    """The tip held 1 nm into the flat and moved across the step of E* and w: the lateral force is
    -dE/dx (central differences of the summed energy), pushes the tip towards the softer side, and
    changes by at most a small fraction of the load between positions 0.05 nm apart."""
    law = stepped.contact_law()
    m = ARModel(flat, R, law, LEVER, material=stepped, zone_energy=True, friction=0.0, deform=False)
    zl, z = ZoneLaw.from_law(law), R - 1.0e-9
    xs = np.linspace(STEP_X - 8e-9, STEP_X + 8e-9, 321)
    forces = np.array([zone_energy(m.zone_lattice, zl, (x, Y0, z))[1] for x in xs])
    d = 1e-12
    for k in range(0, xs.size, 40):
        de = zone_energy(m.zone_lattice, zl, (xs[k] + d, Y0, z))[0] - zone_energy(m.zone_lattice, zl, (xs[k] - d, Y0, z))[0]
        assert forces[k, 0] == pytest.approx(-de / (2 * d), rel=1e-3, abs=1e-4 * forces[k, 2])
    assert forces[160, 0] < -0.05 * forces[160, 2]  # towards the soft side (x < 64 nm), a sizeable share
    assert np.abs(np.diff(forces, axis=0)).max() <= 0.02 * np.abs(forces[:, 2]).max()


@pytest.mark.parametrize("x", [24e-9, 104e-9])
def test_the_friction_s_adhesive_normal_is_the_local_pull_off(flat, stepped, x):
    """|F_t| = mu (P + 2 pi R w) on a steady slide, w the map's where the tip slides."""
    law = stepped.contact_law()
    m = ARModel(flat, R, law, LEVER, material=stepped, zone_energy=True, friction=0.2, deform=False)
    depth = 0.3e-9
    for z in np.linspace(R + 1e-9, R - depth, 40):
        m.step((x, Y0, z))
    for k in range(1, 41):
        t = m.step((x + k * 0.2e-9, Y0, R - depth))
    assert t.in_contact and t.slipping
    w = float(stepped.work_of_adhesion(t.tip[0], Y0))  # the slide moved 8 nm; the map is flat there
    expected = 0.2 * (t.load + 2.0 * math.pi * R * w)
    assert math.hypot(*t.simulated_force[:2]) == pytest.approx(expected, rel=1e-6)
    assert not math.isclose(w, law.work_of_adhesion, rel_tol=0.05)


def test_the_passivity_reserve_bounds_every_local_well(flat, stepped):
    law = stepped.contact_law()
    k = 3.0
    m = ARModel(flat, R, law, LEVER, material=stepped, zone_energy=True, coupling_stiffness=k)
    reserve = m.adhesion_energy()
    assert reserve >= m.adhesion_energy(with_map=False)
    wells = []
    for x in X:
        z = ZoneLaw.from_law(_local_law(stepped, x, Y0, law))
        pc = z.pull_off_force()
        wells.append(pc * (z.zero_load_depth() + z.interaction_range + pc / k))
    assert max(wells) <= reserve <= 2.0 * max(wells)  # a bound, and not a loose one
