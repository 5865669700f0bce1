"""Maugis-Dugdale: limits, critical points, branches, kernel accuracy against a slow reference."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from tests.support.reference import ref_load_depth, ref_min, ref_radius_from_depth, ref_radius_from_load

from arsurf.contact.maugis_dugdale import (
    LAMBDA_TRANSITION,
    MaugisDugdale,
    MDState,
    md_contact_from_depth_kernel,
    md_contact_hysteresis_kernel,
    md_load_from_depth_kernel,
    md_radius_from_depth_kernel,
    md_solve_depth,
    md_solve_load,
    md_zero_radius_limit,
)
from arsurf.contact.mechanics import DMT, JKR, Hertz
from arsurf.errors import ContactError

R = 20e-9          # m
E_STAR = 50e9      # Pa
W = 0.1            # J/m^2
K = 4.0 * E_STAR / 3.0


def md_for_lambda(lam: float, R=R, E=E_STAR, w=W) -> MaugisDugdale:
    """A model with the requested Maugis parameter (sigma0 from lambda = 2 sigma0 (R/(pi w K^2))^1/3)."""
    k = 4.0 * E / 3.0
    sigma0 = 0.5 * lam / (R / (math.pi * w * k * k)) ** (1.0 / 3.0)
    return MaugisDugdale(R, E, w, sigma0)


LAMBDAS = [0.01, 0.0316, 0.1, 0.316, 0.9, 1.0, 3.16, 10.0, 31.6, 100.0]


# ---------------------------------------------------------------------------------------------
# kernel and API against the reference
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("lam", LAMBDAS)
def test_kernel_matches_reference_across_lambda(lam):
    md = md_for_lambda(lam)
    assert md.maugis_parameter == pytest.approx(lam, rel=1e-12)
    fold = ref_min(lambda a: ref_load_depth(a, lam)[1])
    a_lo = max(fold[0] * 1.02 if fold else 1e-2, 1e-2)
    worst = 0.0
    for A in np.geomspace(a_lo, 30.0, 12):
        _, D = ref_load_depth(A, lam)
        A_ref = ref_radius_from_depth(D, lam)
        status, a = md_radius_from_depth_kernel(D * md.depth_scale, *md.kernel_args)
        assert status == 0
        worst = max(worst, abs(a / md.radius_scale / A_ref - 1.0))
    assert worst <= 3e-10, f"lambda={lam}: max relative error {worst:.2e} (the module docstring promises 3e-10)"


@pytest.mark.parametrize("lam", [0.01, 0.3, 1.0, 10.0, 100.0])
def test_load_control_matches_reference(lam):
    md = md_for_lambda(lam)
    A_pull, P_pull = ref_min(lambda a: ref_load_depth(a, lam)[0])
    assert md.pull_off_force() / md.load_scale == pytest.approx(P_pull, abs=1e-9)
    for P in [P_pull + 1e-3, P_pull / 2, 0.0, 1.0, 30.0, 1e3]:
        a = md.contact_radius(load=P * md.load_scale)
        assert a / md.radius_scale == pytest.approx(ref_radius_from_load(P, lam), rel=2e-10)


def test_python_api_equals_kernel_and_handles_arrays():
    md = md_for_lambda(0.7)
    depths = np.linspace(md.jump_out_depth() * 1.5, 3e-9, 101).reshape(1, 101)
    radius = md.contact_radius(depth=depths)
    load = md.load(depths)
    assert radius.shape == depths.shape and load.shape == depths.shape
    for d, a, p in zip(depths.ravel(), radius.ravel(), load.ravel()):
        status, a_k, p_k = md_contact_from_depth_kernel(d, *md.kernel_args)
        assert status in (0, 1, 2)
        assert a_k == a and p_k == p
        assert md_radius_from_depth_kernel(d, *md.kernel_args)[1] == a
        assert md_load_from_depth_kernel(d, *md.kernel_args)[1] == p
    assert isinstance(md.contact_radius(depth=1e-9), float)
    assert np.all(np.isfinite(radius)) and np.all(np.isfinite(load))


def test_kernel_inside_njit_loop_no_exceptions_on_nan():
    md = md_for_lambda(2.0)

    @njit
    def run(depths, out, status, ds, rs, ls, lam, tf, df):
        for i in range(depths.size):
            st_, r = md_radius_from_depth_kernel(depths[i], ds, rs, ls, lam, tf, df)
            out[i] = r
            status[i] = st_

    depths = np.array([1e-9, np.nan, -1.0, np.inf, 0.0])
    out = np.empty(5)
    status = np.empty(5, np.int64)
    run(depths, out, status, *md.kernel_args)
    assert status.tolist() == [0, -1, 2, -1, 0]
    assert out[2] == 0.0


# ---------------------------------------------------------------------------------------------
# limits
# ---------------------------------------------------------------------------------------------

def test_jkr_limit_lambda_100():
    md = md_for_lambda(100.0)
    jkr = JKR(R, E_STAR, W)
    # critical points within 1e-4 (in units of pi w R and of the MD depth unit)
    assert md.pull_off_force() / md.load_scale == pytest.approx(-1.5, abs=1e-4)
    assert md.jump_out_depth() / md.depth_scale == pytest.approx(jkr.jump_out_depth() / md.depth_scale, abs=1e-4)
    cp = md.critical_points()
    assert cp.pull_off_radius == pytest.approx(jkr.contact_radius(load=jkr.pull_off_force()), rel=1e-4)
    assert cp.jump_out_radius / md.radius_scale == pytest.approx(6 ** (-1 / 3), abs=1e-4)

    def p_dev(lam):
        m = md_for_lambda(lam)
        worst = 0.0
        for A in np.geomspace(0.2, 5.0, 25):
            st_ = m.at_radius(A * m.radius_scale)
            P_jkr = A ** 3 - math.sqrt(6 * A ** 3)
            worst = max(worst, abs(st_.load / m.load_scale - P_jkr) / (abs(P_jkr) + 1.0))
        return worst

    # P(a): the MD correction is O(lambda^-2) (about 2e-4 of |P| + pi w R at lambda = 100) ...
    d100, d300 = p_dev(100.0), p_dev(300.0)
    assert d100 <= 3e-4
    assert 7.0 < d100 / d300 < 11.0      # ... and it falls as lambda^-2
    # over the adhesive range (a up to the zero-load radius) it is within 1e-4 at lambda = 100
    for A in np.geomspace(6 ** (-1 / 3), 1.5, 10):
        P_md = md.at_radius(A * md.radius_scale).load / md.load_scale
        assert P_md == pytest.approx(A ** 3 - math.sqrt(6 * A ** 3), abs=1.2e-4)


def test_dmt_limit_small_lambda():
    devs = []
    for lam in [0.1, 0.01, 0.001]:
        md = md_for_lambda(lam)
        devs.append(max(abs(md.at_radius(A * md.radius_scale).load / md.load_scale - (A ** 3 - 2.0))
                        for A in np.geomspace(0.5, 3.0, 10)))
        assert md.pull_off_force() / md.load_scale == pytest.approx(-2.0, abs=3 * lam ** 0.75)
    assert devs[0] > devs[1] > devs[2]
    assert devs[2] < 0.08
    # and the DMT class itself is the limit of the pull-off: -2 pi w R
    assert DMT(R, E_STAR, W).pull_off_force() == pytest.approx(-2 * math.pi * W * R, rel=1e-15)


@pytest.mark.parametrize("w", [1e-3, 1e-5, 1e-7])
def test_hertz_limit_small_work_of_adhesion(w):
    md = MaugisDugdale(R, E_STAR, w)          # default sigma0 = 16 w / (9 sqrt3 z0)
    hertz = Hertz(R, E_STAR)
    for d in [0.2e-9, 1e-9, 3e-9]:
        a = md.contact_radius(depth=d)
        tol = 2e3 * w ** (2 / 3)          # the adhesive correction to a^2 scales as w^(2/3)
        assert a * a / (R * d) == pytest.approx(1.0, abs=tol)
        assert md.load(d) == pytest.approx(hertz.load(d), rel=tol)
    assert abs(md.pull_off_force()) < 2.01 * math.pi * w * R


# ---------------------------------------------------------------------------------------------
# critical points
# ---------------------------------------------------------------------------------------------

def test_pull_off_from_dmt_to_jkr_monotone_and_matches_cos_fit():
    lams = np.geomspace(0.01, 100.0, 25)
    pulls = np.array([md_for_lambda(lam).pull_off_force() / (math.pi * W * R) for lam in lams])
    assert np.all(np.diff(pulls) > 0.0)                   # from -2 (DMT) up to -1.5 (JKR)
    assert -2.0 < pulls[0] < -1.99 and -1.5001 < pulls[-1] < -1.5
    # the empirical Carpick-Ogletree-Salmeron fit, J. Colloid Interface Sci. 211, 395 (1999),
    # an independent check of the whole curve: within 2 % (its worst point is near lambda = 0.3)
    x = 4.04 * lams ** 1.4
    cos_fit = -7.0 / 4.0 + 0.25 * (x - 1.0) / (x + 1.0)
    assert np.allclose(pulls, cos_fit, rtol=2e-2)


def test_maugis_transition_for_jump_out_under_displacement_control():
    assert LAMBDA_TRANSITION == pytest.approx(0.938, abs=5e-4)
    # reference: does Delta(A) have an interior minimum (a fold) just below / above 0.938?
    assert ref_min(lambda a: ref_load_depth(a, 0.93)[1], lo=1e-4, hi=5.0) is None
    assert ref_min(lambda a: ref_load_depth(a, 0.95)[1], lo=1e-4, hi=5.0) is not None
    radii = []
    for lam in [0.5, 0.9, 0.93, 0.945, 0.96, 1.0, 2.0, 10.0]:
        cp = md_for_lambda(lam).critical_points()
        radii.append(cp.jump_out_radius)
        if lam < LAMBDA_TRANSITION:
            # continuous: the contact shrinks to a = 0, then the cohesive neck holds a while
            assert cp.jump_out_radius == 0.0
            assert cp.jump_out_depth < cp.contact_loss_depth
            assert cp.jump_out_load < 0.0
        else:
            # a jump from a finite radius to separation
            assert cp.jump_out_radius > 0.0
            assert cp.jump_out_depth == cp.contact_loss_depth
            assert cp.jump_in_depth > cp.jump_out_depth
    assert np.all(np.diff(radii) >= 0.0)                 # jump-out radius grows from 0 with lambda
    assert radii[-1] / md_for_lambda(10.0).radius_scale == pytest.approx(0.545, abs=2e-3)


def test_jump_out_is_where_displacement_control_loses_stability():
    for lam in [1.5, 5.0]:
        md = md_for_lambda(lam)
        fold = ref_min(lambda a: ref_load_depth(a, lam)[1])
        assert md.jump_out_depth() / md.depth_scale == pytest.approx(fold[1], abs=1e-9)
        d = md.jump_out_depth()
        assert md.contact_state(depth=d + 1e-15).branch == "contact"
        below = md.contact_state(depth=d - 1e-13)
        assert below.branch == "separated" and below.radius == 0.0 and below.load == 0.0


def test_cohesive_neck_is_continuous_then_snaps():
    md = md_for_lambda(0.2)
    cp = md.critical_points()
    eps = 1e-6 * md.depth_scale
    inside = md.contact_state(depth=cp.contact_loss_depth + eps)
    neck = md.contact_state(depth=cp.contact_loss_depth - eps)
    assert inside.branch == "contact" and neck.branch == "cohesive"
    assert neck.load == pytest.approx(inside.load, rel=1e-3)                # no jump in force
    assert neck.cohesive_radius == pytest.approx(inside.cohesive_radius, rel=1e-3)
    assert not neck.in_contact and neck.radius == 0.0 and neck.m == math.inf
    snap = md.contact_state(depth=cp.jump_out_depth - eps)
    assert snap.branch == "separated" and snap.load == 0.0 and snap.cohesive_radius == 0.0
    # the cohesive branch formula: Delta = c^2/2 - 8 lam c /(3 pi) - 2/(lam pi)
    c = neck.cohesive_radius / md.radius_scale
    lam = md.maugis_parameter
    assert (c * c / 2 - 8 * lam * c / (3 * math.pi) - 2 / (lam * math.pi)) * md.depth_scale == pytest.approx(neck.depth, rel=1e-9)


# ---------------------------------------------------------------------------------------------
# hysteresis, branches, flags
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("lam", [0.3, 3.0])
def test_approach_retract_hysteresis(lam):
    md = md_for_lambda(lam)
    lo, hi = md.jump_out_depth(), md.jump_in_depth()
    assert lo < hi < 0.0
    assert hi == pytest.approx(-W / md.dugdale_stress, rel=1e-15)
    between = 0.5 * (lo + hi)
    retract = md.contact_state(depth=between)
    approach = md.contact_state(depth=between, approach=True)
    assert retract.branch in ("contact", "cohesive") and retract.load < 0.0
    assert approach.branch == "separated" and approach.load == 0.0 and approach.radius == 0.0
    # past jump-in both agree
    d = hi + 1e-12
    assert md.contact_state(depth=d, approach=True) == md.contact_state(depth=d)
    # a full cycle: approach, press, retract, and the retract curve lies below (adhesive) or on it
    path = np.sort(np.concatenate([np.linspace(2 * lo, 2e-9, 100), np.linspace(lo, hi, 12)[1:-1]]))
    f_app = md.load(path, approach=True)
    f_ret = md.load(path)
    assert np.all(f_ret <= f_app + 1e-18)
    assert np.any(f_ret < f_app)
    assert np.all(np.isfinite(f_app)) and np.all(np.isfinite(f_ret))


@pytest.mark.parametrize("lam", [0.3, 3.0])
def test_hysteresis_kernel_cycle_matches_api(lam):
    md = md_for_lambda(lam)
    lo, hi = md.jump_out_depth(), md.jump_in_depth()
    down = np.sort(np.concatenate([np.linspace(3 * lo, 2e-9, 80), np.linspace(lo, hi, 8)[1:-1]]))
    path = np.concatenate([down, down[::-1]])                 # approach, press, retract
    interacting = False
    loads = []
    for i, d in enumerate(path):
        status, a, p = md_contact_hysteresis_kernel(d, interacting, *md.kernel_args)
        approaching = i < down.size
        ref = md.contact_state(depth=d, approach=approaching and not interacting)
        assert (a, p) == (ref.radius, ref.load)
        interacting = status in (0, 1)
        loads.append(p)
    loads = np.array(loads)
    assert loads[0] == 0.0 and loads[-1] == 0.0                # starts and ends separated
    app, ret = loads[:down.size], loads[down.size:][::-1]      # the same depths, both ways
    assert np.all(ret <= app) and np.any(ret < app)
    dissipated = np.sum((app - ret)[1:] * np.diff(down))         # area of the loop, J
    assert dissipated > 0.0
    assert md_contact_hysteresis_kernel(math.nan, True, *md.kernel_args)[0] == -1


def test_no_contact_results_are_flagged_not_nan():
    md = md_for_lambda(5.0)
    st_ = md.contact_state(depth=-10e-9)
    assert isinstance(st_, MDState)
    assert (st_.radius, st_.load, st_.in_contact, st_.branch) == (0.0, 0.0, False, "separated")
    below = md.contact_state(load=2 * md.pull_off_force())
    assert below.branch == "separated" and below.radius == 0.0 and below.load == 0.0
    assert below.depth == -math.inf and not below.in_contact
    assert md.contact_radius(load=2 * md.pull_off_force()) == 0.0
    with pytest.raises(ContactError, match="below the pull-off force"):
        md.depth(2 * md.pull_off_force())
    arr = md.contact_state(depth=np.array([-1e-8, 1e-9]))
    assert arr.branch.tolist() == ["separated", "contact"] and arr.in_contact.tolist() == [False, True]


@pytest.mark.parametrize("lam", [0.2, 3.0])
def test_equilibria_lists_stable_and_unstable_branches(lam):
    md = md_for_lambda(lam)
    cp = md.critical_points()
    # displacement control between jump-out and the a -> 0 end: for lambda > 0.938 two contacts
    if lam > LAMBDA_TRANSITION:
        d = 0.5 * (cp.jump_out_depth + md.jump_in_depth())
        eqs = md.equilibria(depth=d)
        contacts = [e for e in eqs if e.branch == "contact"]
        assert [e.stable for e in contacts] == [True, False]
        assert contacts[0].radius > cp.jump_out_radius > contacts[1].radius > 0.0
        for e in contacts:        # both satisfy Maugis' equations
            A = e.radius / md.radius_scale
            assert ref_load_depth(A, lam)[1] * md.depth_scale == pytest.approx(d, rel=1e-7)
    else:
        d = 0.5 * (cp.jump_out_depth + cp.contact_loss_depth)
        eqs = md.equilibria(depth=d)
        coh = [e for e in eqs if e.branch == "cohesive"]
        assert coh[0].stable and coh[0] == md.contact_state(depth=d)
    # load control between pull-off and the a -> 0 end of the branch: a stable and an unstable contact
    P0 = md_zero_radius_limit(lam)[2] * md.load_scale
    P = 0.5 * (md.pull_off_force() + P0)
    eqs = md.equilibria(load=P)
    contacts = [e for e in eqs if e.branch == "contact"]
    assert contacts[0].stable and not contacts[1].stable
    assert contacts[0].radius > cp.pull_off_radius > contacts[1].radius
    for e in contacts:
        A = e.radius / md.radius_scale
        assert ref_load_depth(A, lam)[0] * md.load_scale == pytest.approx(P, rel=1e-7)
    # below the a -> 0 load only the cohesive (no-contact) state remains, unstable under load control
    coh = [e for e in md.equilibria(load=0.5 * P0) if e.branch == "cohesive"]
    assert len(coh) == 1 and not coh[0].stable and coh[0].radius == 0.0


# ---------------------------------------------------------------------------------------------
# round trips (hypothesis)
# ---------------------------------------------------------------------------------------------

@settings(max_examples=40, deadline=None)
@given(log_lam=st.floats(-2.0, 2.0), u=st.floats(0.0, 1.0))
def test_round_trip_depth_radius_load(log_lam, u):
    md = md_for_lambda(10.0 ** log_lam)
    cp = md.critical_points()
    d = cp.contact_loss_depth + 1e-3 * md.depth_scale + u * (4e-9 - cp.contact_loss_depth)
    a = md.contact_radius(depth=d)
    p = md.load(d)
    at = md.at_radius(a)                                 # radius -> (load, depth)
    assert at.depth == pytest.approx(d, rel=1e-8, abs=1e-9 * md.depth_scale)
    assert at.load == pytest.approx(p, rel=1e-8, abs=1e-9 * md.load_scale)
    if a >= cp.pull_off_radius:                          # load control sees the same state
        assert md.depth(p) == pytest.approx(d, rel=1e-7, abs=1e-8 * md.depth_scale)
        assert md.contact_radius(load=p) == pytest.approx(a, rel=1e-7)


@settings(max_examples=40, deadline=None)
@given(log_lam=st.floats(-2.0, 2.0), u=st.floats(0.0, 1.0), v=st.floats(0.0, 1.0))
def test_stable_branch_is_monotone(log_lam, u, v):
    md = md_for_lambda(10.0 ** log_lam)
    d1, d2 = sorted(md.jump_out_depth() + np.array([u, v]) * 5e-9)
    assert md.contact_radius(depth=d1) <= md.contact_radius(depth=d2)
    p1, p2 = sorted(md.pull_off_force() + np.array([u, v]) * 1e-7)
    assert md.contact_radius(load=p1) <= md.contact_radius(load=p2)


# ---------------------------------------------------------------------------------------------
# the non-dimensional kernels directly
# ---------------------------------------------------------------------------------------------

def test_nondimensional_kernels_edges():
    md = md_for_lambda(3.0)
    ds, rs, ls, lam, tf, df = md.kernel_args
    st_, A, P, c = md_solve_depth(df, lam, tf, df)          # exactly at the fold
    assert st_ == 0 and A * rs == pytest.approx(md.critical_points().jump_out_radius, rel=1e-12)
    assert md_solve_depth(df - 1e-12, lam, tf, df)[0] == 2
    assert md_solve_depth(math.nan, lam, tf, df)[0] == -1
    p_pull = md.pull_off_force() / ls
    assert md_solve_load(p_pull - 1e-9, lam, md._t_pull, p_pull)[0] == 2
    assert md_solve_load(math.inf, lam, md._t_pull, p_pull)[0] == -1
    # huge depths (w -> 0 regime): still converges, Hertz-like A^2 ~ Delta
    st_, A, P, c = md_solve_depth(1e8, lam, tf, df)
    assert st_ == 0 and A * A == pytest.approx(1e8, rel=1e-3)


# ---------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------

def test_bad_input_raises_clear_errors():
    with pytest.raises(ContactError, match="tip_radius.*positive"):
        MaugisDugdale(-1e-9, E_STAR, W, 1e9)
    with pytest.raises(ContactError, match="effective_modulus.*positive"):
        MaugisDugdale(R, -5.0, W, 1e9)
    with pytest.raises(ContactError, match="work_of_adhesion.*>= 0"):
        MaugisDugdale(R, E_STAR, -0.1, 1e9)
    with pytest.raises(ContactError, match="work_of_adhesion.*> 0 for Maugis-Dugdale.*Hertz"):
        MaugisDugdale(R, E_STAR, 0.0, 1e9)
    with pytest.raises(ContactError, match="dugdale_stress.*positive"):
        MaugisDugdale(R, E_STAR, W, 0.0)
    with pytest.raises(ContactError, match="tip_radius.*nan"):
        MaugisDugdale(math.nan, E_STAR, W, 1e9)
    md = md_for_lambda(1.0)
    with pytest.raises(ContactError, match=r"`depth` must be finite \(got nan"):
        md.contact_radius(depth=math.nan)
    with pytest.raises(ContactError, match=r"`depth` must be finite.*index \[1\]"):
        md.load(np.array([0.0, np.nan]))
    with pytest.raises(ContactError, match="`load` must be finite"):
        md.depth(math.inf)
    with pytest.raises(ContactError, match="exactly one of"):
        md.contact_radius()
    with pytest.raises(ContactError, match="exactly one of"):
        md.contact_state(depth=1e-9, load=1e-9)
    with pytest.raises(ContactError, match="lambda .* outside"):
        MaugisDugdale(R, E_STAR, W, 1e-3)


# ---------------------------------------------------------------------------------------------
# ContactEngineering's Adhesion package as an oracle (optional)
# ---------------------------------------------------------------------------------------------

def test_adhesion_package_oracle():
    AMD = pytest.importorskip("Adhesion.ReferenceSolutions.MaugisDugdale")
    for lam in [0.05, 0.5, 2.0, 20.0]:
        md = md_for_lambda(lam)
        sigma0 = md.dugdale_stress
        for a in np.array([0.5, 1.0, 2.0, 4.0]) * md.radius_scale:
            P, d = AMD.load_and_displacement(np.array([a]), R, E_STAR, W, sigma0)
            st_ = md.at_radius(a)
            # Adhesion solves m by brentq with its default xtol 2e-12 on m: ~1e-7 relative near m = 1
            assert st_.load == pytest.approx(P[0], rel=1e-6, abs=1e-6 * md.load_scale)
            assert st_.depth == pytest.approx(d[0], rel=1e-6, abs=1e-6 * md.depth_scale)
