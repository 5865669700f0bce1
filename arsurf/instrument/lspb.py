r"""Linear Segments with Parabolic Blends (LSPB): smooth point-to-point moves for the stages.

[Alabdulmuhsin] (Sec. 3.4, Fig. 4.6) smooths every step sent to the piezo stages with an LSPB
interpolator so that the stages never see a step input. Each axis accelerates at
:math:`a` for a blend time :math:`t_b`, cruises at :math:`V`, and decelerates at :math:`a`:

.. math::

    q(t) = \begin{cases}
      q_0 + \tfrac12 s a t^2, & 0 \le t < t_b \\
      q_0 + s V (t - t_b/2), & t_b \le t < T - t_b \\
      q_1 - \tfrac12 s a (T - t)^2, & T - t_b \le t \le T
    \end{cases}
    \qquad s = \operatorname{sign}(q_1 - q_0),\ V = a t_b .

The minimum-time move for limits :math:`v_{max}`, :math:`a_{max}` and distance :math:`D` is a
trapezoid with :math:`t_b = v_{max}/a_{max}`, :math:`T = D/v_{max} + v_{max}/a_{max}` when
:math:`D \ge v_{max}^2/a_{max}`, otherwise a triangle with :math:`t_b = \sqrt{D/a_{max}}`,
:math:`T = 2 t_b` that never reaches :math:`v_{max}`. Several axes are synchronised on the slowest
one: each keeps :math:`a_{max}` and lowers its cruise speed to
:math:`V = \tfrac12\big(aT - \sqrt{a^2T^2 - 4aD}\big)` so that all finish together. Position and
velocity are continuous, the acceleration is bounded by :math:`a_{max}`, and the end point is
reached exactly (the last blend is written from :math:`q_1`).

Examples
--------
>>> move = LSPB.plan(0.0, 1e-6, max_velocity=1e-4, max_acceleration=1e-3)
>>> round(move.duration * 1e3, 4), bool(move.triangular[0])   # too short to reach 0.1 mm/s
(63.2456, True)
>>> q, v, a = move.evaluate([0.0, move.duration])
>>> q[:, 0].tolist()
[0.0, 1e-06]
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from arsurf.errors import InstrumentError


def _axes(name: str, value, n: int | None = None, positive: bool = False) -> np.ndarray:
    a = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if a.ndim != 1:
        raise InstrumentError(f"{name} must be a scalar or a 1-D array of axes (got shape {a.shape})")
    if n is not None and a.size not in (1, n):
        raise InstrumentError(f"{name} has {a.size} axes but the move has {n}")
    if not np.all(np.isfinite(a)):
        raise InstrumentError(f"{name} must be finite (got {np.asarray(value).tolist()!r})")
    if positive and np.any(a <= 0.0):
        raise InstrumentError(
            f"{name} must be positive (got {np.asarray(value).tolist()!r}); limits are SI (m/s, m/s^2)"
        )
    return np.broadcast_to(a, (n,)).copy() if n is not None else a


def minimum_duration(distance, max_velocity, max_acceleration) -> np.ndarray:
    """Shortest LSPB duration for each axis (seconds), trapezoid or triangle.

    .. math::

        T = \\frac{D}{v_{max}} + \\frac{v_{max}}{a_{max}}\\ (D \\ge v_{max}^2/a_{max}),
        \\qquad T = 2\\sqrt{D / a_{max}}\\ \\text{otherwise}
    """
    d = np.abs(np.asarray(distance, dtype=np.float64))
    v = np.asarray(max_velocity, dtype=np.float64)
    a = np.asarray(max_acceleration, dtype=np.float64)
    return np.where(d >= v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))


@dataclass(frozen=True)
class LSPB:
    """A planned LSPB move of n synchronised axes (build with :meth:`plan`).

    Attributes
    ----------
    start, end : (n,) float, metres
    duration : float, seconds
        Common duration T.
    blend : (n,) float, seconds
        Blend time t_b of each axis.
    acceleration : (n,) float, m/s^2
        Magnitude used on each axis (its a_max; 0 for an axis that does not move).
    cruise : (n,) float, m/s
        Peak speed V = a t_b of each axis.
    triangular : (n,) bool
        True where the axis never cruises (the move is too short to reach the speed limit).
    """

    start: np.ndarray
    end: np.ndarray
    duration: float
    blend: np.ndarray
    acceleration: np.ndarray
    cruise: np.ndarray
    triangular: np.ndarray

    @classmethod
    def plan(cls, start, end, max_velocity, max_acceleration, duration: float | None = None) -> "LSPB":
        """Plan a move from ``start`` to ``end`` within the limits (minimum time unless ``duration``).

        Parameters
        ----------
        start, end : float or (n,) float, metres
        max_velocity, max_acceleration : float or (n,) float, SI, > 0
        duration : float, seconds, optional
            At least the minimum; a longer move lowers the cruise speeds.

        Returns
        -------
        LSPB

        Raises
        ------
        InstrumentError
            Non-finite positions, non-positive limits, or a duration shorter than the limits allow.
        """
        q0 = _axes("start", start)
        q1 = _axes("end", end)
        if q0.size != q1.size:
            raise InstrumentError(f"start has {q0.size} axes and end {q1.size}; give one value per axis")
        n = q0.size
        vmax = _axes("max_velocity", max_velocity, n, positive=True)
        amax = _axes("max_acceleration", max_acceleration, n, positive=True)
        dist = np.abs(q1 - q0)
        own = minimum_duration(dist, vmax, amax)  # each axis alone
        t_min = float(np.max(own))
        if duration is None:
            T = t_min
        else:
            T = float(duration)
            if not math.isfinite(T) or T < t_min * (1.0 - 1e-12):
                raise InstrumentError(
                    f"duration must be at least {t_min:.6g} s for these limits (got {duration!r}); "
                    "raise the limits or leave duration out for the fastest move"
                )
            T = max(T, t_min)
        moving = dist > 0.0
        a = np.where(moving, amax, 0.0)
        # the axes that set T move in minimum time: closed forms (the quadratic below has a double
        # root for a triangle, where the square root would amplify rounding)
        limiting = moving & (own >= T * (1.0 - 1e-12))
        cruising = dist >= vmax * vmax / amax
        tb_min = np.where(cruising, vmax / amax, np.sqrt(dist / amax))
        # slower axes keep a_max and cruise at V = (aT - sqrt(a^2 T^2 - 4 a D)) / 2, rationalised
        root = np.sqrt(np.maximum(T * T - 4.0 * dist / amax, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            v_sync = np.where(moving, 2.0 * dist / (T + root), 0.0)
        V = np.where(limiting, amax * tb_min, np.minimum(v_sync, vmax))
        V = np.where(moving, V, 0.0)
        tb = np.where(limiting, tb_min, np.where(moving, V / amax, 0.0))
        tri = moving & (2.0 * tb >= T * (1.0 - 1e-12))
        return cls(q0, q1, T, tb, a, V, tri)

    @property
    def axes(self) -> int:
        return int(self.start.size)

    def evaluate(self, t):
        """Position, velocity and acceleration at times ``t`` (clamped to [0, T]).

        Parameters
        ----------
        t : float or (m,) float, seconds

        Returns
        -------
        q, v, a : (m, n) float arrays (metres, m/s, m/s^2); m = 1 for a scalar ``t``.
        """
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if tt.ndim != 1 or not np.all(np.isfinite(tt)):
            raise InstrumentError(f"t must be finite times in seconds, scalar or 1-D (got {t!r})")
        T = self.duration
        tc = np.clip(tt, 0.0, T)[:, None]
        s = np.sign(self.end - self.start)
        a = self.acceleration
        tb = self.blend
        V = self.cruise
        q0, q1 = self.start, self.end
        first = tc < tb
        last = tc > T - tb
        q = np.where(first, q0 + 0.5 * s * a * tc * tc,
                     np.where(last, q1 - 0.5 * s * a * (T - tc) ** 2, q0 + s * V * (tc - 0.5 * tb)))
        v = np.where(first, s * a * tc, np.where(last, s * a * (T - tc), s * V))
        acc = np.where(first, s * a, np.where(last, -s * a, 0.0))
        outside = (tt < 0.0) | (tt > T)
        v = np.where(outside[:, None], 0.0, v)
        acc = np.where(outside[:, None], 0.0, acc)
        if T == 0.0:
            q = np.broadcast_to(q1, q.shape).copy()
        return q, v, acc

    def sample(self, rate: float, include_end: bool = True):
        """Times ``k / rate`` from 0 to T (and T itself) with positions, velocities, accelerations.

        Returns
        -------
        t : (m,) seconds; q, v, a : (m, n)
        """
        r = float(rate)
        if not (math.isfinite(r) and r > 0.0):
            raise InstrumentError(f"rate must be a positive sampling rate in Hz (got {rate!r})")
        t = np.arange(int(math.floor(self.duration * r)) + 1) / r
        if include_end and (t.size == 0 or t[-1] < self.duration):
            t = np.append(t, self.duration)
        return (t, *self.evaluate(t))
