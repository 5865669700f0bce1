"""The Force Dimension adapter against a simulated SDK (a C library compiled here that exports the
SDK functions forcedimension-core binds and simulates an omega.3 with a mass-spring handle):
frame and units, limits from the device, calibration, the firmware watchdog, the full 1 kHz loop
recorded, and the device disappearing mid-session."""
from __future__ import annotations

import ctypes
import importlib.util
import itertools
import os
import subprocess
import sys
import time

import numpy as np
import pytest

if importlib.util.find_spec("forcedimension_core") is None:  # importing it would load the SDK library
    pytest.skip("forcedimension-core is not installed (pip install 'arsurf[forcedimension]')", allow_module_level=True)

from tests.support import hardware_sim  # noqa: E402
from tests.support.hardware_sim.session import run  # noqa: E402

from arsurf.errors import DeviceDisconnected, DeviceNotFound, HapticsError, MissingDependency  # noqa: E402
from arsurf.haptics.scheduler import Scheduler  # noqa: E402

# the simulated SDK's watchdog and 1 kHz loop run on wall-clock time: alone under xdist (docs/testing.rst)
pytestmark = pytest.mark.realtime

OMEGA3, FALCON = 33, 60


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    if hardware_sim.CC is None:
        pytest.skip(hardware_sim.NO_COMPILER)
    sdk, lib = hardware_sim.build_fdsdk(tmp_path_factory.mktemp("fdsdk"))
    if "forcedimension_core.runtime" in sys.modules:  # loaded by another test module: reuse its library
        from forcedimension_core import runtime

        path = runtime._libdrd._name
    else:
        os.environ["FDSDK"] = str(sdk)
        from arsurf.haptics.forcedimension import _sdk

        _sdk()
        path = str(lib)
    h = hardware_sim.load(path)
    h.sim_set_hand.argtypes = [ctypes.POINTER(ctypes.c_double)] * 2 + [ctypes.c_double] * 3
    h.sim_place.argtypes = [ctypes.POINTER(ctypes.c_double)]
    return h


def _vec(*v):
    return (ctypes.c_double * len(v))(*v)


def state(sim):
    out = (ctypes.c_double * 12)()
    sim.sim_state(out)
    a = np.array(out)
    return {"x": a[0:3], "v": a[3:6], "applied": a[6:9], "commanded": a[9:12]}


def counters(sim):
    out = (ctypes.c_double * 15)()
    sim.sim_counters(out)
    keys = ["set_force", "get_position", "autoinit", "watchdog_trips", "saturated", "max_commanded", "max_applied",
            "sdk_cap", "watchdog", "force_on", "opened", "expert", "expert_refused", "drd_refused", "drd_opened"]
    return dict(zip(keys, np.array(out)))


def reset(sim, kind=OMEGA3, calibrated=1, kinematics=1, hand=(0.0, 0.0, 0.0), amp=(0.0, 0.0, 0.0), freq=0.0,
          watchdog=1):
    sim.sim_reset(kind, calibrated, kinematics, watchdog)
    sim.sim_set_hand(_vec(*hand), _vec(*amp), freq, 200.0, 5.0)
    sim.sim_place(_vec(*hand))


def device(**kw):
    from arsurf.haptics.forcedimension import ForceDimensionDevice

    return ForceDimensionDevice(**kw)


#: the simulated kinematics reach a cylinder of radius 70 mm and height 120 mm (fdsdk_sim.c): the largest
#: box inside it is 70 sqrt(2) mm square by 120 mm; its bounding box (140 x 140 x 120 mm) is not reachable
INSCRIBED = [0.070 * 2**0.5, 0.070 * 2**0.5, 0.120]


