"""Standard feel scenarios: a modelled hand on a virtual device, pressing, sliding, stroking, tapping.

Each scenario closes the whole loop as a user would: a surface (a real scan prepared as the demo
prepares it, or a synthetic step or ridge), the demo's tip, contact law, lever and haptic gains,
a :class:`~arsurf.haptics.virtual_device.VirtualDevice` whose :class:`HandModel` follows a scripted
set point, at a loop rate of 1-20 kHz, with the virtual coupling and passivity controller the
device and rate call for (:func:`arsurf.haptics.gains.coupling_stiffness`). The device force
record is scored by :func:`arsurf.haptics.feel.score_force` (after 1 s of settling).

Motions (hand set point; the probe scale is 1 mm -> 10 nm):

==============  ==============================================================================
``press``       press 1 mm down in 0.5 s (the probe 10 nm into the surface) and hold still
``slide-1``     press, then slide along x at 1 nm/s at the probe (from 0.5 s)
``slide-10``    ... at 10 nm/s
``slide-100``   ... at 100 nm/s
``stroke``      press, then stroke 300 nm along x at 150 nm/s across the middle (a step edge on
                the ``step`` surface)
``tap``         tap twice a second: the set point goes from 0.3 mm above to 1 mm into the surface
``wobble``      press, then a multisine of 0.05 mm in z (10 tones, 2-400 Hz, Schroeder phases):
                the excitation of the transparency (Bode) estimate in ``bench/feel.py``; not
                one of the table's :data:`MOTIONS`
==============  ==============================================================================

Used by ``bench/feel.py`` (the whole table) and the tests (the buzz scenarios on real scans).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from arsurf.assembly import build_loop, make_model
from arsurf.assembly import preset as _preset
from arsurf.errors import HapticsError
from arsurf.haptics.feel import FeelScore, score_force
from arsurf.haptics.loop import LOOP_OUT
from arsurf.haptics.virtual_device import HandModel, VirtualDevice

__all__ = ["FAMILIES", "MOTIONS", "RATE_TOLERANCE", "SOURCES", "FeelRun", "GeneratedSurface", "energy_ok",
           "generated_surfaces", "prepared_surface", "rate_convergence", "run_scenario", "synthetic_surface"]

MOTIONS = ("press", "slide-1", "slide-10", "slide-100", "stroke", "tap")
#: motions of the generated families beyond the table's: slides at 0.1 nm/s, and circles (a slide
#: in every direction, staying on a small surface) at 10-1000 nm/s
EXTRA_MOTIONS = ("slide-0.1", "circle-10", "circle-100", "circle-1000")
SOURCES = ("simulated", "measured", "blended")
#: photodiode noise of the measured and blended sources (rad rms per angle)
SIGNAL_NOISE = 1e-8
_PRESS = 1e-3  # m of hand travel into the surface
_PRESS_TIME = 0.5  # s


@dataclass(frozen=True)
class FeelRun:
    """One scenario: its score, the device force (n, 3) N, the observed energy (n,) J, contact
    (n,) bool, passivity-controller ticks, the per-tick compute time (n,) ns, the loop's
    steady-state transparency (|device force| / (K_f |tip force|) over the last 0.2 s) and the tip
    centre (n, 3) m and the force on the probe (n, 3) N of every tick; ``energy_reserve`` J the
    passive store E0 of the loop's passivity controller."""

    score: FeelScore
    force: np.ndarray
    energy: np.ndarray
    contact: np.ndarray
    passivity_ticks: int
    tick_ns: np.ndarray
    transparency: float
    tip: np.ndarray
    probe_force: np.ndarray
    energy_reserve: float = 0.0


def prepared_surface(path, preset: str = "demo"):
    """(scan, surface): ``path`` loaded, levelled, smoothed and fitted as the preset does."""
    from arsurf.scan.prepare import prepare_scan
    from arsurf.spline.fit import fit_surface

    p = _preset(preset)
    scan = prepare_scan(path, None, p.level, p.sigma, True)
    return scan, fit_surface(scan)


