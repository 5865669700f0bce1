"""The model with the energy of the whole tip as its contact (ARModel(zone_energy=True),
arsurf.contact.zone_energy): on a flat the law's exact load, depth and Hertz radius; in the valley
narrower than the tip, where the several-contact model's force is not a gradient
(tests/contact/test_force_field.py, strict xfail), a force that is one, and behind the coupling a
force that turns across the valley without a step; bad settings refused in one line."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import L_QUAD, ZoneLaw, zone_energy
from arsurf.contact.zone_quadric import Q_WEIGHT
from arsurf.errors import ContactError
from arsurf.feel_scenarios import clearance_height
from arsurf.model import ARModel
from arsurf.scan import synthetic
from arsurf.spline.fit import fit_surface
from arsurf.status import CONTACT, SEPARATED
from tests.support.valleys import LEVER, R, height_for, pressed_onto, valley_model

LAW = MaugisDugdale(R, 50e9, 0.05)


@pytest.fixture(scope="module")
def flat():
    return fit_surface(synthetic.sinusoid(shape=(40, 40), pixel=1e-9, amplitude=0.0, period=10e-9))


@pytest.mark.parametrize("depth", [0.1e-9, 0.5e-9, 1.0e-9])
def test_on_a_flat_the_tip_feels_the_law_s_load(flat, depth):
    m = ARModel(flat, R, LAW, LEVER, friction=0.0, deform=False, zone_energy=True)
    t = m.step((20.3e-9, 19.6e-9, R - depth))
    exact = ZoneLaw.from_law(LAW).flat_load(depth)
    assert t.md_status == CONTACT and t.in_contact
    assert t.depth == pytest.approx(depth, abs=1e-15)
    assert t.load == pytest.approx(exact, rel=0.01)  # the quadrature of the lattice, 0.5 nm apart
    np.testing.assert_allclose(t.simulated_force, [0.0, 0.0, t.load], atol=3e-3 * exact)  # the quadrature's
    assert t.contact_radius == pytest.approx(math.sqrt(R * depth), rel=1e-12)
    assert m.step((20e-9, 20e-9, R + 2.0 * ZoneLaw.from_law(LAW).interaction_range)).md_status == SEPARATED


def test_behind_a_coupling_the_tip_rests_where_the_spring_balances_the_law(flat):
    k = 5.0
    m = ARModel(flat, R, LAW, LEVER, friction=0.0, deform=False, coupling_stiffness=k, zone_energy=True)
    target = np.array([20e-9, 20e-9, R - 3e-9])
    pressed_onto(m, target)
    t = m.step(target)
    law = ZoneLaw.from_law(LAW)
    np.testing.assert_allclose(t.simulated_force, k * (t.tip - target), rtol=1e-6, atol=1e-6 * k * R)
    assert t.coupled and t.depth == pytest.approx(R - t.tip[2], abs=1e-15)
    # the lattice's sum at the tip, the law's exact load within the quadrature of a 0.2 nm deep cap
    summed = zone_energy(m.zone_lattice, law, t.tip)[1]
    np.testing.assert_allclose(t.simulated_force, summed, rtol=1e-12)
    assert t.load == pytest.approx(law.flat_load(t.depth), rel=0.02)


@pytest.mark.parametrize("offset", [0.3e-9, 0.8e-9, 1.5e-9])
def test_in_a_valley_narrower_than_the_tip_the_force_is_a_gradient(offset):
    """tests/contact/test_force_field.py's strict xfail, with the zone energy as the contact. The
    Jacobian by differences over 0.1 nm: each lattice sample crossing the contact's edge adds a
    stiffness that is infinite there but integrable (the Hertz pressure's square root), so at the
    pm scale the differences see single samples (1.6 % skew at 1 pm at one offset, 0.5 % at
    0.1 nm); the several-contact model's skew is 9-12 % at either step."""
    m = valley_model("sinusoid", zone_energy=True)
    c = np.array([33e-9 + offset, 24e-9, height_for("sinusoid", 33e-9, 2e-9)])  # both slopes ~2 nm deep
    pressed_onto(m, c)
    jac = m.force_jacobian(c, step=1e-10)
    skew, sym = 0.5 * (jac - jac.T), 0.5 * (jac + jac.T)
    assert np.linalg.norm(skew) <= 0.01 * np.linalg.norm(sym)


def test_behind_a_coupling_the_force_crosses_the_valley_without_a_step():
    """The target swept 3 nm across the valley narrower than the tip in 1 pm ticks behind a 5 N/m
    coupling: the force turns one way without a step (the several-contact model steps where a
    contact enters or leaves, docs/feel.rst)."""
    m = valley_model("sinusoid", coupling=5.0, zone_energy=True)
    z = height_for("sinusoid", 33e-9, 2e-9) - 1e-9
    xs = 33e-9 + np.linspace(-1.5e-9, 1.5e-9, 3001)
    pressed_onto(m, np.array([xs[0], 24e-9, z]))
    forces = np.array([m.step((x, 24e-9, z)).simulated_force for x in xs])
    size = np.linalg.norm(forces, axis=1)
    assert size.min() > 0.0
    assert np.linalg.norm(np.diff(forces, axis=0), axis=1).max() <= 2e-3 * np.median(size)
    angle = np.arctan2(forces[:, 0], forces[:, 2])
    assert np.all(np.diff(angle) < 0.0)  # turning one way, through the middle


def test_bad_settings_are_refused_in_one_line(flat):
    with pytest.raises(ContactError, match="zone_energy"):
        ARModel(flat, R, LAW, LEVER, zone_energy="yes")
    with pytest.raises(ContactError, match="MaterialMap"):  # a material map or nothing
        ARModel(flat, R, LAW, LEVER, zone_energy=True, material=object())


def test_in_closed_form_the_slide_feels_the_lattice_s_force_where_the_contact_is_smooth():
    """ARModel(zone_energy=True, zone_closed_form=True) on a wave smooth under a 20 nm tip: the one term
    carries the slide, within its accuracy of the lattice's force."""
    wave = fit_surface(synthetic.sinusoid(shape=(96, 96), pixel=1e-9, amplitude=2e-9, period=80e-9, angle=0.6))
    closed, summed = (ARModel(wave, R, LAW, LEVER, friction=0.0, deform=False, coupling_stiffness=5.0,
                              zone_energy=True, zone_closed_form=form) for form in (True, False))
    forces, alone = [], 0
    for x in np.linspace(35e-9, 60e-9, 120):  # 1 nm below where the sphere would touch: along the wave
        target = (x, 48e-9, clearance_height(wave, x, 48e-9, R, samples=61) - 1.0e-9)
        forces.append((closed.step(target).simulated_force, summed.step(target).simulated_force))
        alone += closed.zone_lattice.arrays[L_QUAD][Q_WEIGHT] == 1.0  # the one term's weight at the tick's tip
    a, b = (np.array(f) for f in zip(*forces))
    assert np.abs(b[:, 2]).min() > 2e-9  # pressed all along (the coupling, 5 N/m, 1 nm deep)
    assert np.abs(a - b).max() <= 0.015 * np.abs(b).max()
    assert alone >= 0.8 * len(forces)
    with pytest.raises(ContactError, match="zone_closed_form"):
        ARModel(wave, R, LAW, LEVER, zone_energy=True, zone_closed_form=1)
