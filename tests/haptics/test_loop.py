"""The integrated haptic tick: deterministic, safe, the right force on the hand."""
import math

import numpy as np
import pytest

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import HapticsError
from arsurf.force.cantilever import Cantilever
from arsurf.haptics.device import DeviceState
from arsurf.haptics.loop import HapticLoop, LoopConfig
from arsurf.haptics.scheduler import Scheduler
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.model import ARModel
from arsurf.scan.synthetic import sinusoid
from arsurf.spline.fit import fit_surface

R = 20e-9
LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)


def _setup(source="simulated", noise=0.0, trajectory=None, max_force=7.9, seed=0, e_star=50e9):
    s = fit_surface(sinusoid((96, 96), 4e-9, 5e-9, 160e-9))
    model = ARModel(s, R, MaugisDugdale(R, e_star, 0.05), LEVER, friction=0.2)
    c = (190e-9, 190e-9)
    origin = (*c, s.evaluate(*c)[2] + R + 5e-9)
    if trajectory is None:  # press 10 nm down, slide 30 nm along x, lift
        trajectory = (np.array([0.0, 2.0, 6.0, 8.0, 10.0]),
                      np.array([[0, 0, 0], [0, 0, -1e-3], [3e-3, 0.5e-3, -1e-3], [3e-3, 0.5e-3, 0], [3e-3, 0.5e-3, 0]]))
    dev = VirtualDevice(dt=1e-3, hand=HandModel(trajectory), max_force=max_force).open()
    loop = HapticLoop.direct(model, dev.info, origin, config=LoopConfig(source=source, signal_noise=noise, seed=seed),
                             ramp_time=0.05)
    return s, model, dev, loop


def _run(dev, loop, n):
    rows = []
    for _ in range(n):
        st = dev.read_state()
        f = loop.step(st, st.timestamp)
        dev.command_force(f)
        rows.append(loop.out.copy())
    return np.array(rows)


def test_ten_thousand_ticks_deterministic_finite_and_saturated():
    a = _run(*_setup(noise=1e-8, seed=3)[2:], 10_000)
    b = _run(*_setup(noise=1e-8, seed=3)[2:], 10_000)
    assert np.array_equal(a, b, equal_nan=True)                    # bit-for-bit deterministic
    dev_force = a[:, 17:20]
    assert np.isfinite(dev_force).all()
    assert np.linalg.norm(dev_force, axis=1).max() <= 7.9 * (1 + 1e-12)
    probe_force = a[:, 8:11]
    assert probe_force[:, 2].max() > 1e-9                          # it did press into the sample


def test_probe_follows_the_scaled_master_and_the_hand_feels_the_scaled_force():
    s, model, dev, loop = _setup()
    masters, outs = [], []
    for _ in range(4000):
        st = dev.read_state()
        masters.append(st.position.copy())
        dev.command_force(loop.step(st, st.timestamp))
        outs.append(loop.out.copy())
    masters, out = np.array(masters), np.array(outs)
    origin = out[0, 0:3] - 1e-5 * masters[0]
    np.testing.assert_allclose(out[:, 0:3], origin + 1e-5 * masters, rtol=0, atol=1e-18)  # probe = p0 + s x
    in_contact = out[:, 8 + 2] > 0
    assert in_contact.any()
    k = np.flatnonzero(in_contact)[-1]
    np.testing.assert_allclose(out[k, 14:17], 1e5 * out[k, 11:14], rtol=1e-12)  # hand = K_f x filtered