def synthetic_surface(kind: str, size: int = 128, pixel: float = 4e-9):
    """A ``"step"`` (5 nm, 2 nm wide edge at x = middle) or ``"ridge"`` (8 nm high, 10 nm wide)
    height field as a B-spline (:meth:`BSplineSurface.from_heights`), ``size`` control points of
    ``pixel`` metres."""
    from arsurf.spline.surface import BSplineSurface

    x = np.arange(size) * pixel
    x0 = x[-1] / 2
    if kind == "step":
        z = 2.5e-9 * (1.0 + np.tanh((x - x0) / 2e-9))
    elif kind == "ridge":
        z = 8e-9 * np.exp(-0.5 * ((x - x0) / 10e-9) ** 2)
    else:
        raise HapticsError(f"synthetic surface must be 'step' or 'ridge' (got {kind!r})")
    return BSplineSurface.from_heights(np.tile(z, (size, 1)).T, (0.0, x[-1]), (0.0, x[-1]))


def _trajectory(motion: str, scale: float):
    """The hand's set point r(t) (m) for a motion."""
    def press(t):
        return -_PRESS * min(t / _PRESS_TIME, 1.0)

    if motion == "press":
        return lambda t: [0.0, 0.0, press(t)]
    if motion.startswith("slide-"):
        speed = float(motion.split("-")[1]) * 1e-9 / scale  # probe nm/s -> hand m/s
        return lambda t: [speed * max(t - _PRESS_TIME, 0.0), 0.0, press(t)]
    if motion.startswith("circle-"):  # a circle of 0.1 mm (1 nm at the probe) at the speed, from 0.5 s
        speed = float(motion.split("-")[1]) * 1e-9 / scale
        rc = 0.1e-3

        def circle(t):
            a = speed * max(t - _PRESS_TIME, 0.0) / rc
            return [rc * (math.cos(a) - 1.0), rc * math.sin(a), press(t)]
        return circle
    if motion == "stroke":
        speed = 150e-9 / scale
        return lambda t: [-150e-9 / scale + min(speed * max(t - _PRESS_TIME, 0.0), 300e-9 / scale), 0.0, press(t)]
    if motion == "tap":
        return lambda t: [0.0, 0.0, 0.3e-3 - 1.3e-3 * 0.5 * (1.0 - math.cos(2.0 * math.pi * 2.0 * t))]
    if motion == "wobble":
        tones = np.geomspace(2.0, 400.0, 10)
        phases = -math.pi * np.arange(10) * np.arange(1, 11) / 10  # Schroeder: a low crest factor
        amp = 0.05e-3 / 10
        return lambda t: [0.0, 0.0, press(t) + (amp * float(np.sin(2.0 * math.pi * tones * (t - _PRESS_TIME) + phases).sum())
                                                if t > _PRESS_TIME else 0.0)]
    raise HapticsError(f"motion must be one of {MOTIONS + ('wobble',)} (got {motion!r})")


