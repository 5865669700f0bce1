r"""Haply Inverse3 (and its VerseGrip handle) over USB serial.

Through ``haplyhardwareapi`` (extra ``arsurf[haply]``; imported as ``HaplyHardwareAPI``), the
vendor's compiled binding. Its serial protocol, as the package (0.1.x) speaks it, one command
byte then little-endian ``float32`` fields:

===========================  ====================================================================
host -> Inverse3             Inverse3 -> host
===========================  ====================================================================
``0A`` wake-up               ``0B`` u16 device id, u8 model, u8 hardware, u8 firmware, 16-byte UUID
``2A`` force x, y, z (N)     ``2B`` position x, y, z (m), velocity x, y, z (m/s)
===========================  ====================================================================

and for the handle (its own serial port): ``0A`` -> ``D0`` + 6 bytes of information; ``DA``
(status request) -> ``DA`` u16 device id, u8 error flag, u8 Hall sensor level, quaternion (4
``float32``), u8 n, then n bytes of user data, the first of which holds the buttons (bit 0: the
main button).

**The package never raises on a dead link.** A read that times out prints a line on stderr and
returns zeros (a wake-up even returns uninitialised memory as the device id). The adapter
treats an all-zero state (a position at the base's origin, where the handle cannot be, and a
velocity of exactly zero) as a missed sample, drains the input before every exchange so a late
reply (which the package, reading whatever bytes come first, returns as the next exchange's) can
answer at most one later command, and checks that the wake-up answered with a non-zero UUID (1 s).

**The loop never waits on the serial port.** The package's exchange (``end_effector_force``: the
force out, the state back) busy-polls the port for the reply's header, up to ``read_timeout``,
then for its body, up to ``read_timeout`` again: a lost reply costs its caller two read timeouts
(observed on 0.1.13). The Inverse3 answers only a command ("you must send a force value to the
device" to read its position, Haply's Inverse Service documentation), so one exchange per loop
tick. A thread of the adapter's own, :class:`Inverse3Link`, owns the port and makes every
exchange; the loop swaps data with it through two mailboxes, each one immutable tuple replaced
whole (an atomic reference swap in CPython, no lock):

- *state* (link -> loop): a sequence number, the time the reply arrived, position and velocity.
  ``read_state`` takes the latest and never blocks; a state older than ``sample_timeout`` (default
  5 ms), or older than a lost reply, is a missed sample (timestamp :math:`-\infty`: the safety
  layer flags it ``STALE`` and commands zero in that tick), and ``disconnect_after`` of them in a
  row end the session;
- *command* (loop -> link): the force, when it was commanded, and the sequence number of the state
  it was computed from. ``command_force`` stores it and wakes the link, which sends it at once.

**A lost reply: the retry carries zero.** When a reply is lost (the package returns zeros), the
link retries at once with zero force, and keeps sending zero until a command
computed from a state newer than the loss arrives: the held force is never sent again on a state
the loop has not seen. Between commands the link exchanges every :data:`LINK_PERIOD` (1 ms, the
period of Haply's own examples) so the state stays fresh when the loop commands nothing (the
bring-up's reads); a command older than ``command_timeout`` (10 ms: the loop stalled) goes out as
zero.

**Frame.** The Inverse3's own, as Haply documents it ("Developing with Inverse3" and the Inverse
Service's "Basis Permutation" page, docs.haply.co): right-handed, metres, origin on the flat face
of the mounting plate near its centre, axes on the device's plaque: :math:`x` right, :math:`y`
forward (away from the operator), :math:`z` up - arsurf's own axes, ``AxisMap("x,y,z")``
(``axes=`` changes it, e.g. for a device mounted turned). ``HaplyHardwareAPI`` 0.1.x passes the
firmware's frame through unchanged (no basis permutation, unlike the Inverse Service); check the
axes and the force sign at bring-up (docs/bringup.rst). Home is where the handle is when the
device is opened (hold it where you want the middle of the workspace), or ``home=(x, y, z)`` in
the device's frame.

**Limits.** The device reports none over this protocol. The force limit is ``max_force`` (N) up
to :data:`MAX_FORCE_N`, the Inverse3's published peak force; without it, the first-connection
limit of 1 N (:data:`~arsurf.haptics.hardware.FIRST_FORCE_N`). ``workspace`` ((3,) m, centred on
home) is required, from your bring-up sweep; ``stiffness`` defaults to a conservative 1 kN/m. A silent handle (no status for ``handle_timeout``) reads as its main button
held: the disengage button, so the force is zero until the handle answers again.

Examples
--------
>>> HaplyDevice(port="/dev/ttyACM0", max_force=3.0, workspace=(0.2, 0.12, 0.15)).axes.spec
'x,y,z'
"""
from __future__ import annotations

