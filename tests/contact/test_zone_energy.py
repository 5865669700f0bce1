"""The tip's energy summed over the surface (arsurf.contact.zone_energy): on a flat the rigid
tip's exact load (the DMT limit, at any depth), a force that is the gradient of the energy (and a Hessian that is its
derivative), and - in the valley narrower than the tip where the several-contact model's force is
not a gradient (tests/contact/test_force_field.py) - no work round a loop and a force continuous
across the middle; behind a virtual coupling, the proxy tip at the balance of the two."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import (CORRECTION_SHARE, L_MEMO, L_US, L_VS, PROXY_TOL, TILE, TRACKING_REDUCTION, Z_FORCE, ZONE_OUT, ZoneLaw, lattice_for, surface_lattice,
                                        zone_energy,
                                        zone_energy_kernel, zone_law_kernel, zone_proxy_kernel)
from arsurf.errors import ContactError, SurfaceError
from arsurf.scan import synthetic
from arsurf.spline.fit import fit_surface
from arsurf.spline.surface import BSplineSurface
from tests.support.valleys import R, height_for, valley_surface

LAW = ZoneLaw.from_law(MaugisDugdale(R, 50e9, 0.05))


@pytest.fixture(scope="module")
def flat():
    return surface_lattice(fit_surface(synthetic.sinusoid(shape=(60, 60), pixel=1e-9, amplitude=0.0,
                                                          period=10e-9)), per_knot=4)


@pytest.fixture(scope="module")
def rough_surface():
    return fit_surface(synthetic.rough(shape=(64, 64), pixel=0.5e-9, rms=1.5e-9, correlation_length=2.5e-9, seed=3))


def top(surface, lattice) -> float:
    """The highest sample of ``lattice`` on ``surface`` (m)."""
    uu, vv = np.meshgrid(lattice.arrays[L_US], lattice.arrays[L_VS])
    return float(surface.evaluate(uu, vv)[..., 2].max())


def tip_on_flat(depth):
    """The law summed over a flat by rings (the integral the lattice approximates), written out
    here: the ring at radius r has the gap -depth plus the tip's rise there (the sphere, then
    the cone tangent to it at 15 degrees) and pushes up with its whole pressure."""
    cos, sin = math.cos(math.radians(15.0)), math.sin(math.radians(15.0))

    def rise(r):
        return R - math.sqrt(R * R - r * r) if r < R * cos else R * (1.0 - sin) + (r - R * cos) * cos / sin

    def ring(r):
        return 2.0 * math.pi * r * zone_law_kernel(rise(r) - depth, *LAW.args)[1]

    edge = math.sqrt(max(depth * (2.0 * R - depth), 0.0))  # where the gap closes: the pressure's kink
    reach = math.sqrt((depth + LAW.interaction_range) * (2.0 * R - depth - LAW.interaction_range))
    return quad(ring, 0.0, reach, points=[edge] if edge > 0 else None, limit=200, epsabs=0.0, epsrel=1e-11)[0]


@pytest.mark.parametrize("depth", [-0.15e-9, 0.0, 0.2e-9, 0.5e-9, 1.0e-9])
def test_on_a_flat_the_tip_feels_the_law_summed_over_its_cap(flat, depth):
    energy, force = zone_energy(flat, LAW, (30e-9, 30.1e-9, R - depth))
    exact = LAW.flat_load(depth)
    assert tip_on_flat(depth) == pytest.approx(exact, rel=1e-7)
    assert force[2] == pytest.approx(exact, rel=2e-3)  # the lattice's quadrature, 0.25 nm apart
    assert np.abs(force[:2]).max() <= 1e-3 * abs(exact)
    if depth >= 0.0:  # Hertz with the Dugdale adhesion's -2 pi R w (the DMT limit) to order (depth + h0) / R
        dmt = 4.0 / 3.0 * LAW.effective_modulus * math.sqrt(R) * depth ** 1.5 - 2.0 * math.pi * R * LAW.work_of_adhesion
        assert abs(exact - dmt) <= (depth + LAW.interaction_range) / R * (abs(dmt) + LAW.pull_off_force())


def test_out_of_reach_the_tip_feels_nothing(flat):
    energy, force = zone_energy(flat, LAW, (30e-9, 30e-9, R + 1.01 * LAW.interaction_range))
    assert energy == 0.0 and not force.any()


def test_the_force_is_the_gradient_of_the_energy_on_a_rough_surface(rough_surface):
    rough = surface_lattice(rough_surface, per_knot=3)
    z = top(rough_surface, rough)
    h = 1e-12
    for c in ([16e-9, 15e-9, z + R - 1.0e-9], [14e-9, 17.5e-9, z + R - 2.5e-9], [18e-9, 16e-9, z + R - 0.1e-9]):
        c = np.array(c)
        force = zone_energy(rough, LAW, c)[1]
        grad = [(zone_energy(rough, LAW, c + h * e)[0] - zone_energy(rough, LAW, c - h * e)[0]) / (2 * h)
                for e in np.eye(3)]
        np.testing.assert_allclose(-np.array(grad), force, rtol=1e-5, atol=1e-6 * np.linalg.norm(force))


def test_the_hessian_is_the_derivative_of_the_force(rough_surface):
    rough = surface_lattice(rough_surface, per_knot=3)
    z = top(rough_surface, rough)
    h = 1e-13
    for c in ([16e-9, 15e-9, z + R - 1.0e-9], [14e-9, 17.5e-9, z + R - 2.5e-9]):
        c = np.array(c)
        hess, out = np.empty((3, 3)), ZONE_OUT.zeros()
        zone_energy_kernel(*rough.kernel_args(), *c, *LAW.args, out, hess)
        jac = np.column_stack([(zone_energy(rough, LAW, c + h * e)[1] - zone_energy(rough, LAW, c - h * e)[1]) / (2 * h)
                               for e in np.eye(3)])
        np.testing.assert_allclose(hess, -jac, atol=1e-4 * np.linalg.norm(jac))
        assert np.array_equal(hess, hess.T)


def test_behind_a_coupling_the_proxy_rests_where_the_spring_balances_the_law(flat):
    """A target 3 nm into a flat behind a 5 N/m coupling: the tip, brought down from 1 nm above,
    settles where k (T - C) is the law's load at its depth (a 1-D root of the exact flat load)."""
    from scipy.optimize import brentq

    k, target = 5.0, np.array([30e-9, 30.1e-9, R - 3e-9])
    tip, out = np.array([30e-9, 30.1e-9, R + 1e-9]), ZONE_OUT.zeros()
    iterations = zone_proxy_kernel(*flat.kernel_args(), *target, k, *LAW.args, tip, out)
    assert 0 < iterations <= 20
    np.testing.assert_allclose(out[Z_FORCE:Z_FORCE + 3], k * (tip - target), atol=1e-6 * k * R)  # the balance
    depth = brentq(lambda d: LAW.flat_load(d) - k * (R - d - target[2]), -LAW.interaction_range, R / 2)
    assert R - tip[2] == pytest.approx(depth, abs=1e-12)  # within a picometre: the lattice's quadrature
    assert zone_proxy_kernel(*flat.kernel_args(), *target, k, *LAW.args, tip, out) == 0  # already there