def test_limits_come_from_the_device(sim):
    reset(sim)
    with device(max_force=5.0) as dev:
        assert dev.workspace_source == "kinematics"
        np.testing.assert_allclose(dev.info.workspace, INSCRIBED, atol=2e-4)
        assert dev.info.max_force == 5.0
        assert counters(sim)["sdk_cap"] == 5.0  # the SDK enforces the same cap
        assert counters(sim)["watchdog"] == pytest.approx(0.02)
        assert dev.watchdog_set and dev.safety_record()["watchdog_set"] is True
    reset(sim, kinematics=0)
    with device(max_force=12.0) as dev:  # no kinematics: the omega's nominal figures (12 N, 160 mm circle x 110 mm)
        assert dev.workspace_source == "nominal"
        assert dev.info.max_force == 12.0
        np.testing.assert_allclose(dev.info.workspace, [0.160 / 2**0.5, 0.160 / 2**0.5, 0.110])
    with pytest.raises(HapticsError, match="above what"):
        device(max_force=50.0).open()
    assert counters(sim)["opened"] == 0  # a refused open leaves nothing open


def test_the_workspace_is_reachable_everywhere(sim):
    """Every corner of the measured box maps through the SDK's inverse kinematics to encoders in
    its range; the box grown by 1 % along x is not (it is the largest), nor is the bounding box."""
    from forcedimension_core import dhd, drd

    from arsurf.haptics.forcedimension import reachable_box

    reset(sim)
    i = drd.open()
    try:
        assert dhd.expert.enableExpertMode() == 0
        half = reachable_box(dhd, i)
        emin, emax, enc = [0] * 8, [0] * 8, [0, 0, 0]
        dhd.expert.getEncRange(emin, emax, i)

        def inside(p):
            dhd.expert.deltaPositionToEncoder(tuple(p), enc, i)
            return all(emin[a] <= enc[a] <= emax[a] for a in range(3))

        corners = np.array(list(itertools.product((-1, 1), repeat=3)), dtype=float)
        assert all(inside(c * half) for c in corners)
        assert not inside(corners[-1] * half * [1.01, 1.0, 1.0])
        assert not inside([0.07, 0.07, 0.0])  # the bounding box's corner
    finally:
        dhd.expert.disableExpertMode()
        drd.close(i)


def test_expert_calls_need_expert_mode_and_it_is_left_after(sim):
    """The simulated SDK refuses the watchdog and the kinematics without dhdEnableExpertMode, as the
    SDK does; the adapter turns it on for them and off before the loop runs."""
    from forcedimension_core import dhd, drd

    reset(sim)
    i = drd.open()
    assert dhd.expert.setWatchdog(160, i) == -1 and dhd.errorGetLast() == 9  # DHD_ERROR_EXPERT_MODE_DISABLED
    drd.close(i)
    reset(sim)
    with device(max_force=2.0) as dev:
        c = counters(sim)
        assert c["expert_refused"] == 0 and c["expert"] == 0  # every expert call in expert mode, and left after
        assert c["watchdog"] == pytest.approx(0.02) and dev.watchdog_set
        assert c["drd_opened"] == 1 and c["drd_refused"] == 0  # opened by the DRD, as its calls need


def test_a_device_without_watchdog_needs_an_explicit_flag(sim, tmp_path, capsys):
    reset(sim, watchdog=0)
    with pytest.raises(HapticsError, match="watchdog could not be set.*allow_no_watchdog"):
        device(max_force=2.0).open()
    assert counters(sim)["opened"] == 0 and counters(sim)["force_on"] == 0
    with pytest.raises(HapticsError, match="watchdog=0 turns"):
        device(watchdog=0.0)
    with device(max_force=2.0, allow_no_watchdog=True) as dev:
        rec = dev.safety_record()
        assert rec["watchdog_set"] is False and rec["allow_no_watchdog"] is True
    from arsurf.cli import main

    assert main(["live", "--device", "forcedimension", "--seconds", "0.2"]) != 0
    assert "--allow-no-watchdog" in capsys.readouterr().err
    path = tmp_path / "nowd.h5"
    assert main(["live", "--device", "forcedimension", "--seconds", "0.2", "--allow-no-watchdog",
                 "--record", str(path)]) == 0
    from arsurf.sessions.reader import load_session

    meta = load_session(path).metadata["device"]
    assert meta["watchdog_set"] is False and meta["allow_no_watchdog"] is True
    assert meta["workspace_source"] == "kinematics"


