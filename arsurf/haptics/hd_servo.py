r"""The OpenHaptics servo callback, compiled: it runs on the HD servo thread without Python's GIL.

The HD scheduler calls one function per servo tick (1 kHz) from its own C thread. A Python
callback there must take the GIL first, and waits whenever arsurf's loop thread (or any other
Python thread) holds it: on the simulated ``libHD`` the samples it published were up to 5.6 ms old
(p99) against a 1 ms servo period. This callback is a numba ``cfunc`` (machine code with a C
signature) that calls the HD functions through their C entry points, so the servo never waits on
Python. It exchanges data with arsurf's thread through one shared block of 64-bit slots, each side
writing under a *sequence counter* (a seqlock: the writer makes the counter odd, writes, makes it
even; a reader that sees it odd, or changed across its copy, reads again):

- sample (servo -> arsurf): position (mm), velocity (mm/s), buttons, the time it was read
  (``CLOCK_MONOTONIC`` s, the clock of :func:`time.perf_counter` on Linux), the last HD error;
- command (arsurf -> servo): the force (N, HD frame). The servo counts its ticks since the command
  last changed and applies zero once that exceeds the command timeout (arsurf's loop stalled).

A frame that ends in an HD error publishes no sample (its count and code are kept). The two halves
of a seqlock write are separated by opaque C calls (``clock_gettime``), which the compiler cannot
move stores across; the hardware keeps the order on x86-64 (total store order).

``hdGetError`` returns a 12-byte struct; numba calls C functions through ctypes types without
structs, so it is declared as returning a 64-bit integer whose low 32 bits are the struct's first
field, ``errorCode``: how the System V x86-64 and AArch64 calling conventions return a struct of
at most 16 bytes (in registers). :func:`compile_servo` refuses other platforms.
"""
from __future__ import annotations

import ctypes
import platform
import sys

import numpy as np

from arsurf._layout import Layout
from arsurf.errors import HapticsError

__all__ = ["SERVO_BLOCK", "SIZE", "ServoBlock", "compile_servo"]

#: the shared block, 64-bit slots read as int64 or float64: the sample (its sequence counter,
#: position mm, velocity mm/s, buttons, time s, the last HD error and their count), the device
#: handle, the command (its sequence counter, force N, the counter the servo last took, its age in
#: ticks, the timeout in ticks) and the servo's scratch (two timespecs, the 4x4 transform, the
#: button word, the velocity, the force it applies, a zero force)
SERVO_BLOCK = Layout("OpenHaptics servo block", [
    ("seq", 1), ("position", 3), ("velocity", 3), ("buttons", 1), ("time", 1), ("error", 1), ("errors", 1),
    ("device", 1), ("command_seq", 1), ("force", 3), ("seen", 1), ("age", 1), ("timeout", 1), ("clock", 2),
    ("clock_after", 2), ("transform", 16), ("button_word", 1), ("velocity_read", 3), ("out", 3), ("zero", 3)])
(_SEQ, _POS, _VEL, _BUTTONS, _T, _ERR, _NERR, _DEV, _CSEQ, _FORCE, _SEEN, _AGE, _TIMEOUT, _TS, _TS2, _XFORM, _IBUF,
 _VBUF, _OUT, _ZERO) = (SERVO_BLOCK.offset(f) for f in SERVO_BLOCK.fields)
SIZE = SERVO_BLOCK.size
HD_CURRENT_BUTTONS, HD_CURRENT_VELOCITY, HD_CURRENT_TRANSFORM, HD_CURRENT_FORCE = 0x2000, 0x2051, 0x2052, 0x2700
CLOCK_MONOTONIC = 1


def _supported() -> bool:
    return sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64", "aarch64", "arm64")


