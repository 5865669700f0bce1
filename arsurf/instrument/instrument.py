r"""A virtual AFM: stages, a sample, a cantilever spring and a noisy photodiode, in simulated time.

It is one :class:`~arsurf.instrument.interface.Instrument` (the others drive a real controller,
:mod:`arsurf.instrument.nanonis`): read the tip position and the two signals, move in XY (the
nano stage XY) and Z (the PicoCube), engage (the procedure of :mod:`arsurf.instrument.engage`),
hold the deflection with an ideal Z feedback, withdraw.

The instrument of [Alabdulmuhsin] (Fig. 3.1): the micro stage and the nano stage raise the sample under
the tip, the PicoCube carries the probe. The simulation runs at the real-time loop rate (10 kHz in
[Alabdulmuhsin]) and records every sample: stage positions, gap, deflection, true force and the
measured vertical signal.

Vertical model (contact mode, no adhesion; the sample is much stiffer than the lever):

.. math::

    g = z_{tip} - z_{surface}, \qquad \delta = \max(0, -g), \qquad F = k\,\delta, \qquad
    V_v = \operatorname{clip}\big(V_0 + \delta / S_n + n(t),\ -1, 1\big)

with :math:`z_{tip} = h_{probe} - z_{pico}` (the tip apex when the lever is straight; the PicoCube
extends the probe towards the sample) and
:math:`z_{surface} = h(x, y) + z_{micro} + z_{nano}`. The normalised vertical signal saturates at
:math:`\pm 1` ([Alabdulmuhsin], Sec. 4.2.2). [Alabdulmuhsin]'s rectangular lever: k = 0.3 N/m (Table 4.1),
:math:`|S_n|` = 1117 nm/V (Sec. 4.1.1; the sign depends on the detector mounting, [Alabdulmuhsin]
finds it negative).

Lateral signal: while the tip slides in contact, friction opposes the motion,
:math:`\mathbf F_l = -\mu F \hat{\mathbf u}`, and the torsion signal reads its component across
the lever (y): :math:`V_h = \operatorname{clip}(V_{h0} + F_{l,y} / S_l + n_h(t), -1, 1)`, with
:math:`S_l` the lateral force per signal unit (N); at rest it reads the offset and noise.
Z feedback (``set_feedback(True)``, or after :meth:`VirtualAFM.engage`): an ideal controller
that sets the PicoCube, every tick, so that the deflection equals the set point (within its
travel): :math:`\delta = |S_n| V_{set}`.

Photodiode noise ([Alabdulmuhsin], Fig. 4.4): with the sample away from the lever the vertical signal
spans 0.0140 V peak to peak over 5 s for the rectangular cantilever, 0.0195 V for the triangular
one, which also shows low-frequency noise below 60 Hz. :class:`PhotodiodeNoise` is white
Gaussian noise (plus an optional first-order low-pass component) whose standard deviation is set
so that the *expected* peak-to-peak over that window equals the measured one. Noise is drawn from
a seeded generator: a run is reproducible.

Examples
--------
>>> afm = VirtualAFM(surface=0.0, probe_height=5e-6, seed=1)
>>> afm.gap() == 5e-6
True
>>> signal = afm.dwell(0.01)            # 10 ms of the free lever's signal
>>> signal.size, bool(abs(signal.mean()) < 2e-3)
(100, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter
from scipy.special import ndtr

from arsurf.errors import InstrumentError
from arsurf.instrument import imaging
from arsurf.instrument.engage import engage
from arsurf.instrument.interface import Instrument, InstrumentLimits, InstrumentSample
from arsurf.instrument.lspb import LSPB
from arsurf.instrument.stages import MICRO_STAGE, NANO_STAGE, NANO_STAGE_XY, PICOCUBE, Stage
from arsurf.scan.scan import Scan


def expected_range(n: int) -> float:
    """Expected peak-to-peak (max - min) of ``n`` independent standard normal samples.

    .. math:: E[R_n] = \\int_{-\\infty}^{\\infty} \\big(1 - \\Phi(x)^n - (1 - \\Phi(x))^n\\big)\\,dx

    Examples
    --------
    >>> round(expected_range(2), 6)    # 2 / sqrt(pi)
    1.128379
    """
    n = int(n)
    if n < 2:
        raise InstrumentError(f"the range needs at least 2 samples (got {n})")
    x = np.linspace(-12.0, 12.0, 240_001)
    p = ndtr(x)
    f = 1.0 - p**n - (1.0 - p) ** n
    return float(np.sum(0.5 * (f[1:] + f[:-1])) * (x[1] - x[0]))


@dataclass(frozen=True)
class PhotodiodeNoise:
    """Noise of the vertical photodiode signal, specified as [Alabdulmuhsin] measures it.

    Parameters
    ----------
    peak_to_peak : float, volts (signal units)
        Expected max - min over ``window`` seconds sampled at ``rate``.
    window : float, seconds
        Length of the record the peak-to-peak refers to (5 s in [Alabdulmuhsin], Fig. 4.4).
    rate : float, Hz
        Sampling rate of the record (the 10 kHz real-time loop).
    low_frequency_fraction : float in [0, 1)
        Share of the noise variance in a first-order low-pass component with corner ``corner``.
    corner : float, Hz

    Examples
    --------
    >>> round(RECTANGULAR_NOISE.sigma * 1e3, 3)     # mV rms
    1.655
    """

    peak_to_peak: float
    window: float = 5.0
    rate: float = 10e3
    low_frequency_fraction: float = 0.0
    corner: float = 60.0
    _sigma: float = field(init=False, repr=False, compare=False, default=0.0)

    def __post_init__(self) -> None:
        for f in ("peak_to_peak", "window", "rate", "corner"):
            v = float(getattr(self, f))
            if not (math.isfinite(v) and v > 0.0):
                raise InstrumentError(f"{f} must be positive and finite (got {getattr(self, f)!r})")
            object.__setattr__(self, f, v)
        lf = float(self.low_frequency_fraction)
        if not 0.0 <= lf < 1.0:
            raise InstrumentError(f"low_frequency_fraction must be in [0, 1) (got {self.low_frequency_fraction!r})")
        object.__setattr__(self, "low_frequency_fraction", lf)
        object.__setattr__(self, "_sigma", self.peak_to_peak / expected_range(self.samples))

    @property
    def samples(self) -> int:
        """Samples in the reference window."""
        return max(2, int(round(self.window * self.rate)))

    @property
    def sigma(self) -> float:
        """Total rms noise (signal units) giving the specified expected peak-to-peak.

        The low-frequency share is correlated, so it spreads less over the window than white
        noise of the same variance; the calibration below is exact for the white part and treats
        the whole variance as white (conservative: the realised peak-to-peak is slightly lower
        when ``low_frequency_fraction > 0``).
        """
        return self._sigma

    def generate(self, n: int, rng: np.random.Generator, state: float = 0.0) -> tuple[np.ndarray, float]:
        """``n`` samples at ``rate`` and the low-pass state to continue from (seeded, reproducible)."""
        n = int(n)
        s = self.sigma
        white = rng.standard_normal(n) * s * math.sqrt(1.0 - self.low_frequency_fraction)
        if self.low_frequency_fraction == 0.0 or n == 0:
            return white, state
        # exact discretisation of a first-order low-pass driven by white noise (AR(1)),
        # stationary variance lf * sigma^2
        alpha = math.exp(-2.0 * math.pi * self.corner / self.rate)
        drive = rng.standard_normal(n) * s * math.sqrt(self.low_frequency_fraction * (1.0 - alpha * alpha))
        lf, _ = lfilter([1.0], [1.0, -alpha], drive, zi=[alpha * state])
        return white + lf, float(lf[-1])


# [Alabdulmuhsin] Sec. 4 (Fig. 4.4): disengaged vertical signal over 5 s.
RECTANGULAR_NOISE = PhotodiodeNoise(peak_to_peak=0.0140)
# The triangular lever's 0.0195 V includes noise below 60 Hz; its share is not given (assumed 1/2).
TRIANGULAR_NOISE = PhotodiodeNoise(peak_to_peak=0.0195, low_frequency_fraction=0.5, corner=60.0)


#: how far a withdraw backs the micro stage off (the engage's coarse step, [Alabdulmuhsin]), metres
WITHDRAW_COARSE = 0.16e-6


@dataclass(frozen=True)
class InstrumentHistory:
    """Every simulated sample of a run (all arrays of the same length).

    Attributes
    ----------
    time : seconds
    micro, nano, pico : metres, stage positions
    gap : metres, tip-to-surface distance with a straight lever (negative in contact)
    deflection : metres
    force : newtons, true force on the tip (k * deflection)
    signal : normalised vertical photodiode signal (with noise, clipped to [-1, 1])
    x, y : metres, tip position over the sample
    lateral : normalised lateral (torsion) photodiode signal (with noise, clipped to [-1, 1])
    """

    time: np.ndarray
    micro: np.ndarray
    nano: np.ndarray
    pico: np.ndarray
    gap: np.ndarray
    deflection: np.ndarray
    force: np.ndarray
    signal: np.ndarray
    x: np.ndarray
    y: np.ndarray
    lateral: np.ndarray

    def __len__(self) -> int:
        return int(self.time.size)


_FIELDS = ("time", "micro", "nano", "pico", "gap", "deflection", "force", "signal", "x", "y", "lateral")


class VirtualAFM(Instrument):
    """Simulated AFM: the engage procedure, replay-style tests, and the instrument behind the
    simulated Nanonis controller (:mod:`arsurf.instrument.nanonis_sim`).

    Parameters
    ----------
    surface : float, Scan or callable (x, y) -> z
        Sample height under the tip (metres): a constant, a scan (bilinear at the tip, which must
        stay inside it) or a function.
    probe_height : float, metres
        Tip apex height (straight lever) with the PicoCube at 0; with the stages at 0 the gap is
        ``probe_height - surface``. Every stage closes the gap when its position grows: the
        micro and nano stages raise the sample, the PicoCube lowers the probe.
    tip_xy : (2,) float, metres
        Lateral tip position over the sample (moved by :meth:`move_to` on the XY nano stage).
    spring_constant : float, N/m
        Normal stiffness k ([Alabdulmuhsin] Table 4.1: 0.3 N/m).
    deflection_sensitivity : float, metres per signal unit
        S_n: deflection per unit of normalised signal ([Alabdulmuhsin]: 1117 nm/V); its sign is the
        detector's mounting.
    signal_offset : float
        Free-lever signal V_0 (the laser is rarely centred perfectly).
    noise : PhotodiodeNoise
        Noise of both signals (each channel its own seeded stream).
    rate : float, Hz
        Simulation (real-time loop) rate.
    micro, nano, pico, xy : Stage
        Coarse Z, fine Z, probe Z and the lateral stage (both axes).
    seed : int
        Seed of the noise generators.
    friction : float
        Sliding friction coefficient mu of the lateral force (0: no lateral signal).
    lateral_sensitivity : float, newtons per signal unit
        S_l: lateral force per unit of the torsion signal (non-zero; its sign is the mounting).
    lateral_offset : float
        Torsion signal of the free lever.
    setpoint : float
        Deflection signal change the Z feedback and :meth:`engage` hold (signal units, > 0).
    engage_force_limit : float, newtons, optional
        Force limit of the engage procedure.
    keep_history : bool
        Record every sample (:meth:`history`); off for a long-running server.
    sample : imaging.Sample, optional
        What :meth:`scan_image` images (substrate, dent, objects); default: ``surface`` when it
        is a Scan.
    imaging_tip : imaging.TipShape, optional
        The tip that images (default: a 10 nm sphere on a 20 deg cone).
    drift : imaging.ThermalDrift, optional
        The stage's thermal drift (default none); a new velocity every scan.
    scan_settings : imaging.ScanSettings, optional
        The raster :meth:`scan_image` runs by default (default: the whole sample).
    """

    signal_units = ("normalised", "normalised")

    def __init__(self, surface=0.0, *, probe_height: float, tip_xy=(0.0, 0.0), spring_constant: float = 0.3,
                 deflection_sensitivity: float = 1117e-9, signal_offset: float = 0.0,
                 noise: PhotodiodeNoise = RECTANGULAR_NOISE, rate: float = 10e3,
                 micro: Stage = MICRO_STAGE, nano: Stage = NANO_STAGE, pico: Stage = PICOCUBE,
                 xy: Stage = NANO_STAGE_XY, seed: int = 0, friction: float = 0.0,
                 lateral_sensitivity: float = 100e-9, lateral_offset: float = 0.0, setpoint: float = 0.05,
                 engage_force_limit: float | None = 25e-9, keep_history: bool = True, sample=None,
                 imaging_tip=None, drift=None, scan_settings=None) -> None:
        super().__init__()
        xy_ = np.asarray(tip_xy, dtype=np.float64)
        if xy_.shape != (2,) or not np.all(np.isfinite(xy_)):
            raise InstrumentError(f"tip_xy must be (x, y) in metres (got {tip_xy!r})")
        self._surface_source = surface
        self.surface_height = self._surface(surface, float(xy_[0]), float(xy_[1]))
        self.probe_height = self._real("probe_height", probe_height)
        self.tip_xy = xy_
        self.spring_constant = self._real("spring_constant", spring_constant, positive=True)
        s = self._real("deflection_sensitivity", deflection_sensitivity)
        if s == 0.0:
            raise InstrumentError("deflection_sensitivity must be non-zero (metres per signal unit, e.g. 1117e-9)")
        self.deflection_sensitivity = s
        self.signal_offset = self._real("signal_offset", signal_offset)
        if abs(self.signal_offset) >= 1.0:
            raise InstrumentError(f"signal_offset must be within the signal range (-1, 1) (got {signal_offset!r})")
        if not isinstance(noise, PhotodiodeNoise):
            raise InstrumentError(f"noise must be a PhotodiodeNoise (got {type(noise).__name__})")
        self.noise = noise
        self.rate = self._real("rate", rate, positive=True)
        self.stages = {"micro": micro, "nano": nano, "pico": pico}
        self.xy_stage = xy
        self.position = {"micro": 0.0, "nano": 0.0, "pico": 0.0}
        self.friction = self._real("friction", friction)
        if self.friction < 0.0:
            raise InstrumentError(f"friction must be >= 0 (got {friction!r}); it is the sliding coefficient mu")
        ls = self._real("lateral_sensitivity", lateral_sensitivity)
        if ls == 0.0:
            raise InstrumentError("lateral_sensitivity must be non-zero (newtons per signal unit, e.g. 100e-9)")
        self.lateral_sensitivity = ls
        self.lateral_offset = self._real("lateral_offset", lateral_offset)
        if abs(self.lateral_offset) >= 1.0:
            raise InstrumentError(f"lateral_offset must be within the signal range (-1, 1) (got {lateral_offset!r})")
        sp = self._real("setpoint", setpoint)
        if not 0.0 < sp < 1.0:
            raise InstrumentError(f"setpoint must be a signal change in (0, 1) (got {setpoint!r}); e.g. 0.05")
        self.setpoint = sp
        self.engage_force_limit = engage_force_limit
        self.keep_history = bool(keep_history)
        self.time = 0.0
        self._rng = np.random.default_rng(seed)
        self._rng_lateral = np.random.default_rng([seed, 1])  # its own stream: the vertical one is unchanged
        self._noise_state = 0.0
        self._noise_state_lateral = 0.0
        self._chunks: list[tuple[np.ndarray, ...]] = []
        self._imaging = imaging.Imaging(sample if sample is not None else surface, imaging_tip, drift, scan_settings,
                                        seed)

    # -- construction helpers -------------------------------------------------------------------
    @staticmethod
    def _real(name: str, value, positive: bool = False) -> float:
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InstrumentError(f"{name} must be a real number (got {value!r})") from None
        if not math.isfinite(v) or (positive and v <= 0.0):
            raise InstrumentError(f"{name} must be {'positive and ' if positive else ''}finite (got {value!r})")
        return v

    @staticmethod
    def _surface(surface, x: float, y: float) -> float:
        if isinstance(surface, Scan):
            ny, nx = surface.shape
            fx, fy = x / surface.dx, y / surface.dy
            if not (0.0 <= fx <= nx - 1 and 0.0 <= fy <= ny - 1):
                raise InstrumentError(
                    f"tip_xy ({x:.4g}, {y:.4g}) m is outside the scan (0..{surface.size[0]:.4g}, "
                    f"0..{surface.size[1]:.4g}) m; place the tip over the scanned area"
                )
            ix, iy = min(int(fx), max(nx - 2, 0)), min(int(fy), max(ny - 2, 0))
            tx, ty = fx - ix, fy - iy
            h = surface.heights
            ix1, iy1 = min(ix + 1, nx - 1), min(iy + 1, ny - 1)
            z = ((1 - tx) * (1 - ty) * h[iy, ix] + tx * (1 - ty) * h[iy, ix1]
                 + (1 - tx) * ty * h[iy1, ix] + tx * ty * h[iy1, ix1])
        elif callable(surface):
            z = surface(x, y)
        else:
            z = surface
        z = float(z)
        if not math.isfinite(z):
            raise InstrumentError(
                f"the surface height under the tip is not finite ({z!r}); inpaint the scan or move the tip"
            )
        return z

    # -- physics ------------------------------------------------------------------------------------
    def gap(self, micro=None, nano=None, pico=None):
        """Tip-to-surface distance with a straight lever, metres (negative: the lever is bent)."""
        m = self.position["micro"] if micro is None else micro
        n = self.position["nano"] if nano is None else nano
        p = self.position["pico"] if pico is None else pico
        return (self.probe_height - p) - (self.surface_height + m + n)

    def tip_z(self) -> float:
        """Tip apex height (straight lever) in the frame of the sample, metres: the instrument's z."""
        p = self.position
        return self.probe_height - p["pico"] - p["micro"] - p["nano"]

    def _hold(self, surface, micro, nano):
        """PicoCube position(s) at which the Z feedback holds the set point (clipped to its travel)."""
        target = self.probe_height - surface - micro - nano + self.setpoint * abs(self.deflection_sensitivity)
        return np.clip(target, 0.0, self.stages["pico"].travel)

    def _record(self, micro: np.ndarray, nano: np.ndarray, pico: np.ndarray, x=None, y=None, surface=None,
                direction=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Append samples (one per loop tick); returns their vertical and lateral signals.

        ``x``, ``y``, ``surface`` per sample (default: where the tip is); ``direction`` the unit
        vector of the lateral motion (friction acts against it)."""
        n = micro.size
        x = np.full(n, self.tip_xy[0]) if x is None else x
        y = np.full(n, self.tip_xy[1]) if y is None else y
        zs = self.surface_height if surface is None else surface
        g = (self.probe_height - pico) - (zs + micro + nano)
        d = np.maximum(-g, 0.0)
        f = self.spring_constant * d
        noise, self._noise_state = self.noise.generate(n, self._rng, self._noise_state)
        sig = np.clip(self.signal_offset + d / self.deflection_sensitivity + noise, -1.0, 1.0)
        noise_l, self._noise_state_lateral = self.noise.generate(n, self._rng_lateral, self._noise_state_lateral)
        f_lat = -self.friction * f * direction[1]
        lat = np.clip(self.lateral_offset + f_lat / self.lateral_sensitivity + noise_l, -1.0, 1.0)
        t = self.time + np.arange(1, n + 1) / self.rate
        self.time = float(t[-1]) if n else self.time
        if self.keep_history:
            self._chunks.append((t, micro, nano, pico, g, d, f, sig, x, y, lat))
        return sig, lat

    def _heights(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface heights under the tip at each of the points (x, y), metres."""
        src = self._surface_source
        if not (isinstance(src, Scan) or callable(src)):
            return np.full(x.size, float(src))
        return np.array([self._surface(src, float(a), float(b)) for a, b in zip(x, y)])

    # -- operations -----------------------------------------------------------------------------------
    def move(self, stage: str, target: float) -> np.ndarray:
        """Move one stage to ``target`` (rounded to its resolution) along an LSPB profile sampled at
        the loop rate; returns the vertical signal of every tick of the move."""
        if stage not in self.stages:
            raise InstrumentError(f"stage must be one of {sorted(self.stages)} (got {stage!r})")
        st = self.stages[stage]
        profile: LSPB = st.move(self.position[stage], target)
        n = max(1, int(math.ceil(profile.duration * self.rate - 1e-9)))
        t = np.arange(1, n + 1) / self.rate
        q = profile.evaluate(t)[0][:, 0]
        others = {k: np.full(n, v) for k, v in self.position.items()}
        others[stage] = q
        sig, _ = self._record(others["micro"], others["nano"], others["pico"])
        self.position[stage] = float(profile.end[0])
        return sig

    def dwell(self, duration: float) -> np.ndarray:
        """Stay still for ``duration`` seconds; returns the vertical signal of every tick."""
        n = int(round(self._real("duration", duration) * self.rate))
        if n < 1:
            raise InstrumentError(f"duration {duration!r} s is shorter than one tick (1/{self.rate:g} s)")
        self._apply_feedback()
        return self._record(*(np.full(n, self.position[k]) for k in ("micro", "nano", "pico")))[0]

    def _apply_feedback(self) -> None:
        if self._feedback:
            p = self.position
            p["pico"] = float(self._hold(self.surface_height, p["micro"], p["nano"]))

    def history(self) -> InstrumentHistory:
        """Every sample recorded so far."""
        if not self._chunks:
            return InstrumentHistory(*(np.empty(0) for _ in _FIELDS))
        return InstrumentHistory(*(np.concatenate([c[i] for c in self._chunks]) for i in range(len(_FIELDS))))

    def force_from_signal(self, signal, baseline: float):
        """Force estimated from the vertical signal as [Alabdulmuhsin] Eq. 7 does: k S_n (V - V_0)."""
        return self.spring_constant * self.deflection_sensitivity * (np.asarray(signal) - baseline)

    # -- the Instrument interface ------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return "virtual AFM ([Alabdulmuhsin] stages)"

    @property
    def limits(self) -> InstrumentLimits:
        """XY: the lateral stage's travel (and the scan, for a scan surface); z: the tip heights the
        PicoCube reaches with the coarse stages where they are."""
        hi_xy = np.full(2, self.xy_stage.travel)
        src = self._surface_source
        if isinstance(src, Scan):
            hi_xy = np.minimum(hi_xy, [(src.shape[1] - 1) * src.dx, (src.shape[0] - 1) * src.dy])
        p = self.position
        z_top = self.probe_height - p["micro"] - p["nano"]
        speed = min(self.xy_stage.max_velocity, self.stages["pico"].max_velocity)
        return InstrumentLimits((0.0, 0.0, z_top - self.stages["pico"].travel), (hi_xy[0], hi_xy[1], z_top), speed,
                                "the virtual AFM's stages")

    def now(self) -> float:
        """Simulated time, seconds."""
        return self.time

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _read(self, out: InstrumentSample) -> None:
        """One tick: the tip where it is, both signals with fresh noise."""
        self._apply_feedback()
        p = self.position
        sig, lat = self._record(*(np.full(1, p[k]) for k in ("micro", "nano", "pico")))
        out.position[:] = (self.tip_xy[0], self.tip_xy[1], self.tip_z())
        out.signals[0], out.signals[1] = sig[0], lat[0]
        out.timestamp = self.time

    def _move(self, target: np.ndarray, axes: str, wait: bool) -> None:
        """XY on the lateral stage (an LSPB on both axes, the surface and the friction followed
        tick by tick, the feedback holding Z if it is on); Z on the PicoCube. Simulated moves
        always run to their end (``wait`` changes nothing)."""
        if "z" in axes:
            p = self.position
            self.move("pico", self.probe_height - p["micro"] - p["nano"] - target[2])
        if "xy" not in axes:
            return
        st = self.xy_stage
        goal = st.quantize(target[:2])
        start = self.tip_xy.copy()
        profile = LSPB.plan(start, goal, st.max_velocity, st.max_acceleration)
        n = max(1, int(math.ceil(profile.duration * self.rate - 1e-9)))
        path = profile.evaluate(np.arange(1, n + 1) / self.rate)[0]
        x, y = path[:, 0], path[:, 1]
        surface = self._heights(x, y)
        p = self.position
        micro, nano = np.full(n, p["micro"]), np.full(n, p["nano"])
        pico = self._hold(surface, micro, nano) if self._feedback else np.full(n, p["pico"])
        step = goal - start
        length = float(np.hypot(step[0], step[1]))
        direction = (step[0] / length, step[1] / length) if length > 0.0 else (0.0, 0.0)
        self._record(micro, nano, pico, x, y, surface, direction)
        self.tip_xy = np.asarray(goal, dtype=np.float64)
        self.surface_height = float(surface[-1])
        p["pico"] = float(pico[-1])

    def _set_feedback(self, on: bool) -> None:
        self._feedback = on
        self._apply_feedback()

    def _engage(self) -> None:
        """The procedure of [Alabdulmuhsin] (:func:`arsurf.instrument.engage.engage`), then the feedback on,
        with the nano stage's position at contact moved to the PicoCube as its working range."""
        self._feedback = False
        result = engage(self, setpoint=self.setpoint, force_limit=self.engage_force_limit)
        if not result.engaged:
            raise InstrumentError(f"{self.name}: the engage stopped without contact ({result.reason}) after "
                                  f"{result.coarse_steps} coarse and {result.fine_steps} fine steps")
        # give the feedback room both ways: trade the nano stage's travel for the PicoCube's, the
        # sample lowered first (the tip lifts off a little, never presses harder)
        trade = min(self.position["nano"], 0.5 * self.stages["pico"].travel - self.position["pico"])
        if trade > 0.0:
            self.move("nano", self.position["nano"] - trade)
            self.move("pico", self.position["pico"] + trade)
        self._set_feedback(True)

    @property
    def scan_settings(self):
        """The raster :meth:`scan_image` runs without settings (:class:`~arsurf.instrument.imaging.ScanSettings`)."""
        return self._imaging.settings or self._imaging.default_settings()

    def _scan_image(self, settings) -> Scan:
        """One frame of :mod:`arsurf.instrument.imaging` (the instrument's clock moves on by its
        duration); the photodiode noise read as height through the deflection sensitivity."""
        scan = self._imaging.acquire(settings, self.time, self.noise, abs(self.deflection_sensitivity))
        self.time += float(scan.metadata["virtual_afm"]["duration_s"])
        return scan

    def _withdraw(self) -> None:
        """Feedback off; the PicoCube and the nano stage fully retracted and the micro stage backed
        off by one engage step (0.16 um, on its 0.05 um grid): the engage may have found the surface right after a
        coarse step, where retracting the fine stages alone would leave the tip touching."""
        self._feedback = False
        self.move("pico", 0.0)
        self.move("nano", 0.0)
        self.move("micro", max(0.0, self.position["micro"] - WITHDRAW_COARSE))