def test_first_connection_is_at_one_newton(sim):
    """Without max_force the omega.3 (12 N nominal) runs at 1 N; the SDK holds the same cap."""
    reset(sim)
    with device() as dev:
        assert dev.info.max_force == 1.0 and counters(sim)["sdk_cap"] == 1.0
        assert dev.safety_record()["force_limit_source"] == "first connection"
        assert "first-connection limit 1 N of 12 N" in dev.info.name
        dev.command_force([0.0, 0.0, 5.0])
        assert np.linalg.norm(state(sim)["applied"]) == pytest.approx(1.0)


def test_axes_and_force_sign_at_rest(sim):
    """The hand holds the handle at (10, 20, -5) mm in the SDK frame; a constant +1 N along arsurf
    x (the operator's right) moves it +1/k_hand along the SDK's y: same axis, same sign."""
    reset(sim, hand=(0.010, 0.020, -0.005))
    with device() as dev:
        s = dev.read_state()
        np.testing.assert_allclose(s.position, [0.020, -0.010, -0.005], atol=1e-6)
        push = np.array([1.0, 0.0, 0.0])
        read = []  # the handle as the loop read it, under the push: once the loop stops nothing commands
        # the force, and a stop that outlasts the firmware's 20 ms watchdog (29 ms measured) turns it off
        sched = Scheduler(lambda st, inputs, dt: push, None, rate=1000.0,
                          source=lambda: read.append(dev.read_state()) or read[-1], sink=dev.command_force)
        sched.run_for(1.0)
        s = read[-1]
        np.testing.assert_allclose(state(sim)["commanded"], [0.0, 1.0, 0.0])
        np.testing.assert_allclose(s.position, [0.020 + 1.0 / 200.0, -0.010, -0.005], atol=2e-4)
        assert abs(s.velocity).max() < 5e-3


def test_the_full_loop_records_positions_and_forces(sim, tmp_path):
    """The hand presses the stylus 3 mm down (the probe 30 nm into a flat sample) and holds: the
    loop pushes up until the handle rests where the device's force balances the hand's spring,
    F_z = k_hand (p_hand - z), and the device applies the force the session recorded. A run the
    machine stalled in (a tick more than 10 ms late, or the device's 20 ms watchdog tripped: the
    handle is then pushed by the hand alone until the loop is back, and settles again) is run again,
    up to three times: rest is asserted on an undisturbed run."""
    for attempt in range(3):
        reset(sim, hand=(0.0, 0.0, -0.003))
        seen = {}
        with device(max_force=4.0) as dev:
            r = run(dev, tmp_path / f"s{attempt}.h5", 1.5, events=[(1.3, lambda: seen.update(state(sim)))])
            last = state(sim)
        assert r.error is None and r.complete
        stalled = counters(sim)["watchdog_trips"] > 0 or np.diff(r.ticks["t"]).max() > 0.010
        if not stalled:
            break
    t = r.ticks
    assert len(t["t"]) > 1000  # 1.5 s at 1 kHz (a loaded machine skips some ticks)
    z, fz = t["stylus_position"][:, 2], t["device_force"][:, 2]
    assert -0.003 < z[-1] < -0.0005  # held above the hand's set point, in contact (probe > 5 nm down)
    rest = slice(-100, None)
    assert abs(t["stylus_velocity"][rest]).max() < 2e-3
    np.testing.assert_allclose(fz[rest], 200.0 * (z[rest] + 0.003), rtol=0.03)  # pushes up: +z is up in both frames
    np.testing.assert_allclose(seen["applied"], [0.0, 0.0, fz[-1]], atol=0.03 * fz[-1])
    assert abs(t["stylus_position"][:, :2]).max() < 1e-6 and abs(t["device_force"][:, :2]).max() < 1e-6
    np.testing.assert_allclose(t["probe_position"][:, 2], 25e-9 + z * 1e-5, atol=1e-15)  # 1 mm -> 10 nm
    assert np.linalg.norm(t["device_force"], axis=1).max() <= 4.0 * (1 + 1e-12)
    assert counters(sim)["max_commanded"] <= 4.0 * (1 + 1e-12)
    np.testing.assert_allclose(last["commanded"], 0.0)  # on stop the loop commanded zero


