"""The tip behind the virtual coupling: the coupling's Newton runs (along the contact branch, in
depth) and the memo of their last answers."""
import math

import numpy as np
import pytest

from arsurf.contact.maugis_dugdale import LAMBDA_TRANSITION, MaugisDugdale, md_contact_hysteresis_kernel
from arsurf.contact.proxy import BRANCH_TOLERANCE, MD_MEMO, _branch_coupled, _depth_coupled, coupled_depth_kernel
from arsurf.status import COHESIVE, CONTACT

R = 20e-9
K_C = 2.0  # N/m at the probe


def _law(e_star=50e9, w=0.05):
    """(law, (jump-out depth, zero-load depth) m, kernel arguments), as the model gives them."""
    md = MaugisDugdale(R, e_star, w)
    return md, (md.jump_out_depth(), float(md.depth(0.0))), md.kernel_args


def _slide(targets, law, memo_kept, solve=coupled_depth_kernel, k_c=K_C):
    """The coupled depth along ``targets`` (m), each tick started from the last depth, with the
    memo kept between ticks or emptied before each (the solve without it)."""
    md, (jump_out, zero_load), args = law
    memo = MD_MEMO.full(np.nan)
    depth, interacting, rows = math.nan, False, []
    for t in targets:
        if not memo_kept:
            memo[:] = np.nan
        st, a, load, depth, coupled = solve(t, depth if interacting else math.nan, interacting, k_c,
                                            jump_out, zero_load, *args, memo)
        interacting = st in (0, 1)
        rows.append((st, a, load, depth, coupled))
    return rows, memo


def test_the_memo_gives_the_solves_answers_bit_for_bit():
    """A press and a slow pull-off through the coupling, solved in depth: with the memo of the
    last answer kept between ticks the run gives, every tick, the same status, radius, load and
    depth as the solve without it; the memo ends holding the last depth with its answer and law."""
    law = _law()
    targets = np.concatenate([np.linspace(-0.2e-9, 1.5e-9, 400), np.linspace(1.5e-9, -1.0e-9, 600)])
    kept, memo = _slide(targets, law, True, _depth_coupled)
    fresh, _ = _slide(targets, law, False, _depth_coupled)
    assert kept == fresh                                                  # exact tuples: bit for bit
    assert sum(r[4] for r in kept) > 500 and any(r[0] == CONTACT for r in kept)
    last = [r for r in kept if r[4]][-1]
    assert memo[MD_MEMO.offset("depth")] == last[3] or not kept[-1][4]
    assert tuple(memo[MD_MEMO.offset("law"):MD_MEMO.offset("law") + 6]) == tuple(law[2])


def test_the_memo_never_answers_for_another_law():
    """A memo made under one contact law (a material map changes the law from point to point)
    is not used under another at the same depth: the answer is the other law's own."""
    from arsurf.contact.maugis_dugdale import md_contact_hysteresis_kernel
    from arsurf.contact.proxy import _md_interacting

    soft, stiff = _law(e_star=2e9)[2], _law(e_star=50e9)[2]
    depth = 0.3e-9
    memo = MD_MEMO.full(np.nan)
    assert _md_interacting(depth, *soft, memo) == md_contact_hysteresis_kernel(depth, True, *soft)
    assert memo[MD_MEMO.offset("depth")] == depth                       # the soft law's answer is kept
    assert _md_interacting(depth, *soft, memo) == md_contact_hysteresis_kernel(depth, True, *soft)  # found
    want = md_contact_hysteresis_kernel(depth, True, *stiff)
    assert want != md_contact_hysteresis_kernel(depth, True, *soft)
    assert _md_interacting(depth, *stiff, memo) == want


