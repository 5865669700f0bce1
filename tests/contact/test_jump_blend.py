"""The tip's jumps behind the coupling, rendered over the blend time (arsurf.contact.jump_blend)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.contact.jump_blend import (BLEND_SPEED, BLEND_TIME, HOP_EXCESS, JUMP_SPEED_RATIO, STATE_SIZE,
                                      blend_jumps_kernel, redo_steps)

TAU = BLEND_TIME
JUMP = np.array([2e-9, 0.0, -1e-9])  # the balance lands 2.2 nm away
K_C = 50.0  # N/m: the balance's force is the coupling's, K_C (T* - C)


def _render(balance, target, period, blend_time=TAU, speed=BLEND_SPEED, forces=False):
    """The rendered tip T = T* + e over the rows of ``balance`` and ``target`` (m), and with
    ``forces`` the rendered force F* + E of a balance held by the coupling alone, F* = K_C (T* - C)."""
    state = np.full(STATE_SIZE, np.nan)
    out = np.empty_like(balance)
    force = np.empty_like(balance)
    for k, (t, c) in enumerate(zip(balance, target)):
        f = K_C * (t - c)
        e = blend_jumps_kernel(blend_time, speed, period, *t, *c, *f, state, 0)
        out[k] = t + np.array(e[:3])
        force[k] = f + np.array(e[3:])
    return (out, force) if forces else out


def _jump_at(n, k_jump, hand=(0.0, 0.0, 0.0), period=1e-3):
    """A hand moving at ``hand`` m/s whose balance is 3 nm above it until tick ``k_jump``, then jumps by JUMP."""
    t = np.arange(n)[:, None] * period
    target = np.array([50e-9, 40e-9, 10e-9]) + t * np.array(hand)
    balance = target + np.array([0.0, 0.0, 3e-9])
    balance[k_jump:] += JUMP
    return target, balance


def test_a_jump_while_the_hand_is_still_reaches_the_hand_as_one_minus_an_exponential():
    """T(t) = T*_old + D (1 - exp(-t/tau)) from the tick of the jump: no step, monotone."""
    target, balance = _jump_at(80, 10)
    tip, force = _render(balance, target, 1e-3, forces=True)
    assert np.array_equal(tip[:10], balance[:10])  # before: the balance itself
    np.testing.assert_allclose(force, K_C * (tip - target), rtol=0, atol=1e-12 * K_C * 1e-9)  # the force follows
    t = (np.arange(80) - 10)[10:] * 1e-3
    expected = balance[0] + JUMP[None, :] * (1.0 - np.exp(-t / TAU))[:, None]
    np.testing.assert_allclose(tip[10:], expected, rtol=0, atol=1e-9 * 1e-9)
    steps = np.linalg.norm(np.diff(tip, axis=0), axis=1)
    assert steps.max() <= np.linalg.norm(JUMP) * (1.0 - math.exp(-1e-3 / TAU)) * (1 + 1e-9)
    along = (tip - balance[0]) @ JUMP
    assert np.all(np.diff(along) >= 0.0)  # no reversal


@pytest.mark.parametrize("rate", [1000.0, 5000.0, 10000.0])
def test_the_blend_is_the_same_function_of_time_at_any_loop_rate(rate):
    period = 1.0 / rate
    k = int(round(0.01 * rate))  # the jump at 10 ms
    target, balance = _jump_at(int(round(0.08 * rate)), k, period=period)
    tip = _render(balance, target, period)
    for ms in (0.0, 5.0, 15.0, 40.0):
        i = k + int(round(ms * 1e-3 * rate))
        np.testing.assert_allclose(tip[i] - balance[i], -JUMP * math.exp(-ms * 1e-3 / TAU), rtol=1e-9, atol=1e-24)


def test_a_tip_riding_over_the_surface_with_the_hand_is_rendered_as_it_is():
    """A balance that moves with the hand, up a slope of 55 degrees (1.74x the hand's move in a
    tick), is no jump: the tip is the balance."""
    n = 200
    target = np.array([50e-9, 40e-9, 10e-9]) + np.arange(n)[:, None] * np.array([10e-12, 0.0, 0.0])  # 10 nm/s
    balance = target + np.array([0.0, 0.0, 3e-9])
    balance[:, 2] += np.tan(math.radians(55.0)) * (target[:, 0] - target[0, 0])
    assert np.array_equal(_render(balance, target, 1e-3), balance)


def test_a_fast_hand_s_jumps_are_rendered_as_they_are():
    """At 1000 nm/s a tick of the 1 kHz loop is 1 nm, as large as the jumps: a blend would take a
    share of them that depends on the rate, so a fast hand's jumps are not blended."""
    target, balance = _jump_at(100, 60, hand=(1e-6, 0.0, 0.0))
    tip = _render(balance, target, 1e-3)
    slow = 1.0 / (1.0 + (1e-6 / BLEND_SPEED) ** 4)
    assert np.abs(tip - balance).max() <= slow * np.linalg.norm(JUMP)
    assert np.abs(tip - balance).max() < 1e-4 * np.linalg.norm(JUMP)
    still_target, still_balance = _jump_at(100, 60)
    assert np.abs(_render(still_balance, still_target, 1e-3) - still_balance).max() > 0.9 * np.abs(JUMP).max()