def test_forces_saturate_at_the_device_limit(sim, tmp_path):
    # 10 mm in: the default virtual coupling (~930 N/m at the handle here) alone asks for 9 N, and the
    # force gain for kN; 3 mm in (2.8 N through the coupling) would not reach the limit
    reset(sim, hand=(0.0, 0.0, -0.010))
    with device(max_force=3.0) as dev:
        r = run(dev, tmp_path / "s.h5", 0.6, force_gain=1e9)  # asks for kN
    assert r.error is None
    norms = np.linalg.norm(r.ticks["device_force"], axis=1)
    assert norms.max() == pytest.approx(3.0, rel=1e-9)
    assert counters(sim)["max_commanded"] <= 3.0 * (1 + 1e-12)


def test_the_device_disappearing_mid_session(sim, tmp_path):
    """Unplugged at 0.5 s: zero force from the first missed sample, a clean DeviceDisconnected,
    and the recording kept (marked incomplete) with every tick up to the end."""
    reset(sim, hand=(0.0, 0.0, -0.003))
    dev = device(disconnect_after=0.05)
    dev.open()
    r = run(dev, tmp_path / "s.h5", 3.0, events=[(0.5, sim.sim_unplug)])
    dev.close()  # the device is gone: close still releases it
    assert isinstance(r.error.__cause__, DeviceDisconnected)
    assert "has not answered" in str(r.error) and not r.complete
    f = np.linalg.norm(r.ticks["device_force"], axis=1)
    assert f[:400].max() > 0.1  # it was pushing before
    k = dev.missed_samples - 1  # recorded ticks after the unplugging (the last read raised, unrecorded)
    assert 1 <= k < 200
    assert f[-k - 1] > 0.1 and np.all(f[-k:] == 0.0), f[-k - 3:]  # zero force from the first missed sample
    assert np.all(r.ticks["stylus_position"][-k:] == r.ticks["stylus_position"][-k - 1])  # the last good sample
    assert np.isfinite(r.ticks["t"]).all() and len(f) > 100 and r.ticks["t"][-1] > 0.5


def test_watchdog_zeroes_a_stalled_loop(sim):
    reset(sim)
    with device(watchdog=0.01, max_force=3.0) as dev:
        dev.command_force([0.0, 0.0, 2.0])
        assert state(sim)["applied"][2] == pytest.approx(2.0)
        time.sleep(0.05)  # the loop stalls: no force command for 50 ms
        assert np.all(state(sim)["applied"] == 0.0)
        assert counters(sim)["watchdog_trips"] == 1


def test_calibration_is_asked_for_and_done(sim):
    reset(sim, calibrated=0)
    with pytest.raises(HapticsError, match="not calibrated.*calibrate=True"):
        device().open()
    assert counters(sim)["opened"] == 0
    with device(calibrate=True, max_force=12.0) as dev:
        assert counters(sim)["autoinit"] == 1
        assert counters(sim)["force_on"] == 1
        assert dev.info.max_force == 12.0


def test_falcon_and_no_device(sim):
    reset(sim, kind=FALCON, kinematics=0)
    with device(max_force=9.0) as dev:  # no DRD on a Falcon: no calibration step; nominal 9 N
        assert dev.info.max_force == 9.0 and dev.workspace_source == "nominal"
    with pytest.raises(HapticsError, match="above what"):
        device(max_force=9.5).open()
    sim.sim_unplug()
    with pytest.raises(DeviceNotFound, match="no device connected"):
        device().open()


