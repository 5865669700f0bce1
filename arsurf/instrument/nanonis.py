r"""A Nanonis controller as an :class:`~arsurf.instrument.interface.Instrument`, over its TCP
programming interface (:mod:`arsurf.instrument.nanonis_protocol`).

One reading is one round trip: ``Signals.ValsGet`` of five signals at once - the tip's X, Y, Z
(the controller's ``X (m)``, ``Y (m)``, ``Z (m)`` signals) and the two photodiode inputs wired
to deflection and torsion - resolved by name from ``Signals.NamesGet`` when the link opens.
Moves are ``FolMe.XYPosSet`` (Follow Me, at the speed set with ``FolMe.SpeedSet``) and
``ZCtrl.ZPosSet`` (the Z controller off); ``ZCtrl.OnOffSet`` switches the feedback,
``AutoApproach`` engages and ``ZCtrl.Withdraw`` withdraws. :meth:`NanonisAFM.scan_image` runs one
frame (``Scan.Action``, ``Scan.WaitEndOfScan``) and fetches it (``Scan.FrameDataGrab``).

**Tap.** ``Signals.ValsGet`` returns its values 0 to Tap seconds after the call, oversampled
over the TCP receiver's acquisition period Tap (``Util.AcqPeriodGet``; ``acquisition_period``
sets it with ``Util.AcqPeriodSet`` at open). A sample's time is therefore its reply's arrival minus
Tap/2 (the middle of the window it averages), and :meth:`NanonisAFM.sample_age_limit` - the
oldest a sample may be before the haptic loop refuses it (``arsurf live --max-age-ms``'s default)
- follows from Tap and the round trip measured at open.

**Link loss.** ``on_link_loss`` says what happens to the tip when the link is lost (in xyz mode
the Z feedback is off and the tip would stay where it was): ``"withdraw"`` (default) opens a
second connection (the server takes up to four) and sends ``ZCtrl.Withdraw``; ``"feedback"``
switches the Z controller on the same way; ``"hold"`` leaves it. A controller that does not answer
that either is reported in the error.

Every reply has a deadline: a controller that does not answer within ``timeout`` seconds (or
closes the connection, or sends bytes that are not its protocol) raises
:class:`~arsurf.errors.InstrumentLinkLost`, after which the link is closed - a late reply can
never be taken for the answer to a later command - and the tip is left where it is. An error
the controller reports in a reply's error section raises :class:`~arsurf.errors.ControllerError`
with its description, and the link stays usable.

Why not call the vendor's ``nanonis_spm.Nanonis`` in the loop: its ``send`` waits for replies
without a time limit (it sets a 1000 s socket timeout after each message), reads the body with
a thousand extra ``recv`` calls, and prints errors instead of raising them; a stalled controller
would hang the servo thread. The message layouts here are checked byte for byte against it
instead (``tests/instrument/test_nanonis.py``, when ``pip install 'arsurf[nanonis]'`` installed it).

Examples
--------
>>> # with NanonisAFM("192.168.1.10", 6501, limits=InstrumentLimits((-2e-6,) * 3, (2e-6,) * 3, 1e-6)) as afm:
>>> #     s = afm.read()          # s.position (m), s.signals (V): deflection, torsion
"""
from __future__ import annotations

import math
import re
import socket
import struct
import threading
import time

import numpy as np

from arsurf.errors import InstrumentError, InstrumentLinkLost
from arsurf.instrument import nanonis_protocol as proto
from arsurf.instrument.interface import Instrument, InstrumentLimits, InstrumentSample
from arsurf.scan.scan import Scan

__all__ = ["NanonisAFM", "NanonisConnection", "frame_scan"]

#: the signals read for the tip position, by the names the Nanonis software gives them
POSITION_SIGNALS = ("X (m)", "Y (m)", "Z (m)")
#: what NanonisAFM may do to the tip when the link is lost
LINK_LOSS = ("withdraw", "feedback", "hold")
#: s: the longest acquisition period accepted (a Tap read beyond it is refused at open)
MAX_TAP = 10.0


