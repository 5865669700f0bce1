r"""The haptic rendering loop: one deterministic, compiled tick from stylus to device force.

``step`` ([Alabdulmuhsin] and [Bolopion]; docs/design.rst, "The pipeline") runs, in one compiled call:

1. **position**: master position -> probe (tip centre) position, per-axis scale and clutch
   (:func:`arsurf.haptics.scaling.position_map_step`), or the slave position of the
   force-position coupling;
2. **model**: collision, Maugis-Dugdale, dent, simulated force (:func:`arsurf.model.model_tick_kernel`);
3. **force on the probe**: ``"simulated"`` (MD load along n + friction), ``"measured"`` (decoupled
   from the two angles: given by an AFM / a session, or synthesised by the model from the
   simulated force through the cantilever model plus photodiode noise; out of contact the
   classical reading, see :func:`arsurf.model.model_tick_kernel`) or ``"blended"``
   :math:`F = w F_{meas} + (1 - w) F_{sim}` ([SplineAR]'s augmented reality);
4. **filter**: first-order low-pass, exact ZOH discretisation (:mod:`arsurf.haptics.filters`), of
   the measured part of the force only, :math:`F_m = w (F_{meas} - F_{sim})` (photodiode noise):
   :math:`F_f = (F - F_m) + \mathrm{LP}(F_m)`. The contact's force is never delayed, neither its
   magnitude nor its direction: a lagging spring returns more energy than it took (a 200 Hz
   low-pass on the whole force gave the hand ~35 nJ per 2 Hz tap), and so does a lagging
   direction - the force once turned with a 50 Hz low-passed contact normal, and a tip pressed
   into a valley narrower than itself, whose walls turn the normal within a fraction of a
   nanometre, swung across it at ~10 Hz and gave the hand 5-9 times the passive store (docs/feel-log.rst).
   A closest point that jumps is the model's to smooth, not the loop's
   (:mod:`arsurf.contact.zone_normal`);
5. **coupling**: direct, :math:`F_h = K_f \odot F` ([Alabdulmuhsin] Eq. 9-10), or force-position with the
   PI controller :math:`C(s) = B_{fp} + K_{fp}/s` and P slave controller ([Bolopion]);
6. **safety**: saturation, ramp, rate limit, watchdog, disengage (:mod:`arsurf.haptics.safety`).

With a scene of nano-objects (``HapticLoop(..., scene=TubeScene)``, :mod:`arsurf.manipulation.scene`)
the scene is stepped between 3 and 4 - the tip's move pushes the objects, their resistance joins
the probe force before the filter - as three compiled calls (steps 1-3, the scene, steps 4-6):
the haptics layer cannot import the manipulation models into its kernel.

:meth:`HapticLoop.step` is pure given its state (no clock, no sleeping, no I/O): tests run it
10⁴ times in a row; :class:`~arsurf.haptics.scheduler.Scheduler` runs it in real time.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, typeof, types
from numba.experimental import structref

from arsurf import _structs
from arsurf._layout import Layout
from arsurf.contact.jump_blend import BLEND_TIME
from arsurf.status import BAD_BUTTONS
from arsurf.errors import HapticsError
from arsurf.haptics.coupling import FP_PARAMS, FP_STATE, DirectCoupling, ForcePositionCoupling, fp_step
from arsurf.haptics.device import DeviceState
from arsurf.haptics.filters import LowPass, lowpass1_step
from arsurf.haptics.gains import coupling_stiffness
from arsurf.haptics.passivity import S_ALPHA, S_ENERGY, PassivityController, passivity_applied, passivity_observe_control
from arsurf.haptics.safety import _P_DT as _SAFETY_P_DT
from arsurf.haptics.safety import SafetyLayer, safety_step
from arsurf.haptics.samples import SAMPLE_FAULTS, SAMPLE_STATE, SampleCheck, sample_check_step
from arsurf.haptics.scaling import POSITION_PARAMS, POSITION_STATE, force_scale_step, position_map_step
from arsurf.model import (M_BENDING, M_MEAS_FX, M_MODEL_FLAGS, M_NX, M_SIM_FX, M_TIP, M_TORSION, MODEL_ARGS,
                          SIGNALS_GIVEN, SIGNALS_NONE, SIGNALS_SYNTHESISED, ARModel, model_tick_kernel)

SOURCES = {"simulated": 0, "measured": 1, "blended": 2}
_BUTTONS_LIMIT = 1 << 31  # a button word is a small non-negative bit mask


def _valid_buttons(buttons) -> tuple[int, bool]:
    """(button word, malformed) from what a device reported: an integer in [0, 2^31) (numpy
    integers and bools included) as it is, anything else (NaN, None, 2**64, negative, text) as
    no press, flagged malformed."""
    if isinstance(buttons, (int, np.integer)) and 0 <= buttons < _BUTTONS_LIMIT:
        return int(buttons), False
    return 0, True
COUPLINGS = {"direct": 0, "force-position": 1}

#: the loop output vector (``HapticLoop.out``): m, m/s, rad, N; flags and status as floats
LOOP_OUT = Layout("loop output", [
    ("probe", 3), ("probe_velocity", 3), ("signals", 2), ("probe_force", 3), ("filtered_force", 3),
    ("hand_force", 3), ("device_force", 3), ("safety_flags", 1), ("coupling_flags", 1), ("collide_status", 1),
    ("tip", 3), ("energy", 1), ("passivity_damping", 1), ("measured_part", 3), ("normal", 3)])
# the offsets as the kernels use them
L_PROBE, L_PROBE_V, L_SIGNALS = LOOP_OUT.offset("probe"), LOOP_OUT.offset("probe_velocity"), LOOP_OUT.offset("signals")
L_F_PROBE, L_F_FILT = LOOP_OUT.offset("probe_force"), LOOP_OUT.offset("filtered_force")
L_F_HAND, L_F_DEVICE = LOOP_OUT.offset("hand_force"), LOOP_OUT.offset("device_force")
L_SAFETY_FLAGS, L_COUPLING_FLAGS = LOOP_OUT.offset("safety_flags"), LOOP_OUT.offset("coupling_flags")
L_COLLIDE_STATUS = LOOP_OUT.offset("collide_status")
L_TIP, L_ENERGY, L_PC_DAMPING = LOOP_OUT.offset("tip"), LOOP_OUT.offset("energy"), LOOP_OUT.offset("passivity_damping")
L_MEAS_PART, L_NORMAL = LOOP_OUT.offset("measured_part"), LOOP_OUT.offset("normal")
L_SIZE = LOOP_OUT.size
#: the filter's channels (step 4): the measured part of the probe force
FILTER_CHANNELS = Layout("loop filter channels", [("measured_part", 3)])
_F_PART = FILTER_CHANNELS.offset("measured_part")
#: the measured angles given to a tick or the noise added to synthesised ones (rad)
SIGNALS = Layout("signals", [("bending", 1), ("torsion", 1)])

#: Everything the compiled tick reads but the per-tick inputs (buttons, clock, sample age), in one
#: order: the fields of :class:`LoopArrays`, the struct the kernels take, which
#: :meth:`HapticLoop._pack` fills by these names. The device sample (m, m/s), the period (s), the
#: given signals (NaN: none) and the noise (:data:`SIGNALS`), the force source, blend weight,
#: coupling mode (0 direct, 1 force-position) and clutch buttons; the position map
#: (:mod:`~arsurf.haptics.scaling`), the force-position coupling (:mod:`~arsurf.haptics.coupling`;
#: placeholders of its layouts when direct), the force scale, the filter's alpha and state
#: (:data:`FILTER_CHANNELS`), the passivity controller and the safety layer; the model's arrays
#: (:data:`arsurf.model.MODEL_ARGS`); the previous probe position and the output (:data:`LOOP_OUT`);
#: the sample check's parameters and memory (:mod:`~arsurf.haptics.samples`) and the block of
#: noise rows drawn ahead (:data:`SIGNALS` per row), which the one-call tick reads.
LOOP_FIELDS = ("x", "v", "dt", "ext", "noise", "source", "blend", "coupling_mode", "clutch_mask",
               "pos_params", "pos_state", "fp_params", "fp_phi", "fp_gamma", "fp_state",
               "gain", "alpha", "filt_state", "pc_params", "pc_state", "safety_params", "safety_state",
               *MODEL_ARGS, "prev_probe", "out", "check_params", "check_state", "noise_block")


@_structs.register  # the compiled tick reads its fields without counting references
class _LoopArraysType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class LoopArrays(structref.StructRefProxy):
    """The compiled tick's arrays and settings (:data:`LOOP_FIELDS`) as one numba struct, built
    once per loop: a tick from Python passes one reference instead of the ~40 arrays and settings
    (16 of them the projector's arrays; ~2 µs of unboxing per tick), and with them the sample
    check's and the noise block's, so that a tick passes only the sample's two arrays besides.
    The tick's kernels read its fields without counting references (:mod:`arsurf._structs`)."""


structref.define_proxy(LoopArrays, _LoopArraysType, list(LOOP_FIELDS))


@njit(cache=True)
def _new_loop_arrays(values):
    """``LoopArrays(*values)`` by a cached kernel: the proxy's own constructor (numba's) is
    compiled anew in every process, ~1 s of CPU at each start even on a warm cache."""
    return LoopArrays(*values)


@njit(cache=True)
def loop_model_kernel(a, buttons):
    """Steps 1-3 of a tick (module docstring): probe position, model, force on the probe; the
    first half of :func:`loop_tick_kernel`, for a loop with a scene. ``a`` is the loop's
    :class:`LoopArrays`.

    Writes ``a.out[L_PROBE:L_F_FILT]`` and ``a.mout``, sets ``a.prev_probe`` to the new probe
    position; returns the collision status."""
    return _model_step(a, buttons)


@njit(cache=True, _nrt=False)
def _model_step(a, buttons):
    """:func:`loop_model_kernel`'s work, compiled without reference counts: the entry point from Python
    counts the struct's reference, the body reads its fields borrowed (:mod:`arsurf._structs`)."""
    out = a.out
    prev_probe = a.prev_probe
    fp_state = a.fp_state
    source = a.source
    probe = out[L_PROBE:L_PROBE + 3]
    if a.coupling_mode == 0:
        position_map_step(a.pos_params, a.pos_state, a.x, buttons, a.clutch_mask, probe)
    else:
        for j in range(3):  # the slave position computed by the previous coupling tick
            probe[j] = fp_state[j] if math.isfinite(fp_state[j]) else prev_probe[j]
    for j in range(3):
        out[L_PROBE_V + j] = (probe[j] - prev_probe[j]) / a.dt if math.isfinite(prev_probe[j]) else 0.0
        prev_probe[j] = probe[j]
    ext_signals = a.ext
    have_ext = math.isfinite(ext_signals[0]) and math.isfinite(ext_signals[1])
    if have_ext:
        mode, b, t = SIGNALS_GIVEN, ext_signals[0], ext_signals[1]
    elif source != 0:
        mode, b, t = SIGNALS_SYNTHESISED, a.noise[0], a.noise[1]
    else:
        mode, b, t = SIGNALS_NONE, 0.0, 0.0
    mout = a.mout
    st = model_tick_kernel(a.proj, a.zone_energy, a.live_ctrl, a.live_rest, a.ku, a.kv, a.patch, a.md_args, a.dec_params,
                           a.tip_radius, a.friction, a.deform, probe[0], probe[1], probe[2], b, t, mode,
                           a.model_state, a.coll, a.dec, a.ev, a.mout)
    out[L_COLLIDE_STATUS] = st
    for j in range(3):
        out[L_TIP + j] = mout[M_TIP + j]
    for j in range(3):
        out[L_NORMAL + j] = mout[M_NX + j] if st >= 0 else 0.0
    out[L_SIGNALS] = mout[M_BENDING]
    out[L_SIGNALS + 1] = mout[M_TORSION]
    f = out[L_F_PROBE:L_F_PROBE + 3]
    w = 0.0 if source == 0 else (1.0 if source == 1 else a.blend)
    for j in range(3):
        if st < 0 or w == 0.0:
            out[L_MEAS_PART + j] = 0.0
            f[j] = 0.0 if st < 0 else mout[M_SIM_FX + j]
        else:
            f[j] = w * mout[M_MEAS_FX + j] + (1.0 - w) * mout[M_SIM_FX + j]  # exactly F_meas for w = 1
            out[L_MEAS_PART + j] = f[j] - mout[M_SIM_FX + j]
    return st


@njit(cache=True, inline="always")
def loop_output_kernel(a, buttons, now, age):
    """Steps 4-6 of a tick: filter the probe force ``a.out[L_F_PROBE:]``, couple, keep the port
    passive (:mod:`arsurf.haptics.passivity`), saturate; the second half of
    :func:`loop_tick_kernel`, for a loop with a scene. ``now`` (s) the loop clock, ``age`` (s)
    the age of the device sample.

    Writes ``a.out[L_F_FILT:]``; returns the safety flags."""
    out = a.out
    x_m = a.x
    v_m = a.v
    filt_state = a.filt_state
    alpha = a.alpha
    pc_state = a.pc_state
    clutched = (buttons & a.clutch_mask) != 0
    f = out[L_F_PROBE:L_F_PROBE + 3]
    filt = out[L_F_FILT:L_F_FILT + 3]
    part = out[L_MEAS_PART:L_MEAS_PART + 3]
    lowpass1_step(alpha, filt_state[_F_PART:_F_PART + 3], part, filt)  # the measured part (module docstring, step 4)
    for j in range(3):
        filt[j] += f[j] - part[j]
    hand = out[L_F_HAND:L_F_HAND + 3]
    cflags = 0
    if a.coupling_mode == 0:
        cflags = force_scale_step(a.gain, filt, hand)
    else:
        fp_state = a.fp_state
        nxt = out[L_F_DEVICE:L_F_DEVICE + 3]  # scratch for the next slave position
        cflags = fp_step(a.fp_params, a.fp_phi, a.fp_gamma, fp_state, x_m, v_m, filt, clutched, hand, nxt)
        for j in range(3):
            fp_state[j] = nxt[j]
    out[L_COUPLING_FLAGS] = cflags
    for j in range(3):  # a stylus reading that is not a number is a device fault: zero force now
        if not (math.isfinite(x_m[j]) and math.isfinite(v_m[j])):
            hand[0] = math.nan
    pflag = passivity_observe_control(a.pc_params, pc_state, x_m, v_m, hand)
    dev = out[L_F_DEVICE:L_F_DEVICE + 3]
    flags = safety_step(a.safety_params, a.safety_state, hand, now, age, buttons, dev) | pflag \
        | int(a.mout[M_MODEL_FLAGS])  # the model's caveats (BEYOND_MODEL) in the recorded word
    passivity_applied(pc_state, dev)
    out[L_ENERGY] = pc_state[S_ENERGY]
    out[L_PC_DAMPING] = pc_state[S_ALPHA]
    out[L_SAFETY_FLAGS] = flags
    return flags


@njit(cache=True)
def loop_tick_kernel(a, buttons, now, age):
    """One tick (module docstring) on the loop's :class:`LoopArrays` ``a``. Writes ``a.out``
    (:data:`LOOP_OUT`) and ``a.mout`` (:data:`~arsurf.model.MODEL_OUT`); returns the safety flags.
    ``a.ext`` holds measured (bending, torsion), NaN when none; ``a.noise`` the radians added to
    synthesised signals.

    This is :func:`loop_model_kernel` followed by :func:`loop_output_kernel` (inlined): one
    compiled call from Python, while a loop with a scene calls the two halves separately around
    the scene's step."""
    return _tick_step(a, buttons, now, age)


@njit(cache=True, _nrt=False)
def _tick_step(a, buttons, now, age):
    """:func:`loop_tick_kernel`'s work, compiled without reference counts: the entry point from Python
    counts the struct's reference, the body reads its fields borrowed (:mod:`arsurf._structs`)."""
    _model_step(a, buttons)
    return loop_output_kernel(a, buttons, now, age)


#: where the sample check keeps its last good position (:data:`~arsurf.haptics.samples.SAMPLE_STATE`)
_LAST_GOOD = SAMPLE_STATE.offset("position")
#: what a sample vector that can go straight to the compiled tick is: a C-contiguous (3,) float64 array
_NDARRAY, _F8, _SHAPE3, _C3 = np.ndarray, np.dtype(np.float64), (3,), (8,)
#: sample stamps and clock readings that go to it as they are (a float64)
_STAMPS = frozenset((float, np.float64))
#: noise rows drawn at a time: one draw costs ~1.7 µs (1024 at once cost 22 µs in one tick, a
#: missed deadline at 10 kHz); the sequence is the same whatever the block size
_NOISE_ROWS = 64


@njit(cache=True)
def loop_sample_tick_kernel(a, position, velocity, stamp, buttons, now, row):
    """A tick from a well-formed device sample in one compiled call: the sample check
    (:func:`~arsurf.haptics.samples.sample_check_step` on ``a.check_params``, ``a.check_state``),
    the sample - or, for a sample that cannot be real, the last good position held still - into
    ``a.x``, ``a.v``, the synthesised signals' noise ``a.noise_block[row]`` into ``a.noise``
    (``row`` < 0: none), then :func:`loop_tick_kernel` with the sample's age ``now - stamp`` (0
    for a bad sample). ``position``, ``velocity`` (3,) m, m/s; ``stamp``, ``now`` s. Returns the
    sample's flags (0: a sample that can be real); :meth:`HapticLoop.step` adds them to the tick.

    Two arrays and four numbers per call: each array argument costs ~0.1-0.2 µs to unbox from
    Python, so everything that does not come with the sample lives in ``a``."""
    return _sample_tick_step(a, position, velocity, stamp, buttons, now, row)


@njit(cache=True, _nrt=False)
def _sample_tick_step(a, position, velocity, stamp, buttons, now, row):
    """:func:`loop_sample_tick_kernel`'s work, compiled without reference counts: the entry point from Python
    counts the struct's reference, the body reads its fields borrowed (:mod:`arsurf._structs`)."""
    check_state = a.check_state
    bad = sample_check_step(a.check_params, check_state, position, velocity, stamp, now)
    x = a.x
    v = a.v
    if bad:
        for j in range(3):
            x[j] = check_state[_LAST_GOOD + j]
            v[j] = 0.0
        age = 0.0
    else:
        for j in range(3):
            x[j] = position[j]
            v[j] = velocity[j]
        age = now - stamp
    if row >= 0:
        noise = a.noise_block
        a.noise[0] = noise[row, 0]
        a.noise[1] = noise[row, 1]
    _tick_step(a, buttons, now, age)
    return bad


def _entry_point(dispatcher, args):
    """The compiled entry point of ``dispatcher`` for the types of ``args`` (it must have run on
    them), or the dispatcher itself if numba does not expose it. Calling the entry point skips
    the dispatcher's type resolution - ~2 µs per call for a structref argument such as
    :class:`LoopArrays` - so it may only be called with arguments of exactly these types."""
    try:
        return dispatcher.overloads[tuple(typeof(x) for x in args)].entry_point
    except (AttributeError, KeyError, TypeError, ValueError):
        return dispatcher


def _hand_per_probe_stiffness(coupling: DirectCoupling) -> float:
    """The largest hand stiffness per probe stiffness of a direct coupling, :math:`\\max_i |K_{f,i} s_i|`
    (a probe spring k is felt as :math:`K_f s k` at the handle)."""
    return float(np.max(np.abs(np.asarray(coupling.force.gain) * np.asarray(coupling.position.scale))))


def _give_virtual_coupling(model: ARModel, coupling: DirectCoupling, device_info, rate: float, on) -> float | None:
    """Give ``model`` the direct coupling's virtual coupling (class docstring, ``virtual_coupling``);
    returns the stiffness chosen (N/m at the handle), None when none was (off, or the model's own).

    The probe's stiffness is :math:`k_{vc}/\\max_i |K_{f,i} s_i|`, the same floating-point
    operations as :func:`arsurf.assembly.build_model` does on the recorded ``coupling_stiffness``:
    a replay rebuilds the same bits."""
    if not isinstance(on, (bool, np.bool_)):
        raise HapticsError(f"virtual_coupling must be True or False (got {on!r})")
    has = math.isfinite(model.coupling_stiffness)
    if not on:
        if has:
            raise HapticsError(f"virtual_coupling=False but the model has a virtual coupling of "
                               f"{model.coupling_stiffness:g} N/m at the probe; build the model without one")
        return None
    if has:
        return None
    if device_info is None:
        raise HapticsError("the direct coupling's virtual coupling is chosen from the device's limits: pass "
                           "device_info=device.info, or virtual_coupling=False to run without one (record it)")
    k_vc = coupling_stiffness(device_info, rate)
    model.set_coupling_stiffness(k_vc / _hand_per_probe_stiffness(coupling))
    return k_vc


@dataclass
class LoopConfig:
    """Settings of the loop (SI units; the defaults are the demo's).

    ``rate`` Hz; ``source`` "simulated" | "measured" | "blended" with ``blend`` the weight of the
    measured force; ``filter_cutoff`` Hz of the first-order low-pass of the measured part and the
    contact normal (None: off);
    ``signal_noise`` rad rms added to synthesised angles; ``seed`` of that noise; ``passivity``
    False: the passivity observer only logs the energy, its controller never damps; ``jump_blend``
    s over which a jump of the tip behind the virtual coupling reaches the hand
    (:mod:`arsurf.contact.jump_blend`; 0: in one tick).
    """

    rate: float = 1000.0
    source: str = "simulated"
    blend: float = 0.5
    filter_cutoff: float | None = 50.0
    signal_noise: float = 0.0
    seed: int = 0
    passivity: bool = True
    jump_blend: float = BLEND_TIME

    def validate(self) -> None:
        if not (math.isfinite(self.rate) and 1.0 <= self.rate <= 20000.0):
            raise HapticsError(f"rate must be in [1, 20000] Hz (got {self.rate!r}); 1000 is the usual haptic rate")
        if self.source not in SOURCES:
            raise HapticsError(f"source must be one of {sorted(SOURCES)} (got {self.source!r})")
        if not (0.0 <= self.blend <= 1.0):
            raise HapticsError(f"blend must be in [0, 1] (got {self.blend!r}); it weighs the measured force")
        if self.signal_noise < 0 or not math.isfinite(self.signal_noise):
            raise HapticsError(f"signal_noise must be >= 0 rad (got {self.signal_noise!r})")
        if not (isinstance(self.jump_blend, (int, float)) and not isinstance(self.jump_blend, bool)
                and math.isfinite(self.jump_blend) and self.jump_blend >= 0):  # True is not 1 s
            raise HapticsError(f"jump_blend must be a time >= 0 s (got {self.jump_blend!r}); 0 renders the tip's "
                               "jumps in one tick")


@dataclass(frozen=True)
class LoopOutput:
    """What one tick produced (copies): probe position/velocity (m, m/s), probe force (N on the
    tip), filtered force, hand force (coupling output), device force (after safety), flags, the
    tip behind the virtual coupling (m), the passivity observer's energy (J) and the damping its
    controller added (N s/m), the measured part of the probe force (N) and the contact normal."""

    probe: np.ndarray
    probe_velocity: np.ndarray
    signals: np.ndarray
    probe_force: np.ndarray
    filtered_force: np.ndarray
    hand_force: np.ndarray
    device_force: np.ndarray
    safety_flags: int
    collide_status: int
    tip: np.ndarray
    energy: float
    passivity_damping: float
    measured_part: np.ndarray
    normal: np.ndarray


class HapticLoop:
    """Model + scaling + filter + coupling + safety, stepped one tick at a time.

    Parameters
    ----------
    model : ARModel
    coupling : DirectCoupling or ForcePositionCoupling
    safety : SafetyLayer
    config : LoopConfig
    scene : object, optional
        Nano-objects the probe pushes (:class:`arsurf.manipulation.scene.TubeScene`). Any object
        with ``tick(prev, probe, tip_radius, add_to)`` - move the objects the tip sphere meets
        from ``prev`` to ``probe`` ((3,) m; ``prev`` NaN on the first tick) and add their force
        on the tip (N) to ``add_to`` (3,) - will do; the haptics layer does not import the
        manipulation models. With a scene each tick runs the model part of the compiled tick
        (:func:`loop_model_kernel`), the scene, then the filter/coupling/safety part
        (:func:`loop_output_kernel`): the objects' force joins the probe force *before* the
        filter, and the probe force recorded in :attr:`out` includes it. The angles synthesised
        for ``"measured"``/``"blended"`` sources come from the surface contact only. Without a
        scene the tick is the single compiled call it always was (bit-identical outputs).
    max_damping : float, N s/m
        Largest damping the passivity controller may add (the device's ``max_damping``).
    device_info : DeviceInfo, optional
        The device whose samples the loop takes: its workspace bounds a credible stylus position
        (:mod:`arsurf.haptics.samples`; None: every other sample check still applies), and with
        the rate its limits choose the direct coupling's virtual coupling.
    virtual_coupling : bool
        The direct coupling's virtual coupling (:mod:`arsurf.contact.proxy`), on by default: the
        hand feels the contact through a spring of :func:`~arsurf.haptics.gains.coupling_stiffness`
        (N/m at the handle, from the device's limits and the rate), given to the model at the
        probe's scale, :math:`k_{vc} / \\max_i |K_{f,i}\\, s_i|`. A model that already has a
        coupling (a recorded session's, :func:`arsurf.assembly.build_model`) keeps it. False: no
        coupling (the model must have none); record it (``haptics.virtual_coupling``). The
        force-position coupling is itself a position coupling and takes no other.

    Examples
    --------
    >>> # see arsurf.demo for a complete assembly with a VirtualDevice
    """

    def __init__(self, model: ARModel, coupling, safety: SafetyLayer, config: LoopConfig | None = None,
                 scene=None, max_damping: float = math.inf, device_info=None, virtual_coupling: bool = True):
        config = config or LoopConfig()
        config.validate()
        if not isinstance(model, ARModel):
            raise HapticsError(f"model must be an arsurf ARModel (got {type(model).__name__})")
        if not isinstance(safety, SafetyLayer):
            raise HapticsError(f"safety must be a SafetyLayer (got {type(safety).__name__}): every force passes it")
        self.dt = 1.0 / config.rate
        safety_dt = float(safety.params[_SAFETY_P_DT])
        if abs(safety_dt - self.dt) > 1e-9 * self.dt:
            raise HapticsError(f"the safety layer was built for dt={safety_dt!r} s but the loop runs at {self.dt!r} s; "
                               "build both with the same rate")
        self.model = model
        self.coupling = coupling
        self.safety = safety
        self.config = config
        self.sample_check = SampleCheck(device_info, self.dt)  # samples that cannot be real: a fault
        if isinstance(coupling, DirectCoupling):
            self._mode = 0
            pos = coupling.position
            self._pos = (pos.params, pos.state, pos.clutch_mask)
            self._gain = coupling.force.gain
            self._fp = (FP_PARAMS.zeros(), np.zeros((3, 3, 3)), np.zeros((3, 3)), FP_STATE.zeros())  # unused
        elif isinstance(coupling, ForcePositionCoupling):
            self._mode = 1
            self._pos = (POSITION_PARAMS.zeros(), POSITION_STATE.zeros(), int(getattr(coupling, "clutch_mask", 1)))
            self._gain = np.ones(3)
            self._fp = (coupling.params, coupling.phi, coupling.gamma, coupling.state)
        else:
            raise HapticsError(f"coupling must be DirectCoupling or ForcePositionCoupling (got {type(coupling).__name__})")
        # the stiffness chosen here from the device (N/m at the handle), None when the model came with its own
        self._vc_chosen = (_give_virtual_coupling(model, coupling, device_info, config.rate, virtual_coupling)
                           if self._mode == 0 else None)
        model.set_jump_blend(config.jump_blend, self.dt)  # the coupled tip's jumps, over the blend time
        self.passivity = PassivityController(self.dt, max_damping, enabled=config.passivity,
                                             reserve=model.adhesion_energy() * coupling.energy_gain())
        # the measured part (FILTER_CHANNELS; module docstring, step 4)
        self.filter = (LowPass(config.filter_cutoff, self.dt, channels=FILTER_CHANNELS.size) if config.filter_cutoff
                       else None)
        self._alpha = self.filter.alpha if self.filter else 1.0
        self._filt_state = self.filter.state if self.filter else FILTER_CHANNELS.zeros()
        self._rng = np.random.default_rng(config.seed)
        self._noise = SIGNALS.zeros()
        self._noise_block = np.empty((_NOISE_ROWS, SIGNALS.size))
        self._noise_i = _NOISE_ROWS  # empty: filled at the first tick
        self._noisy = config.signal_noise > 0.0
        self._ext = SIGNALS.full(np.nan)
        self._ext_given = False  # the last tick was given signals: clear them when the next is not
        self._x = np.zeros(3)
        self._v = np.zeros(3)
        self.prev_probe = np.full(3, np.nan)
        self.out = LOOP_OUT.zeros()
        self._device_force = self.out[L_F_DEVICE:L_F_DEVICE + 3]
        self._source = SOURCES[config.source]
        if scene is not None and not callable(getattr(scene, "tick", None)):
            raise HapticsError(f"scene must have a tick(prev, probe, tip_radius, add_to) method, like "
                               f"arsurf.manipulation.scene.TubeScene (got {type(scene).__name__})")
        self.scene = scene
        self._scene_prev = np.full(3, np.nan)
        self._model_args = model.kernel_args()
        self._packed = self._pack()
        self._fused = None  # loop_sample_tick_kernel's entry point for this loop's types (set at the first tick)

    def _pack(self) -> LoopArrays:
        """The tick's arrays and settings as one struct (:class:`LoopArrays`, :data:`LOOP_FIELDS`),
        sharing this loop's arrays."""
        fp_params, fp_phi, fp_gamma, fp_state = self._fp
        values = {"x": self._x, "v": self._v, "dt": self.dt, "ext": self._ext, "noise": self._noise,
                  "source": self._source, "blend": float(self.config.blend), "coupling_mode": self._mode,
                  "clutch_mask": int(self._pos[2]), "pos_params": self._pos[0], "pos_state": self._pos[1],
                  "fp_params": fp_params, "fp_phi": fp_phi, "fp_gamma": fp_gamma, "fp_state": fp_state,
                  "gain": self._gain, "alpha": float(self._alpha), "filt_state": self._filt_state,
                  "pc_params": self.passivity.params, "pc_state": self.passivity.state,
                  "safety_params": self.safety.params, "safety_state": self.safety.state,
                  **dict(zip(MODEL_ARGS, self._model_args)), "prev_probe": self.prev_probe, "out": self.out,
                  "check_params": self.sample_check.params, "check_state": self.sample_check.state,
                  "noise_block": self._noise_block}
        if set(values) != set(LOOP_FIELDS):
            raise HapticsError(f"the loop's arrays {sorted(set(values) ^ set(LOOP_FIELDS))} do not match LOOP_FIELDS")
        return _new_loop_arrays(tuple(values[name] for name in LOOP_FIELDS))

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        del state["_packed"]  # a numba struct does not pickle; rebuilt from the arrays
        del state["_device_force"]  # a view of out: a copy would be its own array
        state["_fused"] = None  # the compiled entry point of the struct's types: found again at the first tick
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._device_force = self.out[L_F_DEVICE:L_F_DEVICE + 3]
        self._packed = self._pack()

    @property
    def virtual_coupling(self) -> float | None:
        """Stiffness (N/m at the handle) of the direct coupling's virtual coupling, None without
        one (or with the force-position coupling): what a session records as
        ``haptics.coupling_stiffness``."""
        if self._vc_chosen is not None:
            return self._vc_chosen
        k = self.model.coupling_stiffness
        if self._mode != 0 or not math.isfinite(k):
            return None
        return k * _hand_per_probe_stiffness(self.coupling)

    @classmethod
    def direct(cls, model: ARModel, device_info, probe_origin, *, scale: float = 1e-5, force_gain: float = 1e5,
               config: LoopConfig | None = None, scene=None, virtual_coupling: bool = True,
               **safety_kwargs) -> "HapticLoop":
        """The usual assembly: direct coupling (master displacement x ``scale`` -> probe, probe
        force x ``force_gain`` -> hand), the virtual coupling chosen from the device and the rate,
        the passivity controller (``config.passivity``) and a safety layer saturating at the
        device's max force.

        ``probe_origin`` (3,) m is where the probe is when the master is at its origin; ``scale``
        is probe metres per master metre (1e-5: 1 mm -> 10 nm); ``force_gain`` N per N;
        ``scene`` the optional nano-objects, ``virtual_coupling`` (default on) as in the class.

        Stability: the hand feels the contact stiffness k_c (N/m at the probe, ~E* a) as
        K_f k_c s N/m; a sampled loop renders at most 4 M_v / T² (corrected Table II, [Bolopion]:
        13 kN/m for a 3.3 g stylus at 1 kHz), less with a filter's delay in the loop: with
        k_c ~ 200 N/m and s = 1e-5, K_f = 1e5 renders 200 N/m and is stable with a 200 Hz
        low-pass, K_f = 1e6 (2 kN/m) chatters (measured in the demo); [Alabdulmuhsin]'s K_f = 15e6
        at this scale would not be passive.
        """
        from arsurf.haptics.scaling import ForceScaling, PositionScaling

        config = config or LoopConfig()
        config.validate()
        coupling = DirectCoupling(PositionScaling(scale, probe_origin=probe_origin), ForceScaling(force_gain))
        safety = SafetyLayer.for_device(device_info, 1.0 / config.rate, **safety_kwargs)
        # the passivity controller's damping limit: the device's, else its stiffness limit over one tick
        max_damping = (float(np.min(device_info.max_stiffness)) / config.rate if device_info.max_damping is None
                       else float(np.min(device_info.max_damping)))
        return cls(model, coupling, safety, config, scene=scene, max_damping=max_damping, device_info=device_info,
                   virtual_coupling=virtual_coupling)

    def step(self, inputs: DeviceState, now: float, signals=None) -> np.ndarray:
        """One tick from a device sample; returns the device force (3,) N (a reused array).

        ``now`` is the loop clock (s; the safety watchdog's time base), ``signals`` optional
        measured (bending, torsion) in rad. Allocation-free: the hot path. The sample is checked
        once here (:mod:`arsurf.haptics.samples`): one that cannot be real gives zero force in
        this tick, its flag, and the model runs on the last good sample.

        The usual tick - a C-contiguous (3,) float64 position and velocity, a float stamp and
        clock, a button word in [0, 2^31), no scene - is one compiled call
        (:func:`loop_sample_tick_kernel` through its entry point) after a few type tests; any other
        input takes :meth:`_step_checked`, which gives the same outputs bit for bit.
        """
        if signals is not None or self._ext_given:
            self._take_signals(signals)
        row = -1
        if self._noisy:  # drawn a block of ticks at a time: no allocation per tick
            row = self._noise_i
            if row == _NOISE_ROWS:
                self._rng.standard_normal(out=self._noise_block)
                self._noise_block *= self.config.signal_noise
                row = 0
            self._noise_i = row + 1
        buttons = inputs.buttons
        p = inputs.position
        v = inputs.velocity
        stamp = inputs.timestamp
        fused = self._fused
        if (fused is not None and type(buttons) is int and 0 <= buttons < _BUTTONS_LIMIT
                and type(p) is _NDARRAY and type(v) is _NDARRAY and p.dtype is _F8 and v.dtype is _F8
                and p.shape == _SHAPE3 and v.shape == _SHAPE3 and p.strides == _C3 and v.strides == _C3
                and type(stamp) in _STAMPS and type(now) in _STAMPS and self.scene is None):
            bad = fused(self._packed, p, v, stamp, buttons, now, row)
            if bad:
                self._flag_input(bad)
            return self._device_force
        return self._step_checked(inputs, now, row)

    def _take_signals(self, signals) -> None:
        """The measured (bending, torsion) of this tick into the loop's, or NaN when none follow
        a tick that had them."""
        if signals is not None:
            self._ext[0], self._ext[1] = signals
            self._ext_given = True
        else:
            self._ext[:] = np.nan
            self._ext_given = False

    def _step_checked(self, inputs: DeviceState, now: float, row: int) -> np.ndarray:
        """:meth:`step` for any input (the noise row ``row`` drawn, -1: none): buttons that are not
        a button word count as none and are flagged; a well-formed sample without a scene ticks in
        the one compiled call (the first such finds its entry point); any other sample is checked
        in Python and ticks in :func:`loop_tick_kernel`, or around the scene in two halves."""
        buttons = inputs.buttons
        bad_buttons = False
        if not (type(buttons) is int and 0 <= buttons < _BUTTONS_LIMIT):  # NaN, None, 2**64...: no press,
            buttons, bad_buttons = _valid_buttons(buttons)              # flagged, never an exception
        p, v, stamp = inputs.position, inputs.velocity, inputs.timestamp
        if (type(p) is _NDARRAY and type(v) is _NDARRAY and p.strides == _C3 and v.strides == _C3 and p.shape == _SHAPE3
                and v.shape == _SHAPE3 and p.dtype is _F8 and v.dtype is _F8 and type(stamp) in _STAMPS
                and self.scene is None):
            # a C-contiguous float64 sample: check, sample, noise and tick in one compiled call
            args = (self._packed, p, v, stamp, buttons, float(now), row)
            if self._fused is None:
                bad = loop_sample_tick_kernel(*args)
                self._fused = _entry_point(loop_sample_tick_kernel, args)
            else:
                bad = self._fused(*args)
            if bad_buttons or bad:
                self._flag_input(BAD_BUTTONS * bad_buttons | bad)
            return self._device_force
        if row >= 0:
            self._noise[0] = self._noise_block[row, 0]
            self._noise[1] = self._noise_block[row, 1]
        x, v = self._x, self._v
        bad = self.sample_check.step(inputs, now)
        if bad:
            x[:] = self.sample_check.last_good
            v[:] = 0.0
            age = 0.0
        else:
            x[:] = inputs.position
            v[:] = inputs.velocity
            age = float(now - inputs.timestamp)
        if self.scene is None:
            loop_tick_kernel(self._packed, buttons, float(now), age)
            if bad_buttons or bad:
                self._flag_input(BAD_BUTTONS * bad_buttons | bad)
            return self._device_force
        out = self.out
        loop_model_kernel(self._packed, buttons)
        self.scene.tick(self._scene_prev, out[L_TIP:L_TIP + 3], self.model.tip_radius,
                        out[L_F_PROBE:L_F_PROBE + 3])
        self._scene_prev[:] = out[L_TIP:L_TIP + 3]
        loop_output_kernel(self._packed, buttons, float(now), age)
        if bad_buttons or bad:
            self._flag_input(BAD_BUTTONS * bad_buttons | bad)
        return self._device_force

    def _flag_input(self, flags: int) -> None:
        """Add the input's flags to the tick; a sample fault (:data:`~arsurf.haptics.samples.SAMPLE_FAULTS`)
        also zeroes the device force of this tick and restarts the ramp."""
        out = self.out
        out[L_SAFETY_FLAGS] = int(out[L_SAFETY_FLAGS]) | flags
        if flags & SAMPLE_FAULTS:
            self._device_force[:] = 0.0
            self.safety.zero_now()
            passivity_applied(self.passivity.state, self._device_force)

    @property
    def stylus_position(self) -> np.ndarray:
        """The stylus position (3,) m the last tick ran on: the device's sample, or the last good
        one when that sample could not be real (a view; copy to keep it)."""
        return self._x

    @property
    def stylus_velocity(self) -> np.ndarray:
        """The stylus velocity (3,) m/s the last tick ran on (zero on a refused sample; a view)."""
        return self._v

    def warm_up(self) -> "HapticLoop":
        """Compile (or load from the cache) the tick's kernels on a throw-away copy of this loop.

        Call it before handing the loop to a real-time thread: the first tick of a cold process
        otherwise spends seconds in the numba compiler with the stylus live. This loop's state
        (dent, filters, safety, scene) is not touched.
        """
        import copy

        twin = copy.deepcopy(self)
        twin.step(DeviceState(np.zeros(3), np.zeros(3), 0, 0.0), 0.0)
        return self

    def scheduler_step(self, state, inputs: DeviceState, dt: float) -> np.ndarray:
        """``step(state, inputs, dt)`` signature for :class:`~arsurf.haptics.scheduler.Scheduler`
        (``state`` is this loop; the loop clock is the device sample time)."""
        return self.step(inputs, inputs.timestamp)

    def output(self) -> LoopOutput:
        """The last tick as a :class:`LoopOutput` record (copies)."""
        r = LOOP_OUT.record(self.out)
        del r["coupling_flags"]
        r["safety_flags"], r["collide_status"] = int(r["safety_flags"]), int(r["collide_status"])
        return LoopOutput(**r)