def test_the_proxy_started_where_it_ended_reads_its_memo_and_moves_as_from_a_fresh_lattice(rough_surface):
    """Two ticks of the proxy on a rough surface, the second's target moved 0.1 nm: the second
    call starts where the first ended and reads E, F and the Hessian there from the lattice's memo
    instead of summing them; the tip and force are the same to the bit as from a lattice that
    never saw the first call (the energy is one function of the tip)."""
    lattice = lattice_for(rough_surface, R, LAW.interaction_range)
    k, start = 5.0, np.array([16e-9, 16e-9, top(rough_surface, lattice) + R + 1e-9])
    target = start - [0.0, 0.0, 4e-9]
    tip, out = start.copy(), ZONE_OUT.zeros()
    assert zone_proxy_kernel(*lattice.kernel_args(), *target, k, *LAW.args, tip, out) > 0
    assert np.array_equal(lattice.arrays[L_MEMO][:3], tip)  # remembered where it ended
    moved = target + [0.1e-9, 0.0, 0.0]
    fresh = lattice_for(rough_surface, R, LAW.interaction_range)
    results = []
    for lat in (lattice, fresh):
        t, o = tip.copy(), ZONE_OUT.zeros()
        results.append((zone_proxy_kernel(*lat.kernel_args(), *moved, k, *LAW.args, t, o), t, o))
    (n1, t1, o1), (n2, t2, o2) = results
    assert n1 == n2 > 0 and np.array_equal(t1, t2) and np.array_equal(o1, o2)
    assert not np.array_equal(t1, tip)  # it moved


