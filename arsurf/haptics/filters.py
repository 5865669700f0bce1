"""Low-pass filters for the haptic force: first order (exact ZOH) and Butterworth (biquads).

The measured force carries photodiode noise that the hand feels and feeds back into the probe
([Alabdulmuhsin] section 4.3), so the force is low-passed before it is rendered.

**First order.** :math:`\\dot y = \\omega_c (x - y)`, :math:`\\omega_c = 2\\pi f_c` ([Alabdulmuhsin] Eq.
31-32). With the input held over a tick of :math:`\\Delta T` (zero-order hold) the exact solution is

.. math:: y_k = y_{k-1} + \\alpha\\,(x_k - y_{k-1}), \\qquad \\alpha = 1 - e^{-\\omega_c \\Delta T},

stable for every cutoff (the pole :math:`e^{-\\omega_c\\Delta T}` lies in (0, 1)). Its step response
:math:`1 - e^{-\\omega_c (k+1)\\Delta T}` is the continuous one, sampled exactly.

**[Alabdulmuhsin] Eq. 34 is not that.** The thesis discretises with forward Euler,
:math:`y_{k+1} = (1 - \\omega_c\\Delta T) y_k + \\omega_c\\Delta T\\, x_k`, whose pole
:math:`1 - \\omega_c\\Delta T` leaves the unit circle for :math:`\\omega_c\\Delta T > 2`, and rings
(alternates sign) for :math:`\\omega_c\\Delta T > 1`. The thesis' own setting, :math:`f_c` = 5 kHz at
10 kHz, gives :math:`\\omega_c\\Delta T = \\pi`: the filter diverges. :func:`check_forward_euler`
refuses it (docs/design.rst, "Known errors in the sources").

**Second order.** A Butterworth low-pass of order 2 (one biquad; any order as cascaded
second-order sections) designed by :func:`scipy.signal.butter` with the bilinear transform
prewarped at the cutoff, so its frequency response is exactly

.. math:: |H(e^{j\\omega\\Delta T})|^2 = \\frac{1}{1 + \\left(\\tan(\\omega\\Delta T/2)/\\tan(\\omega_c\\Delta T/2)\\right)^{2n}} .

Kernels take plain float64 arrays and return the loop stages' flag bits (:mod:`arsurf.status`): 0, or
``NONFINITE`` when the input had a non-finite value
(the filter then holds its previous output and keeps its state, so NaN never enters the state).

Examples
--------
>>> f = LowPass(cutoff=100.0, dt=1e-3)
>>> y = f.step([1.0, 0.0, 0.0])
>>> round(float(y[0]), 6) == round(1 - math.exp(-2 * math.pi * 100.0 * 1e-3), 6)
True
"""
from __future__ import annotations

import math
import warnings

import numpy as np
from numba import njit

from arsurf import _validation, status
from arsurf.errors import HapticsError
from arsurf.errors import HapticsWarning

__all__ = [
    "ButterworthLowPass",
    "LowPass",
    "check_forward_euler",
    "forward_euler_pole",
    "lowpass1_step",
    "lowpass_alpha",
    "sos_step",
]

_OK = 0
_NONFINITE = status.NONFINITE


def _positive(value, name: str, unit: str, hint: str) -> float:
    return _validation.positive(value, name, HapticsError, unit=unit, hint=hint)


def lowpass_alpha(cutoff: float, dt: float) -> float:
    """Smoothing factor of the exact (ZOH) first-order low-pass.

    .. math:: \\alpha = 1 - e^{-2\\pi f_c \\Delta T}

    Parameters
    ----------
    cutoff : float, Hz
        -3 dB frequency :math:`f_c` of the continuous filter.
    dt : float, s
        Sampling period :math:`\\Delta T`.

    Examples
    --------
    >>> round(lowpass_alpha(5000.0, 1e-4), 6)   # [Alabdulmuhsin]'s 5 kHz at 10 kHz: stable, alpha < 1
    0.956786
    """
    fc = _positive(cutoff, "cutoff", "Hz", "it is the -3 dB frequency of the filter")
    dt = _positive(dt, "dt", "s", "it is the sampling period (1e-3 for 1 kHz)")
    return -math.expm1(-2.0 * math.pi * fc * dt)


