"""The tip behind the virtual coupling: the coupling's Newton run and the memo of its last answer."""
import math

import numpy as np

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.proxy import MD_MEMO, coupled_depth_kernel
from arsurf.status import CONTACT

R = 20e-9
K_C = 2.0  # N/m at the probe


def _law(e_star=50e9, w=0.05):
    """(law, (jump-out depth, zero-load depth) m, kernel arguments), as the model gives them."""
    md = MaugisDugdale(R, e_star, w)
    return md, (md.jump_out_depth(), float(md.depth(0.0))), md.kernel_args


def _slide(targets, law, memo_kept):
    """The coupled depth along ``targets`` (m), each tick started from the last depth, with the
    memo kept between ticks or emptied before each (the solve without it)."""
    md, (jump_out, zero_load), args = law
    memo = MD_MEMO.full(np.nan)
    depth, interacting, rows = math.nan, False, []
    for t in targets:
        if not memo_kept:
            memo[:] = np.nan
        st, a, load, depth, coupled = coupled_depth_kernel(t, depth if interacting else math.nan, interacting, K_C,
                                                           jump_out, zero_load, *args, memo)
        interacting = st in (0, 1)
        rows.append((st, a, load, depth, coupled))
    return rows, memo


def test_the_memo_gives_the_solves_answers_bit_for_bit():
    """A press and a slow pull-off through the coupling: with the memo of the last answer kept
    between ticks the run gives, every tick, the same status, radius, load and depth as the solve
    without it; the memo ends holding the last depth with its answer and law."""
    law = _law()
    targets = np.concatenate([np.linspace(-0.2e-9, 1.5e-9, 400), np.linspace(1.5e-9, -1.0e-9, 600)])
    kept, memo = _slide(targets, law, True)
    fresh, _ = _slide(targets, law, False)
    assert kept == fresh                                                  # exact tuples: bit for bit
    assert sum(r[4] for r in kept) > 500 and any(r[0] == CONTACT for r in kept)
    last = [r for r in kept if r[4]][-1]
    assert memo[MD_MEMO.offset("depth")] == last[3] or not kept[-1][4]
    assert tuple(memo[MD_MEMO.offset("law"):]) == tuple(law[2])


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
