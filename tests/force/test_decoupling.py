"""Decoupling: round trip over >= 10,000 fixed-seed cases against an explicit numpy solve,
degenerate cases flagged with a sane fallback, the motion method vs [MWCNT] Eq. 6, bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.support.reference import reference_condition, reference_decouple, reference_matrix

from arsurf.errors import ForceError
from arsurf.force.cantilever import Cantilever
from arsurf.force.decoupling import (
    DEFAULT_MAX_CONDITION,
    DecouplingFlag,
    ForceEstimate,
    decouple,
    decouple_by_motion,
    decouple_kernel,
    decouple_many,
    decoupling_parameters,
    directional_noise_kernel,
    method_from_status,
)

LEVERS = [
    Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27),  # [Alabdulmuhsin] contact lever
    Cantilever(125e-6, 30e-6, 4.0e-6, 10e-6, 169e9, 0.27, normal_stiffness=38.6),  # [MWCNT]-like stiff lever
    Cantilever(220e-6, 27e-6, 2.9e-6, 0.0, 150e9, 0.17, beta=1 / 3),  # [Bolopion] tipless
]
ALL_DEGENERATE = (DecouplingFlag.NO_MOTION | DecouplingFlag.STEEP_NORMAL | DecouplingFlag.SINGULAR
                  | DecouplingFlag.ILL_CONDITIONED)


def random_cases(rng, size, degenerate=False):
    """Unit normals (n_z >= 0.02), horizontal velocities, forces in the plane of n and f.

    With ``degenerate``, 3 % of the cases stand still, 3 % have wall normals (n_z < 0.01) and
    6 % move within 10^-12..10^-1 rad of the singular direction.
    """
    n = rng.normal(size=(size, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    n[:, 2] = np.abs(n[:, 2])
    steep = n[:, 2] < 0.02
    n[steep, 2] = 0.02 + rng.uniform(0, 0.5, steep.sum())
    n /= np.linalg.norm(n, axis=1)[:, None]
    speed = 10 ** rng.uniform(-9, -5, size)
    ang = rng.uniform(0, 2 * np.pi, size)
    if degenerate:
        kind = rng.uniform(size=size)
        wall = kind < 0.03
        nz = rng.uniform(0, 0.009, wall.sum())
        az = rng.uniform(0, 2 * np.pi, wall.sum())
        n[wall] = np.column_stack([np.sqrt(1 - nz**2) * np.cos(az), np.sqrt(1 - nz**2) * np.sin(az), nz])
        speed[(kind >= 0.03) & (kind < 0.06)] = 0.0
        near = kind >= 0.94
        # det(v) = p_x - kappa p_z is linear in (v_x, v_y) for p = n x (n_z f): find its zero direction
        nn = n[near]
        kappa = 2 * LEVERS[0].lever_arm / LEVERS[0].length

        def det(vx, vy):
            f = np.column_stack([-vx * nn[:, 2], -vy * nn[:, 2], vx * nn[:, 0] + vy * nn[:, 1]])
            p = np.cross(nn, f)
            return p[:, 0] - kappa * p[:, 2]

        one, zero = np.ones(len(nn)), np.zeros(len(nn))
        a, b = det(one, zero), det(zero, one)
        ang[near] = np.arctan2(-a, b) + rng.choice([-1, 1], len(nn)) * 10 ** rng.uniform(-12, -1, len(nn))
    v = np.column_stack([speed * np.cos(ang), speed * np.sin(ang), rng.normal(0, 1e-7, size)])
    fz = (v[:, 0] * n[:, 0] + v[:, 1] * n[:, 1]) / n[:, 2]
    f = np.column_stack([-v[:, 0], -v[:, 1], fz])
    fnorm = np.linalg.norm(f, axis=1)
    f = np.divide(f, fnorm[:, None], out=np.zeros_like(f), where=fnorm[:, None] > 0)
    big_n = rng.uniform(0.0, 100e-9, size)
    big_t = rng.uniform(-60e-9, 60e-9, size)
    forces = big_n[:, None] * n + big_t[:, None] * f
    return n, v, forces


# ---- round trip ----------------------------------------------------------------------------------
@pytest.mark.parametrize("lever_index", [0, 1, 2])
def test_round_trip_sweep(lever_index):
    lever = LEVERS[lever_index]
    rng = np.random.default_rng(1000 + lever_index)
    size = 12000
    n, v, forces = random_cases(rng, size, degenerate=lever_index == 0)
    bending, torsion = lever.angles(forces)
    got, status, cond = decouple_many(bending, torsion, n, v, lever)
    still = np.hypot(v[:, 0], v[:, 1]) == 0.0
    wall = n[:, 2] < 0.01
    assert np.all(status[still] & DecouplingFlag.NO_MOTION)
    assert np.all(status[wall] & DecouplingFlag.STEEP_NORMAL)
    assert not np.any(status[~still] & DecouplingFlag.NO_MOTION)
    assert not np.any(status[~wall] & DecouplingFlag.STEEP_NORMAL)
    solvable = ~(still | wall)
    ref_cond = np.full(size, np.inf)
    ref_cond[solvable] = [reference_condition(n[i], v[i], lever) for i in np.flatnonzero(solvable)]
    well = status == 0
    assert well.mean() > 0.8
    # every ill-conditioned / singular case is flagged, and only those (ties within 1e-9 not decided)
    clear = solvable & (np.abs(ref_cond / DEFAULT_MAX_CONDITION - 1) > 1e-9)
    bad_cond = (status & (DecouplingFlag.SINGULAR | DecouplingFlag.ILL_CONDITIONED)) != 0
    assert np.array_equal(bad_cond[clear], (ref_cond > DEFAULT_MAX_CONDITION)[clear])
    if lever_index == 0:
        assert bad_cond.sum() > 400 and still.sum() > 200 and wall.sum() > 200
    assert np.all((status[~well] & ALL_DEGENERATE) != 0)
    assert np.allclose(cond[well], ref_cond[well], rtol=1e-9)
    # recovery where well conditioned: 1e-9 relative to |F|
    scale = np.linalg.norm(forces, axis=1)
    rel = np.linalg.norm(got - forces, axis=1) / scale
    assert rel[well].max() < 1e-9
    # against the explicit numpy.linalg.solve of the literal system
    for i in np.flatnonzero(well)[:2000]:
        ref = reference_decouple(bending[i], torsion[i], n[i], v[i], lever)
        assert np.linalg.norm(got[i] - ref) <= 1e-9 * scale[i]
    # every returned force, flagged or not, is finite and reproduces both measured angles
    assert np.all(np.isfinite(got))
    b2, t2 = lever.angles(got)
    assert np.allclose(b2, bending, rtol=1e-9, atol=1e-12 * np.abs(bending).max())
    assert np.allclose(t2, torsion, rtol=1e-9, atol=1e-12 * np.abs(torsion).max())


def test_python_api_matches_kernel_loop():
    lever = LEVERS[0]
    n, v, forces = random_cases(np.random.default_rng(77), 300)
    bending, torsion = lever.angles(forces)
    many, status, cond = decouple_many(bending, torsion, n, v, lever)
    for i in range(300):
        est = decouple(bending[i], torsion[i], n[i], v[i], lever)
        assert isinstance(est, ForceEstimate)
        assert np.array_equal(est.force, many[i])
        assert int(est.flags) == status[i] and est.condition == cond[i]
        assert est.method == method_from_status(status[i])
        assert est.ok == (status[i] == 0)
    assert not est.force.flags.writeable


@settings(max_examples=200, deadline=None)
@given(
    st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(0.0, 1.0),
    st.floats(-1e-5, 1e-5), st.floats(-1e-5, 1e-5),
    st.floats(-1e-7, 1e-7), st.floats(-1e-7, 1e-7),
)
def test_any_valid_input_gives_a_finite_consistent_force(nx, ny, nz, vx, vy, fx_sig, fy_sig):
    """No garbage: whatever the geometry, the answer is finite and explains both angles."""
    n = np.array([nx, ny, nz])
    if np.linalg.norm(n) < 1e-3:
        n = np.array([0.0, 0.0, 1.0])
    n /= np.linalg.norm(n)
    lever = LEVERS[0]
    bending, torsion = fx_sig * 1e-3, fy_sig * 1e-3
    est = decouple(bending, torsion, n, [vx, vy], lever)
    assert np.all(np.isfinite(est.force)) and np.isfinite(est.condition)
    b2, t2 = lever.angles(est.force)
    assert b2 == pytest.approx(bending, rel=1e-9, abs=1e-20)
    assert t2 == pytest.approx(torsion, rel=1e-9, abs=1e-20)
    if est.ok:
        assert est.method == "contact_normal" and est.condition <= DEFAULT_MAX_CONDITION


# ---- degenerate cases ----------------------------------------------------------------------------
def _singular_velocity(n, lever):
    """Horizontal direction of motion for which p_x = kappa p_z (det is linear in v)."""
    kappa = lever.coupling

    def det(v):
        _, p, _ = reference_matrix(n, np.array([v[0], v[1], 0.0]), lever)
        return p[0] - kappa * p[2]

    a, b = det((1.0, 0.0)), det((0.0, 1.0))
    return np.array([b, -a]) / math.hypot(a, b)


def test_no_motion_flagged_and_falls_back_along_normal():
    lever = LEVERS[0]
    n = np.array([0.3, -0.2, 0.0])
    n[2] = math.sqrt(1 - n[0] ** 2 - n[1] ** 2)
    force = 40e-9 * n + np.array([0.0, 5e-9, 0.0])  # along n plus a lateral part
    b, t = lever.angles(force)
    for v in ([0.0, 0.0, 0.0], [0.0, 0.0, 1e-6], [1e-13, -1e-13]):
        est = decouple(b, t, n, v, lever)
        assert est.flags == DecouplingFlag.NO_MOTION
        assert est.method == "normal_plus_torsion"
        # the fallback model F = N n + T e_y is exact for this force
        assert np.allclose(est.force, force, rtol=1e-12, atol=1e-21)


def test_steep_normal_flagged():
    lever = LEVERS[0]
    n = np.array([0.0, math.sqrt(1 - 0.005**2), 0.005])
    b, t = lever.angles([1e-9, 2e-9, 3e-9])
    est = decouple(b, t, n, [1e-6, 0.0], lever)
    assert est.flags & DecouplingFlag.STEEP_NORMAL
    assert est.method == "normal_plus_torsion"
    assert np.all(np.isfinite(est.force))
    # with a lower threshold the same normal is accepted
    est2 = decouple(b, t, n, [1e-6, 0.0], lever, min_normal_z=1e-3)
    assert not est2.flags & DecouplingFlag.STEEP_NORMAL


def test_flat_surface_motion_along_beam_is_singular():
    lever = LEVERS[0]
    force = np.array([-5e-9, 0.0, 30e-9])
    b, t = lever.angles(force)
    est = decouple(b, t, [0.0, 0.0, 1.0], [1e-6, 0.0, 0.0], lever)
    assert est.flags == DecouplingFlag.SINGULAR
    assert est.method == "normal_plus_torsion"
    # friction along x cannot be separated from F_z: the fallback puts the bending in F_z
    assert est.force == pytest.approx([0.0, 0.0, b / lever.bending_compliance], abs=1e-20)


@pytest.mark.parametrize("angle_deg", [60.0, 10.0, 1.0, 0.3])
def test_directional_noise_gain_matches_the_scatter_of_noisy_solutions(angle_deg):
    """sigma_Fx of directional_noise_kernel is the rms scatter of F_x over angles with independent
    noise (first-order exact: the solve is linear in the signals); it grows as the motion turns
    towards the beam axis, and stays below the condition-number bound cond * ||noise||."""
    lever = LEVERS[0]
    params = decoupling_parameters(lever)
    n = np.array([0.1, 0.05, 1.0])
    n /= np.linalg.norm(n)
    phi = math.radians(angle_deg)
    v = (1e-6 * math.cos(phi), 1e-6 * math.sin(phi))
    sb, st = 2e-7, 3e-7
    b0, t0 = lever.angles(np.array([-5e-9, 2e-9, 60e-9]))
    rng = np.random.default_rng(3)
    fx, out = np.empty(4000), np.empty(4)
    for i in range(fx.size):
        assert decouple_kernel(b0 + sb * rng.standard_normal(), t0 + st * rng.standard_normal(), *n, *v,
                               params, out) == 0
        fx[i] = out[0]
    sigma = directional_noise_kernel(*n, *v, params, sb, st)
    assert fx.std() == pytest.approx(sigma, rel=0.05)
    g, _, c = lever.kernel_parameters()
    assert sigma <= out[3] * math.hypot(sb / g, st / c)  # ||M^-1|| <= cond / ||M|| and ||M||_1 >= 1
    if angle_deg < 60.0:
        assert sigma > directional_noise_kernel(*n, 1e-6 * math.cos(math.radians(60.0)),
                                                1e-6 * math.sin(math.radians(60.0)), params, sb, st)


@pytest.mark.parametrize("seed", range(20))
def test_general_singular_direction_and_its_neighbourhood(seed):
    lever = LEVERS[seed % 3]
    rng = np.random.default_rng(seed)
    n = rng.normal(size=3)
    n[2] = abs(n[2]) + 0.3
    n /= np.linalg.norm(n)
    u = _singular_velocity(n, lever)
    b, t = lever.angles([2e-9, -1e-9, 20e-9])
    est = decouple(b, t, n, 1e-6 * u, lever)
    assert est.flags & (DecouplingFlag.SINGULAR | DecouplingFlag.ILL_CONDITIONED)
    assert est.method == "normal_plus_torsion"
    # rotate the motion away from the singular direction: ill-conditioned, then accepted
    for angle, expect_flag in ((1e-6, True), (0.3, False)):
        r = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
        vv = 1e-6 * (r @ u)
        est = decouple(b, t, n, vv, lever)
        ref = reference_condition(n, np.append(vv, 0.0), lever)
        assert bool(est.flags) == expect_flag == (ref > DEFAULT_MAX_CONDITION)


def test_fallback_degenerate_goes_to_bending_only():
    lever = LEVERS[0]
    kappa = lever.coupling
    gamma = math.atan(1 / kappa)  # n_z + kappa n_x = cos(g) - kappa sin(g) = 0
    n = np.array([-math.sin(gamma), 0.0, math.cos(gamma)])
    assert n[2] > 0.01  # not a wall, so only the fallback is degenerate
    b, t = lever.angles([0.0, 3e-9, 10e-9])
    est = decouple(b, t, n, [0.0, 0.0], lever)
    assert est.flags == DecouplingFlag.NO_MOTION | DecouplingFlag.FALLBACK_DEGENERATE
    assert est.method == "bending_only"
    assert est.force == pytest.approx([0.0, 3e-9, 10e-9], rel=1e-12)


def test_kernel_status_on_invalid_input():
    lever = LEVERS[0]
    params = decoupling_parameters(lever)
    out = np.full(4, 7.0)
    assert decouple_kernel(np.nan, 0.0, 0.0, 0.0, 1.0, 1e-6, 0.0, params, out) == DecouplingFlag.INVALID_INPUT
    assert np.array_equal(out[:3], [0.0, 0.0, 0.0]) and np.isinf(out[3])
    assert decouple_kernel(0.0, 0.0, 0.0, 0.0, 2.0, 1e-6, 0.0, params, out) == DecouplingFlag.INVALID_INPUT
    assert decouple_kernel(0.0, 0.0, 0.0, 0.0, 0.0, 1e-6, 0.0, params, out) == DecouplingFlag.INVALID_INPUT
    assert decouple_kernel(0.0, 0.0, 0.0, 0.0, 1.0, np.inf, 0.0, params, out) == DecouplingFlag.INVALID_INPUT
    assert method_from_status(DecouplingFlag.INVALID_INPUT) == "none"
    assert decouple_kernel(1e-4, 1e-4, 0.0, 0.0, 1.0, 0.0, 1e-6, params, out) == 0


def test_the_blend_relative_to_a_model_force_keeps_a_zero_force_on_invalid_input():
    """Decoupled relative to the model's force (the measured force of a contact), invalid signals
    still give INVALID_INPUT and a zero force, not the model's force passed off as measured."""
    from arsurf.force.decoupling import MEASURED_SCRATCH, blended_decouple_kernel

    params = np.append(decoupling_parameters(LEVERS[0]), 1e-7)
    out = np.full(MEASURED_SCRATCH.size, 7.0)
    st = blended_decouple_kernel(np.nan, 0.0, 0.0, 0.0, 1.0, 0.3, 1.0, 1.0, 0.0, 0.0, 1e-9, 1e-9, 2e-9, 5e-9,
                                 params, out)
    assert st & DecouplingFlag.INVALID_INPUT and np.array_equal(out[:3], [0.0, 0.0, 0.0])


