"""A device that plays back a recorded stylus trajectory (offline replay, regression tests).

The recording is three arrays: sample times ``t`` (n,), positions (n, 3) and buttons (n,). Each
:meth:`ReplayDevice.command_force` advances the replay clock by one tick ``dt`` and logs the
commanded force; :meth:`ReplayDevice.read_state` returns the recording at the replay clock:

.. math::

    x(t) = (1 - w)\\,x_i + w\\,x_{i+1}, \\quad w = \\frac{t - t_i}{t_{i+1} - t_i}, \\quad t_i \\le t < t_{i+1},

velocity from the recorded velocities if given (interpolated the same way), else the slope of the
recorded segment, and buttons held from the last sample at or before ``t`` (they are events, not
signals to interpolate). Before the first sample and after the last one the stylus rests at the
end point with zero velocity; ``finished`` turns True after the last sample (``loop=True``
restarts from the beginning instead). The clock starts at ``t[0]``.

Examples
--------
>>> import numpy as np
>>> t = np.array([0.0, 1.0])
>>> dev = ReplayDevice(t, [[0, 0, 0], [0.01, 0, 0]], dt=0.25).open()
>>> for _ in range(2):
...     dev.command_force([0.0, 0.0, 0.0])
>>> s = dev.read_state()
>>> s.timestamp, s.position.round(6).tolist(), s.velocity.round(6).tolist()
(0.5, [0.005, 0.0, 0.0], [0.01, 0.0, 0.0])
"""
from __future__ import annotations

import math

import numpy as np

from arsurf.errors import HapticsError
from arsurf.haptics.device import Device, DeviceInfo, DeviceState, TOUCH_X

__all__ = ["ReplayDevice"]


