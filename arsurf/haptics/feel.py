r"""What the hand feels, scored: buzz, reversals, energy, steps, settling of a force record.

The haptic loop is judged by the force the device applies to the hand, not by its tick time. A
record of device forces :math:`f_k` (N, one row per tick of period :math:`T`) is scored on the
window after ``settle`` seconds (the approach and the start ramp are excluded):

* **high-frequency content**, per axis: the rms of the part of :math:`f` above ``cutoff``
  (100 Hz: above the hand's voluntary bandwidth, ~10 Hz, and where a buzz lives), relative to
  the mean normal force :math:`\bar N = \lVert \bar f \rVert` (the steady push). Computed by
  Parseval's theorem on the real FFT of the linearly detrended window followed by its mirror
  image (the even extension, as a DCT reads a record): the DFT takes a window as one period of
  a periodic record, and a window whose two ends differ (a force that falls slowly as the tip
  slides off a slope) as a jump at the wrap, whose leakage falls only as 1/f (a smooth unloading
  from 20 to 5 mN read as 0.46 % "above 100 Hz", a tip sliding off a ridge of the feel families
  as 6.7 %); the mirrored window has no jump, and its leakage falls as 1/f^2.
* **reversals**, per axis: ticks where the force changes direction of variation with both legs
  larger than ``reversal_fraction`` (1 %) of the peak force norm of the whole record - a
  tick-to-tick zig-zag the hand feels as vibration.
* **energy**: the smallest observed port energy (J) of the passivity observer
  (:mod:`arsurf.haptics.passivity`), when given. An adhesive contact holds a potential well
  below the zero of a tip far away and gives that energy back at snap-in, passively: the loop
  created energy only where :math:`E` goes below :math:`-E_0`, ``energy_reserve`` (the well's
  bound, :meth:`arsurf.model.ARModel.adhesion_energy` at the hand's scale; 0 without adhesion).
  The controller acts one tick after a deficit appears, so dips within 1 % of the record's
  energy scale (its largest |E|) beyond that are not counted.
* **largest step**: the largest tick-to-tick change of the force vector (N), over the whole
  record.
* **settling**: seconds from the first contact tick until the force norm stays within
  ``settle_band`` (5 %) of its final value (the mean of the last 100 ms), when contact is given.

The record *buzzes* when any axis has more than ``buzz_limit`` (2 %) above the cutoff, when there
is any reversal, or when the energy went below ``-energy_tolerance``. Thresholds are those of the
feel targets in docs/feel.rst.

Examples
--------
>>> import numpy as np
>>> t = np.arange(3000) * 1e-3
>>> f = np.zeros((3000, 3)); f[:, 2] = 0.02                      # a steady 20 mN push
>>> score_force(f, 1e-3).buzzes
False
>>> f[:, 0] = 0.002 * np.sin(2 * np.pi * 300 * t)               # plus a 300 Hz, 2 mN buzz
>>> s = score_force(f, 1e-3); s.buzzes, round(float(s.high_frequency[0]), 3)
(True, 0.071)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from arsurf.errors import HapticsError

__all__ = ["FeelScore", "reversal_ticks", "score_force", "session_window_start", "score_session"]

BUZZ_LIMIT = 0.02
REVERSAL_FRACTION = 0.01
ENERGY_TOLERANCE = 1e-2  # of the record's largest |E|
#: the shortest window :func:`score_force` scores, s
MIN_WINDOW = 0.1


@dataclass(frozen=True)
class FeelScore:
    """The feel of a force record (module docstring); SI units.

    ``high_frequency`` (3,) rms above the cutoff / mean normal force; ``reversals`` (3,) counts;
    ``mean_normal`` N; ``peak`` N; ``largest_step`` N; ``min_energy`` J (NaN: not observed);
    ``settle_time`` s (NaN: no contact or never settled); ``window`` s scored, from ``start`` s
    (from the record's first tick); ``buzzes``.
    """

    high_frequency: np.ndarray
    reversals: np.ndarray
    mean_normal: float
    peak: float
    largest_step: float
    min_energy: float
    settle_time: float
    window: float
    buzzes: bool
    start: float = 0.0

    def as_dict(self) -> dict:
        """JSON-ready, units in the keys."""
        return {"high_frequency_over_normal": [float(x) for x in self.high_frequency],
                "reversals": [int(x) for x in self.reversals], "mean_normal_N": self.mean_normal,
                "peak_N": self.peak, "largest_step_N": self.largest_step, "min_energy_J": self.min_energy,
                "settle_time_s": self.settle_time, "window_start_s": self.start, "window_s": self.window,
                "buzzes": self.buzzes}

    def summary(self) -> str:
        """One line for the demo and replay."""
        hf = "/".join(f"{100 * x:.2f}" for x in self.high_frequency)
        verdict = "BUZZES" if self.buzzes else "smooth"
        energy = "n/a" if math.isnan(self.min_energy) else f"{self.min_energy:.3g} J"
        settle = "n/a" if math.isnan(self.settle_time) else f"{1e3 * self.settle_time:.0f} ms"
        return (f"feel: {verdict}; above 100 Hz {hf} % of the mean normal force (x/y/z), "
                f"{int(self.reversals.sum())} reversals, largest step {1e3 * self.largest_step:.3g} mN, "
                f"min energy {energy}, settles in {settle}")


def _reversal_mask(f: np.ndarray, threshold: float) -> np.ndarray:
    """(n - 2, 3) bool: tick k + 1 is a reversal of its axis (both legs above ``threshold``)."""
    d = np.diff(f, axis=0)
    a, b = d[:-1], d[1:]
    return (a * b < 0.0) & (np.minimum(np.abs(a), np.abs(b)) > threshold)


def reversal_ticks(force, dt: float, *, settle: float = 1.0,
                   reversal_fraction: float = REVERSAL_FRACTION) -> np.ndarray:
    """Where :func:`score_force` counts its reversals: (n,) bool, True at a tick where some axis
    of ``force`` ((n, 3) N, every ``dt`` s) changes direction with both legs larger than
    ``reversal_fraction`` of the record's peak force norm, after ``settle`` seconds.

    ``reversal_ticks(f, dt, settle=s).sum()`` is at most ``score_force(f, dt, settle=s).reversals.sum()``
    (ticks where several axes reverse at once count once here).

    Examples
    --------
    >>> f = np.zeros((2000, 3)); f[:, 2] = 0.02; f[1500, 0] = 0.002      # one spike, after 1 s
    >>> np.flatnonzero(reversal_ticks(f, 1e-3)).tolist()
    [1500]
    """
    f = np.asarray(force, dtype=np.float64)
    if f.ndim != 2 or f.shape[1] != 3 or not np.isfinite(f).all():
        raise HapticsError(f"force must be a finite (n, 3) array in newtons (got shape {f.shape})")
    if not (math.isfinite(float(dt)) and float(dt) > 0.0):
        raise HapticsError(f"dt must be a positive period in seconds (got {dt!r})")
    out = np.zeros(f.shape[0], bool)
    peak = float(np.linalg.norm(f, axis=1).max()) if f.shape[0] else 0.0
    start = max(int(round(settle / float(dt))), 0)
    if peak > 0.0 and f.shape[0] - start > 2:
        out[start + 1:-1] = _reversal_mask(f[start:], reversal_fraction * peak).any(axis=1)
    return out


def score_force(force, dt: float, *, settle: float = 1.0, cutoff: float = 100.0, energy=None, contact=None,
                buzz_limit: float = BUZZ_LIMIT, reversal_fraction: float = REVERSAL_FRACTION,
                energy_tolerance: float = ENERGY_TOLERANCE, energy_reserve: float = 0.0,
                settle_band: float = 0.05) -> FeelScore:
    """Score a record of device forces ``force`` (n, 3) N sampled every ``dt`` s.

    ``energy`` (n,) J: the passivity observer's energy per tick (optional; ``energy_tolerance``
    is relative to its largest magnitude, ``energy_reserve`` J the passive store); ``contact`` (n,)
    bool: ticks in contact (optional, for the settling time). Raises :class:`HapticsError` for a
    record that cannot be scored (shape, non-finite values, a window shorter than 0.1 s)."""
    f = np.asarray(force, dtype=np.float64)
    dt = float(dt)
    if f.ndim != 2 or f.shape[1] != 3:
        raise HapticsError(f"force must be an (n, 3) array in newtons (got shape {f.shape})")
    if not (math.isfinite(dt) and dt > 0.0):
        raise HapticsError(f"dt must be a positive period in seconds (got {dt!r})")
    if not np.isfinite(f).all():
        raise HapticsError("the force record holds non-finite values: the device was given no such force")
    start = int(round(settle / dt))
    w = f[start:]
    if w.shape[0] * dt < MIN_WINDOW:
        raise HapticsError(f"the record ({f.shape[0] * dt:.3g} s) leaves less than 0.1 s after {settle} s of "
                           "settling: record longer or settle shorter")
    n = w.shape[0]
    mean_normal = float(np.linalg.norm(w.mean(axis=0)))
    t = np.arange(n) * dt
    trend = np.polynomial.polynomial.polyfit(t, w, 1)
    r = w - (trend[0] + np.outer(t, trend[1]))
    r = np.concatenate([r, r[::-1]])  # its even extension: no jump at the wrap (docstring)
    spec = np.fft.rfft(r, axis=0)
    freq = np.fft.rfftfreq(2 * n, dt)
    hf_rms = np.sqrt(2.0 * (np.abs(spec[freq > cutoff]) ** 2).sum(axis=0)) / (2 * n)
    high = hf_rms / mean_normal if mean_normal > 0.0 else np.where(hf_rms > 0.0, np.inf, 0.0)
    norm = np.linalg.norm(f, axis=1)
    peak = float(norm.max())
    rev = _reversal_mask(w, reversal_fraction * peak).sum(axis=0) if peak > 0.0 else np.zeros(3, np.int64)
    step = float(np.linalg.norm(np.diff(f, axis=0), axis=1).max()) if f.shape[0] > 1 else 0.0
    min_energy = math.nan
    if energy is not None:
        e = np.asarray(energy, dtype=np.float64).reshape(-1)
        if e.shape[0] != f.shape[0]:
            raise HapticsError(f"energy must have one value per tick ({f.shape[0]}), got {e.shape[0]}")
        min_energy = float(np.nanmin(e)) if np.isfinite(e).any() else math.nan
    settle_time = math.nan
    if contact is not None:
        c = np.asarray(contact, dtype=bool).reshape(-1)
        if c.shape[0] != f.shape[0]:
            raise HapticsError(f"contact must have one value per tick ({f.shape[0]}), got {c.shape[0]}")
        if c.any():
            onset = int(np.argmax(c))
            final = norm[-max(1, int(round(0.1 / dt))):].mean()
            outside = np.nonzero(np.abs(norm[onset:] - final) > settle_band * max(final, 1e-300))[0]
            last = onset + (outside[-1] + 1 if outside.size else 0)
            settle_time = (last - onset) * dt if last < f.shape[0] else math.nan
    generated = False
    if not math.isnan(min_energy):
        generated = min_energy < -energy_reserve - energy_tolerance * float(np.nanmax(np.abs(e)))
    buzzes = bool((high > buzz_limit).any() or rev.any() or generated)
    return FeelScore(high_frequency=high, reversals=rev.astype(np.int64), mean_normal=mean_normal, peak=peak,
                     largest_step=step, min_energy=min_energy, settle_time=settle_time, window=n * dt, buzzes=buzzes,
                     start=start * dt)


def session_window_start(n: int, dt: float, contact=None) -> float:
    """Where a session's feel is scored from (s after its first tick): the first contact tick (the
    approach in free space and the start ramp are not felt as buzz), 0 without contact, and never
    later than :data:`MIN_WINDOW` before the end.

    Examples
    --------
    >>> session_window_start(3000, 1e-3, np.arange(3000) >= 1520)
    1.52
    >>> session_window_start(3000, 1e-3), session_window_start(3000, 1e-3, np.arange(3000) >= 2990)
    (0.0, 2.899)
    """
    c = None if contact is None else np.asarray(contact, dtype=bool).reshape(-1)
    first = int(np.argmax(c)) if c is not None and c.any() else 0
    return max(0.0, min(first * dt, (n - 1) * dt - MIN_WINDOW))


def score_session(force, dt: float, *, contact=None, energy=None, energy_reserve: float = 0.0) -> FeelScore | None:
    """The feel of a session: :func:`score_force` on the window from :func:`session_window_start`.

    The one score of a session: the demo prints it and writes it in its summary, the replay
    writes it in its summary and draws it over its flag strip (:mod:`arsurf.replay.plots`).
    Returns None for a record that cannot be scored (wrong shape, non-finite forces, shorter
    than :data:`MIN_WINDOW`) and for one whose ``contact`` holds no contact tick: the criteria are
    shares of the mean normal force, which without contact is only the free lever's noise (in the
    short session of ``arsurf warmup``, ~2 uN at the hand: 232 % "above 100 Hz" of nothing);
    ``energy`` of the wrong shape is left out.

    Examples
    --------
    >>> f = np.zeros((2000, 3)); f[:, 2] = 1e-6 * np.random.default_rng(0).standard_normal(2000)
    >>> score_session(f, 1e-3, contact=np.zeros(2000, bool)) is None
    True
    """
    f = np.asarray(force, dtype=np.float64)
    dt = float(dt)
    n = f.shape[0] if f.ndim == 2 else 0
    if f.ndim != 2 or f.shape[1] != 3 or n < 3 or not np.isfinite(f).all() or not (math.isfinite(dt) and dt > 0.0):
        return None
    c = None if contact is None else np.asarray(contact, dtype=bool)
    if c is not None and not c.any():
        return None  # nothing touched: no normal force to score against
    settle = session_window_start(n, dt, c)
    if (n - round(settle / dt)) * dt < MIN_WINDOW:
        return None
    e = None if energy is None else np.asarray(energy, dtype=np.float64)
    return score_force(f, dt, settle=settle, contact=c if c is not None and c.shape == (n,) else None,
                       energy=e if e is not None and e.shape == (n,) else None, energy_reserve=energy_reserve)
