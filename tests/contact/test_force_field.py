"""The contact force as a field of the tip centre: its Jacobian (ARModel.force_jacobian).

On one contact the force is the gradient of the contact's potential behind the coupling: the
Jacobian is symmetric and its normal stiffness is the coupling in series with the contact,
k_c k/(k_c + k), k = dP/d(delta) of the Maugis-Dugdale law at the tip's depth. In a valley
narrower than the tip the several-contact force (arsurf.contact.multi_contact) is not a gradient:
its skew part is what makes the pressing hand gain energy on rough surfaces (issue 27; strict
xfail until the force is made conservative). Sideways as along the normal, the hand feels the
coupling in series with the valley's walls, not the walls' own stiffness.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import ContactError, PositionError
from arsurf.model import ARModel
from arsurf.scan import synthetic
from arsurf.spline.fit import fit_surface
from tests.support.valleys import LEVER, R, height_for, pressed_onto, valley_model

LAW = MaugisDugdale(R, 50e9, 0.05)


@pytest.mark.parametrize("coupling", [math.inf, 1.0, 20.0])
def test_on_one_contact_the_jacobian_is_the_series_stiffness_and_symmetric(coupling):
    flat = fit_surface(synthetic.sinusoid(shape=(40, 40), pixel=1e-9, amplitude=0.0, period=10e-9))
    m = ARModel(flat, R, LAW, LEVER, friction=0.0, deform=False, coupling_stiffness=coupling)
    c = np.array([20e-9, 20e-9, R - 1.0e-9])  # the target 1 nm into the surface
    pressed_onto(m, c)
    state = m.state.copy()
    jac = m.force_jacobian(c)
    np.testing.assert_array_equal(m.state, state)  # the contact history is untouched
    t = m.step(c)
    h = 1e-13  # the law's stiffness at the tip's own depth (behind the coupling: the tick's depth)
    k = (LAW.load(t.depth + h) - LAW.load(t.depth - h)) / (2 * h)
    series = k if coupling == math.inf else coupling * k / (coupling + k)
    assert -jac[2, 2] == pytest.approx(series, rel=2e-3)
    assert np.abs(jac - jac.T).max() <= 1e-6 * abs(jac[2, 2])
    assert np.abs(jac[:2, :2]).max() <= 1e-6 * abs(jac[2, 2])  # a flat pushes straight up wherever the tip is


def test_bad_arguments_are_refused():
    m = valley_model("sinusoid")
    with pytest.raises(PositionError, match="center"):
        m.force_jacobian((0.0, math.nan, 1e-9))
    with pytest.raises(ContactError, match="step"):
        m.force_jacobian((33e-9, 24e-9, 30e-9), step=0.0)


@pytest.mark.xfail(strict=True, reason="issue 27: the several-contact force is not a gradient (docs/feel.rst)")
@pytest.mark.parametrize("offset", [0.3e-9, 0.8e-9, 1.5e-9])
def test_in_a_valley_narrower_than_the_tip_the_force_is_a_gradient(offset):
    m = valley_model("sinusoid")
    c = np.array([33e-9 + offset, 24e-9, height_for("sinusoid", 33e-9, 2e-9)])  # both slopes ~2 nm deep
    pressed_onto(m, c)
    jac = m.force_jacobian(c)
    skew, sym = 0.5 * (jac - jac.T), 0.5 * (jac + jac.T)
    assert np.linalg.norm(skew) <= 0.01 * np.linalg.norm(sym)


@pytest.mark.parametrize("kind, x_mid", [("sinusoid", 33e-9), ("bumps", 36e-9)])
def test_sideways_the_hand_feels_about_the_coupling_not_the_valley_s_walls(kind, x_mid):
    """A tip resting on both walls of a valley narrower than it, behind a 5 N/m coupling: the
    walls are each some 100 N/m stiff, and the part of their summed force off the total normal
    reached the hand unfiltered (14 N/m sideways, 2.8 k_c). Passed through the coupling sideways
    too (arsurf.contact.multi_contact.coupled_offset_kernel), the stiffest direction of the field
    is about k_c (what is left: the contact normals turning as the target moves)."""
    k_c = 5.0
    m = valley_model(kind, coupling=k_c)
    c = np.array([x_mid + 0.3e-9, 24e-9, height_for(kind, x_mid, 2e-9)])  # both walls ~2 nm deep
    pressed_onto(m, c)
    jac = m.force_jacobian(c)
    stiffness = np.linalg.eigvalsh(-0.5 * (jac + jac.T))  # N/m, along the field's principal directions
    assert stiffness.max() <= 1.15 * k_c, stiffness
    assert stiffness.max() >= 0.9 * k_c  # pressed into the valley, the coupling itself is felt