class ReplayDevice(Device):
    """Plays a recorded stylus trajectory; logs the forces commanded during the replay.

    Parameters
    ----------
    t : (n,) float, s
        Sample times, strictly increasing, finite.
    position : (n, 3) float, m
        Recorded stylus positions.
    buttons : (n,) int, optional
        Recorded button bitmasks (default all 0).
    velocity : (n, 3) float, m/s, optional
        Recorded velocities; default: slope of the piecewise-linear position.
    dt : float, s
        Replay tick (the servo period).
    loop : bool
        Restart at the beginning after the last sample instead of resting there.
    info : DeviceInfo
        Limits of the device that made the recording (default: Touch X).

    Attributes
    ----------
    finished : bool
        True once the replay clock has passed the last sample (never with ``loop=True``).

    Examples
    --------
    >>> dev = ReplayDevice([0.0, 0.1], [[0, 0, 0], [0, 0, 1e-3]], buttons=[0, 1], dt=0.05)
    >>> with dev:
    ...     for _ in range(3):
    ...         dev.command_force([0.0, 0.0, 1.0])
    ...     dev.read_state().buttons, dev.finished, dev.commanded_forces()[1].shape
    (1, True, (3, 3))
    """

    def __init__(self, t, position, buttons=None, velocity=None, dt: float = 1e-3, loop: bool = False,
                 info: DeviceInfo = TOUCH_X) -> None:
        super().__init__()
        t = np.array(t, dtype=np.float64)
        position = np.array(position, dtype=np.float64)
        if t.ndim != 1 or t.size < 1:
            raise HapticsError(f"t must be a 1-D array of sample times with at least one sample (got shape {t.shape})")
        n = t.size
        if position.shape != (n, 3):
            raise HapticsError(f"position must have shape (n, 3) = ({n}, 3) to match t (got {position.shape})")
        if not np.isfinite(t).all() or not np.isfinite(position).all():
            raise HapticsError("t and position must be finite; remove or interpolate the NaN/inf samples first")
        if n > 1 and not (np.diff(t) > 0).all():
            i = int(np.argmin(np.diff(t)))
            raise HapticsError(
                f"t must be strictly increasing (t[{i}] = {float(t[i])!r} s, t[{i + 1}] = {float(t[i + 1])!r} s); "
                "sort the recording"
            )
        if buttons is None:
            buttons = np.zeros(n, dtype=np.int64)
        else:
            b = np.asarray(buttons)
            if b.shape != (n,) or not (np.issubdtype(b.dtype, np.integer) or np.issubdtype(b.dtype, np.bool_)):
                raise HapticsError(f"buttons must be ({n},) integers (bitmasks) (got shape {b.shape}, dtype {b.dtype})")
            if (b < 0).any():
                raise HapticsError("buttons must be non-negative bitmasks")
            buttons = b.astype(np.int64)
        if velocity is None:
            velocity = np.zeros((n, 3))
            if n > 1:
                seg = np.diff(position, axis=0) / np.diff(t)[:, None]
                velocity[:-1] = seg  # slope of the segment starting at each sample
                velocity[-1] = seg[-1]
            self._segment_velocity = True
        else:
            velocity = np.array(velocity, dtype=np.float64)
            if velocity.shape != (n, 3) or not np.isfinite(velocity).all():
                raise HapticsError(f"velocity must be finite with shape ({n}, 3) (got {velocity.shape})")
            self._segment_velocity = False
        dt = float(dt)
        if not (dt > 0.0 and math.isfinite(dt)):
            raise HapticsError(f"dt must be a positive tick period in seconds (got {dt!r})")
        if not isinstance(info, DeviceInfo):
            raise HapticsError(f"info must be a DeviceInfo (got {type(info).__name__})")
        self.t, self.position, self.buttons, self.velocity = t, position, buttons, velocity
        self.dt = dt
        self.loop = bool(loop)
        self._info = info
        self.ticks = 0
        duration = t[-1] - t[0]
        self._log_n = int(math.ceil(duration / dt)) + 2 if not loop else 0
        self._log_t = np.empty(self._log_n)
        self._log_f = np.empty((self._log_n, 3))
        self._logged = 0

    @property
    def info(self) -> DeviceInfo:
        return self._info

    @property
    def duration(self) -> float:
        """Length of the recording, s."""
        return float(self.t[-1] - self.t[0])

    def now(self) -> float:
        """Replay clock, s (starts at ``t[0]``)."""
        return float(self.t[0] + self.ticks * self.dt)

    @property
    def finished(self) -> bool:
        return (not self.loop) and bool(self.now() > self.t[-1])

    def rewind(self) -> None:
        """Back to the first sample; clears the force log."""
        self.ticks = 0
        self._logged = 0

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _read(self, out: DeviceState) -> None:
        t_clock = self.now()
        t = self.t
        tq = t_clock
        if self.loop and t.size > 1:
            span = t[-1] - t[0]
            tq = t[0] + math.fmod(t_clock - t[0], span) if span > 0 else t[0]
        i = int(np.searchsorted(t, tq, side="right")) - 1  # last sample at or before tq
        if i < 0:
            out.position[:] = self.position[0]
            out.velocity[:] = 0.0
            out.buttons = int(self.buttons[0])
        elif i >= t.size - 1:
            out.position[:] = self.position[-1]
            if tq == t[-1] and not self._segment_velocity:
                out.velocity[:] = self.velocity[-1]
            else:
                out.velocity[:] = 0.0
            out.buttons = int(self.buttons[-1])
        else:
            w = (tq - t[i]) / (t[i + 1] - t[i])
            out.position[:] = (1.0 - w) * self.position[i] + w * self.position[i + 1]
            if self._segment_velocity:
                out.velocity[:] = self.velocity[i]
            else:
                out.velocity[:] = (1.0 - w) * self.velocity[i] + w * self.velocity[i + 1]
            out.buttons = int(self.buttons[i])
        out.timestamp = t_clock

    def _apply_force(self, force: np.ndarray) -> None:
        k = self._logged
        if k < self._log_n:
            self._log_t[k] = self.now()
            self._log_f[k] = force
            self._logged = k + 1
        self.ticks += 1

    def commanded_forces(self) -> tuple[np.ndarray, np.ndarray]:
        """The forces commanded so far: times (m,) s and forces (m, 3) N (copies).

        The log holds one entry per tick of the recording (it stops growing after the end and is
        not kept with ``loop=True``).
        """
        k = self._logged
        return self._log_t[:k].copy(), self._log_f[:k].copy()
