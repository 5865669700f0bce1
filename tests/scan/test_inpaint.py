"""inpaint(): harmonic filling of NaN/masked pixels, against exact harmonics and a slow reference."""
from __future__ import annotations

import numpy as np
import pytest
from tests.support.real_scans import real_scan_path
from hypothesis import given, settings
from hypothesis import strategies as st

from arsurf.errors import InvalidHeights
from arsurf.scan.inpaint import dropout_mask, inpaint, require_finite
from arsurf.scan.scan import Scan


def gauss_seidel_reference(h: np.ndarray, holes: np.ndarray, dx: float, dy: float, sweeps=20000, tol=1e-15):
    """Slow, obviously right: Gauss-Seidel on the 5-point stencil with Neumann image borders."""
    z = np.where(holes, np.nanmean(h[~holes]), h)
    ny, nx = h.shape
    wx, wy = 1 / dx**2, 1 / dy**2
    pts = list(zip(*np.nonzero(holes)))
    for _ in range(sweeps):
        change = 0.0
        for iy, ix in pts:
            num = den = 0.0
            for jy, jx, w in ((iy, ix - 1, wx), (iy, ix + 1, wx), (iy - 1, ix, wy), (iy + 1, ix, wy)):
                if 0 <= jy < ny and 0 <= jx < nx:
                    num += w * z[jy, jx]
                    den += w
            new = num / den
            change = max(change, abs(new - z[iy, ix]))
            z[iy, ix] = new
        if change < tol * np.abs(z).max():
            break
    return z


def grid(ny, nx, dx, dy):
    y, x = np.mgrid[0:ny, 0:nx]
    return x * dx, y * dy


@pytest.mark.parametrize("dx, dy", [(1e-9, 1e-9), (2e-9, 5e-9)])
def test_quadratic_harmonic_is_exact_in_interior_holes(dx, dy, rng):
    x, y = grid(20, 24, dx, dy)
    z = (x**2 - y**2) * 1e9 + 3e-3 * x - 1e-3 * y + 1e-8  # harmonic; the 5-point stencil is exact on it
    holes = np.zeros_like(z, dtype=bool)
    holes[3:17, 4:20] = rng.random((14, 16)) < 0.6
    h = z.copy()
    h[holes] = np.nan
    out = inpaint(Scan(h, dx=dx, dy=dy))
    np.testing.assert_allclose(out.heights, z, rtol=0, atol=1e-12 * np.abs(z).max())
    assert out.history[-1]["filled"] == int(holes.sum()) and out.metadata["nan_count"] == 0


def test_matches_gauss_seidel_with_border_holes_and_non_square_pixels(rng):
    h = rng.normal(0, 1e-9, (9, 11)) + np.linspace(0, 5e-9, 11)
    holes = rng.random(h.shape) < 0.3
    holes[0, :4] = True  # touching the border: zero-flux boundary
    h[holes] = np.nan
    dx, dy = 1e-9, 3e-9
    ref = gauss_seidel_reference(h, holes, dx, dy)
    out = inpaint(Scan(h, dx=dx, dy=dy))
    np.testing.assert_allclose(out.heights, ref, rtol=0, atol=1e-18)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), ny=st.integers(2, 8), nx=st.integers(2, 8))
def test_filled_values_obey_max_principle(seed, ny, nx):
    rng = np.random.default_rng(seed)
    h = rng.normal(0, 1e-9, (ny, nx))
    holes = rng.random((ny, nx)) < 0.5
    holes.flat[rng.integers(ny * nx)] = False  # keep one known pixel
    known = h[~holes]
    h[holes] = np.nan
    out = inpaint(Scan(h, dx=1e-9, dy=2e-9)).heights
    if not holes.any():
        np.testing.assert_array_equal(out, h)
        return
    # a discrete harmonic function takes its extremes on the known pixels; known pixels unchanged
    assert out[holes].min() >= known.min() - 1e-21 and out[holes].max() <= known.max() + 1e-21
    np.testing.assert_array_equal(out[~holes], h[~holes])


def test_mask_replaces_finite_pixels_and_history_records_it(rng):
    x, y = grid(6, 7, 1e-9, 1e-9)
    z = 2e-3 * x + 1e-3 * y + 5e-8  # a plane (away from 0: |z| < 1e-12 would be a dropout)
    h = z.copy()
    h[2, 3] = 1e-19  # a dropout
    h[4, 1] = np.nan
    s = Scan(h, dx=1e-9, dy=1e-9, metadata={"history": [{"step": "load"}]})
    m = dropout_mask(s)
    assert m.sum() == 1 and m[2, 3]
    out = inpaint(s, mask=m)
    np.testing.assert_allclose(out.heights, z, atol=1e-20)
    step = out.history[-1]
    assert out.history[0] == {"step": "load"}
    assert (step["step"], step["nan_filled"], step["masked_filled"]) == ("inpaint", 1, 1)
    assert s.heights[2, 3] == 1e-19  # the input scan is untouched


def test_errors():
    s = Scan(np.full((3, 3), np.nan), dx=1e-9, dy=1e-9)
    with pytest.raises(InvalidHeights, match="nothing to interpolate from"):
        inpaint(s)
    t = Scan(np.zeros((3, 3)), dx=1e-9, dy=1e-9)
    with pytest.raises(InvalidHeights, match=r"mask must have the scan's shape \(3, 3\)"):
        inpaint(t, mask=np.zeros((2, 3), bool))
    with pytest.raises(InvalidHeights, match="positive length"):
        dropout_mask(t, threshold=-1.0)
    with pytest.raises(InvalidHeights, match=r"fitting needs every pixel.*1 missing.*arsurf.inpaint"):
        require_finite(Scan(np.array([[0.0, np.nan]]), dx=1e-9, dy=1e-9), "fitting")
    require_finite(t, "fitting")
    assert inpaint(t).history[-1]["filled"] == 0


@pytest.mark.realscan
def test_aborted_nanoftir_scan_is_filled():
    from arsurf.scan.io import load_scan

    s = load_scan(real_scan_path(
        "2022-04-28_1518_PH_trivial_dose1,1_FB_horizontal_interf_synchronize_nanoFTIR_Z.gsf"))
    m = dropout_mask(s)
    assert int(m.sum()) == 1584  # SOURCES.md: "about 1584 dropout pixels with |z| < 1e-12 m"
    # file rows 53-84 hold them: after the flip (row 0 = bottom) they are our rows 0-31
    rows = np.nonzero(m.any(axis=1))[0]
    assert rows.min() >= 0 and rows.max() <= 84 - 53
    out = inpaint(s, mask=m)
    assert np.isfinite(out.heights).all()
    finite = s.heights[np.isfinite(s.heights) & ~m]
    assert out.heights.min() >= finite.min() and out.heights.max() <= finite.max()
    assert out.history[-1]["nan_filled"] == 311 and out.history[-1]["masked_filled"] == 1584
