"""A network bridge device: a haptic PC sends stylus poses over UDP, arsurf sends forces back.

As in the seed systems, where the haptic PC and the AFM PC talk over Ethernet, real hardware can
drive arsurf through a small binary protocol over UDP. arsurf is the server (it listens on
127.0.0.1 by default, port :data:`DEFAULT_PORT`); the haptic PC is the client: it sends one POSE
packet per servo tick and applies the FORCE packets it receives. ``tools/haptic_client.py`` is a
reference client in plain Python (standard library only).

Protocol, version 1. All fields little-endian; ``f64`` IEEE-754 double, ``u8/u16/u32`` unsigned.
Every packet ends with the CRC-32 (zlib/IEEE 802.3 polynomial, as ``zlib.crc32``) of all the bytes
before it. Positions in metres, velocities in m/s, forces in newtons, times in seconds.

POSE, client -> server, 108 bytes::

    offset size type      field
    0      4    char[4]   magic  b"ARSH"
    4      1    u8        version = 1
    5      1    u8        type    = 1 (POSE)
    6      2    u16       flags: bit 0 RESET = the client (re)starts its sequence numbering
    8      4    u32       sequence number, +1 per packet, wraps modulo 2**32
    12     8    f64       client timestamp (the client's monotonic clock)
    20     24   f64[3]    stylus position x, y, z
    44     24   f64[3]    stylus velocity (all three NaN: unknown, the server differentiates)
    68     32   f64[4]    stylus orientation quaternion w, x, y, z
    100    4    u32       buttons bitmask (bit 0: first button)
    104    4    u32       CRC-32 of bytes 0..103

FORCE, server -> client (to the address the last accepted POSE came from), 60 bytes::

    offset size type      field
    0      4    char[4]   magic  b"ARSH"
    4      1    u8        version = 1
    5      1    u8        type    = 2 (FORCE)
    6      2    u16       flags: bit 0 STALE_INPUT, bit 1 RAMPING, bit 2 CLAMPED
    8      4    u32       server sequence number
    12     4    u32       ack: sequence number of the last accepted POSE
    16     8    f64       server timestamp (the server's monotonic clock)
    24     8    f64       echo: client timestamp of the acknowledged POSE (round-trip time)
    32     24   f64[3]    force on the handle x, y, z
    56     4    u32       CRC-32 of bytes 0..55

The server drops, counts in :attr:`UdpBridgeDevice.stats`, and otherwise ignores: datagrams
longer than a POSE (``oversized``) or shorter (``truncated``); a wrong magic (``bad_magic``),
version (``bad_version``), type (``bad_type``) or CRC (``bad_crc``); non-finite position, time or
orientation (``nonfinite``); a sequence number that is not newer than the last accepted one, in
serial-number arithmetic modulo 2**32 (``out_of_order``, duplicates included); a newer packet whose
client timestamp is not later than the last accepted one (``stale``); a sender other than the
current peer while the peer's input is fresh (``foreign``; RESET does not override this, a new
client takes over once the old one has been silent for ``stale_after``). Nothing a packet
contains can raise.

If no POSE has been accepted for ``stale_after`` seconds the input is stale: the force sent ramps
linearly to zero in ``ramp_down`` seconds (and back up in ``ramp_up`` once fresh poses arrive),
the FORCE flags say so, and ``DeviceState.timestamp`` (the local receive time of the last accepted
pose) lets the safety layer see the age too. After a stale period, or with the RESET flag, any
sequence number is accepted again (a restarted client) and a new sender may take over. The client
should apply zero force when it hears no FORCE packet for a while: the network may be gone.

Examples
--------
>>> import socket, struct, zlib, math
>>> with UdpBridgeDevice(port=0) as dev:
...     pkt = encode_pose(seq=1, t=0.0, position=(0.01, 0.0, 0.0), buttons=1)
...     with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
...         _ = c.sendto(pkt, dev.address)
...         dev.wait_for_client(timeout=2.0)
...         s = dev.read_state()
...         dev.command_force([0.0, 0.0, 1.0])
...         reply = decode_force(c.recv(256))
>>> s.position.tolist(), s.buttons, reply["ack"], reply["force"]
([0.01, 0.0, 0.0], 1, 1, (0.0, 0.0, 1.0))
"""
from __future__ import annotations

