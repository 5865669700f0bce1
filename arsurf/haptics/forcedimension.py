r"""Force Dimension devices (omega, delta, sigma, lambda; the Novint Falcon through the same SDK).

Through ``forcedimension-core`` (extra ``arsurf[forcedimension]``), the Python binding of the
vendor's C SDK: it loads ``libdrd`` (which also holds the ``dhd`` functions) at import from
``$FDSDK/lib/release/lin-<machine>-gcc/libdrd.so.*`` (or ``~/.local/lib``, ``/usr/local/lib``),
and needs SDK 3.16 or later.

**Frame.** The SDK's: metres and newtons, origin at the centre of the workspace, :math:`x` towards
the operator, :math:`y` to the operator's right, :math:`z` up. In the arsurf frame
(:mod:`arsurf.haptics.hardware`) that is ``AxisMap("y,-x,z")``.

**The vendor's sequence.** As the SDK's own examples do: the device is opened with ``drdOpen`` /
``drdOpenID`` (the robotic SDK's calls - ``drdIsSupported``, ``drdIsInitialized``,
``drdAutoInit``, ``drdStop`` - act only on a device the DRD opened) and closed with ``drdClose``.
The watchdog and the kinematics are *expert* SDK functions (``dhdc.h``, "expert API"): they fail
with ``DHD_ERROR_EXPERT_MODE_DISABLED`` unless ``dhdEnableExpertMode`` was called; the adapter
enables expert mode for them only and disables it right after (the servo loop runs without it).

**Limits, from the device.** The workspace is the largest box centred on the origin inside the
positions the handle can *reach*, not the bounding box of them (a delta's corners are out of reach):
the encoder range (``dhdGetEncRange``) through the forward kinematics
(``dhdDeltaEncoderToPosition``, on a 9x9x9 grid) bounds it; then a box is reachable when every
point of a 7x7 grid on each of its faces maps, through the inverse kinematics
(``dhdDeltaPositionToEncoder``), to encoders inside that range. The box is the bounding box scaled
down uniformly (bisection) until reachable, then grown one axis at a time while it stays so.
``workspace_source`` says where it came from: ``"kinematics"``, ``"given"`` or ``"nominal"`` (the
model's datasheet figures, when the SDK has no kinematics for it). The force limit is the lowest of
the SDK's own cap (``dhdGetMaxForce``, when one is set), the model's nominal continuous force (below;
the SDK does not report it) and ``max_force``; without ``max_force`` it is the first-connection
limit, 1 N (:data:`~arsurf.haptics.hardware.FIRST_FORCE_N`). The result is written back with
``dhdSetMaxForce`` so the SDK enforces it too. A model not in the table needs ``max_force`` and
``workspace`` from its datasheet.

Nominal figures (vendor datasheets; translation workspace as the largest box in the published
cylinder, continuous force, closed-loop stiffness): omega.3/6/7 12 N, Ø 160 x 110 mm, 14.5 N/mm;
delta.3 20 N, Ø 400 x 260 mm, 14.5 N/mm; sigma.7 20 N, Ø 190 x 130 mm, 14.5 N/mm; Falcon 9 N,
101.6 mm cube, 1 N/mm (an approximate figure: check it at bring-up).

**Calibration.** A device the robotic SDK supports (``drdIsSupported``) and that is not calibrated
(``drdIsInitialized`` false, e.g. after power-up) is refused unless ``calibrate=True``: then
``drdAutoInit`` moves the handle by itself to its limits (hands off, workspace clear) and
``drdStop(True)`` hands it back with forces on. The Falcon homes itself in its firmware (pull the
grip out and push it in after power-up).

**Fail-safe on the device.** The firmware watchdog (``dhdSetWatchdog``, read back with
``dhdGetWatchdog``) is set to ``watchdog`` seconds (default 0.02, at most 31.9 ms): if arsurf's loop
stops commanding forces for that long, the device turns its forces off by itself. A device whose
watchdog cannot be set (a firmware without it) is refused, as is ``watchdog=0``, unless
``allow_no_watchdog=True`` (``arsurf live --allow-no-watchdog``): a stalled loop would then keep its
last force until the device is closed. ``watchdog_set`` and ``workspace_source`` are in
:meth:`safety_record` (the session metadata) and in ``arsurf devices``.

Examples
--------
>>> ForceDimensionDevice().axes.spec
'y,-x,z'
"""
from __future__ import annotations

import contextlib
import io
import itertools
import logging
import math
from dataclasses import dataclass

import numpy as np

from arsurf.errors import DeviceNotFound, HapticsError, MissingDependency
from arsurf.haptics.device import DeviceInfo, _vec3
from arsurf.haptics.hardware import AxisMap, BackendReport, HardwareDevice, device_limits

