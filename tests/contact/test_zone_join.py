"""The zone energy with its closed form joined in (arsurf.contact.zone_energy.tip_energy_kernel on a
lattice made with closed_form): one energy whose force is its gradient wherever the weight stands
(the one term alone, the lattice alone, and the blend between, with the weight's own gradient),
no work round a loop through the blend, the lattice's own force where another point of the surface
comes near the tip, and the one term's where the contact is smooth and alone."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.contact.zone_energy import (L_QUAD, ZONE_OUT, isolation_kernel, lattice_for, surface_lattice,
                                        tip_energy_kernel, zone_energy)
from arsurf.contact.zone_quadric import Q_WEIGHT, quadric_contact
from arsurf.errors import SurfaceError
from arsurf.feel_scenarios import clearance_height
from arsurf.scan import synthetic
from arsurf.spline.fit import fit_surface
from tests.support.valleys import with_heights
from tests.support.zone_law import H0, LAW, R


@pytest.fixture(scope="module")
def hills():
    """Random hills (rms 1.5 nm, 20 nm correlation) under a 10 nm tip: contacts smooth, rough and between."""
    return fit_surface(synthetic.rough(shape=(128, 128), pixel=1e-9, rms=1.5e-9, correlation_length=20e-9, seed=2))


@pytest.fixture(scope="module")
def joined(hills):
    return lattice_for(hills, R, H0, closed_form=True)


@pytest.fixture(scope="module")
def summed(hills):
    return lattice_for(hills, R, H0)


def energy(lattice, tip):
    """``(out, used)``: E and F at ``tip`` and what the kernel returned (-1: the one term alone)."""
    out = ZONE_OUT.zeros()
    return out, tip_energy_kernel(lattice.arrays, *tip, *LAW.args, out, np.empty((0, 0)))


def tips(surface, count, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        x, y = rng.uniform(20e-9, 100e-9, 2)
        yield np.array([x, y, clearance_height(surface, x, y, R, samples=101) - rng.uniform(-0.2e-9, 1.5e-9)])


def test_the_force_is_the_gradient_of_the_joined_energy(hills, joined):
    kinds = set()
    for tip in tips(hills, 40):
        out, used = energy(joined, tip)
        w = joined.arrays[L_QUAD][Q_WEIGHT]
        kinds.add("one term" if used == -1 else "blend" if 0.0 < w < 1.0 else "lattice")
        h = 2e-13
        numeric = np.array([-(energy(joined, tip + h * e)[0][0] - energy(joined, tip - h * e)[0][0]) / (2 * h)
                            for e in np.eye(3)])
        assert np.abs(numeric - out[1:4]).max() <= 1e-4 * np.linalg.norm(out[1:4])
    assert kinds == {"one term", "blend", "lattice"}  # each way the energy is taken, met on these hills


def test_no_work_round_a_loop_through_the_blend(hills, joined):
    # a circle 6 nm across at a fixed depth through smooth, blended and summed contacts
    centre = np.array([60e-9, 60e-9])
    ring = [centre + 3e-9 * np.array([math.cos(a), math.sin(a)]) for a in np.linspace(0, 2 * np.pi, 721)]
    z = max(clearance_height(hills, *p, R, samples=61) for p in ring[::20]) - 1.0e-9
    weights, work, scale = [], 0.0, 0.0
    prev = None
    for p in ring:
        tip = np.array([p[0], p[1], z])
        out, _ = energy(joined, tip)
        weights.append(joined.arrays[L_QUAD][Q_WEIGHT])
        if prev is not None:
            step = tip - prev[0]
            force = 0.5 * (out[1:4] + prev[1])
            work += force @ step
            scale += np.linalg.norm(force) * np.linalg.norm(step)
        prev = (tip, out[1:4].copy())
    assert min(weights) < 1.0 and max(weights) > 0.0
    assert abs(work) <= 1e-4 * scale


def test_another_point_near_the_tip_hands_it_to_the_lattice(summed):
    # a flat with a pillar 4 nm high beside the contact: the sphere's side meets it, the one term does not
    x = np.arange(96) * 1e-9
    heights = 4e-9 * np.exp(-(((x[None, :] - 56e-9) ** 2 + (x[:, None] - 48e-9) ** 2) / (2 * (2.5e-9) ** 2)))
    surface = fit_surface(with_heights(synthetic.sinusoid(shape=(96, 96), pixel=1e-9, amplitude=0.0), heights))
    joined, plain = lattice_for(surface, R, H0, closed_form=True), lattice_for(surface, R, H0)
    tip = np.array([47e-9, 48e-9, R - 0.5e-9])  # 9 nm from the pillar's axis, 0.5 nm into the flat
    one = quadric_contact(surface, LAW, tip)[1]
    near = zone_energy(plain, LAW, tip)[1]
    assert near[0] < -0.05 * near[2]  # the pillar pushes the tip away
    assert abs(one[0]) < 0.2 * abs(near[0])  # the one term sees the flat (and the pillar's foot)
    out, used = energy(joined, tip)
    assert used >= 0 and joined.arrays[L_QUAD][Q_WEIGHT] == 0.0
    assert np.array_equal(out[1:4], near)
    grad = np.zeros(4)
    assert isolation_kernel(joined.arrays, *tip, R, H0, joined.arrays[L_QUAD], grad) < H0


def test_a_smooth_lone_contact_is_the_one_term(summed):
    wave = fit_surface(synthetic.sinusoid(shape=(96, 96), pixel=1e-9, amplitude=2e-9, period=60e-9, angle=0.6))
    joined, plain = lattice_for(wave, R, H0, closed_form=True), lattice_for(wave, R, H0)
    for where in [(45e-9, 45e-9), (31e-9, 37e-9), (70e-9, 44e-9)]:  # troughs and a slope
        tip = np.array([*where, clearance_height(wave, *where, R, samples=201) - 1.0e-9])
        out, used = energy(joined, tip)
        assert used == -1
        assert out[1:4] == pytest.approx(quadric_contact(wave, LAW, tip)[1], rel=1e-12)
        lattice = zone_energy(plain, LAW, tip)[1]
        # within the one term's own accuracy where it is trusted (the wave's quartic term in the trough: 1.2 %)
        assert np.linalg.norm(out[1:4] - lattice) <= 0.015 * np.linalg.norm(lattice)


def test_far_above_the_surface_the_joined_energy_is_zero(joined):
    out, used = energy(joined, (60e-9, 60e-9, 40e-9))
    assert used == -1 and not out.any()


def test_closed_form_is_asked_for_in_one_line(hills):
    with pytest.raises(SurfaceError, match="`closed_form` must be True or False"):
        lattice_for(hills, R, H0, closed_form="yes")
    for reach in (None, 0.0, math.nan, True):  # its check's reach, the tip's radius (lattice_for passes it)
        with pytest.raises(SurfaceError, match="the closed form needs `reach`"):
            surface_lattice(hills, 2, closed_form=True, reach=reach)


def test_in_the_blend_the_hessian_carries_the_weight_s_slope(hills, joined):
    # the joined Hessian steers the tracking proxy's step and its quadratic model of the last one; in the blend
    # it keeps the terms of the weight's first derivatives, grad w grad(E1 - E_sum)^T and its transpose
    # (the weight's second derivatives left out): nearer the force's own derivative than w H1 + (1 - w) H_sum
    errors = []
    for tip in tips(hills, 80, seed=3):
        out, hess = ZONE_OUT.zeros(), np.zeros((3, 3))
        tip_energy_kernel(joined.arrays, *tip, *LAW.args, out, hess)
        w = joined.arrays[L_QUAD][Q_WEIGHT]
        if not 0.05 < w < 0.95:
            continue
        h = 2e-13
        numeric = np.array([-(energy(joined, tip + h * e)[0][1:4] - energy(joined, tip - h * e)[0][1:4]) / (2 * h)
                            for e in np.eye(3)])
        errors.append(np.abs(hess - numeric).max() / np.abs(numeric).max())
    assert len(errors) >= 5
    assert np.median(errors) <= 0.01  # 0.6 % (1.7 % without the weight's terms)


def test_a_second_minimum_inside_the_zone_between_the_checks_points_hands_the_tip_to_the_lattice():
    # a flat on 0.5 nm pixels with a bump 0.4 nm high and 0.6 nm wide 2.5 nm from where a 10 nm tip presses 1 nm: the
    # gap over the bump is about its least, a second contact inside the 5 nm zone; the checks' 12 points
    # on the zone's edge and on the circle beyond do not reach it, the bound of the surface's third derivative does
    x = np.arange(96) * 0.5e-9
    bump = 0.4e-9 * np.exp(-(((x[:, None] - 24e-9 - 2.5e-9 * math.cos(0.26)) ** 2
                              + (x[None, :] - 24e-9 - 2.5e-9 * math.sin(0.26)) ** 2) / (2 * (0.6e-9) ** 2)))
    surface = fit_surface(with_heights(synthetic.sinusoid(shape=(96, 96), pixel=0.5e-9, amplitude=0.0), bump))
    joined, plain = lattice_for(surface, R, H0, closed_form=True), lattice_for(surface, R, H0)
    tip = np.array([24e-9, 24e-9, R - 1e-9])
    (e1, one, _), (e_sum, summed_here) = quadric_contact(surface, LAW, tip), zone_energy(plain, LAW, tip)
    # the one term misses the bump: 3 % of the energy, a lateral force 2-5 % of the load where the sum's is 0.4 %
    assert abs(e1 - e_sum) > 0.02 * abs(e_sum)
    assert np.linalg.norm(one[:2] - summed_here[:2]) > 0.02 * summed_here[2]
    out, used = energy(joined, tip)
    assert used >= 0 and joined.arrays[L_QUAD][Q_WEIGHT] == 0.0  # (1.0 with the checks' points alone)
    assert np.array_equal(out[1:4], summed_here)
