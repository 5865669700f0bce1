r"""3D Systems Touch, Touch X, Phantom Premium... through OpenHaptics (the HD API).

Through ``pyopenhaptics`` (extra ``arsurf[openhaptics]``; imported as ``pyOpenHaptics``), a thin
ctypes binding that loads ``libHD.so`` (``HD.dll``) by name at import: the OpenHaptics runtime
(and the device driver) must be installed and on the library path.

**Servo thread.** The HD API reads and commands the device only inside *frames* run by its own
servo scheduler (1 kHz, a C thread). The adapter schedules one asynchronous callback that, every
servo tick, opens a frame, reads the transform, velocity and buttons, applies the force arsurf's
loop last commanded and closes the frame. That callback is compiled
(:mod:`arsurf.haptics.hd_servo`: a numba ``cfunc``, no Python, no GIL) and exchanges samples and
forces with arsurf's loop through shared memory under sequence counters, so the device's servo
never waits on a Python thread (on the simulated ``libHD``, with a Python thread holding the GIL,
the servo callback's p99 duration went from 16-22 ms with a Python callback to about 10 us:
``tests/haptics/test_hw_openhaptics.py``). Two safeguards live on the servo
side: a force not renewed for ``command_timeout`` (default 10 ms: arsurf's loop stalled) is
replaced by zero, and a frame that ends in an HD error publishes no sample (arsurf then sees a
missed sample and commands zero; see :mod:`arsurf.haptics.hardware`). ``pyOpenHaptics.get_error``
raises ``KeyError`` on error codes its table lacks (``HD_COMM_ERROR`` among them, the
unplugged-cable error), so the adapter reads ``hdGetError`` itself.

**Frame.** HD: millimetres, mm/s, newtons; :math:`x` right, :math:`y` up, :math:`z` towards the
operator; arsurf's is ``AxisMap("x,-z,y", length_scale=1e-3)``. Home is the centre of the usable
workspace the device reports.

**Limits, from the device.** ``HD_USABLE_WORKSPACE_DIMENSIONS`` (the workspace box),
``HD_NOMINAL_MAX_CONTINUOUS_FORCE`` (the default force limit: what the motors hold without
overheating; ``max_force`` may raise it up to ``HD_NOMINAL_MAX_FORCE``), ``HD_NOMINAL_MAX_STIFFNESS``
and ``HD_NOMINAL_MAX_DAMPING``. ``HD_MAX_FORCE_CLAMPING`` is enabled so the driver clamps too.

**Calibration.** As the vendor's Calibration example does: the status (``hdCheckCalibration``)
and the update (``hdUpdateCalibration``) are called inside synchronous scheduled callbacks, never
from the application thread while the servo runs, and the style is asked of the device
(``HD_CALIBRATION_STYLE``), not assumed: ``HD_CALIBRATION_AUTO`` or ``HD_CALIBRATION_INKWELL`` are
updated when the device says it needs an update; ``HD_CALIBRATION_ENCODER_RESET`` (a Phantom
Premium) zeroes the encoders where the arm *is*, so it is done only with ``calibrate=True``, meaning
"the arm is held in its reset position now" (``arsurf live --calibrate``); otherwise the open is
refused with that instruction. A device that needs manual input (the Touch: put the stylus in its
inkwell) is refused with that instruction.

Examples
--------
>>> OpenHapticsDevice().axes.spec
'x,-z,y'
"""
from __future__ import annotations

import contextlib
import ctypes
import io
import logging
import math
import time

import numpy as np

from arsurf.errors import DeviceNotFound, HapticsError, MissingDependency
from arsurf.haptics.device import DeviceInfo
from arsurf.haptics.hardware import AxisMap, BackendReport, HardwareDevice, device_limits
from arsurf.haptics.hd_servo import ServoBlock, compile_servo

__all__ = ["OpenHapticsDevice", "probe"]

