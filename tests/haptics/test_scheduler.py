"""Scheduler: deterministic ticks, a real-time thread, consistent snapshots, errors."""
from __future__ import annotations

import math
import sys
import threading
import time

import numpy as np
import pytest

from arsurf.errors import HapticsError
from arsurf.haptics.safety import SafetyLayer
from arsurf.haptics.scheduler import Scheduler
from arsurf.errors import LoopError
from arsurf.haptics.virtual_device import VirtualDevice


def test_run_ticks_is_deterministic_and_does_not_sleep():
    """10^4 ticks of a pure step: a free mass pushed by 1 N, compared with the closed form."""
    M, dt = 0.1, 1e-3

    def step(state, inputs, dt):
        state["v"] += 1.0 / M * dt  # exact for a constant force
        state["x"] += state["v"] * dt - 0.5 / M * dt * dt
        return state["x"]

    sched = Scheduler(step, {"x": 0.0, "v": 0.0}, rate=1.0 / dt)
    t0 = time.perf_counter()
    sched.run_ticks(10_000)
    wall = time.perf_counter() - t0
    t = 10_000 * dt
    assert sched.state["x"] == pytest.approx(0.5 / M * t * t, rel=1e-9)
    assert sched.ticks == 10_000 and wall < 10.0  # 10 s of loop time, no sleeping
    assert sched.snapshot() is None  # nothing published without a snapshot function


def test_run_ticks_with_a_virtual_device_as_source_and_sink():
    dev = VirtualDevice(dt=1e-3, hand=None).open()
    safety = SafetyLayer.for_device(dev.info, 1e-3, ramp_time=0.0)

    def step(state, inputs, dt):
        return safety.step([0.0, 0.0, 100.0], now=inputs.timestamp, age=dev.now() - inputs.timestamp)

    sched = Scheduler(step, None, rate=1000.0, source=dev.read_state, sink=dev.command_force,
                      snapshot=lambda s, i, o: {"position": i.position, "force": o})
    sched.run_ticks(200)
    snap = sched.snapshot()
    assert snap.tick == 199 and snap.time == pytest.approx(0.199)
    # the safety layer rate-limited then saturated the 100 N request at 7.9 N
    assert np.linalg.norm(snap.values["force"]) == pytest.approx(7.9)
    assert dev.now() == pytest.approx(0.2) and snap.values["position"][2] > 0


def test_threaded_loop_keeps_its_grid_and_reports_statistics():
    calls = []

    def step(state, inputs, dt):
        calls.append(dt)
        return None

    sched = Scheduler(step, None, rate=1000.0)
    stats = sched.run_for(0.3)
    assert stats.ticks == len(calls) > 0
    assert set(calls) == {1e-3}  # the step always gets the nominal period
    # absolute deadlines: the loop never runs ahead of its 1 kHz grid
    assert stats.ticks <= stats.duration * 1000.0 + 2
    assert stats.compute_median <= stats.compute_p99 <= stats.compute_max
    assert stats.jitter_p99 <= stats.jitter_max
    assert 0 <= stats.overruns <= stats.ticks
    assert not sched.is_running
    assert set(stats.as_dict()) >= {"rate", "compute_p99", "jitter_p99", "overruns", "skipped"}


def test_slow_steps_are_counted_as_overruns_and_skipped_slots():
    def step(state, inputs, dt):
        time.sleep(0.0035)  # 3.5 periods of a 1 kHz loop

    stats = Scheduler(step, None, rate=1000.0).run_for(0.1)
    assert stats.ticks >= 1
    assert stats.overruns == stats.ticks or stats.overruns >= stats.ticks - 1
    assert stats.skipped >= 2 * (stats.ticks - 1)
    # the longest wait between two tick starts covers a whole slow step (the hand's longest wait)
    assert stats.longest_gap >= 0.0035 and stats.longest_gap >= stats.jitter_max + 1e-3 - 1e-9