# ---- decoupling by the motion direction ([MWCNT], [Alabdulmuhsin]) ------------------------------------------
def seed000_eq6(s_v, s_h, k, k_v, k_h, k_ct, h_t, b, l_c, alpha):
    """[MWCNT] Eq. 6 in its own frame (x lateral, y along the beam), 'c tan' read as cot."""
    fx = k_ct * k_h * s_h / (h_t + b / 2)
    fy = fx / math.tan(alpha)
    fz = k * k_v * s_v - fy * (h_t + b / 2) / l_c
    return fx, fy, fz


@pytest.mark.parametrize("alpha_deg", [15.0, 45.0, 80.0, 120.0, -60.0])
def test_motion_method_reproduces_seed000_eq6(alpha_deg):
    lever = LEVERS[1]
    k_v, k_h = 706e-9, 0.00565  # [MWCNT] sensitivities
    s_v, s_h = 0.31, -0.07
    alpha = math.radians(alpha_deg)
    # the same measurement as angles: torsion = k_h S_h; bending such that beta = k delta = k k_v S_v
    torsion = k_h * s_h
    bending = lever.bending_compliance * lever.normal_stiffness * k_v * s_v
    est = decouple_by_motion(bending, torsion, [math.cos(alpha), math.sin(alpha)], lever,
                             coupling=lever.lever_arm / lever.length)
    fx_s, fy_s, fz_s = seed000_eq6(s_v, s_h, lever.normal_stiffness, k_v, k_h, lever.torsional_stiffness,
                                   lever.tip_height, lever.thickness, lever.length, alpha)
    # [MWCNT]'s lateral x is our y, its beam axis y is our x
    assert est.method == "motion_direction"
    assert est.force == pytest.approx([fy_s, fx_s, fz_s], rel=1e-12)


