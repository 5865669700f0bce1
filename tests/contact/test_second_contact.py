"""The second contact in valleys narrower than the tip (arsurf.contact.second_contact).

The kernel skips its own Newton run from the previous closest point when the collision query's
run from that same point (OUT_WARM_U/V) already ended at the closest point. That is a shortcut,
not a new rule: with the record hidden (NaN: the kernel runs Newton itself) every answer - the
weight, the jump flag, the blended normal, the followed second contact - must be the same, on one pyramid and
on tiles.
"""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.contact import layout as ly
from arsurf.contact.closest_point import collide_any
from arsurf.contact.newton import MAX_ITER_DOMAIN, STEP_TOL, newton_box
from arsurf.contact.projection import Projector, TiledProjector
from arsurf.contact.second_contact import SAME_POINT, second_contact_kernel
from arsurf.spline.surface import BSplineSurface

R = 20e-9  # tip radius, m
PITCH = 8e-9  # V grooves 8 nm apart: the 20 nm tip bridges each and rests on two slopes


def _grooves(n: int = 96, pixel: float = 1e-9) -> BSplineSurface:
    x = np.arange(n) * pixel
    z = 3e-9 * np.abs(np.sin(np.pi * x / PITCH))[:, None] * np.ones(n)[None, :]
    return BSplineSurface.from_heights(z, (0.0, x[-1]), (0.0, x[-1]))


def _walk(seed: int, n: int = 600) -> np.ndarray:
    """Tip centres wandering across the grooves, pressed ~0.5 nm into them (m)."""
    rng = np.random.default_rng(seed)
    x = 40e-9 + np.cumsum(rng.normal(0.0, 0.15e-9, n))
    y = 48e-9 + np.cumsum(rng.normal(0.0, 0.05e-9, n))
    z = R + 2.5e-9 + 0.3e-9 * np.sin(np.arange(n) / 17.0)
    return np.column_stack([x, y, z])


@pytest.mark.parametrize("kind", ["pyramid", "tiles"])
def test_skipping_the_second_newton_run_changes_no_answer(kind):
    s = _grooves()
    proj = (Projector(s) if kind == "pyramid" else TiledProjector(s, tile=8)).kernel_args()
    ctrl, ku, kv = s.net_arrays()
    coll = np.empty(ly.OUT_SIZE)
    ev = np.empty((6, 3))
    fast, slow = np.full(2, np.nan), np.full(2, np.nan)
    pu = pv = np.nan
    weights, jumps, skipped = [], 0, 0
    h = max(ku[4] - ku[3], kv[4] - kv[3])
    for cx, cy, cz in _walk(3):
        assert collide_any(proj, cx, cy, cz, R, pu, pv, coll) >= 0
        hidden = coll.copy()
        hidden[ly.OUT_WARM_U] = hidden[ly.OUT_WARM_V] = np.nan
        if np.isnan(fast[0]) and np.hypot(coll[ly.OUT_WARM_U] - coll[ly.OUT_U],
                                          coll[ly.OUT_WARM_V] - coll[ly.OUT_V]) <= SAME_POINT * h:
            skipped += 1
        margin = 1e-9
        w_fast, jumped_fast = second_contact_kernel(ctrl, ku, kv, ev, cx, cy, cz, R, pu, pv, margin, fast, 0, coll)
        w_slow, jumped_slow = second_contact_kernel(ctrl, ku, kv, ev, cx, cy, cz, R, pu, pv, margin, slow, 0, hidden)
        assert (w_fast, jumped_fast) == (w_slow, jumped_slow)
        np.testing.assert_array_equal(fast, slow)
        np.testing.assert_array_equal(coll[ly.OUT_NX:ly.OUT_NZ + 1], hidden[ly.OUT_NX:ly.OUT_NZ + 1])
        weights.append(w_fast)
        jumps += jumped_fast
        pu, pv = coll[ly.OUT_U], coll[ly.OUT_V]
    weights = np.asarray(weights)
    # the walk does meet second contacts and jumps, and the shortcut is taken on most other ticks
    assert (weights > 0).sum() >= 20 and jumps >= 1
    assert skipped >= 0.3 * len(weights)


def test_the_warm_record_is_newtons_answer_from_the_hint():
    """On one pyramid, OUT_WARM_U/V is what Newton over the whole domain from the hint gives
    (the very run the second contact would make), and NaN for a cold query."""
    s = _grooves()
    proj = Projector(s).kernel_args()
    ctrl, ku, kv = s.net_arrays()
    coll = np.empty(ly.OUT_SIZE)
    ev = np.empty((6, 3))
    h = max(ku[4] - ku[3], kv[4] - kv[3])
    collide_any(proj, 41e-9, 47e-9, R + 2e-9, R, np.nan, np.nan, coll)
    assert np.isnan(coll[ly.OUT_WARM_U]) and np.isnan(coll[ly.OUT_WARM_V])
    hint = (43.5e-9, 47e-9)
    collide_any(proj, 41e-9, 47e-9, R + 2e-9, R, *hint, coll)
    nu, nv = ku.shape[0], kv.shape[0]
    u, v, _, _, conv = newton_box(ctrl, ku, kv, ev, 41e-9, 47e-9, R + 2e-9, *hint, ku[3], ku[nu - 4], kv[3],
                                  kv[nv - 4], STEP_TOL * h, STEP_TOL * h, h, MAX_ITER_DOMAIN)
    assert conv
    assert np.hypot(coll[ly.OUT_WARM_U] - u, coll[ly.OUT_WARM_V] - v) <= SAME_POINT * h