def forward_euler_pole(cutoff: float, dt: float) -> float:
    """Pole of [Alabdulmuhsin]'s forward-Euler low-pass (Eq. 34): :math:`1 - 2\\pi f_c\\Delta T`.

    Stable iff the pole is inside the unit circle, i.e. :math:`0 < \\omega_c\\Delta T < 2`.

    Examples
    --------
    >>> round(forward_euler_pole(5000.0, 1e-4), 6)   # the thesis' setting: -(pi - 1)
    -2.141593
    """
    fc = _positive(cutoff, "cutoff", "Hz", "it is the -3 dB frequency of the filter")
    dt = _positive(dt, "dt", "s", "it is the sampling period")
    return 1.0 - 2.0 * math.pi * fc * dt


def check_forward_euler(cutoff: float, dt: float, on_unstable: str = "raise") -> float:
    """Check [Alabdulmuhsin]'s forward-Euler low-pass (Eq. 34) for stability; return :math:`\\omega_c\\Delta T`.

    - :math:`\\omega_c\\Delta T \\ge 2`: the pole :math:`1-\\omega_c\\Delta T` is on or outside the
      unit circle, the output oscillates with growing (or constant) amplitude: raises
      :class:`~arsurf.errors.HapticsError` (or warns, with ``on_unstable="warn"``).
    - :math:`1 < \\omega_c\\Delta T < 2`: stable but the pole is negative, the output alternates
      sign around its target: warns :class:`HapticsWarning`.

    Parameters
    ----------
    cutoff : float, Hz
    dt : float, s
    on_unstable : {"raise", "warn"}

    Returns
    -------
    float
        :math:`\\omega_c\\Delta T`.

    Examples
    --------
    >>> check_forward_euler(5000.0, 1e-4)
    Traceback (most recent call last):
    ...
    arsurf.errors.HapticsError: forward-Euler low-pass is unstable: w_c*dT = 2*pi*5000 Hz*0.0001 s = 3.1416 >= 2 (pole 1 - w_c*dT = -2.142 is outside the unit circle; [Alabdulmuhsin] Eq. 34 at its own 5 kHz / 10 kHz setting); use LowPass(method='zoh') (alpha = 1 - exp(-w_c*dT)), or cutoff < 3183.1 Hz at this rate
    """
    if on_unstable not in ("raise", "warn"):
        raise HapticsError(f"on_unstable must be 'raise' or 'warn' (got {on_unstable!r})")
    pole = forward_euler_pole(cutoff, dt)
    wdt = 1.0 - pole
    if wdt >= 2.0:
        limit = 2.0 / (2.0 * math.pi * dt)
        msg = (
            f"forward-Euler low-pass is unstable: w_c*dT = 2*pi*{cutoff:g} Hz*{dt:g} s = {wdt:.4f} >= 2 "
            f"(pole 1 - w_c*dT = {pole:.3f} is outside the unit circle; [Alabdulmuhsin] Eq. 34 at its own "
            f"5 kHz / 10 kHz setting); use LowPass(method='zoh') (alpha = 1 - exp(-w_c*dT)), "
            f"or cutoff < {limit:.1f} Hz at this rate"
        )
        if on_unstable == "raise":
            raise HapticsError(msg)
        warnings.warn(msg, HapticsWarning, stacklevel=2)
    elif wdt > 1.0:
        warnings.warn(
            f"forward-Euler low-pass rings: w_c*dT = {wdt:.4f} > 1 gives a negative pole ({pole:.3f}), "
            "the output alternates sign around its target; use LowPass(method='zoh')",
            HapticsWarning,
            stacklevel=2,
        )
    return wdt


@njit(cache=True)
def lowpass1_step(alpha, y, x, out):
    """One tick of the first-order low-pass on every channel: y += alpha (x - y); out = y.

    Parameters: ``alpha`` float, ``y`` (n,) state (updated), ``x`` (n,) input, ``out`` (n,) output.
    Returns 0, or 1 if ``x`` had a non-finite value (state kept, out = previous output) or the
    state overflowed (state and output reset to zero: the filter recovers at the next tick).
    """
    n = y.shape[0]
    for i in range(n):
        if not math.isfinite(x[i]):
            for j in range(n):
                out[j] = y[j]
            return _NONFINITE
    for i in range(n):
        y[i] += alpha * (x[i] - y[i])
        out[i] = y[i]
    for i in range(n):
        if not math.isfinite(y[i]):  # finite inputs that overflow (1e308 - (-1e308)): restart from rest
            for j in range(n):
                y[j] = 0.0
                out[j] = 0.0
            return _NONFINITE
    return _OK


