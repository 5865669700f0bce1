"""The instrument interface on the virtual AFM, the live link, and a session driven by a (simulated)
Nanonis controller: recorded with the measured signals, replayed exactly, and failing safe when the
link stalls or dies."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from arsurf.assembly import build_model, preset_metadata
from arsurf.errors import InstrumentError, InstrumentLinkLost, SessionError
from arsurf.force.cantilever import Cantilever
from arsurf.force.photodiode import Photodiode
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.instrument.instrument import PhotodiodeNoise, VirtualAFM
from arsurf.instrument.interface import InstrumentFrame, InstrumentLimits, InstrumentSample
from arsurf.instrument.link import InstrumentLink
from arsurf.instrument.nanonis import NanonisAFM
from arsurf.instrument.nanonis_sim import NanonisSimulator
from arsurf.sessions.instrument_session import record_instrument_session
from arsurf.replay.replay import load_replay, replay
from arsurf.sessions.reader import load_session
from arsurf.scan import synthetic
from arsurf.scan.io import save_scan

pytestmark = pytest.mark.timeout(300)
QUIET = PhotodiodeNoise(peak_to_peak=1e-4)
S_N = 20e-9  # m of deflection per signal unit of the virtual lever


# ---------------------------------------------------------------------------------------------
# the virtual AFM through the Instrument interface


def _scan():
    return synthetic.sinusoid(shape=(32, 32), pixel=10e-9, amplitude=2e-9, period=200e-9, angle=0.3)


def test_virtual_afm_reads_moves_and_refuses_targets_outside_its_limits():
    afm = VirtualAFM(0.0, probe_height=0.5e-6, tip_xy=(1e-6, 1e-6), noise=QUIET).open()
    s = afm.read()
    assert s.position.tolist() == [1e-6, 1e-6, 0.5e-6] and s.timestamp == afm.time
    afm.move_to((2e-6, 1.5e-6, 0.1e-6))
    s = afm.read(s)
    assert s.position == pytest.approx([2e-6, 1.5e-6, 0.1e-6], abs=1e-12)
    lim = afm.limits
    assert lim.high[0] == 100e-6 and lim.high[2] == pytest.approx(0.5e-6) and lim.low[2] == pytest.approx(-4.5e-6)
    with pytest.raises(InstrumentError, match=r"target z = -5e-06 m is outside the instrument's limits"):
        afm.move_to((math.nan, math.nan, -5e-6))
    with pytest.raises(InstrumentError, match="must be x, y, z in metres"):
        afm.move_to("here")
    with pytest.raises(InstrumentError, match="must be finite or NaN"):
        afm.move_to((math.inf, 0.0, 0.0))
    with pytest.raises(InstrumentError, match="not open"):
        VirtualAFM(0.0, probe_height=1e-6).read()


def test_feedback_follows_the_topography_at_constant_deflection():
    """Over a sinusoid the ideal Z feedback keeps the deflection at the set point while z tracks
    the surface: the tip's z minus the surface is the same everywhere."""
    scan = _scan()
    afm = VirtualAFM(scan, probe_height=0.1e-6, tip_xy=(50e-9, 150e-9), noise=QUIET, deflection_sensitivity=S_N)
    afm.open()
    afm.engage()
    assert afm.feedback
    gaps, signals = [], []
    for x in np.linspace(60e-9, 250e-9, 12):
        afm.move_to((x, 150e-9, math.nan))
        s = afm.read()
        gaps.append(s.position[2] - afm.surface_height)
        signals.append(s.signals[0])
    h = afm.history()
    assert np.ptp(afm._heights(h.x[-200:], h.y[-200:])) > 1e-9  # the path crossed the corrugation
    assert np.allclose(gaps, -afm.setpoint * S_N, atol=1e-11)   # pressed in by the set-point deflection
    assert np.allclose(signals, afm.setpoint, atol=1e-3)