def test_tracking_the_proxy_leaves_a_hundredth_of_the_gradient_a_tick_and_converges_at_rest(rough_surface):
    """A haptic tick's proxy (reduction TRACKING_REDUCTION) from a converged tip, the target moved
    0.2 nm across a rough surface: it returns after whole steps that left at most a hundredth of the
    gradient it started from (or none, where it published the quadratic model's minimum); ticks at
    the same target then take it to the minimum the converging proxy finds (to the tolerance's
    nanometre fraction)."""
    lattice = lattice_for(rough_surface, R, LAW.interaction_range)
    k = 5.0
    target = np.array([16e-9, 16e-9, top(rough_surface, lattice) + R - 3e-9])
    tip, out = target + [0.0, 0.0, 4e-9], ZONE_OUT.zeros()
    assert zone_proxy_kernel(*lattice.kernel_args(), *target, k, *LAW.args, tip, out) > 0  # converged

    def gradient(t, o, c):
        return np.linalg.norm(k * (t - c) - o[Z_FORCE:Z_FORCE + 3])

    moved = target + [0.2e-9, 0.0, 0.0]
    before = gradient(tip, out, moved)
    converging = zone_proxy_kernel(*lattice.kernel_args(), *moved, k, *LAW.args, tip.copy(), out.copy())
    steps = zone_proxy_kernel(*lattice.kernel_args(), *moved, k, *LAW.args, tip, out, TRACKING_REDUCTION)
    assert 0 < steps < converging and gradient(tip, out, moved) <= TRACKING_REDUCTION * before
    for _ in range(20):
        zone_proxy_kernel(*lattice.kernel_args(), *moved, k, *LAW.args, tip, out, TRACKING_REDUCTION)
    full, full_out = tip.copy(), out.copy()
    zone_proxy_kernel(*lattice.kernel_args(), *moved, k, *LAW.args, full, full_out)  # converging: no further step
    assert np.linalg.norm(full - tip) <= 1e-6 * R
    assert gradient(tip, out, moved) <= PROXY_TOL * k * R


def test_tracking_the_proxy_sums_once_a_tick_and_publishes_the_quadratic_models_minimum(rough_surface):
    """A haptic loop's ticks across the rough surface, the target moving 0.1 nm a tick at a load of
    ~40 nN: each tick sums the energy once (one step from the point summed the tick before, whose
    E, F and Hessian are remembered) and publishes the minimum of the quadratic model about the
    point it summed, where the force balances the coupling (to rounding); it agrees with the
    minimum the converging proxy finds to a thousandth of the force, as the quadratic model's
    error (second order in the step's residual) says; and a call from the published tip starts
    from the summed point, as one from that point on a lattice that never saw the call."""
    lattice = lattice_for(rough_surface, R, LAW.interaction_range)
    k = 50.0
    target = np.array([14e-9, 16e-9, top(rough_surface, lattice) + R - 3e-9])
    tip, out = target + [0.0, 0.0, 4e-9], ZONE_OUT.zeros()
    assert zone_proxy_kernel(*lattice.kernel_args(), *target, k, *LAW.args, tip, out) > 0  # converged
    reference = lattice_for(rough_surface, R, LAW.interaction_range)
    full, full_out = tip.copy(), out.copy()
    published = 0
    for tick in range(40):
        target = target + [0.1e-9, 0.02e-9, 0.0]
        assert zone_proxy_kernel(*lattice.kernel_args(), *target, k, *LAW.args, tip, out, TRACKING_REDUCTION) == 1
        force = out[Z_FORCE:Z_FORCE + 3]
        summed = lattice.arrays[L_MEMO][:3]
        if not np.array_equal(tip, summed):  # published off the summed point: balanced there
            published += 1
            np.testing.assert_allclose(force, k * (tip - target), rtol=0.0, atol=1e-12 * np.linalg.norm(force))
            assert np.linalg.norm(tip - summed) <= CORRECTION_SHARE * 0.11e-9
        zone_proxy_kernel(*reference.kernel_args(), *target, k, *LAW.args, full, full_out)
        assert np.linalg.norm(force - full_out[Z_FORCE:Z_FORCE + 3]) <= 1e-3 * np.linalg.norm(force)
        assert np.linalg.norm(full - tip) <= 1e-3 * np.linalg.norm(force) / k
    assert published >= 20 and np.linalg.norm(force) > 2e-8

    summed = lattice.arrays[L_MEMO][:3].copy()
    fresh = lattice_for(rough_surface, R, LAW.interaction_range)
    moved = target + [0.1e-9, 0.0, 0.0]
    runs = []
    for lat, start in ((lattice, tip), (fresh, summed)):
        t, o = start.copy(), ZONE_OUT.zeros()
        runs.append((zone_proxy_kernel(*lat.kernel_args(), *moved, k, *LAW.args, t, o), t, o))
    (n1, t1, o1), (n2, t2, o2) = runs
    assert n1 == n2 > 0 and np.array_equal(t1, t2) and np.array_equal(o1, o2)