def test_motion_method_round_trip_and_equivalence_with_flat_normal():
    lever = LEVERS[0]
    rng = np.random.default_rng(5)
    for _ in range(500):
        phi = rng.uniform(0, 2 * np.pi)
        v = 1e-6 * np.array([math.cos(phi), math.sin(phi)])
        friction = rng.uniform(0, 30e-9)
        force = np.array([-friction * math.cos(phi), -friction * math.sin(phi), rng.uniform(0, 80e-9)])
        b, t = lever.angles(force)
        est = decouple_by_motion(b, t, v, lever)
        flat = decouple(b, t, [0.0, 0.0, 1.0], v, lever)
        assert np.array_equal(est.force, flat.force) and est.flags == flat.flags
        if est.ok:
            assert np.linalg.norm(est.force - force) <= 1e-9 * np.linalg.norm(force)
        else:
            assert est.method == "bending_only"
            assert est.force[0] == 0.0 and est.force[2] == pytest.approx(b / lever.bending_compliance)


def test_motion_method_degenerate():
    lever = LEVERS[0]
    b, t = lever.angles([-3e-9, 0.0, 20e-9])
    along_beam = decouple_by_motion(b, t, [1e-6, 0.0], lever)  # tan(phi) = 0: [Alabdulmuhsin]'s unmeasurable case
    assert along_beam.flags == DecouplingFlag.SINGULAR and along_beam.method == "bending_only"
    still = decouple_by_motion(b, t, [0.0, 0.0, 0.0], lever)
    assert still.flags == DecouplingFlag.NO_MOTION and still.method == "bending_only"
    nearly = decouple_by_motion(b, t, [1e-6, 1e-10], lever)
    assert nearly.flags == DecouplingFlag.ILL_CONDITIONED


