"""``arsurf live``: the 1 kHz loop on a device chosen by name, optionally on an instrument's measured
signals, from the command line: recorded sessions that ``arsurf replay`` gives back exactly, the
simulated Nanonis controller driven through its TCP interface, a link that dies mid-session, Ctrl-C,
and one-line errors (the Force Dimension adapter's run is in tests/haptics/test_hw_forcedimension.py)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from tests.support.nanonis import quiet_afm as _afm

from arsurf.assembly import BUNDLED_SCAN
from arsurf.cli import main
from arsurf.errors import HapticsError
from arsurf.haptics.backends import DEVICES, make_device
from arsurf.instrument.nanonis_sim import NanonisSimulator
from arsurf.live import parse_instrument
from arsurf.sessions.reader import load_session

pytestmark = pytest.mark.timeout(600)
ROOT = Path(__file__).resolve().parents[2]
R, SCALE = 20e-9, 1e-5


def _live(capsys, *argv):
    rc = main(["live", *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _replayed_exactly(capsys, path, out_dir):
    assert main(["replay", str(path), "--scan", str(BUNDLED_SCAN), "--out", str(out_dir)]) == 0
    out = capsys.readouterr().out
    assert "max |depth diff| 0 m, contact-state mismatches 0" in out, out


def test_virtual_device_session_is_recorded_and_replays_exactly(capsys, tmp_path):
    """The virtual hand presses the stylus (1.5 R + 10 nm) / scale = 4 mm down in 0.3 s: the probe
    goes 10 nm into the bundled scan, the loop pushes the hand back up, every tick recorded."""
    path = tmp_path / "s.h5"
    rc, out, err = _live(capsys, "--device", "virtual", "--seconds", "1", "--record", str(path))
    assert rc == 0, err
    assert f"session recorded: {path}" in out and "arsurf replay" in out
    s = load_session(path)
    t = s.ticks
    assert s.complete and s.n_ticks > 300
    assert s.metadata["device"]["interface"] == "virtual" and s.metadata["haptics"]["source"] == "simulated"
    assert s.metadata["haptics"]["scale"] == SCALE
    # the stylus went down (4 mm at most) and the probe followed it at 1 mm -> 10 nm
    z = t["stylus_position"][:, 2]
    assert -4.2e-3 < z.min() < -2e-3
    np.testing.assert_allclose(t["probe_position"][:, 2] - t["probe_position"][0, 2], (z - z[0]) * SCALE,
                               atol=1e-15)
    pressing = t["in_contact"] == 1
    assert pressing.sum() > 50 and np.median(t["device_force"][pressing, 2]) > 0.0  # pushed back up
    assert np.linalg.norm(t["device_force"], axis=1).max() <= s.metadata["device"]["max_force"] * (1 + 1e-12)
    _replayed_exactly(capsys, path, tmp_path / "replay")


@pytest.mark.parametrize("flags", [(), ("--no-virtual-coupling",), ("--no-passivity",), ("--no-jump-blend",)],
                         ids=["default", "no-vc", "no-pc", "no-jb"])
def test_the_session_records_the_virtual_coupling_and_passivity_and_replays_with_them(capsys, tmp_path, flags):
    """By default the loop has the virtual coupling of the device and rate, the passivity
    controller and the blend of the tip's jumps, and the session says so; a flag turns one off,
    recorded too; either way the replay rebuilds the loop that ran (the replay takes the recorded
    setting, not the default)."""
    from arsurf.contact.jump_blend import BLEND_TIME
    from arsurf.haptics.gains import coupling_stiffness

    path = tmp_path / "s.h5"
    rc, out, err = _live(capsys, "--device", "virtual", "--seconds", "0.6", "--record", str(path), *flags)
    assert rc == 0, err
    h = load_session(path).metadata["haptics"]
    vc, pc = "--no-virtual-coupling" not in flags, "--no-passivity" not in flags
    assert h["virtual_coupling"] is vc and h["passivity"] is pc
    assert h["jump_blend"] == (0.0 if "--no-jump-blend" in flags else BLEND_TIME)
    if vc:
        assert h["coupling_stiffness"] == coupling_stiffness(make_device("virtual").info, 1000.0)
    else:
        assert "coupling_stiffness" not in h
    _replayed_exactly(capsys, path, tmp_path / "replay")


def test_a_session_with_the_zone_energy_as_the_contact_records_it_and_replays_exactly(capsys, tmp_path):
    """``--zone-energy``: the model's contact the energy of the whole tip (arsurf.contact.zone_energy),
    recorded in the session (absent without the flag), the pressing hand pushed back up, and the
    replay rebuilds that contact: the forces again to the bit."""
    path = tmp_path / "z.h5"
    rc, out, err = _live(capsys, "--device", "virtual", "--seconds", "0.6", "--record", str(path), "--zone-energy")
    assert rc == 0, err
    s = load_session(path)
    assert s.metadata["zone_energy"] is True and s.metadata["zone_closed_form"] is True  # its closed form by default
    t = s.ticks
    pressing = t["in_contact"] == 1
    assert pressing.sum() > 50 and np.median(t["device_force"][pressing, 2]) > 0.0
    _replayed_exactly(capsys, path, tmp_path / "replay")


def test_a_nanonis_session_reads_the_measured_force_and_replays(capsys, tmp_path):
    """The simulated Nanonis controller (a virtual AFM over a flat sample, tip at (5, 5) um) with the
    scan's origin at (4.49, 4.49, 0) um: the scan's middle, whose height is ~0 after levelling, is
    over the tip. The virtual hand presses 10 nm in: the controller's deflection input reads the
    lever bending, F = k delta, and that is the force the loop rendered."""
    afm = _afm()
    path = tmp_path / "n.h5"
    with NanonisSimulator(afm) as sim:
        host, port = sim.address
        rc, out, err = _live(capsys, "--instrument", f"nanonis://{host}:{port}", "--deflection-sensitivity-nm", "1117",
                             "--instrument-origin-nm", "4490", "4490", "0", "--seconds", "1.2",
                             "--record", str(path))
    assert rc == 0, err
    assert "instrument samples" in err and f"session recorded: {path}" in out
    s = load_session(path)
    t = s.ticks
    assert s.complete and s.n_ticks > 300
    inst = s.metadata["instrument"]
    assert inst["name"] == f"Nanonis at {host}:{port}" and inst["frame"]["origin"][0] == pytest.approx(4.49e-6)
    assert s.metadata["haptics"]["source"] == "measured"
    assert s.metadata["calibration"]["vertical_sensitivity"] == pytest.approx(1.5 * 1117e-9 / 450e-6)
    # the instrument's link thread must run in time: the loop keeps the ordinary policy by default
    assert s.metadata["realtime"]["policy"] == "ordinary" and "instrument" in s.metadata["realtime"]["reason"]
    # the controller measured the tip where the loop commanded it (scan frame)
    lag = np.abs(t["instrument_position"] - t["probe_position"])
    assert np.nanmedian(lag[:, 2]) < 2e-9
    # the measured force: the lever's deflection read back, pushing the hand up while pressing
    pressing = t["in_contact"] == 1
    assert pressing.sum() > 50
    k = 169e9 * 50e-6 * 2.5e-6**3 / (4 * 450e-6**3)  # the viewer preset's lever, E w t^3 / (4 L^3)
    # the instrument's tip goes where the hand puts it (~10 nm in); the model's tip is held short of it
    # by the default virtual coupling (5.6 nm here): the lever bends by the instrument's indentation,
    # the model's depth plus how far the probe is below the coupled tip
    assert s.metadata["haptics"]["virtual_coupling"] is True
    probe_depth = t["depth"] + t["tip_position"][:, 2] - t["probe_position"][:, 2]
    deep = pressing & (probe_depth > 9e-9)
    assert deep.sum() > 20 and np.median(t["depth"][deep]) < np.median(probe_depth[deep])
    assert np.median(t["force"][deep, 2]) == pytest.approx(k * np.median(probe_depth[deep]), rel=0.25)
    assert np.median(t["device_force"][deep, 2]) > 0.0
    _replayed_exactly(capsys, path, tmp_path / "replay")


def test_a_nanonis_link_that_dies_leaves_zero_force_and_keeps_the_recording(capsys, tmp_path):
    path = tmp_path / "dead.h5"
    with NanonisSimulator(_afm()) as sim:
        sim.faults.close_after = 600  # replies: the connection closes mid-session
        host, port = sim.address
        rc, out, err = _live(capsys, "--instrument", f"nanonis://{host}:{port}", "--deflection-sensitivity-nm", "1117",
                             "--instrument-origin-nm", "4490", "4490", "0", "--seconds", "60",
                             "--record", str(path))
    assert rc == 2
    lines = err.strip().splitlines()
    msg = lines[-1]
    assert msg.startswith("arsurf live: error: instrument link lost: ") and "closed the connection" in msg
    # the controller answers a second connection: the tip is withdrawn (the default --on-link-loss)
    assert "the tip was withdrawn over a second connection" in msg and sim.requests["ZCtrl.Withdraw"] == 1
    assert "the hand got zero force and the tip was last measured at (" in msg and "marked incomplete" in msg
    assert str(path) in msg and out == ""
    s = load_session(path, allow_incomplete=True)
    assert not s.complete and s.n_ticks > 10 and "the hand got zero force" in s.attrs["aborted"]


def test_ctrl_c_ends_the_session_normally(tmp_path):
    """Without --seconds the loop runs until SIGINT, which ends it cleanly: exit 0, a complete session."""
    path = tmp_path / "c.h5"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *sys.path]))
    p = subprocess.Popen([sys.executable, "-m", "arsurf", "live", "--record", str(path)], cwd=tmp_path, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        journal = Path(str(path) + ".journal")
        deadline = time.monotonic() + 300
        while not journal.exists() and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # some ticks
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "stopping (Ctrl-C again aborts)" in err and "session recorded" in out
    s = load_session(path)
    assert s.complete and s.n_ticks > 50


@pytest.mark.parametrize("argv, match", [
    (["--device", "falcon"], "unknown device 'falcon'; devices are: virtual, forcedimension, haply, openhaptics"),
    (["--device", "virtual", "--serial-port", "/dev/ttyACM0"],
     "--serial-port is not an option of --device virtual (it takes --max-force-n, --workspace-mm, --device-name)"),
    (["--instrument", "nanonis://lab-afm"], "instrument 'nanonis://lab-afm' is not nanonis://HOST:PORT"),
    (["--instrument", "bruker://x:1"], "unknown instrument 'bruker://x:1'; give --instrument virtual or"),
    (["--deflection-sensitivity-nm", "50"], "--deflection-sensitivity-nm set up an instrument; give --instrument"),
    (["--record", "/no/such/folder/s.h5"], "its folder does not exist"),
])
def test_bad_setups_are_one_line_before_anything_runs(capsys, argv, match):
    t0 = time.perf_counter()
    rc, out, err = _live(capsys, *argv, "--seconds", "0.1")
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("arsurf live: error: ") and match in err, err
    assert time.perf_counter() - t0 < 60  # refused before the model is built and the loop runs


def test_a_missing_vendor_package_names_the_extra(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "HaplyHardwareAPI", None)  # import HaplyHardwareAPI -> ImportError
    rc, out, err = _live(capsys, "--device", "haply", "--max-force-n", "1", "--workspace-mm", "200", "120", "150",
                         "--seconds", "0.1")
    assert rc == 2 and out == "" and err.count("\n") == 1
    assert "Haply devices need haplyhardwareapi; install it with: pip install 'arsurf[haply]'" in err


def test_a_device_that_is_not_there_is_one_line(capsys, tmp_path):
    pytest.importorskip("HaplyHardwareAPI", reason="haplyhardwareapi is not installed (pip install 'arsurf[haply]')")
    port = str(tmp_path / "ttyACM9")
    rc, out, err = _live(capsys, "--device", "haply", "--serial-port", port, "--max-force-n", "1",
                         "--workspace-mm", "200", "120", "150", "--seconds", "0.1", "--record", str(tmp_path / "x.h5"))
    assert rc == 2 and out == "" and err.count("\n") == 1
    assert f"Haply: serial port {tmp_path / 'ttyACM9'} does not exist" in err
    assert not (tmp_path / "x.h5").exists()  # nothing recorded: the device failed before the loop


def test_make_device_and_parse_instrument():
    assert DEVICES == ("virtual", "forcedimension", "haply", "openhaptics")
    dev = make_device("virtual", max_force=2.0)
    assert dev.info.max_force == 2.0 and not dev.is_open
    fd = make_device("forcedimension", max_force=3.0, calibrate=True, index=1)
    assert fd.calibrate and fd.index == 1 and fd.user_max_force == 3.0 and not fd.is_open  # nothing opened
    with pytest.raises(HapticsError, match="device 'openhaptics' takes no option port; it takes: name, max_force"):
        make_device("openhaptics", port="/dev/ttyACM0")
    with pytest.raises(HapticsError, match="disconnect_after must be in"):
        make_device("haply", max_force=1.0, workspace=(0.1, 0.1, 0.1), disconnect_after=-1.0)
    assert parse_instrument("virtual") == ("virtual",)
    assert parse_instrument("nanonis://[::1]:6501") == ("nanonis", "::1", 6501)
    for bad in ("nanonis://host:0", "nanonis://host:99999", "nanonis://:6501", "nanonis://host:65x"):
        with pytest.raises(Exception, match="is not nanonis://HOST:PORT"):
            parse_instrument(bad)


def _fake_setscheduler(monkeypatch, refuse: bool):
    """os.sched_setscheduler as an OS that grants SCHED_FIFO (recording who asked, changing
    nothing) or refuses it as to an unprivileged user (EPERM)."""
    import arsurf.haptics.scheduler as sched

    calls = []

    def fake(pid, policy, param):
        calls.append((policy, param.sched_priority))
        if refuse:
            raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(sched.os, "sched_setscheduler", fake)
    return calls


@pytest.mark.parametrize("argv, refuse, policy, priority, reason", [
    ((), False, "SCHED_FIFO", 10, "the default"),
    (("--realtime-priority", "40"), False, "SCHED_FIFO", 40, "asked"),
    ((), True, "ordinary", 0, "SCHED_FIFO refused ([Errno 1] Operation not permitted); needs root"),
    (("--no-realtime-priority",), False, "ordinary", 0, "turned off (--no-realtime-priority)"),
])
def test_the_loop_policy_is_chosen_printed_and_recorded(capsys, monkeypatch, tmp_path, argv, refuse, policy,
                                                        priority, reason):
    """By default the loop thread asks SCHED_FIFO priority 10 where the OS permits it; refused
    (an unprivileged user), it runs under the ordinary policy; --no-realtime-priority opts out.
    Each choice, and why, is printed and recorded in the session, and the loop thread gets it."""
    import os

    import arsurf.haptics.scheduler as sched

    calls = _fake_setscheduler(monkeypatch, refuse)
    given = []
    monkeypatch.setattr(sched, "_realtime_priority", lambda p: given.append(p) or 0)
    path = tmp_path / "s.h5"
    rc, out, err = _live(capsys, "--device", "virtual", "--seconds", "0.3", "--record", str(path), *argv)
    assert rc == 0, err
    rt = load_session(path).metadata["realtime"]
    assert rt["policy"] == policy and rt["priority"] == priority and rt["reason"].startswith(reason), rt
    assert f"arsurf live: loop thread under {'SCHED_FIFO priority' if priority else 'the ordinary policy'}" in err
    assert reason in err
    assert given == [priority]  # what the loop thread asks for
    asked = 0 if "--no-realtime-priority" in argv else (40 if "40" in argv else 10)
    assert calls == ([(os.SCHED_FIFO, asked)] if asked else [])  # the probe's one try


def test_a_device_that_answers_from_a_thread_keeps_the_ordinary_policy_by_default():
    """Haply and OpenHaptics answer from a thread of this process, which a real-time loop thread
    would starve on a busy core: no SCHED_FIFO unless asked."""
    from arsurf.cli.live import _DEVICE_THREADS
    from arsurf.haptics.scheduler import choose_realtime

    assert set(_DEVICE_THREADS) == {"haply", "openhaptics"}
    c = choose_realtime(None, device_thread=True)
    assert c.priority == 0 and "answers from a thread" in c.reason


@pytest.mark.parametrize("bad", ["100", "-1", "high"])
def test_a_bad_realtime_priority_is_one_line(capsys, bad):
    with pytest.raises(SystemExit) as e:
        main(["live", "--device", "virtual", "--seconds", "0.1", "--realtime-priority", bad])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert "argument --realtime-priority: must be an integer in [0, 99]" in err, err


def test_the_zone_sum_without_the_zone_energy_is_refused_in_one_line(capsys):
    rc, out, err = _live(capsys, "--device", "virtual", "--seconds", "0.1", "--zone-sum")
    assert rc == 2 and "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert "--zone-sum sums the zone energy's lattice everywhere: give --zone-energy too" in last