@pytest.fixture(scope="module")
def valley():
    return surface_lattice(valley_surface("sinusoid"), per_knot=4)


@pytest.mark.parametrize("offset", [0.3e-9, 0.8e-9, 1.5e-9])
def test_in_the_valley_narrower_than_the_tip_a_loop_gives_no_work(valley, offset):
    """Where the several-contact model's force does ~1 % of its absolute work as net work round a
    0.1 nm loop across the valley and up its walls (tests/haptics/test_feel_circulation_bench.py;
    its Jacobian's skew part is 8.9-11.8 % of the symmetric part, tests/contact/test_force_field.py),
    the zone energy's force gives back all it takes, to the quadrature's rounding."""
    c = np.array([33e-9 + offset, 24e-9, height_for("sinusoid", 33e-9, 2e-9)])
    t = np.linspace(0.0, 2.0 * np.pi, 4001)
    path = c + 0.1e-9 * np.column_stack([np.cos(t), np.zeros_like(t), np.sin(t)])  # the xz plane
    forces = np.array([zone_energy(valley, LAW, p)[1] for p in path])
    mid = 0.5 * (forces[1:] + forces[:-1])  # the trapezoidal rule along the path
    work = np.einsum("ij,ij->i", mid, np.diff(path, axis=0))
    assert abs(work.sum()) <= 1e-6 * np.abs(work).sum()
    energy = [zone_energy(valley, LAW, p)[0] for p in path[::1000]]
    assert abs(energy[0] - energy[-1]) == 0.0  # the same point, the same energy: no memory


def test_across_the_valley_the_force_turns_without_a_step(valley):
    """Sweeping the tip across the middle of the valley, where the closest point hops from one wall
    to the other: both walls push at once, and the force turns continuously."""
    z = height_for("sinusoid", 33e-9, 2e-9)
    xs = 33e-9 + np.linspace(-1.5e-9, 1.5e-9, 3001)  # 1 pm steps
    forces = np.array([zone_energy(valley, LAW, (x, 24e-9, z))[1] for x in xs])
    steps = np.linalg.norm(np.diff(forces, axis=0), axis=1)
    assert steps.max() <= 1e-3 * np.linalg.norm(forces, axis=1).min()
    angle = np.arctan2(forces[:, 0], forces[:, 2])
    assert angle[0] > 0.01 > -0.01 > angle[-1]  # pushed back towards the middle from either side
    assert np.all(np.diff(angle) < 0.0)  # turning one way, through the middle


