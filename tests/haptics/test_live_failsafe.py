"""The live loop fails safe: a fault in the servo thread leaves zero force on the device, and
stopping closes the device whatever happened (issue #15 §4, the server side)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.assembly import make_model
from arsurf.errors import LoopError
from arsurf.haptics.loop import HapticLoop
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.spline.surface import BSplineSurface
from tests.support.waiting import wait_until

R = 20e-9


class RecordingDevice(VirtualDevice):
    """A virtual device that remembers every force commanded and whether it was closed."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.forces = []
        self.closed = 0

    def command_force(self, force):
        self.forces.append(np.array(force, dtype=float))
        return super().command_force(force)

    def close(self):
        self.closed += 1
        return super().close()


def _live(fail_after: int):
    from arsurf.haptics.live_loop import LiveLoop

    s = BSplineSurface.from_heights(np.zeros((40, 40)), (0.0, 37 * 4e-9), (0.0, 37 * 4e-9))
    model = make_model(s, tip_radius=R, effective_modulus=10e9, work_of_adhesion=0.1)
    origin = (70e-9, 70e-9, R - 2e-9)  # pressed 2 nm in: the hand feels a force from the first tick
    hand = HandModel((np.array([0.0, 10.0]), np.zeros((2, 3))))
    dev = RecordingDevice(dt=1e-3, hand=hand)
    loop = HapticLoop.direct(model, dev.info, origin, ramp_time=0.0)
    step = loop.step
    calls = [0]

    def faulty(inputs, now):
        calls[0] += 1
        if calls[0] > fail_after:
            raise RuntimeError("injected fault in the tick")
        return step(inputs, now)

    loop.step = faulty
    return LiveLoop(loop, dev), dev, calls


def test_a_fault_in_the_tick_leaves_zero_force_and_the_device_closed():
    live, dev, calls = _live(fail_after=50)
    live.start()
    wait_until(lambda: calls[0] > 50 and not live.scheduler.is_running, 15.0,
               what="the injected fault stopping the loop")
    assert calls[0] > 50
    assert max(np.linalg.norm(f) for f in dev.forces) > 0.0  # it was rendering a force
    assert np.all(dev.forces[-1] == 0.0), f"last force commanded after the fault: {dev.forces[-1]}"
    with pytest.raises(LoopError, match="injected fault"):
        live.stop()
    assert dev.closed == 1


def test_the_ramp_limits_the_force_actually_commanded():
    """A 10 kN request during the 0.1 s start ramp: the commanded force grows with the ramp
    (k dt / T of the device's limit), not to the limit within a few ticks."""
    from arsurf.haptics.safety import SafetyLayer

    dt, fmax = 1e-3, 7.9
    layer = SafetyLayer(max_force=fmax, dt=dt, ramp_time=0.1, max_rate=np.inf)
    for k in range(1, 120):
        f = np.linalg.norm(layer.step([0.0, 0.0, 1e4], now=k * dt))
        assert f <= min(1.0, k * dt / 0.1) * fmax * (1 + 1e-12), (k, f)
    assert f == pytest.approx(fmax)


def test_a_timestamp_ahead_of_the_clock_is_stale():
    from arsurf.haptics.safety import STALE, SafetyLayer

    layer = SafetyLayer(max_force=7.9, dt=1e-3, ramp_time=0.0)
    layer.step([0.0, 0.0, 1.0], now=0.0, age=0.0)
    layer.step([0.0, 0.0, 1.0], now=1e-3, age=-5.0)  # a sample from 5 s in the future
    assert layer.flags & STALE


def test_the_filter_recovers_from_overflowing_input_within_one_tick():
    from arsurf.haptics.filters import LowPass

    from arsurf.haptics.filters import lowpass1_step

    f = LowPass(200.0, 1e-3)
    out = np.empty(3)

    lowpass1_step(f.alpha, f.state, np.full(3, 1.7e308), out)
    lowpass1_step(f.alpha, f.state, np.full(3, -1.7e308), out)
    assert np.isfinite(f.state).all()
    lowpass1_step(f.alpha, f.state, np.array([1.0, 2.0, 3.0]), out)
    assert np.isfinite(out).all() and np.all(out > 0)