def test_friction_twists_the_lever_against_the_motion():
    afm = VirtualAFM(0.0, probe_height=0.2e-6, tip_xy=(1e-6, 1e-6), noise=QUIET, friction=0.5,
                     deflection_sensitivity=S_N, lateral_sensitivity=10e-9).open()
    afm.move_to((math.nan, math.nan, -10e-9))  # pressed 10 nm in: F = k * 10 nm = 3 nN
    afm.move_to((1e-6, 1.2e-6, math.nan))      # slide along +y: friction along -y
    h = afm.history()
    sliding = h.lateral[-5:]
    f = afm.spring_constant * 10e-9
    assert sliding == pytest.approx(-0.5 * f / 10e-9, abs=1e-3)  # -0.15
    afm.move_to((1e-6, 1.0e-6, math.nan))      # back along -y: the twist changes sign
    assert afm.history().lateral[-5:] == pytest.approx(0.5 * f / 10e-9, abs=1e-3)
    assert abs(afm.read().signals[1]) < 1e-3    # at rest: no lateral force


def test_withdraw_leaves_a_gap_after_the_engage():
    afm = VirtualAFM(0.0, probe_height=0.45e-6, seed=3).open()
    afm.engage()
    assert afm.gap() < 0.0
    afm.withdraw()
    assert not afm.feedback and afm.gap() >= 0.1e-6  # one coarse step, on the micro stage's 0.05 um grid


def test_limits_and_frame_validate_their_input():
    with pytest.raises(InstrumentError, match="low < high"):
        InstrumentLimits((0, 0, 0), (1e-6, 0, 1e-6), 1e-6)
    with pytest.raises(InstrumentError, match="max_speed must be positive"):
        InstrumentLimits((0, 0, 0), (1e-6, 1e-6, 1e-6), 0.0)
    with pytest.raises(InstrumentError, match=r"signs must be \+1 or -1"):
        InstrumentFrame(signs=(1, 0.5, 1))
    f = InstrumentFrame(origin=(1e-6, 2e-6, -20e-9), signs=(-1, 1, 1))
    p = np.array([3e-7, 4e-7, 5e-8])
    assert f.to_scan(f.to_instrument(p)) == pytest.approx(p, abs=1e-20)


# ---------------------------------------------------------------------------------------------
# the live link


def test_link_clips_commands_to_the_limits_and_limits_the_speed():
    afm = VirtualAFM(0.0, probe_height=0.5e-6, tip_xy=(1e-6, 1e-6), noise=QUIET, keep_history=False)
    with InstrumentLink(afm, rate=1000.0, axes="xyz") as link:
        first = link.wait_first()
        link.command(np.array([-5e-6, 1e-6, 0.4e-6]))  # x below 0: clipped
        time.sleep(0.05)
        link.command(np.array([1e-6 + 1e-6, 1e-6, 0.4e-6]))  # 1 um in one go: 100 um/s allows ~0.1 um/ms
        deadline = time.perf_counter() + 20.0
        s = InstrumentSample()
        while time.perf_counter() < deadline:
            link.latest(s)
            if abs(s.position[0] - 2e-6) < 1e-12:
                break
            time.sleep(1e-3)
    assert first.position[0] == 1e-6 and link.error is None
    assert link.clamped == 1 and link.rate_limited > 0
    assert s.position == pytest.approx([2e-6, 1e-6, 0.4e-6], abs=1e-12)
    # the history of moves: no step longer than max_speed x one period (0.1 um) plus the grid
    assert link.moves > 5


def test_link_refuses_z_with_the_feedback_on_and_reports_thread_errors():
    afm = VirtualAFM(0.0, probe_height=0.45e-6, seed=3, keep_history=False).open()
    afm.engage()
    with pytest.raises(InstrumentError, match="axes='xy'"):
        InstrumentLink(afm, axes="xyz").start()

    class Broken(VirtualAFM):
        def _read(self, out):
            raise InstrumentLinkLost("the cable is out")

    link = InstrumentLink(Broken(0.0, probe_height=1e-6), axes="xy").start()
    with pytest.raises(InstrumentLinkLost, match="the cable is out"):
        link.wait_first(timeout=5.0)
    link.stop()
    assert link.error == "the cable is out"


# ---------------------------------------------------------------------------------------------
# a session driven by the simulated Nanonis controller


