"""Photodiode: both signal conventions, spot model round trip, sensitivities, forward simulation."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from arsurf.errors import ForceError
from arsurf.force.cantilever import Cantilever
from arsurf.force.decoupling import decouple_many
from arsurf.force.photodiode import Photodiode, quadrant_signals, quadrants_from_signals
from arsurf.force.simulate import simulate_signals

LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)


def test_conventions_by_hand():
    # A, B top; C, D bottom; A, C left; B, D right
    a, b, c, d = 1.0, 2.0, 3.0, 6.0
    assert quadrant_signals(a, b, c, d, "difference") == ((1 + 2) - (3 + 6), (1 + 3) - (2 + 6))
    v, h = quadrant_signals(a, b, c, d)
    assert v == pytest.approx(-6 / 12, rel=1e-15)
    assert h == pytest.approx(-4 / 12, rel=1e-15)
    # [Bolopion] names: T_l, T_r, B_l, B_r -> u_v = (T_l + T_r) - (B_l + B_r), u_h = (T_l + B_l) - (T_r + B_r)
    tl, tr, bl, br = 0.3, 0.1, 0.7, 0.2
    assert quadrant_signals(tl, tr, bl, br, "difference") == pytest.approx(((tl + tr) - (bl + br), (tl + bl) - (tr + br)))


def test_normalised_is_power_independent():
    rng = np.random.default_rng(5)
    q = rng.uniform(0.1, 2.0, size=(4, 100))
    v1, h1 = quadrant_signals(*q)
    v2, h2 = quadrant_signals(*(3.7 * q))
    assert np.allclose(v1, v2, rtol=1e-14) and np.allclose(h1, h2, rtol=1e-14)
    assert np.all(np.abs(v1) <= 1) and np.all(np.abs(h1) <= 1)


@settings(max_examples=80, deadline=None)
@given(st.floats(-0.9, 0.9), st.floats(-0.9, 0.9), st.floats(0.1, 10.0))
def test_spot_model_round_trip(v, h, total):
    a, b, c, d = quadrants_from_signals(v, h, total=total)
    assert a + b + c + d == pytest.approx(total, rel=1e-12)
    assert (a + d) - (b + c) == pytest.approx(0.0, abs=1e-12 * total)
    vv, hh = quadrant_signals(a, b, c, d)
    assert vv == pytest.approx(v, abs=1e-12) and hh == pytest.approx(h, abs=1e-12)
    a, b, c, d = quadrants_from_signals(v * total, h * total, total=total, convention="difference")
    vv, hh = quadrant_signals(a, b, c, d, "difference")
    assert vv == pytest.approx(v * total, abs=1e-12 * total) and hh == pytest.approx(h * total, abs=1e-12 * total)


def test_sensitivities_round_trip_and_sign():
    pd = Photodiode(-0.013, 0.021)
    b, t = pd.angles(0.25, -0.4)
    assert (b, t) == (pytest.approx(-0.013 * 0.25), pytest.approx(0.021 * -0.4))
    assert pd.signals(b, t) == pytest.approx((0.25, -0.4), rel=1e-15)
    arr = np.linspace(-1, 1, 11)
    bb, tt = pd.angles(arr, arr)
    assert np.allclose(pd.signals(bb, tt), [arr, arr], rtol=1e-15)
    q = quadrants_from_signals(0.25, -0.4)
    assert pd.angles_from_quadrants(*q) == pytest.approx((b, t), rel=1e-13)


def test_from_deflection_sensitivity_matches_end_loaded_beam():
    """S_v = 3 S_delta / (2 l): the bending angle of the lever under an end force equals S_v times
    the signal that the calibrated deflection sensitivity assigns to its end deflection."""
    s_delta = 1117e-9  # m per signal unit ([Alabdulmuhsin])
    pd = Photodiode.from_deflection_sensitivity(s_delta, LEVER.length)
    force = 25e-9
    deflection = force / LEVER.normal_stiffness
    signal = deflection / s_delta
    bending, _ = LEVER.angles([0.0, 0.0, force])
    assert pd.angles(signal, 0.0)[0] == pytest.approx(bending, rel=1e-12)
    assert pd.lateral_sensitivity == pd.vertical_sensitivity
    assert Photodiode.from_deflection_sensitivity(s_delta, LEVER.length, 0.5).lateral_sensitivity == 0.5


def test_simulate_signals_noise_free_round_trip():
    rng = np.random.default_rng(11)
    # forces in the plane of n = e_z and friction opposite to v = (1, 1, 0)/sqrt 2
    n = np.tile([0.0, 0.0, 1.0], (200, 1))
    v = np.tile([1e-6, 1e-6, 0.0], (200, 1))
    fn = rng.uniform(1e-9, 50e-9, 200)
    ff = rng.uniform(0, 20e-9, 200)
    forces = np.column_stack([-ff / np.sqrt(2), -ff / np.sqrt(2), fn])
    pd = Photodiode(0.02, -0.015)
    sim = simulate_signals(forces, LEVER, pd)
    b, t = pd.angles_from_quadrants(*sim.quadrants)
    got, status, _ = decouple_many(b, t, n, v, LEVER)
    assert np.all(status == 0)
    assert np.allclose(got, forces, rtol=1e-9, atol=1e-9 * np.abs(forces).max())


def test_simulate_signals_noise_is_seeded_and_sized():
    forces = np.zeros((20000, 3))
    pd = Photodiode(0.02, 0.02)
    s1 = simulate_signals(forces, LEVER, pd, noise=1e-3, seed=7)
    s2 = simulate_signals(forces, LEVER, pd, noise=1e-3, seed=7)
    s3 = simulate_signals(forces, LEVER, pd, noise=1e-3, seed=8)
    assert np.array_equal(s1.vertical, s2.vertical) and not np.array_equal(s1.vertical, s3.vertical)
    # std of 20000 Gaussian samples: relative error ~ 1/sqrt(2 n) = 0.5 %
    assert np.std(s1.vertical) == pytest.approx(1e-3, rel=0.03)
    assert np.std(s1.lateral) == pytest.approx(1e-3, rel=0.03)
    assert abs(np.corrcoef(s1.vertical, s1.lateral)[0, 1]) < 0.05


def test_bad_input():
    with pytest.raises(ForceError, match="quadrant voltages contain NaN"):
        quadrant_signals(1.0, np.nan, 1.0, 1.0)
    with pytest.raises(ForceError, match="total light A\\+B\\+C\\+D must be positive"):
        quadrant_signals(0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ForceError, match="convention must be 'normalized'"):
        quadrant_signals(1, 1, 1, 1, convention="raw")
    with pytest.raises(ForceError, match="vertical_sensitivity must be finite and non-zero"):
        Photodiode(0.0, 0.01)
    with pytest.raises(ForceError, match="lateral_sensitivity must be finite and non-zero"):
        Photodiode(0.01, np.nan)
    with pytest.raises(ForceError, match="photodiode signals contain NaN"):
        Photodiode(0.01, 0.01).angles(np.nan, 0.0)
    with pytest.raises(ForceError, match="length must be positive"):
        Photodiode.from_deflection_sensitivity(1e-6, -1.0)
    with pytest.raises(ForceError, match="total must be a positive voltage"):
        quadrants_from_signals(0.1, 0.1, total=0.0)
    with pytest.raises(ForceError, match="noise must be >= 0"):
        simulate_signals([0.0, 0.0, 1e-9], LEVER, Photodiode(0.01, 0.01), noise=-1.0)
