r"""A simulated Nanonis controller: the TCP programming interface in front of any instrument.

:class:`NanonisSimulator` listens on a loopback port and answers the commands of
:data:`~arsurf.instrument.nanonis_protocol.COMMANDS` as the Nanonis software does (message
layout, error section, one command after the other per connection, up to four connections),
driving an :class:`~arsurf.instrument.interface.Instrument` - in practice a
:class:`~arsurf.instrument.instrument.VirtualAFM`, whose physics then stands behind the
controller's signals. The signal list is a Nanonis one (``X (m)``, ``Y (m)``, ``Z (m)``,
``Input 1 (V)`` ...); the two inputs wired to the photodiode read the instrument's deflection and
torsion signals times ``volts_per_unit``.

Behaviour taken from the protocol document where it says it, and chosen here where it does not
(said so): ``ZCtrl.ZPosSet`` with the Z controller on is refused with an error (the document:
"to change the Z-position of the tip, the Z-controller must be switched OFF"); an auto-approach
started by ``AutoApproach.OnOffSet`` runs in the background (``AutoApproach.OnOffGet`` reads 1
until it ends; other commands wait for it, chosen); a command the
simulator does not implement gets an error reply (chosen); a request whose header or body is not
the protocol closes the connection (chosen). An instrument's refusal (a target outside its
limits) becomes the reply's error description.

Timing, from the vendor's documentation of ``Signals.ValsGet`` (nanonis-spm 1.0.9's docstring,
the TCP protocol document): the TCP receiver acquires in periods of Tap (``Util.AcqPeriodGet/Set``,
default ``tap`` 20 ms here: chosen, the real one is read at open) and ``Signals.ValsGet`` answers
at the end of the current period, 0 to Tap after the call (waiting for newest data: the end of
the next one, Tap to 2 Tap); every reply also takes ``latency`` (default 1 ms: chosen, a
LabVIEW TCP server's command handling on a lab PC; the document gives no figure). The
``Signals.NamesGet`` array's declared byte size counts the strings' length prefixes unless
``names_size="strings"``: the document does not say which, and a controller may count only the
strings.
Scanning: ``Scan.Action`` 0 starts a frame in the background (the instrument's
:meth:`~arsurf.instrument.interface.Instrument.scan_image`, on the raster ``scan_settings`` in
the direction asked), ``Scan.StatusGet`` reads 1 and ``Scan.WaitEndOfScan`` waits until it ends;
``Scan.FrameGet``/``BufferGet``/``SpeedGet`` describe the raster and ``Scan.FrameDataGrab`` sends
the forward Z data in the order scanned (the top line first for a scan down, as the .sxm file
stores it; chosen: the document does not say). The buffer records one channel, index 0, ``Z (m)``;
the backward image and the actions other than start and stop are refused (chosen).

Faults, for the tests and the benchmark (:class:`Faults`, changeable while it runs): a delay
before replies (slow replies), replies that stop coming (a stalled controller), a connection
closed after some replies (a dead one), error replies to chosen commands, and corrupt replies.

Examples
--------
>>> from arsurf.instrument.instrument import VirtualAFM
>>> from arsurf.instrument.nanonis import NanonisConnection
>>> with NanonisSimulator(VirtualAFM(0.0, probe_height=1e-6, tip_xy=(5e-6, 5e-6))) as sim:
...     link = NanonisConnection(*sim.address)
...     link.open()
...     x, y = link.call("FolMe.XYPosGet", 0)
...     link.close()
>>> round(x * 1e6, 6), round(y * 1e6, 6)
(5.0, 5.0)
"""
from __future__ import annotations

import math
import socket
import struct
import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np

from arsurf.errors import InstrumentError, InstrumentLinkLost
from arsurf.instrument import nanonis_protocol as proto
from arsurf.instrument.interface import Instrument, InstrumentSample

__all__ = ["Faults", "NanonisSimulator", "SIGNAL_NAMES"]


