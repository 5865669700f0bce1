"""A network bridge device: a haptic PC sends stylus poses over UDP, arsurf sends forces back.

As in the seed systems, where the haptic PC and the AFM PC talk over Ethernet, real hardware can
drive arsurf through a small binary protocol over UDP. arsurf is the server (it listens on
127.0.0.1 by default, port :data:`DEFAULT_PORT`); the haptic PC is the client: it sends one POSE
packet per servo tick and applies the FORCE packets it receives. ``arsurf/haptics/client.py`` is the
reference client in plain Python (standard library only); ``docs/bridge-protocol.rst`` is the same
specification for a C/C++ implementer, with a test vector.

The bridge answers its operator only. Every packet is authenticated with a per-session key
(HMAC-SHA256, :rfc:`2104`), carries a 64-bit sequence number that only ever grows (replays and
reordered packets are dropped) and the session id the server drew when it opened (so a packet
recorded in an earlier session, even under the same key, is dropped), and the first authenticated
client is *pinned*: until it sends a RELEASE packet (or, if the operator set ``peer_timeout``,
stays silent that long) no other sender can drive the probe or receive forces, even while the
pinned client is silent. Pinning connects the socket to the client, so the kernel drops any
other sender's datagrams before they queue: a flood from elsewhere costs the loop nothing and
cannot crowd the operator's poses out of the socket buffer.

Protocol, version 3. All fields little-endian; ``f64`` IEEE-754 double, ``u8/u16/u32/u64``
unsigned. Every packet ends with a 32-byte tag, HMAC-SHA256 under the session key of all the
bytes before it. Positions in metres, velocities in m/s, forces in newtons, times in seconds.
Common header, 16 bytes, then (every type) a 16-byte session field::

    offset size type      field
    0      4    char[4]   magic  b"ARSH"
    4      1    u8        version = 3
    5      1    u8        type: 1 POSE, 2 FORCE, 3 RELEASE, 4 HELLO, 5 CHALLENGE
    6      2    u16       flags (FORCE: see below; others 0)
    8      8    u64       sequence number of the sender, strictly increasing, never wraps
    16     16   u8[16]    session id (HELLO: 16 zero bytes)

HELLO, client -> server, 72 bytes (the client asks for the session id)::

    32     8    f64       client timestamp
    40     32   u8[32]    HMAC-SHA256(key, bytes 0..39)

CHALLENGE, server -> the HELLO's sender, 72 bytes (never larger than the HELLO it answers)::

    16     16   u8[16]    session id
    32     8    u64       ack: sequence number of the HELLO answered
    40     32   u8[32]    HMAC-SHA256(key, bytes 0..39)

POSE, client -> server, 156 bytes::

    32     8    f64       client timestamp (the client's monotonic clock)
    40     24   f64[3]    stylus position x, y, z
    64     24   f64[3]    stylus velocity (all three NaN: unknown, the server differentiates)
    88     32   f64[4]    stylus orientation quaternion w, x, y, z
    120    4    u32       buttons bitmask (bit 0: first button)
    124    32   u8[32]    HMAC-SHA256(key, bytes 0..123)

FORCE, server -> pinned client, 112 bytes::

    6      2    u16       flags: bit 0 STALE_INPUT, bit 1 RAMPING, bit 2 CLAMPED
    32     8    u64       ack: sequence number of the last accepted POSE
    40     8    f64       server timestamp (the server's monotonic clock)
    48     8    f64       echo: client timestamp of the acknowledged POSE (round-trip time)
    56     24   f64[3]    force on the handle x, y, z
    80     32   u8[32]    HMAC-SHA256(key, bytes 0..79)

RELEASE, client -> server, 72 bytes (the client is done; another may take over)::

    32     8    f64       client timestamp
    40     32   u8[32]    HMAC-SHA256(key, bytes 0..39)

Sequence numbers are per sender and per key: each packet's number is larger than that of every
packet the sender sent before under the same key. A client that may restart starts from its wall
clock in microseconds (``time.time_ns() // 1000``), which also stays ahead of an earlier client
that sent under the same key; the server does the same for FORCE and CHALLENGE packets.

The server drops, counts in :attr:`UdpBridgeDevice.stats`, and otherwise ignores: datagrams
longer than the packet their type needs (``oversized``) or shorter (``truncated``); a wrong magic
(``bad_magic``), version (``bad_version``; versions 1 and 2 included), or type (``bad_type``);
any packet from a sender other than the pinned peer that was queued before the socket was
connected (``foreign``, checked before the tag, so a stranger costs no HMAC); a POSE or RELEASE
whose session field is not this session's (``bad_session``, before the tag too); a wrong tag
(``bad_mac``: wrong key, or altered bytes); a sequence number not above the last accepted one
(``replayed`` if that number was accepted, among the last 64, ``out_of_order`` otherwise);
non-finite position, time or orientation (``nonfinite``); a POSE whose client timestamp is not
later than the last accepted one (``stale``). A HELLO with a good tag is answered with a CHALLENGE
(``hellos``) and changes nothing else. Nothing a packet contains can raise. The tag is compared in
constant time (:func:`hmac.compare_digest`). At most ``max_packets_per_read`` datagrams are read
per tick.

If no POSE has been accepted for ``stale_after`` seconds the input is stale: the force sent ramps
linearly to zero in ``ramp_down`` seconds (and back up in ``ramp_up`` once fresh poses arrive),
the FORCE flags say so, and ``DeviceState.timestamp`` (the local receive time of the last accepted
pose) lets the safety layer see the age too. A stale peer stays pinned. A RELEASE from the peer
unpins it at once (the force gain drops to zero, nothing more is sent to it, the socket takes
datagrams from anyone again). The client must check every FORCE (sender address, tag, sequence,
session, ``ack`` among its own poses, finiteness, its device's force limit) and apply zero force
when it hears no valid FORCE for a while.

Keys: :func:`generate_key` (32 random bytes, :func:`secrets.token_bytes`), :func:`save_key`
(hex text in a file created with mode 0o600 in a folder of the user's own), :func:`load_key`
(refuses a file other users can read, own or could have planted, as ssh does), :func:`key_from_hex`.
A bridge on loopback without a key makes a fresh one (:attr:`key`); binding any other address needs
a key given by the operator. A key may be reused across sessions: the session id keeps each
session's packets its own.

Examples
--------
>>> import socket
>>> key = bytes(range(32))
>>> with UdpBridgeDevice(port=0, key=key) as dev:
...     with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
...         _ = c.sendto(encode_hello(key, seq=1, t=0.0), dev.address)
...         while dev.stats.hellos == 0:
...             _ = dev.poll()
...         session = decode_challenge(key, c.recv(256))["session"]
...         _ = c.sendto(encode_pose(key, seq=2, t=0.0, position=(0.01, 0.0, 0.0), buttons=1, session=session),
...                      dev.address)
...         dev.wait_for_client(timeout=2.0)
...         s = dev.read_state()
...         dev.command_force([0.0, 0.0, 1.0])
...         reply = decode_force(key, c.recv(256))
>>> s.position.tolist(), s.buttons, reply["ack"], reply["force"]
([0.01, 0.0, 0.0], 1, 2, (0.0, 0.0, 1.0))
"""
from __future__ import annotations

