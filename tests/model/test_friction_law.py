"""Friction that follows the contact (#27 §2): mu (P + |P_c|) down to the pull-off, the area law,
the re-sticking proxy's saw-tooth (period and amplitude derived in arsurf.contact.friction) and
the smooth slide with mu_s = mu_k. All on a flat surface, where every number is analytic."""
import math

import numpy as np
import pytest

from arsurf.contact import friction as fr
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.force.cantilever import Cantilever
from arsurf.model import ARModel
from arsurf.spline.surface import BSplineSurface

R = 20e-9
LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
#: the demo law (preset "demo": E* 10 GPa, w 0.1 J/m^2): pull-off -10.8 nN
LAW = MaugisDugdale(R, 10e9, 0.1)
X0, Y0 = 100e-9, 100e-9


def flat():
    return BSplineSurface.from_heights(np.zeros((60, 60)), (0.0, 57 * 4e-9), (0.0, 57 * 4e-9))


def held_at(model, depth):
    """Press 2 nm in (contact made on the approach), then retract to ``depth`` (m; negative: the
    tip above the surface, held by adhesion under displacement control)."""
    for z in np.linspace(R + 1e-9, R - 2e-9, 60):
        model.step((X0, Y0, z))
    for z in np.linspace(R - 2e-9, R - depth, 60):
        model.step((X0, Y0, z))


def slide(model, depth, step, ticks, direction=(1.0, 0.0)):
    """Slide at the tip height of ``depth`` by ``step`` (m) per tick; the ticks' records."""
    ux, uy = direction
    return [model.step((X0 + k * step * ux, Y0 + k * step * uy, R - depth)) for k in range(1, ticks + 1)]


# depths from compressive to tensile loads, all on the contact branch down to the fold
DEPTHS = (1.5e-9, 0.5e-9, 0.0, -0.1e-9, -0.15e-9, -0.2e-9)  # a = 0 below about -0.2 nm


def test_the_depths_reach_tensile_loads_down_to_near_the_pull_off():
    loads = []
    for depth in DEPTHS:
        m = ARModel(flat(), R, LAW, LEVER, friction=0.2, deform=False)
        held_at(m, depth)
        t = m.step((X0, Y0, R - depth))
        assert t.in_contact
        loads.append(t.load)
    assert max(loads) > 5e-9 and min(loads) < 0.5 * LAW.pull_off_force() < 0  # compressive and well tensile


@pytest.mark.parametrize("depth", DEPTHS)
def test_sliding_friction_is_mu_times_load_plus_pull_off_under_any_load(depth):
    """|F_t| = mu (P + |P_c|) on a steady slide, tensile loads included: the adhesive contact
    resists sliding until the pull-off (before: zero friction whenever P <= 0)."""
    m = ARModel(flat(), R, LAW, LEVER, friction=0.2, deform=False)
    held_at(m, depth)
    ticks = slide(m, depth, 0.2e-9, 40)
    t = ticks[-1]
    assert t.in_contact and t.slipping
    ft = math.hypot(*t.simulated_force[:2])
    expected = 0.2 * (t.load + abs(LAW.pull_off_force()))
    assert ft == pytest.approx(expected, rel=1e-9)
    assert ft > 0.0 and t.simulated_force[0] < 0.0  # against the slide
    assert t.simulated_force[2] == pytest.approx(t.load, rel=1e-12)


def test_no_friction_once_separated():
    m = ARModel(flat(), R, LAW, LEVER, friction=0.2, deform=False)
    held_at(m, 0.0)
    for z in np.linspace(R, R + 3e-9, 40):  # retract past the jump-out
        m.step((X0, Y0, z))
    ticks = slide(m, -3e-9, 0.2e-9, 10)
    assert not ticks[-1].in_contact and np.all(ticks[-1].simulated_force == 0.0)


def test_the_compressive_law_of_old_sessions_has_no_friction_under_tension():
    m = ARModel(flat(), R, LAW, LEVER, friction=0.2, deform=False, friction_law="compressive")
    held_at(m, -0.2e-9)
    t = slide(m, -0.2e-9, 0.2e-9, 20)[-1]
    assert t.in_contact and t.load < 0.0 and t.simulated_force[0] == 0.0 and t.simulated_force[1] == 0.0