import math
import socket
import struct
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from arsurf.errors import HapticsError
from arsurf.haptics.device import Device, DeviceInfo, DeviceState, TOUCH_X

__all__ = [
    "DEFAULT_PORT",
    "FORCE_SIZE",
    "MAGIC",
    "POSE_SIZE",
    "VERSION",
    "BridgeStats",
    "UdpBridgeDevice",
    "decode_force",
    "decode_pose",
    "encode_force",
    "encode_pose",
]

MAGIC = b"ARSH"
VERSION = 1
TYPE_POSE = 1
TYPE_FORCE = 2
FLAG_RESET = 1  # POSE flags
FLAG_STALE_INPUT = 1  # FORCE flags
FLAG_RAMPING = 2
FLAG_CLAMPED = 4
#: Default UDP port of the bridge (any free port works; 0 picks one).
DEFAULT_PORT = 47474

_POSE_BODY = struct.Struct("<4sBBHId3d3d4dI")
_FORCE_BODY = struct.Struct("<4sBBHIIdd3d")
_CRC = struct.Struct("<I")
POSE_SIZE = _POSE_BODY.size + 4  #: 108 bytes
FORCE_SIZE = _FORCE_BODY.size + 4  #: 60 bytes
_RECV_BUFFER = 2048  # anything longer than a POSE is oversized; this only bounds the copy
_SEQ_MOD = 1 << 32


def encode_pose(seq: int, t: float, position, velocity=(math.nan, math.nan, math.nan),
                quaternion=(1.0, 0.0, 0.0, 0.0), buttons: int = 0, reset: bool = False) -> bytes:
    """A POSE packet (108 bytes) as the protocol above defines it.

    Examples
    --------
    >>> len(encode_pose(seq=7, t=1.5, position=(0.0, 0.0, 0.0)))
    108
    """
    body = _POSE_BODY.pack(MAGIC, VERSION, TYPE_POSE, FLAG_RESET if reset else 0, int(seq) % _SEQ_MOD, float(t),
                           *(float(v) for v in position), *(float(v) for v in velocity),
                           *(float(v) for v in quaternion), int(buttons) & 0xFFFFFFFF)
    return body + _CRC.pack(zlib.crc32(body))


def decode_pose(data) -> dict | None:
    """Fields of a POSE packet, or None if it is not a valid one (size, magic, version, type, CRC).

    Examples
    --------
    >>> decode_pose(encode_pose(seq=3, t=0.25, position=(1.0, 2.0, 3.0), buttons=2))["position"]
    (1.0, 2.0, 3.0)
    >>> decode_pose(b"junk") is None
    True
    """
    mv = memoryview(data)
    if len(mv) != POSE_SIZE:
        return None
    f = _POSE_BODY.unpack_from(mv)
    if f[0] != MAGIC or f[1] != VERSION or f[2] != TYPE_POSE:
        return None
    if _CRC.unpack_from(mv, _POSE_BODY.size)[0] != zlib.crc32(mv[:_POSE_BODY.size]):
        return None
    return {"flags": f[3], "seq": f[4], "t": f[5], "position": f[6:9], "velocity": f[9:12],
            "quaternion": f[12:16], "buttons": f[16]}


