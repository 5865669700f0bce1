"""Accuracy sweep of the closest point: >= 100,000 random queries (fixed seed) on hard surfaces.

Surfaces: a trench narrower than the tip, twin ridges, oblique steps (the interpolating spline
rings at each step), Gaussian roughness, the same nets perturbed in x, y and z (deformed: no
longer height fields), and crops of real scans from ../shared/scans-real. Queries cover the
domain and a margin beyond its edges and corners, from below the surface to far above it.

For every query: our distance is never larger than the brute force's (dense sampling + Newton,
tests/contact/test_projection.py) by more than 1e-12 m (a "wrong basin"), agrees with it to 1e-12 m
where both found the same minimum, is never larger than the nearest dense sample, and our point
is on the surface at the distance reported. Warm-started chains (random walks, the candidate
cache in use) must give the cold answers.

Run ``pytest tests/contact/test_projection_sweep.py -s`` to print the per-surface figures (~15 s).
"""
from __future__ import annotations

import numpy as np
import pytest
from tests.support.reference import DenseSampling
from tests.support.projection_surfaces import (
    SCANS, TOL, check_against, perturbed, queries, ridges_scan, rough_scan,
)

from arsurf.contact.projection import project_many
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface

N_PER_SURFACE = 12_000
SEED = 20261122

REAL = {  # file, crop origin (iy, ix) of a 40 x 40 window
    "Veeco_20160622.003": (100, 180),
    "sample_0.jpk": (60, 90),
    "AR_20211011.ibw": (40, 40),
}


def _real_scan(name):
    from tests.support.real_scans import real_scan_path

    from arsurf.scan.io import load_scan

    scan = load_scan(real_scan_path(name))
    iy, ix = REAL[name]
    z = np.asarray(scan.heights[iy:iy + 40, ix:ix + 40], dtype=float)
    assert np.isfinite(z).all()
    return Scan(z - np.median(z), scan.dx, scan.dy)


def _surfaces():
    rng = np.random.default_rng(SEED)
    out = {name: fit_surface(make()) for name, make in SCANS.items()}
    out["deformed-ridges"] = perturbed(fit_surface(ridges_scan()), rng, 0.2e-9, 0.4e-9)
    out["deformed-rough"] = perturbed(fit_surface(rough_scan(seed=11)), rng, 0.25e-9, 0.5e-9)
    return out


def _sweep(name, surface, rng, scale):
    pts = queries(surface, rng, N_PER_SURFACE, margin=4 * scale, above=15 * scale, below=scale)
    res = project_many(surface, pts)
    assert res.distance.shape == (len(pts),) and np.isfinite(res.distance).all(), f"{name}: unanswered queries"
    err, lower, ties = check_against(surface, pts, res)
    assert err <= TOL
    print(f"\n{name:>18}: {N_PER_SURFACE} queries, wrong basins 0, max |d - d_ref| (same point) {err:.1e} m, "
          f"ties (another point within 1e-12 m) {ties}, ours lower than the reference {lower}, "
          f"mean cells {res.cells.mean():.1f}, "
          f"mean Newton iterations {res.iterations.mean():.1f}, on boundary {res.on_boundary.mean():.2f}")


@pytest.mark.slow
def test_sweep_synthetic_and_deformed():
    rng = np.random.default_rng(SEED)
    for name, s in _surfaces().items():
        _sweep(name, s, rng, 1e-9)


@pytest.mark.realscan
@pytest.mark.parametrize("name", sorted(REAL))
def test_sweep_real_scans(name):
    scan = _real_scan(name)
    surface = fit_surface(scan)
    _sweep(name, surface, np.random.default_rng(SEED + len(name)), max(scan.dx, scan.dy))


def test_warm_chains_equal_cold_answers():
    """Random walks (0.2 nm steps) warm-started from the previous answer, the candidate cache in
    use, on every synthetic and deformed surface."""
    rng = np.random.default_rng(SEED + 1)
    for name, s in _surfaces().items():
        (u0, u1), (v0, v1) = s.domain
        walk = np.cumsum(rng.normal(scale=0.2e-9, size=(4000, 3)), axis=0)
        pts = np.column_stack([u0 + np.mod(walk[:, 0] + 20e-9, u1 - u0 + 6e-9) - 3e-9,
                               v0 + np.mod(walk[:, 1] + 20e-9, v1 - v0 + 6e-9) - 3e-9,
                               s.control_points[..., 2].max() + np.abs(np.mod(walk[:, 2], 20e-9) - 10e-9) - 6e-9])
        cold = project_many(s, pts)
        warm = project_many(s, pts, chain=True)
        diff = np.abs(np.abs(warm.distance) - np.abs(cold.distance))
        assert diff.max() <= TOL, name
        # and both agree with the dense samples' bound
        nearest = DenseSampling(s, 4).nearest(pts)[0]
        assert np.all(np.abs(warm.distance) <= nearest + TOL)