def test_the_filter_delays_the_measured_part_only_never_the_contact_s_force():
    """With the simulated source there is no measured part: the filtered force is the probe force
    on every tick, its direction included, while the contact normal turns as the tip slides over
    the sinusoid. (The force once turned with a 50 Hz low-passed normal; a lagging direction is an
    active element: pressed into a valley narrower than the tip the hand swung across it at ~10 Hz
    and gained 5-9 times the passive store, docs/feel-log.rst.)"""
    from arsurf.haptics.loop import LOOP_OUT

    s, model, dev, loop = _setup()
    assert loop.config.filter_cutoff == 50.0                                # the filter is on
    out = _run(dev, loop, 8000)
    probe, filtered = out[:, LOOP_OUT.slice("probe_force")], out[:, LOOP_OUT.slice("filtered_force")]
    normal = out[:, LOOP_OUT.slice("normal")]
    touching = np.linalg.norm(normal, axis=1) > 0.5
    turn = np.arccos(np.clip(normal[touching] @ normal[touching][0], -1.0, 1.0))
    assert turn.max() > 0.1                                                 # the normal turned by > 0.1 rad
    np.testing.assert_array_equal(filtered, probe)


def test_measured_source_recovers_the_simulated_force_without_noise():
    from arsurf.model import M_DECOUPLE_STATUS, M_SIM_FX

    # press 10 nm, then slide 30 nm in 1 s (30 nm/s: sliding, above the friction velocity)
    slide = (np.array([0.0, 2.0, 3.0, 10.0]),
             np.array([[0, 0, 0], [0, 0, -1e-3], [3e-3, 0.5e-3, -1e-3], [3e-3, 0.5e-3, -1e-3]]))
    _, model, dev, loop = _setup(source="measured", trajectory=slide)
    rows = []
    for _ in range(5000):
        st = dev.read_state()
        dev.command_force(loop.step(st, st.timestamp))
        rows.append((model.out[M_SIM_FX:M_SIM_FX + 3].copy(), loop.out[8:11].copy(), model.out[M_DECOUPLE_STATUS]))
    sim = np.array([r[0] for r in rows])
    used = np.array([r[1] for r in rows])
    ok = (np.array([r[2] for r in rows]) == 0) & (sim[:, 2] > 1e-10)
    assert ok.sum() > 100  # sliding in contact, well-conditioned decoupling
    # the force decoupled from the synthesised angles is the simulated force (round trip)
    np.testing.assert_allclose(used[ok], sim[ok], rtol=1e-9, atol=1e-18)


def test_nan_stylus_never_reaches_the_device():
    _, _, dev, loop = _setup()
    _run(dev, loop, 200)
    bad = DeviceState(position=np.array([np.nan, 0.0, 0.0]), velocity=np.zeros(3), buttons=0, timestamp=0.201)
    f = loop.step(bad, 0.201)
    assert np.isfinite(f).all() and np.linalg.norm(f) <= 7.9


def test_warm_up_compiles_on_a_copy_and_leaves_the_loop_untouched():
    s, model, dev, loop = _setup()
    _run(dev, loop, 3000)                                          # pressed: a dent, filter and ramp state
    ctrl, state, out = model.surface.control_points.copy(), model.state.copy(), loop.out.copy()
    assert loop.warm_up() is loop
    assert np.array_equal(model.surface.control_points, ctrl) and np.array_equal(model.state, state, equal_nan=True)
    assert np.array_equal(loop.out, out, equal_nan=True)
    b = _setup()
    cont, ref = _run(dev, loop, 1000), (_run(*b[2:], 3000), _run(*b[2:], 1000))[1]
    assert np.array_equal(cont, ref, equal_nan=True)               # the run goes on as if never warmed


def test_a_copied_loop_is_its_own_and_ticks_as_the_original():
    """The compiled tick reads the loop's arrays through one struct (LoopArrays): a copy must get
    a struct of its own arrays (not the original's), and a device-force view of its own output."""
    import copy

    s, model, dev, loop = _setup(noise=1e-8, seed=5)
    _run(dev, loop, 1500)                                          # in contact, dent, filters, noise drawn
    twin, dev2 = copy.deepcopy(loop), copy.deepcopy(dev)
    a, b = _run(dev, loop, 800), _run(dev2, twin, 800)
    assert np.array_equal(a, b, equal_nan=True)                    # bit-identical continuation
    assert twin._packed is not loop._packed and np.shares_memory(twin._device_force, twin.out)
    assert not np.shares_memory(twin.out, loop.out) and not np.shares_memory(twin.model.state, loop.model.state)
    before = loop.out.copy()
    st = dev2.read_state()
    twin.step(st, st.timestamp)
    assert np.array_equal(loop.out, before, equal_nan=True)        # stepping the copy leaves the original