def encode_force(seq: int, ack: int, t: float, echo: float, force, flags: int = 0) -> bytes:
    """A FORCE packet (60 bytes).

    Examples
    --------
    >>> decode_force(encode_force(1, 2, 0.5, 0.25, (0.0, 1.0, 0.0)))["force"]
    (0.0, 1.0, 0.0)
    """
    body = _FORCE_BODY.pack(MAGIC, VERSION, TYPE_FORCE, int(flags) & 0xFFFF, int(seq) % _SEQ_MOD,
                            int(ack) % _SEQ_MOD, float(t), float(echo), *(float(v) for v in force))
    return body + _CRC.pack(zlib.crc32(body))


def decode_force(data) -> dict | None:
    """Fields of a FORCE packet, or None if it is not a valid one."""
    mv = memoryview(data)
    if len(mv) != FORCE_SIZE:
        return None
    f = _FORCE_BODY.unpack_from(mv)
    if f[0] != MAGIC or f[1] != VERSION or f[2] != TYPE_FORCE:
        return None
    if _CRC.unpack_from(mv, _FORCE_BODY.size)[0] != zlib.crc32(mv[:_FORCE_BODY.size]):
        return None
    return {"flags": f[3], "seq": f[4], "ack": f[5], "t": f[6], "echo": f[7], "force": f[8:11]}


@dataclass
class BridgeStats:
    """Packet counters of a :class:`UdpBridgeDevice` (see the module docstring for each reason)."""

    received: int = 0
    accepted: int = 0
    oversized: int = 0
    truncated: int = 0
    bad_magic: int = 0
    bad_version: int = 0
    bad_type: int = 0
    bad_crc: int = 0
    nonfinite: int = 0
    out_of_order: int = 0
    stale: int = 0
    foreign: int = 0
    resyncs: int = 0
    sent: int = 0
    send_errors: int = 0
    receive_errors: int = 0

    @property
    def dropped(self) -> int:
        """All packets received and not accepted."""
        return (self.oversized + self.truncated + self.bad_magic + self.bad_version + self.bad_type
                + self.bad_crc + self.nonfinite + self.out_of_order + self.stale + self.foreign)

    def as_dict(self) -> dict[str, int]:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["dropped"] = self.dropped
        return d


def _seq_newer(seq: int, last: int) -> bool:
    """Serial-number arithmetic (RFC 1982) modulo 2**32: is ``seq`` after ``last``?"""
    d = (seq - last) % _SEQ_MOD
    return 0 < d < (_SEQ_MOD >> 1)