__all__ = ["NOMINAL", "ForceDimensionDevice", "Nominal", "probe", "reachable_box"]

log = logging.getLogger(__name__)

#: The SDK frame in arsurf's (module docstring).
FD_AXES = "y,-x,z"
EXTRA = "forcedimension"


@dataclass(frozen=True)
class Nominal:
    """Datasheet figures of one model: continuous force N, workspace box m (SDK axes), stiffness N/m."""

    name: str
    force: float
    workspace: tuple
    stiffness: float


def _cyl(d_mm: float, h_mm: float) -> tuple:
    s = d_mm / math.sqrt(2.0) * 1e-3  # the square inscribed in the published circle
    return (s, s, h_mm * 1e-3)


_OMEGA = Nominal("omega.x", 12.0, _cyl(160, 110), 14.5e3)
_SIGMA = Nominal("sigma.x", 20.0, _cyl(190, 130), 14.5e3)
#: DHD device type -> nominal figures (module docstring)
NOMINAL = {33: _OMEGA, 34: _OMEGA, 35: _OMEGA, 36: _OMEGA, 37: _OMEGA,
           63: Nominal("delta.3", 20.0, _cyl(400, 260), 14.5e3),
           104: _SIGMA, 105: _SIGMA, 206: _SIGMA,
           60: Nominal("Falcon", 9.0, (0.1016, 0.1016, 0.1016), 1.0e3)}


def _sdk():
    """``(dhd, drd)`` of forcedimension-core, or a :class:`MissingDependency` saying what is missing."""
    quiet = io.StringIO()
    try:
        with contextlib.redirect_stderr(quiet):  # the binding writes its search result to stderr
            from forcedimension_core import dhd, drd
    except ImportError as exc:
        if "libdrd" in str(exc):
            raise MissingDependency(
                "forcedimension-core is installed but the Force Dimension SDK library (libdrd) was not found: install "
                "the SDK and set FDSDK to its folder (it looks in $FDSDK/lib/release/lin-<machine>-gcc/)") from exc
        raise MissingDependency("Force Dimension devices need forcedimension-core; install it with: "
                                f"pip install 'arsurf[{EXTRA}]' (and the vendor SDK, see docs/devices.rst)") from exc
    return dhd, drd


@contextlib.contextmanager
def _expert_mode(dhd):
    """Expert mode on for the block, off after it (the SDK's expert calls need it; the loop does not)."""
    dhd.expert.enableExpertMode()
    try:
        yield
    finally:
        dhd.expert.disableExpertMode()


def _set_watchdog(dhd, i: int, seconds: float) -> bool:
    """Set the firmware watchdog (expert mode) and read it back; True when the device holds it."""
    units = max(1, min(255, round(seconds / 125e-6)))
    if dhd.expert.setWatchdog(units, i) < 0:
        return False
    return dhd.expert.getWatchdog(i) == units


def _type(dhd, i: int) -> int:
    try:
        return int(dhd.getSystemType(i))
    except ValueError:  # a type this binding does not know
        return -1


def reachable_box(dhd, i: int, grid: int = 9, face: int = 7, steps: int = 16):
    """Half extents (m, SDK axes) of the largest box centred on the origin inside the positions
    the handle reaches (module docstring), or None without kinematics. Expert mode must be on."""
    emin, emax = [0] * 8, [0] * 8
    if dhd.expert.getEncRange(emin, emax, i) < 0:
        return None
    lo, hi = np.array(emin[:3]), np.array(emax[:3])
    if not (hi > lo).all():
        return None
    out, enc = [0.0, 0.0, 0.0], [0, 0, 0]
    pts = []
    for e in itertools.product(*(np.linspace(lo[a], hi[a], grid).round().astype(int) for a in range(3))):
        if dhd.expert.deltaEncoderToPosition(tuple(int(x) for x in e), out, i) < 0:
            return None
        pts.append(tuple(out))
    p = np.array(pts)
    bound = np.minimum(-p.min(0), p.max(0))
    if not (np.isfinite(bound).all() and (bound > 0).all()):
        return None
    u = np.linspace(-1.0, 1.0, face)
    cube = np.array([c for c in itertools.product(u, u, u) if np.abs(c).max() == 1.0])  # the unit cube's faces

    def reachable(half) -> bool:
        for q in cube * half:
            if dhd.expert.deltaPositionToEncoder(tuple(float(x) for x in q), enc, i) < 0:
                return False
            if not all(lo[a] <= enc[a] <= hi[a] for a in range(3)):
                return False
        return True

    def grow(half, axis=None) -> np.ndarray:
        """The largest reachable box between ``half`` and the bound, scaling all axes (None) or one."""
        a, b = 0.0, 1.0
        for _ in range(steps):
            m = 0.5 * (a + b)
            if axis is None:
                trial = m * bound
            else:
                trial = half.copy()
                trial[axis] += m * (bound[axis] - half[axis])
            a, b = (m, b) if reachable(trial) else (a, m)
        if axis is None:
            return a * bound
        half = half.copy()
        half[axis] += a * (bound[axis] - half[axis])
        return half

    half = grow(bound)
    for axis in range(3):
        half = grow(half, axis)
    return half if (half > 0).all() else None


