"""Safe by default: every public way to build a loop for a device has the virtual coupling (its
stiffness chosen from the device's limits and the loop rate, :func:`arsurf.haptics.gains.coupling_stiffness`)
and the passivity controller; turning either off is explicit and lands in the session metadata.

The CLI paths (``arsurf live``, ``arsurf view --bridge-port``) are in tests/cli/test_live_cli.py and
tests/haptics/test_cpp_bridge.py."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from arsurf.assembly import BRIDGE_HAPTICS, BUNDLED_SCAN, PRESETS, build_loop, build_model, loop_metadata, make_model
from arsurf.assembly import preset_metadata
from arsurf.errors import ContactError, HapticsError, SessionError
from arsurf.haptics.coupling import DirectCoupling
from arsurf.haptics.device import TOUCH_X, DeviceInfo
from arsurf.haptics.gains import coupling_stiffness
from arsurf.haptics.loop import L_ENERGY, L_F_DEVICE, L_F_PROBE, L_NORMAL, L_PROBE, L_TIP, HapticLoop, LoopConfig
from arsurf.haptics.safety import SafetyLayer
from arsurf.haptics.scaling import ForceScaling, PositionScaling
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.scan.synthetic import rough
from arsurf.spline.fit import fit_surface
from arsurf.spline.surface import BSplineSurface
from arsurf.model import F_PERIOD, MODEL_ARGS

R, SCALE, GAIN = 20e-9, 1e-5, 1e5
#: a stiffer, better damped device than the virtual one: its coupling differs from the demo's 66.7 N/m
STIFF = DeviceInfo("stiff", 5.0, TOUCH_X.workspace, np.full(3, 3000.0), damping=np.full(3, 0.5))


def _model(surface=None):
    s = surface or BSplineSurface.from_heights(np.zeros((16, 16)), (0.0, 200e-9), (0.0, 200e-9))
    return make_model(s, tip_radius=R, effective_modulus=10e9, work_of_adhesion=0.1)


ORIGIN = (100e-9, 100e-9, R + 5e-9)


@pytest.mark.parametrize("info", [VirtualDevice().info, STIFF, TOUCH_X], ids=["virtual", "stiff", "touch"])
@pytest.mark.parametrize("rate", [500.0, 1000.0, 4000.0])
def test_hapticloop_direct_has_the_virtual_coupling_of_the_device_and_rate_and_passivity(info, rate):
    model = _model()
    loop = HapticLoop.direct(model, info, ORIGIN, scale=SCALE, force_gain=GAIN, config=LoopConfig(rate=rate))
    k_vc = coupling_stiffness(info, rate)
    assert loop.virtual_coupling == k_vc
    assert model.coupling_stiffness == k_vc / (GAIN * SCALE)   # at the probe's scale: k_vc / (K_f s)
    assert loop.config.passivity and loop.passivity.params[2] == 1.0  # the controller is on


def test_the_class_constructor_takes_the_coupling_from_device_info_or_an_explicit_no():
    model = _model()
    coupling = DirectCoupling(PositionScaling(SCALE, probe_origin=ORIGIN), ForceScaling(GAIN))
    loop = HapticLoop(model, coupling, SafetyLayer.for_device(STIFF, 1e-3), LoopConfig(), device_info=STIFF)
    assert loop.virtual_coupling == coupling_stiffness(STIFF, 1000.0)
    # no device to choose it from: refused, naming the two ways out
    with pytest.raises(HapticsError, match="device_info=.*virtual_coupling=False"):
        HapticLoop(_model(), coupling, SafetyLayer.for_device(STIFF, 1e-3), LoopConfig())
    off = HapticLoop(m := _model(), coupling, SafetyLayer.for_device(STIFF, 1e-3), LoopConfig(), virtual_coupling=False)
    assert off.virtual_coupling is None and m.coupling_stiffness == math.inf


def test_turning_the_coupling_off_is_explicit_and_a_model_with_its_own_keeps_it():
    model = _model()
    loop = HapticLoop.direct(model, STIFF, ORIGIN, virtual_coupling=False)
    assert loop.virtual_coupling is None and model.coupling_stiffness == math.inf
    own = make_model(BSplineSurface.from_heights(np.zeros((16, 16)), (0.0, 200e-9), (0.0, 200e-9)), tip_radius=R,
                     effective_modulus=10e9, work_of_adhesion=0.1, coupling_stiffness=3.0)
    HapticLoop.direct(own, STIFF, ORIGIN)
    assert own.coupling_stiffness == 3.0  # a recorded session's coupling is the one the replay rebuilds
    with pytest.raises(HapticsError, match="virtual_coupling=False but the model has"):
        HapticLoop.direct(own, STIFF, ORIGIN, virtual_coupling=False)
    with pytest.raises(HapticsError, match="True or False"):
        HapticLoop.direct(_model(), STIFF, ORIGIN, virtual_coupling="no")


def test_build_loop_and_the_bridge_settings_have_both_protections_and_record_them():
    model = _model()
    loop = build_loop(model, BRIDGE_HAPTICS, STIFF, ORIGIN)
    assert loop.virtual_coupling == coupling_stiffness(STIFF, BRIDGE_HAPTICS["rate"]) and loop.config.passivity
    h = loop_metadata({"haptics": dict(BRIDGE_HAPTICS)}, loop)["haptics"]
    assert h["virtual_coupling"] is True and h["coupling_stiffness"] == loop.virtual_coupling and h["passivity"]
    off = build_loop(_model(), dict(BRIDGE_HAPTICS, virtual_coupling=False, passivity=False), STIFF, ORIGIN)
    assert off.virtual_coupling is None and not off.config.passivity
    h = loop_metadata({"haptics": dict(BRIDGE_HAPTICS, virtual_coupling=False, passivity=False)}, off)["haptics"]
    assert h["virtual_coupling"] is False and "coupling_stiffness" not in h and h["passivity"] is False
    with pytest.raises(SessionError, match="virtual_coupling must be true or false"):
        build_loop(_model(), dict(BRIDGE_HAPTICS, virtual_coupling="off"), STIFF, ORIGIN)


def test_the_loop_blends_the_tip_s_jumps_by_default_and_a_session_replays_its_own_setting():
    """The public loop gives its model the blend of the tip's jumps at its own tick
    (arsurf.contact.jump_blend); 0 turns it off, recorded; a session recorded before the blend
    existed (no ``jump_blend``) rendered its jumps in one tick and its model is rebuilt that way."""
    from arsurf.contact.jump_blend import BLEND_TIME

    model = _model()
    assert model.jump_blend == 0.0  # outside a loop: no tick period, the tip is the balance
    loop = build_loop(model, BRIDGE_HAPTICS, STIFF, ORIGIN)
    assert loop.config.jump_blend == BLEND_TIME and model.jump_blend == BLEND_TIME
    assert model.kernel_args()[MODEL_ARGS.index("friction")][F_PERIOD] == loop.dt
    meta = preset_metadata(BUNDLED_SCAN, "viewer", haptics=dict(BRIDGE_HAPTICS))
    setup = build_model(meta)
    assert loop_metadata(meta, build_loop(setup.model, setup.config.haptics, STIFF, ORIGIN))["haptics"]["jump_blend"] \
        == BLEND_TIME
    assert build_model(meta).model.jump_blend == BLEND_TIME
    legacy = dict(meta, haptics={k: v for k, v in meta["haptics"].items() if k != "jump_blend"})
    assert build_model(legacy).model.jump_blend == 0.0
    off = build_loop(_model(), dict(BRIDGE_HAPTICS, jump_blend=0.0), STIFF, ORIGIN)
    assert off.model.jump_blend == 0.0 and loop_metadata({"haptics": {}}, off)["haptics"]["jump_blend"] == 0.0
    with pytest.raises(HapticsError, match="jump_blend must be a time >= 0 s"):
        LoopConfig(jump_blend=-0.01).validate()
    with pytest.raises(HapticsError, match="jump_blend must be a time >= 0 s"):
        LoopConfig(jump_blend=True).validate()  # a switch is not a time (the session's key refuses it too)
    with pytest.raises(SessionError, match="haptics.jump_blend must be a finite number"):
        build_model(dict(meta, haptics=dict(meta["haptics"], jump_blend="15 ms")))
    with pytest.raises(ContactError, match="the jump blend time must be >= 0"):
        _model().set_jump_blend(math.nan, 1e-3)


def test_the_bridge_loop_of_arsurf_view_has_the_coupling_of_its_device():
    from arsurf.live import bridge_loop

    live = bridge_loop(model := _model(), port=0, key=bytes(range(32)))  # nothing opened here
    info = live.device.info
    assert live.loop.virtual_coupling == coupling_stiffness(info, 1000.0)
    assert model.coupling_stiffness == coupling_stiffness(info, 1000.0) / (GAIN * SCALE) and live.loop.config.passivity


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_runs_with_the_coupling_of_the_device_and_the_passivity_controller(name):
    """The direct presets' loops choose the coupling from the device they run on (not a stiffness
    fixed for the virtual device), and replay rebuilds it from what the session records; the
    force-position preset's coupling is itself a position coupling ([Bolopion]) and keeps the
    passivity controller on."""
    p = PRESETS[name]
    assert p.haptics.get("passivity", True) is True and p.haptics.get("virtual_coupling", True) is True
    meta = preset_metadata(BUNDLED_SCAN, name)
    setup = build_model(meta)
    if p.haptics["coupling"] != "direct":
        assert setup.model.coupling_stiffness == math.inf
        return
    origin = (50e-9, 50e-9, 60e-9)
    loop = build_loop(setup.model, setup.config.haptics, STIFF, origin)
    assert loop.virtual_coupling == coupling_stiffness(STIFF, p.haptics["rate"]) and loop.config.passivity
    rebuilt = build_model(loop_metadata(meta, loop)).model
    assert rebuilt.coupling_stiffness == setup.model.coupling_stiffness  # bit for bit: the replay's model


def _rough_run(seed, press, at, slide):
    """The default loop (HapticLoop.direct, nothing turned off) with the virtual device's hand
    pressing ``press`` into a rough generated surface at ``at`` (m), sliding ``slide`` (m of
    stylus) over 1 s, then holding still; returns the loop outputs of 4000 ticks, the model and E0."""
    scan = rough((48, 48), 4e-9, rms=2e-9, correlation_length=12e-9, seed=seed)
    surface = fit_surface(scan)
    model = _model(surface)
    x0, y0 = at
    z0 = float(surface.evaluate(x0, y0)[2]) + R + 3e-9
    depth = -(3e-9 + press) / SCALE
    times = np.array([0.0, 0.5, 1.5, 4.0])
    pts = np.array([[0, 0, 0], [0, 0, depth], [slide, 0.5 * slide, depth], [slide, 0.5 * slide, depth]])
    dev = VirtualDevice(dt=1e-3, hand=HandModel((times, pts))).open()
    loop = HapticLoop.direct(model, dev.info, (x0, y0, z0), scale=SCALE, force_gain=GAIN, ramp_time=0.05)
    outs = np.empty((4000, loop.out.size))
    for k in range(4000):
        s = dev.read_state()
        dev.command_force(loop.step(s, s.timestamp))
        outs[k] = loop.out
    return outs, model, float(loop.passivity.params[3])


# derandomized: a random draw can land on the known limit cycle at rest below (a valley narrower than
# the tip, issue 27 §1), kept as strict xfails; the fixed draws here must settle
@settings(max_examples=8, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**16), press=st.floats(4e-9, 12e-9), x=st.floats(60e-9, 130e-9),
       y=st.floats(60e-9, 130e-9))
def test_the_default_loop_pressing_a_rough_surface_settles_on_the_scaled_force(seed, press, x, y):
    """Pressing into a rough generated surface and holding: at rest the device force is K_f times
    the probe force within 1 %, the probe force's normal part balancing the coupling spring,
    P = k_c (tip - target) . n ([proxy]). (Passivity, E >= -E0: see the two known cases below.)"""
    outs, model, e0 = _rough_run(seed, press, (x, y), 0.0)
    last = outs[-1]
    f_probe = last[L_F_PROBE:L_F_PROBE + 3]
    assert f_probe[2] > 0.0  # pressed into the surface
    np.testing.assert_allclose(last[L_F_DEVICE:L_F_DEVICE + 3], GAIN * f_probe, rtol=0.01,
                               atol=0.01 * GAIN * np.linalg.norm(f_probe))
    n = last[L_NORMAL:L_NORMAL + 3]
    stretch = float((last[L_TIP:L_TIP + 3] - last[L_PROBE:L_PROBE + 3]) @ n)
    assert stretch > 0.0
    np.testing.assert_allclose(float(f_probe @ n), model.coupling_stiffness * stretch, rtol=0.01)


# were strict xfails on the single contact (#26, issue 27 §1): the observer fell to -2.3 to -2.5 E0 sliding and
# pressing on a rough scan, and with the hand still (press-limit-cycle, found by the settling property) the
# closest point hopped between two asperities every ~0.6 s, -3.7 E0 in 4 s. With every minimum in reach a
# contact of its own (arsurf.contact.multi_contact) the three stay at -0.58, -0.53 and -0.45 E0.
@pytest.mark.parametrize("seed, press, at, slide", [(7, 10e-9, (90e-9, 90e-9), 2e-3),
                                                    (74, 1.0875695603926861e-08, (1.192092896e-07, 1.254187866373914e-07),
                                                     0.0),
                                                    (371, 9.991941610472833e-09, (9.762259055650202e-08, 1.1592297160552779e-07),
                                                     0.0)], ids=["slide", "press", "press-limit-cycle"])
def test_the_default_loop_on_a_rough_surface_stays_above_minus_e0(seed, press, at, slide):
    outs, _, e0 = _rough_run(seed, press, at, slide)
    assert outs[:, L_ENERGY].min() >= -e0 * (1 + 1e-9)
