"""The Haply adapter's timing against the package's own behaviour, on a modelled clock: the
stand-in binding (tests/support/hardware_sim/haply_binding.py) charges each exchange's modelled
duration to the thread that made it, as ``haplyhardwareapi`` makes its caller wait (a lost reply:
two read timeouts of busy polling), and the device's clock moves only when the test says. So
these tests read, without timing anything, who waited on the serial port and for how long, and
what each exchange sent. They need neither the package nor a serial port."""
from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from arsurf.haptics import haply
from arsurf.haptics.haply import HaplyDevice
from arsurf.haptics.safety import SafetyLayer
from tests.support.hardware_sim.haply_binding import FakeHaplyBinding, ModelClock
from tests.support.waiting import wait_until

PERIOD = 1e-3  # s: the 1 kHz loop
PUSH = (0.0, 0.0, 0.5)  # N: the loop keeps pushing up, whatever it reads
SAMPLE_TIMEOUT = 0.005  # s: the shipped limit of a state's age (HaplyDevice's sample_timeout)


@pytest.fixture
def fake(tmp_path, monkeypatch):
    """An open HaplyDevice (shipped defaults) on the stand-in binding; yields (device, Inverse3, clock)."""
    clock = ModelClock()
    port = tmp_path / "ttyACM0"
    port.touch()
    binding = FakeHaplyBinding(clock, str(port))
    monkeypatch.setattr(haply, "_api", lambda: binding)
    dev = HaplyDevice(str(port), workspace=(0.2, 0.12, 0.15))
    assert getattr(dev, "sample_timeout", SAMPLE_TIMEOUT) == SAMPLE_TIMEOUT
    dev.now = clock  # the device's clock is the model's
    dev.open()
    yield dev, binding.inverse3, clock
    binding.inverse3.release()
    dev.close()


def tick(dev, inv, clock, force=PUSH):
    """One loop tick one period after the last: read, command; returns the modelled time the loop's
    own thread spent in the package during it, once the exchange the command asked for is made."""
    me = threading.get_ident()
    clock.advance(PERIOD)
    first = len(inv.calls)
    dev.read_state()
    dev.command_force(force)
    wait_until(lambda: len(inv.calls) > first, what="the exchange of this tick's command")
    return sum(c.cost for c in inv.calls[first:] if c.thread == me)


def test_a_lost_reply_never_blocks_the_loop(fake):
    """The package waits two read timeouts for a lost reply (2 ms at the shipped 1 ms): never in
    the loop's tick, which only swaps mailboxes with the link's thread."""
    dev, inv, clock = fake
    blocked = []
    for k in range(30):
        if k in (10, 20):
            inv.lose(1)
        blocked.append(tick(dev, inv, clock))
    assert sum(c.lost for c in inv.calls) == 2  # both losses happened, each costing 2 read timeouts
    assert max(c.cost for c in inv.calls) == pytest.approx(2 * dev.read_timeout)
    assert max(blocked) <= PERIOD, blocked


def test_the_retry_after_a_lost_reply_sends_zero(fake):
    """The device applied the push and its reply was lost: the next command it gets is zero, not
    the held push again, even though the loop keeps commanding the push from what it last read;
    once a state newer than the loss has been read, the loop's commands go out again."""
    dev, inv, clock = fake
    for k in range(20):
        if k == 8:
            inv.lose(1)
        tick(dev, inv, clock)
    calls = inv.calls
    i = next(j for j, c in enumerate(calls) if c.lost)
    assert calls[i].force == pytest.approx(PUSH)  # it was pushing
    assert calls[i + 1].force == (0.0, 0.0, 0.0), [c.force for c in calls[i - 1:i + 4]]  # the retry: zero
    assert any(c.force == pytest.approx(PUSH) for c in calls[i + 2:])  # the loop's force again after a fresh state


def test_a_stale_sample_reads_missed_zero_force_and_flagged(fake):
    """The reply is still on its way while the loop goes on: the loop's read returns at once; a
    state older than sample_timeout is a missed sample (timestamp -inf), so the safety layer flags
    it STALE and gives zero force in that tick."""
    dev, inv, clock = fake
    safety = SafetyLayer(max_force=dev.info.max_force, dt=PERIOD)  # compiled before the link is held
    for _ in range(3):
        tick(dev, inv, clock)
    fresh = dev.read_state()
    assert 0.0 <= dev.now() - fresh.timestamp <= SAMPLE_TIMEOUT
    inv.hold()  # the next exchange waits for a reply
    clock.advance(PERIOD)
    first = len(inv.calls)
    dev.read_state()
    dev.command_force(PUSH)
    wait_until(inv.holding.is_set, what="the link's exchange waiting for its reply")
    clock.advance(SAMPLE_TIMEOUT + PERIOD)  # the loop goes on; the state ages past the limit
    missed = dev.missed_samples
    s = dev.read_state()
    assert s.timestamp == -math.inf and dev.missed_samples == missed + 1
    f = safety.step(PUSH, now=clock(), age=dev.now() - s.timestamp, buttons=s.buttons)
    np.testing.assert_array_equal(f, 0.0)
    assert "STALE" in safety.flag_names()
    assert len(inv.calls) == first  # the loop read without touching the port
    assert dev.safety_record()["sample_timeout_s"] == SAMPLE_TIMEOUT  # in the session metadata
    inv.release()
    wait_until(lambda: len(inv.calls) > first, what="the held exchange ending")


def test_a_late_reply_answers_at_most_the_retry(fake):
    """A reply later than the package's wait lands while the next exchange (the retry) waits, and
    the package returns it as the retry's reply (the protocol has no sequence number); the input is
    drained before every exchange, so from the one after the retry on each state is the reply to its
    own command (without that drain every later state is one exchange old)."""
    dev, inv, clock = fake
    for k in range(20):
        if k == 8:
            inv.lose(1, late=True)
        tick(dev, inv, clock)
    calls = inv.calls
    i = next(j for j, c in enumerate(calls) if c.lost)
    assert calls[i + 1].answer_to == i  # the late reply answered the retry
    assert [c.answer_to for c in calls[i + 2:]] == list(range(i + 2, len(calls)))