log = logging.getLogger(__name__)
EXTRA = "openhaptics"
HD_AXES = "x,-z,y"
# HD API constants (OpenHaptics hdDefines.h)
HD_INVALID_HANDLE = 0xFFFFFFFF
HD_CALLBACK_DONE, HD_CALLBACK_CONTINUE = 0, 1
HD_CURRENT_BUTTONS, HD_CURRENT_VELOCITY, HD_CURRENT_TRANSFORM, HD_UPDATE_RATE = 0x2000, 0x2051, 0x2052, 0x2600
HD_USABLE_WORKSPACE_DIMENSIONS, HD_CALIBRATION_STYLE = 0x2551, 0x2555
HD_NOMINAL_MAX_STIFFNESS, HD_NOMINAL_MAX_FORCE, HD_NOMINAL_MAX_CONTINUOUS_FORCE = 0x2602, 0x2603, 0x2604
HD_NOMINAL_MAX_DAMPING, HD_CURRENT_FORCE = 0x2609, 0x2700
HD_FORCE_OUTPUT, HD_MAX_FORCE_CLAMPING = 0x4000, 0x4001
HD_CALIBRATION_OK, HD_CALIBRATION_NEEDS_UPDATE, HD_CALIBRATION_NEEDS_MANUAL_INPUT = 0x5000, 0x5001, 0x5002
HD_CALIBRATION_ENCODER_RESET, HD_CALIBRATION_AUTO, HD_CALIBRATION_INKWELL = 1, 2, 4
HD_MAX_SCHEDULER_PRIORITY = (1 << 16) - 1


def _binding():
    """The ``pyOpenHaptics.hd`` module, or a :class:`MissingDependency` saying what is missing."""
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            from pyOpenHaptics import hd
    except ImportError as exc:
        raise MissingDependency("3D Systems devices need pyopenhaptics; install it with: "
                                f"pip install 'arsurf[{EXTRA}]' (and OpenHaptics, see docs/devices.rst)") from exc
    except OSError as exc:  # the binding loads libHD.so at import
        raise MissingDependency(f"pyopenhaptics is installed but the OpenHaptics library libHD.so cannot be loaded "
                                f"({exc}); install OpenHaptics and the device driver and put libHD.so on the "
                                "library path (LD_LIBRARY_PATH)") from exc
    return hd


