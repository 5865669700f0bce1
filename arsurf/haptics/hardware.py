r"""What every real haptic device adapter shares: the frame, the unit change, the fault handling.

An adapter (:mod:`~arsurf.haptics.forcedimension`, :mod:`~arsurf.haptics.haply`,
:mod:`~arsurf.haptics.openhaptics`) talks to one vendor package and fills four methods of
:class:`HardwareDevice`: ``_connect`` (open the device, calibrate it if needed, read its limits),
``_poll`` (one sample in the vendor's frame and units), ``_send`` (one force in the vendor's frame
and units) and ``_release``. Everything else is here, once.

**The arsurf device frame.** Right-handed, origin at the device's home (the centre of its
workspace unless the adapter says otherwise): :math:`x` to the operator's right, :math:`y` away
from the operator, :math:`z` up; metres, m/s, newtons. A vendor frame maps onto it by a signed
permutation :math:`R` (:class:`AxisMap`, e.g. ``"y,-x,z"``: arsurf :math:`x` is the vendor's
:math:`y`, arsurf :math:`y` is minus the vendor's :math:`x`) and a unit factor :math:`s` (m per
vendor length unit; N per vendor force unit :math:`s_F`):

.. math:: p = s\,R\,(p_v - h_v), \qquad v = s\,R\,v_v, \qquad F_v = R^{T} F / s_F,

so that the power :math:`F\cdot v = s / s_F\,F_v\cdot v_v` is the same in both frames (a
rotation, never a mirror: :math:`\det R = +1` is enforced).

**Faults.** A poll that fails or returns a non-finite number is a *missed sample*: the state keeps
the last good position but its timestamp becomes :math:`-\infty`, so the safety layer sees an
infinitely old sample (``STALE``) and commands zero force in that very tick. When the samples have
been missed in a row for ``disconnect_after`` seconds the read raises
:class:`~arsurf.errors.DeviceDisconnected`; a loop under the
:class:`~arsurf.haptics.scheduler.Scheduler` then stops, its ``on_stop`` commands zero force, and
the recording is closed by its owner. :meth:`Device.close` sends zero force (best effort: a
device that is gone cannot hear it) and releases the vendor handle whatever happened.

**First connection.** Without ``max_force`` a device runs at :data:`FIRST_FORCE_N` (1 N) or its
own limit if lower, never at its full nominal force: a wrong axis or force sign found at bring-up
then pushes the hand with 1 N, not 12 or 20 (``max_force`` / ``--max-force-n`` raises it, up to the
device's limit; docs/bringup.rst). What each open decided (force limit and its source, and the
adapter's own protections, e.g. the firmware watchdog) is :meth:`HardwareDevice.safety_record`,
kept in the session metadata.

The clock is the host's :func:`time.perf_counter` (``now`` and every timestamp), as for the
network bridge.

Examples
--------
>>> m = AxisMap("y,-x,z", length_scale=1e-3)          # a vendor frame in mm, x towards the operator
>>> m.matrix.astype(int).tolist()
[[0, 1, 0], [-1, 0, 0], [0, 0, 1]]
>>> m.position([10.0, 0.0, 0.0]).tolist()              # 10 mm towards the operator: y = -0.01 m
[0.0, -0.01, 0.0]
>>> m.force_to_vendor([1.0, 0.0, 0.0]).tolist()        # 1 N to the right is +y in the vendor frame
[0.0, 1.0, 0.0]
"""
from __future__ import annotations

import abc
import math
import time
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from arsurf.errors import DeviceDisconnected, HapticsError
from arsurf.haptics.device import Device, DeviceInfo, DeviceState, _vec3
from arsurf.haptics.safety import _num

__all__ = ["FIRST_FORCE_N", "AxisMap", "BackendReport", "HardwareDevice", "device_limits"]

#: N: the force limit of a device opened without ``max_force`` (module docstring)
FIRST_FORCE_N = 1.0

_AXES = {"x": 0, "y": 1, "z": 2}


