"""The direction a contact pushes: the resultant over its zone (arsurf.contact.zone_normal)."""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.contact.zone_normal import ZONE_FADE, ZONE_HALF_WIDTH, ZONE_NODES, zone_normal_kernel
from arsurf.spline.surface import BSplineSurface

R = 5e-9
FLOOR = -0.5e-9  # the interaction floor (a depth, m)


def _surface(heights, size=40e-9):
    return BSplineSurface.from_heights(heights, (0.0, size), (0.0, size))


def _unit_normal(s, u, v):
    _, su, sv = s.evaluate(u, v, 1)
    n = np.cross(su, sv)
    return n / np.linalg.norm(n)


def _zone_normal(s, centre, u, v, depth, zone, normal=None):
    ctrl, _, ku, kv = s.kernel_arrays()
    n = _unit_normal(s, u, v) if normal is None else np.array(normal, dtype=float)
    zone_normal_kernel(ctrl, ku, kv, np.zeros((6, 3)), *centre, R, FLOOR, depth, zone, u, v, n)
    return n


@pytest.mark.parametrize("tilt", [0.0, 0.3, 1.0])
def test_on_a_plane_the_zone_pushes_along_the_plane_s_normal(tilt):
    """Every sample of a plane has the plane's normal: whatever the weights, the resultant is it."""
    x = np.linspace(0.0, 40e-9, 41)
    s = _surface(tilt * x[:, None] + 0.2 * x[None, :])
    n = _unit_normal(s, 20e-9, 20e-9)
    assert 0.2 * n[0] == pytest.approx(tilt * n[1], abs=1e-12)                  # a plane's: its slopes' ratio
    corner = _unit_normal(s, 20e-9 + ZONE_HALF_WIDTH * R, 20e-9 - ZONE_HALF_WIDTH * R)
    np.testing.assert_allclose(corner, n, atol=1e-12)                          # one normal over the stencil
    foot = s.evaluate(20e-9, 20e-9)
    depth = 1e-9
    got = _zone_normal(s, foot + (R - depth) * n, 20e-9, 20e-9, depth, zone=3e-9)
    np.testing.assert_allclose(got, n, atol=1e-12)


def test_on_a_symmetric_bump_the_zone_pushes_along_its_axis_and_off_it_turns_less_than_the_point():
    """A tip centred over a round bump is pushed straight up (the stencil is symmetric about the
    point). Beside the top, the resultant over a zone of the curved cap is the mean of normals
    turned less than the point's own and more on its far side: it lies between the point's normal
    and the axis."""
    x = np.linspace(0.0, 40e-9, 81)
    s = _surface(6e-9 * np.exp(-((x[:, None] - 20e-9) ** 2 + (x[None, :] - 20e-9) ** 2) / (2 * (5e-9) ** 2)))
    top = s.evaluate(20e-9, 20e-9)
    got = _zone_normal(s, top + np.array([0.0, 0.0, R - 1e-9]), 20e-9, 20e-9, 1e-9, zone=3e-9)
    np.testing.assert_allclose(got, [0.0, 0.0, 1.0], atol=1e-12)
    u = 23e-9                                             # on the flank, where the bump turns away
    n = _unit_normal(s, u, 20e-9)
    centre = s.evaluate(u, 20e-9) + (R - 1e-9) * n
    got = _zone_normal(s, centre, u, 20e-9, 1e-9, zone=3e-9)
    assert got[1] == pytest.approx(0.0, abs=1e-12)        # symmetric in y
    assert 0.0 < got[0] < n[0]                            # turned between the axis and the point's normal


def test_a_zone_finer_than_the_stencil_is_the_point_s_own_normal():
    """A light touch, whose zone holds no sample but its own point, pushes along the point's normal."""
    x = np.linspace(0.0, 40e-9, 81)
    s = _surface(3e-9 * np.sin(x[:, None] / 3e-9) * np.cos(x[None, :] / 4e-9))
    u, v = 17e-9, 22e-9
    n = _unit_normal(s, u, v)
    step = 2.0 * ZONE_HALF_WIDTH * R / (ZONE_NODES - 1)
    got = _zone_normal(s, s.evaluate(u, v) + (R - 0.2e-9) * n, u, v, 0.2e-9, zone=0.99 * step)
    np.testing.assert_allclose(got, n, atol=1e-15)


def test_near_and_behind_the_surface_the_zone_fades_to_the_point_s_normal():
    """Below ZONE_FADE R of distance between centre and surface the direction turns back linearly to
    the point's own normal, reached at 0; behind the patch, and out of reach, nothing is changed."""
    x = np.linspace(0.0, 40e-9, 81)
    s = _surface(3e-9 * np.sin(x[:, None] / 3e-9) * np.cos(x[None, :] / 4e-9))
    u, v = 17e-9, 22e-9
    n = _unit_normal(s, u, v)
    foot = s.evaluate(u, v)

    def at(d):  # the centre d from the foot along the normal
        return _zone_normal(s, foot + d * n, u, v, R - d, zone=3e-9)

    far = at(ZONE_FADE * R)
    assert np.arccos(far @ n) > 0.02                      # the zone's direction differs from the point's
    for d in (1e-12, -1e-9, R - FLOOR + 1e-12):          # at the surface, behind it, out of reach
        got = at(d)
        assert np.arccos(min(1.0, got @ n)) < 1e-3 if d > 0 else np.array_equal(got, n)
    for f in (1e-2, 1e-3):  # continuous at the surface: the turn from the point's normal vanishes with d
        near = at(f * ZONE_FADE * R)
        assert np.arccos(np.clip(near @ n, -1, 1)) <= 2 * f * np.arccos(np.clip(far @ n, -1, 1))


def test_the_direction_moves_continuously_with_the_centre():
    """Along a path of the centre in 1 pm steps on a rough surface (the point held), the direction
    turns by steps that halve when the steps do: no jump, however the weights of the samples change."""
    rng = np.random.default_rng(3)
    s = _surface(1.5e-9 * rng.standard_normal((41, 41)))
    u, v = 20e-9, 20e-9
    n = _unit_normal(s, u, v)
    foot = s.evaluate(u, v)

    def turns(step):
        prev, out = None, []
        for k in range(200):
            centre = foot + (R - 1.5e-9) * n + np.array([k * step, 0.5 * k * step, 0.0])
            d = float(np.linalg.norm(centre - foot))
            got = _zone_normal(s, centre, u, v, R - d, zone=3e-9)
            if prev is not None:
                out.append(np.arccos(np.clip(got @ prev, -1.0, 1.0)))
            prev = got
        return np.array(out)

    a, b = turns(2e-12), turns(1e-12)
    assert a.max() > 0.0
    assert b[: len(b) // 2].max() <= 0.6 * a[: len(a) // 4].max() + 1e-12