class OpenHapticsDevice(HardwareDevice):
    """A device of the OpenHaptics HD API (Touch, Touch X, Phantom).

    Parameters
    ----------
    name : str
        The device's configured name (``"Default Device"``: the one set in Touch Setup).
    max_force : float, N, optional
        Force limit; default the device's nominal continuous force, at most its nominal maximum.
    command_timeout : float, s
        The servo thread applies zero force when arsurf's last command is older than this.
    sample_timeout : float, s
        A servo sample older than this is a missed sample for arsurf's loop (default 5 ms: five
        servo ticks).
    calibrate : bool
        An encoder-reset device is in its reset position: update its calibration there.
    disconnect_after : float, s
        See :class:`~arsurf.haptics.hardware.HardwareDevice`.
    """

    def __init__(self, name: str = "Default Device", *, max_force: float | None = None,
                 command_timeout: float = 0.01, sample_timeout: float = 0.005, calibrate: bool = False,
                 disconnect_after: float = 0.05) -> None:
        super().__init__(AxisMap(HD_AXES, length_scale=1e-3), max_force=max_force, disconnect_after=disconnect_after)
        if not isinstance(name, str) or not name:
            raise HapticsError(f"name must be the device's configured name, e.g. 'Default Device' (got {name!r})")
        if not (isinstance(command_timeout, (int, float)) and 0.0 < command_timeout <= 1.0):
            raise HapticsError(f"command_timeout must be in (0, 1] s (got {command_timeout!r})")
        if not (isinstance(sample_timeout, (int, float)) and 0.0 < sample_timeout < disconnect_after):
            raise HapticsError(f"sample_timeout must be positive and below disconnect_after (got {sample_timeout!r} s)")
        self.name = name
        self.command_timeout = float(command_timeout)
        self.sample_timeout = float(sample_timeout)
        self.calibrate = bool(calibrate)
        self.calibration = ""  # what the open found and did (safety_record)
        self._hd = None
        self._id = HD_INVALID_HANDLE
        self._block = None  # the shared block with the compiled servo callback
        self._poll_t = -math.inf
        self._callback = None
        self._handle = 0
        self._scheduled = False

    @property
    def servo_errors(self) -> int:
        """Servo frames that ended in an HD error."""
        return 0 if self._block is None else self._block.errors[0]

    @property
    def last_servo_error(self) -> int:
        """The HD error code of the last of them."""
        return 0 if self._block is None else self._block.errors[1]

    # -- connection -------------------------------------------------------------------------------
    def _connect(self) -> DeviceInfo:
        hd = self._hd = _binding()
        lib = hd._lib_hd
        with contextlib.redirect_stdout(io.StringIO()):  # the binding prints its progress
            self._id = hd.init_device(self.name)
        err = hd._get_error().errorCode
        if self._id is None or self._id == HD_INVALID_HANDLE or err:
            self._id = HD_INVALID_HANDLE
            raise DeviceNotFound(f"OpenHaptics: no device {self.name!r} (hdInitDevice error 0x{err:x}); check Touch "
                                 "Setup, the cable and the driver")
        try:
            model = f"{hd.get_vendor()} {hd.get_model()}"
            box = np.array(hd._get_doublev(HD_USABLE_WORKSPACE_DIMENSIONS, ctypes.c_double * 6))
            fmax = float(hd._get_doublev(HD_NOMINAL_MAX_FORCE, ctypes.c_double).value)
            fcont = float(hd._get_doublev(HD_NOMINAL_MAX_CONTINUOUS_FORCE, ctypes.c_double).value)
            k = float(hd._get_doublev(HD_NOMINAL_MAX_STIFFNESS, ctypes.c_double).value) * 1e3  # N/mm -> N/m
            b = float(hd._get_doublev(HD_NOMINAL_MAX_DAMPING, ctypes.c_double).value) * 1e3  # N s/mm -> N s/m
            lo, hi = box[:3], box[3:]
            if not (np.isfinite(box).all() and (hi > lo).all() and fmax > 0 and fcont > 0 and k > 0):
                raise HapticsError(f"OpenHaptics: {model} reports unusable limits (workspace {box.tolist()} mm, "
                                   f"force {fcont}/{fmax} N, stiffness {k} N/m)")
            self.home = 0.5 * (lo + hi)
            user = self.user_max_force
            if user is not None and user > fmax:
                raise HapticsError(f"max_force {user:g} N is above {model}'s nominal maximum ({fmax:g} N)")
            info = device_limits(model, fcont if user is None else fmax, user, self.axes.extents(hi - lo), k,
                                 b if b > 0 else None, source="OpenHaptics")
            lib.hdEnable.argtypes = [ctypes.c_uint]
            lib.hdEnable(HD_MAX_FORCE_CLAMPING)
            with contextlib.redirect_stdout(io.StringIO()):
                hd.enable_force()
            rate = int(hd._get_integerv(HD_UPDATE_RATE, ctypes.c_int).value) or 1000
            self._block = ServoBlock(self._id, round(self.command_timeout * rate))
            self._callback = compile_servo(lib)
            sched = ctypes.CDLL(lib._name, handle=lib._handle).hdScheduleAsynchronous
            sched.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_ushort]
            sched.restype = ctypes.c_ulong
            self._handle = sched(self._callback.address, self._block.address, HD_MAX_SCHEDULER_PRIORITY)
            self._scheduled = True
            hd.start_scheduler()
            self._calibrate(model)
            deadline = time.perf_counter() + 1.0
            while self._block.sample(np.empty(3), np.empty(3)) is None:
                if time.perf_counter() > deadline:
                    raise DeviceNotFound(f"OpenHaptics: {model} gave no sample within 1 s of starting the servo "
                                         f"scheduler (last HD error 0x{self.last_servo_error:x})")
                time.sleep(0.002)
        except BaseException:
            self._release()
            raise
        return info

    def _in_servo(self, work) -> None:
        """Run ``work()`` inside a synchronous scheduled callback (on the servo thread, in a frame)."""
        hd, lib = self._hd, self._hd._lib_hd
        cb_type = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_void_p)

        def call(_data):
            hd.begin_frame(self._id)
            try:
                work()
            finally:
                hd.end_frame(self._id)
            return HD_CALLBACK_DONE

        cb = cb_type(call)
        lib.hdScheduleSynchronous.argtypes = [cb_type, ctypes.c_void_p, ctypes.c_ushort]
        lib.hdScheduleSynchronous(cb, None, HD_MAX_SCHEDULER_PRIORITY)

    def _calibration_status(self) -> int:
        lib = self._hd._lib_hd
        lib.hdCheckCalibration.restype = ctypes.c_uint
        status = []
        self._in_servo(lambda: status.append(int(lib.hdCheckCalibration())))
        return status[0] if status else HD_CALIBRATION_OK

    def _calibrate(self, model: str) -> None:
        """The vendor's calibration sequence (module docstring): ask the status and the styles,
        update inside a scheduled callback, check again."""
        hd, lib = self._hd, self._hd._lib_hd
        status = self._calibration_status()
        if status == HD_CALIBRATION_OK:
            self.calibration = "ok"
            return
        styles = int(hd._get_integerv(HD_CALIBRATION_STYLE, ctypes.c_int).value)
        if status == HD_CALIBRATION_NEEDS_MANUAL_INPUT:
            raise HapticsError(f"OpenHaptics: {model} needs calibrating by hand: put the stylus in its inkwell (or "
                               "follow Touch Diagnostic's calibration) and open it again")
        style = next((s for s in (HD_CALIBRATION_AUTO, HD_CALIBRATION_INKWELL, HD_CALIBRATION_ENCODER_RESET)
                      if styles & s), None)
        if style is None:
            raise HapticsError(f"OpenHaptics: {model} needs a calibration update but supports no style (0x{styles:x})")
        if style == HD_CALIBRATION_ENCODER_RESET and not self.calibrate:
            raise HapticsError(f"OpenHaptics: {model} needs an encoder-reset calibration: hold its arm in the reset "
                               "position, then open it with calibrate=True (arsurf live --calibrate)")
        log.warning("%s: updating its calibration (style %d) in a scheduled callback", model, style)
        lib.hdUpdateCalibration.argtypes = [ctypes.c_uint]

        def update():
            if int(lib.hdCheckCalibration()) == HD_CALIBRATION_NEEDS_UPDATE:
                lib.hdUpdateCalibration(style)

        self._in_servo(update)
        err = hd._get_error().errorCode
        if err or self._calibration_status() != HD_CALIBRATION_OK:
            raise HapticsError(f"OpenHaptics: {model}: the calibration update (style {style}) did not take (HD error "
                               f"0x{err:x}); calibrate it in Touch Diagnostic and open it again")
        self.calibration = f"updated (style {style})"

    def safety_record(self) -> dict:
        """The base record plus the calibration the open found or did."""
        return {**super().safety_record(), "calibration": self.calibration}

    # -- the arsurf tick ----------------------------------------------------------------------------
    def _poll(self, vpos, vvel):
        got = self._block.sample(vpos, vvel)
        if got is None or not (time.perf_counter() - got[1] <= self.sample_timeout):  # none that recent
            return None
        self._poll_t = got[1]
        return got[0]

    def _sample_time(self) -> float:
        return self._poll_t

    def _send(self, vforce) -> bool:
        self._block.command(vforce)
        return True

    def _release(self) -> None:
        hd = self._hd
        if hd is None:
            return
        if self._block is not None:
            self._block.stop_forces()
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                if self._scheduled:
                    hd.stop_scheduler()
                    hd._lib_hd.hdUnschedule.argtypes = [ctypes.c_ulong]
                    hd._lib_hd.hdUnschedule(self._handle)
                    self._scheduled = False
                if self._id != HD_INVALID_HANDLE:
                    hd.close_device(self._id)
        except Exception:  # noqa: BLE001 - releasing must not raise
            pass
        self._id = HD_INVALID_HANDLE


def probe() -> BackendReport:
    """Is OpenHaptics there, and does the default device answer (initialised and released at once)."""
    try:
        hd = _binding()
    except MissingDependency as exc:
        return BackendReport("openhaptics", False, str(exc))
    import importlib.metadata as md

    detail = f"pyopenhaptics {md.version('pyopenhaptics')}"
    with contextlib.redirect_stdout(io.StringIO()):
        i = hd.init_device("Default Device")
    err = hd._get_error().errorCode
    if i is None or i == HD_INVALID_HANDLE or err:
        return BackendReport("openhaptics", True, detail, [])
    name = f"{hd.get_vendor()} {hd.get_model()}"
    with contextlib.redirect_stdout(io.StringIO()):
        hd.close_device(i)
    return BackendReport("openhaptics", True, detail, [f"'Default Device': {name}"])