def _signal_names() -> tuple[str, ...]:
    """A Nanonis-like list of 128 signal names (the real one depends on the controller's setup)."""
    names = ["Current (A)", "Bias (V)"]
    names += [f"Input {k} (V)" for k in range(1, 9)]
    names += [f"Output {k} (V)" for k in range(1, 9)]
    names += ["X (m)", "Y (m)", "Z (m)", "Phase (deg)", "Amplitude (m)", "Frequency Shift (Hz)", "Excitation (V)"]
    names += [f"Internal {k} (V)" for k in range(1, 128 - len(names) + 1)]
    return tuple(names[:128])


SIGNAL_NAMES = _signal_names()
_MAX_CONNECTIONS = 4  # the Nanonis server accepts up to four connections


@dataclass
class Faults:
    """What the simulated controller does wrong (attributes may change while it runs).

    Attributes
    ----------
    delay : float, s
        Wait before every ``delay_every``-th reply (a slow controller).
    delay_every : int
    stall_after : int or None
        After this many more replies, replies stop (requests are still read): a stalled link.
    close_after : int or None
        After this many more replies, the connection is closed: a dead link.
    errors : dict command -> description
        Commands answered with an error (status 1 and the description).
    corrupt : str or None
        ``"name"`` (a reply under another command's name), ``"size"`` (a body size of 2^31 - 1),
        ``"truncated"`` (the body cut short, then the connection closed) for every reply.
    """

    delay: float = 0.0
    delay_every: int = 1
    stall_after: int | None = None
    close_after: int | None = None
    errors: dict = field(default_factory=dict)
    corrupt: str | None = None
    first_connection_only: bool = False  # stall/close faults hit the first connection only (its network died)