class NanonisConnection:
    """One TCP connection to the Nanonis server: request, reply with a deadline, or a clear error.

    Parameters
    ----------
    host, port : str, int
        The Nanonis TCP server (Nanonis: System > Options > TCP Programming Interface).
    timeout : float, s
        Longest wait for a reply (per command unless the call gives its own).
    connect_timeout : float, s
    """

    def __init__(self, host: str, port: int, timeout: float = 0.25, connect_timeout: float = 2.0) -> None:
        for name, v in (("timeout", timeout), ("connect_timeout", connect_timeout)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
                raise InstrumentError(f"{name} must be a positive number of seconds (got {v!r})")
        if not isinstance(port, int) or not 0 < port < 65536:
            raise InstrumentError(f"port must be an integer in 1..65535 (got {port!r}); Nanonis uses 6501-6504")
        self.host, self.port = str(host), port
        self.timeout, self.connect_timeout = float(timeout), float(connect_timeout)
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        self._header = bytearray(proto.HEADER_SIZE)
        self.lost: str | None = None  # why the link was closed, once it was
        self.round_trips = 0

    @property
    def where(self) -> str:
        return f"Nanonis at {self.host}:{self.port}"

    def open(self) -> None:
        try:
            s = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        except OSError as exc:
            raise InstrumentLinkLost(f"cannot connect to {self.where} ({exc.strerror or exc}); is the Nanonis "
                                     "software running with its TCP programming interface on this port?") from None
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # one small message per command: no Nagle delay
        self._sock, self.lost = s, None

    def close(self) -> None:
        s, self._sock = self._sock, None
        if s is not None:
            try:
                s.close()
            except OSError:  # pragma: no cover - closing a broken socket
                pass

    def _fail(self, message: str) -> InstrumentLinkLost:
        """Close the link (its byte stream cannot be trusted any more) and say why."""
        self.lost = message
        self.close()
        return InstrumentLinkLost(message)

    def _recv_exactly(self, view: memoryview, deadline: float, command: str, timeout: float) -> None:
        sock = self._sock
        got, n = 0, len(view)
        while got < n:
            left = deadline - time.perf_counter()
            if left <= 0.0:
                raise self._fail(f"{self.where} did not answer {command} within {timeout * 1e3:.0f} ms: the link "
                                 "stalled; it is closed and the tip was left where it was")
            sock.settimeout(left)
            try:
                k = sock.recv_into(view[got:], n - got)
            except TimeoutError:
                continue  # the deadline check above says it
            except OSError as exc:
                raise self._fail(f"{self.where}: the link broke while waiting for {command} "
                                 f"({exc.strerror or exc}); the tip was left where it was") from None
            if k == 0:
                raise self._fail(f"{self.where} closed the connection while answering {command}; the tip was "
                                 "left where it was")
            got += k

    def request(self, command: str, message: bytes, timeout: float | None = None) -> bytes:
        """Send ``message`` (a whole request of ``command``) and return the reply's body."""
        timeout = self.timeout if timeout is None else timeout
        with self._lock:
            if self._sock is None:
                raise InstrumentLinkLost(self.lost or f"the link to {self.where} is not open")
            deadline = time.perf_counter() + timeout
            try:
                self._sock.settimeout(timeout)
                self._sock.sendall(message)
            except OSError as exc:
                raise self._fail(f"{self.where}: cannot send {command} ({exc.strerror or exc}); the link is "
                                 "closed and the tip was left where it was") from None
            head = memoryview(self._header)
            self._recv_exactly(head, deadline, command, timeout)
            try:
                name, size, _ = proto.parse_header(bytes(head))
            except InstrumentLinkLost as exc:
                raise self._fail(f"{self.where}: {exc}") from None
            if name != command:
                raise self._fail(f"{self.where} answered {name!r} to {command}: the replies are out of step; the "
                                 "link is closed")
            body = bytearray(size)
            self._recv_exactly(memoryview(body), deadline, command, timeout)
            self.round_trips += 1
            return bytes(body)

    def call(self, command: str, *args, timeout: float | None = None) -> tuple:
        """Encode, send, wait for and decode one command (:data:`~arsurf.instrument.nanonis_protocol.COMMANDS`)."""
        body = self.request(command, proto.encode_request(command, args), timeout)
        try:
            return proto.decode_reply(command, body)
        except InstrumentLinkLost as exc:
            raise self._fail(f"{self.where}: {exc}") from None


def _signal_index(names: list[str], wanted, role: str) -> int:
    """Index of the signal ``wanted`` (a name, matched exactly then ignoring case, or an index)."""
    if isinstance(wanted, (int, np.integer)) and not isinstance(wanted, bool):
        if not 0 <= wanted < len(names):
            raise InstrumentError(f"the {role} signal index {wanted} is not one of the controller's "
                                  f"{len(names)} signals (0..{len(names) - 1})")
        return int(wanted)
    if wanted in names:
        return names.index(wanted)
    folded = [n.casefold() for n in names]
    if isinstance(wanted, str) and wanted.casefold() in folded:
        return folded.index(wanted.casefold())
    shown = ", ".join(repr(n) for n in names[:24]) + (" ..." if len(names) > 24 else "")
    raise InstrumentError(f"the controller has no signal {wanted!r} for the {role}; its signals are {shown}")


class NanonisAFM(Instrument):
    """A Nanonis-controlled AFM over the TCP programming interface.

    Parameters
    ----------
    host, port : str, int
        The Nanonis TCP server (default port 6501).
    limits : InstrumentLimits
        The box the tip may be commanded in (instrument frame, metres) and the largest speed (m/s).
        Required: measure it at bring-up (docs/instruments.rst). Its Z range is narrowed to the
        controller's Z limits (``ZCtrl.LimitsGet``); a box wider than the piezo range
        (``Piezo.RangeGet``) is refused; the Follow Me speed is set to ``max_speed``.
    deflection, torsion : str or int
        The controller signals wired to the photodiode's vertical and lateral outputs, by name
        (``"Input 1 (V)"``) or index (0-127).
    position : 3 names or indexes
        The signals of the tip's X, Y, Z (default ``X (m)``, ``Y (m)``, ``Z (m)``).
    timeout : float, s
        Longest wait for a reply to an ordinary command (default 0.25 s).
    move_timeout, withdraw_timeout, approach_timeout : float, s
        Longest waits of a move with ``wait=True``, a withdraw, an auto-approach.
    connect_timeout : float, s
    acquisition_period : float, s, optional
        Set the TCP receiver's Tap at open (None: keep the controller's; it is read either way).
    on_link_loss : {"withdraw", "feedback", "hold"}
        What to do to the tip when the link is lost (module docstring).
    scan_direction : "up" or "down"
        The slow-axis direction :meth:`scan_image` starts the scan in.
    scan_channel : int, optional
        The scan buffer's channel index of Z (default: the buffer's first channel; the frame's
        channel name must be Z either way).
    scan_timeout, frame_timeout : float, s
        Longest wait for a frame to end, and for its data to arrive.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 6501, *, limits: InstrumentLimits,
                 deflection="Input 1 (V)", torsion="Input 2 (V)", position=POSITION_SIGNALS, timeout: float = 0.25,
                 move_timeout: float = 30.0, withdraw_timeout: float = 10.0, approach_timeout: float = 300.0,
                 connect_timeout: float = 2.0, acquisition_period: float | None = None,
                 on_link_loss: str = "withdraw", scan_direction: str = "up", scan_channel: int | None = None,
                 scan_timeout: float = 3600.0, frame_timeout: float = 30.0) -> None:
        super().__init__()
        if acquisition_period is not None and not (isinstance(acquisition_period, (int, float))
                                                   and math.isfinite(acquisition_period)
                                                   and 0.0 < acquisition_period <= MAX_TAP):
            raise InstrumentError(f"acquisition_period must be in (0, {MAX_TAP:g}] s (got {acquisition_period!r})")
        if on_link_loss not in LINK_LOSS:
            raise InstrumentError(f"on_link_loss must be one of {', '.join(LINK_LOSS)} (got {on_link_loss!r})")
        self.set_tap = acquisition_period
        self.on_link_loss = on_link_loss
        self.acquisition_period = math.nan  # Tap, s, read at open
        self.round_trip = math.nan  # s: the slowest of a few round trips measured at open
        self.loss_action = ""  # what was done to the tip after a lost link
        if not isinstance(limits, InstrumentLimits):
            raise InstrumentError(f"limits must be an InstrumentLimits: the box the tip may be commanded in and the "
                                  f"largest speed (got {type(limits).__name__}); measure them at bring-up")
        if scan_direction not in ("up", "down"):
            raise InstrumentError(f"scan_direction must be 'up' or 'down' (got {scan_direction!r})")
        if scan_channel is not None and (isinstance(scan_channel, bool) or not isinstance(scan_channel, int)
                                         or not 0 <= scan_channel < 128):
            raise InstrumentError(f"scan_channel must be a channel index 0..127 or None (got {scan_channel!r})")
        self.scan_direction, self.scan_channel = scan_direction, scan_channel
        for name, v in (("move_timeout", move_timeout), ("withdraw_timeout", withdraw_timeout),
                        ("approach_timeout", approach_timeout), ("scan_timeout", scan_timeout),
                        ("frame_timeout", frame_timeout)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
                raise InstrumentError(f"{name} must be a positive number of seconds (got {v!r})")
        if len(tuple(position)) != 3:
            raise InstrumentError(f"position must name the X, Y and Z signals (got {position!r})")
        self.link = NanonisConnection(host, port, timeout, connect_timeout)
        self._user_limits = limits
        self._limits = limits
        self._wanted = (*tuple(position), deflection, torsion)
        self.move_timeout, self.withdraw_timeout = float(move_timeout), float(withdraw_timeout)
        self.approach_timeout = float(approach_timeout)
        self.scan_timeout, self.frame_timeout = float(scan_timeout), float(frame_timeout)
        self.signal_indexes: tuple[int, ...] = ()
        self.signal_names: tuple[str, ...] = ()
        self._vals_request = b""
        self._vals = struct.Struct(">i5fIi")  # count, 5 float32, error status, error size (an empty error)

    @property
    def name(self) -> str:
        return f"Nanonis at {self.link.host}:{self.link.port}"

    @property
    def limits(self) -> InstrumentLimits:
        return self._limits

    def now(self) -> float:
        """The host's monotonic clock, seconds (a sample's time is its reply's arrival)."""
        return time.perf_counter()

    def _call(self, command: str, *args, timeout: float | None = None) -> tuple:
        if self.link.lost is not None:
            raise InstrumentLinkLost(f"{self.link.lost} (reopen the instrument to go on)")
        try:
            return self.link.call(command, *args, timeout=timeout)
        except InstrumentLinkLost as exc:
            raise self._lost(exc) from None

    def _lost(self, exc: InstrumentLinkLost) -> InstrumentLinkLost:
        """The link was just lost: secure the tip as ``on_link_loss`` says, over a new connection."""
        if self.on_link_loss == "hold" or self.loss_action or not self.is_open:
            return exc
        spare = NanonisConnection(self.link.host, self.link.port, self.link.timeout, min(self.link.connect_timeout, 0.5))
        try:
            spare.open()
            if self.on_link_loss == "withdraw":
                spare.call("ZCtrl.Withdraw", 0, int(self.withdraw_timeout * 1e3))
                self.loss_action = "the tip was withdrawn over a second connection (ZCtrl.Withdraw)"
            else:
                spare.call("ZCtrl.OnOffSet", 1)
                self.loss_action = "the Z controller was switched on over a second connection"
        except InstrumentError as why:
            self.loss_action = f"securing the tip ({self.on_link_loss}) failed too: {why}"
        finally:
            spare.close()
        said = re.sub(r"(;| and) the tip was left where it was", "", str(exc))
        return InstrumentLinkLost(f"{said}; {self.loss_action}")

    def sample_age_limit(self, axes: str = "xyz") -> float:
        """The oldest a sample may be before the haptic loop refuses it, s: one read cycle -
        Tap/2 (the middle of the oversampling window) + up to Tap (the wait of Signals.ValsGet) +
        its round trip and, in xyz mode, two more (``ZCtrl.ZPosSet``, ``FolMe.XYPosSet``) - three
        such cycles (one late cycle is not a stalled link), and 10 ms for the host's scheduling:
        109 ms at Tap = 20 ms and 1 ms round trips."""
        self._require_open()
        trips = 3 if axes == "xyz" else 2
        return 3.0 * (1.5 * self.acquisition_period + trips * self.round_trip) + 10e-3

    def _open(self) -> None:
        self.link.open()
        try:
            (names,) = self._call("Signals.NamesGet")
            roles = ("X position", "Y position", "Z position", "deflection", "torsion")
            idx = tuple(_signal_index(names, w, r) for w, r in zip(self._wanted, roles))
            self.signal_indexes, self.signal_names = idx, tuple(names[i] for i in idx)
            self._vals_request = proto.encode_request("Signals.ValsGet", (list(idx), 0))
            z_high, z_low = self._call("ZCtrl.LimitsGet")
            rx, ry, rz = self._call("Piezo.RangeGet")
            u = self._user_limits
            width = u.high - u.low
            for axis, w, r in zip("xy", width[:2], (rx, ry)):
                if math.isfinite(r) and r > 0.0 and w > r * (1.0 + 1e-6):
                    raise InstrumentError(f"the {axis} limits span {w:.6g} m, more than the controller's piezo range "
                                          f"{r:.6g} m (Piezo.RangeGet); narrow them")
            if not (math.isfinite(z_high) and math.isfinite(z_low) and z_low < z_high):
                raise InstrumentError(f"the controller's Z limits are not a range (high {z_high!r}, low {z_low!r} m; "
                                      "ZCtrl.LimitsGet)")
            ctrl = InstrumentLimits((u.low[0], u.low[1], z_low), (u.high[0], u.high[1], z_high), u.max_speed,
                                    "the controller's Z limits (ZCtrl.LimitsGet)")
            self._limits = u.intersect(ctrl)
            self._call("FolMe.SpeedSet", u.max_speed, 1)
            if self.set_tap is not None:
                self._call("Util.AcqPeriodSet", float(self.set_tap))
            (tap,) = self._call("Util.AcqPeriodGet")
            if not (math.isfinite(tap) and 0.0 < tap <= MAX_TAP):
                raise InstrumentError(f"the controller's acquisition period Tap is {tap!r} s (Util.AcqPeriodGet); "
                                      f"expected (0, {MAX_TAP:g}] s: set it in the TCP receiver or with "
                                      "acquisition_period=")
            self.acquisition_period = float(tap)
            trips = []
            for _ in range(5):  # the round trip of a command that does not wait for data
                t0 = time.perf_counter()
                (on,) = self._call("ZCtrl.OnOffGet")
                trips.append(time.perf_counter() - t0)
            self.round_trip = max(trips)
            self._feedback = bool(on)
            self.loss_action = ""
        except BaseException:
            self.link.close()
            raise

    def _close(self) -> None:
        self.link.close()

    def _read(self, out: InstrumentSample) -> None:
        if self.link.lost is not None:
            raise InstrumentLinkLost(f"{self.link.lost} (reopen the instrument to go on)")
        try:
            body = self.link.request("Signals.ValsGet", self._vals_request)
        except InstrumentLinkLost as exc:
            raise self._lost(exc) from None
        t = time.perf_counter() - 0.5 * self.acquisition_period  # the middle of the window it averages
        if len(body) == self._vals.size:  # the usual reply: five values and no error, read in one go
            n, x, y, z, d, tor, status, err = self._vals.unpack(body)
            if n == 5 and status == 0 and err == 0:
                out.position[0], out.position[1], out.position[2] = x, y, z
                out.signals[0], out.signals[1] = d, tor
                out.timestamp = t
                return
        try:
            (values,) = proto.decode_reply("Signals.ValsGet", body)
        except InstrumentLinkLost as exc:
            raise self.link._fail(f"{self.link.where}: {exc}") from None
        if len(values) != 5:
            raise self.link._fail(f"{self.link.where} returned {len(values)} values for the 5 signals asked "
                                  "(Signals.ValsGet); the link is closed")
        out.position[:] = values[:3]
        out.signals[:] = values[3:]
        out.timestamp = t

    def _move(self, target: np.ndarray, axes: str, wait: bool) -> None:
        if "z" in axes:
            self._call("ZCtrl.ZPosSet", float(target[2]))
        if "xy" in axes:
            self._call("FolMe.XYPosSet", float(target[0]), float(target[1]), int(wait),
                       timeout=self.move_timeout if wait else None)

    def stop(self) -> None:
        """Stop a Follow Me move where the tip is (``FolMe.Stop``)."""
        self._require_open()
        self._call("FolMe.Stop")

    def _set_feedback(self, on: bool) -> None:
        self._call("ZCtrl.OnOffSet", int(on))

    def _engage(self) -> None:
        """``AutoApproach``: open the module, start, wait until it stops (or ``approach_timeout``:
        then it is stopped), and require the Z controller on at the end."""
        self._call("AutoApproach.Open")
        self._call("AutoApproach.OnOffSet", 1)
        deadline = time.perf_counter() + self.approach_timeout
        while True:
            (running,) = self._call("AutoApproach.OnOffGet")
            if not running:
                break
            if time.perf_counter() > deadline:
                self._call("AutoApproach.OnOffSet", 0)
                raise InstrumentError(f"{self.name}: the auto-approach did not finish within {self.approach_timeout:g}"
                                      " s; it was stopped")
            time.sleep(0.05)
        (on,) = self._call("ZCtrl.OnOffGet")
        if not on:
            self._feedback = False
            raise InstrumentError(f"{self.name}: the auto-approach stopped with the Z controller off: not engaged")

    def _withdraw(self) -> None:
        ms = int(self.withdraw_timeout * 1e3)
        self._call("ZCtrl.Withdraw", 1, ms, timeout=self.withdraw_timeout + self.link.timeout)

    def _scan_image(self, settings) -> Scan:
        """One frame on the controller's own frame and buffer: ``Scan.Action`` start (direction
        :attr:`scan_direction`), ``Scan.WaitEndOfScan`` in 1 s waits until it ends (or
        ``scan_timeout``: then ``Scan.Action`` stop and an error), then the frame's geometry
        (``Scan.FrameGet``, ``Scan.BufferGet``, ``Scan.SpeedGet``) and its forward data
        (``Scan.FrameDataGrab``) as a Scan with the metadata a file gives.

        The data come in the order they were scanned (as the controller's .sxm file stores
        them): the top line first for a scan down, flipped here so that row 0 is the bottom."""
        if settings is not None:
            raise InstrumentError(f"{self.name}: a Nanonis scan runs on the frame and buffer set on the controller; "
                                  "call scan_image() without settings")
        up = int(self.scan_direction == "up")
        self._call("Scan.Action", 0, up)
        deadline = time.perf_counter() + self.scan_timeout
        while True:
            timed_out, path = self._call("Scan.WaitEndOfScan", 1000, timeout=1.0 + self.link.timeout)
            if not timed_out:
                break
            if time.perf_counter() > deadline:
                self._call("Scan.Action", 1, up)
                raise InstrumentError(f"{self.name}: the scan did not end within {self.scan_timeout:g} s; it was "
                                      "stopped (raise scan_timeout for a slower frame)")
        cx, cy, width, height, angle = self._call("Scan.FrameGet")
        channels, pixels, lines = self._call("Scan.BufferGet")
        speed = self._call("Scan.SpeedGet")
        ch = channels[0] if self.scan_channel is None and channels else self.scan_channel
        if ch not in channels:
            raise InstrumentError(f"{self.name}: channel {ch!r} is not one the scan records (Scan.BufferGet: "
                                  f"{list(channels)}); pass scan_channel= one of them")
        name, data, direction = self._call("Scan.FrameDataGrab", int(ch), 1, timeout=self.frame_timeout)
        return frame_scan(self.name, name, data, direction, (cx, cy, width, height, angle), pixels, lines, speed,
                          path)


def frame_scan(where: str, name: str, data: np.ndarray, direction: int, frame, pixels: int, lines: int, speed,
               path: str = "") -> Scan:
    """A :class:`~arsurf.scan.scan.Scan` of a Nanonis frame (``Scan.FrameDataGrab``), every field
    checked: a Z channel in metres, the data ``lines x pixels`` as the buffer says, a frame of
    positive finite size (``Scan.FrameGet``); pixel (ix, iy) at x = ix dx, y = iy dy in the
    frame's own coordinates (its first pixel's centre in ``metadata["instrument"]["origin_m"]``)."""
    from arsurf.scan.readers._common import Channel, make_scan

    cx, cy, width, height, angle = (float(v) for v in frame)
    if not str(name).strip().casefold().startswith("z"):
        raise InstrumentError(f"{where}: the frame's channel is {name!r}, not the height (Z); pass scan_channel= "
                              "the index of Z in the scan buffer")
    if not (isinstance(pixels, int) and isinstance(lines, int) and 1 <= pixels <= 4096 and 1 <= lines <= 4096):
        raise InstrumentError(f"{where}: the buffer has {pixels!r} pixels x {lines!r} lines (1..4096 each)")
    if data.shape != (lines, pixels):
        raise InstrumentError(f"{where}: the frame is {data.shape[0]} x {data.shape[1]} values but the buffer says "
                              f"{lines} lines x {pixels} pixels (Scan.BufferGet)")
    if not all(math.isfinite(v) for v in (cx, cy, width, height, angle)) or width <= 0.0 or height <= 0.0:
        raise InstrumentError(f"{where}: the scan frame (centre {cx!r}, {cy!r}, size {width!r} x {height!r} m, angle "
                              f"{angle!r} deg; Scan.FrameGet) is not a frame")
    down = direction == 0
    img = data[::-1] if down else data
    dx, dy = width / pixels, height / lines
    instrument = {"software": "Nanonis", "format": "Nanonis TCP (Scan.FrameDataGrab)", "controller": where,
                  "scan_dir": "down" if down else "up", "frame_centre_m": [cx, cy], "frame_size_m": [width, height],
                  "angle": angle, "origin_m": [cx - 0.5 * width + 0.5 * dx, cy - 0.5 * height + 0.5 * dy],
                  "line_speed_m_per_s": float(speed[0]), "file": path}
    return make_scan(where, "nanonis-tcp", img, dx, dy, Channel(str(name), unit="m", direction="forward"),
                     [Channel(str(name), unit="m", direction="forward")], rows_flipped=down, instrument=instrument)

