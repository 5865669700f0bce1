"""BSplineSurface: evaluation against the reference, derivatives, edges, copy/reset, bad input."""
import numpy as np
import pytest

from arsurf.errors import SurfaceError
from arsurf.spline.knots import clamped_uniform_knots
from arsurf.spline.surface import BSplineSurface
from tests.support.reference import surface_reference


@pytest.fixture
def wavy(rng):
    """A general 3-D net (moved in x, y and z: not a height field)."""
    s = BSplineSurface.from_heights(rng.normal(size=(7, 6)) * 1e-9, (0.0, 8e-9), (0.0, 6e-9))
    ctrl = s.control_points.copy()
    ctrl += rng.normal(size=ctrl.shape) * 0.2e-9
    return BSplineSurface(ctrl, s.knots_u, s.knots_v)


def test_point_and_derivatives_match_reference(wavy, rng):
    ctrl, _, ku, kv = wavy.kernel_arrays()
    pts = [(0.0, 0.0), (8e-9, 6e-9), (2e-9, 3e-9)] + [tuple(x) for x in rng.uniform([0, 0], [8e-9, 6e-9], (10, 2))]
    for u, v in pts:
        got = wavy.evaluate(u, v, derivatives=2)
        for k, (du, dv) in enumerate([(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]):
            ref = surface_reference(ctrl, ku, kv, u, v, du, dv)
            scale = (1e-9) ** (du + dv)  # compare in units of nm^(1 - order)
            np.testing.assert_allclose(got[k] * scale, ref * scale, rtol=0, atol=1e-21 * 1e3)


def test_batch_equals_single_and_keeps_shape(wavy, rng):
    u = rng.uniform(0, 8e-9, (3, 4))
    v = rng.uniform(0, 6e-9, (3, 4))
    S, Su, Sv = wavy.evaluate(u, v, derivatives=1)
    assert S.shape == (3, 4, 3)
    for idx in np.ndindex(3, 4):
        s1, su1, sv1 = wavy.evaluate(float(u[idx]), float(v[idx]), derivatives=1)
        np.testing.assert_array_equal(S[idx], s1)
        np.testing.assert_array_equal(Su[idx], su1)


def test_derivatives_against_central_differences(wavy):
    u, v, h = 3.3e-9, 2.7e-9, 1e-13
    S, Su, Sv, Suu, Suv, Svv = wavy.evaluate(u, v, derivatives=2)
    fd_u = (wavy.evaluate(u + h, v) - wavy.evaluate(u - h, v)) / (2 * h)
    fd_v = (wavy.evaluate(u, v + h) - wavy.evaluate(u, v - h)) / (2 * h)
    np.testing.assert_allclose(Su, fd_u, atol=1e-6)
    np.testing.assert_allclose(Sv, fd_v, atol=1e-6)
    H = 1e-12
    fd_uv = (wavy.evaluate(u + H, v, 1)[2] - wavy.evaluate(u - H, v, 1)[2]) / (2 * H)
    np.testing.assert_allclose(Suv, fd_uv, rtol=1e-5, atol=1e3)


def test_continuity_across_a_knot_line(wavy):
    h = wavy.spacing[0]
    knot = 2 * h
    for order in range(3):
        left = wavy.evaluate(knot - 1e-20, 3e-9, derivatives=2)
        right = wavy.evaluate(knot + 1e-20, 3e-9, derivatives=2)
        for k in (0, 1, 3):  # S, S_u, S_uu are continuous for a cubic (C2)
            np.testing.assert_allclose(left[k], right[k], rtol=1e-9, atol=1e-20)


def test_out_of_domain_parameters_are_clamped(wavy):
    np.testing.assert_array_equal(wavy.evaluate(-1.0, 7.0), wavy.evaluate(0.0, 6e-9))


def test_undeformed_height_field_has_x_equal_u():
    s = BSplineSurface.from_heights(np.ones((6, 5)), (1e-9, 6e-9), (0.0, 4e-9))
    uu, vv = np.meshgrid(np.linspace(1e-9, 6e-9, 13), np.linspace(0, 4e-9, 7))
    S = s.evaluate(uu, vv)
    # exact to rounding: a few ulps of the domain size
    np.testing.assert_allclose(S[..., 0], uu, rtol=0, atol=6e-9 * 4e-16)
    np.testing.assert_allclose(S[..., 1], vv, rtol=0, atol=6e-9 * 4e-16)
    np.testing.assert_allclose(S[..., 2], 1.0, rtol=1e-15)


def test_copy_is_independent_and_reset_restores_exactly(wavy):
    c = wavy.copy()
    ctrl, rest, _, _ = c.kernel_arrays()
    ctrl[2:4, 2:4, 2] += 1e-9
    assert c.is_deformed and not wavy.is_deformed
    c.reset()
    assert not c.is_deformed
    np.testing.assert_array_equal(c.control_points, wavy.control_points)
    with pytest.raises(ValueError):
        c.control_points[0, 0, 0] = 1.0  # read-only view


def test_bad_input_is_refused_clearly():
    ku = clamped_uniform_knots(5, 0, 1)
    good = np.zeros((5, 5, 3))
    bad = good.copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(SurfaceError, match="1 non-finite"):
        BSplineSurface(bad, ku, ku)
    with pytest.raises(SurfaceError, match=r"shape \(nu, nv, 3\)"):
        BSplineSurface(np.zeros((5, 5)), ku, ku)
    with pytest.raises(SurfaceError, match="do not match"):
        BSplineSurface(np.zeros((6, 5, 3)), ku, ku)
    s = BSplineSurface(good, ku, ku)
    with pytest.raises(SurfaceError, match="finite"):
        s.evaluate(np.nan, 0.5)
    with pytest.raises(SurfaceError, match="derivatives must be"):
        s.evaluate(0.5, 0.5, derivatives=3)