@njit(cache=True)
def sos_step(sos, zi, last, x, out):
    """One tick of a cascade of second-order sections (transposed direct form II) per channel.

    Parameters: ``sos`` (ns, 6) coefficients [b0, b1, b2, 1, a1, a2]; ``zi`` (ns, n, 2) state
    (updated); ``last`` (n,) previous output (updated); ``x`` (n,) input; ``out`` (n,) output.
    Returns 0, or 1 if ``x`` had a non-finite value (state kept, out = previous output) or the
    state overflowed (state and output reset to zero: the filter recovers at the next tick).
    """
    n = x.shape[0]
    for i in range(n):
        if not math.isfinite(x[i]):
            for j in range(n):
                out[j] = last[j]
            return _NONFINITE
    ns = sos.shape[0]
    for c in range(n):
        v = x[c]
        for s in range(ns):
            b0 = sos[s, 0]
            b1 = sos[s, 1]
            b2 = sos[s, 2]
            a1 = sos[s, 4]
            a2 = sos[s, 5]
            y = b0 * v + zi[s, c, 0]
            zi[s, c, 0] = b1 * v - a1 * y + zi[s, c, 1]
            zi[s, c, 1] = b2 * v - a2 * y
            v = y
        out[c] = v
        last[c] = v
    return _OK


def _channels(channels) -> int:
    try:
        n = int(channels)
    except (TypeError, ValueError) as exc:
        raise HapticsError(f"channels must be a positive integer (got {channels!r})") from exc
    if n < 1 or n != channels:
        raise HapticsError(f"channels must be a positive integer (got {channels!r}); 3 for a force vector")
    return n


class LowPass:
    """First-order low-pass on ``channels`` signals (a force vector by default).

    Parameters
    ----------
    cutoff : float, Hz
        -3 dB frequency :math:`f_c`.
    dt : float, s
        Sampling period.
    channels : int
        Number of signals filtered together (3 for a force).
    method : {"zoh", "forward_euler"}
        ``"zoh"`` (default): exact discretisation, :math:`\\alpha = 1 - e^{-\\omega_c\\Delta T}`,
        stable for every cutoff. ``"forward_euler"``: [Alabdulmuhsin] Eq. 34,
        :math:`\\alpha = \\omega_c\\Delta T`, for comparisons only; refused when unstable
        (:func:`check_forward_euler`).
    initial : float or (channels,)
        Initial output (the filter starts at rest there).

    Attributes
    ----------
    alpha : float
        Smoothing factor.
    state : (channels,) float64
        Current output; pass it with ``alpha`` to :func:`lowpass1_step` inside a compiled tick.
    nonfinite : int
        Number of ticks whose input was not finite (output held).

    Examples
    --------
    >>> f = LowPass(cutoff=50.0, dt=1e-3)
    >>> for _ in range(1000):
    ...     y = f.step([2.0, -1.0, 0.5])
    >>> y.round(9).tolist()
    [2.0, -1.0, 0.5]
    """

    def __init__(self, cutoff: float, dt: float, channels: int = 3, method: str = "zoh", initial=0.0) -> None:
        if method == "zoh":
            alpha = lowpass_alpha(cutoff, dt)
        elif method == "forward_euler":
            alpha = check_forward_euler(cutoff, dt, on_unstable="raise")
        else:
            raise HapticsError(f"method must be 'zoh' or 'forward_euler' (got {method!r})")
        self.cutoff = float(cutoff)
        self.dt = float(dt)
        self.method = method
        self.alpha = float(alpha)
        self.channels = _channels(channels)
        self.state = np.zeros(self.channels)
        self._out = np.zeros(self.channels)
        self.nonfinite = 0
        self.reset(initial)

    @property
    def pole(self) -> float:
        """Pole of the discrete filter, :math:`1 - \\alpha`."""
        return 1.0 - self.alpha

    def reset(self, value=0.0) -> None:
        """Put the filter at rest at ``value`` (scalar or (channels,))."""
        v = np.broadcast_to(np.asarray(value, dtype=np.float64), (self.channels,))
        if not np.isfinite(v).all():
            raise HapticsError(f"reset value must be finite (got {np.asarray(value).tolist()})")
        self.state[:] = v

    def step(self, x, out: np.ndarray | None = None) -> np.ndarray:
        """Filter one sample ``x`` (channels,); returns the output (``out`` if given, else a copy)."""
        xa = x if isinstance(x, np.ndarray) and x.dtype == np.float64 else np.asarray(x, dtype=np.float64)
        if xa.shape != (self.channels,):
            raise HapticsError(f"input must have shape ({self.channels},) (got {xa.shape})")
        o = self._out if out is None else out
        if lowpass1_step(self.alpha, self.state, xa, o):
            self.nonfinite += 1
        return o.copy() if out is None else o

    def frequency_response(self, frequency) -> np.ndarray:
        """Exact complex response of the discrete filter at ``frequency`` (Hz).

        .. math:: H(e^{j\\omega\\Delta T}) = \\frac{\\alpha}{1 - (1-\\alpha)e^{-j\\omega\\Delta T}}
        """
        z1 = np.exp(-2j * np.pi * np.asarray(frequency, dtype=np.float64) * self.dt)
        return self.alpha / (1.0 - (1.0 - self.alpha) * z1)


