"""The zone law in closed form over a smooth contact (arsurf.contact.zone_quadric): exact on a flat
(the sphere's own area kept), a force that is the gradient of its energy (the surface's third
derivatives in it) and a Hessian near the force's derivative; against a lattice finer than the
engine's, close on a surface smooth at the contact's scale and far off on one rough under it; and
a height field's jet to third order (arsurf.spline.basis.height_jet) that is the spline's."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import ZoneLaw, surface_lattice, zone_energy, zone_law_kernel
from arsurf.contact.zone_quadric import (NO_MINIMUM, QUADRIC_OUT, Q_DET, Q_GAP, Q_UV, Q_WEIGHT, law_moments,
                                         quadric_contact, quadric_contact_kernel)
from arsurf.errors import ContactError
from arsurf.feel_scenarios import clearance_height
from arsurf.scan import synthetic
from arsurf.spline.basis import height_jet, surface_point
from arsurf.spline.curvature import curvature_net
from arsurf.spline.fit import fit_surface
from tests.support.valleys import R as VALLEY_R, height_for, valley_surface
from tests.support.zone_law import H0, LAW, R



@pytest.fixture(scope="module")
def flat():
    return fit_surface(synthetic.sinusoid(shape=(60, 60), pixel=1e-9, amplitude=0.0, period=10e-9))


@pytest.fixture(scope="module")
def smooth():
    """A wave 4 nm peak to peak and 60 nm long, oblique to x: smooth at the scale of a 10 nm tip's contact."""
    return fit_surface(synthetic.sinusoid(shape=(96, 96), pixel=1e-9, amplitude=2e-9, period=60e-9, angle=0.6))


@pytest.fixture(scope="module")
def rough():
    """Asperities 2 nm high, 3 nm apart: rough under a 10 nm tip's contact."""
    return fit_surface(synthetic.rough(shape=(64, 64), pixel=0.5e-9, rms=2e-9, correlation_length=3e-9, seed=5))


def net(surface):
    """The kernel's net arguments: control points, knots and the curvature's own net."""
    ctrl = np.array(surface.rest_control_points, order="C")
    return (ctrl, surface.knots_u, surface.knots_v, *curvature_net(ctrl, surface.knots_u, surface.knots_v, R))


def pressed(surface, x, y, depth):
    """A tip centre ``depth`` (m) below where the sphere first touches above (x, y)."""
    return np.array([x, y, clearance_height(surface, x, y, R, samples=201) - depth])


@pytest.mark.parametrize("g0", [-2e-9, -0.3e-9, 0.0, 0.1e-9, 0.25e-9, 0.4e-9])
def test_the_law_moments_are_the_integrals(g0):
    i0, i1 = law_moments(g0, *LAW.args)
    phi = [lambda g: zone_law_kernel(g, *LAW.args)[0], lambda g: g * zone_law_kernel(g, *LAW.args)[0]]
    for got, f in zip((i0, i1), phi):
        want = quad(f, g0, max(H0, g0), points=[0.0] if g0 < 0 else None, epsabs=0.0, epsrel=1e-12, limit=200)[0]
        assert got == pytest.approx(want, rel=1e-9, abs=1e-30)


@pytest.mark.parametrize("depth", [-0.15e-9, 0.0, 0.2e-9, 0.5e-9, 1.5e-9])
def test_on_a_flat_the_one_term_is_the_law_summed_over_the_sphere(flat, depth):
    energy, force, status = quadric_contact(flat, LAW, (30e-9, 30.3e-9, R - depth))
    assert status >= 0
    assert force[2] == pytest.approx(LAW.flat_load(depth), rel=1e-9)  # dA/dg = 2 pi (R - s): the sphere's, exactly
    assert np.abs(force[:2]).max() <= 1e-12 * abs(force[2])


def test_out_of_reach_the_one_term_is_zero(flat):
    out = QUADRIC_OUT.full(math.nan)
    ctrl = np.array(flat.rest_control_points, order="C")
    status = quadric_contact_kernel(*net(flat), 30e-9, 30e-9, R + 1.01 * H0, *LAW.args, out,
                                    np.empty((0, 0)))
    assert status >= 0 and out[Q_GAP] == pytest.approx(1.01 * H0, rel=1e-9)
    assert not out[:4].any()
    assert out[Q_DET] == pytest.approx(1.0 / R ** 2, rel=1e-9)


@pytest.mark.parametrize("where", [(30e-9, 9.3e-9), (50e-9, 33e-9), (20e-9, 24e-9), (70e-9, 44e-9)])  # on slopes
def test_the_force_is_the_gradient_of_the_one_term(smooth, where):
    tip = pressed(smooth, *where, 1.0e-9)
    energy, force, status = quadric_contact(smooth, LAW, tip)
    assert status >= 0 and energy != 0.0
    h = 1e-12
    numeric = np.array([-(quadric_contact(smooth, LAW, tip + h * e)[0] - quadric_contact(smooth, LAW, tip - h * e)[0])
                        / (2 * h) for e in np.eye(3)])
    assert np.abs(force - numeric).max() <= 2e-5 * np.linalg.norm(force)
    assert abs(force[0]) > 0.1 * abs(force[2])  # on a slope: the lateral force, and the surface's curvature in it