import atexit
import logging
import math
import os
import threading
import time
import weakref

import numpy as np

from arsurf.errors import DeviceNotFound, HapticsError, MissingDependency
from arsurf.haptics.device import BUTTON_1, DeviceInfo, _vec3
from arsurf.haptics.hardware import AxisMap, BackendReport, HardwareDevice, device_limits

__all__ = ["HaplyDevice", "Inverse3Link", "probe"]

log = logging.getLogger(__name__)
EXTRA = "haply"
_ZERO = np.zeros(3)
#: N: the Inverse3's published peak force, the most ``max_force`` may ask for (module docstring)
MAX_FORCE_N = 10.0


_HANDLE_CLASS = []


def _handle_class(api):
    """A subclass of the binding's ``Handle`` whose status callback stores the buttons in its device
    (made once: a Python subclass of a pybind11 class made per call crashes at interpreter exit)."""
    if not _HANDLE_CLASS:
        class _Handle(api.Handle):
            device = None

            def OnReceiveHandleStatusMessage(self, device_id, quaternion, error_flag, hall, n, user_data):
                dev = self.device() if self.device is not None else None
                if dev is not None:
                    dev._buttons = int(user_data[0]) & 0xFF if n > 0 else 0
                    dev._buttons_t = time.perf_counter()

        _HANDLE_CLASS.append(_Handle)
    return _HANDLE_CLASS[0]


def _api():
    try:
        import HaplyHardwareAPI
    except ImportError as exc:
        raise MissingDependency("Haply devices need haplyhardwareapi; install it with: "
                                f"pip install 'arsurf[{EXTRA}]'") from exc
    return HaplyHardwareAPI


#: s: the longest time between two exchanges of the link (module docstring)
LINK_PERIOD = 1e-3
#: zero-force exchanges ``open()`` tries for the first state, each waiting ``read_timeout``
FIRST_EXCHANGES = 50


def _lost(pos, vel) -> bool:
    """The package's answer to a reply that never came: all zeros (module docstring)."""
    return not any(pos) and not any(vel)


