"""The curvature's own field (arsurf.spline.curvature): its value and slopes continuous across the
knot lines where the spline's own third derivatives step, near the spline's curvature on a surface
smooth at the knot spacing, exact on a quadratic, its slopes those of its values; and the third
derivative's bound at least the third derivative anywhere within its reach."""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.scan import synthetic
from arsurf.spline.basis import height_jet
from arsurf.spline.curvature import curvature_jet, curvature_net
from arsurf.spline.fit import fit_surface
from arsurf.spline.knots import clamped_uniform_knots, greville
from arsurf.spline.surface import BSplineSurface


REACH = 3e-9  # m: the third derivative's bound holds over this reach


def _net(surface):
    ctrl = np.array(surface.rest_control_points, order="C")
    return (ctrl, surface.knots_u, surface.knots_v, *curvature_net(ctrl, surface.knots_u, surface.knots_v, REACH))


@pytest.fixture(scope="module")
def rough():
    return fit_surface(synthetic.rough(shape=(48, 48), pixel=0.5e-9, rms=1e-9, correlation_length=2e-9, seed=3))


def test_across_a_knot_line_the_field_and_its_slopes_are_continuous(rough):
    ctrl, ku, kv, curv, cu, cv = _net(rough)
    eps = 1e-9 * (ku[5] - ku[4])
    for k in (8, 17, 30):  # interior knot lines of u, at three heights along v
        u, v = ku[k], 0.5 * (kv[k + 3] + kv[k + 4])
        lo = np.array(curvature_jet(curv, cu, cv, u - eps, v, 1.0, 1.0))
        hi = np.array(curvature_jet(curv, cu, cv, u + eps, v, 1.0, 1.0))
        for part in (slice(0, 3), slice(3, 4)):  # the curvature (1/m), the bound (1/m^2)
            scale = np.abs(curv[:, :, part]).max()
            assert np.abs(hi[part] - lo[part]).max() <= 1e-6 * scale
            for slope in (4, 8):  # their slopes along x and y
                lo_s, hi_s = lo[slope:slope + 4][part], hi[slope:slope + 4][part]
                assert np.abs(hi_s - lo_s).max() <= 1e-6 * scale / (ku[5] - ku[4])
        # where the spline's own curvature has a kink: its slope z_uuu steps
        own_lo, own_hi = height_jet(ctrl, ku, kv, u - eps, v), height_jet(ctrl, ku, kv, u + eps, v)
        assert abs(own_hi[10] - own_lo[10]) > 0.1 * max(abs(own_hi[10]), abs(own_lo[10]))


def test_its_slopes_are_those_of_its_values(rough):
    ctrl, ku, kv, curv, cu, cv = _net(rough)
    xu, yv = 1.0, 1.0  # the fitted net's parameters are its coordinates
    h = 1e-4 * (ku[5] - ku[4])
    for u, v in ((6.3e-9, 11.1e-9), (12.9e-9, 4.4e-9), (17.05e-9, 19.7e-9)):
        jet = np.array(curvature_jet(curv, cu, cv, u, v, xu, yv))
        du = (np.array(curvature_jet(curv, cu, cv, u + h, v, xu, yv)) - curvature_jet(curv, cu, cv, u - h, v, xu, yv))
        dv = (np.array(curvature_jet(curv, cu, cv, u, v + h, xu, yv)) - curvature_jet(curv, cu, cv, u, v - h, xu, yv))
        for part in (slice(0, 3), slice(3, 4)):  # the curvature's slopes, the bound's
            # the slopes' own size, or the value's over a knot interval (a plateau of the bound has none)
            scale = max(np.abs(jet[4:][np.r_[part, 4 + part.start:4 + part.stop]]).max(),
                        np.abs(jet[part]).max() / (ku[5] - ku[4]))
            assert jet[4:8][part] == pytest.approx(du[:4][part] / (2 * h), abs=1e-6 * scale)
            assert jet[8:12][part] == pytest.approx(dv[:4][part] / (2 * h), abs=1e-6 * scale)


