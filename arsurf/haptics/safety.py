"""The safety layer: the one gate every force passes through on its way to the device.

One call of :func:`safety_step` per servo tick turns the force the algorithms want into the force
the device gets. In order:

1. **Non-finite input** (NaN/inf in any component): the output is zero at once, the engagement
   gain drops to zero (so the force comes back through the start-up ramp), flag :data:`NONFINITE`.
   NaN never reaches a device.
2. **Watchdog**: the loop's clock ``now`` must advance by about one period ``dt`` per call. A gap
   longer than ``miss_factor * dt`` counts :math:`\\mathrm{round}(gap/dt) - 1` missed deadlines (a
   non-advancing or non-finite clock counts too). The misses fill a leaky bucket (the meter of
   J. S. Turner, *New directions in communications*, IEEE Communications Magazine, October 1986)
   that each on-time tick drains by ``max_misses / recover_ticks``: when it holds ``max_misses``
   the watchdog trips (:data:`WATCHDOG`), and it re-arms when the bucket is empty again
   (``recover_ticks`` on-time ticks after a trip). A burst of misses or one stall of
   ``max_misses + 1`` periods trips at once; a steady share of late ticks below
   :math:`r/(1+r)`, :math:`r` = ``max_misses / recover_ticks`` (9 % by default), never does.
3. **Stale sensor data**: the device sample is older than ``stale_after`` (or its age is not
   finite): :data:`STALE`.
4. **Disengage button**: a button in ``disengage_mask`` is held: :data:`DISENGAGED`.
5. Any of 2-4 is a *fault*: the last output is frozen and faded to zero linearly in ``stop_time``
   (zero at once if ``stop_time = 0``); the input is ignored. Without a fault the engagement gain
   :math:`g` rises linearly from where it is to 1 in ``ramp_time`` (the start-up ramp: no jolt
   when the coupling engages, after start-up and after every fault), except that it goes to 1 at
   once while the wanted force is no larger than ``free_force`` (free space: there is nothing to
   jolt, and a gain that grows while a contact is loaded scales a stored force up, which gives
   the hand energy; engaging in free space keeps a loop that starts out of contact passive), and

   .. math::

      f = g\\,F_{in}, \\quad f \\leftarrow f\\,\\min\\!\\left(1, \\frac{F_{max}}{\\lVert f\\rVert}\\right),
      \\quad f \\leftarrow f_{prev} + \\Delta\\,\\min\\!\\left(1, \\frac{\\dot F_{max}\\,\\Delta t}{\\lVert\\Delta\\rVert}\\right),
      \\ \\Delta = f - f_{prev}

   (saturation of the vector norm at the device's maximum force, :data:`SATURATED`; rate limit,
   :data:`RATE_LIMITED`; :data:`RAMPING` while :math:`0 < g < 1`).

The rate-limited force lies between two forces of norm at most :math:`F_{max}`, so by convexity
the output never exceeds :math:`F_{max}`; a final check enforces it against rounding. The kernel
allocates nothing and never raises; :class:`SafetyLayer` validates the settings once.

Limits: 7.9 N for a Touch X ([Alabdulmuhsin]), 6 N as [Bolopion] saturates its Virtuose.

Examples
--------
>>> s = SafetyLayer(max_force=6.0, dt=1e-3, ramp_time=0.0, max_rate=1e9)
>>> s.step([10.0, 0.0, 0.0], now=0.0).tolist(), s.flag_names()
([6.0, 0.0, 0.0], ['SATURATED'])
>>> s.step([float("nan"), 0.0, 0.0], now=1e-3).tolist(), s.flag_names()
([0.0, 0.0, 0.0], ['NONFINITE'])
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf import status
from arsurf._layout import Layout
from arsurf.errors import HapticsError
from arsurf.haptics.device import BUTTON_1, DeviceInfo

__all__ = [
    "DISENGAGED",
    "FLAG_NAMES",
    "NONFINITE",
    "RAMPING",
    "RATE_LIMITED",
    "SAFETY_PARAMS",
    "SAFETY_STATE",
    "SATURATED",
    "STALE",
    "WATCHDOG",
    "SafetyLayer",
    "safety_step",
]

# flags (one table for all loop stages: arsurf.status)
SATURATED = status.SATURATED  #: force norm clamped to max_force
RATE_LIMITED = status.RATE_LIMITED  #: force change limited to max_rate * dt
RAMPING = status.RAMPING  #: engagement gain between 0 and 1 (start-up / re-engage ramp or fault fade-out)
STALE = status.STALE  #: device sample older than stale_after
WATCHDOG = status.WATCHDOG  #: the loop missed its deadlines repeatedly
DISENGAGED = status.DISENGAGED  #: disengage button held
NONFINITE = status.NONFINITE  #: NaN/inf in the input force: zero output
FLAG_NAMES = status.FLAG_NAMES[:7]  # the safety layer's flags: the seven lowest bits

#: the parameters of :func:`safety_step` (:class:`SafetyLayer` arguments): max_force (N), max_rate
#: (N/s), ramp_time, stop_time, stale_after, dt (s), miss_factor, max_misses, recover_ticks,
#: disengage_mask (a button bitmask as a float), free_force (N)
SAFETY_PARAMS = Layout("safety parameters", [
    ("max_force", 1), ("max_rate", 1), ("ramp_time", 1), ("stop_time", 1), ("stale_after", 1), ("dt", 1),
    ("miss_factor", 1), ("max_misses", 1), ("recover_ticks", 1), ("disengage_mask", 1), ("free_force", 1)])
#: its state: the last output and the output frozen at a fault (N), the engagement gain, the last
#: clock reading (s; NaN: none), the bucket of missed deadlines, watchdog tripped, in a fault (0
#: or 1), then one counter per flag bit (:data:`FLAG_NAMES`)
SAFETY_STATE = Layout("safety state", [
    ("force", 3), ("held", 3), ("gain", 1), ("last_now", 1), ("misses", 1), ("tripped", 1),
    ("fault", 1), ("counts", len(FLAG_NAMES))])
# the offsets as the kernel uses them
_P_FMAX, _P_RATE, _P_RAMP, _P_STOP, _P_STALE, _P_DT, _P_MISSF, _P_MAXMISS, _P_RECOVER, _P_MASK, _P_FREE = (
    SAFETY_PARAMS.offset(f) for f in SAFETY_PARAMS.fields)
_S_F, _S_HOLD, _S_GAIN = SAFETY_STATE.offset("force"), SAFETY_STATE.offset("held"), SAFETY_STATE.offset("gain")
_S_LAST_NOW, _S_MISS = SAFETY_STATE.offset("last_now"), SAFETY_STATE.offset("misses")
_S_WD, _S_FAULT, _S_COUNT = SAFETY_STATE.offset("tripped"), SAFETY_STATE.offset("fault"), SAFETY_STATE.offset("counts")
_N_COUNTS = SAFETY_STATE.width("counts")
_FAULTS = STALE | WATCHDOG | DISENGAGED


@njit(cache=True)
def safety_step(params, state, force, now, age, buttons, out):
    """One tick of the safety layer (see the module docstring); returns the flags.

    Parameters: ``params`` (:data:`SAFETY_PARAMS`) settings, ``state`` (:data:`SAFETY_STATE`) memory
    (updated), ``force`` (3,) N wanted, ``now`` s loop clock, ``age`` s age of the device sample,
    ``buttons`` int, ``out`` (3,) N to send.
    """
    fmax = params[_P_FMAX]
    dt = params[_P_DT]
    flags = 0
    # 2. watchdog on the loop clock: a leaky bucket of missed deadlines
    missed = 0.0
    if not math.isfinite(now):
        missed = 1.0
    else:
        last = state[_S_LAST_NOW]
        if math.isfinite(last):
            gap = now - last
            if gap > params[_P_MISSF] * dt or gap <= 0.0:
                missed = 1.0
                if gap > 0.0:
                    missed = max(1.0, math.floor(gap / dt + 0.5) - 1.0)
        state[_S_LAST_NOW] = now
    # the bucket in units of 1/recover_ticks of a miss (integers: exact): a miss adds recover_ticks,
    # an on-time tick drains max_misses; full (max_misses misses) trips, empty re-arms
    full = params[_P_MAXMISS] * params[_P_RECOVER]
    if missed > 0.0:
        state[_S_MISS] = min(full, state[_S_MISS] + missed * params[_P_RECOVER])
        if state[_S_MISS] >= full:
            state[_S_WD] = 1.0
    else:
        state[_S_MISS] = max(0.0, state[_S_MISS] - params[_P_MAXMISS])
        if state[_S_MISS] <= 0.0:
            state[_S_WD] = 0.0
    if state[_S_WD] != 0.0:
        flags |= WATCHDOG
    # 3. stale sample (NaN age is stale, and so is a sample from the future: its clock is wrong)
    if not (0.0 <= age <= params[_P_STALE]):
        flags |= STALE
    # 4. disengage button
    if (buttons & int(params[_P_MASK])) != 0:
        flags |= DISENGAGED
    # 1. non-finite input: zero now, restart the ramp
    finite = math.isfinite(force[0]) and math.isfinite(force[1]) and math.isfinite(force[2])
    if not finite:
        flags |= NONFINITE
        for j in range(3):
            out[j] = 0.0
            state[_S_F + j] = 0.0
            state[_S_HOLD + j] = 0.0
        state[_S_GAIN] = 0.0
        state[_S_FAULT] = 1.0
    elif (flags & _FAULTS) != 0:
        # 5. fault: fade the frozen last output to zero in stop_time
        if state[_S_FAULT] == 0.0:
            for j in range(3):
                state[_S_HOLD + j] = state[_S_F + j]
            state[_S_FAULT] = 1.0
        g = state[_S_GAIN]
        stop = params[_P_STOP]
        if stop > 0.0:
            g -= dt / stop
        else:
            g = 0.0
        if g < 0.0:
            g = 0.0
        state[_S_GAIN] = g
        if g > 0.0:
            flags |= RAMPING
        for j in range(3):
            out[j] = state[_S_HOLD + j] * g
    else:
        state[_S_FAULT] = 0.0
        f0 = force[0]
        f1 = force[1]
        f2 = force[2]
        n = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        g = state[_S_GAIN]
        ramp = params[_P_RAMP]
        if ramp > 0.0 and n > params[_P_FREE]:
            g += dt / ramp
        else:
            g = 1.0
        if g > 1.0:
            g = 1.0
        state[_S_GAIN] = g
        if g < 1.0:
            flags |= RAMPING
        # saturate first, then ramp: the ramp bounds the force actually commanded (g x fmax)
        if n > fmax:
            s = fmax / n
            f0 *= s
            f1 *= s
            f2 *= s
            flags |= SATURATED
        f0 *= g
        f1 *= g
        f2 *= g
        d0 = f0 - state[_S_F]
        d1 = f1 - state[_S_F + 1]
        d2 = f2 - state[_S_F + 2]
        dn = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        lim = params[_P_RATE] * dt
        if dn > lim:
            s = lim / dn
            f0 = state[_S_F] + d0 * s
            f1 = state[_S_F + 1] + d1 * s
            f2 = state[_S_F + 2] + d2 * s
            flags |= RATE_LIMITED
        out[0] = f0
        out[1] = f1
        out[2] = f2
    # final guard against rounding: never above fmax
    n = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    if n > fmax:
        s = (fmax / n) * (1.0 - 4.0e-16)
        for j in range(3):
            out[j] *= s
    for j in range(3):
        state[_S_F + j] = out[j]
    for b in range(_N_COUNTS):
        if (flags >> b) & 1:
            state[_S_COUNT + b] += 1.0
    return flags


def _num(value, name: str, *, positive: bool = False, nonneg: bool = False, finite: bool = True, unit: str = "") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise HapticsError(f"{name} must be a number{' in ' + unit if unit else ''} (got {value!r})") from exc
    if math.isnan(v) or (finite and math.isinf(v)):
        raise HapticsError(f"{name} must be finite (got {value!r} {unit})")
    if positive and not v > 0:
        raise HapticsError(f"{name} must be positive (got {value!r} {unit})")
    if nonneg and not v >= 0:
        raise HapticsError(f"{name} must be >= 0 (got {value!r} {unit})")
    return v


class SafetyLayer:
    """Saturation, start-up ramp, rate limit, stale-data and deadline watchdog, disengage button.

    Parameters
    ----------
    max_force : float, N
        Saturation of the force norm (the device's maximum, e.g. 7.9 N for a Touch X).
    dt : float, s
        Nominal loop period; ramps advance by ``dt`` per call.
    max_rate : float, N/s
        Largest change of the rendered force per second (default 1000 N/s: 7.9 N in 8 ms; a
        design choice, not from the seeds).
    ramp_time : float, s
        Time for the engagement gain to go from 0 to 1 (default 0.5 s).
    free_force : float, N, optional
        A wanted force no larger than this is free space: the engagement gain goes to 1 at once
        (default ``max_rate * dt``, the step the rate limit lets through anyway; 0 when the rate
        is unlimited).
    stop_time : float, s
        Time to fade the force to zero on a fault (default 0: at once, within the faulty tick, as
        the project promises; a few ms softens the stop for a hand that is known to be holding on).
    stale_after : float, s
        A device sample older than this is stale (default 0.02 s).
    miss_factor : float
        A clock gap above ``miss_factor * dt`` is a missed deadline (default 1.5).
    max_misses : int
        Missed deadlines in the watchdog's bucket that trip it (default 10).
    recover_ticks : int
        On-time ticks that empty a full bucket and re-arm a tripped watchdog (default 100); each
        drains ``max_misses / recover_ticks`` misses.
    disengage_mask : int
        Buttons that disengage the force (default :data:`~arsurf.haptics.device.BUTTON_1`, seed
        001: "pressing the stylus button temporarily disables the force"); 0: none.

    Attributes
    ----------
    params, state : float64 arrays
        Arguments of :func:`safety_step` for a compiled tick.
    flags : int
        Flags of the last :meth:`step`.

    Examples
    --------
    >>> s = SafetyLayer(max_force=7.9, dt=1e-3, ramp_time=0.01)
    >>> [round(float(s.step([0, 0, 5.0], now=k * 1e-3)[2]), 2) for k in range(4)]   # start-up ramp
    [0.5, 1.0, 1.5, 2.0]
    >>> s.reset(); [round(float(s.step([0, 0, f], now=k * 1e-3)[2]), 2) for k, f in enumerate([0, 5, 5])]   # free space: engaged at once; then the rate limit (1 N per tick)
    [0.0, 1.0, 2.0]
    """

    def __init__(self, max_force: float, dt: float, *, max_rate: float = 1000.0, ramp_time: float = 0.5,
                 free_force: float | None = None, stop_time: float = 0.0, stale_after: float = 0.02, miss_factor: float = 1.5,
                 max_misses: int = 10, recover_ticks: int = 100, disengage_mask: int = BUTTON_1) -> None:
        p = SAFETY_PARAMS.zeros()
        p[_P_FMAX] = _num(max_force, "max_force", positive=True, unit="N")
        p[_P_DT] = _num(dt, "dt", positive=True, unit="s")
        p[_P_RATE] = _num(max_rate, "max_rate", positive=True, finite=False, unit="N/s")
        p[_P_RAMP] = _num(ramp_time, "ramp_time", nonneg=True, unit="s")
        p[_P_STOP] = _num(stop_time, "stop_time", nonneg=True, unit="s")
        p[_P_STALE] = _num(stale_after, "stale_after", positive=True, finite=False, unit="s")
        mf = _num(miss_factor, "miss_factor", positive=True)
        if mf < 1.0:
            raise HapticsError(f"miss_factor must be >= 1 (got {miss_factor!r}); a gap of one period is on time")
        p[_P_MISSF] = mf
        for name, v in (("max_misses", max_misses), ("recover_ticks", recover_ticks)):
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise HapticsError(f"{name} must be a positive integer (got {v!r})")
        p[_P_MAXMISS] = max_misses
        p[_P_RECOVER] = recover_ticks
        if not isinstance(disengage_mask, (int, np.integer)) or disengage_mask < 0:
            raise HapticsError(f"disengage_mask must be a non-negative button bitmask (got {disengage_mask!r})")
        p[_P_MASK] = disengage_mask
        if free_force is None:
            free_force = p[_P_RATE] * p[_P_DT] if math.isfinite(p[_P_RATE]) else 0.0
        p[_P_FREE] = _num(free_force, "free_force", nonneg=True, unit="N")
        self.params = p
        self.state = SAFETY_STATE.zeros()
        self._out = np.zeros(3)
        self._in = np.zeros(3)
        self.flags = 0
        self.reset()

    @classmethod
    def for_device(cls, info: DeviceInfo, dt: float, **kwargs) -> "SafetyLayer":
        """A safety layer saturating at ``info.max_force``.

        Examples
        --------
        >>> from arsurf.haptics.device import TOUCH_X
        >>> SafetyLayer.for_device(TOUCH_X, 1e-3).max_force
        7.9
        """
        if not isinstance(info, DeviceInfo):
            raise HapticsError(f"info must be a DeviceInfo (got {type(info).__name__})")
        return cls(info.max_force, dt, **kwargs)

    @property
    def max_force(self) -> float:
        return float(self.params[_P_FMAX])

    @property
    def gain(self) -> float:
        """Engagement gain in [0, 1]."""
        return float(self.state[_S_GAIN])

    @property
    def watchdog_tripped(self) -> bool:
        return bool(self.state[_S_WD] != 0.0)

    @property
    def counts(self) -> dict[str, int]:
        """How many ticks raised each flag since the last :meth:`reset`."""
        return {n: int(self.state[_S_COUNT + b]) for b, n in enumerate(FLAG_NAMES)}

    def reset(self) -> None:
        """Back to start-up: zero force, gain 0 (the next forces ramp in), watchdog cleared."""
        self.state[:] = 0.0
        self.state[_S_LAST_NOW] = math.nan
        self.flags = 0

    def zero_now(self) -> None:
        """A fault found outside this layer (e.g. a device sample that cannot be real): the force
        held is zero from this tick and the engagement gain restarts from zero, so the force
        comes back through the start-up ramp."""
        st = self.state
        st[_S_F:_S_F + 3] = 0.0
        st[_S_HOLD:_S_HOLD + 3] = 0.0
        st[_S_GAIN] = 0.0
        st[_S_FAULT] = 1.0

    def step(self, force, now: float, age: float = 0.0, buttons: int = 0,
             out: np.ndarray | None = None) -> np.ndarray:
        """The force to send to the device, (3,) N.

        Parameters
        ----------
        force : (3,) float, N
            The force the algorithms want on the handle (anything: NaN, inf, huge).
        now : float, s
            Loop clock at this tick (advances by ``dt`` per tick).
        age : float, s
            Age of the device sample the force was computed from (``device.now() - state.timestamp``).
        buttons : int
            Button bitmask of that sample.
        out : (3,) float64, optional
            Written in place.
        """
        f = self._in
        try:
            f[0] = force[0]
            f[1] = force[1]
            f[2] = force[2]
        except (TypeError, IndexError, ValueError):
            f[:] = math.nan  # unusable input is treated as NaN: zero force, flagged
        o = self._out if out is None else out
        try:
            now_f = float(now)
            age_f = float(age)
        except (TypeError, ValueError):
            now_f, age_f = math.nan, math.nan
        self.flags = safety_step(self.params, self.state, f, now_f, age_f, int(buttons), o)
        return o.copy() if out is None else o

    def flag_names(self, flags: int | None = None) -> list[str]:
        """Names of the bits set in ``flags`` (default: the last step's)."""
        fl = self.flags if flags is None else int(flags)
        return [n for b, n in enumerate(FLAG_NAMES) if (fl >> b) & 1]