def run_scenario(surface, *, motion: str = "press", source: str = "simulated", rate: float = 1000.0,
                 seconds: float = 3.0, preset: str = "demo", at=None, friction: float | None = None,
                 static_friction: float | None = None, coupling: bool = True, passivity: bool = True,
                 signal_noise: float = SIGNAL_NOISE, seed: int = 7, max_rate: float | None = None,
                 filter_cutoff: float | None | str = "preset", tip_radius: float | None = None) -> FeelRun:
    """Run one scenario on ``surface`` (module docstring) and score the device force.

    ``at`` (x, y) m: the middle of the motion (default: the middle of the surface; a stroke
    comes down 150 nm before it and ends 150 nm after); ``coupling`` False: no virtual coupling (the tip is the scaled stylus), ``passivity``
    False: the controller only observes; ``max_rate`` N/s the safety layer's rate limit (default:
    the preset's); ``filter_cutoff`` Hz of the force low-pass (None: off; default: the preset's);
    ``tip_radius`` m (default: the preset's). The surface is restored to rest afterwards."""
    p = _preset(preset)
    h = dict(p.haptics)
    scale, gain = float(h["scale"]), float(h["force_gain"])
    dev = VirtualDevice(dt=1.0 / rate, hand=HandModel(_trajectory(motion, scale))).open()
    radius = p.tip_radius if tip_radius is None else float(tip_radius)
    model = make_model(surface, tip_radius=radius, effective_modulus=p.effective_modulus,
                       work_of_adhesion=p.work_of_adhesion, cantilever=p.cantilever,
                       friction=p.friction if friction is None else friction, static_friction=static_friction,
                       signal_noise=0.0 if source == "simulated" else signal_noise)  # the loop's, below
    (u0, u1), (v0, v1) = surface.domain
    x, y = (0.5 * (u0 + u1), 0.5 * (v0 + v1)) if at is None else at
    z = float(surface.evaluate(x - (150e-9 if motion == "stroke" else 0.0), y)[2])
    origin = (x, y, z + radius + 2e-9)
    h.update(rate=float(rate), source=source, signal_noise=0.0 if source == "simulated" else signal_noise,
             virtual_coupling=bool(coupling), passivity=passivity, seed=seed)  # the coupling: from dev, rate
    if max_rate is not None:
        h["max_rate"] = max_rate
    if filter_cutoff != "preset":
        h["filter_cutoff"] = filter_cutoff
    loop = build_loop(model, h, dev.info, origin, seed=seed)
    n = int(round(seconds * rate))
    force = np.empty((n, 3))
    energy = np.empty(n)
    contact = np.empty(n, bool)
    tip_force = np.empty((n, 3))
    tip = np.empty((n, 3))
    tick_ns = np.empty(n)
    pc = 0
    clock = time.perf_counter_ns
    out = loop.out
    get = LOOP_OUT.get
    from arsurf.model import M_IN_CONTACT

    try:
        for k in range(n):
            st = dev.read_state()
            t0 = clock()
            f = loop.step(st, st.timestamp)
            tick_ns[k] = clock() - t0
            dev.command_force(f)
            force[k] = f
            energy[k] = get(out, "energy")
            pc += get(out, "passivity_damping") > 0.0
            contact[k] = model.out[M_IN_CONTACT] > 0.5
            tip_force[k] = get(out, "probe_force")
            tip[k] = get(out, "tip")
    finally:
        dev.close()
        model.reset()
    tail = slice(n - max(1, int(0.2 * rate)), n)
    scaled = np.linalg.norm(tip_force[tail].mean(axis=0)) * gain
    transparency = float(np.linalg.norm(force[tail].mean(axis=0)) / scaled) if scaled > 0 else math.nan
    score = score_force(force, 1.0 / rate, energy=energy, contact=contact, energy_reserve=loop.passivity.reserve)
    return FeelRun(score, force, energy, contact, int(pc), tick_ns, transparency, tip, tip_force,
                   float(loop.passivity.reserve))


#: the generated surface families (issue 27 §3): random rough surfaces of a Gaussian or power-law
#: spectrum, steps and ridges; each drawn by a seeded generator (:func:`generated_surfaces`)
FAMILIES = ("gaussian", "power-law", "step", "ridge")
#: the ranges drawn from (log-uniformly), metres: rms roughness (or step/ridge height),
#: correlation length (or edge/ridge width), pixel pitch, tip radius
RMS_RANGE = (0.5e-9, 20e-9)
LENGTH_RANGE = (2e-9, 200e-9)
PIXEL_RANGE = (0.25e-9, 8e-9)
TIP_RANGE = (2e-9, 50e-9)
#: pixels per side of a generated scan
GENERATED_PIXELS = 192


@dataclass(frozen=True)
class GeneratedSurface:
    """One generated surface of a family: its parameters (m) and seed; :meth:`surface` fits it."""

    family: str
    seed: int
    height: float
    length: float
    pixel: float
    tip_radius: float

    @property
    def name(self) -> str:
        return (f"{self.family}#{self.seed} h={self.height * 1e9:.3g}nm l={self.length * 1e9:.3g}nm "
                f"px={self.pixel * 1e9:.3g}nm R={self.tip_radius * 1e9:.3g}nm")

    def surface(self):
        """The scan generated (:func:`arsurf.scan.synthetic.rough` or a step/ridge profile) and fitted."""
        from arsurf.scan import synthetic
        from arsurf.spline.fit import fit_surface

        n = GENERATED_PIXELS
        if self.family in ("gaussian", "power-law"):
            scan = synthetic.rough((n, n), self.pixel, rms=self.height, correlation_length=self.length,
                                   spectrum=self.family, seed=self.seed)
            return fit_surface(scan)
        x = np.arange(n) * self.pixel
        x0 = x[-1] / 2
        if self.family == "step":
            z = 0.5 * self.height * (1.0 + np.tanh((x - x0) / (0.5 * self.length)))
        else:
            z = self.height * np.exp(-0.5 * ((x - x0) / (0.5 * self.length)) ** 2)
        from arsurf.spline.surface import BSplineSurface

        return BSplineSurface.from_heights(np.tile(z, (n, 1)).T, (0.0, x[-1]), (0.0, x[-1]))