class ForceDimensionDevice(HardwareDevice):
    """A Force Dimension device (or a Falcon) through the vendor SDK.

    Parameters
    ----------
    index : int, optional
        Which connected device (``drdOpenID``); None: the first available (``drdOpen``).
    max_force : float, N, optional
        Cap below the device's limit (module docstring).
    workspace : (3,) float, m, optional
        Workspace extents along arsurf x, y, z when the device reports none and the model is not in
        :data:`NOMINAL`.
    calibrate : bool
        Let ``drdAutoInit`` calibrate an uncalibrated device (it moves by itself).
    watchdog : float, s
        Firmware watchdog (0: leave it off; needs ``allow_no_watchdog``).
    allow_no_watchdog : bool
        Run even when the firmware watchdog is not set (recorded in :meth:`safety_record`).
    disconnect_after : float, s
        See :class:`~arsurf.haptics.hardware.HardwareDevice`.

    Attributes
    ----------
    workspace_source : str
        ``"kinematics"`` (measured on the device's own kinematics), ``"nominal"`` or ``"given"``.
    watchdog_set : bool
        Whether the firmware accepted the watchdog.
    """

    def __init__(self, index: int | None = None, *, max_force: float | None = None, workspace=None,
                 calibrate: bool = False, watchdog: float = 0.02, allow_no_watchdog: bool = False,
                 disconnect_after: float = 0.05) -> None:
        super().__init__(AxisMap(FD_AXES), max_force=max_force, disconnect_after=disconnect_after)
        if index is not None and not (isinstance(index, int) and 0 <= index < 128):
            raise HapticsError(f"index must be a device number 0..127 or None (got {index!r})")
        if not (isinstance(watchdog, (int, float)) and 0.0 <= watchdog <= 255 * 125e-6):
            raise HapticsError(f"watchdog must be 0 (off) to {255 * 125e-6:.4f} s (got {watchdog!r})")
        if watchdog == 0 and not allow_no_watchdog:
            raise HapticsError("watchdog=0 turns the device's firmware watchdog off: a stalled loop would keep its "
                               "last force; pass allow_no_watchdog=True (--allow-no-watchdog) to mean it")
        self.allow_no_watchdog = bool(allow_no_watchdog)
        self.index = index
        self.given_workspace = None if workspace is None else _vec3(workspace, "workspace")
        self.calibrate = bool(calibrate)
        self.watchdog = float(watchdog)
        self.workspace_source = ""
        self.watchdog_set = False
        self.device_type = None
        self._id = -1
        self._dhd = self._drd = None
        self._prev_t = math.nan
        self._prev_pos = np.zeros(3)

    # -- connection -------------------------------------------------------------------------------
    def _fail(self, what: str, cls=HapticsError):
        msg = f"Force Dimension: {what} ({self._dhd.errorGetLastStr()})"
        self._release()
        raise cls(msg)

    def _connect(self) -> DeviceInfo:
        dhd, drd = self._dhd, self._drd = _sdk()
        if dhd.getDeviceCount() < 1:
            raise DeviceNotFound("Force Dimension: no device connected (dhdGetDeviceCount = 0); check USB and power")
        self._id = drd.open() if self.index is None else drd.openID(self.index)
        if self._id < 0:
            self._fail("cannot open the device" + ("" if self.index is None else f" #{self.index}"), DeviceNotFound)
        i = self._id
        raw_type = self.device_type = _type(dhd, i)
        name = dhd.getSystemName(i) or f"Force Dimension type {raw_type}"
        if drd.isSupported(i) and not drd.isInitialized(i):
            if not self.calibrate:
                self._release()
                raise HapticsError(f"{name} is not calibrated; open it with calibrate=True: it then moves by itself to "
                                   "its limits for a few seconds (hands off, workspace clear)")
            log.warning("%s: calibrating (drdAutoInit): the handle moves by itself", name)
            if drd.autoInit(i) < 0:
                self._fail(f"{name}: calibration (drdAutoInit) failed")
            if drd.stop(True, i) < 0:
                self._fail(f"{name}: could not hand the device back after calibration (drdStop)")
        nominal = NOMINAL.get(raw_type)
        sdk_cap = float(dhd.getMaxForce(i))
        limits = [x for x in (nominal.force if nominal else None, sdk_cap if sdk_cap > 0 else None) if x is not None]
        source = "SDK kinematics" if nominal is None else f"SDK kinematics, {nominal.name} nominal force"
        with _expert_mode(dhd):
            half = reachable_box(dhd, i)
            self.watchdog_set = self.watchdog > 0 and _set_watchdog(dhd, i, self.watchdog)
            why = dhd.errorGetLastStr()
        if half is not None:
            workspace, self.workspace_source = self.axes.extents(2.0 * half), "kinematics"
        elif self.given_workspace is not None:
            workspace, self.workspace_source = self.given_workspace, "given"
        elif nominal is not None:
            workspace, self.workspace_source = self.axes.extents(nominal.workspace), "nominal"
            source = f"{nominal.name} nominal"
        else:
            self._release()
            raise HapticsError(f"{name} (type {raw_type}) reports no workspace and is not in the nominal table; give "
                               "workspace=(x, y, z) in metres from its datasheet")
        if not self.watchdog_set and self.watchdog > 0:
            if not self.allow_no_watchdog:
                self._release()
                raise HapticsError(f"{name}: its firmware watchdog could not be set ({why}): a stalled loop would keep "
                                   "its last force; update the firmware, or pass allow_no_watchdog=True "
                                   "(--allow-no-watchdog) to run without it")
            log.warning("%s: running without the firmware watchdog (%s), as allowed", name, why)
        stiffness = nominal.stiffness if nominal else 1.0e3
        try:
            info = device_limits(name, min(limits) if limits else None, self.user_max_force, workspace, stiffness,
                                 source=source)
        except HapticsError:
            self._release()
            raise
        if dhd.setMaxForce(info.max_force, i) < 0:
            self._fail(f"{name}: could not set the SDK force limit (dhdSetMaxForce)")
        if dhd.enableForce(True, i) < 0:
            self._fail(f"{name}: could not enable forces")
        self._prev_t = math.nan
        return info

    def safety_record(self) -> dict:
        """The base record plus the firmware watchdog (``watchdog_set``, ``watchdog_s``,
        ``allow_no_watchdog``) and ``workspace_source``."""
        return {**super().safety_record(), "watchdog_set": bool(self.watchdog_set), "watchdog_s": self.watchdog,
                "allow_no_watchdog": self.allow_no_watchdog, "workspace_source": self.workspace_source}

    # -- the servo tick -------------------------------------------------------------------------
    def _poll(self, vpos, vvel):
        dhd, i = self._dhd, self._id
        if dhd.getPosition(vpos, i) < 0:
            return None
        t = self.now()
        if dhd.getLinearVelocity(vvel, i) < 0:
            # the SDK's estimator needs two position updates in its window: difference ours meanwhile
            if not math.isfinite(self._prev_t) or t <= self._prev_t:
                vvel[:] = 0.0
            else:
                vvel[:] = (vpos - self._prev_pos) / (t - self._prev_t)
        self._prev_t = t
        self._prev_pos[:] = vpos
        return int(dhd.getButtonMask(i))

    def _send(self, vforce) -> bool:
        return self._dhd.setForce(vforce, self._id) >= 0

    def _release(self) -> None:
        if self._id >= 0 and self._dhd is not None:
            try:
                self._dhd.enableForce(False, self._id)
                self._drd.close(self._id)
            except Exception:  # noqa: BLE001 - releasing must not raise
                pass
        self._id = -1


