"""smooth(): analytic Gaussian response, per-axis widths in metres, NaN holes, edges, errors."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from arsurf.errors import ScanError
from arsurf.scan.level import level
from arsurf.scan.scan import Scan
from arsurf.scan.smooth import smooth
from arsurf.errors import SmoothingError
from tests.support.real_scans import real_scan_path


def _attenuation(sigma, wavelength):
    return np.exp(-2 * np.pi**2 * sigma**2 / wavelength**2)


def _reference(z, sigma_px, truncate=4.0):
    """Normalised convolution by explicit sums over the kernel offsets, edges mirrored (d c b a | a b c d)."""
    ny, nx = z.shape
    valid = np.isfinite(z)
    kernels = []
    for s in sigma_px:  # (y, x)
        r = int(truncate * s + 0.5)
        k = np.exp(-0.5 * (np.arange(-r, r + 1) / s) ** 2) if s > 0 else np.ones(1)
        kernels.append(k / k.sum())
    ky, kx = kernels
    ry, rx = len(ky) // 2, len(kx) // 2

    def mirror(i, n):
        i = np.mod(i, 2 * n)
        return np.where(i < n, i, 2 * n - 1 - i)

    num = np.zeros(z.shape)
    den = np.zeros(z.shape)
    zz = np.where(valid, z, 0.0)
    vv = valid.astype(float)
    iy = np.arange(ny)[:, None]
    ix = np.arange(nx)[None, :]
    for a in range(-ry, ry + 1):
        for b in range(-rx, rx + 1):
            w = ky[a + ry] * kx[b + rx]
            src = (mirror(iy + a, ny), mirror(ix + b, nx))
            num += w * zz[src]
            den += w * vv[src]
    return num / den


# ---------------------------------------------------------------------------------------------
# analytic response


@pytest.mark.parametrize("sigma_px,period_px", [(1.5, 16), (2.0, 12), (3.0, 40), (6.0, 64)])
def test_sinusoid_is_attenuated_by_the_gaussian_transfer_function(sigma_px, period_px):
    dx = 2e-9
    nx = 4 * period_px  # a multiple of half a period: the mirrored edges continue the cosine exactly
    x = np.arange(nx) * dx
    L = period_px * dx
    z = np.tile(3e-9 * np.cos(2 * np.pi * (x + 0.5 * dx) / L), (5, 1))
    out = smooth(Scan(z, dx=dx, dy=dx), sigma_px * dx, truncate=8.0).heights
    np.testing.assert_allclose(out, _attenuation(sigma_px * dx, L) * z, rtol=0, atol=1e-12 * 3e-9)
    # the default 4-sigma kernel is within 1e-4 of the analytic response
    out4 = smooth(Scan(z, dx=dx, dy=dx), sigma_px * dx).heights
    np.testing.assert_allclose(out4, _attenuation(sigma_px * dx, L) * z, rtol=0, atol=1e-4 * 3e-9)


def test_sigma_is_in_metres_per_axis_for_non_square_pixels():
    dx, dy = 2e-9, 5e-9
    ny, nx = 48, 120
    x, y = np.arange(nx) * dx, np.arange(ny) * dy
    Lx, Ly = 40e-9, 120e-9  # 20 px and 24 px: ny, nx are multiples of half periods
    wave_x = np.tile(np.cos(2 * np.pi * (x + dx / 2) / Lx), (ny, 1)) * 1e-9
    wave_y = np.tile(np.cos(2 * np.pi * (y + dy / 2) / Ly)[:, None], (1, nx)) * 1e-9
    sigma = 8e-9  # 4 px along x, 1.6 px along y: the same physical width
    for wave, L in ((wave_x, Lx), (wave_y, Ly)):
        out = smooth(Scan(wave, dx=dx, dy=dy), sigma, truncate=8.0).heights
        np.testing.assert_allclose(out, _attenuation(sigma, L) * wave, rtol=0, atol=1e-21)
    both = wave_x * wave_y / 1e-9
    sx, sy = 6e-9, 15e-9
    out = smooth(Scan(both, dx=dx, dy=dy), (sx, sy), truncate=8.0)
    expected = _attenuation(sx, Lx) * _attenuation(sy, Ly) * both
    np.testing.assert_allclose(out.heights, expected, rtol=0, atol=1e-21)
    step = out.history[-1]
    assert step["sigma_x"] == sx and step["sigma_y"] == sy and np.allclose(step["sigma_px"], [3.0, 3.0], rtol=1e-15)


@pytest.mark.parametrize("sigma_px", [0.7, 2.5, 9.0, 30.0])
def test_heights_sum_is_conserved(rng, sigma_px):
    z = rng.normal(0, 1e-9, (37, 41)) + 5e-9
    out = smooth(Scan(z, dx=1e-9, dy=1e-9), sigma_px * 1e-9).heights
    assert out.sum() == pytest.approx(z.sum(), rel=1e-12)


def test_matches_the_explicit_reference_with_and_without_holes(rng):
    z = rng.normal(0, 1e-9, (30, 34))
    dx, dy = 1e-9, 2.5e-9
    sigma = (2.2e-9, 3.0e-9)
    got = smooth(Scan(z, dx=dx, dy=dy), sigma).heights
    np.testing.assert_allclose(got, _reference(z, (3.0e-9 / dy, 2.2e-9 / dx)), rtol=0, atol=1e-22)
    z[rng.random(z.shape) < 0.15] = np.nan
    z[10:14, 12:20] = np.nan
    got = smooth(Scan(z, dx=dx, dy=dy), sigma).heights
    ref = _reference(z, (3.0e-9 / dy, 2.2e-9 / dx))
    ok = np.isfinite(z)
    np.testing.assert_allclose(got[ok], ref[ok], rtol=0, atol=1e-22)


# ---------------------------------------------------------------------------------------------
# NaN holes


def test_holes_stay_nan_and_do_not_spread_or_bias(rng):
    ny, nx = 60, 60
    z = np.full((ny, nx), 4e-9)
    z[20:28, 30:36] = np.nan
    z[rng.random(z.shape) < 0.05] = np.nan
    out = smooth(Scan(z, dx=1e-9, dy=1e-9), 3e-9).heights
    assert np.array_equal(np.isnan(out), np.isnan(z))
    np.testing.assert_allclose(out[np.isfinite(out)], 4e-9, rtol=1e-13)  # a constant stays constant
    filled = smooth(Scan(z, dx=1e-9, dy=1e-9), 3e-9, fill_holes=True)
    assert filled.nan_count == 0
    np.testing.assert_allclose(filled.heights, 4e-9, rtol=1e-13)


def test_pixels_far_from_holes_are_unaffected(rng):
    z = rng.normal(0, 1e-9, (64, 64))
    holed = z.copy()
    holed[30:34, 30:34] = np.nan
    sigma_px = 2.0
    a = smooth(Scan(z, dx=1e-9, dy=1e-9), sigma_px * 1e-9).heights
    b = smooth(Scan(holed, dx=1e-9, dy=1e-9), sigma_px * 1e-9).heights
    far = np.ones(z.shape, bool)
    r = int(4 * sigma_px + 0.5)
    far[30 - r : 34 + r, 30 - r : 34 + r] = False
    np.testing.assert_allclose(b[far], a[far], rtol=0, atol=1e-22)
    assert np.isfinite(b[~far & np.isfinite(holed)]).all()


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    sigma_px=st.floats(0.3, 6.0),
    hole_fraction=st.floats(0.0, 0.6),
    shape=st.tuples(st.integers(1, 20), st.integers(1, 20)),
)
def test_output_stays_within_the_input_range_and_keeps_its_holes(seed, sigma_px, hole_fraction, shape):
    assume(sigma_px <= max(shape))  # wider kernels are refused (tested below)
    rng = np.random.default_rng(seed)
    z = rng.normal(0, 1e-9, shape)
    z[rng.random(shape) < hole_fraction] = np.nan
    out = smooth(Scan(z, dx=1e-9, dy=2e-9), sigma_px * 1e-9).heights
    assert np.array_equal(np.isnan(out), np.isnan(z))
    if np.isfinite(z).any():  # a positive kernel: a weighted mean of the valid pixels
        tol = 1e-12 * np.nanmax(np.abs(z))
        assert np.nanmin(out) >= np.nanmin(z) - tol and np.nanmax(out) <= np.nanmax(z) + tol


def test_single_scan_line_is_smoothed_along_x_only():
    from scipy.ndimage import gaussian_filter1d

    z = np.sin(np.arange(80) / 5.0)[None, :] * 1e-9
    out = smooth(Scan(z, dx=1e-9, dy=1e-9), 2e-9).heights
    np.testing.assert_allclose(out[0], gaussian_filter1d(z[0], 2.0, mode="reflect"), rtol=0, atol=1e-24)


# ---------------------------------------------------------------------------------------------
# errors and history


@pytest.mark.parametrize(
    "sigma,match",
    [
        (-2e-9, r"`sigma` must be positive \(got -2e-09 m\); it is the Gaussian width in metres"),
        (0.0, r"`sigma` must be positive \(got 0.0 m\)"),
        (float("nan"), r"`sigma` must be positive \(got nan m\)"),
        (float("inf"), r"`sigma` must be positive \(got inf m\)"),
        ((1e-9, -1e-9), r"got -1e-09 m"),
        ((1e-9, 2e-9, 3e-9), r"one width or a pair \(sigma_x, sigma_y\).*3 values"),
        ("2nm", "must be a number or a pair"),
        (2.0, r"`sigma` along x is 2 m = 2e\+09 pixels, wider than the scan \(16 pixels\); sigma is in metres"),
        ((1e-9, 17e-9), r"`sigma` along y is 1.7e-08 m = 17 pixels, wider than the scan \(16 pixels\)"),
    ],
)
def test_bad_sigma_raises_a_clear_error(sigma, match):
    with pytest.raises(SmoothingError, match=match):
        smooth(Scan(np.zeros((8, 16)), dx=1e-9, dy=1e-9), sigma)


def test_other_errors_and_history():
    scan = Scan(np.zeros((8, 16)), dx=1e-9, dy=1e-9)
    with pytest.raises(SmoothingError, match=r"`truncate` must be positive \(got 0\)"):
        smooth(scan, 1e-9, truncate=0)
    with pytest.raises(SmoothingError, match="needs an arsurf Scan"):
        smooth(np.zeros((8, 16)), 1e-9)
    assert issubclass(SmoothingError, ScanError) and issubclass(SmoothingError, ValueError)
    out = smooth(level(scan, "plane"), 1e-9)
    assert [h["operation"] for h in out.history] == ["level", "smooth"]
    assert out.history[-1]["edges"] == "reflect" and scan.history == []


# ---------------------------------------------------------------------------------------------
# real scans


@pytest.mark.realscan
def test_smoothing_a_levelled_real_scan_removes_pixel_noise_but_keeps_the_grains():
    from arsurf.scan.io import load_scan

    scan = level(level(load_scan(real_scan_path("Veeco_20160622.003"), "Height"), "rows-median"), "scars")
    out = smooth(scan, 2 * scan.dx)  # ~7 nm, well below the ~50 nm grains

    def lap_rms(h):  # pixel-scale roughness: rms of the discrete Laplacian
        return np.std(h[2:, 1:-1] + h[:-2, 1:-1] + h[1:-1, 2:] + h[1:-1, :-2] - 4 * h[1:-1, 1:-1])

    assert lap_rms(out.heights) < 0.3 * lap_rms(scan.heights)
    assert np.std(out.heights) > 0.9 * np.std(scan.heights)  # the grain relief survives
    assert out.heights.sum() == pytest.approx(scan.heights.sum(), rel=1e-9, abs=1e-9 * np.abs(scan.heights).sum())