@pytest.mark.parametrize("buttons", [float("nan"), None, 2**64, -1, "1"])
def test_malformed_buttons_are_a_flagged_no_press(buttons):
    from arsurf import status
    from arsurf.haptics.device import DeviceState

    s = BSplineSurface.from_heights(np.zeros((20, 20)), (0.0, 76e-9), (0.0, 76e-9))
    model = make_model(s, tip_radius=R, effective_modulus=10e9, work_of_adhesion=0.1)
    dev = VirtualDevice(dt=1e-3)
    loop = HapticLoop.direct(model, dev.info, (38e-9, 38e-9, R + 5e-9), ramp_time=0.0)
    good = loop.step(DeviceState(np.zeros(3), np.zeros(3), 0, 0.0), 0.0).copy()
    force = loop.step(DeviceState(np.zeros(3), np.zeros(3), buttons, 1e-3), 1e-3)
    assert np.isfinite(force).all()
    assert loop.output().safety_flags & status.BAD_BUTTONS
    np.testing.assert_allclose(force, good, atol=1e-12)  # no press: the same force as before


# --- device samples that cannot be real (issue 25 §4) ---------------------------------------------
def _pressed_loop():
    s = BSplineSurface.from_heights(np.zeros((40, 40)), (0.0, 37 * 4e-9), (0.0, 37 * 4e-9))
    model = make_model(s, tip_radius=R, effective_modulus=10e9, work_of_adhesion=0.1)
    info = VirtualDevice(dt=1e-3).info
    # the default virtual coupling renders 13 mN here: a rate limit of 5 N/s (5 mN per tick, the
    # free-space force below which the ramp lets a force through at once) keeps that force ramped
    return HapticLoop.direct(model, info, (70e-9, 70e-9, R - 2e-9), ramp_time=0.05, force_gain=1e8, max_rate=5.0)


def _wild(kind, k, dt=1e-3):
    """The sample of tick ``k`` (a good one, or the wild ``kind``) and the loop clock."""
    from arsurf.haptics.device import DeviceState

    now = k * dt
    pos, vel, stamp = np.array([1e-4 * math.sin(k * 0.05), 0.0, 0.0]), np.zeros(3), now
    if kind == "1_m_away":
        pos = np.array([1.0, 0.0, 0.0])
    elif kind == "1_km_away":
        pos = np.array([0.0, -1e3, 0.0])
    elif kind == "jump_faster_than_a_hand":  # 5 cm in one 1 ms tick, inside the workspace: 50 m/s
        pos = pos + np.array([0.0, 0.05, 0.0])
    elif kind == "velocity_faster_than_a_hand":
        vel = np.array([0.0, 0.0, -200.0])
    elif kind == "shape_1":
        pos = np.array([1e-4])
    elif kind == "scalar":
        pos = 1e-4
    elif kind == "integer_dtype":
        pos = np.zeros(3, dtype=np.int64)
    elif kind == "float32_dtype":
        pos = pos.astype(np.float32)
    elif kind == "nan":
        pos = np.array([np.nan, 0.0, 0.0])
    elif kind == "text_timestamp":
        stamp = "0.1"
    elif kind == "clock_and_stamp_back_10_s":
        now, stamp = now - 10.0, now - 10.0
    elif kind == "stamp_back_10_s":
        stamp = now - 10.0
    return DeviceState(pos, vel, 0, stamp), now


_WILD = ("1_m_away", "1_km_away", "jump_faster_than_a_hand", "velocity_faster_than_a_hand", "shape_1", "scalar",
         "integer_dtype", "float32_dtype", "nan", "text_timestamp", "clock_and_stamp_back_10_s", "stamp_back_10_s")
_FLAG = {"1_m_away": "SAMPLE_OUTSIDE", "1_km_away": "SAMPLE_OUTSIDE", "jump_faster_than_a_hand": "SAMPLE_TOO_FAST",
         "velocity_faster_than_a_hand": "SAMPLE_TOO_FAST", "shape_1": "SAMPLE_MALFORMED", "scalar": "SAMPLE_MALFORMED",
         "integer_dtype": "SAMPLE_MALFORMED", "float32_dtype": "SAMPLE_MALFORMED", "nan": "SAMPLE_MALFORMED",
         "text_timestamp": "SAMPLE_MALFORMED", "clock_and_stamp_back_10_s": "TIME_BACKWARDS",
         "stamp_back_10_s": "TIME_BACKWARDS"}