def test_on_a_smooth_wave_it_is_the_splines_curvature():
    # a wave 60 nm long on 1 nm knots: the field differs from the spline's own by O(h^2 k^2) of it
    wave = fit_surface(synthetic.sinusoid(shape=(96, 96), pixel=1e-9, amplitude=2e-9, period=60e-9, angle=0.6))
    ctrl, ku, kv, curv, cu, cv = _net(wave)
    rng = np.random.default_rng(0)
    worst = 0.0
    for u, v in rng.uniform(20e-9, 75e-9, (40, 2)):
        jet = height_jet(ctrl, ku, kv, u, v)
        own = np.array([jet[7], jet[8], jet[9]]) / np.array([jet[2] ** 2, jet[2] * jet[3], jet[3] ** 2])
        field = np.array(curvature_jet(curv, cu, cv, u, v, jet[2], jet[3])[:3])
        worst = max(worst, np.abs(field - own).max())
    peak = 2e-9 * (2 * np.pi / 60e-9) ** 2  # the wave's largest curvature, A k^2
    assert worst <= 0.01 * peak


def test_on_a_quadratic_it_is_exact():
    # a net whose control values are a x^2 + b x y + c y^2 at its Greville abscissae: away from the clamped ends
    # the spline is that quadratic plus a constant, its curvature constant, and the field carries it exactly
    a, b, c = 3e7, -1e7, 2e7  # 1/m
    n, side = 20, 17e-9
    g = greville(clamped_uniform_knots(n, 0.0, side))
    x, y = np.meshgrid(g, g, indexing="ij")
    surface = BSplineSurface.from_heights(a * x * x + b * x * y + c * y * y, (0.0, side), (0.0, side))
    ctrl, ku, kv, curv, cu, cv = _net(surface)
    for u, v in ((8.3e-9, 9.1e-9), (9.5e-9, 9.5e-9), (10.9e-9, 8.2e-9)):
        jet = height_jet(ctrl, ku, kv, u, v)
        own = np.array([jet[7] / jet[2] ** 2, jet[8] / (jet[2] * jet[3]), jet[9] / jet[3] ** 2])
        field = np.array(curvature_jet(curv, cu, cv, u, v, jet[2], jet[3])[:3])
        assert own == pytest.approx([2 * a, b, 2 * c], rel=1e-9)
        assert field == pytest.approx(own, rel=1e-9)


def test_the_bound_holds_the_third_derivative_within_its_reach(rough):
    ctrl, ku, kv, curv, cu, cv = _net(rough)
    rng = np.random.default_rng(1)
    tight = []
    for u, v in rng.uniform(4e-9, 19e-9, (30, 2)):
        bound = curvature_jet(curv, cu, cv, u, v, 1.0, 1.0)[3]
        angle, r = rng.uniform(0, 2 * np.pi, 40), REACH * np.sqrt(rng.uniform(0, 1, 40))
        sizes = []
        for a, b in zip(u + r * np.cos(angle), v + r * np.sin(angle)):
            t = height_jet(ctrl, ku, kv, a, b)[10:]  # z_xxx, z_xxy, z_xyy, z_yyy (x = u, y = v)
            sizes.append(np.sqrt(t[0] ** 2 + 3 * t[1] ** 2 + 3 * t[2] ** 2 + t[3] ** 2))
        assert max(sizes) <= bound
        tight.append(max(sizes) / bound)
    assert np.median(tight) > 0.2  # a bound, not a wall: within a few times what is met


def test_the_field_is_the_same_evaluated_in_chunks(rough, monkeypatch):
    import arsurf.spline.curvature as curvature

    ctrl = np.array(rough.rest_control_points, order="C")
    whole = curvature_net(ctrl, rough.knots_u, rough.knots_v, REACH)[0]
    monkeypatch.setattr(curvature, "CHUNK", 7)  # chunks that cut rows of the net
    assert np.array_equal(curvature_net(ctrl, rough.knots_u, rough.knots_v, REACH)[0], whole)