def compile_servo(lib: ctypes.CDLL):
    """The compiled servo callback for the loaded ``libHD`` (a numba ``cfunc``; its ``address`` is
    the C function pointer to schedule, its user data a :class:`ServoBlock`'s ``address``)."""
    if not _supported():
        raise HapticsError(f"the compiled OpenHaptics servo callback supports Linux on x86-64 and AArch64 (this is "
                           f"{sys.platform} {platform.machine()})")
    import numba as nb

    own = ctypes.CDLL(lib._name, handle=lib._handle)  # our own prototypes: the binding's stay as they are
    u, p = ctypes.c_uint, ctypes.c_void_p
    begin, end, getd, geti, setd, error = (own.hdBeginFrame, own.hdEndFrame, own.hdGetDoublev, own.hdGetIntegerv,
                                           own.hdSetDoublev, own.hdGetError)
    for fn, args in ((begin, [u]), (end, [u]), (getd, [u, p]), (geti, [u, p]), (setd, [u, p])):
        fn.argtypes, fn.restype = args, None
    error.argtypes, error.restype = [], ctypes.c_uint64
    libc = ctypes.CDLL(None)
    clock = libc.clock_gettime
    clock.argtypes, clock.restype = [ctypes.c_int, p], ctypes.c_int

    @nb.cfunc(nb.types.uint32(nb.types.voidptr), nopython=True)
    def servo(data):  # pragma: no cover - runs on the HD servo thread
        f = nb.carray(data, (SIZE,), np.float64)
        i = nb.carray(data, (SIZE,), np.int64)
        base = f.ctypes.data
        dev = np.uint32(i[_DEV])
        begin(dev)
        getd(HD_CURRENT_TRANSFORM, base + 8 * _XFORM)
        getd(HD_CURRENT_VELOCITY, base + 8 * _VBUF)
        i[_IBUF] = 0
        geti(HD_CURRENT_BUTTONS, base + 8 * _IBUF)
        c = i[_CSEQ]  # the command, read under its sequence counter
        if c % 2 == 0 and c != i[_SEEN]:
            fx, fy, fz = f[_FORCE], f[_FORCE + 1], f[_FORCE + 2]
            if i[_CSEQ] == c:
                f[_OUT], f[_OUT + 1], f[_OUT + 2] = fx, fy, fz
                i[_SEEN], i[_AGE] = c, 0
            else:
                i[_AGE] += 1
        else:
            i[_AGE] += 1
        out = _OUT if i[_AGE] <= i[_TIMEOUT] else _ZERO
        setd(HD_CURRENT_FORCE, base + 8 * out)
        end(dev)
        err = error() & 0xFFFFFFFF
        if err != 0:
            i[_ERR] = err
            i[_NERR] += 1
            return 1  # HD_CALLBACK_CONTINUE, no sample
        s = i[_SEQ]
        i[_SEQ] = s + 1
        clock(CLOCK_MONOTONIC, base + 8 * _TS)  # opaque call: the odd counter is stored before the data
        f[_POS], f[_POS + 1], f[_POS + 2] = f[_XFORM + 12], f[_XFORM + 13], f[_XFORM + 14]  # translation column
        f[_VEL], f[_VEL + 1], f[_VEL + 2] = f[_VBUF], f[_VBUF + 1], f[_VBUF + 2]
        i[_BUTTONS] = i[_IBUF] & 0xFFFFFFFF
        f[_T] = i[_TS] + 1e-9 * i[_TS + 1]
        clock(CLOCK_MONOTONIC, base + 8 * _TS2)  # and the data before the even counter
        i[_SEQ] = s + 2
        return 1

    return servo


class ServoBlock:
    """The shared block between the compiled servo callback and arsurf's thread.

    Parameters
    ----------
    device : int
        The HD device handle.
    timeout_ticks : int
        Servo ticks without a new command after which the servo applies zero force.
    """

    def __init__(self, device: int, timeout_ticks: int) -> None:
        self._f = SERVO_BLOCK.zeros()
        self._i = self._f.view(np.int64)
        self._i[_DEV] = int(device)
        self._i[_TIMEOUT] = max(1, int(timeout_ticks))
        self._i[_AGE] = 1 << 40  # no command yet: zero force
        self.address = self._f.ctypes.data

    def sample(self, vpos: np.ndarray, vvel: np.ndarray):
        """Copy the latest sample into ``vpos`` (mm), ``vvel`` (mm/s); ``(buttons, time s)`` or
        None when the servo has published none (or kept writing through four tries)."""
        i, f = self._i, self._f
        for _ in range(4):
            s = int(i[_SEQ])
            if s == 0 or s & 1:
                if s == 0:
                    return None
                continue
            vpos[:] = f[_POS:_POS + 3]
            vvel[:] = f[_VEL:_VEL + 3]
            buttons, t = int(i[_BUTTONS]), float(f[_T])
            if int(i[_SEQ]) == s:
                return buttons, t
        return None

    def command(self, vforce) -> None:
        """Publish the force (N, HD frame) for the servo's next tick."""
        i = self._i
        c = int(i[_CSEQ])
        i[_CSEQ] = c + 1
        self._f[_FORCE:_FORCE + 3] = vforce
        i[_CSEQ] = c + 2

    def stop_forces(self) -> None:
        """Make the servo apply zero from its next tick (the command is as old as it gets)."""
        self.command((0.0, 0.0, 0.0))

    @property
    def errors(self) -> tuple[int, int]:
        """``(frames that ended in an HD error, the last error code)``."""
        return int(self._i[_NERR]), int(self._i[_ERR])