class NanonisSimulator:
    """A Nanonis TCP server on loopback driving ``instrument``.

    Parameters
    ----------
    instrument : Instrument
        What the controller controls (opened here).
    host, port : str, int
        Where to listen (port 0: a free port; :attr:`address` tells which).
    signal_names : sequence of str
        The controller's signal list (default :data:`SIGNAL_NAMES`).
    deflection, torsion : str
        The inputs wired to the instrument's two signals.
    volts_per_unit : float
        Input volts per unit of the instrument's signals.
    faults : Faults, optional
    tap : float, s
        The acquisition period Tap (module docstring).
    latency : float, s
        Time every reply takes.
    names_size : {"prefixed", "strings"}
        What the declared byte size of the signal names counts (module docstring).
    scan_settings : arsurf.instrument.imaging.ScanSettings, optional
        The scan frame and buffer (default: the instrument's ``scan_settings``).
    """

    def __init__(self, instrument: Instrument, *, host: str = "127.0.0.1", port: int = 0, signal_names=SIGNAL_NAMES,
                 deflection: str = "Input 1 (V)", torsion: str = "Input 2 (V)", volts_per_unit: float = 1.0,
                 faults: Faults | None = None, tap: float = 0.02, latency: float = 1e-3,
                 names_size: str = "prefixed", scan_settings=None) -> None:
        if not isinstance(instrument, Instrument):
            raise InstrumentError(f"instrument must be an arsurf Instrument (got {type(instrument).__name__})")
        self.instrument = instrument
        self.names = tuple(signal_names)
        role = {"X (m)": ("position", 0), "Y (m)": ("position", 1), "Z (m)": ("position", 2),
                deflection: ("signals", 0), torsion: ("signals", 1)}
        self._roles = {self.names.index(n): r for n, r in role.items() if n in self.names}
        self.volts_per_unit = float(volts_per_unit)
        self.faults = faults or Faults()
        if names_size not in ("prefixed", "strings"):
            raise InstrumentError(f"names_size must be 'prefixed' or 'strings' (got {names_size!r})")
        self.tap, self.latency, self.names_size = float(tap), float(latency), names_size
        self._t0 = time.perf_counter()  # the acquisition clock: periods of Tap from here
        self._accepted = 0
        self.speed, self.custom_speed = 1e-6, 1
        self.requests: dict[str, int] = {}
        self._lock = threading.Lock()  # one command at a time on the instrument
        self._approaching = threading.Event()
        self.approach_error: str | None = None
        self.scan_settings = scan_settings
        self.scan_channels = {0: "Z (m)"}  # the scan buffer: channel index -> name
        self._scanning = threading.Event()
        self.frame = None  # the last frame (a Scan) and the raster it ran
        self.frame_settings = None
        self.scan_error: str | None = None
        self._sample = InstrumentSample()
        self._stop = threading.Event()
        self._server = socket.create_server((host, port))
        self._server.settimeout(0.05)
        self.address = self._server.getsockname()[:2]
        self._conns: list[socket.socket] = []
        self._threads: list[threading.Thread] = []
        self._accept = threading.Thread(target=self._serve, name="nanonis-sim", daemon=True)

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> "NanonisSimulator":
        self.instrument.open()
        self._accept.start()
        return self

    def close(self) -> None:
        """Stop listening, close every connection, join the threads."""
        self._stop.set()
        for s in [self._server, *self._conns]:
            try:
                s.close()
            except OSError:  # pragma: no cover
                pass
        for t in [self._accept, *self._threads]:
            if t.is_alive() and t is not threading.current_thread():
                t.join(2.0)

    def __enter__(self) -> "NanonisSimulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            if sum(t.is_alive() for t in self._threads) >= _MAX_CONNECTIONS:
                conn.close()
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._conns.append(conn)
            self._accepted += 1
            t = threading.Thread(target=self._connection, args=(conn, self._accepted == 1), name="nanonis-sim-conn",
                                 daemon=True)
            self._threads.append(t)
            t.start()

    # -- one connection ----------------------------------------------------------------------------
    @staticmethod
    def _recv(conn: socket.socket, n: int) -> bytes | None:
        buf = bytearray(n)
        view, got = memoryview(buf), 0
        while got < n:
            k = conn.recv_into(view[got:], n - got)
            if k == 0:
                return None
            got += k
        return bytes(buf)

    def _connection(self, conn: socket.socket, first: bool = True) -> None:
        replies = 0
        f = self.faults
        try:
            while not self._stop.is_set():
                head = self._recv(conn, proto.HEADER_SIZE)
                if head is None:
                    return
                name, size, respond = proto.parse_header(head, request=True)
                body = self._recv(conn, size)
                if body is None:
                    return
                self.requests[name] = self.requests.get(name, 0) + 1
                reply = self._answer(name, body)
                if not respond:
                    continue
                hit = first or not f.first_connection_only
                if hit and f.close_after is not None and replies >= f.close_after:
                    return
                if hit and f.stall_after is not None and replies >= f.stall_after:
                    continue  # read, never answered: the link stalls
                if f.delay > 0.0 and replies % max(1, f.delay_every) == 0 and self._stop.wait(f.delay):
                    return
                conn.sendall(self._corrupt(reply, name) if f.corrupt else reply)
                replies += 1
                if f.corrupt == "truncated":
                    return
        except (OSError, InstrumentLinkLost):  # a broken client or a request that is not the protocol
            return
        finally:
            try:
                conn.close()
            except OSError:  # pragma: no cover
                pass

    def _corrupt(self, reply: bytes, name: str) -> bytes:
        kind = self.faults.corrupt
        if kind == "name":
            other = "ZCtrl.ZPosGet" if name != "ZCtrl.ZPosGet" else "FolMe.XYPosGet"
            return other.encode().ljust(32, b"\0") + reply[32:]
        if kind == "size":
            return reply[:32] + (2**31 - 1).to_bytes(4, "big") + reply[36:]
        if kind == "truncated":
            return reply[:proto.HEADER_SIZE + max(0, (len(reply) - proto.HEADER_SIZE) // 2)]
        raise InstrumentError(f"unknown corruption {kind!r}; use 'name', 'size' or 'truncated'")

    def _wait_for_data(self, newest: bool) -> None:
        """Signals.ValsGet's wait: to the end of the current acquisition period (and one more when
        waiting for newest data)."""
        now = time.perf_counter() - self._t0
        end = (math.floor(now / self.tap) + 1 + int(bool(newest))) * self.tap
        self._stop.wait(end - now)

    def _answer(self, name: str, body: bytes) -> bytes:
        if self.latency > 0.0:
            self._stop.wait(self.latency)
        if name not in proto.COMMANDS:  # answered under its own name, with an error and no values
            return proto.encode_error_reply(name, f"command {name!r} is not implemented by the simulated controller")
        args = proto.decode_request(name, body)
        error = self.faults.errors.get(name)
        if error:
            return proto.encode_reply(name, (), error)
        try:
            if name == "AutoApproach.OnOffGet":  # answered while the approach holds the instrument
                return proto.encode_reply(name, (int(self._approaching.is_set()),))
            if name in ("Scan.StatusGet", "Scan.WaitEndOfScan"):  # answered while the scan holds it
                return proto.encode_reply(name, self._scan_status(name, args))
            with self._lock:
                values = self._execute(name, args)
        except InstrumentError as exc:
            return proto.encode_reply(name, (), str(exc))
        reply = proto.encode_reply(name, values)
        if name == "Signals.NamesGet" and self.names_size == "strings":  # the size without the length prefixes
            at = proto.HEADER_SIZE
            size = sum(len(n.encode()) for n in self.names)
            reply = reply[:at] + struct.pack(">i", size) + reply[at + 4:]
        return reply

    # -- the commands ----------------------------------------------------------------------------------
    def _approach(self) -> None:
        """The auto-approach, in the background; a failure leaves the Z controller off."""
        try:
            with self._lock:
                self.instrument.engage()
        except InstrumentError as exc:
            self.approach_error = str(exc)
        finally:
            self._approaching.clear()

    def _scan(self, settings) -> None:
        """One frame, in the background (the instrument's :meth:`~Instrument.scan_image`)."""
        try:
            with self._lock:
                self.frame = self.instrument.scan_image(settings)
                self.frame_settings = settings
        except InstrumentError as exc:
            self.scan_error = str(exc)
        finally:
            self._scanning.clear()

    def _scan_status(self, name: str, args: tuple) -> tuple:
        if name == "Scan.StatusGet":
            return (int(self._scanning.is_set()),)
        (ms,) = args  # Scan.WaitEndOfScan: until the frame ends or the timeout (-1: no timeout)
        deadline = None if ms < 0 else ms / 1e3
        t = 0.0
        while self._scanning.is_set() and not self._stop.is_set() and (deadline is None or t < deadline):
            step = 0.02 if deadline is None else min(0.02, deadline - t)
            self._stop.wait(step)
            t += step
        return (int(self._scanning.is_set()), "")

    def _settings(self):
        st = self.scan_settings if self.scan_settings is not None else getattr(self.instrument, "scan_settings", None)
        if st is None:
            raise InstrumentError("the simulated controller has no scan frame: give it scan_settings")
        return st

    def _frame_data(self, args: tuple) -> tuple:
        channel, forward = args
        if channel not in self.scan_channels:
            raise InstrumentError(f"channel {channel} is not acquired (the buffer records {sorted(self.scan_channels)})")
        if not forward:
            raise InstrumentError("the simulated controller records the forward (trace) image only")
        if self.frame is None:
            raise InstrumentError("no frame has been acquired yet: start a scan (Scan.Action 0) first")
        up = self.frame_settings.direction == "up"
        h = self.frame.heights if up else self.frame.heights[::-1]  # in the order scanned
        return (self.scan_channels[channel], h, int(up))

    def _value(self, index: int, s: InstrumentSample) -> float:
        role = self._roles.get(index)
        if role is None:
            return 0.0
        arr, j = role
        return float(s.position[j]) if arr == "position" else float(s.signals[j]) * self.volts_per_unit

    def _execute(self, name: str, args: tuple) -> tuple:
        afm = self.instrument
        nan = math.nan
        if name == "Signals.NamesGet":
            return (list(self.names),)
        if name == "Util.AcqPeriodGet":
            return (self.tap,)
        if name == "Util.AcqPeriodSet":
            if not (math.isfinite(args[0]) and args[0] > 0.0):
                raise InstrumentError(f"the acquisition period must be positive (got {args[0]!r} s)")
            self.tap = float(args[0])
            return ()
        if name == "Signals.ValsGet":
            indexes, wait = args
            bad = [i for i in indexes if not 0 <= i < len(self.names)]
            if bad:
                raise InstrumentError(f"signal indexes {bad} are outside 0..{len(self.names) - 1}")
            self._lock.release()  # the acquisition runs on: other commands are not held by the wait
            try:
                self._wait_for_data(wait)
            finally:
                self._lock.acquire()
            s = afm.read(self._sample)
            return ([self._value(i, s) for i in indexes],)
        if name in ("FolMe.XYPosGet", "ZCtrl.ZPosGet"):
            p = afm.read(self._sample).position
            return (float(p[0]), float(p[1])) if name == "FolMe.XYPosGet" else (float(p[2]),)
        if name == "FolMe.XYPosSet":
            x, y, wait = args
            afm.move_to((x, y, nan), wait=bool(wait))
            return ()
        if name == "FolMe.SpeedSet":
            speed, custom = args
            if not (math.isfinite(speed) and speed > 0.0):
                raise InstrumentError(f"the Follow Me speed must be positive (got {speed!r} m/s)")
            self.speed, self.custom_speed = speed, custom
            return ()
        if name == "FolMe.SpeedGet":
            return (self.speed, self.custom_speed)
        if name == "ZCtrl.ZPosSet":
            if afm.feedback:
                raise InstrumentError("the Z-Controller is on: switch it off to change the Z position of the tip")
            afm.move_to((nan, nan, args[0]))
            return ()
        if name == "ZCtrl.OnOffGet":
            return (int(afm.feedback),)
        if name == "ZCtrl.OnOffSet":
            afm.set_feedback(bool(args[0]))
            return ()
        if name == "ZCtrl.StatusGet":
            return (2 if afm.feedback else 1,)
        if name == "ZCtrl.Withdraw":
            afm.withdraw()
            return ()
        lim = afm.limits
        if name == "ZCtrl.LimitsGet":
            return (float(lim.high[2]), float(lim.low[2]))
        if name == "Piezo.RangeGet":
            return tuple(float(v) for v in np.asarray(lim.high) - np.asarray(lim.low))
        if name in ("AutoApproach.Open", "FolMe.Stop"):
            return ()
        if name == "AutoApproach.OnOffSet":
            if args[0] and not self._approaching.is_set():
                self._approaching.set()
                threading.Thread(target=self._approach, name="nanonis-sim-approach", daemon=True).start()
            return ()
        if name == "AutoApproach.OnOffGet":
            return (int(self._approaching.is_set()),)
        if name == "Scan.Action":
            action, up = args
            if action == 0:
                if not self._scanning.is_set():
                    settings = replace(self._settings(), direction="up" if up else "down")
                    self.scan_error = None
                    self._scanning.set()
                    threading.Thread(target=self._scan, args=(settings,), name="nanonis-sim-scan", daemon=True).start()
                return ()
            if action == 1:
                return ()  # a frame is computed at once: there is nothing left to stop
            raise InstrumentError(f"scan action {action} is not simulated (0 start and 1 stop are)")
        if name in ("Scan.FrameGet", "Scan.BufferGet", "Scan.SpeedGet"):
            st = self.frame_settings if self.frame is not None else self._settings()
            (w, h), (dx, dy) = st.size, st.spacing
            if name == "Scan.FrameGet":
                return (st.origin[0] - 0.5 * dx + 0.5 * w, st.origin[1] - 0.5 * dy + 0.5 * h, w, h, 0.0)
            if name == "Scan.BufferGet":
                return (sorted(self.scan_channels), st.pixels[0], st.pixels[1])
            return (st.line_speed, st.line_speed, w / st.line_speed, w / st.line_speed, 0, 1.0)
        if name == "Scan.FrameDataGrab":
            return self._frame_data(args)
        raise InstrumentError(f"command {name!r} is not implemented by the simulated controller")  # pragma: no cover