def test_the_tiles_give_the_whole_lattice_sum_whatever_the_pool_holds(rough_surface):
    """The lattice is sampled a tile at a time where the tip reaches: along a path across many
    tiles the energy and force equal the sum over every sample of the lattice taken at once (by
    numpy, here), and are the same to the bit with a pool of one tile (each tile sampled again
    every time it is needed) as with the default pool."""
    lattice, single = surface_lattice(rough_surface, per_knot=3), surface_lattice(rough_surface, per_knot=3, pool=1)
    nu, nv = lattice.shape
    uu, vv = np.meshgrid(lattice.arrays[L_US], lattice.arrays[L_VS], indexing="ij")
    s, su, sv = rough_surface.evaluate(uu, vv, 1)
    points = s.reshape(-1, 3)
    weights = np.outer(np.r_[0.5, np.ones(nu - 2), 0.5], np.r_[0.5, np.ones(nv - 2), 0.5]).ravel()
    areas = np.abs(su[..., 0] * sv[..., 1] - su[..., 1] * sv[..., 0]).ravel() * weights \
        * np.diff(lattice.arrays[L_US][:2]) * np.diff(lattice.arrays[L_VS][:2])
    z = top(rough_surface, lattice)
    cos15, sin15 = math.cos(math.radians(15.0)), math.sin(math.radians(15.0))
    path = np.column_stack([np.linspace(4e-9, 28e-9, 25), np.linspace(27e-9, 5e-9, 25), np.full(25, z + R - 3e-9)])
    touched = 0
    for c in path:
        across = c[:2] - points[:, :2]
        r = np.hypot(across[:, 0], across[:, 1])
        sphere = r < R * cos15
        root = np.sqrt(np.where(sphere, R * R - r * r, 1.0))
        rise = np.where(sphere, R - root, R * (1.0 - sin15) + (r - R * cos15) * cos15 / sin15)
        slope = np.where(sphere, 1.0 / root, cos15 / sin15 / np.where(sphere, 1.0, r))  # s'(r) / r
        grad = np.column_stack([slope[:, None] * across, np.ones(len(points))])  # the gap's gradient
        gap = c[2] - R + rise - points[:, 2]
        near = np.nonzero(gap < LAW.interaction_range)[0]
        law = np.array([zone_law_kernel(g, *LAW.args) for g in gap[near]]).reshape(-1, 2)
        energy = float((areas[near] * law[:, 0]).sum())
        force = ((areas[near] * law[:, 1])[:, None] * grad[near]).sum(axis=0)
        tiled, again = zone_energy(lattice, LAW, c), zone_energy(single, LAW, c)
        assert tiled[0] == pytest.approx(energy, rel=1e-12, abs=1e-40)
        np.testing.assert_allclose(tiled[1], force, rtol=1e-12, atol=1e-12 * np.abs(force).max(initial=0.0))
        assert again[0] == tiled[0] and np.array_equal(again[1], tiled[1])
        touched += near.size > 0
    assert touched >= 20 and single.sampled_tiles == 1 and lattice.sampled_tiles > 4


def test_a_lattice_beyond_memory_is_sampled_only_where_the_tip_is():
    """A 600 x 600 net sampled 16 times per knot interval is a lattice of 9553 x 9553 samples
    (3 GB of points and areas at once); pressed in one place, the tip samples a few tiles of it
    and feels the flat's exact load: the tiles within reach, at most those over the disc where the
    gap is below the range, widened by a tile's diagonal."""
    surface = BSplineSurface.from_heights(np.zeros((600, 600)), (0.0, 600e-9), (0.0, 600e-9))
    lattice = surface_lattice(surface, per_knot=16)
    assert lattice.shape == (9553, 9553)
    depth = 0.5e-9
    energy, force = zone_energy(lattice, LAW, (300.3e-9, 299.1e-9, R - depth))
    assert force[2] == pytest.approx(LAW.flat_load(depth), rel=2e-3)
    disc = math.sqrt(2.0 * R * (LAW.interaction_range + depth))
    tile = TILE * lattice.spacing[0]
    bound = math.pi * (disc + math.sqrt(2.0) * tile) ** 2 / tile ** 2
    assert 1 <= lattice.sampled_tiles <= bound < 1e-3 * 9553 ** 2 / TILE ** 2