# ---- bad input -----------------------------------------------------------------------------------
def test_bad_input_raises():
    lever = LEVERS[0]
    n, v = [0.0, 0.0, 1.0], [1e-6, 0.0]
    with pytest.raises(ForceError, match="bending must be finite"):
        decouple(float("nan"), 0.0, n, v, lever)
    with pytest.raises(ForceError, match="torsion must be finite"):
        decouple(0.0, float("inf"), n, v, lever)
    with pytest.raises(ForceError, match="bending must be a real number"):
        decouple("0.1", 0.0, n, v, lever)
    with pytest.raises(ForceError, match="normal is the zero vector"):
        decouple(0.0, 0.0, [0.0, 0.0, 0.0], v, lever)
    with pytest.raises(ForceError, match=r"normal must be a unit vector \(got \|n\| = 2\)"):
        decouple(0.0, 0.0, [0.0, 0.0, 2.0], v, lever)
    with pytest.raises(ForceError, match=r"normal must have shape \(3,\)"):
        decouple(0.0, 0.0, [0.0, 1.0], v, lever)
    with pytest.raises(ForceError, match="normal must be finite"):
        decouple(0.0, 0.0, [np.nan, 0.0, 1.0], v, lever)
    with pytest.raises(ForceError, match=r"velocity must have shape \(2,\) or \(3,\)"):
        decouple(0.0, 0.0, n, [1.0], lever)
    with pytest.raises(ForceError, match="velocity must be finite"):
        decouple(0.0, 0.0, n, [np.nan, 0.0], lever)
    with pytest.raises(ForceError, match="cantilever must be an arsurf Cantilever"):
        decouple(0.0, 0.0, n, v, "lever")
    with pytest.raises(ForceError, match="max_condition must be >= 1"):
        decouple(0.0, 0.0, n, v, lever, max_condition=0.5)
    with pytest.raises(ForceError, match=r"min_normal_z must be in \[0, 1\)"):
        decouple(0.0, 0.0, n, v, lever, min_normal_z=1.0)
    with pytest.raises(ForceError, match="min_speed must be >= 0"):
        decouple(0.0, 0.0, n, v, lever, min_speed=-1.0)
    with pytest.raises(ForceError, match="coupling must be >= 0"):
        decouple_by_motion(0.0, 0.0, v, lever, coupling=-0.1)
    with pytest.raises(ForceError, match="bending must be finite"):
        decouple_by_motion(np.nan, 0.0, v, lever)
    with pytest.raises(ForceError, match=r"1 NaN or infinite samples \(first at index 1\)"):
        decouple_many([0.0, np.nan], [0.0, 0.0], np.tile(n, (2, 1)), np.tile(v, (2, 1)), lever)
    with pytest.raises(ForceError, match=r"row 1 has \|n\| = 0.5"):
        decouple_many([0.0, 0.0], [0.0, 0.0], [[0, 0, 1.0], [0, 0, 0.5]], np.tile(v, (2, 1)), lever)
    with pytest.raises(ForceError, match=r"normals must have shape \(2, 3\)"):
        decouple_many([0.0, 0.0], [0.0, 0.0], [[0, 0, 1.0]], np.tile(v, (2, 1)), lever)