@pytest.mark.parametrize("kind", _WILD)
def test_a_sample_that_cannot_be_real_is_a_fault_with_zero_force_in_its_tick(kind):
    """Pressed into the surface and rendering a force, one wild sample: zero force in that very
    tick, its named flag, the probe (and the dent) where the last good sample put it, and no kick
    after (the force comes back through the ramp, never above what it was)."""
    from arsurf import status

    loop = _pressed_loop()
    for k in range(100):
        f = loop.step(*_wild("ok", k)).copy()
    assert np.linalg.norm(f) > 5e-3  # rendering a contact force (13 mN through the default virtual coupling)
    probe = loop.output().probe.copy()
    sample, now = _wild(kind, 100)
    forced = loop.step(sample, now).copy()
    out = loop.output()
    assert not forced.any(), (kind, forced)
    assert _FLAG[kind] in status.flag_names(out.safety_flags), (kind, status.flag_names(out.safety_flags))
    np.testing.assert_allclose(out.probe, probe, atol=1e-12)  # the model ran on the last good sample
    after = [np.linalg.norm(loop.step(*_wild("ok", k))) for k in range(101, 111)]
    assert max(after) <= np.linalg.norm(f) * 1.01 and after[0] < 0.5 * np.linalg.norm(f), (kind, after)


def test_a_refused_sample_is_recorded_as_the_sample_the_tick_ran_on_with_its_flag(tmp_path):
    from arsurf import status
    from arsurf.sessions.reader import load_session
    from arsurf.sessions.writer import SessionWriter, record_loop_tick

    from arsurf.assembly import BUNDLED_SCAN, preset_metadata

    loop = _pressed_loop()
    path = tmp_path / "wild.h5"
    meta = preset_metadata(BUNDLED_SCAN, "demo")
    with SessionWriter(path, meta) as w:
        for k in range(30):
            state, now = _wild("1_km_away" if k == 20 else ("shape_1" if k == 25 else "ok"), k)
            loop.step(state, now)
            record_loop_tick(w, loop, now, state)
    s = load_session(path)
    flags = s.ticks["safety_flags"]
    assert flags[20] & status.SAMPLE_OUTSIDE and flags[25] & status.SAMPLE_MALFORMED
    assert not (flags[:20] & (status.SAMPLE_OUTSIDE | status.SAMPLE_MALFORMED)).any()
    pos = s.ticks["stylus_position"]
    np.testing.assert_array_equal(pos[20], pos[19])  # the last good sample, not 1 km away
    assert np.abs(pos).max() < 0.01 and not s.ticks["device_force"][[20, 25]].any()


# --- property: random fault sequences through the compiled tick ---------------------------------
from hypothesis import example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from arsurf.haptics.device import DeviceState  # noqa: E402

_FAULTS = ("ok", "nan_position", "huge_position", "stale", "future", "bad_buttons", "clock_stall", "huge_velocity",
           *_WILD)
_LOOP = {}


def _property_loop():
    """One loop for all examples (compiled once); reset between examples by rebuilding its parts."""
    s = BSplineSurface.from_heights(np.zeros((40, 40)), (0.0, 37 * 4e-9), (0.0, 37 * 4e-9))
    model = make_model(s, tip_radius=R, effective_modulus=10e9, work_of_adhesion=0.1)
    info = VirtualDevice(dt=1e-3).info
    # stop_time = one tick: a fault must zero the force within one tick
    return HapticLoop.direct(model, info, (70e-9, 70e-9, R - 2e-9), ramp_time=0.05, stop_time=1e-3,
                             max_rate=50.0, force_gain=1e8)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(_FAULTS), st.floats(-3e-3, 3e-3)), min_size=20, max_size=120))
