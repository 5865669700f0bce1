"""Cubic basis kernels against the Cox-de Boor recursion; knots and Greville abscissae."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from arsurf.errors import SurfaceError
from arsurf.spline.basis import cubic_basis, find_span
from arsurf.spline.knots import check_clamped_uniform, clamped_uniform_knots, greville
from tests.support.reference import cox_de_boor, cox_de_boor_derivative

KNOTS = clamped_uniform_knots(9, 0.0, 3e-9)  # 6 spans of 0.5 nm


def _kernel_row(knots, u):
    i = find_span(knots, u)
    return i, np.array(cubic_basis(knots, i, u)).reshape(3, 4)


@pytest.mark.parametrize("u", [0.0, 1e-10, 0.5e-9, 0.73e-9, 1.5e-9, 2.999e-9, 3e-9])
def test_basis_matches_cox_de_boor_values_and_derivatives(u):
    i, b = _kernel_row(KNOTS, u)
    for order in range(3):
        ref = [cox_de_boor_derivative(KNOTS, k, 3, u, order) for k in range(i - 3, i + 1)]
        scale = (0.5e-9) ** order  # derivatives scale as 1/h^order
        np.testing.assert_allclose(b[order] * scale, np.array(ref) * scale, rtol=0, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1.0))
def test_partition_of_unity_and_nonnegativity(frac):
    u = frac * 3e-9
    _, b = _kernel_row(KNOTS, u)
    assert abs(b[0].sum() - 1.0) < 1e-14
    assert (b[0] >= -1e-16).all()
    # derivatives of a partition of unity sum to zero
    assert abs(b[1].sum()) * 0.5e-9 < 1e-12 and abs(b[2].sum()) * (0.5e-9) ** 2 < 1e-11


def test_all_basis_functions_sum_to_one_by_reference():
    for u in np.linspace(0, 3e-9, 37):
        assert abs(sum(cox_de_boor(KNOTS, k, 3, u) for k in range(9)) - 1.0) < 1e-14


def test_find_span_is_o1_lookup_and_clamped():
    n = 9
    for u, span in [(0.0, 3), (0.49e-9, 3), (0.5e-9, 4), (2.9e-9, n - 1), (3e-9, n - 1)]:
        assert find_span(KNOTS, u) == span
    assert find_span(KNOTS, -1.0) == 3 and find_span(KNOTS, 1.0) == n - 1


def test_knot_vector_shape_and_greville_identity():
    t = clamped_uniform_knots(7, 2.0, 6.0)
    np.testing.assert_array_equal(t, [2, 2, 2, 2, 3, 4, 5, 6, 6, 6, 6])
    g = greville(t)
    assert g[0] == 2.0 and g[-1] == 6.0 and np.all(np.diff(g) > 0)
    # linear precision: sum_i xi_i N_i(u) = u
    for u in np.linspace(2.0, 6.0, 41):
        assert abs(sum(g[k] * cox_de_boor(t, k, 3, u) for k in range(7)) - u) < 1e-13


def test_knot_errors_are_clear():
    with pytest.raises(SurfaceError, match="at least 4 control points"):
        clamped_uniform_knots(3, 0.0, 1.0)
    with pytest.raises(SurfaceError, match="a < b"):
        clamped_uniform_knots(5, 1.0, 1.0)
    with pytest.raises(SurfaceError, match="not a clamped uniform"):
        check_clamped_uniform(np.array([0, 0, 0, 0, 0.3, 1, 1, 1, 1.0]), "knots_u")


def test_the_height_slope_is_the_jet_s():
    from arsurf.scan import synthetic
    from arsurf.spline.basis import height_jet, height_slope
    from arsurf.spline.fit import fit_surface

    s = fit_surface(synthetic.rough(shape=(24, 24), pixel=1e-9, rms=1e-9, correlation_length=4e-9, seed=1))
    ctrl = np.array(s.rest_control_points, order="C")
    for u, v in ((0.0, 0.0), (3.3e-9, 17.2e-9), (11.0e-9, 11.0e-9), (23e-9, 5.5e-9)):  # ends and interior
        jet = height_jet(ctrl, s.knots_u, s.knots_v, u, v)
        assert np.allclose(height_slope(ctrl, s.knots_u, s.knots_v, u, v), jet[4:7], rtol=1e-12, atol=1e-25)
