"""The projection tests' surfaces and checks: hard scans (trench narrower than the tip, twin
ridges, oblique steps, roughness; 1 nm pixels), random query points, randomly perturbed nets, and
the comparison with the brute-force reference (:mod:`tests.support.reference`). Metres."""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from arsurf.scan.scan import Scan
from arsurf.spline.surface import BSplineSurface
from tests.support.reference import brute_force


H = 1e-9          # pixel = knot spacing of the test surfaces
TOL = 1e-12       # distance accuracy target, metres


def check_against(surface, points, ours, per_cell=8, k=8):
    """Our answers are never farther than the brute force (no wrong basin) and agree with it to
    TOL; returns (max |error| where both found the same point (within 10 pm), count where ours
    is lower by more than TOL, count of ties: different points within TOL of each other)."""
    ru, rv, rd, nearest = brute_force(surface, points, per_cell, k)
    d = np.abs(ours.distance)
    assert np.all(d <= nearest + TOL), "a dense sample is closer than our answer"
    worse = d > rd + TOL
    assert not worse.any(), (
        f"{worse.sum()} wrong-basin answers, e.g. C={points[worse][0]} ours={d[worse][0]} ref={rd[worse][0]}"
    )
    # our point is on the surface, at the distance reported
    s = surface.evaluate(ours.uv[:, 0], ours.uv[:, 1])
    np.testing.assert_allclose(s, ours.point, rtol=0, atol=1e-20)
    np.testing.assert_allclose(np.linalg.norm(points - s, axis=1), d, rtol=1e-14, atol=1e-22)
    same_point = np.linalg.norm(s - surface.evaluate(ru, rv), axis=1) < 1e-11
    ties = ~same_point & (np.abs(d - rd) <= TOL)
    return (float(np.max(np.abs(d - rd)[same_point], initial=0.0)), int(np.sum(d < rd - TOL)),
            int(ties.sum()))


# --------------------------------------------------------------------------------------------
# test surfaces (1 nm pixels, heights in nm)
def grid(n=40):
    y, x = np.mgrid[0:n, 0:n] * H
    return x, y


def trench_scan(n=40):
    """A 5 nm wide, 6 nm deep trench along y: narrower than a 10 nm tip."""
    x, y = grid(n)
    return Scan(np.where(np.abs(x - 20e-9) < 2.6e-9, -6e-9, 0.0) + 0.0 * y, H, H)


def ridges_scan(n=40):
    """Two equal Gaussian ridges along y, 12 nm apart."""
    x, y = grid(n)
    return Scan(4e-9 * (np.exp(-((x - 14e-9) / 2.5e-9) ** 2) + np.exp(-((x - 26e-9) / 2.5e-9) ** 2)) + 0.0 * y, H, H)


def steps_scan(n=40):
    """Oblique 2 nm terraces with one-pixel steps (the interpolating spline rings at each step)."""
    x, y = grid(n)
    return Scan(2e-9 * np.floor((x + 0.6 * y) / 10e-9), H, H)


def rough_scan(n=40, seed=5):
    """Gaussian random roughness, 6 nm amplitude, 1.5 px correlation."""
    z = gaussian_filter(np.random.default_rng(seed).normal(size=(n, n)), 1.5)
    return Scan(z * 6e-9 / z.std() * 0.5, H, H)


SCANS = {"trench": trench_scan, "ridges": ridges_scan, "steps": steps_scan, "rough": rough_scan}


def queries(surface, rng, n, margin=4e-9, above=15e-9, below=1e-9):
    """Random points over the domain (and a margin beyond its edges), from below the lowest
    point of the surface to ``above`` over its highest, denser near the surface."""
    (u0, u1), (v0, v1) = surface.domain
    z = surface.control_points[..., 2]
    lo, hi = z.min() - below, z.max() + above
    return np.column_stack([rng.uniform(u0 - margin, u1 + margin, n), rng.uniform(v0 - margin, v1 + margin, n),
                            lo + (hi - lo) * rng.uniform(0, 1, n) ** 2])


# --------------------------------------------------------------------------------------------


def perturbed(surface, rng, lateral=0.25e-9, vertical=0.5e-9):
    """A copy whose control net is moved randomly in x, y and z: no longer a height field."""
    ctrl = surface.control_points.copy()
    ctrl += rng.normal(size=ctrl.shape) * [lateral, lateral, vertical]
    return BSplineSurface(ctrl, surface.knots_u, surface.knots_v)