def test_runs_under_the_scheduler_without_sleeping():
    _, _, dev, loop = _setup()
    sched = Scheduler(loop.scheduler_step, loop, rate=1000.0, source=dev.read_state, sink=dev.command_force)
    sched.run_ticks(2000)
    assert sched.ticks == 2000 and math.isclose(dev.read_state().timestamp, 2.0)


def test_bad_settings():
    with pytest.raises(HapticsError, match="source must be one of"):
        LoopConfig(source="telepathy").validate()
    with pytest.raises(HapticsError, match="rate must be"):
        LoopConfig(rate=0.0).validate()
    s, model, dev, loop = _setup()
    from arsurf.haptics.safety import SafetyLayer

    with pytest.raises(HapticsError, match="same rate"):
        HapticLoop(model, loop.coupling, SafetyLayer(7.9, 1e-4), LoopConfig(rate=1000.0))


def test_a_contact_beyond_the_law_is_flagged_in_the_recorded_word():
    """#30: the model's BEYOND_MODEL (a > 0.4 R) reaches the tick's flag word, which sessions record
    (``safety_flags``), exactly on the ticks whose contact is that wide."""
    from arsurf.contact.mechanics import SMALL_CONTACT_LIMIT
    from arsurf.haptics.loop import L_SAFETY_FLAGS
    from arsurf.model import M_RADIUS
    from arsurf.status import BEYOND_MODEL

    press = (np.array([0.0, 2.0, 4.0]), np.array([[0, 0, 0], [0, 0, -4e-3], [0, 0, 0]]))  # 40 nm down and up
    _, model, dev, loop = _setup(trajectory=press, e_star=2e9)  # a polymer: the hand sinks in
    wide, flagged = [], []
    for _ in range(4000):
        st = dev.read_state()
        dev.command_force(loop.step(st, st.timestamp))
        wide.append(model.out[M_RADIUS] > SMALL_CONTACT_LIMIT * R)
        flagged.append(bool(int(loop.out[L_SAFETY_FLAGS]) & BEYOND_MODEL))
    assert any(wide) and not all(wide) and flagged == wide


def test_the_one_call_tick_is_the_checked_python_tick_bit_for_bit():
    """A well-formed sample ticks in one compiled call (sample check, sample, tick:
    loop_sample_tick_kernel through its entry point); a sample given as strided views takes the
    Python path (check, copies, tick). Fed the same samples - a slide with noise, a NaN, a jump
    no stylus makes and a stamp going backwards among them - the two give the same output every
    tick, bit for bit."""
    _, _, dev, loop = _setup(source="blended", noise=1e-8, seed=5)
    twin = _setup(source="blended", noise=1e-8, seed=5)[3]
    for k in range(1500):
        st = dev.read_state()
        p, v, t = st.position.copy(), st.velocity.copy(), st.timestamp
        if k == 700:
            p[1] = np.nan
        elif k == 900:
            p[0] += 0.5                                                 # 0.5 m in one tick
        elif k == 1100:
            t -= 0.01                                                   # stamped in the past
        f = loop.step(DeviceState(p, v, st.buttons, t), st.timestamp)
        ps, vs = np.empty(6)[::2], np.empty(6)[::2]
        ps[:], vs[:] = p, v
        twin.step(DeviceState(ps, vs, st.buttons, t), st.timestamp)
        assert np.array_equal(loop.out, twin.out, equal_nan=True), k
        dev.command_force(f)
    assert loop._fused is not None and twin._fused is None              # each took its own path
    assert loop.out[8:11].any()                                         # it touched