class ButterworthLowPass:
    """Butterworth low-pass (order 2 = one biquad) on ``channels`` signals, run in a numba kernel.

    Coefficients from :func:`scipy.signal.butter` (bilinear transform prewarped at the cutoff);
    the state lives in plain arrays so a compiled tick can call :func:`sos_step` directly.

    Parameters
    ----------
    cutoff : float, Hz
        -3 dB frequency, strictly below the Nyquist frequency :math:`1/(2\\Delta T)`.
    dt : float, s
        Sampling period.
    channels : int
        Signals filtered together (3 for a force).
    order : int
        Filter order (default 2); odd orders add a first-order section.
    initial : float or (channels,)
        Initial output; the filter starts in the steady state at that value.

    Examples
    --------
    >>> f = ButterworthLowPass(cutoff=10.0, dt=1e-3)
    >>> ys = [float(f.step([1.0, 1.0, 1.0])[0]) for _ in range(1000)]
    >>> round(max(ys), 3), round(ys[-1], 6)   # 4.3 % overshoot of a 2nd-order Butterworth
    (1.043, 1.0)
    """

    def __init__(self, cutoff: float, dt: float, channels: int = 3, order: int = 2, initial=0.0) -> None:
        from scipy import signal

        fc = _positive(cutoff, "cutoff", "Hz", "it is the -3 dB frequency of the filter")
        dt = _positive(dt, "dt", "s", "it is the sampling period")
        nyq = 0.5 / dt
        if fc >= nyq:
            raise HapticsError(
                f"cutoff must be below the Nyquist frequency 1/(2 dt) = {nyq:g} Hz (got {fc:g} Hz); "
                "a digital low-pass cannot cut above it: lower the cutoff or raise the rate"
            )
        if not isinstance(order, (int, np.integer)) or not (1 <= order <= 8):
            raise HapticsError(f"order must be an integer in 1..8 (got {order!r}); 2 is one biquad")
        self.cutoff, self.dt, self.order = fc, dt, int(order)
        self.channels = _channels(channels)
        self.sos = np.ascontiguousarray(signal.butter(self.order, fc, btype="low", fs=1.0 / dt, output="sos"))
        self._zi_unit = signal.sosfilt_zi(self.sos)  # (ns, 2) steady state for a unit input
        self.state = np.zeros((self.sos.shape[0], self.channels, 2))
        self.last = np.zeros(self.channels)
        self._out = np.zeros(self.channels)
        self.nonfinite = 0
        self.reset(initial)

    def reset(self, value=0.0) -> None:
        """Put the filter in its steady state at ``value`` (scalar or (channels,))."""
        v = np.broadcast_to(np.asarray(value, dtype=np.float64), (self.channels,))
        if not np.isfinite(v).all():
            raise HapticsError(f"reset value must be finite (got {np.asarray(value).tolist()})")
        self.state[:] = self._zi_unit[:, None, :] * v[None, :, None]
        self.last[:] = v

    def step(self, x, out: np.ndarray | None = None) -> np.ndarray:
        """Filter one sample ``x`` (channels,); returns the output (``out`` if given, else a copy)."""
        xa = x if isinstance(x, np.ndarray) and x.dtype == np.float64 else np.asarray(x, dtype=np.float64)
        if xa.shape != (self.channels,):
            raise HapticsError(f"input must have shape ({self.channels},) (got {xa.shape})")
        o = self._out if out is None else out
        if sos_step(self.sos, self.state, self.last, xa, o):
            self.nonfinite += 1
        return o.copy() if out is None else o

    def frequency_response(self, frequency) -> np.ndarray:
        """Complex response of the discrete cascade at ``frequency`` (Hz), from its coefficients."""
        z1 = np.exp(-2j * np.pi * np.asarray(frequency, dtype=np.float64) * self.dt)
        h = np.ones_like(z1)
        for b0, b1, b2, _, a1, a2 in self.sos:
            h = h * (b0 + b1 * z1 + b2 * z1 * z1) / (1.0 + a1 * z1 + a2 * z1 * z1)
        return h
