"""level(): exact planes and polynomials, robustness, row alignment, scars, masks, NaN, real scans."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from arsurf.errors import ScanError
from arsurf.scan.level import level
from arsurf.errors import LevelingError
from arsurf.scan.scan import Scan
from tests.support.real_scans import real_scan_path


def _grid(ny, nx, dx, dy):
    y, x = np.mgrid[0:ny, 0:nx].astype(float)
    return x * dx, y * dy


# ---------------------------------------------------------------------------------------------
# slow, obviously-right references


def _lstsq_background(z, valid, dx, dy, terms):
    """Background by numpy lstsq on a monomial design matrix in centred, scaled coordinates."""
    ny, nx = z.shape
    x, y = _grid(ny, nx, dx, dy)
    xs = (x - x.mean()) / max(np.ptp(x), dx)
    ys = (y - y.mean()) / max(np.ptp(y), dy)
    cols = [xs**i * ys**j for (i, j) in terms]
    A = np.stack([c[valid] for c in cols], axis=1)
    c, *_ = np.linalg.lstsq(A, z[valid], rcond=None)
    return sum(ci * col for ci, col in zip(c, cols))


def _row_offsets_reference(z, valid, stat):
    """Row offsets by a plain loop: stat of differences with the previous row, cumulated, mean 0."""
    ny = z.shape[0]
    steps = [0.0]
    for i in range(1, ny):
        both = valid[i] & valid[i - 1]
        steps.append(stat(z[i, both] - z[i - 1, both]))
    off = np.cumsum(steps)
    return off - off.mean()


def _trimmed(values, trim):
    s = np.sort(values)
    k = min(int(np.floor(trim * s.size)), (s.size - 1) // 2)
    return s[k : s.size - k].mean()


# ---------------------------------------------------------------------------------------------
# planes


@pytest.mark.parametrize("shape,dx,dy", [((40, 60), 2e-9, 3e-9), ((7, 5), 1e-7, 1e-7), ((64, 64), 0.5e-9, 0.5e-9)])
def test_plane_is_removed_exactly_and_coefficients_are_si(shape, dx, dy):
    x, y = _grid(*shape, dx, dy)
    plane = 7e-9 + 0.02 * x - 0.035 * y
    out = level(Scan(plane, dx=dx, dy=dy))
    assert np.abs(out.heights).max() <= 1e-12 * np.ptp(plane)
    c = out.history[-1]["coefficients"]
    assert c["offset"] == pytest.approx(7e-9, rel=1e-10)
    assert c["slope_x"] == pytest.approx(0.02, rel=1e-10)
    assert c["slope_y"] == pytest.approx(-0.035, rel=1e-10)


def _plane_with_outliers(rng, shape=(80, 100), dx=2e-9, dy=2e-9, frac=0.10):
    x, y = _grid(*shape, dx, dy)
    plane = -3e-9 + 0.01 * x + 0.025 * y
    z = plane.copy()
    out = rng.random(shape) < frac
    z[out] += rng.uniform(5e-9, 60e-9, out.sum())  # particles/spikes, all on one side
    return plane, z, out


def test_robust_plane_is_exact_with_ten_percent_outliers_where_least_squares_is_not(rng):
    plane, z, out = _plane_with_outliers(rng)
    scan = Scan(z, dx=2e-9, dy=2e-9)
    robust = level(scan, "plane-robust")
    ls = level(scan, "plane")
    tol = 1e-12 * np.ptp(plane)
    assert np.abs(robust.heights[~out]).max() <= tol
    np.testing.assert_allclose(robust.heights[out], (z - plane)[out], rtol=0, atol=tol)
    assert np.abs(ls.heights[~out]).max() > 1e3 * tol  # least squares is dragged up by them
    step = robust.history[-1]
    assert step["converged"] and step["outlier_pixels"] == int(out.sum())
    assert step["coefficients"]["slope_y"] == pytest.approx(0.025, rel=1e-10)


def test_robust_plane_with_noise_matches_least_squares_on_the_inliers(rng):
    plane, z, out = _plane_with_outliers(rng, shape=(120, 120))
    sigma = 0.3e-9
    z = z + rng.normal(0, sigma, z.shape)
    x, y = _grid(120, 120, 2e-9, 2e-9)
    ref = _lstsq_background(z, ~out, 2e-9, 2e-9, [(0, 0), (1, 0), (0, 1)])  # knows the outliers
    got = z - level(Scan(z, dx=2e-9, dy=2e-9), "plane-robust").heights
    # the robust fit does not know which pixels were outliers, yet lands within the noise of the
    # oracle fit: sigma sqrt(7/N) is the oracle's own standard error at a corner of the scan, and
    # Tukey's biweight loses only ~5 % efficiency (measured: 0.15-0.46 of it over 5 seeds)
    assert np.abs(got - ref).max() < 1.5 * sigma * np.sqrt(7 / (~out).sum())
    ls = z - level(Scan(z, dx=2e-9, dy=2e-9), "plane").heights
    assert np.abs(ls - ref).max() > 1e-9


def test_huber_loss_is_better_than_least_squares_but_tukey_is_best(rng):
    plane, z, out = _plane_with_outliers(rng)
    scan = Scan(z, dx=2e-9, dy=2e-9)
    err = {
        name: np.abs(level(scan, m, **kw).heights[~out]).max()
        for name, m, kw in [("ls", "plane", {}), ("huber", "plane-robust", {"loss": "huber"}),
                            ("tukey", "plane-robust", {})]
    }
    assert err["tukey"] < 1e-3 * err["huber"] < 1e-3 * err["ls"]


def test_robust_fit_that_runs_out_of_iterations_warns_and_says_so(rng):
    plane, z, out = _plane_with_outliers(rng)
    z = z + rng.normal(0, 0.3e-9, z.shape)
    with pytest.warns(RuntimeWarning, match="did not converge in 1 iterations per phase.*raise `max_iter`"):
        s = level(Scan(z, dx=2e-9, dy=2e-9), "plane-robust", max_iter=1)
    assert s.history[-1]["converged"] is False and s.history[-1]["iterations"] == 2


def test_single_scan_line_levels_to_a_line():
    x = np.arange(50) * 1e-9
    out = level(Scan((2e-9 + 0.3 * x)[None, :], dx=1e-9, dy=1e-9))
    assert np.abs(out.heights).max() < 1e-12 * 15e-9
    assert out.history[-1]["coefficients"]["slope_y"] == 0.0


# ---------------------------------------------------------------------------------------------
# polynomials


def test_polynomial_removes_a_known_cubic_and_recovers_its_si_coefficients():
    dx, dy = 3e-9, 2e-9
    x, y = _grid(50, 70, dx, dy)
    lx, ly = x.max(), y.max()
    true = {(0, 0): 4e-9, (1, 0): 0.01, (0, 1): -0.02, (2, 0): 2e-9 / lx**2, (1, 1): -3e-9 / (lx * ly),
            (0, 2): 1e-9 / ly**2, (3, 0): 5e-9 / lx**3, (2, 1): -2e-9 / (lx**2 * ly), (1, 2): 0.0,
            (0, 3): 1.5e-9 / ly**3}
    z = sum(c * x**i * y**j for (i, j), c in true.items())
    out = level(Scan(z, dx=dx, dy=dy), "polynomial", order=3)
    assert np.abs(out.heights).max() <= 1e-12 * np.ptp(z)
    got = {(t["x_power"], t["y_power"]): t["coefficient"] for t in out.history[-1]["coefficients"]}
    assert set(got) == set(true)
    for (i, j), c in true.items():  # each term's size over the scan agrees to 1e-9 of the range
        assert abs(got[(i, j)] - c) * lx**i * ly**j <= 1e-9 * np.ptp(z), (i, j)


def test_tensor_order_removes_x2_y_terms_that_total_degree_two_cannot():
    x, y = _grid(30, 40, 1e-9, 1e-9)
    z = 1e7 * x**2 * y / 40e-9  # degree 3 term x^2 y
    assert np.abs(level(Scan(z, dx=1e-9, dy=1e-9), "polynomial", order=(2, 1)).heights).max() < 1e-12 * np.ptp(z)
    assert np.abs(level(Scan(z, dx=1e-9, dy=1e-9), "polynomial", order=2).heights).max() > 1e-3 * np.ptp(z)


@pytest.mark.parametrize("order", [0, 1, 2, 4])
def test_polynomial_fit_equals_direct_lstsq_with_nan_and_mask(rng, order):
    ny, nx, dx, dy = 45, 55, 2e-9, 4e-9
    z = rng.normal(0, 1e-9, (ny, nx)) + 1e-9 * np.sin(np.arange(nx) / 7.0)[None, :]
    z[rng.random(z.shape) < 0.05] = np.nan
    mask = np.zeros(z.shape, bool)
    mask[10:20, 5:30] = True
    valid = np.isfinite(z) & ~mask
    terms = [(i, j) for j in range(order + 1) for i in range(order + 1) if i + j <= order]
    ref = z - _lstsq_background(z, valid, dx, dy, terms)
    got = level(Scan(z, dx=dx, dy=dy), "polynomial", order=order, mask=mask).heights
    assert np.array_equal(np.isnan(got), np.isnan(z))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.nanmax(np.abs(z)))


def test_robust_polynomial_ignores_particles_on_a_bowed_surface(rng):
    dx = 2e-9
    x, y = _grid(96, 96, dx, dx)
    bow = 20e-9 * ((x - 90e-9) ** 2 + (y - 100e-9) ** 2) / (100e-9) ** 2 + 0.01 * x
    z = bow.copy()
    particles = np.zeros(z.shape, bool)
    for cx, cy in rng.uniform(10e-9, 180e-9, (12, 2)):
        particles |= (x - cx) ** 2 + (y - cy) ** 2 < (8e-9) ** 2
    z[particles] += 15e-9
    out = level(Scan(z, dx=dx, dy=dx), "polynomial-robust", order=2)
    assert np.abs(out.heights[~particles]).max() < 1e-12 * np.ptp(z)
    assert np.abs(level(Scan(z, dx=dx, dy=dx), "polynomial", order=2).heights[~particles]).max() > 0.3e-9


# ---------------------------------------------------------------------------------------------
# masks and NaN


def test_masked_pixels_do_not_influence_the_fit(rng):
    x, y = _grid(60, 80, 1e-9, 1e-9)
    plane = 1e-9 + 0.05 * x - 0.02 * y
    z = plane.copy()
    mask = np.zeros(z.shape, bool)
    mask[20:35, 30:60] = True
    z[mask] = rng.uniform(-1e-6, 1e-6, mask.sum())  # garbage, far larger than the plane
    out = level(Scan(z, dx=1e-9, dy=1e-9), "plane", mask=mask)
    assert np.abs(out.heights[~mask]).max() <= 1e-12 * np.ptp(plane)
    np.testing.assert_allclose(out.heights[mask], (z - plane)[mask], rtol=0, atol=1e-12 * np.ptp(plane))
    assert out.history[-1]["masked_pixels"] == int(mask.sum())


@settings(max_examples=30, deadline=None)
@given(
    method=st.sampled_from(["plane", "polynomial", "rows-median", "rows-trimmed"]),
    seed=st.integers(0, 2**32 - 1),
    fill=st.floats(-1e-6, 1e-6),
)
def test_values_under_the_mask_never_change_the_unmasked_result(method, seed, fill):
    rng = np.random.default_rng(seed)
    z = rng.normal(0, 1e-9, (12, 15))
    mask = rng.random(z.shape) < 0.3
    mask[:, :3] = False  # every row keeps valid pixels shared with its neighbours
    z2 = z.copy()
    z2[mask] = fill
    a = level(Scan(z, dx=1e-9, dy=1e-9), method, mask=mask).heights
    b = level(Scan(z2, dx=1e-9, dy=1e-9), method, mask=mask).heights
    np.testing.assert_allclose(a[~mask], b[~mask], rtol=0, atol=1e-22)


def test_nan_pixels_are_ignored_by_the_fit_and_stay_nan(rng):
    x, y = _grid(50, 50, 1e-9, 1e-9)
    plane = 0.1 * x + 0.2 * y
    z = plane.copy()
    holes = rng.random(z.shape) < 0.2
    z[holes] = np.nan
    z[5, :] = np.nan  # a whole missing row
    for method in ("plane", "plane-robust", "polynomial"):
        out = level(Scan(z, dx=1e-9, dy=1e-9), method).heights
        assert np.array_equal(np.isnan(out), np.isnan(z))
        assert np.nanmax(np.abs(out)) <= 1e-12 * np.ptp(plane)


# ---------------------------------------------------------------------------------------------
# row alignment


def _row_jitter_surface(rng, ny=64, nx=100, particles=True):
    x = np.arange(nx) * 2e-9
    base = np.tile(3e-9 * np.sin(2 * np.pi * x / 60e-9), (ny, 1))  # varies along x only
    if particles:
        for _ in range(10):
            cy, cx = rng.integers(0, ny), rng.integers(0, nx)
            base[max(cy - 3, 0) : cy + 3, max(cx - 3, 0) : cx + 3] += 8e-9
    offsets = rng.normal(0, 4e-9, ny)
    return base, offsets, base + offsets[:, None]


@pytest.mark.parametrize("method", ["rows-median", "rows-trimmed"])
def test_row_alignment_recovers_the_known_offsets(rng, method):
    base, offsets, z = _row_jitter_surface(rng)
    out = level(Scan(z, dx=2e-9, dy=2e-9), method)
    rec = np.array(out.history[-1]["row_offsets"])
    np.testing.assert_allclose(rec, offsets - offsets.mean(), rtol=0, atol=1e-12 * np.ptp(z))
    np.testing.assert_allclose(out.heights, base + offsets.mean(), rtol=0, atol=1e-12 * np.ptp(z))


def test_row_alignment_with_noise_is_within_the_statistical_error(rng):
    base, offsets, z = _row_jitter_surface(rng, ny=80, nx=400)
    sigma = 0.5e-9
    z = z + rng.normal(0, sigma, z.shape)
    rec = np.array(level(Scan(z, dx=2e-9, dy=2e-9), "rows-median").history[-1]["row_offsets"])
    err = rec - (offsets - offsets.mean())
    # median of 400 differences of noise sqrt(2) sigma: sd ~ 1.25 sqrt(2) sigma / 20, then a random walk
    # over the rows; the offsets are 4 nm, the error must stay well below 1 nm
    assert np.abs(err).max() < 1.25 * np.sqrt(2) * sigma / 20 * np.sqrt(80) * 4


@pytest.mark.parametrize("method,stat", [("rows-median", np.median), ("rows-trimmed", lambda v: _trimmed(v, 0.25))])
def test_row_offsets_equal_a_plain_loop_with_nan_and_mask(rng, method, stat):
    z = rng.normal(0, 1e-9, (30, 41)) + rng.normal(0, 5e-9, 30)[:, None]
    z[rng.random(z.shape) < 0.1] = np.nan
    mask = rng.random(z.shape) < 0.1
    valid = np.isfinite(z) & ~mask
    got = np.array(level(Scan(z, dx=1e-9, dy=1e-9), method, mask=mask).history[-1]["row_offsets"])
    np.testing.assert_allclose(got, _row_offsets_reference(z, valid, stat), rtol=0, atol=1e-22)


def test_trim_zero_is_the_mean_of_the_differences(rng):
    z = rng.normal(0, 1e-9, (20, 30))
    got = np.array(level(Scan(z, dx=1e-9, dy=1e-9), "rows-trimmed", trim=0.0).history[-1]["row_offsets"])
    np.testing.assert_allclose(got, _row_offsets_reference(z, np.isfinite(z), np.mean), rtol=0, atol=1e-22)


def test_rows_without_shared_columns_are_tied_by_their_medians():
    z = np.zeros((4, 6))
    z[1] = 5e-9
    z[2] = 9e-9
    z[3] = 2e-9
    z[1, 3:] = np.nan
    z[2, :3] = np.nan  # rows 1 and 2 share no valid column
    out = level(Scan(z, dx=1e-9, dy=1e-9), "rows-median")
    assert np.nanmax(np.abs(out.heights - np.nanmean(out.heights))) < 1e-20
    z[2, :] = np.nan  # a missing row: stays NaN, rows 1 and 3 are compared directly
    out = level(Scan(z, dx=1e-9, dy=1e-9), "rows-median")
    assert np.isnan(out.heights[2]).all()
    assert np.nanmax(out.heights) - np.nanmin(out.heights) < 1e-20


# ---------------------------------------------------------------------------------------------
# scars


def _smooth_surface(rng, ny=80, nx=160, noise=0.05e-9):
    y, x = np.mgrid[0:ny, 0:nx].astype(float)
    z = 2e-9 * np.sin(2 * np.pi * x / 53.0) * np.cos(2 * np.pi * y / 41.0) + 1e-9 * np.sin(y / 9.0)
    return z + rng.normal(0, noise, z.shape)


def test_scar_removal_restores_planted_scars(rng):
    clean = _smooth_surface(rng)
    z = clean.copy()
    planted = np.zeros(z.shape, bool)
    for (r0, w, c0, length, h) in [(10, 1, 20, 40, 6e-9), (30, 2, 60, 30, -5e-9), (50, 3, 100, 50, 4e-9),
                                   (65, 1, 0, 25, -8e-9)]:
        z[r0 : r0 + w, c0 : c0 + length] += h
        planted[r0 : r0 + w, c0 : c0 + length] = True
    out = level(Scan(z, dx=1e-9, dy=1e-9), "scars")
    err = np.abs(out.heights - clean)
    # replaced by interpolation between the rows above and below: off by the surface's curvature
    # over <= 4 rows plus noise, far below the 4-8 nm scars
    assert err[planted].max() < 0.6e-9
    changed = out.heights != z
    assert changed[planted].mean() > 0.97
    assert not changed[~planted].any()
    step = out.history[-1]
    assert step["scars"] == 4 and step["scar_pixels"] == int(changed.sum())


def test_scar_removal_with_nan_holes_keeps_them(rng):
    clean = _smooth_surface(rng)
    z = clean.copy()
    z[30, 40:80] += 6e-9
    z[rng.random(z.shape) < 0.03] = np.nan
    out = level(Scan(z, dx=1e-9, dy=1e-9), "scars").heights
    assert np.array_equal(np.isnan(out), np.isnan(z))
    ok = np.isfinite(z[30, 40:80])
    assert np.abs(out[30, 40:80][ok] - clean[30, 40:80][ok]).max() < 0.6e-9


def test_scar_removal_leaves_a_clean_surface_untouched(rng):
    z = _smooth_surface(rng, noise=0.2e-9)
    out = level(Scan(z, dx=1e-9, dy=1e-9), "scars")
    assert np.array_equal(out.heights, z)
    assert out.history[-1]["scar_pixels"] == 0


def test_scar_removal_respects_the_mask_and_min_length(rng):
    clean = _smooth_surface(rng)
    z = clean.copy()
    z[20, 10:50] += 6e-9  # a scar, or a thin tube lying along x: protect it with the mask
    z[40, 70:75] += 6e-9  # five pixels: shorter than the default min_length=16
    mask = np.zeros(z.shape, bool)
    mask[19:22, 5:55] = True
    out = level(Scan(z, dx=1e-9, dy=1e-9), "scars", mask=mask)
    assert np.array_equal(out.heights, z)
    out = level(Scan(z, dx=1e-9, dy=1e-9), "scars", min_length=4)
    assert np.abs(out.heights[40, 70:75] - clean[40, 70:75]).max() < 0.6e-9


# ---------------------------------------------------------------------------------------------
# history and errors


def test_history_records_each_step_in_order(rng):
    base, offsets, z = _row_jitter_surface(rng)
    s = level(level(level(Scan(z, dx=2e-9, dy=2e-9), "rows-median"), "scars"), "plane")
    assert [h["method"] for h in s.history] == ["rows-median", "scars", "plane"]
    assert all(h["operation"] == "level" for h in s.history)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(method="cubic"), "unknown levelling method 'cubic'; use one of"),
        (dict(method="plane", order=2), "option `order` does not apply to method 'plane'"),
        (dict(method="rows-median", trim=0.1), "option `trim` does not apply.*'rows-trimmed'"),
        (dict(method="rows-trimmed", trim=0.5), r"`trim` must be in \[0, 0.5\) \(got 0.5\)"),
        (dict(method="polynomial", order=-1), r"`order` must be an integer >= 0 \(got -1\)"),
        (dict(method="polynomial", order=(1, 2, 3)), "pair"),
        (dict(method="plane-robust", loss="cauchy"), "`loss` must be 'tukey' or 'huber'"),
        (dict(method="plane-robust", tuning=-1.0), "tuning must be positive"),
        (dict(method="scars", threshold=2.0, threshold_low=3.0), "must not exceed `threshold`"),
        (dict(method="scars", max_width=0), r"`max_width` must be an integer >= 1 \(got 0\)"),
        (dict(mask=np.zeros((3, 3), bool)), r"`mask` must have the scan's shape \(10, 12\) \(got \(3, 3\)\)"),
        (dict(mask=np.full((10, 12), 0.5)), "`mask` must be boolean"),
        (dict(mask=np.ones((10, 12), bool)), "no valid pixel to level"),
    ],
)
def test_bad_requests_raise_clear_errors(kwargs, match):
    scan = Scan(np.zeros((10, 12)), dx=1e-9, dy=1e-9)
    with pytest.raises(LevelingError, match=match):
        level(scan, **kwargs)


def test_too_few_pixels_for_the_order_and_wrong_input_type():
    z = np.full((10, 12), np.nan)
    z[3, :] = 1e-9  # one valid row: a plane's y slope is undetermined
    with pytest.raises(LevelingError, match=r"do not determine a background with 3 terms \(rank 2\)"):
        level(Scan(z, dx=1e-9, dy=1e-9))
    with pytest.raises(LevelingError, match="needs an arsurf Scan"):
        level(np.zeros((4, 4)))
    assert issubclass(LevelingError, ScanError) and issubclass(LevelingError, ValueError)


# ---------------------------------------------------------------------------------------------
# real scans


@pytest.mark.realscan
def test_veeco_rows_median_and_scars_leave_a_granular_film_without_artefact_rows():
    from arsurf.scan.io import load_scan

    raw = load_scan(real_scan_path("Veeco_20160622.003"), "Height")
    assert np.ptp(raw.heights) > 150e-9  # SOURCES.md: 159.5 nm, dominated by bad lines
    rows = level(raw, "rows-median")
    p2p = np.ptp(rows.heights, axis=1)
    assert p2p.max() > 6 * np.median(p2p)  # the scar band (rows 29-31) survives row alignment
    clean = level(rows, "scars")
    h = clean.heights
    p2p = np.ptp(h, axis=1)
    assert np.median(p2p) < 10e-9  # grains: ~8 nm peak to peak along a row
    assert p2p.max() < 2.5 * np.median(p2p)  # no artefact row left
    assert np.ptp(h) < 25e-9  # from 159.5 nm
    lo, hi = np.percentile(h, [0.5, 99.5])
    assert hi - lo < 20e-9  # 17 nm: the "~10 nm" of SOURCES.md is the p-p of a row
    assert (h != rows.heights).mean() < 0.02  # scar removal touched < 2 % of the pixels


@pytest.mark.realscan
def test_jpk_bow_needs_a_polynomial_then_row_alignment():
    from arsurf.scan.io import load_scan

    raw = load_scan(real_scan_path("sample_0.jpk"), "height (retrace)")
    assert np.ptp(raw.heights) > 50e-9  # SOURCES.md: 56.65 nm, mostly bow
    plane = level(raw, "plane").heights
    cubic = level(raw, "polynomial", order=3)
    both = level(cubic, "rows-median").heights
    assert np.std(plane) > 8e-9  # a plane leaves the bow
    assert np.std(cubic.heights) < 2e-9
    assert np.std(both) < 1.2e-9 and np.ptp(both) < 14e-9  # ~3 nm features left


@pytest.mark.realscan
@pytest.mark.parametrize(
    "name", ["2018-02-09_1506_PH_dt20nmwindow1_Z_C.gsf", "AR_20211011.ibw", "Park_20210916_034.tiff",
             "STM_nanonis_generic_4_5.sxm"],
)
def test_scar_removal_leaves_real_scans_without_scars_untouched(name):
    from arsurf.scan.io import load_scan

    rows = level(load_scan(real_scan_path(name)), "rows-median")
    out = level(rows, "scars")
    assert out.history[-1]["scar_pixels"] == 0 and np.array_equal(out.heights, rows.heights)


@pytest.mark.realscan
def test_scar_removal_finds_the_two_bad_lines_of_the_pmma_wedge():
    from arsurf.scan.io import load_scan

    raw = load_scan(real_scan_path("2024-08-21_132732_PH_pmma_wedge_on_gold_thick_1600nm_Z_raw.gsf"))
    rows = level(raw, "rows-median")
    out = level(rows, "scars")
    changed = out.heights != rows.heights
    per_row = changed.sum(axis=1)
    assert out.history[-1]["scars"] == 2 and np.count_nonzero(per_row) == 2
    assert per_row[per_row > 0].min() > 100  # two long partial lines (of 400 px)


@pytest.mark.realscan
def test_thin_real_lines_along_x_are_kept_with_a_smaller_max_width():
    # the e-beam dose-test lines are ~3 rows thick and run along x: with the default
    # max_width=3 they look like scars; max_width=2 (or a mask) keeps them
    from arsurf.scan.io import load_scan

    name = "2022-04-28_1518_PH_trivial_dose1,1_FB_horizontal_interf_synchronize_nanoFTIR_Z.gsf"
    rows = level(load_scan(real_scan_path(name)), "rows-median")
    out = level(rows, "scars", max_width=2)
    assert out.history[-1]["scar_pixels"] == 0
    assert np.array_equal(np.isnan(out.heights), np.isnan(rows.heights))