# found by CI: a jump just credible after four unreadable ticks (5 cm in 5 ms = the speed limit) is
# accepted, the 'ok' move back is refused, and the next jump lands where the last good sample is
@example([("ok", 0.0)] * 13 + [("nan_position", 0.0)] * 4
         + [("jump_faster_than_a_hand", 0.0), ("ok", 0.0), ("jump_faster_than_a_hand", 0.001953125)])
@example([("ok", 0.0)] * 14 + [("nan_position", 0.0)] * 4 + [("future", 0.0), ("jump_faster_than_a_hand", 0.0)])
@example([("nan_position", 0.0)] * 5 + [("stamp_back_10_s", 0.0)] * 2 + [("ok", 0.0)] * 13)
@example([("nan_position", 0.0)] + [("jump_faster_than_a_hand", 0.0)] * 2 + [("ok", 0.0)] * 17)
def test_property_random_faults_never_let_a_bad_force_through(sequence):
    """Whatever the fault sequence, the force commanded is finite, within the device limit, within
    the rate limit from the previous tick (or zero), and zero within one tick of a fault (a stylus
    reading that is not a number, a sample stale or stamped ahead of the clock), and zero in the
    very tick of a sample that cannot be real (outside the workspace, too fast, malformed, time
    going backwards), which is flagged by name."""
    from arsurf import status
    from arsurf.haptics.samples import SAMPLE_FAULTS, SAMPLE_STATE

    loop = _property_loop()
    limit = loop.safety.max_force
    step_limit = 50.0 * 1e-3 * (1 + 1e-9)
    prev = np.zeros(3)
    now = 0.0
    prev_good = False  # the previous tick's sample, stamped on time, became the loop's last good one
    for kind, x in sequence:
        if kind != "clock_stall":
            now += 1e-3
        pos = np.array([x, 0.0, -abs(x)])
        vel = np.zeros(3)
        stamp, buttons = now, 0
        if kind == "nan_position":
            pos[0] = np.nan
        elif kind == "huge_position":
            pos[:] = 1.7e308
        elif kind == "huge_velocity":
            vel[:] = -1.7e308
        elif kind == "stale":
            stamp = now - 1.0
        elif kind == "future":
            stamp = now + 1.0
        elif kind == "bad_buttons":
            buttons = float("nan")
        sample = DeviceState(pos, vel, buttons, stamp)
        if kind in _WILD:
            sample, _ = _wild(kind, 0)
            if kind == "clock_and_stamp_back_10_s":
                sample.timestamp, now_k = now - 10.0, now - 10.0
            else:
                now_k = now
                if kind == "stamp_back_10_s":
                    sample.timestamp = now - 10.0
                elif kind != "text_timestamp":
                    sample.timestamp = now
                if kind == "jump_faster_than_a_hand":
                    sample.position = pos + np.array([0.0, 0.05, 0.0])
        else:
            now_k = now
        f = np.array(loop.step(sample, now_k), dtype=float)
        assert np.isfinite(f).all()
        assert np.linalg.norm(f) <= limit * (1 + 1e-12)
        assert not f.any() or np.linalg.norm(f - prev) <= step_limit
        if kind in ("nan_position", "stale", "future"):
            assert not f.any(), kind  # zero within the tick (stop_time = one tick)
        # a move or a step back in time is judged against the last good sample: only right after one
        # (an 'ok' sample may itself be refused, e.g. the move back from a jump that was just credible,
        # a sample stamped ahead of the clock never becomes the reference, and one stamped 10 s back
        # makes the next one 10 s back look on time; a jump accepted as the first sample is where the
        # next jump lands)
        relative = kind in ("jump_faster_than_a_hand", "clock_and_stamp_back_10_s", "stamp_back_10_s")
        if (kind in _WILD or kind == "huge_position") and (not relative or prev_good):
            assert not f.any(), kind  # zero in this very tick
            assert loop.output().safety_flags & SAMPLE_FAULTS, (kind, status.flag_names(loop.output().safety_flags))
        prev = f
        reference = loop.sample_check.state[SAMPLE_STATE.offset("stamp")]
        prev_good = (reference == sample.timestamp == now and kind != "jump_faster_than_a_hand"
                     and not loop.output().safety_flags & SAMPLE_FAULTS)