class UdpBridgeDevice(Device):
    """A device whose stylus lives on another machine: poses in, forces out, over UDP.

    Parameters
    ----------
    host : str
        Address to listen on (default ``"127.0.0.1"``: loopback only; give the interface address
        explicitly to accept a haptic PC on the network).
    port : int
        UDP port (default :data:`DEFAULT_PORT`; 0 picks a free one, see :attr:`address`).
    info : DeviceInfo
        Limits of the remote device (default: Touch X); forces are clamped to ``info.max_force``.
    stale_after : float, s
        Input older than this is stale (default 0.05 s).
    ramp_down, ramp_up : float, s
        Time for the sent force to fade to zero on stale input, and to come back (0.05 s, 0.2 s).
    clock : callable
        Monotonic clock in seconds (default :func:`time.perf_counter`); tests inject their own.
    max_packets_per_read : int
        Bound on the datagrams drained per :meth:`read_state` (default 256).

    Attributes
    ----------
    stats : BridgeStats
    orientation : (4,) float
        Latest stylus orientation quaternion (w, x, y, z).
    peer : tuple or None
        Address of the client forces are sent to.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, info: DeviceInfo = TOUCH_X, *,
                 stale_after: float = 0.05, ramp_down: float = 0.05, ramp_up: float = 0.2,
                 clock: Callable[[], float] = time.perf_counter, max_packets_per_read: int = 256) -> None:
        super().__init__()
        if not isinstance(host, str) or not host:
            raise HapticsError(f"host must be an address string such as '127.0.0.1' (got {host!r})")
        if not isinstance(port, (int, np.integer)) or not (0 <= port <= 65535):
            raise HapticsError(f"port must be an integer in 0..65535 (got {port!r}); 0 picks a free port")
        if not isinstance(info, DeviceInfo):
            raise HapticsError(f"info must be a DeviceInfo (got {type(info).__name__})")
        for name, v in (("stale_after", stale_after), ("ramp_down", ramp_down), ("ramp_up", ramp_up)):
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise HapticsError(f"{name} must be a positive number of seconds (got {v!r})")
        if not isinstance(max_packets_per_read, int) or max_packets_per_read < 1:
            raise HapticsError(f"max_packets_per_read must be a positive integer (got {max_packets_per_read!r})")
        self.host, self.port = host, int(port)
        self._info = info
        self.stale_after, self.ramp_down, self.ramp_up = float(stale_after), float(ramp_down), float(ramp_up)
        self.clock = clock
        self.max_packets_per_read = max_packets_per_read
        self.stats = BridgeStats()
        self._sock: socket.socket | None = None
        self._buf = bytearray(_RECV_BUFFER)
        self._reset_session()

    def _reset_session(self) -> None:
        self.peer = None
        self._last_seq = None
        self._last_client_t = -math.inf
        self._last_rx = -math.inf
        self._position = np.zeros(3)
        self._velocity = np.zeros(3)
        self.orientation = np.array([1.0, 0.0, 0.0, 0.0])
        self._buttons = 0
        self._gain = 1.0  # the safety layer ramps in at start-up; this gain only fades stale input
        self._last_cmd = None
        self._tx_seq = 0
        self._last_flags = 0
        self._seen_clamped = self.clamped_forces

    # -- Device -----------------------------------------------------------------------------
    @property
    def info(self) -> DeviceInfo:
        return self._info

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the bridge listens on (the real port when opened with port 0)."""
        if self._sock is None:
            return (self.host, self.port)
        return self._sock.getsockname()[:2]

    def now(self) -> float:
        return float(self.clock())

    def _open(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            sock.bind((self.host, self.port))
        except OSError as exc:
            sock.close()
            raise HapticsError(
                f"cannot listen on UDP {self.host}:{self.port} ({exc}); pick another port (0 = any free one)"
            ) from exc
        self._sock = sock
        self._reset_session()

    def _close(self) -> None:
        try:
            if self.peer is not None:
                self._send(np.zeros(3), 0)
        finally:
            if self._sock is not None:
                self._sock.close()
            self._sock = None

    def input_age(self) -> float:
        """Seconds since the last accepted pose (inf before the first)."""
        return self.now() - self._last_rx

    @property
    def stale(self) -> bool:
        return self.input_age() > self.stale_after

    def _read(self, out: DeviceState) -> None:
        self.poll()
        out.position[:] = self._position
        out.velocity[:] = self._velocity
        out.buttons = self._buttons
        out.timestamp = self._last_rx

    def _apply_force(self, force: np.ndarray) -> None:
        t = self.now()
        dt = 0.0 if self._last_cmd is None else max(0.0, t - self._last_cmd)
        self._last_cmd = t
        flags = 0
        if self.input_age() > self.stale_after:
            flags |= FLAG_STALE_INPUT
            self._gain = max(0.0, self._gain - dt / self.ramp_down)
        else:
            self._gain = min(1.0, self._gain + dt / self.ramp_up) if self._gain < 1.0 else 1.0
        if 0.0 < self._gain < 1.0:
            flags |= FLAG_RAMPING
        if self.clamped_forces != self._seen_clamped:  # the base class clamped this force
            flags |= FLAG_CLAMPED
            self._seen_clamped = self.clamped_forces
        self._last_flags = flags
        if self.peer is not None:
            self._send(force * self._gain, flags)

    @property
    def force_gain(self) -> float:
        """Current ramp gain in [0, 1] applied to the force sent (0 while the input is stale)."""
        return self._gain

    def _send(self, force: np.ndarray, flags: int) -> None:
        self._tx_seq = (self._tx_seq + 1) % _SEQ_MOD
        pkt = encode_force(self._tx_seq, self._last_seq or 0, self.now(), self._last_client_t
                           if math.isfinite(self._last_client_t) else math.nan, force, flags)
        try:
            self._sock.sendto(pkt, self.peer)
            self.stats.sent += 1
        except OSError:  # peer gone (ICMP unreachable), buffer full: never break the loop
            self.stats.send_errors += 1

    # -- receiving --------------------------------------------------------------------------
    def poll(self) -> int:
        """Drain pending datagrams (at most ``max_packets_per_read``); returns how many were accepted."""
        if self._sock is None:
            return 0
        accepted = 0
        buf = self._buf
        for _ in range(self.max_packets_per_read):
            try:
                n, addr = self._sock.recvfrom_into(buf)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP port unreachable reported on the socket
                self.stats.receive_errors += 1
                continue
            self.stats.received += 1
            if self._accept(buf, n, addr):
                accepted += 1
        return accepted

    def _accept(self, buf: bytearray, n: int, addr) -> bool:
        st = self.stats
        if n > POSE_SIZE:
            st.oversized += 1
            return False
        if n < POSE_SIZE:
            st.truncated += 1
            return False
        f = _POSE_BODY.unpack_from(buf)
        if f[0] != MAGIC:
            st.bad_magic += 1
            return False
        if f[1] != VERSION:
            st.bad_version += 1
            return False
        if f[2] != TYPE_POSE:
            st.bad_type += 1
            return False
        if _CRC.unpack_from(buf, _POSE_BODY.size)[0] != zlib.crc32(memoryview(buf)[:_POSE_BODY.size]):
            st.bad_crc += 1
            return False
        flags, seq, t = f[3], f[4], f[5]
        pos, vel, quat = f[6:9], f[9:12], f[12:16]
        if not (math.isfinite(t) and all(math.isfinite(v) for v in pos) and all(math.isfinite(v) for v in quat)):
            st.nonfinite += 1
            return False
        now = self.now()
        fresh = (now - self._last_rx) <= self.stale_after
        reset = bool(flags & FLAG_RESET)
        if self.peer is not None and addr != self.peer and fresh:
            st.foreign += 1
            return False
        resync = reset or not fresh or self._last_seq is None or addr != self.peer
        if not resync:
            if not _seq_newer(seq, self._last_seq):
                st.out_of_order += 1
                return False
            if not t > self._last_client_t:
                st.stale += 1
                return False
        elif self._last_seq is not None:
            st.resyncs += 1
        # accepted
        if all(math.isfinite(v) for v in vel):
            self._velocity[:] = vel
        elif not resync and t > self._last_client_t:
            dtc = t - self._last_client_t
            for j in range(3):
                self._velocity[j] = (pos[j] - self._position[j]) / dtc
        else:
            self._velocity[:] = 0.0
        self._position[:] = pos
        q = np.asarray(quat)
        qn = math.sqrt(float(q @ q))
        if qn > 0.0:
            self.orientation[:] = q / qn
        self._buttons = int(f[16])
        self._last_seq = seq
        self._last_client_t = t
        self._last_rx = now
        self.peer = addr
        st.accepted += 1
        return True

    def wait_for_client(self, timeout: float = 5.0) -> None:
        """Block until a pose has been accepted (polling every millisecond), or raise HapticsError."""
        self._require_open()
        deadline = time.monotonic() + float(timeout)
        while self._last_seq is None:
            self.poll()
            if self._last_seq is not None:
                break
            if time.monotonic() > deadline:
                raise HapticsError(
                    f"no valid pose packet on UDP {self.address[0]}:{self.address[1]} within {timeout} s "
                    f"(received {self.stats.received}, dropped {self.stats.dropped}); start the client "
                    "(tools/haptic_client.py) with this host and port"
                )
            time.sleep(0.001)