class _LoggedDevice(VirtualDevice):
    """A virtual device that remembers every force it was commanded (and from which thread)."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.log: list[np.ndarray] = []
        self.at_tick = None  # (k, callable): called when the k-th force is commanded

    def _apply_force(self, force):
        self.log.append(force.copy())
        if self.at_tick is not None and len(self.log) == self.at_tick[0]:
            self.at_tick[1]()
        super()._apply_force(force)


X0, Y0 = 150e-9, 150e-9


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    d = tmp_path_factory.mktemp("instrument-session")
    scan_path = save_scan(_scan(), d / "scan.npz")
    haptics = {"coupling": "direct", "scale": 1e-5, "force_gain": 1e5, "rate": 1000.0, "source": "measured",
               "filter_cutoff": 200.0, "signal_noise": 0.0, "passivity": True}
    meta = preset_metadata(scan_path, "demo", haptics=haptics)
    setup = build_model(meta)
    lever = Cantilever(**{k: v for k, v in meta["cantilever"].items() if v is not None})
    zs = float(setup.surface.evaluate(X0, Y0)[2])
    return d, scan_path, meta, setup, lever, zs


def _afm(setup, lever, zs):
    afm = VirtualAFM(setup.scan, probe_height=zs + 2e-6, tip_xy=(X0, Y0), spring_constant=lever.normal_stiffness,
                     deflection_sensitivity=S_N, noise=QUIET)
    afm.open()
    afm.move_to((X0, Y0, zs + 8e-9))  # hover 8 nm above the surface, where the stylus origin maps
    return afm


def _device():
    """Hover, press 12 nm in, slide 80 nm along x, lift (device frame, 1 mm -> 10 nm)."""
    times = np.array([0.0, 0.2, 0.7, 1.1, 1.4, 10.0])
    pts = np.array([[0, 0, 0], [0, 0, 0], [0, 0, -2.0e-3], [0.8e-2, 0, -2.0e-3], [0.8e-2, 0, 0], [0.8e-2, 0, 0]])
    return _LoggedDevice(dt=1e-3, hand=HandModel((times, pts)))


def _record(bench, path, afm, faults=None, ticks=1600, max_age=None, **kw):
    d, scan_path, meta, setup, lever, zs = bench
    pd = Photodiode.from_deflection_sensitivity(S_N, lever.length)
    dev = _device()
    R = meta["tip_radius"]
    with NanonisSimulator(afm) as sim:
        if faults is not None:  # (tick, fault(sim)): the controller goes wrong in the middle of the session
            dev.at_tick = (faults[0], lambda: faults[1](sim))
        limits = InstrumentLimits((0.0, 0.0, -1e-6), (300e-9, 300e-9, 3e-6), 100e-6)
        inst = NanonisAFM(*sim.address, limits=limits, timeout=0.25)
        try:
            result = record_instrument_session(d / path, meta, dev, inst, photodiode=pd, ticks=ticks,
                                               probe_origin=(X0, Y0, zs + R + 8e-9), ramp_time=0.1,
                                               max_age=max_age, **kw)
        except InstrumentLinkLost as exc:
            result = exc
    return result, dev, pd


@pytest.mark.slow
def test_a_session_through_the_simulated_nanonis_records_and_replays_the_measured_signals(bench):
    d, scan_path, meta, setup, lever, zs = bench
    afm = _afm(setup, lever, zs)
    result, dev, pd = _record(bench, "session.h5", afm)
    assert not isinstance(result, Exception), result
    s = load_session(result.path)
    t = s.ticks
    assert s.complete and s.n_ticks == result.ticks >= 1600
    assert s.metadata["instrument"]["signals"] == ["X (m)", "Y (m)", "Z (m)", "Input 1 (V)", "Input 2 (V)"]
    assert s.metadata["calibration"]["vertical_sensitivity"] == pd.vertical_sensitivity
    # the device's limits, which the reader bounds the recorded stylus and device force by
    assert s.metadata["device"]["workspace"] == dev.info.workspace.tolist()
    assert s.metadata["device"]["max_force"] == dev.info.max_force
    assert np.all(np.isfinite(t["signals"])) and result.instrument_samples > 50
    # the signals are the instrument's: the bending angle reads the true deflection of the virtual
    # lever, F = k delta (classical reading alpha / g; float32 on the wire, noise 1e-4 units)
    hist = afm.history()
    f_read = t["signals"][:, 0] / lever.bending_compliance
    true_peak = hist.force.max()
    assert true_peak > 1e-9
    assert f_read.max() == pytest.approx(true_peak, rel=0.02, abs=5e-12)
    # and the loop rendered them: the measured force pushes the hand up while pressing
    pressing = t["in_contact"] == 1
    assert pressing.sum() > 200 and np.median(t["force"][pressing, 2]) > 0.0
    # where the instrument measured the tip follows the commanded probe (scan frame)
    lag = np.abs(t["instrument_position"] - t["probe_position"])
    assert np.nanmedian(lag[:, 2]) < 2e-9
    # replay: the model re-run with the recorded probe and signals gives back the recorded
    # contact and measured force exactly
    r = replay(result.path, scan_path, d / "replay", overwrite=True, progress=False)
    assert r.n_ticks == s.n_ticks and r.contact_mismatches == 0 and r.load_difference == 0.0
    rep = load_replay(d / "replay" / "replay.h5").ticks
    np.testing.assert_array_equal(rep["measured_force"], t["force"])
    np.testing.assert_array_equal(rep["depth"], t["depth"])


@pytest.mark.parametrize("fault, match", [
    (lambda sim: setattr(sim.faults, "stall_after", 0), r"instrument link (stalled: the newest sample from "
                                                        r"Nanonis at .* ms old \(limit \d+ ms\)|lost: .*stalled)"),
    (lambda sim: setattr(sim.faults, "close_after", 0), "instrument link lost: Nanonis at .* closed the connection"),
    (lambda sim: sim.faults.errors.update({"FolMe.XYPosSet": "Follow Me is busy"}),
     "instrument link lost: the Nanonis controller refused FolMe.XYPosSet: Follow Me is busy"),
])
def test_a_link_that_stalls_or_dies_leaves_the_hand_at_zero_force_and_the_tip_where_it_is(bench, fault, match):
    d, scan_path, meta, setup, lever, zs = bench
    afm = _afm(setup, lever, zs)
    moved = []
    original = afm._move
    afm._move = lambda *a: (moved.append(afm.time), original(*a))  # when the server moved the tip
    result, dev, pd = _record(bench, "failed.h5", afm, faults=(600, fault), ticks=100_000)
    assert isinstance(result, InstrumentLinkLost)
    msg = str(result)
    assert "\n" not in msg
    import re
    assert re.search(match, msg), msg
    assert "the hand got zero force and the tip was left at (" in msg and "marked incomplete" in msg
    # zero force at once: the last force the device was given is zero, and the device is closed
    assert np.all(dev.log[-1] == 0.0) and not dev.is_open
    # the tip is where it was left: nothing moved it after the failure (the server got no move)
    n_moves = len(moved)
    tip = afm.tip_xy.copy(), afm.tip_z()
    time.sleep(0.1)
    assert len(moved) == n_moves and afm.tip_xy.tolist() == tip[0].tolist() and afm.tip_z() == tip[1]
    # the recording is kept: every tick up to the failure, marked incomplete with the reason
    s = load_session(d / "failed.h5", allow_incomplete=True)
    assert not s.complete and s.n_ticks > 10 and "the hand got zero force" in s.attrs["aborted"]


def test_a_session_needs_the_measured_source(bench):
    d, scan_path, meta, setup, lever, zs = bench
    wrong = dict(meta, haptics=dict(meta["haptics"], source="simulated"))
    with pytest.raises(SessionError, match="haptics source must be 'measured' or 'blended'"):
        record_instrument_session(d / "x.h5", wrong, _device(), _afm(setup, lever, zs),
                                  photodiode=Photodiode(1.0, 1.0), seconds=1.0, probe_origin=(X0, Y0, zs))