def generated_surfaces(count: int, seed: int = 0, families=FAMILIES) -> list[GeneratedSurface]:
    """``count`` surfaces drawn in turn from ``families``, each parameter log-uniform over its
    range (:data:`RMS_RANGE`, :data:`LENGTH_RANGE`, :data:`PIXEL_RANGE`, :data:`TIP_RANGE`),
    seeded: the same ``seed`` gives the same table, a larger ``count`` extends it. Kept inside
    what the scan can hold: a correlation length of at least one pixel and at most a quarter of
    the side (the rough generator's rule), a tip whose diameter and a 1 nm circle fit in a third
    of the side, a step or ridge width of at most a quarter of the side (its feature on the scan)."""
    rng = np.random.default_rng(seed)
    out = []

    def draw(lo, hi):
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))

    for k in range(int(count)):
        family = families[k % len(families)]
        pixel = draw(*PIXEL_RANGE)
        side = GENERATED_PIXELS * pixel
        length = draw(max(LENGTH_RANGE[0], 2.0 * pixel), max(LENGTH_RANGE[0], min(LENGTH_RANGE[1], 0.25 * side)))
        tip = draw(TIP_RANGE[0], max(TIP_RANGE[0], min(TIP_RANGE[1], side / 6.0 - 1e-9)))
        out.append(GeneratedSurface(family, int(rng.integers(2**31)), draw(*RMS_RANGE), length, pixel, tip))
    return out


#: rate convergence (issue 27 §3): a faster motion's force at 1 kHz must match the same motion at
#: 10 kHz, averaged over each 1 ms tick, within this rms fraction of the 10 kHz force's rms
RATE_TOLERANCE = 0.15


def energy_ok(run: FeelRun) -> bool:
    """Observed energy >= -E0 (the passive store), to the score's tolerance
    (:func:`~arsurf.haptics.feel.score_force`)."""
    from arsurf.haptics.feel import ENERGY_TOLERANCE

    e = run.score.min_energy
    return bool(math.isnan(e) or e >= -run.energy_reserve - ENERGY_TOLERANCE * float(np.nanmax(np.abs(run.energy))))


def rate_convergence(surface, motion: str, source: str = "simulated", seconds: float = 2.0, tip_radius=None,
                     seed: int = 7) -> dict:
    """Texture is not buzz: what the surface gives stays when the loop rate goes from 1 to 10 kHz,
    what the loop adds does not. Runs ``motion`` at both rates and returns the rms of
    :math:`F_{1k}(t_k) - \bar F_{10k}(t_k)` over the rms of :math:`\bar F_{10k}` after 1 s
    (:math:`\bar F_{10k}` the 10 kHz force averaged over the 1 ms of tick k), whether both runs
    kept the observed energy >= -E0, and ``ok`` (error <= :data:`RATE_TOLERANCE` and energy)."""
    slow = run_scenario(surface, motion=motion, source=source, rate=1000.0, seconds=seconds, tip_radius=tip_radius,
                        seed=seed)
    fast = run_scenario(surface, motion=motion, source=source, rate=10000.0, seconds=seconds,
                        tip_radius=tip_radius, seed=seed)
    n = min(slow.force.shape[0], fast.force.shape[0] // 10)
    f1 = slow.force[:n]
    f10 = fast.force[:10 * n].reshape(n, 10, 3).mean(axis=1)
    w = slice(1000, n)
    ref = float(np.sqrt(np.mean(np.sum(f10[w] ** 2, axis=1))))
    err = float(np.sqrt(np.mean(np.sum((f1[w] - f10[w]) ** 2, axis=1)))) / ref if ref > 0 else 0.0
    energy = [energy_ok(r) for r in (slow, fast)]
    return {"motion": motion, "source": source, "rate_error": err, "energy_ok": all(energy),
            "min_energy_J": [slow.score.min_energy, fast.score.min_energy],
            "ok": bool(err <= RATE_TOLERANCE and all(energy))}
