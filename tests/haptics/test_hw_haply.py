"""The Haply adapter against a simulated Inverse3 and handle on pseudo-terminals, speaking the
serial protocol as HaplyHardwareAPI implements it: the wake-up, frame and units, the limits it
must be given, the handle's buttons (and its silence), the full 1 kHz loop recorded, and the
device disappearing mid-session (the package itself never raises: it returns zeros)."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

if importlib.util.find_spec("HaplyHardwareAPI") is None:
    pytest.skip("haplyhardwareapi is not installed (pip install 'arsurf[haply]')", allow_module_level=True)

from tests.support.hardware_sim.haply_pty import REST, HandlePty, Inverse3Pty, close_all  # noqa: E402
from tests.support.hardware_sim.session import run  # noqa: E402

from arsurf.errors import DeviceDisconnected, DeviceNotFound, HapticsError  # noqa: E402
from arsurf.haptics.device import BUTTON_1  # noqa: E402
from arsurf.haptics.scheduler import Scheduler  # noqa: E402
from tests.support.waiting import wait_until  # noqa: E402

# the simulated Inverse3 answers from a thread within its timeouts: alone under xdist (docs/testing.rst)
pytestmark = pytest.mark.realtime

WS = (0.20, 0.12, 0.15)


@pytest.fixture
def inv():
    p = Inverse3Pty().start()
    yield p
    close_all(p)


@pytest.fixture
def grip():
    p = HandlePty().start()
    yield p
    close_all(p)


def device(port, **kw):
    """The adapter with 100 ms read, sample and command timeouts (default 1, 5 and 10 ms), and 0.5 s
    to disconnect: the simulated device is a Python thread on a shared machine, and answers in
    0.1 ms typically but up to 30 ms under load (and the loop may stall as long)."""
    from arsurf.haptics.haply import HaplyDevice

    return HaplyDevice(port, **{"max_force": 4.0, "workspace": WS, "read_timeout": 0.1, "sample_timeout": 0.1,
                                "command_timeout": 0.1, "disconnect_after": 0.5, **kw})


def test_limits_are_required_and_given(inv):
    from arsurf.haptics.haply import MAX_FORCE_N, HaplyDevice

    with pytest.raises(HapticsError, match="reports no workspace"):
        HaplyDevice(inv.path, max_force=3.0)
    with device(inv.path, max_force=None) as dev:  # first connection: 1 N
        assert dev.info.max_force == 1.0 and dev.safety_record()["force_limit_source"] == "first connection"
    with pytest.raises(HapticsError, match="above what"):  # the published peak force bounds it
        device(inv.path, max_force=MAX_FORCE_N * 1.2).open()
    with device(inv.path) as dev:
        assert dev.info.max_force == 4.0 and dev.info.workspace.tolist() == list(WS)
        assert dev.device_id == UUID_HEX
        np.testing.assert_allclose(dev.home, REST, atol=1e-4)  # home: where the handle was at opening


UUID_HEX = bytes(range(0x10, 0x20)).hex()


def test_nothing_answers_on_the_port(tmp_path):
    import os
    import pty

    m, s = pty.openpty()  # a port where nothing answers: the package returns garbage, the adapter refuses
    try:
        with pytest.raises(DeviceNotFound, match="answered the wake-up"):
            device(os.ttyname(s)).open()
    finally:
        os.close(m)
        os.close(s)
    with pytest.raises(DeviceNotFound, match="does not exist"):
        device(str(tmp_path / "ttyACM9")).open()


def test_axes_units_and_force_sign(inv):
    """The hand moves the handle 10 mm to the right of where it was at opening: x = +0.01 m; a
    constant +1 N along arsurf z (up) lifts it 1/k_hand."""
    with device(inv.path) as dev:
        inv.hand = REST + [0.010, 0.0, 0.0]

        def moved():
            dev.command_force([0.0, 0.0, 0.0])
            return np.allclose(dev.read_state().position, [0.010, 0.0, 0.0], atol=2e-4)

        wait_until(moved, what="the handle's 10 mm move reaching read_state")
        dev.command_force([0.0, 0.0, 0.0])
        np.testing.assert_allclose(dev.read_state().position, [0.010, 0.0, 0.0], atol=2e-4)
        push = np.array([0.0, 0.0, 1.0])
        last = []

        def source():
            st = dev.read_state()
            last[:] = [st.position.copy(), inv.state()[2]]  # the handle, and the force the device applies
            return st

        Scheduler(lambda st, inputs, dt: push, None, rate=1000.0, source=source, sink=dev.command_force).run_for(1.0)
        np.testing.assert_allclose(last[1], [0.0, 0.0, 1.0], atol=1e-6)  # float32 on the wire
        np.testing.assert_allclose(last[0], [0.010, 0.0, 1.0 / 200.0], atol=3e-4)
        # the loop has stopped: once its last command is older than command_timeout the device gets zero
        wait_until(lambda: not inv.state()[2].any(), what="zero force after the loop's last command")


def test_handle_buttons_and_a_silent_handle(inv, grip):
    with device(inv.path, handle_port=grip.path, handle_timeout=0.1) as dev:
        wait_until(lambda: dev.read_state().buttons == 0, what="the released buttons")
        assert dev.read_state().buttons == 0
        grip.buttons = 1
        wait_until(lambda: dev.read_state().buttons == BUTTON_1, what="button 1 pressed")
        assert dev.read_state().buttons == BUTTON_1
        grip.buttons = 0
        wait_until(lambda: dev.read_state().buttons == 0, what="button 1 released")
        assert dev.read_state().buttons == 0
        grip.unplug()  # silent: reads as the disengage button held
        wait_until(lambda: dev.read_state().buttons == BUTTON_1, what="the silent handle read as disengaged")
        assert dev.read_state().buttons == BUTTON_1


def test_the_full_loop_records_positions_and_forces(inv, tmp_path):
    inv.hand = REST + [0.0, 0.0, -0.003]  # the hand presses 3 mm below where it opened the device
    with device(inv.path) as dev:
        inv.hand = dev.home + [0.0, 0.0, -0.003]
        r = run(dev, tmp_path / "s.h5", 1.5)
        applied = inv.state()[2]
    assert r.error is None and r.complete
    t = r.ticks
    z, fz = t["stylus_position"][:, 2], t["device_force"][:, 2]
    assert -0.003 < z[-1] < -0.0005
    # at rest the coupling's spring law holds, tick by tick; the simulated device is a Python thread
    # that a loaded machine can stall for tens of ms, kicking the handle, so the law is judged by the
    # median over the last half second (a mean over 100 ticks was 5.3 % off after one such kick)
    rest = slice(-500, None)
    np.testing.assert_allclose(np.median(fz[rest] / (200.0 * (z[rest] + 0.003))), 1.0, rtol=0.02)
    assert np.linalg.norm(t["device_force"], axis=1).max() <= 4.0 * (1 + 1e-12)
    assert inv.max_force_seen <= 4.0 * (1 + 1e-6)  # float32 on the wire
    np.testing.assert_allclose(t["probe_position"][:, 2], 25e-9 + z * 1e-5, atol=1e-15)
    np.testing.assert_allclose(applied, 0.0)  # the loop's stop commanded zero, and the device got it


def test_the_device_disappearing_mid_session(inv, tmp_path):
    """The cable is pulled at 0.5 s: the package returns zeros (it never raises), the adapter
    counts them as missed samples, zero force, a clean DeviceDisconnected, the recording kept."""
    dev = device(inv.path)
    dev.open()
    inv.hand = dev.home + [0.0, 0.0, -0.003]
    unplugged = []
    r = run(dev, tmp_path / "s.h5", 3.0, events=[(0.5, lambda: (unplugged.append(dev.now()), inv.unplug()))])
    dev.close()
    assert isinstance(r.error.__cause__, DeviceDisconnected) and not r.complete
    f = np.linalg.norm(r.ticks["device_force"], axis=1)
    after = r.ticks["t"] > unplugged[0] - r.t0
    # the ticks right after the pull still read the last state the link brought back, until it is
    # older than sample_timeout (0.1 s here, 5 ms shipped) or the link has found its reply lost
    # (2 read timeouts): from then on the sample is missed and the force zero (10 ms: a tick's margin)
    late = r.ticks["t"] > unplugged[0] - r.t0 + dev.sample_timeout + 0.01
    assert f[~after].max() > 0.1 and late.sum() >= 3 and np.all(f[late] == 0.0), f[after]


def test_a_lost_reply_is_retried_with_zero(inv, tmp_path):
    """The Inverse3 applies a force but its reply is lost: the adapter's link thread (not the loop)
    waits for it, and the next command it sends - the retry - is zero, never the held force again;
    the session goes on. (The loop's side, on a modelled clock: tests/haptics/test_haply_link.py.)"""
    inv.hand = REST + [0.0, 0.0, -0.003]
    with device(inv.path, read_timeout=0.05, disconnect_after=0.5) as dev:  # 0.5 s: a loaded machine's slow replies
        inv.hand = dev.home + [0.0, 0.0, -0.003]  # pressed: the loop pushes up
        r = run(dev, tmp_path / "s.h5", 1.2, events=[(0.4, lambda: inv.lose(1, above=0.05)),
                                                          (0.8, lambda: inv.lose(1, above=0.05))])
    assert r.error is None
    log = list(inv.commands_log)
    assert len(inv.lost_at) == 2
    for k in inv.lost_at:
        assert np.linalg.norm(log[k][1]) > 0.05, log[k]  # it was pushing
        np.testing.assert_array_equal(log[k + 1][1], 0.0)  # the retry: zero
    assert dev.link.lost_replies >= 2 and dev.link.zero_retries >= 2  # (and any reply slower than 50 ms)