import errno
import hashlib
import hmac
import ipaddress
import math
import os
import secrets
import socket
import stat
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from arsurf.errors import HapticsError
from arsurf.haptics.device import Device, DeviceInfo, DeviceState, TOUCH_X

__all__ = [
    "DEFAULT_PORT",
    "CHALLENGE_SIZE",
    "FORCE_SIZE",
    "HELLO_SIZE",
    "MAC_SIZE",
    "MAGIC",
    "POSE_SIZE",
    "NO_SESSION",
    "RELEASE_SIZE",
    "SESSION_SIZE",
    "VERSION",
    "BridgeStats",
    "UdpBridgeDevice",
    "decode_challenge",
    "decode_force",
    "decode_pose",
    "encode_challenge",
    "encode_force",
    "encode_hello",
    "encode_pose",
    "encode_release",
    "generate_key",
    "is_loopback",
    "key_from_hex",
    "load_key",
    "packet_mac",
    "save_key",
]

MAGIC = b"ARSH"
VERSION = 3
TYPE_POSE = 1
TYPE_FORCE = 2
TYPE_RELEASE = 3
TYPE_HELLO = 4
TYPE_CHALLENGE = 5
FLAG_STALE_INPUT = 1  # FORCE flags
FLAG_RAMPING = 2
FLAG_CLAMPED = 4
#: Default UDP port of the bridge (any free port works; 0 picks one).
DEFAULT_PORT = 47474
#: Length of the HMAC-SHA256 tag that ends every packet, bytes.
MAC_SIZE = 32
#: Length of a generated session key, bytes: 256 bits, the SHA-256 output length (RFC 2104 sec. 3: at least that).
KEY_SIZE = 32
#: Length of the session id the server draws at every open (and a HELLO's zero field), bytes.
SESSION_SIZE = 16
#: The session field of a HELLO (the client has no session yet).
NO_SESSION = bytes(SESSION_SIZE)
_KEY_MIN, _KEY_MAX = 16, 64  # 128 bits at least; HMAC hashes longer keys (RFC 2104 sec. 3)

