"""Device samples that cannot be real: checked once per tick, where a sample enters the loop.

A haptic device reports where the stylus is; a driver bug, a corrupt packet or a clock that
steps can report something no stylus can do. :meth:`HapticLoop.step
<arsurf.haptics.loop.HapticLoop.step>` checks every sample before the model sees it, and a sample
that fails is a **fault**: the device gets zero force in that very tick, the engagement gain
drops to zero (the force comes back through the safety layer's start-up ramp, no kick), the model
is run on the last good sample instead (no dent where the stylus never was), and a flag names the
rule in the tick's safety flag word (``/ticks/safety_flags`` of a session, :mod:`arsurf.status`):

- :data:`SAMPLE_MALFORMED`: position or velocity not a float64 array of shape (3,) (a scalar or a
  (1,) array would broadcast to x = y = z), not finite, or a timestamp that is not a real number;
- :data:`SAMPLE_OUTSIDE`: a position component outside the device workspace plus a margin,
  :math:`|x_j| > w_j / 2 + m_j` (``DeviceInfo.workspace`` is centred on the home position);
- :data:`SAMPLE_TOO_FAST`: a move from the last good sample faster than the stylus can go,
  :math:`\\lVert x - x_{good}\\rVert > v_{max} \\max(t - t_{good}, \\Delta t)`, or a reported
  velocity component above :math:`v_{max}`;
- :data:`TIME_BACKWARDS`: the sample stamped earlier than the last good one, or the loop clock
  earlier than at the previous tick.

:math:`v_{max}` is :data:`MAX_STYLUS_SPEED` (10 m/s) unless the device gives its own: fast human
arm movements peak at a few m/s, so a desktop stylus moved by a hand stays below it with margin,
while a one-tick jump of 1 m (1000 m/s at 1 kHz) or 1 km is far above. The margin defaults to half
the workspace extent on each side (a box twice the usable one): a stylus pushed against its stops
stays inside, a reading metres away does not.

The check is one compiled call on preallocated arrays (:func:`sample_check_step`) after a type
test in Python; it allocates nothing.

Examples
--------
>>> import numpy as np
>>> from arsurf.haptics.device import TOUCH_X, DeviceState
>>> check = SampleCheck(TOUCH_X, dt=1e-3)
>>> check.step(DeviceState(np.zeros(3), np.zeros(3), 0, 0.0), 0.0)
0
>>> from arsurf.status import flag_names
>>> flag_names(check.step(DeviceState(np.array([1.0, 0.0, 0.0]), np.zeros(3), 0, 1e-3), 1e-3))   # 1 m away
['SAMPLE_OUTSIDE', 'SAMPLE_TOO_FAST']
>>> flag_names(check.step(DeviceState(np.zeros(1), np.zeros(3), 0, 2e-3), 2e-3))   # shape (1,)
['SAMPLE_MALFORMED']
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf import status
from arsurf._layout import Layout
from arsurf.errors import HapticsError
from arsurf.haptics.device import DeviceInfo, DeviceState

__all__ = ["MAX_STYLUS_SPEED", "SAMPLE_FAULTS", "SAMPLE_MALFORMED", "SAMPLE_OUTSIDE", "SAMPLE_TOO_FAST",
           "TIME_BACKWARDS", "SampleCheck", "sample_check_step"]

SAMPLE_MALFORMED = status.SAMPLE_MALFORMED  #: wrongly shaped, typed or non-finite sample
SAMPLE_OUTSIDE = status.SAMPLE_OUTSIDE  #: position outside the device workspace plus margin
SAMPLE_TOO_FAST = status.SAMPLE_TOO_FAST  #: a move (or a velocity) faster than the stylus can go
TIME_BACKWARDS = status.TIME_BACKWARDS  #: the sample's stamp or the loop clock went backwards
#: every flag of this module: any of them is a fault with zero force in its tick
SAMPLE_FAULTS = SAMPLE_MALFORMED | SAMPLE_OUTSIDE | SAMPLE_TOO_FAST | TIME_BACKWARDS
#: Speed no hand-held desktop stylus reaches, m/s (module docstring).
MAX_STYLUS_SPEED = 10.0

#: the check's parameters: workspace half-extent + margin (3) m, max speed m/s, loop period s
SAMPLE_PARAMS = Layout("sample check parameters", [("limit", 3), ("max_speed", 1), ("dt", 1)])
#: its state: last good position (3) m, its stamp s, the last loop clock s, 1 once a good sample came
SAMPLE_STATE = Layout("sample check state", [("position", 3), ("stamp", 1), ("now", 1), ("have", 1)])
_P_LIM, _P_VMAX, _P_DT = (SAMPLE_PARAMS.offset(f) for f in ("limit", "max_speed", "dt"))
_S_X, _S_T, _S_NOW, _S_HAVE = (SAMPLE_STATE.offset(f) for f in ("position", "stamp", "now", "have"))
_F8 = np.dtype(np.float64)
_SHAPE3 = (3,)


@njit(cache=True)
def sample_check_step(params, state, x, v, t, now):
    """Flags of the sample ``x`` (3,) m, ``v`` (3,) m/s stamped ``t`` s at loop clock ``now`` s
    (module docstring); a sample with no flag, stamped no later than ``now``, becomes the last
    good one. Allocation-free."""
    flags = 0
    for j in range(3):
        if not (math.isfinite(x[j]) and math.isfinite(v[j])):
            flags |= SAMPLE_MALFORMED
    if math.isnan(t) or t == math.inf:
        flags |= SAMPLE_MALFORMED
    if flags == 0:
        for j in range(3):
            if abs(x[j]) > params[_P_LIM + j]:
                flags |= SAMPLE_OUTSIDE
            if abs(v[j]) > params[_P_VMAX]:
                flags |= SAMPLE_TOO_FAST
    last_now = state[_S_NOW]
    if math.isfinite(now):
        if math.isfinite(last_now) and now < last_now:
            flags |= TIME_BACKWARDS
        state[_S_NOW] = now
    if state[_S_HAVE] != 0.0 and math.isfinite(t):
        if t < state[_S_T]:
            flags |= TIME_BACKWARDS
        elif (flags & SAMPLE_MALFORMED) == 0:
            d0 = x[0] - state[_S_X]
            d1 = x[1] - state[_S_X + 1]
            d2 = x[2] - state[_S_X + 2]
            elapsed = max(t - state[_S_T], params[_P_DT])
            if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) > params[_P_VMAX] * elapsed:
                flags |= SAMPLE_TOO_FAST
    if flags == 0 and math.isfinite(t) and not t > now:  # a sample stamped ahead of the clock (stale for
        for j in range(3):                                 # the safety layer) never becomes the reference
            state[_S_X + j] = x[j]
        state[_S_T] = t
        state[_S_HAVE] = 1.0
    return flags


class SampleCheck:
    """The checks of the module docstring for one device, with their memory.

    Parameters
    ----------
    info : DeviceInfo or None
        The device: its workspace bounds positions (None: no workspace bound, the other checks
        still apply).
    dt : float, s
        Loop period: the shortest time a move is allowed to take.
    max_speed : float, m/s
        Fastest credible stylus move (default :data:`MAX_STYLUS_SPEED`).
    margin : float or (3,) float, m, optional
        Added to the workspace half-extent (default: the half-extent itself).

    Attributes
    ----------
    params, state : float64 arrays
        Arguments of :func:`sample_check_step`.
    """

    def __init__(self, info: DeviceInfo | None, dt: float, *, max_speed: float = MAX_STYLUS_SPEED,
                 margin=None) -> None:
        if info is not None and not isinstance(info, DeviceInfo):
            raise HapticsError(f"info must be a DeviceInfo or None (got {type(info).__name__})")
        for name, val in (("dt", dt), ("max_speed", max_speed)):
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise HapticsError(f"{name} must be a positive finite number (got {val!r})")
        p = SAMPLE_PARAMS.zeros()
        if info is None:
            p[_P_LIM:_P_LIM + 3] = math.inf
        else:
            half = info.workspace / 2.0
            m = half if margin is None else np.broadcast_to(np.asarray(margin, dtype=float), (3,))
            if not (np.isfinite(m).all() and (m >= 0).all()):
                raise HapticsError(f"margin must be finite and >= 0 m (got {margin!r})")
            p[_P_LIM:_P_LIM + 3] = half + m
        p[_P_VMAX] = float(max_speed)
        p[_P_DT] = float(dt)
        self.params = p
        self.state = SAMPLE_STATE.zeros()
        self.reset()

    def reset(self) -> None:
        """Forget the last good sample and the last clock reading."""
        self.state[:] = 0.0
        self.state[_S_T] = -math.inf
        self.state[_S_NOW] = math.nan

    @staticmethod
    def well_formed(sample: DeviceState) -> bool:
        """True if position and velocity are float64 arrays of shape (3,) and the stamp a real number."""
        p, v, t = sample.position, sample.velocity, sample.timestamp
        return (type(p) is np.ndarray and type(v) is np.ndarray and p.dtype == _F8 and v.dtype == _F8
                and p.shape == _SHAPE3 and v.shape == _SHAPE3 and isinstance(t, (float, int)) and not isinstance(t, bool))

    def step(self, sample: DeviceState, now: float) -> int:
        """Flags of ``sample`` at loop clock ``now`` (0: a sample that can be real)."""
        if not self.well_formed(sample):
            sample_check_step(self.params, self.state, _NAN3, _NAN3, math.nan, float(now))
            return SAMPLE_MALFORMED
        return sample_check_step(self.params, self.state, sample.position, sample.velocity, float(sample.timestamp),
                                 float(now))

    @property
    def last_good(self) -> np.ndarray:
        """The last good position (3,) m (zeros before the first); a view."""
        return self.state[_S_X:_S_X + 3]


_NAN3 = np.full(3, np.nan)