def test_the_area_law_gives_tau_pi_a_squared():
    tau = 50e6
    m = ARModel(flat(), R, LAW, LEVER, friction=0.2, deform=False, friction_law="area", shear_strength=tau)
    for depth in (0.5e-9, -0.2e-9):
        m.reset()
        held_at(m, depth)
        t = slide(m, depth, 0.2e-9, 40)[-1]
        assert math.hypot(*t.simulated_force[:2]) == pytest.approx(tau * math.pi * t.contact_radius ** 2, rel=1e-9)


def test_the_law_is_validated():
    from arsurf.errors import ContactError

    with pytest.raises(ContactError, match="friction_law"):
        ARModel(flat(), R, LAW, LEVER, friction_law="coulomb")
    with pytest.raises(ContactError, match="shear_strength"):
        ARModel(flat(), R, LAW, LEVER, friction_law="area")
    with pytest.raises(ContactError, match="shear_strength"):
        ARModel(flat(), R, LAW, LEVER, shear_strength=1e6)


def tangential_stiffness(t):
    """The proxy's k_t at this tick: Mindlin's, 2 (1 - nu) / (2 - nu) 2 E* a (no coupling)."""
    return fr.MINDLIN_RATIO * 2.0 * LAW.effective_modulus * t.contact_radius


@pytest.mark.parametrize("depth, step", [(1.0e-9, 1.2e-12), (0.5e-9, 0.3e-12), (-0.2e-9, 0.6e-12)])
def test_with_mu_s_above_mu_k_a_slide_is_a_saw_tooth_of_the_derived_period(depth, step):
    """mu_s = 0.3, mu_k = 0.2: the friction climbs k_t v dt per tick from mu_k N to mu_s N and
    slips back. Period (friction.py): T = dt (floor((mu_s - mu_k) N / (k_t v dt)) + 1), within a
    tick of the continuous (mu_s - mu_k) N / (k_t v); amplitude (mu_s - mu_k) N less one tick's rise."""
    m = ARModel(flat(), R, LAW, LEVER, friction=0.2, static_friction=0.3, deform=False)
    held_at(m, depth)
    ticks = slide(m, depth, step, 1500)
    fx = np.array([t.simulated_force[0] for t in ticks])
    slips = np.flatnonzero([t.slipping for t in ticks])
    t = ticks[-1]
    normal = t.load + abs(LAW.pull_off_force())
    k_t = tangential_stiffness(t)
    gap = 0.1 * normal / (k_t * step)  # (mu_s - mu_k) N / (k_t v dt): the period in ticks, continuous
    assert 20 < gap < 200  # a saw-tooth resolved by the ticks
    periods = np.diff(slips[1:])  # the first slip is the break-away from rest
    assert len(periods) >= 5
    assert np.all(periods == math.floor(gap) + 1)
    assert periods.mean() == pytest.approx(gap, rel=0.05)
    steady = fx[slips[1]:]
    amplitude = steady.max() - steady.min()
    assert 0.1 * normal - k_t * step <= amplitude <= 0.1 * normal * (1 + 1e-9)
    assert -steady.max() == pytest.approx(0.2 * normal, rel=1e-9)  # the slips drop to the kinetic limit
    rises = np.diff(steady)
    assert np.sum(rises > 0) == len(periods)  # one drop per tooth (the friction is -F_x)


def test_with_mu_s_equal_to_mu_k_the_slide_is_smooth():
    m = ARModel(flat(), R, LAW, LEVER, friction=0.2, static_friction=0.2, deform=False)
    held_at(m, 1.0e-9)
    ticks = slide(m, 1.0e-9, 1.2e-12, 1500)
    fx = np.array([t.simulated_force[0] for t in ticks])[200:]
    normal = ticks[-1].load + abs(LAW.pull_off_force())
    np.testing.assert_allclose(fx, -0.2 * normal, rtol=1e-9)
    d = np.diff(fx)
    assert np.sum(np.sign(d[1:]) * np.sign(d[:-1]) < 0) == 0  # no reversals
    assert all(t.slipping for t in ticks[200:])
