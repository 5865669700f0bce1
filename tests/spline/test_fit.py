"""fit_surface: exact reproduction of bicubics, interpolation, least squares, bad input."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.interpolate import RectBivariateSpline

from arsurf.errors import InvalidHeights, SurfaceError
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface


def _poly(coef, x, y):
    return sum(coef[i, j] * x**i * y**j for i in range(4) for j in range(4))


@settings(max_examples=25, deadline=None)
@given(st.integers(4, 12), st.integers(4, 12), st.floats(0.3e-9, 5e-9), st.floats(0.3e-9, 5e-9), st.integers(0, 2**31))
def test_interpolation_reproduces_any_bicubic_polynomial_everywhere(nx, ny, dx, dy, seed):
    rng = np.random.default_rng(seed)
    # coefficients scaled so every term is ~1 nm over the scan
    lx, ly = (nx - 1) * dx, (ny - 1) * dy
    coef = rng.normal(size=(4, 4)) * 1e-9 / (lx ** np.arange(4)[:, None] * ly ** np.arange(4)[None, :])
    y, x = np.mgrid[0:ny, 0:nx]
    scan = Scan(_poly(coef, x * dx, y * dy), dx=dx, dy=dy)
    s = fit_surface(scan)
    u = rng.uniform(0, lx, 50)
    v = rng.uniform(0, ly, 50)
    S, Su, Sv = s.evaluate(u, v, derivatives=1)
    np.testing.assert_allclose(S[:, 2], _poly(coef, u, v), rtol=0, atol=1e-9 * 1e-10)
    dpx = sum(i * coef[i, j] * u ** (i - 1) * v**j for i in range(1, 4) for j in range(4))
    np.testing.assert_allclose(Su[:, 2], dpx, rtol=0, atol=1e-9 / lx * 1e-9)
    np.testing.assert_allclose(S[:, 0], u, rtol=0, atol=lx * 1e-14)


def test_paraboloid_second_derivatives_are_exact():
    y, x = np.mgrid[0:9, 0:11] * 2e-9
    a = 1e7  # z = a (x^2 + y^2), curvature 2a
    s = fit_surface(Scan(a * (x**2 + y**2), dx=2e-9, dy=2e-9))
    _, _, _, Suu, Suv, Svv = s.evaluate(7.3e-9, 5.1e-9, derivatives=2)
    assert abs(Suu[2] - 2 * a) < 1e-6 * a and abs(Svv[2] - 2 * a) < 1e-6 * a and abs(Suv[2]) < 1e-6 * a


def test_interpolates_random_data_with_non_square_pixels(rng):
    z = rng.normal(size=(17, 23)) * 1e-9
    scan = Scan(z, dx=1.5e-9, dy=4e-9)
    s = fit_surface(scan)
    assert s.shape == (25, 19)
    xx, yy = np.meshgrid(scan.x, scan.y)
    np.testing.assert_allclose(s.evaluate(xx, yy)[..., 2], z, rtol=0, atol=1e-21)
    assert s.domain == ((0.0, 22 * 1.5e-9), (0.0, 16 * 4e-9))


def test_equals_scipy_not_a_knot_interpolant(rng):
    """The interpolant is unique in the not-a-knot space: scipy's FITPACK s=0 gives the same function."""
    z = rng.normal(size=(12, 15)) * 1e-9
    scan = Scan(z, dx=1e-9, dy=1e-9)
    ref = RectBivariateSpline(scan.y, scan.x, z, s=0)
    s = fit_surface(scan)
    u = rng.uniform(0, 14e-9, 200)
    v = rng.uniform(0, 11e-9, 200)
    np.testing.assert_allclose(s.evaluate(u, v)[:, 2], ref.ev(v, u), rtol=0, atol=1e-9 * 1e-9)


def test_least_squares_with_fewer_control_points_reproduces_cubics(rng):
    y, x = np.mgrid[0:40, 0:30] * 1e-9
    z = 1e-9 * ((x / 3e-8) ** 3 - 2 * (y / 4e-8) ** 2 + x * y / 1e-18 * 1e-9)
    s = fit_surface(Scan(z, dx=1e-9, dy=1e-9), control_shape=(8, 10))
    assert s.shape == (8, 10)
    np.testing.assert_allclose(s.evaluate(x, y)[..., 2], z, rtol=0, atol=1e-21)


def test_smoothing_penalty_keeps_planes_and_damps_noise(rng):
    y, x = np.mgrid[0:32, 0:32] * 1e-9
    plane = 0.1 * x - 0.2 * y
    s = fit_surface(Scan(plane, dx=1e-9, dy=1e-9), smoothing=10.0)
    np.testing.assert_allclose(s.evaluate(x, y)[..., 2], plane, rtol=0, atol=1e-20)
    noisy = Scan(plane + rng.normal(size=plane.shape) * 1e-9, dx=1e-9, dy=1e-9)
    resid = [np.std(fit_surface(noisy, smoothing=lam).evaluate(x, y)[..., 2] - plane) for lam in (0.0, 1.0, 100.0)]
    assert resid[0] > resid[1] > resid[2]


@pytest.mark.parametrize(
    "heights, kwargs, exc, match",
    [
        (np.zeros((3, 10)), {}, InvalidHeights, "at least 4x4"),
        (np.zeros((1, 10)), {}, InvalidHeights, "single scan line"),
        (np.where(np.eye(6) > 0, np.nan, 0.0), {}, InvalidHeights, "6 pixels are NaN.*inpaint"),
        (np.zeros((6, 6)), {"control_shape": (3, 6)}, SurfaceError, "control_shape"),
        (np.zeros((6, 6)), {"control_shape": (7, 6)}, SurfaceError, "control_shape"),
        (np.zeros((6, 6)), {"smoothing": -1.0}, SurfaceError, "smoothing"),
        (np.zeros((6, 6)), {"smoothing": np.nan}, SurfaceError, "smoothing"),
    ],
)
def test_bad_input(heights, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        fit_surface(Scan(heights, dx=1e-9, dy=1e-9), **kwargs)


def test_refuses_non_scan():
    with pytest.raises(SurfaceError, match="takes an arsurf.Scan"):
        fit_surface(np.zeros((5, 5)))