_HEADER = struct.Struct("<4sBBHQ")
_SESSION = struct.Struct("<16s")
_POSE_BODY = struct.Struct("<4sBBHQ16sd3d3d4dI")
_FORCE_BODY = struct.Struct("<4sBBHQ16sQdd3d")
_RELEASE_BODY = struct.Struct("<4sBBHQ16sd")  # HELLO: the same layout, session field zero
_CHALLENGE_BODY = struct.Struct("<4sBBHQ16sQ")
POSE_SIZE = _POSE_BODY.size + MAC_SIZE  #: 156 bytes
FORCE_SIZE = _FORCE_BODY.size + MAC_SIZE  #: 112 bytes
RELEASE_SIZE = _RELEASE_BODY.size + MAC_SIZE  #: 72 bytes
HELLO_SIZE = RELEASE_SIZE  #: 72 bytes
CHALLENGE_SIZE = _CHALLENGE_BODY.size + MAC_SIZE  #: 72 bytes: never larger than the HELLO it answers
_SERVER_SIZES = {TYPE_POSE: POSE_SIZE, TYPE_RELEASE: RELEASE_SIZE, TYPE_HELLO: HELLO_SIZE}
_RECV_BUFFER = 2048  # anything longer than a POSE is oversized; this only bounds the copy
_SEQ_MAX = (1 << 64) - 1
_WINDOW = 64  # accepted sequence numbers remembered below the newest, to tell replays apart


# -- keys ---------------------------------------------------------------------------------------
def generate_key() -> bytes:
    """A fresh session key: 32 bytes from the operating system's CSPRNG (:func:`secrets.token_bytes`).

    Examples
    --------
    >>> len(generate_key()), generate_key() != generate_key()
    (32, True)
    """
    return secrets.token_bytes(KEY_SIZE)


def _check_key(key) -> bytes:
    if not isinstance(key, (bytes, bytearray)):
        raise HapticsError(f"the bridge key must be bytes (got {type(key).__name__}); "
                           "use generate_key(), load_key(path) or key_from_hex(text)")
    if not (_KEY_MIN <= len(key) <= _KEY_MAX):
        raise HapticsError(f"the bridge key must be {_KEY_MIN} to {_KEY_MAX} bytes (got {len(key)}); "
                           f"generate_key() makes a {KEY_SIZE}-byte one")
    return bytes(key)


def key_from_hex(text: str) -> bytes:
    """The key written as hexadecimal text (32 to 128 hex digits; surrounding whitespace ignored).

    The message of a bad key never repeats the text (it may be most of a secret).

    Examples
    --------
    >>> key_from_hex("00" * 32) == bytes(32)
    True
    """
    if not isinstance(text, str):
        raise HapticsError(f"the bridge key must be hexadecimal text (got {type(text).__name__})")
    s = text.strip()
    try:
        key = bytes.fromhex(s)
    except ValueError:
        raise HapticsError(f"the bridge key must be hexadecimal digits only (got {len(s)} characters that are "
                           "not); write it as 64 hex digits, as save_key() does") from None
    return _check_key(key)


def _folder_problem(folder: str, st: os.stat_result) -> str | None:
    """Why ``folder`` may not hold a key file (as ssh judges a key's folder), or None.

    Owned by the current user or root, and writable by its owner only: in a folder others can
    write to, one of them could plant the key file first (then read, or drive, the session)."""
    if st.st_uid not in (os.geteuid(), 0):
        return f"is owned by uid {st.st_uid}, not by you (uid {os.geteuid()}) or root"
    if st.st_mode & 0o022:
        return f"is writable by other users (mode {oct(stat.S_IMODE(st.st_mode))})"
    return None


def save_key(path, key: bytes) -> str:
    """Write ``key`` as one line of hex to a new file readable by its owner only (mode 0o600).

    The file is created exclusively (an existing file is never overwritten or followed), in a
    folder only its owner can write to (the rule :func:`load_key` checks).

    Returns
    -------
    str
        The path written.
    """
    key = _check_key(key)
    path = os.fspath(path)
    if os.name == "posix":
        folder = os.path.dirname(os.path.abspath(path))
        try:
            why = _folder_problem(folder, os.stat(folder))
        except OSError as exc:
            raise HapticsError(f"cannot write the bridge key file {path!r}: its folder {folder!r} "
                               f"({exc.strerror})") from None
        if why:
            raise HapticsError(f"refusing to write the bridge key file {path!r}: its folder {folder!r} {why}; "
                               "pick a folder of your own (chmod go-w)")
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
    except FileExistsError:
        raise HapticsError(f"key file {path!r} already exists; refusing to overwrite it "
                           "(read it with load_key, or pick a new path)") from None
    except OSError as exc:
        raise HapticsError(f"cannot write the bridge key file {path!r} ({exc.strerror})") from None
    with os.fdopen(fd, "w") as fh:
        if hasattr(os, "fchmod"):
            os.fchmod(fh.fileno(), 0o600)  # whatever the umask did
        fh.write(key.hex() + "\n")
    return path