def test_the_hessian_is_near_the_forces_derivative(smooth):
    tip = pressed(smooth, 45e-9, 45e-9, 1.0e-9)
    out, hess = QUADRIC_OUT.full(math.nan), np.empty((3, 3))
    ctrl = np.array(smooth.rest_control_points, order="C")
    quadric_contact_kernel(*net(smooth), *tip, *LAW.args, out, hess)
    h = 1e-12
    numeric = np.array([-(quadric_contact(smooth, LAW, tip + h * e)[1] - quadric_contact(smooth, LAW, tip - h * e)[1])
                        / (2 * h) for e in np.eye(3)])
    assert np.allclose(hess, hess.T)
    assert np.abs(hess - numeric).max() <= 0.03 * np.abs(numeric).max()  # the fourth derivatives left out


def test_the_minimum_is_found_again_from_where_it_was(smooth):
    tip = pressed(smooth, 40e-9, 50e-9, 0.8e-9)
    out = QUADRIC_OUT.full(math.nan)
    ctrl = np.array(smooth.rest_control_points, order="C")
    args = (*net(smooth), *tip, *LAW.args)
    first = quadric_contact_kernel(*args, out, np.empty((0, 0)))
    again = out.copy()
    second = quadric_contact_kernel(*args, again, np.empty((0, 0)))
    assert second < first and second <= 2
    assert again[:4] == pytest.approx(out[:4], rel=1e-12)
    u, v = out[Q_UV:Q_UV + 2]
    ev = np.empty((6, 3))
    surface_point(ctrl, smooth.knots_u, smooth.knots_v, u, v, 1, ev)
    d = ev[0, :2] - tip[:2]
    rho = math.sqrt(R * R - d @ d)
    assert d / rho == pytest.approx(ev[1:3, 2] / np.array([ev[1, 0], ev[2, 1]]), rel=1e-6)  # the sphere's slope
    # is the surface's there: the closest approach of the vertical gap


def test_on_a_smooth_surface_the_one_term_is_the_lattices_sum(smooth):
    fine = surface_lattice(smooth, per_knot=8, pool=2048)  # 0.125 nm apart: the sum converged to ~1e-4
    for where, within in [((52e-9, 20e-9), 0.001), ((40e-9, 44e-9), 0.005), ((31e-9, 37e-9), 0.02)]:
        tip = pressed(smooth, *where, 1.0e-9)
        force = quadric_contact(smooth, LAW, tip)[1]
        # in the trough (31, 37) nm the zone is widest and the wave's fourth-order term left out is 1.3 % of the load
        assert np.linalg.norm(force - zone_energy(fine, LAW, tip)[1]) <= within * np.linalg.norm(force)


def test_on_a_surface_rough_under_the_contact_the_one_term_is_not_the_sum(rough):
    fine = surface_lattice(rough, per_knot=8, pool=2048)
    off = []
    for where in [(12e-9, 15e-9), (16e-9, 18e-9), (20e-9, 13e-9), (14e-9, 21e-9)]:
        tip = pressed(rough, *where, 1.0e-9)
        energy, force, status = quadric_contact(rough, LAW, tip)
        lattice = zone_energy(fine, LAW, tip)[1]
        off.append(np.inf if status < 0 else np.linalg.norm(force - lattice) / np.linalg.norm(lattice))
    assert max(off) > 0.1  # the lattice stays needed there


def test_over_a_valley_narrower_than_the_tip_no_minimum_is_said(flat):
    # the gap's stationary point over the valley's bottom is a saddle: the sphere touches the walls
    valley = valley_surface("sinusoid")
    law = ZoneLaw.from_law(MaugisDugdale(VALLEY_R, 50e9, 0.05))
    out = QUADRIC_OUT.full(math.nan)
    ctrl = np.array(valley.rest_control_points, order="C")
    status = quadric_contact_kernel(*net(valley), 33e-9, 24e-9, height_for("sinusoid", 33e-9),
                                    *law.args, out, np.empty((0, 0)))
    assert status == NO_MINIMUM and not out[:4].any() and out[Q_WEIGHT] == 0.0
    with pytest.raises(ContactError, match="center"):
        quadric_contact(flat, LAW, (0.0, math.nan, 0.0))