def test_probe_lists_the_device(sim):
    from arsurf.haptics.forcedimension import probe

    reset(sim)
    rep = probe()
    assert rep.installed and "SDK 3.17.0" in rep.detail
    assert rep.devices == ["#0 omega.3 s/n 4242, watchdog_set yes, workspace_source kinematics (99 x 99 x 120 mm, SDK "
                           "axes)"], rep.devices
    reset(sim, watchdog=0, kinematics=0)
    assert probe().devices == ["#0 omega.3 s/n 4242, watchdog_set no (needs --allow-no-watchdog), workspace_source "
                               "nominal"]
    assert counters(sim)["opened"] == 0


def test_missing_sdk_library_is_one_clear_error(tmp_path):
    code = ("from arsurf.haptics.forcedimension import ForceDimensionDevice\n"
            "try:\n    ForceDimensionDevice().open()\n"
            "except Exception as e:\n    print(type(e).__name__, e)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("FDSDK", "FORCEDIM_SDK")}
    env["HOME"] = str(tmp_path)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.stdout.startswith("MissingDependency") and "libdrd" in out.stdout and "FDSDK" in out.stdout, out
    assert MissingDependency.__name__ in out.stdout


def test_arsurf_live_drives_the_device_and_records_a_replayable_session(sim, tmp_path, capsys):
    """``arsurf live --device forcedimension``: the hand holds the handle 4 mm down (the probe 10 nm
    into the bundled scan): the loop pushes up through the SDK, within --max-force-n, the session
    replays exactly, and the device gets zero force when the command ends."""
    from arsurf.assembly import BUNDLED_SCAN
    from arsurf.cli import main
    from arsurf.sessions.reader import load_session

    reset(sim, hand=(0.0, 0.0, -0.004))
    path = tmp_path / "fd.h5"
    assert main(["live", "--device", "forcedimension", "--max-force-n", "4", "--seconds", "1.0",
                 "--record", str(path)]) == 0, capsys.readouterr().err
    assert "on omega.3" in capsys.readouterr().err
    s = load_session(path)
    t = s.ticks
    assert s.complete and s.n_ticks > 300
    dev = s.metadata["device"]
    assert dev["interface"] == "forcedimension" and dev["name"].startswith("omega.3") and dev["max_force"] == 4.0
    np.testing.assert_allclose(dev["workspace"], INSCRIBED, atol=2e-4)  # measured on its kinematics
    assert dev["watchdog_set"] is True and dev["workspace_source"] == "kinematics"
    assert dev["force_limit_source"] == "given" and dev["allow_no_watchdog"] is False
    z = t["stylus_position"][:, 2]
    assert -0.0045 < z.min() and z.max() < -0.0035  # where the hand holds it (SDK z is arsurf z)
    np.testing.assert_allclose(t["probe_position"][:, 2] - t["probe_position"][0, 2], (z - z[0]) * 1e-5, atol=1e-15)
    # pushes the hand up, except in the ticks the safety layer faulted (its deadline watchdog trips when
    # a shared machine makes the 1 kHz thread late: zero force at once, tests/haptics/test_safety.py)
    from arsurf.haptics.safety import STALE, WATCHDOG

    faulted = (t["safety_flags"] & (STALE | WATCHDOG)) != 0
    pressing = (t["in_contact"] == 1) & ~faulted
    assert pressing.sum() > 50 and np.median(t["device_force"][pressing, 2]) > 0.0
    assert np.all(t["device_force"][faulted] == 0.0)
    assert np.linalg.norm(t["device_force"], axis=1).max() <= 4.0 * (1 + 1e-12)
    assert counters(sim)["max_commanded"] <= 4.0 * (1 + 1e-12)
    np.testing.assert_allclose(state(sim)["commanded"], 0.0)  # zero force at the end
    assert counters(sim)["opened"] == 0  # and the device released
    assert main(["replay", str(path), "--scan", str(BUNDLED_SCAN), "--out", str(tmp_path / "replay")]) == 0
    assert "contact-state mismatches 0" in capsys.readouterr().out
