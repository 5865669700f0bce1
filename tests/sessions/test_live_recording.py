"""The live loop records its session through the demo's path (record_loop_tick into a
SessionWriter), from its servo thread: the session replays bit for bit, and a fault mid-session
leaves zero force, the device closed and the recording kept (issue #16 §3)."""
from __future__ import annotations

import time
from functools import partial

import numpy as np
import pytest

from arsurf.assembly import BUNDLED_SCAN, build_model, loop_metadata, preset_metadata
from arsurf.errors import LoopError, SessionError
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.replay.replay import replay
from arsurf.sessions.reader import load_session
from arsurf.sessions.writer import SessionWriter, record_loop_tick


class ClosingDevice(VirtualDevice):
    """A virtual device that remembers the forces commanded."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.forces = []

    def command_force(self, force):
        self.forces.append(np.array(force, dtype=float))
        return super().command_force(force)


@pytest.fixture(scope="module")
def setup():
    from arsurf.assembly import BRIDGE_HAPTICS

    meta = preset_metadata(BUNDLED_SCAN, "viewer", haptics=dict(BRIDGE_HAPTICS))
    return meta, build_model(meta)


def _live(setup, record=None):
    from arsurf.assembly import build_loop
    from arsurf.haptics.live_loop import LiveLoop, bridge_start

    meta, s = setup
    s.model.reset()
    s.surface.reset()
    # the hand lowers the stylus 4 mm in 0.3 s (the tip 40 nm: from 30 nm above into the surface) and holds
    hand = HandModel((np.array([0.0, 0.3, 100.0]), np.array([[0, 0, 0], [0, 0, -4e-3], [0, 0, -4e-3]])))
    dev = ClosingDevice(dt=1e-3, hand=hand)
    loop = build_loop(s.model, meta["haptics"], dev.info, bridge_start(s.surface, s.model.tip_radius))
    return LiveLoop(loop, dev, record=record), dev


def _run_until(live, ticks):
    deadline = time.monotonic() + 60.0  # generous: CI machines are shared
    while live.scheduler.ticks < ticks and live.scheduler.is_running and time.monotonic() < deadline:
        time.sleep(0.02)


def test_a_live_device_loop_records_a_session_that_replays_bit_for_bit(setup, tmp_path):
    meta, _ = setup
    path = tmp_path / "live.h5"
    live, dev = _live(setup)
    # the session records the virtual coupling the loop chose from the device: the replay rebuilds it
    with SessionWriter(path, loop_metadata(meta, live.loop)) as writer:
        live.record = partial(record_loop_tick, writer)
        live.start()
        try:
            _run_until(live, 800)
        finally:
            stats = live.stop()
    assert not dev.is_open
    s = load_session(path)
    assert s.complete and s.n_ticks == stats.ticks >= 800 and s.attrs["dropped_ticks"] == 0
    t = s.ticks
    assert np.all(np.diff(t["t"]) > 0)  # the loop clock of every tick
    assert t["in_contact"].sum() > 100 and np.abs(t["force"][:, 2]).max() > 0
    np.testing.assert_array_equal(t["device_force"][: len(dev.forces)], np.array(dev.forces)[: s.n_ticks])
    r = replay(path, BUNDLED_SCAN, tmp_path / "replay", progress=False)
    assert r.contact_mismatches == 0 and r.load_difference == 0.0 and r.depth_difference == 0.0
    out = np.genfromtxt(tmp_path / "replay" / "forces.csv", delimiter=",", names=True)
    for axis in "xyz":
        np.testing.assert_array_equal(out[f"F_recorded_{axis}_N"], out[f"F_simulated_{axis}_N"])


def test_a_fault_mid_session_keeps_the_recording_and_zeroes_the_force(setup, tmp_path):
    meta, _ = setup
    path = tmp_path / "fault.h5"
    calls = [0]

    def record(loop, t, state):
        calls[0] += 1
        if calls[0] > 500:
            raise RuntimeError("injected fault in the recorder")
        record_loop_tick(writer, loop, t, state)

    live, dev = _live(setup, record)
    with pytest.raises(LoopError, match="injected fault"):
        with SessionWriter(path, loop_metadata(meta, live.loop)) as writer:
            live.start()
            try:
                _run_until(live, 10**9)  # until the fault stops it
            finally:
                live.stop()
    assert not dev.is_open
    np.testing.assert_array_equal(dev.forces[-1], 0.0)  # the hand's last command is zero
    assert np.abs(np.array(dev.forces[:400])).max() > 0  # it felt the surface before
    with pytest.raises(SessionError, match="incomplete"):
        load_session(path)
    s = load_session(path, allow_incomplete=True)
    assert s.n_ticks == 500 and "LoopError" in s.attrs["aborted"]
    r = replay(path, BUNDLED_SCAN, tmp_path / "replay", progress=False, allow_incomplete=True)
    assert r.n_ticks == 500 and r.load_difference == 0.0