def test_only_the_part_of_a_move_faster_than_the_hand_s_is_blended():
    """A tick where the hand moves h and the balance D > r h: the tip takes r h of it at once."""
    state = np.full(STATE_SIZE, np.nan)
    c0, t0 = np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 3e-9])
    blend_jumps_kernel(TAU, math.inf, 1e-3, *t0, *c0, 0.0, 0.0, 0.0, state, 0)
    h = np.array([0.1e-9, 0.0, 0.0])
    e = np.array(blend_jumps_kernel(TAU, math.inf, 1e-3, *(t0 + JUMP), *(c0 + h), 0.0, 0.0, 0.0, state, 0))[:3]
    taken = np.linalg.norm(JUMP + e)  # the rendered tip's move
    assert taken == pytest.approx(JUMP_SPEED_RATIO * np.linalg.norm(h), rel=1e-12)


@pytest.mark.parametrize("blend_time, period", [(0.0, 1e-3), (TAU, math.nan)])
def test_off_without_a_blend_time_or_a_tick_period(blend_time, period):
    target, balance = _jump_at(40, 10)
    assert np.array_equal(_render(balance, target, period, blend_time=blend_time), balance)


def test_hops_in_quick_succession_never_pile_up_more_excess_than_one_and_a_half_jumps():
    """A contact set that keeps hopping (a minimum lost at a fold and reborn) while a blend is
    still running: each new hop is blended by what is left, so the excess stays within
    HOP_EXCESS times the largest jump. Piled up, the force followed each hop late, the hand's
    response made the next one, and a still press gave the hand 5 E0 (seed 1 of the feel table)."""
    rng = np.random.default_rng(3)
    n = 400
    target = np.tile(np.array([50e-9, 40e-9, 10e-9]), (n, 1))
    steps = np.where(rng.random((n, 1)) < 0.3, rng.normal(0.0, 1e-9, (n, 3)), 0.0)  # a hop on 30 % of ticks
    steps[:100] = np.where(np.arange(100)[:, None] % 2 == 0, np.array([1e-9, 0.0, 0.0]), 0.0)  # a staircase
    balance = target + np.array([0.0, 0.0, 3e-9]) + np.cumsum(steps, axis=0)
    tip = _render(balance, target, 1e-3)
    largest = np.linalg.norm(steps, axis=1).max()
    assert np.linalg.norm(tip - balance, axis=1).max() <= HOP_EXCESS * largest * (1 + 1e-9)
    assert np.linalg.norm(tip - balance, axis=1).max() > 0.5 * largest  # and the hops are blended


@pytest.mark.parametrize("rate, steps", [(1000.0, 10), (5000.0, 2), (10000.0, 1), (20000.0, 1), (100.0, 32)])
def test_a_jump_tick_is_run_again_in_steps_of_a_10_khz_tick(rate, steps):
    assert redo_steps(BLEND_TIME, 1.0 / rate) == steps
    assert redo_steps(0.0, 1.0 / rate) == 1 and redo_steps(BLEND_TIME, math.nan) == 1  # the blend off: no redo


def test_a_1_khz_model_meets_each_jump_as_ten_10_khz_ticks_do():
    """A target pressed 1 nm into a generated power-law surface (2.1 nm rms over 11 nm) and slid at
    50 nm/s under a 4.6 nm tip behind a soft coupling: the balance snaps between asperities and
    contacts come and go. Each 1 kHz tick is compared with ten 10 kHz ticks of a copy of the model
    along the same path. Where the balance jumped over the tick, or a contact was found or lost,
    the 1 kHz tick's force is the 10 kHz one to the last bit (it was run again in those steps);
    elsewhere it is not run again. Taken in one tick, the forces were 0.1 % or more away from the
    10 kHz ones on 53 of the 399 ticks; 6 with only the jumps run again, 3 now."""
    import copy

    from arsurf.assembly import make_model
    from arsurf.contact.jump_blend import JUMP_STATE, jumped_kernel
    from arsurf.feel_scenarios import generated_surfaces
    from arsurf.contact.multi_contact import T_COUNT
    from arsurf.model import M_SIM_FX, S_CONTACTS, S_JUMPS

    g = generated_surfaces(10, seed=0)[9]
    s = g.surface()
    (u0, u1), (v0, v1) = s.domain
    uc, vc = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    m = make_model(s, tip_radius=g.tip_radius, effective_modulus=10e9, work_of_adhesion=0.1)
    m.set_coupling_stiffness(0.05)
    m.set_jump_blend(BLEND_TIME, 1e-3)
    z = float(np.asarray(s.evaluate(uc, vc)).ravel()[2]) + g.tip_radius - 1e-9
    last_target = S_JUMPS + JUMP_STATE.offset("last_target")
    m.tick((uc - 10e-9, vc, z))  # the first tick, which has no last target
    jumps = apart = 0
    for k in range(1, 400):
        fine = copy.deepcopy(m)
        fine.set_jump_blend(BLEND_TIME, 1e-4)  # the same model in a 10 kHz loop, from the same state
        fine.state[:] = m.state
        before = m.state.copy()
        c = np.array([uc - 10e-9 + 50e-9 * k * 1e-3, vc, z])
        f = m.tick(c)[M_SIM_FX:M_SIM_FX + 3].copy()
        start = before[last_target:last_target + 3]
        for i in range(1, 11):
            f_fine = fine.tick(start + (c - start) * i / 10 if i < 10 else c)[M_SIM_FX:M_SIM_FX + 3]
        if not np.abs(f_fine).max() > 0.0:
            continue
        count = S_CONTACTS + T_COUNT
        again = jumped_kernel(before, S_JUMPS, fine.state, S_JUMPS) or before[count] != fine.state[count]
        assert again == np.array_equal(f, f_fine), (k, f, f_fine)
        jumps += again
        apart += np.abs(f - f_fine).max() > 1e-3 * np.abs(f_fine).max()
    assert jumps > 100 and apart <= 6, (jumps, apart)