class Inverse3Link:
    """The thread that owns the Inverse3's port: every exchange, the loop's mailboxes (module
    docstring).

    Parameters
    ----------
    inv : HaplyHardwareAPI.Inverse3
        The woken device (anything with ``end_effector_force(force) -> (position, velocity)`` and
        ``flush_input()``).
    clock : callable
        Seconds, the clock of the states' timestamps and the commands' times.
    command_timeout : float, s
        A command older than this is sent as zero.
    period : float, s
        Longest time between two exchanges (the loop's commands come sooner).
    keep : tuple
        Objects the thread holds for as long as it runs (the binding's stream: freeing it under a
        running exchange would crash).

    Attributes
    ----------
    exchanges, lost_replies, zero_retries, stale_commands : int
        Exchanges made; replies lost; exchanges sent as zero because of a lost reply, and because
        the command was older than ``command_timeout``.
    zero_below : int
        States numbered below this are older than a lost reply: the commands computed from them go
        out as zero, and the loop reads them as missed samples.
    """

    def __init__(self, inv, clock, command_timeout: float = 0.01, period: float = 1e-3, keep: tuple = ()) -> None:
        self._inv = inv
        self._clock = clock
        self.command_timeout = float(command_timeout)
        self.period = float(period)
        self._keep = keep
        self._state = None  # (seq, time s, position (3,) m, velocity (3,) m/s): replaced whole
        self._command = (0.0, 0.0, 0.0, -math.inf, 0)  # (fx, fy, fz N, time s, seq of its state): replaced whole
        self._seq = 0
        self.zero_below = 0  # commands computed from a state older than this sequence number are sent as zero
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = None
        self.exchanges = self.lost_replies = self.zero_retries = self.stale_commands = 0

    # -- the loop's side: never blocks --------------------------------------------------------------
    def latest(self):
        """``(seq, time s, position, velocity)`` of the latest state, or None before the first."""
        return self._state

    def command(self, fx: float, fy: float, fz: float, seq: int) -> None:
        """Send this force (N, Inverse3 frame), computed from the state ``seq``, at the next exchange."""
        self._command = (fx, fy, fz, self._clock(), seq)
        self._wake.set()

    # -- the link's side ------------------------------------------------------------------------------
    def publish(self, pos, vel) -> None:
        """A state that arrived now becomes the latest (``open()`` seeds the first)."""
        self._seq += 1
        self._state = (self._seq, self._clock(), tuple(pos), tuple(vel))

    def exchange(self) -> bool:
        """One exchange: the command (zero after a lost reply, or when it is too old) out, the state
        back; False when the reply was lost."""
        fx, fy, fz, t, seq = self._command
        if seq < self.zero_below:
            fx = fy = fz = 0.0
            self.zero_retries += 1
        elif not (self._clock() - t <= self.command_timeout):
            fx = fy = fz = 0.0
            self.stale_commands += 1
        self.exchanges += 1
        try:
            self._inv.flush_input()  # a late reply (or its successor) must not answer this command
            pos, vel = self._inv.end_effector_force([fx, fy, fz])
        except Exception:  # noqa: BLE001 - the package does not raise on a dead link; treat it as a lost reply
            pos = vel = (0.0, 0.0, 0.0)
        if _lost(pos, vel):
            self.lost_replies += 1
            self.zero_below = self._seq + 1  # until a command computed from the next state: zero
            return False
        self.publish(pos, vel)
        return True

    def _run(self) -> None:
        wake, stop = self._wake, self._stop
        while not stop.is_set():
            wake.wait(self.period)
            wake.clear()
            if stop.is_set():
                break
            if not self.exchange():
                wake.set()  # the retry, with zero, at once
        self._command = (0.0, 0.0, 0.0, -math.inf, 0)
        self.exchange()  # the last command: zero

    def start(self) -> None:
        """Run the exchanges on the link's thread (a daemon; :meth:`stop` at the latest at exit)."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="arsurf-haply-link", daemon=True)
        self._thread.start()
        atexit.register(self.stop)

    def stop(self, timeout: float = 1.0) -> None:
        """Send zero, end the thread (waits at most ``timeout`` s; never raises)."""
        atexit.unregister(self.stop)
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None


class HaplyDevice(HardwareDevice):
    """An Inverse3, with or without its handle.

    Parameters
    ----------
    port : str, optional
        Serial port of the Inverse3 (None: the first ``detect_inverse3s()`` finds).
    max_force : float, N, optional
        Force limit, at most :data:`MAX_FORCE_N` (None: the first-connection 1 N).
    workspace : (3,) float, m
        Workspace extents along arsurf x, y, z, centred on home (required).
    stiffness : float, N/m
        Largest stiffness to render (default 1000).
    handle_port : str, optional
        Serial port of the handle (``"auto"``: the first ``detect_handles()`` finds; None: no
        handle, no buttons).
    home : (3,) float, m, optional
        Home in the Inverse3 frame (None: where the handle is at opening).
    axes : str
        Vendor axes behind arsurf x, y, z (:class:`~arsurf.haptics.hardware.AxisMap`).
    read_timeout : float, s
        The package's wait for each half of a reply, on the link's thread (default 1 ms; a lost
        reply holds the link, never the loop, for twice this before the retry with zero).
    sample_timeout : float, s
        A state older than this is a missed sample for the loop (default 5 ms).
    command_timeout : float, s
        A command older than this is sent as zero (default 10 ms: the loop stalled).
    handle_timeout : float, s
        Silence of the handle that reads as disengaged.
    disconnect_after : float, s
        See :class:`~arsurf.haptics.hardware.HardwareDevice`.
    """

    def __init__(self, port: str | None = None, *, max_force: float | None = None, workspace=None,
                 stiffness: float = 1000.0, handle_port: str | None = None, home=None, axes: str = "x,y,z",
                 read_timeout: float = 0.001, sample_timeout: float = 0.005, command_timeout: float = 0.01,
                 handle_timeout: float = 0.1, disconnect_after: float = 0.05) -> None:
        super().__init__(AxisMap(axes), max_force=max_force, disconnect_after=disconnect_after)
        for name, v in (("port", port), ("handle_port", handle_port)):
            if v is not None and not (isinstance(v, str) and v):
                raise HapticsError(f"{name} must be a serial port path or None (got {v!r})")
        if workspace is None:
            raise HapticsError("the Inverse3 reports no workspace: give workspace=(x, y, z) in metres (the box, "
                               "centred on home, the handle may use; see the bring-up checklist in docs/bringup.rst)")
        self.workspace = _vec3(workspace, "workspace")
        if (self.workspace <= 0).any():
            raise HapticsError(f"workspace extents must be positive metres (got {self.workspace.tolist()})")
        if not (isinstance(stiffness, (int, float)) and stiffness > 0):
            raise HapticsError(f"stiffness must be positive N/m (got {stiffness!r})")
        for name, v in (("read_timeout", read_timeout), ("handle_timeout", handle_timeout),
                        ("command_timeout", command_timeout)):
            if not (isinstance(v, (int, float)) and 0.0 < v <= 1.0):
                raise HapticsError(f"{name} must be in (0, 1] s (got {v!r})")
        if not (isinstance(sample_timeout, (int, float)) and 0.0 < sample_timeout < self.disconnect_after):
            raise HapticsError(f"sample_timeout must be positive and below disconnect_after "
                               f"({self.disconnect_after:g} s) (got {sample_timeout!r} s)")
        self.port = port
        self.handle_port = handle_port
        self.given_home = None if home is None else _vec3(home, "home")
        self.stiffness = float(stiffness)
        self.read_timeout = float(read_timeout)
        self.sample_timeout = float(sample_timeout)
        self.command_timeout = float(command_timeout)
        self.handle_timeout = float(handle_timeout)
        self.device_id = None
        self._inv = None
        self._stream = None
        self._handle = None
        self._handle_stream = None
        self._handle_thread = None
        self._handle_stop = threading.Event()
        self._buttons = 0
        self._buttons_t = -np.inf
        self.link: Inverse3Link | None = None
        self._xt = -math.inf  # when the state the loop read last arrived
        self._xseq = 0  # and its sequence number: the basis of the next command

    # -- connection -------------------------------------------------------------------------------
    def _connect(self) -> DeviceInfo:
        api = _api()
        port = self.port
        if port is None:
            found = api.detect_inverse3s()
            if not found:
                raise DeviceNotFound("Haply: no Inverse3 found (detect_inverse3s); check USB and power, and that you "
                                     "may open serial ports (group dialout)")
            port = found[0]
        if not os.path.exists(port):
            raise DeviceNotFound(f"Haply: serial port {port} does not exist")
        try:
            self._stream = api.SerialStream(port)
            self._inv = api.Inverse3(self._stream, 1.0)  # keeps a C++ reference to the stream: so do we
            info = self._inv.device_wakeup_dict()
            raw = getattr(info.get("device_id_ext"), "bytes", b"")
            raw = bytes(raw() if callable(raw) else raw)  # uuid.UUID, or the package's own UUID type
            if not any(raw):
                raise DeviceNotFound(f"Haply: no Inverse3 answered the wake-up on {port} (within 1 s)")
            self.device_id = raw.hex()
            self._inv.set_read_timeout(self.read_timeout)
            # exchanges at zero force: the home, and proof that the device answers at the loop's timeout;
            # the first replies after the wake-up may come late (a lost reply reads as all zeros), so
            # up to FIRST_EXCHANGES tries, about as long as the wake-up's own 1 s at most
            for _ in range(FIRST_EXCHANGES):
                pos, vel = self._inv.end_effector_force([0.0, 0.0, 0.0])
                if not _lost(pos, vel):
                    break
            else:
                raise DeviceNotFound(f"Haply: the Inverse3 on {port} woke up but sends no state "
                                     f"({FIRST_EXCHANGES} exchanges of {self.read_timeout * 1e3:g} ms)")
            self.home = np.array(pos, dtype=np.float64) if self.given_home is None else self.given_home
            self.link = Inverse3Link(self._inv, self.now, self.command_timeout, LINK_PERIOD, keep=(self._stream,))
            self.link.publish(pos, vel)
            self._xt, self._xseq = -math.inf, 0
            self.link.start()
            if self.handle_port is not None:
                self._start_handle(api)
            return device_limits(f"Haply Inverse3 {self.device_id[:8]}", MAX_FORCE_N, self.user_max_force,
                                 self.workspace, self.stiffness, source="published peak force, given workspace")
        except BaseException:
            self._release()
            raise

    def _start_handle(self, api) -> None:
        port = self.handle_port
        if port == "auto":
            found = api.detect_handles()
            if not found:
                raise DeviceNotFound("Haply: handle_port='auto' but no handle was found (detect_handles)")
            port = found[0]
        if not os.path.exists(port):
            raise DeviceNotFound(f"Haply: handle serial port {port} does not exist")
        self._handle_stream = api.SerialStream(port)  # the Handle keeps a reference to it, not a Python one
        self._handle = _handle_class(api)(self._handle_stream)
        self._handle.device = weakref.ref(self)
        self._handle.SendDeviceWakeup()
        self._handle.Receive()
        self._handle_stop.clear()
        # the thread holds the handle and its stream: a Receive may block for seconds when the
        # handle is gone, and freeing either under it would crash; it is not a daemon, so the
        # interpreter waits for it rather than freeing them under it at exit
        self._handle_thread = threading.Thread(target=self._handle_loop, args=(self._handle, self._handle_stream,
                                                                            self._handle_stop),
                                               name="arsurf-haply-handle")
        self._handle_thread.start()

    @staticmethod
    def _handle_loop(h, stream, stop) -> None:
        while not stop.is_set():
            try:
                h.RequestStatus()
                h.Receive()
            except Exception:  # noqa: BLE001 - a silent handle reads as disengaged (see _poll)
                time.sleep(0.01)
            time.sleep(0.002)

    def safety_record(self) -> dict:
        """The base record plus the link's timeouts (``read_timeout_s``, ``sample_timeout_s``,
        ``command_timeout_s``) and ``workspace_source`` (always ``given``)."""
        return {**super().safety_record(), "read_timeout_s": self.read_timeout, "sample_timeout_s": self.sample_timeout,
                "command_timeout_s": self.command_timeout, "workspace_source": "given"}

    # -- the servo tick: the link's mailboxes, never the port ----------------------------------------
    def _poll(self, vpos, vvel):
        got = self.link.latest()
        if got is None:
            return None
        seq, t, pos, vel = got
        if seq < self.link.zero_below or not (self.now() - t <= self.sample_timeout):
            return None  # a reply lost since (the device is being sent zero), or none that recent: missed
        self._xseq, self._xt = seq, t
        vpos[:] = pos
        vvel[:] = vel
        if self._handle is None:
            return 0
        if time.perf_counter() - self._buttons_t > self.handle_timeout:
            return BUTTON_1  # the handle is silent: disengaged
        return self._buttons

    def _sample_time(self) -> float:
        return self._xt

    def _send(self, vforce) -> bool:
        self.link.command(float(vforce[0]), float(vforce[1]), float(vforce[2]), self._xseq)
        return True

    def _release(self) -> None:
        self._handle_stop.set()
        if self._handle_thread is not None:
            self._handle_thread.join(timeout=0.5)  # if it is still in a Receive, it ends when that times out
            self._handle_thread = None
        self._handle = None  # each binding object before the stream it reads
        self._handle_stream = None
        if self.link is not None:
            # its last exchange sends zero; a link stuck in a dead port's waits keeps the binding's
            # objects until it ends (at most 2 read_timeout per exchange)
            self.link.stop(timeout=4 * self.read_timeout + 0.5)
        self._inv = None
        self._stream = None


def probe() -> BackendReport:
    """Is the package there, and which Inverse3s and handles does it detect."""
    try:
        api = _api()
    except MissingDependency as exc:
        return BackendReport("haply", False, str(exc))
    import importlib.metadata as md

    devices = [f"Inverse3 on {p}" for p in api.detect_inverse3s()] + [f"handle on {p}" for p in api.detect_handles()]
    return BackendReport("haply", True, f"haplyhardwareapi {md.version('haplyhardwareapi')}", devices)