def test_the_height_jet_is_the_splines(rough):
    ctrl = np.array(rough.rest_control_points, order="C")
    ku, kv = rough.knots_u, rough.knots_v
    ev = np.empty((6, 3))
    (u0, u1), (v0, v1) = rough.domain
    rng = np.random.default_rng(0)
    h = 1e-4 * (u1 - u0) / (ctrl.shape[0] - 3)  # within a knot span
    for u, v in [(u0 + 2 * h, v0 + 0.5 * (v1 - v0)), (u1 - 2 * h, v1 - 1.5 * h)] + list(
            zip(rng.uniform(u0 + 3 * h, u1 - 3 * h, 12), rng.uniform(v0 + 3 * h, v1 - 3 * h, 12))):
        jet = np.array(height_jet(ctrl, ku, kv, u, v))
        surface_point(ctrl, ku, kv, u, v, 2, ev)
        assert jet[[0, 1, 2, 3]] == pytest.approx([ev[0, 0], ev[0, 1], ev[1, 0], ev[2, 1]], rel=1e-12)
        assert jet[4:10] == pytest.approx(ev[[0, 1, 2, 3, 4, 5], 2], rel=1e-10, abs=1e-12 * np.abs(ev[:, 2]).max())

        def second(a, b):
            surface_point(ctrl, ku, kv, a, b, 2, ev)
            return ev[3:6, 2].copy()  # z_uu, z_uv, z_vv

        du = (second(u + h, v) - second(u - h, v)) / (2 * h)
        dv = (second(u, v + h) - second(u, v - h)) / (2 * h)
        scale = np.abs(jet[10:]).max()
        assert jet[10:] == pytest.approx([du[0], du[1], du[2], dv[2]], abs=1e-5 * scale)


@pytest.mark.parametrize("ring", [0.5 * R, 1.1 * R, 1.3 * R])  # on the sphere, and past it on the cone
def test_the_checks_see_the_gap_under_the_tip_s_own_profile(flat, ring):
    # on a flat at z = 0, the minimum under the tip's axis: the gap at a point of a check circle is the
    # lattice's (the sphere, then the cone: zone_law._rise), and it does not change as tip and minimum move
    # together; a check circle may reach past the sphere (1.5 zones across, deep under a small tip)
    from arsurf.contact.zone_law import _cone, _rise
    from arsurf.contact.zone_quadric import _deviation

    ctrl = np.array(flat.rest_control_points, order="C")
    tz = R - 3e-9
    u, v = 30e-9, 30e-9  # the net's parameters are its coordinates
    model = (30e-9, 30e-9, tz, u, v, 1.0, 1.0, 30e-9, 30e-9, 0.0, 0.0, tz - R, 1 / R, 0.0, 1 / R,
             0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0)
    for angle in (0.0, 1.0, 2.5):
        out = _deviation(ctrl, flat.knots_u, flat.knots_v, model, R, ring, 0.0, angle)
        gap, grad = out[4], np.array(out[5:8])
        assert gap == pytest.approx(tz - R + _rise(ring * ring, R, *_cone(R))[0], rel=1e-9)
        assert np.allclose(grad, [0.0, 0.0, 1.0], atol=1e-9)


@pytest.mark.parametrize("depth", [0.5e-9, 1.5e-9, 2.5e-9])  # down to a quarter of R under the apex's level
def test_on_a_flat_the_one_term_is_trusted_however_deep(flat, depth):
    # the one term is the law summed over the sphere exactly, so its checks must find no deviation on a flat
    # at any depth the sphere's room allows: the fit's model is the sphere's own profile over q,
    # g0 + R - sqrt(R^2 - 2 R q), not its quartic truncation g0 + q + q^2/2R (a third of R deep, that
    # truncation alone is 10 % of the gap's range off on the zone's edge)
    out = QUADRIC_OUT.full(math.nan)
    ctrl = np.array(flat.rest_control_points, order="C")
    status = quadric_contact_kernel(*net(flat), 30e-9, 30.3e-9, R - depth, *LAW.args, out,
                                    np.empty((0, 0)))
    assert status >= 0
    assert out[Q_WEIGHT] == 1.0
    assert not out[Q_WEIGHT + 1:Q_WEIGHT + 4].any()


def test_the_force_is_continuous_where_the_minimum_crosses_a_knot_line():
    # a tip sliding 1 nm in 2 pm steps over a surface rough at its 0.5 nm knots: the gap's minimum crosses knot
    # lines, where the spline's third derivatives step; the energy's curvature is read from the curvature's own C2
    # field, so the force has no step there (with the spline's own curvature: a step 160 times the force's change
    # over a step elsewhere)
    surface = fit_surface(synthetic.rough(shape=(64, 64), pixel=0.5e-9, rms=0.4e-9, correlation_length=4e-9, seed=2))
    z = pressed(surface, 14e-9, 16e-9, 0.8e-9)[2]
    forces = []
    for x in 14e-9 + 2e-12 * np.arange(500):
        energy, force, status = quadric_contact(surface, LAW, (x, 16e-9, z))
        assert status >= 0
        forces.append(force)
    steps = np.linalg.norm(np.diff(np.array(forces), axis=0), axis=1)
    assert steps.max() <= 4.0 * np.median(steps)
