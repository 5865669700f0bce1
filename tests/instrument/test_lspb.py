"""LSPB interpolator ([Alabdulmuhsin] Sec. 3.4): limits, exact end point, continuity, minimum time."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from arsurf.errors import InstrumentError
from arsurf.instrument.lspb import LSPB, minimum_duration


def check_profile(move: LSPB, vmax, amax, n=4001):
    """Assert limits, end points, continuity and consistency of one planned move."""
    T = move.duration
    vmax = np.broadcast_to(np.asarray(vmax, float), move.start.shape)
    amax = np.broadcast_to(np.asarray(amax, float), move.start.shape)
    # dense samples plus both sides of every break point
    eps = 1e-9 * max(T, 1e-300)
    breaks = np.concatenate([move.blend, T - move.blend])
    t = np.unique(np.clip(np.concatenate([np.linspace(0, T, n), breaks - eps, breaks, breaks + eps]), 0, T))
    q, v, a = move.evaluate(t)
    assert np.all(np.abs(v) <= vmax * (1 + 1e-12))
    assert np.all(np.abs(a) <= amax * (1 + 1e-12))
    # exact end points
    q_end = move.evaluate(T)[0][0]
    assert np.array_equal(q_end, move.end)
    assert np.array_equal(move.evaluate(0.0)[0][0], move.start)
    assert np.array_equal(move.evaluate(T + 1.0)[0][0], move.end)  # holds after the end
    # no overshoot: monotone between start and end
    s = np.sign(move.end - move.start)
    assert np.all(np.diff(q * s, axis=0) >= -1e-15 * np.abs(move.end - move.start).max(initial=1))
    # continuity of position and velocity across the break points
    scale_q = np.abs(move.end - move.start) + 1e-300
    for b in breaks:
        if 0 < b < T:
            ql, vl, _ = move.evaluate(b - eps)
            qr, vr, _ = move.evaluate(b + eps)
            assert np.all(np.abs(qr - ql) <= 4 * vmax * eps + 1e-12 * scale_q)
            assert np.all(np.abs(vr - vl) <= 4 * amax * eps + 1e-12 * vmax)
    # velocity is the derivative of position (trapezoidal integration of v reproduces q)
    integral = move.start + np.concatenate([np.zeros((1, q.shape[1])),
                                            np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], axis=0)])
    assert np.all(np.abs(integral - q) <= 1e-6 * scale_q + 1e-18)
    return q, v, a


@settings(max_examples=120, deadline=None)
@given(
    q0=st.floats(-1e-3, 1e-3),
    dist=st.floats(-1e-3, 1e-3).filter(lambda d: abs(d) > 1e-12),
    vmax=st.floats(1e-6, 1e-2),
    amax=st.floats(1e-4, 10.0),
)
def test_single_axis_profiles_respect_limits(q0, dist, vmax, amax):
    move = LSPB.plan(q0, q0 + dist, vmax, amax)
    q, v, a = check_profile(move, vmax, amax)
    D = abs((q0 + dist) - q0)  # the distance the plan is given (q0 + dist rounds: ~1e-11 relative near q0)
    if D < vmax**2 / amax:  # too short to cruise: triangular, peak sqrt(a D) below the limit
        assert move.triangular[0]
        assert np.abs(v).max() == pytest.approx(math.sqrt(amax * D), rel=1e-3)
        assert move.duration == pytest.approx(2 * math.sqrt(D / amax), rel=1e-12)
    else:
        assert move.triangular[0] == (D <= vmax**2 / amax * (1 + 1e-12))  # no cruise at the boundary
        assert move.cruise[0] == pytest.approx(vmax, rel=1e-12)
        assert move.duration == pytest.approx(D / vmax + vmax / amax, rel=1e-12)


def bang_coast_bang_time(D, vmax, amax, dt):
    """Slow reference: step the motion with exact constant-acceleration updates, accelerating
    (or cruising at v_max) as long as the lever can still stop in the remaining distance after
    the step, braking at a_max otherwise; returns the arrival time and distance."""
    x = v = t = 0.0
    while True:
        v_a = min(v + amax * dt, vmax)
        x_a = x + 0.5 * (v + v_a) * dt
        if D - x_a >= v_a * v_a / (2 * amax):
            x, v = x_a, v_a
        else:
            v_b = max(v - amax * dt, 0.0)
            x += 0.5 * (v + v_b) * dt
            v = v_b
        t += dt
        if v == 0.0:
            return t, x


@pytest.mark.parametrize("D,vmax,amax", [(1e-9, 1e-4, 1e-2), (1e-6, 1e-4, 1e-1), (2e-4, 1.5e-3, 1e-2),
                                         (2e-3, 1.5e-3, 1e-2)])
def test_minimum_time_matches_a_stepped_bang_coast_bang(D, vmax, amax):
    T = float(minimum_duration(D, vmax, amax))
    t_ref, x_ref = bang_coast_bang_time(D, vmax, amax, T / 20000)
    assert x_ref == pytest.approx(D, rel=1e-4)
    assert t_ref == pytest.approx(T, rel=2e-4)
    # time-optimal (bang-coast-bang): at every instant one limit is saturated
    move = LSPB.plan(0.0, D, vmax, amax)
    t = np.linspace(0, T, 2001)[1:-1]
    t = t[np.abs(t - move.blend[0]) > 1e-9 * T]
    t = t[np.abs(t - (T - move.blend[0])) > 1e-9 * T]
    _, v, a = move.evaluate(t)
    assert np.all((np.abs(a[:, 0]) == amax) | np.isclose(np.abs(v[:, 0]), vmax, rtol=1e-12))


def test_synchronised_axes_finish_together_within_their_limits():
    start = np.array([0.0, 1e-6, -2e-6])
    end = np.array([5e-6, 1e-6 + 0.1e-6, -2e-6 - 3e-6])
    vmax = np.array([1e-4, 1e-4, 5e-5])
    amax = np.array([1e-2, 2e-2, 1e-2])
    move = LSPB.plan(start, end, vmax, amax)
    assert move.duration == pytest.approx(float(np.max(minimum_duration(end - start, vmax, amax))), rel=1e-14)
    check_profile(move, vmax, amax)
    # every axis is still moving until T (synchronised), not parked early
    _, v, _ = move.evaluate(0.999 * move.duration)
    assert np.all(np.abs(v) > 0)


def test_longer_duration_lowers_the_cruise_speed():
    fast = LSPB.plan(0.0, 1e-6, 1e-4, 1e-1)
    slow = LSPB.plan(0.0, 1e-6, 1e-4, 1e-1, duration=3 * fast.duration)
    assert slow.cruise[0] < fast.cruise[0]
    check_profile(slow, 1e-4, 1e-1)


def test_sample_at_the_loop_rate_ends_on_the_target():
    move = LSPB.plan(0.0, 1e-6, 1e-4, 1e-2)  # [Alabdulmuhsin] Fig. 4.6: a 1000 nm step
    t, q, v, a = move.sample(10e3)
    assert t[0] == 0.0 and t[-1] == move.duration and q[-1, 0] == 1e-6
    assert np.all(np.diff(t) > 0)


def test_zero_move_and_bad_limits():
    still = LSPB.plan([1e-6, 2e-6], [1e-6, 2e-6], 1e-4, 1e-2)
    assert still.duration == 0.0
    q, v, _ = still.evaluate([0.0, 1.0])
    assert np.all(q == [1e-6, 2e-6]) and np.all(v == 0)
    with pytest.raises(InstrumentError, match="max_velocity must be positive"):
        LSPB.plan(0.0, 1e-6, 0.0, 1e-2)
    with pytest.raises(InstrumentError, match="duration must be at least"):
        LSPB.plan(0.0, 1e-6, 1e-4, 1e-2, duration=1e-6)
    with pytest.raises(InstrumentError, match="start has 2 axes and end 3"):
        LSPB.plan([0.0, 0.0], [1.0, 1.0, 1.0], 1.0, 1.0)
    with pytest.raises(InstrumentError, match="end must be finite"):
        LSPB.plan(0.0, np.nan, 1.0, 1.0)
