"""Cantilever: [Bolopion] figures, load-point formulas, torsion table, forward model vs beam integrals."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate

from arsurf.errors import ForceError
from arsurf.force.cantilever import (
    TORSION_TABLE,
    Cantilever,
    torsion_coefficient,
    torsional_stiffness_from_geometry,
)

# [Bolopion], Table I: silicon tipless lever
SEED003 = dict(length=220e-6, width=27e-6, thickness=2.9e-6, tip_height=0.0, youngs_modulus=150e9, poisson_ratio=0.17)
# [Alabdulmuhsin], Table 4.1 geometry with silicon moduli
CONTACT = dict(length=450e-6, width=50e-6, thickness=2.5e-6, tip_height=15e-6, youngs_modulus=169e9, poisson_ratio=0.27)


def test_seed003_normal_stiffness():
    lever = Cantilever(**SEED003)
    # k_z(L) = E w t^3 / (4 L^3), computed by hand: 2.319 N/m; the paper's calibrated value is 2.4 N/m
    assert lever.normal_stiffness == pytest.approx(150e9 * 27e-6 * 2.9e-6**3 / (4 * 220e-6**3), rel=1e-14)
    assert lever.normal_stiffness == pytest.approx(2.4, rel=0.05)


def test_seed003_torsional_stiffness_thin_plate():
    # [Bolopion] Eq. 10 uses k_tphi = G w t^3 / (3 x_p), i.e. beta = 1/3: 64.0e-9 N m
    lever = Cantilever(**SEED003, beta=1 / 3)
    assert lever.torsional_stiffness == pytest.approx(64.0e-9, rel=2e-3)
    assert lever.torsional_stiffness_at(220e-6) == pytest.approx(lever.torsional_stiffness, rel=1e-15)
    # the finite-aspect coefficient (t/w = 0.107) is 7 % lower
    exact = Cantilever(**SEED003)
    assert exact.beta == pytest.approx(torsion_coefficient(2.9 / 27), rel=1e-15)
    assert exact.torsional_stiffness / lever.torsional_stiffness == pytest.approx(exact.beta * 3, rel=1e-12)


def test_seed003_force_at_07um():
    # delta(L, 0) = 0.7 um with the calibrated k_z(L) = 2.4 N/m gives ~1.7 uN at point E (x_p = L)
    lever = Cantilever(**SEED003, normal_stiffness=2.4)
    force = lever.force_from_end_deflection(220e-6, 0.7e-6)
    assert force == pytest.approx(1.68e-6, rel=1e-12)
    assert force == pytest.approx(1.7e-6, rel=0.02)


def test_load_point_formulas_consistent():
    lever = Cantilever(**SEED003)
    L = lever.length
    xp = np.linspace(0.2, 1.0, 9) * L
    # Eq. 6 both forms
    assert np.allclose(lever.normal_stiffness_at(xp), 150e9 * 27e-6 * 2.9e-6**3 / (4 * xp**3), rtol=1e-13)
    force = 1e-6
    for x in xp:
        d_end = lever.deflection(L, x, force)
        d_load = lever.deflection(x, x, force)
        # Eq. 5-6: F = k_z(x_p) delta(x_p); Eq. 7: delta(x_p) = 2 x_p / (3L - x_p) delta(L)
        assert force == pytest.approx(lever.normal_stiffness_at(x) * d_load, rel=1e-12)
        assert d_load == pytest.approx(2 * x / (3 * L - x) * d_end, rel=1e-12)
        # Eq. 8 inverts the end reading
        assert lever.force_from_end_deflection(x, d_end) == pytest.approx(force, rel=1e-12)


def test_deflection_matches_beam_integral():
    """delta(x) against a double integral of M/EI (the slow, obviously right reference)."""
    lever = Cantilever(**CONTACT)
    ei, L, xp, F = lever.flexural_rigidity, lever.length, 0.6 * CONTACT["length"], 2e-9

    def slope(x):
        return integrate.quad(lambda s: F * max(xp - s, 0.0) / ei, 0.0, x, limit=200)[0]

    for x in (0.25 * L, xp, 0.9 * L, L):
        ref = integrate.quad(slope, 0.0, x, limit=200)[0]
        assert lever.deflection(x, xp, F) == pytest.approx(ref, rel=1e-9)


def test_flexural_rigidity_and_override():
    lever = Cantilever(**CONTACT)
    assert lever.flexural_rigidity == pytest.approx(169e9 * 50e-6 * 2.5e-6**3 / 12, rel=1e-14)
    assert lever.second_moment == pytest.approx(50e-6 * 2.5e-6**3 / 12, rel=1e-15)
    calibrated = Cantilever(**CONTACT, normal_stiffness=0.3)
    assert calibrated.normal_stiffness == 0.3
    assert calibrated.flexural_rigidity == pytest.approx(0.3 * 450e-6**3 / 3, rel=1e-14)
    # the tip deflection under an end force is F / k whatever the source of k
    assert calibrated.deflection(450e-6, 450e-6, 3e-9) == pytest.approx(1e-8, rel=1e-12)
    assert Cantilever(**CONTACT, torsional_stiffness=1e-9).torsional_stiffness == 1e-9


def test_torsion_coefficient_against_table():
    for ratio, beta in TORSION_TABLE[:-1]:
        assert torsion_coefficient(1.0 / ratio) == pytest.approx(beta, abs=1.5e-3)
        assert torsion_coefficient(1.0 / ratio, "table") == pytest.approx(beta, abs=1e-12)
        assert torsion_coefficient(1.0 / ratio, "roark") == pytest.approx(beta, abs=3e-3)
    assert torsion_coefficient(1e-6) == pytest.approx(1 / 3, rel=1e-6)
    assert torsion_coefficient(4.0) == torsion_coefficient(0.25)  # symmetric in the sides
    # interpolated table close to the series between the rows
    for r in np.linspace(0.1, 1.0, 19):
        assert torsion_coefficient(r, "table") == pytest.approx(torsion_coefficient(r), abs=6e-3)


def test_torsional_stiffness_from_geometry():
    G = 150e9 / (2 * 1.17)
    k = torsional_stiffness_from_geometry(220e-6, 27e-6, 2.9e-6, G, beta=1 / 3)
    assert k == pytest.approx(G * 27e-6 * 2.9e-6**3 / (3 * 220e-6), rel=1e-14)
    assert torsional_stiffness_from_geometry(220e-6, 27e-6, 2.9e-6, G) == pytest.approx(
        Cantilever(**SEED003).torsional_stiffness, rel=1e-14)


def test_angles_against_beam_integrals():
    """End slope from integrating M(x)/EI and twist T l / (G J) with explicit lever arms."""
    lever = Cantilever(**CONTACT)
    a = CONTACT["tip_height"] + CONTACT["thickness"] / 2
    F = np.array([3e-9, -2e-9, 7e-9])
    ei = lever.flexural_rigidity
    # moment about y at section x from a force at the apex (l, 0, -a): F_z (l - x) + a F_x
    slope = integrate.quad(lambda x: (F[2] * (lever.length - x) + a * F[0]) / ei, 0.0, lever.length)[0]
    gj = lever.shear_modulus * torsion_coefficient(2.5 / 50) * 50e-6 * 2.5e-6**3
    twist = a * F[1] * lever.length / gj
    bending, torsion = lever.angles(F)
    assert bending == pytest.approx(slope, rel=1e-12)
    assert torsion == pytest.approx(twist, rel=1e-12)
    assert lever.lever_arm == pytest.approx(a, rel=1e-15)
    assert lever.coupling == pytest.approx(2 * a / lever.length, rel=1e-15)


def test_angles_vectorised():
    lever = Cantilever(**CONTACT)
    forces = np.random.default_rng(3).normal(size=(50, 3)) * 1e-9
    b, t = lever.angles(forces)
    assert b.shape == t.shape == (50,)
    for i in (0, 17, 49):
        assert (b[i], t[i]) == lever.angles(forces[i])


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-1e-6, 1e-6), min_size=3, max_size=3),
    st.lists(st.floats(-1e-6, 1e-6), min_size=3, max_size=3),
    st.floats(-5, 5),
)
def test_angles_linear(f1, f2, s):
    lever = Cantilever(**CONTACT)
    f1, f2 = np.array(f1), np.array(f2)
    lhs = np.array(lever.angles(f1 + s * f2))
    rhs = np.array(lever.angles(f1)) + s * np.array(lever.angles(f2))
    assert np.allclose(lhs, rhs, rtol=1e-9, atol=1e-9 * (np.abs(rhs).max() + 1e-30) + 1e-300)


@pytest.mark.parametrize("name", ["length", "width", "thickness", "youngs_modulus"])
@pytest.mark.parametrize("bad", [0.0, -1e-6, float("nan"), float("inf")])
def test_bad_geometry(name, bad):
    kwargs = dict(CONTACT, **{name: bad})
    with pytest.raises(ForceError, match=f"{name} must be positive"):
        Cantilever(**kwargs)


def test_bad_other_parameters():
    with pytest.raises(ForceError, match="tip_height must be >= 0"):
        Cantilever(**dict(CONTACT, tip_height=-1e-6))
    with pytest.raises(ForceError, match=r"poisson_ratio must be in \(-1, 0.5\)"):
        Cantilever(**dict(CONTACT, poisson_ratio=0.5))
    with pytest.raises(ForceError, match="normal_stiffness must be positive"):
        Cantilever(**CONTACT, normal_stiffness=0.0)
    with pytest.raises(ForceError, match="torsional_stiffness must be positive"):
        Cantilever(**CONTACT, torsional_stiffness=-1.0)
    with pytest.raises(ForceError, match=r"beta must be in \(0, 1/3\]"):
        Cantilever(**CONTACT, beta=0.5)
    with pytest.raises(ForceError, match="length must be a number"):
        Cantilever(**dict(CONTACT, length="long"))
    lever = Cantilever(**CONTACT)
    with pytest.raises(ForceError, match=r"load point x_p must lie in \(0, length"):
        lever.normal_stiffness_at(0.0)
    with pytest.raises(ForceError, match=r"load point x_p must lie in \(0, length"):
        lever.torsional_stiffness_at(2 * lever.length)
    with pytest.raises(ForceError, match=r"force must have shape \(3,\) or \(n, 3\)"):
        lever.angles([1.0, 2.0])
    with pytest.raises(ForceError, match="force has NaN"):
        lever.angles([1.0, float("nan"), 0.0])
    with pytest.raises(ForceError, match="the side ratio t/w must be positive"):
        torsion_coefficient(0.0)
    with pytest.raises(ForceError, match="method must be"):
        torsion_coefficient(0.5, "exact")
    with pytest.raises(ForceError, match="end_deflection must be finite"):
        lever.force_from_end_deflection(lever.length, math.nan)