@pytest.mark.parametrize("pixel, radius", [(0.0156e-9, 20e-9), (0.3e-9, 7e-9), (6.4e-9, 2e-9), (2e-9, 50e-9)])
def test_the_lattice_resolves_the_tip_and_its_contact_not_finer(pixel, radius):
    """The lattice a tip is summed over: at most R/8 and an eighth of the zone where a flat at zero
    load interacts, sqrt(2 R h0), apart, whatever the pixels: no finer under an STM image of 0.016
    nm pixels and a 20 nm tip, finer than the pixels where they are coarse."""
    law = ZoneLaw.from_law(MaugisDugdale(radius, 50e9, 0.05))
    surface = BSplineSurface.from_heights(np.zeros((400, 400)), (0.0, 399 * pixel), (0.0, 399 * pixel))
    h = lattice_for(surface, radius, law.interaction_range).spacing[0]
    wanted = min(radius / 8.0, math.sqrt(2.0 * radius * law.interaction_range) / 8.0)
    assert wanted / 1.1 <= h <= wanted * (1 + 1e-9)  # the nearest whole number of samples across the scan


def test_knots_wider_than_64_spacings_get_a_coarser_lattice_and_say_so(caplog):
    """Knots of ~100 nm under a 20 nm tip (the 2022 gsf scan's): 64 samples a knot, not 0.43 nm apart."""
    law = ZoneLaw.from_law(MaugisDugdale(20e-9, 10e9, 0.1))
    surface = BSplineSurface.from_heights(np.zeros((12, 12)), (0.0, 11 * 100e-9), (0.0, 11 * 100e-9))
    with caplog.at_level("WARNING", logger="arsurf.contact.zone_energy"):
        h = lattice_for(surface, 20e-9, law.interaction_range).spacing[0]
    assert h == pytest.approx(surface.spacing[0] / 64, rel=0.05)
    coarse = f"{surface.spacing[0] / 64 * 1e9:.3g} nm apart, not 0.427 nm"
    assert len(caplog.records) == 1 and coarse in caplog.records[0].getMessage()