def test_snapshots_never_tear():
    """The step writes the tick number into two big arrays, one after the other; a reader thread
    must always see both equal to the snapshot's tick."""
    n = 20_000
    state = {"a": np.zeros(n), "b": np.zeros(n), "k": 0}

    def step(state, inputs, dt):
        state["k"] += 1
        state["a"][:] = state["k"]
        time.sleep(0)  # give other threads the chance to look at a half-written state
        state["b"][:] = state["k"]
        return state["k"]

    sched = Scheduler(step, state, rate=2000.0, snapshot_rate=5000.0,
                      snapshot=lambda s, i, o: {"a": s["a"], "b": s["b"], "k": np.array(o)})
    seen = []
    problems = []
    stop = threading.Event()

    def reader():
        while not stop.is_set():
            snap = sched.snapshot()
            if snap is None:
                continue
            a, b, k = snap.values["a"], snap.values["b"], int(snap.values["k"])
            if not (a[0] == a[-1] == b[0] == b[-1] == k and (a == k).all() and (b == k).all()):
                problems.append((snap.tick, a[0], b[-1], k))
            if snap.tick + 1 != k:
                problems.append(("tick", snap.tick, k))
            seen.append(k)

    th = threading.Thread(target=reader)
    sched.start()
    th.start()
    time.sleep(0.4)
    stop.set()
    th.join()
    stats = sched.stop()
    assert not problems
    assert len(seen) > 10 and len(set(seen)) > 5
    assert stats.snapshots_published > 10


def test_an_error_in_step_stops_the_loop_and_is_reported():
    stopped = []

    def step(state, inputs, dt):
        state["n"] += 1
        if state["n"] == 5:
            raise ValueError("contact model exploded")

    sched = Scheduler(step, {"n": 0}, rate=1000.0, on_stop=lambda: stopped.append(True))
    sched.start()
    deadline = time.monotonic() + 2.0
    while sched.is_running and time.monotonic() < deadline:
        time.sleep(0.001)
    with pytest.raises(LoopError, match="step raised ValueError: contact model exploded") as info:
        sched.stop()
    assert isinstance(info.value.__cause__, ValueError)
    assert stopped == [True] and sched.state["n"] == 5


def test_bad_settings():
    with pytest.raises(HapticsError, match="rate must be between 1 and 20000 Hz"):
        Scheduler(lambda s, i, d: None, rate=50_000.0)
    with pytest.raises(HapticsError, match="step must be a callable"):
        Scheduler(42)
    with pytest.raises(HapticsError, match="sink must be callable"):
        Scheduler(lambda s, i, d: None, sink=3)
    sched = Scheduler(lambda s, i, d: None, rate=500.0)
    with pytest.raises(HapticsError, match="n must be a non-negative integer"):
        sched.run_ticks(-1)
    sched.start()
    try:
        with pytest.raises(HapticsError, match="already running"):
            sched.start()
        with pytest.raises(HapticsError, match="stop\\(\\) it before run_ticks"):
            sched.run_ticks(1)
    finally:
        sched.stop()
    assert math.isfinite(sched.stats().rate)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_TIMERSLACK is Linux's")
def test_the_loop_thread_asks_for_a_tight_timer_slack():
    """The loop thread's sleeps may otherwise end up to 50 us late (Linux's default slack), half a
    10 kHz period (bench/haptic_loop.py: 3.4 % overruns at 10 kHz without, 0.5-0.75 % with)."""
    from arsurf.haptics.scheduler import _tight_timer_slack

    seen = []

    def probe():
        _tight_timer_slack()
        import ctypes

        seen.append(ctypes.CDLL(None).prctl(30, 0, 0, 0, 0))  # PR_GET_TIMERSLACK: this thread's

    t = threading.Thread(target=probe)
    t.start()
    t.join()
    assert seen == [1]


@pytest.mark.skipif(not hasattr(__import__("os"), "sched_getscheduler"), reason="POSIX scheduling policies")
@pytest.mark.parametrize("priority", [0, 40])
def test_the_loop_thread_runs_under_the_policy_it_reports(priority):
    """A granted priority puts the step's own thread under SCHED_FIFO at that priority (what the
    stats report); 0, or a refusal, leaves the ordinary policy and reports 0. The caller's thread
    is never changed."""
    import os

    seen = []

    def step(state, inputs, dt):
        if not seen:
            seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

    before = os.sched_getscheduler(0)
    stats = Scheduler(step, rate=1000.0, priority=priority).run_for(0.05)
    assert os.sched_getscheduler(0) == before
    assert stats.realtime_priority in (0, priority)
    if stats.realtime_priority:
        assert seen[0] == (os.SCHED_FIFO, priority)
    else:
        assert seen[0][0] != os.SCHED_FIFO


def test_priority_is_checked():
    for bad in (-1, 100, 2.5, True, "40"):
        with pytest.raises(HapticsError, match="priority must be an integer in \\[0, 99\\]"):
            Scheduler(lambda s, i, d: None, priority=bad)


def test_run_for_takes_a_finite_duration():
    sched = Scheduler(lambda s, i, d: None, rate=1000.0)
    for bad in (-1.0, math.inf, math.nan, "soon", None):
        with pytest.raises(HapticsError, match="seconds must be a"):
            sched.run_for(bad)
    assert not sched.is_running