#: (E* Pa, w J/m^2, k_c N/m): Maugis' lambda from 0.02 (DMT-like, no fold: a cohesive neck) to 4.7
#: (JKR-like, a fold), couplings from far softer to far stiffer than the contact
LAWS = [(200e9, 0.02, 1.0), (50e9, 0.05, 2.0), (10e9, 0.1, 2.0), (10e9, 0.1, 0.05), (2e9, 0.1, 20.0),
        (1e9, 0.3, 0.5), (50e9, 0.05, 200.0)]


@pytest.mark.parametrize("e_star, w, k_c", LAWS)
def test_the_solve_along_the_branch_agrees_with_the_solve_in_depth(e_star, w, k_c):
    """A press to 6 depth scales and a pull-off through the jump-out: the tick (along the contact
    branch where it can) gives the status and coupled flag of the solve in depth on the law's
    solves every tick, and its depth, load and radius within BRANCH_TOLERANCE of the law's scales;
    it solved along the branch on most contact ticks; its answers balance the coupling and lie on
    the law; the same run with the memo emptied before every tick (cold starts) agrees as well."""
    law = _law(e_star, w)
    md, (jump_out, zero_load), args = law
    ds, rs, ps = args[:3]
    targets = np.concatenate([np.linspace(-1.5 * ds, 6 * ds, 500), np.linspace(6 * ds, jump_out - 3 * ds, 700)])
    ref, _ = _slide(targets, law, True, _depth_coupled, k_c)
    for kept in (True, False):
        rows, memo = _slide(targets, law, kept, k_c=k_c)
        assert [r[0] for r in rows] == [r[0] for r in ref] and [r[4] for r in rows] == [r[4] for r in ref]
        got, want = np.array([r[1:4] for r in rows]), np.array([r[1:4] for r in ref])
        err = np.abs(got - want) / np.array([rs, ps, ds])
        assert err.max() <= BRANCH_TOLERANCE, err.max(axis=0)
    coupled_contact = [(t, r) for t, r in zip(targets, rows) if r[0] == CONTACT and r[4]]
    assert len(coupled_contact) > 300
    for t, (st, a, load, depth, _) in coupled_contact:
        assert abs(load - k_c * (t - depth)) <= 1e-9 * ps                  # the coupling balanced
        s2, a2, p2 = md_contact_hysteresis_kernel(depth, True, *args)       # on the law at that depth (its
        assert s2 == CONTACT and max(abs(a2 - a) / rs, abs(p2 - load) / ps) <= BRANCH_TOLERANCE  # solve's error)
    # the branch took the contact ticks: its own run answers them from the previous tick's t
    memo = MD_MEMO.full(np.nan)
    on_branch = 0
    previous = math.nan
    for t, (st, a, load, depth, _) in coupled_contact:
        lo, hi = (jump_out, t) if t > zero_load else (t, max(zero_load, t))
        ok, a2, p2, d2 = _branch_coupled(t, previous, lo, hi, k_c, *args, memo)
        on_branch += ok
        previous = depth
    assert on_branch >= 0.9 * len(coupled_contact)


def test_the_cohesive_neck_is_solved_in_depth():
    """A fold-free law (lambda < lambda_t) pulled off slowly behind a stiff coupling: ticks whose
    equilibrium is on the cohesive neck (no contact radius, adhesive load) are answered, by the
    solve in depth; the branch's run declines them."""
    law = _law(200e9, 0.02)
    md, (jump_out, zero_load), args = law
    assert args[3] < LAMBDA_TRANSITION and math.isinf(args[4])
    ds = args[0]
    targets = np.linspace(2 * ds, jump_out - 2 * ds, 2000)
    rows, _ = _slide(targets, law, True, k_c=50.0)
    neck = [(t, r) for t, r in zip(targets, rows) if r[0] == COHESIVE and r[4]]
    assert neck and all(r[1] == 0.0 and r[2] < 0.0 for _, r in neck)
    t, r = neck[len(neck) // 2]
    assert not _branch_coupled(t, r[3], t, max(zero_load, t), 50.0, *args, MD_MEMO.full(np.nan))[0]