def load_key(path) -> bytes:
    """Read a key written by :func:`save_key`, refusing a file someone else could have planted or read.

    As ssh does for a private key: the file must be a regular file (not a link, FIFO or device),
    owned by the current user, readable and writable by its owner only (mode ``0600`` or
    stricter), in a folder owned by the current user or root that no one else can write to.
    Checked on the opened file (no race between the check and the read), opened without
    following a link and without blocking.

    Examples
    --------
    >>> import tempfile, os
    >>> d = tempfile.mkdtemp()
    >>> load_key(save_key(os.path.join(d, "k"), bytes(range(32)))) == bytes(range(32))
    True
    """
    path = os.fspath(path)
    how = "create one with save_key or let the bridge generate it"
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        why = "it is a symbolic link" if exc.errno == errno.ELOOP else exc.strerror
        raise HapticsError(f"cannot read the bridge key file {path!r} ({why}); {how}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise HapticsError(f"the bridge key file {path!r} is not a regular file; {how}")
        if os.name == "posix":
            if st.st_uid != os.geteuid():
                raise HapticsError(f"the bridge key file {path!r} is owned by uid {st.st_uid}, not by you (uid "
                                   f"{os.geteuid()}): someone else may have planted it; {how} in a folder of your own")
            if st.st_mode & 0o077:
                raise HapticsError(f"the bridge key file {path!r} is accessible to other users (mode "
                                   f"{oct(st.st_mode & 0o777)}); make it owner-only: chmod 600 {path}")
            folder = os.path.dirname(os.path.abspath(path))
            why = _folder_problem(folder, os.stat(folder))
            if why:
                raise HapticsError(f"the bridge key file {path!r} is in a folder that {why} ({folder!r}): someone "
                                   "else could have planted it; keep key files in a folder of your own (chmod go-w)")
        if st.st_size > 4096:
            raise HapticsError(f"the bridge key file {path!r} is {st.st_size} bytes; a key file is one line of hex")
        text = os.read(fd, 4097).decode("ascii", errors="replace")
    except OSError as exc:
        raise HapticsError(f"cannot read the bridge key file {path!r} ({exc.strerror}); {how}") from None
    finally:
        os.close(fd)
    return key_from_hex(text)


def is_loopback(host: str) -> bool:
    """True if ``host`` is a loopback address (``127.0.0.0/8``, ``::1``) or ``"localhost"``.

    A host name other than ``localhost`` counts as not loopback (it may resolve to anything).

    Examples
    --------
    >>> is_loopback("127.0.0.1"), is_loopback("0.0.0.0"), is_loopback("192.168.1.5")
    (True, False, False)
    """
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


# -- packets ------------------------------------------------------------------------------------
def packet_mac(key: bytes, body) -> bytes:
    """The 32-byte tag of a packet: HMAC-SHA256 under ``key`` of ``body`` (every byte before the tag).

    Examples
    --------
    >>> packet_mac(bytes(32), b"").hex()[:16]
    'b613679a0814d9ec'
    """
    return hmac.new(key, body, hashlib.sha256).digest()


def _seq(seq) -> int:
    s = int(seq)
    if not 0 <= s <= _SEQ_MAX:
        raise HapticsError(f"sequence number must be in 0..2**64-1 (got {s}); it never wraps: use a new key")
    return s


def _session(session) -> bytes:
    if not isinstance(session, (bytes, bytearray)) or len(session) != SESSION_SIZE:
        raise HapticsError(f"the session id must be {SESSION_SIZE} bytes (got {session!r:.40}); it is the one the "
                           "bridge's CHALLENGE gave")
    return bytes(session)


def encode_pose(key: bytes, seq: int, t: float, position, velocity=(math.nan, math.nan, math.nan),
                quaternion=(1.0, 0.0, 0.0, 0.0), buttons: int = 0, *, session: bytes) -> bytes:
    """A POSE packet (156 bytes) of the session ``session``, as the protocol above defines it, tagged under ``key``.

    Examples
    --------
    >>> len(encode_pose(bytes(32), seq=7, t=1.5, position=(0.0, 0.0, 0.0), session=bytes(16)))
    156
    """
    body = _POSE_BODY.pack(MAGIC, VERSION, TYPE_POSE, 0, _seq(seq), _session(session), float(t),
                           *(float(v) for v in position), *(float(v) for v in velocity),
                           *(float(v) for v in quaternion), int(buttons) & 0xFFFFFFFF)
    return body + packet_mac(key, body)


def encode_release(key: bytes, seq: int, t: float, *, session: bytes) -> bytes:
    """A RELEASE packet (72 bytes): the client is done, the server unpins it.

    Examples
    --------
    >>> len(encode_release(bytes(32), seq=9, t=2.0, session=bytes(16)))
    72
    """
    body = _RELEASE_BODY.pack(MAGIC, VERSION, TYPE_RELEASE, 0, _seq(seq), _session(session), float(t))
    return body + packet_mac(key, body)


def encode_hello(key: bytes, seq: int, t: float) -> bytes:
    """A HELLO packet (72 bytes): a client asks for the session id (the server answers CHALLENGE).

    Examples
    --------
    >>> len(encode_hello(bytes(32), seq=1, t=0.0))
    72
    """
    body = _RELEASE_BODY.pack(MAGIC, VERSION, TYPE_HELLO, 0, _seq(seq), NO_SESSION, float(t))
    return body + packet_mac(key, body)


def encode_challenge(key: bytes, seq: int, ack: int, session: bytes) -> bytes:
    """A CHALLENGE packet (72 bytes): the session id, answering the HELLO numbered ``ack``.

    Examples
    --------
    >>> k = bytes(32)
    >>> decode_challenge(k, encode_challenge(k, 5, 4, bytes(range(16))))["session"] == bytes(range(16))
    True
    """
    body = _CHALLENGE_BODY.pack(MAGIC, VERSION, TYPE_CHALLENGE, 0, _seq(seq), _session(session), _seq(ack))
    return body + packet_mac(key, body)


def _verify(key: bytes, mv, size: int) -> bool:
    return hmac.compare_digest(packet_mac(key, mv[:size - MAC_SIZE]), mv[size - MAC_SIZE:size])


def decode_pose(key: bytes, data) -> dict | None:
    """Fields of a POSE packet, or None if it is not a valid one (size, magic, version, type, tag).

    Examples
    --------
    >>> k, sid = bytes(32), bytes(range(16))
    >>> decode_pose(k, encode_pose(k, seq=3, t=0.25, position=(1.0, 2.0, 3.0), buttons=2, session=sid))["position"]
    (1.0, 2.0, 3.0)
    >>> decode_pose(k, b"junk") is None, decode_pose(b"another key 16 B", encode_pose(k, 3, 0.0, (0, 0, 0), session=sid))
    (True, None)
    """
    mv = memoryview(data)
    if len(mv) != POSE_SIZE:
        return None
    f = _POSE_BODY.unpack_from(mv)
    if f[0] != MAGIC or f[1] != VERSION or f[2] != TYPE_POSE or not _verify(key, mv, POSE_SIZE):
        return None
    return {"flags": f[3], "seq": f[4], "session": f[5], "t": f[6], "position": f[7:10], "velocity": f[10:13],
            "quaternion": f[13:17], "buttons": f[17]}


def encode_force(key: bytes, seq: int, ack: int, t: float, echo: float, force, flags: int = 0, *,
                 session: bytes) -> bytes:
    """A FORCE packet (112 bytes) of the session ``session``, tagged under ``key``.

    Examples
    --------
    >>> k, sid = bytes(32), bytes(16)
    >>> decode_force(k, encode_force(k, 1, 2, 0.5, 0.25, (0.0, 1.0, 0.0), session=sid))["force"]
    (0.0, 1.0, 0.0)
    """
    body = _FORCE_BODY.pack(MAGIC, VERSION, TYPE_FORCE, int(flags) & 0xFFFF, _seq(seq), _session(session), _seq(ack),
                            float(t), float(echo), *(float(v) for v in force))
    return body + packet_mac(key, body)


def decode_force(key: bytes, data) -> dict | None:
    """Fields of a FORCE packet, or None if it is not a valid one (size, magic, version, type, tag).

    Only the format and the tag are checked here; a client also checks the sender, the sequence
    number, the session, the ``ack``, finiteness and its force limit (:mod:`arsurf.haptics.client` does).
    """
    mv = memoryview(data)
    if len(mv) != FORCE_SIZE:
        return None
    f = _FORCE_BODY.unpack_from(mv)
    if f[0] != MAGIC or f[1] != VERSION or f[2] != TYPE_FORCE or not _verify(key, mv, FORCE_SIZE):
        return None
    return {"flags": f[3], "seq": f[4], "session": f[5], "ack": f[6], "t": f[7], "echo": f[8], "force": f[9:12]}


def decode_challenge(key: bytes, data) -> dict | None:
    """Fields of a CHALLENGE packet (``seq``, ``session``, ``ack``), or None if it is not a valid one."""
    mv = memoryview(data)
    if len(mv) != CHALLENGE_SIZE:
        return None
    f = _CHALLENGE_BODY.unpack_from(mv)
    if f[0] != MAGIC or f[1] != VERSION or f[2] != TYPE_CHALLENGE or not _verify(key, mv, CHALLENGE_SIZE):
        return None
    return {"seq": f[4], "session": f[5], "ack": f[6]}


def _disconnect(sock) -> None:
    """Undo ``connect`` on a UDP socket: ``connect`` to an ``AF_UNSPEC`` address (POSIX ``connect()``:
    "the socket's peer address shall be reset"), through the C library since Python's ``connect``
    only takes addresses of the socket's family. Where that is not possible the socket stays
    connected and only the old peer is heard until the bridge is reopened: fail closed."""
    if sock is None:
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        unspec = (ctypes.c_ubyte * 16)()  # sockaddr, sa_family = AF_UNSPEC = 0 (Linux u16, BSD sa_len + u8)
        libc.connect(sock.fileno(), unspec, ctypes.c_uint32(16))
    except (OSError, AttributeError):
        pass


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
    foreign: int = 0
    bad_session: int = 0
    bad_mac: int = 0
    replayed: int = 0
    out_of_order: int = 0
    nonfinite: int = 0
    stale: int = 0
    releases: int = 0
    hellos: int = 0
    pins: int = 0
    peer_timeouts: int = 0
    resyncs: int = 0
    sent: int = 0
    send_errors: int = 0
    receive_errors: int = 0

    @property
    def dropped(self) -> int:
        """All packets received and neither accepted, a release nor a hello."""
        return (self.oversized + self.truncated + self.bad_magic + self.bad_version + self.bad_type + self.foreign
                + self.bad_session + self.bad_mac + self.replayed + self.out_of_order + self.nonfinite + self.stale)

    def as_dict(self) -> dict[str, int]:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["dropped"] = self.dropped
        return d


class UdpBridgeDevice(Device):
    """A device whose stylus lives on another machine: authenticated poses in, forces out, over UDP.

    Parameters
    ----------
    host : str
        Address to listen on (default ``"127.0.0.1"``: loopback only). Any other address (the
        interface of the network the haptic PC is on) needs ``key``.
    port : int
        UDP port (default :data:`DEFAULT_PORT`; 0 picks a free one, see :attr:`address`).
    info : DeviceInfo
        Limits of the remote device (default: Touch X); forces are clamped to ``info.max_force``.
    key : bytes, optional
        Session key (16 to 64 bytes) shared with the client out of band. None (loopback only):
        a fresh :func:`generate_key`, readable as :attr:`key` to hand to the client.
    stale_after : float, s
        Input older than this is stale (default 0.05 s).
    ramp_down, ramp_up : float, s
        Time for the sent force to fade to zero on stale input, and to come back (0.05 s, 0.2 s).
    peer_timeout : float or None, s
        Unpin a peer silent for this long, so another client may take over (default None:
        the peer stays pinned for the whole session, until it sends RELEASE).
    clock : callable
        Monotonic clock in seconds (default :func:`time.perf_counter`); tests inject their own.
    max_packets_per_read : int
        Bound on the datagrams drained per :meth:`read_state` (default 64: a tick's work on
        received datagrams is bounded whatever arrives; the pinned operator sends one per tick).

    Attributes
    ----------
    stats : BridgeStats
    orientation : (4,) float
        Latest stylus orientation quaternion (w, x, y, z).
    peer : tuple or None
        Address of the pinned client (forces go there only), None before the first valid POSE
        and after a RELEASE or a peer timeout. While a peer is pinned the socket is connected
        to it: the kernel drops every other sender's datagrams before they queue.
    key : bytes
        The session key.
    session : bytes
        The session id (16 random bytes drawn at every :meth:`open`), sent in CHALLENGE packets;
        a POSE or RELEASE of any other session is dropped (``bad_session``).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, info: DeviceInfo = TOUCH_X, *,
                 key: bytes | None = None, stale_after: float = 0.05, ramp_down: float = 0.05,
                 ramp_up: float = 0.2, peer_timeout: float | None = None,
                 clock: Callable[[], float] = time.perf_counter, max_packets_per_read: int = 64) -> None:
        super().__init__()
        if not isinstance(host, str) or not host:
            raise HapticsError(f"host must be an address string such as '127.0.0.1' (got {host!r})")
        if not isinstance(port, (int, np.integer)) or not (0 <= port <= 65535):
            raise HapticsError(f"port must be an integer in 0..65535 (got {port!r}); 0 picks a free port")
        if not isinstance(info, DeviceInfo):
            raise HapticsError(f"info must be a DeviceInfo (got {type(info).__name__})")
        if key is None:
            if not is_loopback(host):
                raise HapticsError(f"binding the bridge to {host!r} (not loopback) needs a key given by the operator "
                                   "(key=..., or --bridge-key-file); only on 127.0.0.1 is one generated")
            key = generate_key()
        self.key = _check_key(key)
        for name, v in (("stale_after", stale_after), ("ramp_down", ramp_down), ("ramp_up", ramp_up)):
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise HapticsError(f"{name} must be a positive number of seconds (got {v!r})")
        if peer_timeout is not None and not (isinstance(peer_timeout, (int, float)) and peer_timeout > 0
                                             and math.isfinite(peer_timeout)):
            raise HapticsError(f"peer_timeout must be a positive number of seconds or None (got {peer_timeout!r}); "
                               "None keeps the client pinned for the whole session")
        if not isinstance(max_packets_per_read, int) or max_packets_per_read < 1:
            raise HapticsError(f"max_packets_per_read must be a positive integer (got {max_packets_per_read!r})")
        self.host, self.port = host, int(port)
        self._info = info
        self.stale_after, self.ramp_down, self.ramp_up = float(stale_after), float(ramp_down), float(ramp_up)
        self.peer_timeout = None if peer_timeout is None else float(peer_timeout)
        self.clock = clock
        self.max_packets_per_read = max_packets_per_read
        self.stats = BridgeStats()
        self._sock: socket.socket | None = None
        self._buf = bytearray(_RECV_BUFFER)
        self._mv = memoryview(self._buf)
        self.session = NO_SESSION
        self._reset_session()

    def _reset_session(self) -> None:
        self.peer = None
        self._last_seq = None  # newest accepted sequence number (POSE or RELEASE), whole session
        self._seen = 0  # bit k: sequence number _last_seq - k was accepted
        self._last_client_t = -math.inf
        self._last_rx = -math.inf
        self._position = np.zeros(3)
        self._velocity = np.zeros(3)
        self.orientation = np.array([1.0, 0.0, 0.0, 0.0])
        self._buttons = 0
        self._gain = 1.0  # the safety layer ramps in at start-up; this gain only fades stale input
        self._last_cmd = None
        self._tx_seq = time.time_ns() // 1000  # ahead of any earlier server under the same key
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

    def _bind(self, port: int) -> socket.socket:
        """A non-blocking UDP socket bound to ``(host, port)`` with ``port`` given explicitly: the
        kernel then keeps the port when the socket is disconnected from a peer (Linux releases a
        port it chose itself)."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            sock.bind((self.host, port))
        except OSError:
            sock.close()
            raise
        return sock

    def _open(self) -> None:
        try:
            if self.port != 0:
                sock = self._bind(self.port)
            else:  # a free port chosen by the kernel, then bound by its number (nobody knows it yet)
                for attempt in range(20):
                    probe = self._bind(0)
                    free = probe.getsockname()[1]
                    probe.close()
                    try:
                        sock = self._bind(free)
                        break
                    except OSError:
                        if attempt == 19:
                            raise
        except OSError as exc:
            raise HapticsError(
                f"cannot listen on UDP {self.host}:{self.port} ({exc}); pick another port (0 = any free one)"
            ) from exc
        self._sock = sock
        self._bound = sock.getsockname()
        self.session = secrets.token_bytes(SESSION_SIZE)  # a packet of an earlier session never matches
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
        self._tx_seq = min(self._tx_seq + 1, _SEQ_MAX)
        pkt = encode_force(self.key, self._tx_seq, self._last_seq or 0, self.now(), self._last_client_t
                           if math.isfinite(self._last_client_t) else math.nan, force, flags, session=self.session)
        self._transmit(pkt, self.peer)

    def _transmit(self, pkt: bytes, addr) -> None:
        try:
            if self.peer is not None and addr == self.peer:
                self._sock.send(pkt)  # connected to the peer
            else:
                self._sock.sendto(pkt, addr)
            self.stats.sent += 1
        except OSError:  # peer gone (ICMP unreachable), buffer full: never break the loop
            self.stats.send_errors += 1

    def _pin(self, addr) -> None:
        """Pin ``addr``: from now on the kernel delivers its datagrams only (``connect``)."""
        try:
            self._sock.connect(addr)
        except OSError:  # cannot happen for an address a datagram came from; filter in Python then
            pass
        self.peer = addr

    def _unpin(self) -> None:
        self.peer = None
        _disconnect(self._sock)  # datagrams from anyone again: the next client may say HELLO
        if self._sock is not None and self._sock.getsockname() != self._bound:  # never lose the port
            self._sock.close()
            self._sock = None
            try:
                self._sock = self._bind(self._bound[1])
            except OSError:
                self.stats.receive_errors += 1  # the port is gone: nobody can drive the probe any more
        self._last_rx = -math.inf
        self._last_client_t = -math.inf
        self._gain = 0.0  # whoever comes next starts from zero force

    # -- receiving --------------------------------------------------------------------------
    def poll(self) -> int:
        """Drain pending datagrams (at most ``max_packets_per_read``); returns how many were accepted."""
        if self._sock is None:
            return 0
        if (self.peer is not None and self.peer_timeout is not None
                and self.now() - self._last_rx > self.peer_timeout):
            self.stats.peer_timeouts += 1
            self._unpin()
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
            if self._accept(n, addr):
                accepted += 1
        return accepted

    def _check_seq(self, seq: int) -> bool:
        """Is ``seq`` newer than every accepted one? Counts ``replayed`` / ``out_of_order`` if not."""
        last = self._last_seq
        if last is None or seq > last:
            return True
        k = last - seq
        if k < _WINDOW and (self._seen >> k) & 1:
            self.stats.replayed += 1
        else:
            self.stats.out_of_order += 1
        return False

    def _take_seq(self, seq: int) -> None:
        last = self._last_seq
        d = _WINDOW if last is None else seq - last
        self._seen = ((self._seen << d) | 1) & ((1 << _WINDOW) - 1) if d < _WINDOW else 1
        self._last_seq = seq

    def _accept(self, n: int, addr) -> bool:
        st = self.stats
        buf = self._buf
        if n > POSE_SIZE:
            st.oversized += 1
            return False
        if n < _HEADER.size:
            st.truncated += 1
            return False
        magic, version, kind, _flags, seq = _HEADER.unpack_from(buf)
        if magic != MAGIC:
            st.bad_magic += 1
            return False
        if version != VERSION:
            st.bad_version += 1
            return False
        size = _SERVER_SIZES.get(kind)
        if size is None:
            st.bad_type += 1
            return False
        if n != size:
            if n > size:
                st.oversized += 1
            else:
                st.truncated += 1
            return False
        if self.peer is not None and addr != self.peer:  # queued before the socket was connected
            st.foreign += 1
            return False
        if kind == TYPE_HELLO:
            if not _verify(self.key, self._mv, size):
                st.bad_mac += 1
                return False
            st.hellos += 1  # answered whatever its number: it changes no state, and the answer is no larger
            self._tx_seq = min(self._tx_seq + 1, _SEQ_MAX)
            self._transmit(encode_challenge(self.key, self._tx_seq, seq, self.session), addr)
            return False
        if buf[16:16 + SESSION_SIZE] != self.session:  # another session's packet (the id is no secret:
            st.bad_session += 1                          # this only spares the HMAC)
            return False
        if not _verify(self.key, self._mv, size):
            st.bad_mac += 1
            return False
        if not self._check_seq(seq):
            return False
        if kind == TYPE_RELEASE:
            self._take_seq(seq)
            st.releases += 1
            if self.peer is not None:
                self._unpin()
            return False
        f = _POSE_BODY.unpack_from(buf)
        t, pos, vel, quat = f[6], f[7:10], f[10:13], f[13:17]
        if not (math.isfinite(t) and all(math.isfinite(v) for v in pos) and all(math.isfinite(v) for v in quat)):
            st.nonfinite += 1
            return False
        now = self.now()
        resync = self.peer is None or (now - self._last_rx) > self.stale_after
        if not resync and not t > self._last_client_t:
            st.stale += 1
            return False
        if self.peer is None:
            st.pins += 1
        elif resync:
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
        if qn > 0.0 and math.isfinite(qn):
            self.orientation[:] = q / qn
        self._buttons = int(f[17])
        self._take_seq(seq)
        self._last_client_t = t
        self._last_rx = now
        if self.peer is None:
            self._pin(addr)
        st.accepted += 1
        return True

    def wait_for_client(self, timeout: float = 5.0) -> None:
        """Block until a pose has been accepted (polling every millisecond), or raise HapticsError."""
        self._require_open()
        deadline = time.monotonic() + float(timeout)
        while self.peer is None:
            self.poll()
            if self.peer is not None:
                break
            if time.monotonic() > deadline:
                raise HapticsError(
                    f"no valid pose packet on UDP {self.address[0]}:{self.address[1]} within {timeout} s "
                    f"(received {self.stats.received}, dropped {self.stats.dropped}, wrong key "
                    f"{self.stats.bad_mac}); start the client (python -m arsurf.haptics.client) with this host, port and key"
                )
            time.sleep(0.001)