def test_the_one_call_tick_takes_any_input_the_checked_tick_takes_bit_for_bit():
    """The one-call tick's type tests send every input they do not pass to the checked tick:
    numpy float stamps and clocks (passed as they are), a button word that is not one (flagged,
    no press), measured signals on some ticks and not on the next (cleared), a sample of int64
    arrays. Fed to a loop whose samples are strided views (the Python path throughout), the
    outputs agree every tick, bit for bit, and the well-formed ticks ran in the compiled call."""
    from arsurf.haptics.loop import L_SAFETY_FLAGS
    from arsurf.status import BAD_BUTTONS

    _, _, dev, loop = _setup(source="blended", noise=1e-8, seed=11)
    twin = _setup(source="blended", noise=1e-8, seed=11)[3]
    checked, step_checked = [], loop._step_checked
    loop._step_checked = lambda *args: checked.append(args[0].timestamp) or step_checked(*args)
    for k in range(1200):
        st = dev.read_state()
        p, v, t, now, buttons, signals = st.position.copy(), st.velocity.copy(), st.timestamp, st.timestamp, st.buttons, None
        if k % 7 == 3:
            t, now = np.float64(t), np.float64(now)
        if k in (300, 301, 640):
            buttons = -1 if k != 640 else 2 ** 64                       # not a button word
        if 500 <= k < 520 or k == 800:
            signals = (1e-4 * math.sin(k), -2e-5)                       # measured angles on these ticks
        sample = DeviceState(p.astype(np.int64) if k == 900 else p, v, buttons, t)
        f = loop.step(sample, now, signals)
        ps, vs = np.empty(6)[::2], np.empty(6)[::2]
        ps[:], vs[:] = p, v
        twin.step(sample if k == 900 else DeviceState(ps, vs, buttons, t), now, signals)  # 900: both refuse it
        assert np.array_equal(loop.out, twin.out, equal_nan=True), k
        if k in (300, 640):
            assert int(loop.out[L_SAFETY_FLAGS]) & BAD_BUTTONS
        dev.command_force(f)
    assert twin._fused is None and loop._fused is not None
    assert len(checked) == 5                                            # the first tick, 300, 301, 640, 900


def test_the_compiled_tick_reads_the_loops_struct_without_leaving_a_reference():
    """The loop's kernels are compiled without reference counts and read the fields of the loop's
    struct borrowed (arsurf._structs): through both paths (the one-call tick and the checked
    one) the struct keeps its own reference count, and NRT gives back every block and reference
    a step takes - 300 steps take exactly 300 times what one does (the sample's two arrays)."""
    from numba.core.runtime import _nrt_python, rtsys

    def stats():
        s = rtsys.get_allocation_stats()
        return np.array([s.alloc, s.free, s.mi_alloc, s.mi_free])

    _, _, dev, loop = _setup(source="blended", noise=1e-8, seed=2)

    def checked_step():  # a strided position takes the checked path
        st = dev.read_state()
        strided = np.empty(6)[::2]
        strided[:] = st.position
        loop.step(DeviceState(strided, st.velocity.copy(), st.buttons, st.timestamp), st.timestamp)

    _run(dev, loop, 5)  # both paths compiled, the entry point found
    checked_step()
    refs = loop._packed._meminfo.refcount
    enabled = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        s0 = stats()
        _run(dev, loop, 1)
        s1 = stats()
        _run(dev, loop, 300)
        s2 = stats()
        checked_step()
        s3 = stats()
    finally:
        if not enabled:
            _nrt_python.memsys_disable_stats()
    one, many = s1 - s0, s2 - s1
    np.testing.assert_array_equal(many, 300 * one)
    assert many[0] == many[1] and many[2] == many[3]
    assert (s3 - s2)[0] == (s3 - s2)[1] and (s3 - s2)[2] == (s3 - s2)[3]
    assert loop._packed._meminfo.refcount == refs
    assert loop.out[8:11].any()                                         # it touched
