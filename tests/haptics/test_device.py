"""Device interface, VirtualDevice (exact master + modelled hand, [Alabdulmuhsin] Eq. 30), ReplayDevice."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arsurf.errors import HapticsError
from arsurf.haptics.device import BUTTON_1, DEVICE_LIMITS, TOUCH_X, Device, DeviceInfo, DeviceState
from arsurf.haptics.replay_device import ReplayDevice
from arsurf.haptics.virtual_device import (
    DEFAULT_DAMPING,
    DEFAULT_HAND_DAMPING,
    DEFAULT_HAND_STIFFNESS,
    DEFAULT_MASS,
    HandModel,
    VirtualDevice,
    discretize_zoh,
)


def fit_sine(y, f, dt):
    """Least-squares amplitude of the sin(2 pi f t) + cos component of y (with an offset)."""
    t = np.arange(y.size) * dt
    A = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
    (a, b, _), *_ = np.linalg.lstsq(A, y, rcond=None)
    return math.hypot(a, b)


# ---------------------------------------------------------------------------------------------
# DeviceInfo, DeviceState, the base class
# ---------------------------------------------------------------------------------------------
def test_touch_x_limits_from_seed001():
    assert DEVICE_LIMITS["touch_x"] is TOUCH_X
    assert TOUCH_X.max_force == 7.9
    np.testing.assert_allclose(TOUCH_X.workspace, [0.120, 0.160, 0.120])  # X_h depth, Y_h width, Z_h height
    np.testing.assert_allclose(TOUCH_X.max_stiffness, [1860.0, 2350.0, 1480.0])  # 1.86, 2.35, 1.48 N/mm
    assert TOUCH_X.max_damping is None
    with pytest.raises(ValueError):
        TOUCH_X.workspace[0] = 1.0  # read-only


def test_device_info_validation():
    with pytest.raises(HapticsError, match=r"max_force must be positive \(got 0"):
        DeviceInfo("x", 0.0, (0.1, 0.1, 0.1), (1e3, 1e3, 1e3))
    with pytest.raises(HapticsError, match="max_force must be positive"):
        DeviceInfo("x", math.nan, (0.1, 0.1, 0.1), (1e3, 1e3, 1e3))
    with pytest.raises(HapticsError, match="workspace must be a scalar or a 3-vector"):
        DeviceInfo("x", 1.0, (0.1, 0.1), (1e3, 1e3, 1e3))
    with pytest.raises(HapticsError, match="workspace extents must be positive"):
        DeviceInfo("x", 1.0, (0.1, -0.1, 0.1), (1e3, 1e3, 1e3))


def test_device_state_copies():
    s = DeviceState(np.array([1.0, 2, 3]), np.array([0.1, 0, 0]), BUTTON_1, 0.5)
    c = s.copy()
    c.position[0] = 9
    assert s.position[0] == 1
    out = DeviceState()
    pos_id = id(out.position)
    s.copy_into(out)
    assert id(out.position) == pos_id and out.buttons == BUTTON_1 and out.timestamp == 0.5


def test_device_base_sanitises_every_force():
    sent = []

    class Recorder(Device):
        info = TOUCH_X

        def now(self):
            return 0.0

        def _open(self):
            pass

        def _close(self):
            pass

        def _read(self, out):
            out.timestamp = 0.0

        def _apply_force(self, force):
            sent.append(force.copy())

    dev = Recorder()
    with pytest.raises(HapticsError, match="Recorder is not open; call open"):
        dev.read_state()
    with pytest.raises(HapticsError, match="not open"):
        dev.command_force([0, 0, 0])
    with dev:
        dev.command_force([np.nan, 0, 0])
        dev.command_force([1.0, np.inf, 0])
        dev.command_force("garbage")
        dev.command_force([30.0, 40.0, 0.0])
        dev.command_force([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(sent[0], 0)
    np.testing.assert_array_equal(sent[1], 0)
    np.testing.assert_array_equal(sent[2], 0)
    assert np.linalg.norm(sent[3]) == pytest.approx(7.9) and sent[3][1] > sent[3][0] > 0
    np.testing.assert_array_equal(sent[4], [1.0, 2.0, 3.0])
    assert dev.rejected_forces == 3 and dev.clamped_forces == 1
    assert not dev.is_open


# ---------------------------------------------------------------------------------------------
# VirtualDevice
# ---------------------------------------------------------------------------------------------
def test_zoh_discretisation_of_a_double_integrator():
    Phi, Gamma = discretize_zoh([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], 0.01)
    np.testing.assert_allclose(Phi, [[1, 0.01], [0, 1]], atol=1e-15)
    np.testing.assert_allclose(Gamma[:, 0], [0.5e-4, 0.01], rtol=1e-12)


@pytest.mark.parametrize("dt", [1e-3, 1e-4, 7e-3])
def test_free_master_is_integrated_exactly(dt):
    """H_m = 1/(B_v + M_v s) under a constant force: closed form, whatever the tick."""
    M, B, F = 0.05, 0.4, 1.5
    dev = VirtualDevice(dt=dt, mass=M, damping=B, hand=None).open()
    n = int(round(0.3 / dt))
    for _ in range(n):
        dev.command_force([F, 0.0, -F])
    s = dev.read_state()
    t = n * dt
    tau = M / B
    v = F / B * (1 - math.exp(-t / tau))
    x = F / B * (t - tau * (1 - math.exp(-t / tau)))
    assert s.timestamp == pytest.approx(t)
    assert s.velocity[0] == pytest.approx(v, rel=1e-10) and s.velocity[2] == pytest.approx(-v, rel=1e-10)
    assert s.position[0] == pytest.approx(x, rel=1e-10) and s.position[1] == 0.0


def test_defaults_reproduce_seed001_eq30_as_a_whole():
    # total mass, damping, stiffness of the held stylus: 1 / (M s^2 + B s + K) = 300 / (s^2 + 100 s + 10000)
    assert 1 / DEFAULT_MASS == pytest.approx(300.0)
    assert (DEFAULT_DAMPING + DEFAULT_HAND_DAMPING) / DEFAULT_MASS == pytest.approx(100.0)
    assert DEFAULT_HAND_STIFFNESS / DEFAULT_MASS == pytest.approx(10000.0)


@pytest.mark.parametrize("f", [0.5, 10.0, 20.0, 100.0])
def test_held_stylus_frequency_response_is_seed001_eq30(f):
    """[Alabdulmuhsin] Figs. 4.15-4.17: a 0.5 N sinusoidal force on the held stylus, f = 0.5, 10, 20, 100 Hz."""
    dt = 2e-4
    amp = 0.5
    dev = VirtualDevice(dt=dt, external_force=lambda t: (amp * math.sin(2 * math.pi * f * t), 0.0, 0.0)).open()
    n_settle = int(0.2 / dt)  # transients decay as exp(-50 t)
    n = int(round(math.ceil(f) / f / dt))  # whole periods, at least one and about a second
    x = np.empty(n)
    for _ in range(n_settle):
        dev.command_force([0.0, 0.0, 0.0])
    for k in range(n):
        x[k] = dev.read_state().position[0]
        dev.command_force([0.0, 0.0, 0.0])
    w = 2 * math.pi * f
    H = 300.0 / abs(complex(10000.0 - w * w, 100.0 * w))  # m/N, Eq. 30
    # the force is sampled and held: its fundamental is attenuated by sinc(f dt)
    measured = fit_sine(x, f, dt) / amp / np.sinc(f * dt)
    assert measured == pytest.approx(H, rel=3e-3)


def test_hand_bandwidth_limits_how_fast_the_stylus_follows_a_trajectory():
    dt = 2e-4
    M, Bv, Kh, Bh = DEFAULT_MASS, DEFAULT_DAMPING, DEFAULT_HAND_STIFFNESS, DEFAULT_HAND_DAMPING
    wh = 2 * math.pi * 10.0
    ratios = {}
    for f in (1.0, 10.0, 30.0):
        a = 0.01
        hand = HandModel(trajectory=lambda t, f=f: (a * math.sin(2 * math.pi * f * t), 0.0, 0.0))
        dev = VirtualDevice(dt=dt, hand=hand).open()
        n_settle, n = int(0.5 / dt), int(round(max(1.0, 5 / f) / dt))
        for _ in range(n_settle):
            dev.command_force([0, 0, 0])
        x = np.empty(n)
        for k in range(n):
            x[k] = dev.read_state().position[0]
            dev.command_force([0, 0, 0])
        s = 2j * math.pi * f
        lp = wh**2 / (s + wh) ** 2  # intent filter, critically damped at 10 Hz
        grip = (Bh * s + Kh) / (M * s * s + (Bv + Bh) * s + Kh)
        ratios[f] = fit_sine(x, f, dt) / a
        assert ratios[f] == pytest.approx(abs(lp * grip) * np.sinc(f * dt), rel=3e-3)
    assert ratios[1.0] > 0.95 and ratios[30.0] < 0.15  # follows slow motion, not fast


def test_virtual_device_is_deterministic_and_reports_its_limits():
    def run():
        hand = HandModel(trajectory=(np.array([0.0, 0.1, 0.2]), np.array([[0, 0, 0], [0.01, 0, 0], [0.01, 0.02, 0]])))
        dev = VirtualDevice(dt=1e-3, hand=hand, buttons=lambda t: BUTTON_1 if t > 0.1 else 0).open()
        out = []
        for k in range(300):
            s = dev.read_state()
            out.append(np.r_[s.position, s.velocity, s.buttons, s.timestamp])
            dev.command_force([0.1 * math.sin(k * 0.1), 0.0, 0.0])
        return np.array(out)

    a, b = run(), run()
    np.testing.assert_array_equal(a, b)
    assert a[50, 6] == 0 and a[200, 6] == BUTTON_1
    dev = VirtualDevice(dt=1e-3, mass=0.01, damping=0.5)
    np.testing.assert_allclose(dev.info.max_stiffness, 4 * 0.01 / 1e-6)  # corrected Table II, K_fp <= 4 M_v / T_e^2
    np.testing.assert_allclose(dev.info.max_damping, 2 * 0.01 / 1e-3 - 0.5)
    assert dev.info.max_force == TOUCH_X.max_force


def test_virtual_device_reset_and_bad_settings():
    dev = VirtualDevice(dt=1e-3, initial_position=(0.01, 0, 0)).open()
    for _ in range(10):
        dev.command_force([1.0, 0, 0])
    dev.reset()
    s = dev.read_state()
    assert s.timestamp == 0.0 and s.position[0] == 0.01 and (s.velocity == 0).all()
    with pytest.raises(HapticsError, match="dt must be a positive tick period"):
        VirtualDevice(dt=0.0)
    with pytest.raises(HapticsError, match="mass must be positive"):
        VirtualDevice(mass=-1.0)
    with pytest.raises(HapticsError, match="hand must be a HandModel or None"):
        VirtualDevice(hand="left")
    with pytest.raises(HapticsError, match="trajectory times must be strictly increasing"):
        HandModel(trajectory=(np.array([0.0, 0.0]), np.zeros((2, 3))))
    with pytest.raises(HapticsError, match="hand bandwidth must be a positive frequency"):
        HandModel(bandwidth=0.0)


# ---------------------------------------------------------------------------------------------
# ReplayDevice
# ---------------------------------------------------------------------------------------------
def test_replay_interpolates_positions_and_holds_buttons(rng):
    t = np.sort(rng.uniform(0, 1, 40))
    t[0] = 0.0
    pos = rng.normal(size=(40, 3)) * 1e-3
    buttons = rng.integers(0, 4, 40)
    dt = 1e-3
    dev = ReplayDevice(t, pos, buttons=buttons, dt=dt).open()
    for k in range(int(t[-1] / dt) + 5):
        s = dev.read_state()
        tk = k * dt
        assert s.timestamp == pytest.approx(tk)
        ref = [np.interp(tk, t, pos[:, j]) for j in range(3)]
        np.testing.assert_allclose(s.position, ref, rtol=0, atol=1e-15)
        i = max(0, np.searchsorted(t, tk, side="right") - 1)
        assert s.buttons == buttons[i]
        if tk < t[-1]:
            np.testing.assert_allclose(s.velocity, (pos[i + 1] - pos[i]) / (t[i + 1] - t[i]), rtol=1e-12)
        else:
            assert (s.velocity == 0).all()
        dev.command_force([0.0, 0.0, 1e-3 * k])
    assert dev.finished
    times, forces = dev.commanded_forces()
    assert forces.shape[0] == times.shape[0] <= math.ceil(t[-1] / dt) + 2
    np.testing.assert_allclose(forces[:, 2], 1e-3 * np.arange(forces.shape[0]))
    np.testing.assert_allclose(times, dt * np.arange(forces.shape[0]))


def test_replay_with_recorded_velocity_loop_and_logged_forces():
    t = np.array([0.0, 0.1, 0.2])
    pos = np.array([[0, 0, 0], [0.01, 0, 0], [0.01, 0.01, 0]], dtype=float)
    vel = np.array([[0.1, 0, 0], [0.05, 0.05, 0], [0, 0.1, 0]])
    dev = ReplayDevice(t, pos, velocity=vel, dt=0.05, loop=True).open()
    states = []
    for _ in range(9):
        states.append(dev.read_state().copy())
        dev.command_force([np.nan, 0, 0])  # logged as zero: NaN never reaches a device
    np.testing.assert_allclose(states[1].velocity, [0.075, 0.025, 0])  # interpolated recorded velocity
    np.testing.assert_allclose(states[4].position, states[0].position)  # looped after 0.2 s
    assert not dev.finished and dev.rejected_forces == 9


def test_replay_validation():
    with pytest.raises(HapticsError, match=r"position must have shape \(n, 3\) = \(2, 3\)"):
        ReplayDevice([0, 1], np.zeros((3, 3)))
    with pytest.raises(HapticsError, match=r"strictly increasing \(t\[0\] = 1.0"):
        ReplayDevice([1.0, 0.5], np.zeros((2, 3)))
    with pytest.raises(HapticsError, match="must be finite"):
        ReplayDevice([0.0, 1.0], [[0, 0, 0], [np.nan, 0, 0]])
    with pytest.raises(HapticsError, match="buttons must be"):
        ReplayDevice([0.0, 1.0], np.zeros((2, 3)), buttons=[0.5, 1.0])