def probe() -> BackendReport:
    """Is the SDK there, and which devices answer (each opened and closed at once): its name and
    serial number, whether its firmware watchdog can be set (``watchdog_set``, tried at the
    default 20 ms) and where its workspace would come from (``workspace_source``)."""
    try:
        dhd, drd = _sdk()
    except MissingDependency as exc:
        return BackendReport("forcedimension", False, str(exc))
    import importlib.metadata as md

    detail = f"forcedimension-core {md.version('forcedimension-core')}, SDK {dhd.getSDKVersion()}"
    devices = []
    for k in range(max(0, dhd.getDeviceCount())):
        i = drd.openID(k)
        if i < 0:
            devices.append(f"#{k} busy or not answering ({dhd.errorGetLastStr()})")
            continue
        try:
            with _expert_mode(dhd):
                wd = _set_watchdog(dhd, i, 0.02)
                half = reachable_box(dhd, i)
            source = (f"kinematics ({' x '.join(f'{2e3 * h:.0f}' for h in half)} mm, SDK axes)" if half is not None
                      else "nominal" if _type(dhd, i) in NOMINAL else "none (needs workspace=)")
            devices.append(f"#{k} {dhd.getSystemName(i)} s/n {dhd.getSerialNumber(i)}, watchdog_set "
                           f"{'yes' if wd else 'no (needs --allow-no-watchdog)'}, workspace_source {source}")
        finally:
            drd.close(i)
    return BackendReport("forcedimension", True, detail, devices)