def test_a_scan_too_wide_for_the_tiles_gets_a_coarser_lattice_and_says_so(caplog, monkeypatch):
    """A scan whose lattice would have more than MAX_TILES tiles (a 1024^2 scan of 25 nm pixels under
    a 20 nm tip: 14 million) is summed on the finest lattice within them, with a warning, not refused
    (here MAX_TILES lowered to 10 000 on a 60^2 net)."""
    import arsurf.contact.zone_energy as ze

    monkeypatch.setattr(ze, "MAX_TILES", 10_000)
    law = ZoneLaw.from_law(MaugisDugdale(20e-9, 10e9, 0.1))
    surface = BSplineSurface.from_heights(np.zeros((60, 60)), (0.0, 59 * 25e-9), (0.0, 59 * 25e-9))
    with caplog.at_level("WARNING", logger="arsurf.contact.zone_energy"):
        lattice = lattice_for(surface, 20e-9, law.interaction_range)
    tiles = -(-lattice.shape[0] // TILE) * -(-lattice.shape[1] // TILE)
    assert 0.9 * 10_000 <= tiles <= 10_000  # as fine as the tiles allow
    (record,) = caplog.records
    assert f"{lattice.spacing[0] * 1e9:.3g} nm apart, not 0.427 nm" in record.getMessage()
    assert "at most 10000 tiles" in record.getMessage()


@pytest.mark.parametrize("pixel", [1e-9, 4e-9])
@pytest.mark.parametrize("radius", [5e-9, 20e-9])
def test_the_model_s_lattice_sums_the_law_on_a_flat(pixel, radius):
    """On a flat of coarse or fine pixels, from the law's tail to the small-contact limit (contact
    radius 0.4 R) and wherever the tip's axis falls in a lattice cell, the summed load is the law's
    (ZoneLaw.flat_load, exact) within 2 % of the load or of the pull-off 2 pi R w where the load is
    smaller. At R/8 apart (before: the pixels' spacing, at most R/8) the adhesive ring, h0/slope
    wide, fell between the samples: up to 70 % off (bench/zone_quadrature.py)."""
    law = ZoneLaw.from_law(MaugisDugdale(radius, 10e9, 0.1))
    n = int(4.0 * radius / pixel + 16)
    surface = BSplineSurface.from_heights(np.zeros((n, n)), (0.0, (n - 1) * pixel), (0.0, (n - 1) * pixel))
    lattice = lattice_for(surface, radius, law.interaction_range)
    c, h = 0.5 * (n - 1) * pixel, lattice.spacing[0]
    for depth in np.linspace(-0.8 * law.interaction_range, radius * (1.0 - math.sqrt(0.84)), 7):
        exact = law.flat_load(depth)
        for fx, fy in ((0.0, 0.0), (0.5, 0.5), (0.3, 0.17)):
            load = zone_energy(lattice, law, (c + fx * h, c + fy * h, radius - depth))[1][2]
            assert abs(load - exact) <= 0.02 * max(abs(exact), law.pull_off_force()), (depth, fx, fy)


def test_bad_inputs_are_refused_in_one_line(flat):
    with pytest.raises(ContactError, match="center"):
        zone_energy(flat, LAW, (0.0, math.nan, 1e-9))
    with pytest.raises(ContactError, match="contact vector"):  # a material map's, or nothing
        surface_lattice(valley_surface("sinusoid"), material=np.zeros(3))
    for bad in (math.nan, -1.0, "1 nN"):  # below the load at depth 0 (about -2 pi R w), or not a load
        with pytest.raises(ContactError, match="load"):
            LAW.flat_depth(bad)
    with pytest.raises(ContactError, match="effective_modulus"):
        ZoneLaw(R, -1.0, 0.05, 1e8)
    with pytest.raises(ContactError, match="work_of_adhesion"):
        ZoneLaw(R, 50e9, math.inf, 1e8)
    with pytest.raises(ContactError, match="tip_radius"):
        lattice_for(valley_surface("sinusoid"), -1e-9)
    with pytest.raises(ContactError, match="interaction_range"):
        lattice_for(valley_surface("sinusoid"), R, math.nan)
    surface = valley_surface("sinusoid")
    for bad in (0, 65, -1.0, math.nan, True):
        with pytest.raises(SurfaceError, match="per_knot"):
            surface_lattice(surface, bad)
        with pytest.raises(SurfaceError, match="pool"):
            surface_lattice(surface, pool=bad if bad != 65 else 10**9)
    ctrl = surface.control_points.copy()
    ctrl[:, :, 0] += 1e-10 * np.arange(ctrl.shape[1])  # x now varies along v too: not a height field
    skewed = BSplineSurface(ctrl, surface.knots_u, surface.knots_v)
    with pytest.raises(SurfaceError, match="height-field"):
        surface_lattice(skewed)


def test_behind_a_coupling_the_proxy_crosses_the_valley_without_a_step_and_gives_back_its_work(valley):
    """The target swept across the valley narrower than the tip behind a 5 N/m coupling (the
    setting of test_force_field.py's sideways test), the tip followed from where it was: the
    force the hand gets, k (T - C), turns without a step, and round a closed loop of the target
    it does no net work (the proxy stays on one minimum: its force is the gradient of the
    coupled energy's minimum over the tip)."""
    k = 5.0
    z = height_for("sinusoid", 33e-9, 2e-9) - 1e-9
    tip, out = np.array([31.5e-9, 24e-9, z + 10e-9]), ZONE_OUT.zeros()

    def hand_force(target):
        iterations = zone_proxy_kernel(*valley.kernel_args(), *target, k, *LAW.args, tip, out)
        assert iterations >= 0
        return k * (tip - target)

    xs = 33e-9 + np.linspace(-1.5e-9, 1.5e-9, 3001)
    forces = np.array([hand_force(np.array([x, 24e-9, z])) for x in xs])
    steps = np.linalg.norm(np.diff(forces, axis=0), axis=1)
    assert steps.max() <= 1e-3 * np.linalg.norm(forces, axis=1).min()
    t = np.linspace(0.0, 2.0 * np.pi, 2001)
    c = np.array([33.8e-9, 24e-9, z])
    path = c + 0.3e-9 * np.column_stack([np.cos(t), np.zeros_like(t), np.sin(t)])
    hand_force(path[0])
    loop = np.array([hand_force(p) for p in path])
    mid = 0.5 * (loop[1:] + loop[:-1])
    work = np.einsum("ij,ij->i", mid, np.diff(path, axis=0))
    assert abs(work.sum()) <= 1e-5 * np.abs(work).sum()