@njit(cache=True)
def map_sample(R, scale, home, vpos, vvel, pos, vel):
    """``pos = scale R (vpos - home)``, ``vel = scale R vvel`` (all (3,) / (3, 3) float64); returns
    False when an input is not finite (the outputs are then untouched)."""
    for j in range(3):
        if not (math.isfinite(vpos[j]) and math.isfinite(vvel[j])):
            return False
    for i in range(3):
        p = 0.0
        v = 0.0
        for j in range(3):
            p += R[i, j] * (vpos[j] - home[j])
            v += R[i, j] * vvel[j]
        pos[i] = scale * p
        vel[i] = scale * v
    return True


@njit(cache=True)
def map_force(R, inv_force_scale, force, out):
    """``out = R^T force / s_F`` ((3,) float64, the force in the vendor's frame and unit)."""
    for j in range(3):
        f = 0.0
        for i in range(3):
            f += R[i, j] * force[i]
        out[j] = f * inv_force_scale


class AxisMap:
    """A vendor frame onto the arsurf device frame: signed axis permutation and unit factors.

    Parameters
    ----------
    axes : str or (3, 3) array
        ``"a,b,c"``: arsurf x, y, z are the vendor's axes a, b, c, each ``x``, ``y`` or ``z`` with an
        optional ``-`` (``"x,y,z"`` is the identity); or the matrix :math:`R` itself (a signed
        permutation). Mirrors (:math:`\\det R = -1`) are refused.
    length_scale : float
        Metres per vendor length unit (1e-3 for millimetres); velocities use it too.
    force_scale : float
        Newtons per vendor force unit.

    Examples
    --------
    >>> AxisMap("x,-z,y", length_scale=1e-3).spec        # OpenHaptics: y up, z towards the operator
    'x,-z,y'
    """

    def __init__(self, axes="x,y,z", length_scale: float = 1.0, force_scale: float = 1.0) -> None:
        if isinstance(axes, str):
            R = np.zeros((3, 3))
            parts = [p.strip().lower() for p in axes.split(",")]
            if len(parts) != 3 or any(p.lstrip("+-") not in _AXES for p in parts):
                raise HapticsError(f"axes must name the vendor axis behind arsurf x, y, z, e.g. 'y,-x,z' (got {axes!r})")
            for i, p in enumerate(parts):
                R[i, _AXES[p.lstrip("+-")]] = -1.0 if p.startswith("-") else 1.0
        else:
            try:
                R = np.array(axes, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise HapticsError(f"axes must be a string like 'y,-x,z' or a 3x3 matrix (got {axes!r})") from exc
        if R.shape != (3, 3) or not np.all(np.isin(R, (-1.0, 0.0, 1.0))) or not np.array_equal(np.abs(R).sum(0), np.ones(3)) \
                or not np.array_equal(np.abs(R).sum(1), np.ones(3)):
            raise HapticsError(f"axes must be a signed permutation: each vendor axis used once (got {R.tolist()})")
        if round(float(np.linalg.det(R))) != 1:
            raise HapticsError(f"axes {self._spec(R)!r} mirror the frame (det = -1); both frames are right-handed: "
                               "flip the sign of one more axis")
        for name, v in (("length_scale", length_scale), ("force_scale", force_scale)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise HapticsError(f"{name} must be a positive finite factor (got {v!r})")
        self.matrix = np.ascontiguousarray(R)
        self.matrix.setflags(write=False)
        self.length_scale = float(length_scale)
        self.force_scale = float(force_scale)

    @staticmethod
    def _spec(R) -> str:
        names = "xyz"
        return ",".join(("-" if R[i, j] < 0 else "") + names[j] for i in range(3) for j in range(3) if R[i, j] != 0)

    @property
    def spec(self) -> str:
        """The ``"a,b,c"`` form of the map."""
        return self._spec(self.matrix)

    def position(self, vendor_position, home=(0.0, 0.0, 0.0)) -> np.ndarray:
        """A vendor position (vendor units) as arsurf metres: :math:`s R (p_v - h_v)`."""
        pos, vel = np.empty(3), np.empty(3)
        if not map_sample(self.matrix, self.length_scale, _vec3(home, "home"), _vec3(vendor_position, "position"),
                          np.zeros(3), pos, vel):
            raise HapticsError("position must be finite")
        return pos

    def force_to_vendor(self, force) -> np.ndarray:
        """An arsurf force (N) in the vendor's frame and unit: :math:`R^T F / s_F`."""
        out = np.empty(3)
        map_force(self.matrix, 1.0 / self.force_scale, _vec3(force, "force"), out)
        return out

    def extents(self, vendor_extents) -> np.ndarray:
        """Workspace extents (vendor units, vendor axes) as arsurf metres along arsurf x, y, z."""
        return np.abs(self.matrix) @ (_vec3(vendor_extents, "extents") * self.length_scale)


def device_limits(name: str, reported_force: float | None, user_force: float | None, workspace, stiffness,
                  damping=None, *, source: str) -> DeviceInfo:
    """The :class:`DeviceInfo` of a connected device: its reported limits, capped by the user's.

    ``reported_force`` N is the most the device may be asked for (None: the device reports
    nothing and ``user_force`` is required); ``user_force`` N may only lower it; without it the
    limit is :data:`FIRST_FORCE_N` (or ``reported_force`` if lower). ``workspace`` m
    (arsurf axes), ``stiffness`` N/m, ``damping`` N s/m or None. ``source`` names where the
    figures came from (kept in the name for the logs and the session metadata).

    Examples
    --------
    >>> device_limits("omega.3", 12.0, 5.0, (0.16, 0.16, 0.11), 14500.0, source="sdk").max_force
    5.0
    >>> device_limits("omega.3", 12.0, None, (0.16, 0.16, 0.11), 14500.0, source="sdk").max_force
    1.0
    """
    if user_force is not None:
        uf = _num(user_force, "max_force", positive=True, unit="N")
        if reported_force is not None and uf > reported_force:
            raise HapticsError(f"max_force {uf:g} N is above what {name} allows ({reported_force:g} N, {source}); "
                               "give at most that")
        fmax = uf
    elif reported_force is None:
        raise HapticsError(f"{name} reports no force limit; give max_force= in newtons (its datasheet's continuous "
                           "force, or less)")
    else:
        fmax = min(float(reported_force), FIRST_FORCE_N)
        source = f"{source}; first-connection limit {fmax:g} N of {float(reported_force):g} N, max_force raises it"
    return DeviceInfo(name=f"{name} ({source})", max_force=fmax, workspace=workspace, max_stiffness=stiffness,
                      max_damping=damping)


@dataclass
class BackendReport:
    """What ``arsurf devices`` says about one backend: is it installed, what answers.

    ``installed`` is False when the Python package or its vendor library is missing (``detail``
    says which and how to install it); ``devices`` lists one description per connected device.
    """

    backend: str
    installed: bool
    detail: str
    devices: list[str] = field(default_factory=list)

    def line(self) -> str:
        """One line for the terminal."""
        if not self.installed:
            return f"{self.backend:<15} not available: {self.detail}"
        found = "; ".join(self.devices) if self.devices else "none connected"
        return f"{self.backend:<15} installed ({self.detail}); {found}"


class HardwareDevice(Device):
    """A real device behind a vendor package (see the module docstring).

    Parameters
    ----------
    axes : AxisMap
        The vendor frame and units onto arsurf's.
    max_force : float, N, optional
        Cap below the device's own limit (None: the device's).
    disconnect_after : float, s
        No good sample for this long: :class:`~arsurf.errors.DeviceDisconnected` (default 0.05 s;
        every missed sample before that already gives zero force).

    Attributes
    ----------
    missed_samples : int
        Polls that failed or returned non-finite numbers.
    failed_sends : int
        Force commands the device refused.
    """

    def __init__(self, axes: AxisMap, max_force: float | None = None, disconnect_after: float = 0.05) -> None:
        super().__init__()
        if not isinstance(axes, AxisMap):
            raise HapticsError(f"axes must be an AxisMap (got {type(axes).__name__})")
        try:
            disconnect_after = float(disconnect_after)
        except (TypeError, ValueError) as exc:
            raise HapticsError(f"disconnect_after must be seconds (got {disconnect_after!r})") from exc
        if not (0.0 < disconnect_after <= 10.0):
            raise HapticsError(f"disconnect_after must be in (0, 10] s (got {disconnect_after!r})")
        self.axes = axes
        self.user_max_force = max_force
        self.disconnect_after = disconnect_after
        self.home = np.zeros(3)  # vendor frame and units
        self._info: DeviceInfo | None = None
        self._vpos = np.zeros(3)
        self._vvel = np.zeros(3)
        self._vforce = np.zeros(3)
        self._last = DeviceState()
        self._misses = 0  # missed samples in a row
        self._miss_since = math.nan  # when the first of them was missed
        self._inv_fs = 1.0 / axes.force_scale
        self.missed_samples = 0
        self.failed_sends = 0

    # -- what an adapter provides ---------------------------------------------------------------
    @abc.abstractmethod
    def _connect(self) -> DeviceInfo:
        """Open the vendor device (calibrating it if it must), set ``self.home``; return its limits.
        Raise a clear :class:`~arsurf.errors.ArsurfError` (and leave nothing open) on failure."""

    @abc.abstractmethod
    def _poll(self, vpos: np.ndarray, vvel: np.ndarray) -> int | None:
        """Fill the vendor position and velocity; return the button mask, None if the device did not answer."""

    @abc.abstractmethod
    def _send(self, vforce: np.ndarray) -> bool:
        """Command the vendor force; False if the device refused it."""

    @abc.abstractmethod
    def _release(self) -> None:
        """Release the vendor handle (never raises)."""

    def safety_record(self) -> dict:
        """What the last open decided for safety, for the session metadata (JSON types, SI
        suffixes): the force limit and whether it was given or the first-connection default;
        adapters add their own protections (e.g. ``watchdog_set``)."""
        return {"max_force_N": float(self.info.max_force),
                "force_limit_source": "given" if self.user_max_force is not None else "first connection"}

    def _sample_time(self) -> float:
        """When the sample ``_poll`` just gave was taken (:meth:`now` clock): now, unless the
        vendor's servo thread took it earlier."""
        return self.now()

    # -- Device ---------------------------------------------------------------------------------
    @property
    def info(self) -> DeviceInfo:
        if self._info is None:
            raise HapticsError(f"{type(self).__name__}: open() it first; its limits come from the device itself")
        return self._info

    def now(self) -> float:
        """The host clock, s (:func:`time.perf_counter`)."""
        return time.perf_counter()

    def open(self) -> "HardwareDevice":
        """Connect, read the limits, enable forces (idempotent); returns ``self``."""
        if not self._is_open:
            # compile (or load) the mapping kernels now: a first call in the servo loop would stall it
            map_sample(self.axes.matrix, 1.0, self.home, self._vpos, self._vvel, np.empty(3), np.empty(3))
            map_force(self.axes.matrix, 1.0, self._vforce, np.empty(3))
            self._info = self._connect()
            try:
                super().open()
            except BaseException:
                self._release()
                raise
            self._last = DeviceState()
            self._misses = 0
        return self

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        try:
            self._vforce[:] = 0.0
            self._send(self._vforce)
        except Exception:  # noqa: BLE001 - a device that is gone cannot hear zero; release it anyway
            pass
        finally:
            self._release()

    def _read(self, out: DeviceState) -> None:
        buttons = None
        try:
            buttons = self._poll(self._vpos, self._vvel)
        except Exception:  # noqa: BLE001 - a vendor call that raises is a missed sample, judged below
            buttons = None
        t = self.now() if buttons is None else self._sample_time()
        last = self._last
        if buttons is not None and map_sample(self.axes.matrix, self.axes.length_scale, self.home, self._vpos,
                                              self._vvel, last.position, last.velocity):
            last.buttons = int(buttons)
            last.timestamp = t
            self._misses = 0
            last.copy_into(out)
            return
        self.missed_samples += 1
        t = self.now()
        if self._misses == 0:
            self._miss_since = t
        self._misses += 1
        if t - self._miss_since > self.disconnect_after:
            raise DeviceDisconnected(
                f"{self.info.name} has not answered for {t - self._miss_since:.3f} s ({self._misses} missed samples in "
                "a row); zero force was commanded; check the cable and power, then start again")
        last.copy_into(out)
        out.buttons = 0
        out.timestamp = -math.inf  # an infinitely old sample: the safety layer gives zero force now

    def _apply_force(self, force: np.ndarray) -> None:
        map_force(self.axes.matrix, self._inv_fs, force, self._vforce)
        ok = False
        try:
            ok = self._send(self._vforce)
        except Exception:  # noqa: BLE001 - counted; the reads decide whether the device is gone
            ok = False
        if not ok:
            self.failed_sends += 1
