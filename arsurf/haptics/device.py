"""The haptic device interface: what every device (virtual, replayed, networked) looks like.

A device is opened, read once per servo tick (:meth:`Device.read_state` gives the stylus
position, velocity, buttons and the time the sample was taken), commanded once per tick
(:meth:`Device.command_force`, the force on the handle in newtons), and closed. Its limits are a
:class:`DeviceInfo`. Coordinates are the device's own, in SI units: metres from the device's home
position, m/s, N; the clock of :meth:`Device.now` and of ``DeviceState.timestamp`` is the device's
clock in seconds (simulated time for the virtual and replay devices, the host's monotonic clock for
the network bridge), so ``device.now() - state.timestamp`` is the age of the sample.

Every device is its own last line of defence: :meth:`Device.command_force` never forwards a
non-finite force (it sends zero and counts it in ``rejected_forces``) and clamps the vector norm
to ``info.max_force`` (counted in ``clamped_forces``). The real safety policy (ramps, rate limit,
watchdog) lives in :mod:`arsurf.haptics.safety`; this is only the backstop.

Examples
--------
>>> from arsurf.haptics.virtual_device import VirtualDevice
>>> with VirtualDevice(dt=1e-3) as dev:
...     s = dev.read_state()
...     dev.command_force([0.0, 0.0, 0.5])
...     s.position.shape, dev.info.max_force
((3,), 7.9)
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from arsurf.errors import HapticsError, HapticsWarning

__all__ = [
    "BUTTON_1",
    "BUTTON_2",
    "DEVICE_LIMITS",
    "TOUCH_X",
    "Device",
    "DeviceInfo",
    "DeviceState",
    "HapticsWarning",
    "sanitize_force",
]


#: Bit of the first (front) stylus button in ``DeviceState.buttons``.
BUTTON_1 = 1
#: Bit of the second stylus button.
BUTTON_2 = 2


def _vec3(value, name: str, *, allow_inf: bool = False) -> np.ndarray:
    """``value`` as a finite float64 (3,) array (scalars broadcast), or a clear HapticsError."""
    try:
        arr = np.array(np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)), dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise HapticsError(
            f"{name} must be a scalar or a 3-vector of numbers (got {value!r}); give one value per axis x, y, z"
        ) from exc
    bad = np.isnan(arr) if allow_inf else ~np.isfinite(arr)
    if bad.any():
        raise HapticsError(f"{name} must be finite (got {arr.tolist()}); NaN/inf cannot be a device setting")
    return arr


@dataclass(frozen=True, eq=False)
class DeviceInfo:
    """Limits of a haptic device, in SI units.

    Parameters
    ----------
    name : str
        Device name, for logs and the HUD.
    max_force : float, N
        Largest force norm the device may be commanded (the saturation of the safety layer).
        ``inf`` is allowed only for simulations that must stay linear.
    workspace : (3,) float, m
        Extent of the usable workspace box along x, y, z, centred on the home position.
    max_stiffness : (3,) float, N/m
        Largest stiffness the device renders stably, per axis.
    max_damping : (3,) float, N s/m, or None
        Largest virtual damping, per axis; None when the source gives none.
    damping : (3,) float, N s/m, or None
        The device's own (physical) viscous damping, per axis; None when unknown. It sets the
        stiffness a sampled loop renders passively (:func:`arsurf.haptics.gains.coupling_stiffness`).

    Examples
    --------
    >>> TOUCH_X.max_force, TOUCH_X.workspace.tolist()
    (7.9, [0.12, 0.16, 0.12])
    """

    name: str
    max_force: float
    workspace: np.ndarray
    max_stiffness: np.ndarray
    max_damping: np.ndarray | None = None
    damping: np.ndarray | None = None

    def __post_init__(self) -> None:
        mf = float(self.max_force)
        if not (mf > 0.0):  # also rejects NaN
            raise HapticsError(
                f"max_force must be positive (got {self.max_force!r} N); it is the saturation force norm in newtons"
            )
        object.__setattr__(self, "max_force", mf)
        ws = _vec3(self.workspace, "workspace")
        if (ws <= 0).any():
            raise HapticsError(f"workspace extents must be positive (got {ws.tolist()} m)")
        object.__setattr__(self, "workspace", ws)
        ks = _vec3(self.max_stiffness, "max_stiffness", allow_inf=True)
        if (ks <= 0).any():
            raise HapticsError(f"max_stiffness must be positive (got {ks.tolist()} N/m)")
        object.__setattr__(self, "max_stiffness", ks)
        if self.max_damping is not None:
            bs = _vec3(self.max_damping, "max_damping", allow_inf=True)
            if (bs < 0).any():
                raise HapticsError(f"max_damping must be >= 0 (got {bs.tolist()} N s/m)")
            object.__setattr__(self, "max_damping", bs)
        if self.damping is not None:
            bd = _vec3(self.damping, "damping")
            if (bd < 0).any():
                raise HapticsError(f"damping must be >= 0 (got {bd.tolist()} N s/m)")
            object.__setattr__(self, "damping", bd)
        for a in ("workspace", "max_stiffness", "max_damping", "damping"):
            v = getattr(self, a)
            if v is not None:
                v.setflags(write=False)


# Geomagic Touch X, [Alabdulmuhsin] section 3.2 (vendor datasheet [23] there): 7.9 N maximum force,
# workspace 160 mm wide (Y_h) x 120 mm high (Z_h) x 120 mm deep (X_h), spring stiffness
# 1.86, 2.35, 1.48 N/mm along X, Y, Z. The seed gives no damping limit.
TOUCH_X = DeviceInfo(
    name="Geomagic Touch X",
    max_force=7.9,
    workspace=(0.120, 0.160, 0.120),
    max_stiffness=(1860.0, 2350.0, 1480.0),
    max_damping=None,
)

#: Device limits by key, one place for all of them (each value says where it comes from).
DEVICE_LIMITS: dict[str, DeviceInfo] = {"touch_x": TOUCH_X}


@dataclass(eq=False)
class DeviceState:
    """One sample of the stylus.

    Parameters
    ----------
    position : (3,) float, m
        Stylus position in the device frame (from its home position).
    velocity : (3,) float, m/s
        Stylus velocity.
    buttons : int
        Button bitmask (:data:`BUTTON_1`, :data:`BUTTON_2`).
    timestamp : float, s
        Time the sample was taken, in the device clock (:meth:`Device.now`); ``-inf`` before the
        first sample (its age is infinite, so the safety layer renders no force).

    Examples
    --------
    >>> s = DeviceState()
    >>> s.position.tolist(), s.buttons, s.timestamp
    ([0.0, 0.0, 0.0], 0, -inf)
    """

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    buttons: int = 0
    timestamp: float = -math.inf

    def copy(self) -> "DeviceState":
        """An independent copy (new arrays)."""
        return DeviceState(self.position.copy(), self.velocity.copy(), int(self.buttons), float(self.timestamp))

    def copy_into(self, out: "DeviceState") -> "DeviceState":
        """Copy this sample into ``out`` without allocating; returns ``out``."""
        out.position[:] = self.position
        out.velocity[:] = self.velocity
        out.buttons = self.buttons
        out.timestamp = self.timestamp
        return out


@njit(cache=True)
def sanitize_force(force, fmax, out):
    """Copy ``force`` (3,) into ``out`` (3,): zero if not finite (returns 1), norm clamped to
    ``fmax`` (returns 2), else unchanged (returns 0)."""
    f0 = force[0]
    f1 = force[1]
    f2 = force[2]
    if not (math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)):
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        return 1
    n = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    if n > fmax:
        s = fmax / n
        out[0] = f0 * s
        out[1] = f1 * s
        out[2] = f2 * s
        return 2
    out[0] = f0
    out[1] = f1
    out[2] = f2
    return 0


_NAN3 = np.full(3, np.nan)  # stands for an unusable force argument


class Device(abc.ABC):
    """Abstract haptic device: open, read the stylus, command a force, close.

    Subclasses implement :attr:`info`, :meth:`now`, :meth:`_open`, :meth:`_close`,
    :meth:`_read` and :meth:`_apply_force`. The public methods check that the device is open and
    sanitise the force (non-finite -> zero, norm clamped to ``info.max_force``) before
    :meth:`_apply_force` sees it, so no subclass can forward NaN.

    A device is a context manager: ``with VirtualDevice() as dev: ...`` opens and closes it.
    """

    def __init__(self) -> None:
        self._is_open = False
        self._force = np.zeros(3)
        #: commanded forces that were not finite (replaced by zero)
        self.rejected_forces = 0
        #: commanded forces whose norm exceeded ``info.max_force`` (clamped)
        self.clamped_forces = 0

    # -- what a subclass provides ------------------------------------------------------------
    @property
    @abc.abstractmethod
    def info(self) -> DeviceInfo:
        """The device limits."""

    @abc.abstractmethod
    def now(self) -> float:
        """Current time of the device clock, in seconds (same clock as ``DeviceState.timestamp``)."""

    @abc.abstractmethod
    def _open(self) -> None: ...

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the device; a device with actuators commands zero force here first."""

    @abc.abstractmethod
    def _read(self, out: DeviceState) -> None:
        """Fill ``out`` with the latest sample."""

    @abc.abstractmethod
    def _apply_force(self, force: np.ndarray) -> None:
        """Send a sanitised (finite, norm <= max_force) force to the device."""

    # -- public API ----------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._is_open

    def open(self) -> "Device":
        """Open the device (idempotent); returns ``self``."""
        if not self._is_open:
            self._max_force = float(self.info.max_force)
            self._open()
            self._is_open = True
        return self

    def close(self) -> None:
        """Close the device (idempotent); a device with real actuators zeroes its force in ``_close``."""
        if self._is_open:
            try:
                self._force[:] = 0.0
                self._close()
            finally:
                self._is_open = False

    def __enter__(self) -> "Device":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def _require_open(self) -> None:
        if not self._is_open:
            raise HapticsError(
                f"{type(self).__name__} is not open; call open() first or use it as a context manager"
            )

    def read_state(self, out: DeviceState | None = None) -> DeviceState:
        """The latest stylus sample.

        Parameters
        ----------
        out : DeviceState, optional
            Filled in place (no allocation in the servo loop); a new record otherwise.

        Returns
        -------
        DeviceState
        """
        if not self._is_open:
            self._require_open()
        if out is None:
            out = DeviceState()
        self._read(out)
        return out

    def command_force(self, force) -> None:
        """Command the force on the handle, (3,) newtons, held until the next command.

        A non-finite force is replaced by zero (``rejected_forces`` += 1); a force whose norm exceeds
        ``info.max_force`` is scaled down to it (``clamped_forces`` += 1). This method never raises
        on the force values, so it is safe in the servo loop.
        """
        if not self._is_open:
            self._require_open()
        f = self._force
        if not (isinstance(force, np.ndarray) and force.dtype == np.float64 and force.shape == (3,)):
            try:
                force = np.asarray(force, dtype=np.float64)
                if force.shape != (3,):
                    raise ValueError
            except (TypeError, ValueError):
                force = _NAN3
        code = sanitize_force(force, self._max_force, f)
        if code == 1:
            self.rejected_forces += 1
        elif code == 2:
            self.clamped_forces += 1
        self._apply_force(f)
