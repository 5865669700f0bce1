r"""The Nanonis TCP programming interface: message layout and the commands arsurf uses.

The Nanonis software is a TCP server (ports 6501-6504 by default); each connection executes its
commands one after the other. Every message is a 40-byte header and a body, every number
big-endian (Nanonis "TCP Protocol - TCP Programming Interface", R14718, "Request message" and
"Response message"; the vendor's package ``nanonis-spm`` 1.0.9, ``Nanonis.send``):

========================  ======  =====================================================
request header            bytes   value
========================  ======  =====================================================
command name              32      ASCII, zero padded (``FolMe.XYPosGet``)
body size                 4       int32, bytes of the body
send response back        2       uint16, 1: the server answers (always, here)
not used                  2       zero
========================  ======  =====================================================

The response header is the command name (32), the body size (int32) and 4 unused bytes. The
response body holds the return values, then the *error section*: error status (uint32, 1 = an
error), error description size (int32) and the description (string). Strings in a body are
prepended by their size (int32); arrays usually by their number of elements (int32); an array
of strings by its size in bytes and its number of elements, each string prepended by its size.

Type codes (those of the vendor's ``quickSend``): ``H`` uint16, ``I`` uint32, ``i`` int32,
``f`` float32, ``d`` float64; ``+*i`` an int32 array prepended by its length (request);
``*f`` / ``*i`` a float32 / int32 array whose length is the value before it, ``*-c`` a string
whose byte size is the value before it, ``*+c`` an array of strings whose byte size and count
are the two values before it, ``2f`` a 2-D float32 array (row-major) whose rows and columns are
the two values before it (replies). A frame (``Scan.FrameDataGrab``) may be larger than other
replies: up to :data:`MAX_FRAME_BODY`.

:data:`COMMANDS` lists every command arsurf sends with its argument and return types, checked
against the protocol document and ``nanonis_spm.Nanonis`` (``tests/test_nanonis.py`` compares
the bytes with the vendor package's when it is installed).

Everything received is untrusted: :func:`decode_reply` and :func:`decode_request` check every
size and count against the bytes actually there before reading, cap the body at
:data:`MAX_BODY`, and raise :class:`~arsurf.errors.InstrumentLinkLost` (the stream cannot be
trusted any more) or :class:`~arsurf.errors.ControllerError` (the controller reported an
error) with one line.

Examples
--------
>>> msg = encode_request("FolMe.XYPosGet", (1,))
>>> msg[:14], len(msg), msg[32:40].hex()
(b'FolMe.XYPosGet', 44, '0000000400010000')
>>> body = encode_reply_body("FolMe.XYPosGet", (5e-9, -5e-9))
>>> decode_reply("FolMe.XYPosGet", body)
(5e-09, -5e-09)
"""
from __future__ import annotations

import struct

import numpy as np

from arsurf.errors import ControllerError, InstrumentLinkLost

__all__ = ["COMMANDS", "HEADER_SIZE", "MAX_BODY", "MAX_FRAME_BODY", "body_limit", "decode_reply", "decode_request", "encode_error_reply", "encode_reply",
           "encode_reply_body", "encode_request", "parse_header"]

HEADER_SIZE = 40
#: the largest body accepted (a reply to the commands used here is < 10 kB; 128 signal names ~ 3 kB)
MAX_BODY = 1 << 20
#: the longest string accepted inside a body
MAX_STRING = 1 << 16
_REQUEST_HEADER = struct.Struct(">32siHH")
_REPLY_HEADER = struct.Struct(">32si4x")
_SCALARS = {"H": struct.Struct(">H"), "I": struct.Struct(">I"), "i": struct.Struct(">i"), "f": struct.Struct(">f"),
            "d": struct.Struct(">d")}
_ERROR = struct.Struct(">Ii")

#: command -> (argument types, return types); from the TCP protocol document (R14718) and the
#: vendor package nanonis-spm 1.0.9 (the method of the same name, ``.`` -> ``_``)
COMMANDS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # wait for newest data (uint32) -> X, Y (m, float64)
    "FolMe.XYPosGet": (("I",), ("d", "d")),
    # X, Y (m, float64), wait end of move (uint32)
    "FolMe.XYPosSet": (("d", "d", "I"), ()),
    # speed (m/s, float32), custom speed (uint32: 1 uses this speed, 0 the scan speed)
    "FolMe.SpeedSet": (("f", "I"), ()),
    "FolMe.SpeedGet": ((), ("f", "I")),
    "FolMe.Stop": ((), ()),
    # Z position (m, float32); set only with the Z controller off
    "ZCtrl.ZPosGet": ((), ("f",)),
    "ZCtrl.ZPosSet": (("f",), ()),
    # Z controller status (uint32: 0 off, 1 on)
    "ZCtrl.OnOffGet": ((), ("I",)),
    "ZCtrl.OnOffSet": (("I",), ()),
    # wait until finished (uint32), timeout (ms, int32; -1 forever): controller off, tip fully up
    "ZCtrl.Withdraw": (("I", "i"), ()),
    # Z high limit, Z low limit (m, float32); the piezo range when the limits are not enabled
    "ZCtrl.LimitsGet": ((), ("f", "f")),
    # 1 off, 2 on, 3 hold, 4 switching off, 5 safe tip event, 6 withdrawing (uint16)
    "ZCtrl.StatusGet": ((), ("H",)),
    # names size (bytes, int32), names number (int32), names (1D array of strings)
    "Signals.NamesGet": ((), ("i", "i", "*+c")),
    # signal indexes (int32 array, length prepended), wait for newest data (uint32)
    # -> values size (int32), values (float32 array), in physical units
    "Signals.ValsGet": (("+*i", "I"), ("i", "*f")),
    # range X, Y, Z (m, float32)
    "Piezo.RangeGet": ((), ("f", "f", "f")),
    # the TCP receiver's acquisition period Tap (s, float32): Signals.ValsGet returns 0..Tap after the
    # call (Tap..2 Tap waiting for newest data), its values oversampled over Tap
    "Util.AcqPeriodGet": ((), ("f",)),
    "Util.AcqPeriodSet": (("f",), ()),
    "AutoApproach.Open": ((), ()),
    # on/off (uint16): starts (1) or stops (0) the auto-approach
    "AutoApproach.OnOffSet": (("H",), ()),
    # status (uint16): 0 off, 1 running
    "AutoApproach.OnOffGet": ((), ("H",)),
    # action (uint16: 0 start, 1 stop, 2 pause, 3 resume, 4 freeze, 5 unfreeze, 6 go to centre),
    # direction (uint32: 1 up, 0 down)
    "Scan.Action": (("H", "I"), ()),
    # scan status (uint32: 1 running, 0 not)
    "Scan.StatusGet": ((), ("I",)),
    # timeout (ms, int32; -1 forever) -> timed out (uint32: 1 yes), file path size (uint32), file path
    "Scan.WaitEndOfScan": (("i",), ("I", "I", "*-c")),
    # centre X, Y, width, height (m, float32), angle (deg, float32, clockwise)
    "Scan.FrameGet": ((), ("f", "f", "f", "f", "f")),
    # channel count (int32), channel indexes (int32 array), pixels per line, lines (int32)
    "Scan.BufferGet": ((), ("i", "*i", "i", "i")),
    # forward, backward speed (m/s), forward, backward time per line (s) (float32), kept constant
    # (uint16), speed ratio (float32)
    "Scan.SpeedGet": ((), ("f", "f", "f", "f", "H", "f")),
    # channel index (uint32), data direction (uint32: 1 forward, 0 backward) -> channel name size
    # (int32), channel name, rows, columns (int32), data (2D float32, rows x columns), scan
    # direction (uint32: 1 up, 0 down)
    "Scan.FrameDataGrab": (("I", "I"), ("i", "*-c", "i", "i", "2f", "I")),
}

#: a reply's array or string and the number of counts before it that it fills (byte sizes and
#: element counts: the caller gives the array, the encoder writes its counts)
_DEPENDENT = {"*f": 1, "*i": 1, "*-c": 1, "*+c": 2, "2f": 2}
#: the largest frame accepted from Scan.FrameDataGrab: 4096 x 4096 float32 and its fields
MAX_FRAME_BODY = 4096 * 4096 * 4 + 4096


def body_limit(command: str) -> int:
    """The largest body accepted in a reply to ``command`` (:data:`MAX_BODY`; a frame's is larger)."""
    return MAX_FRAME_BODY if command == "Scan.FrameDataGrab" else MAX_BODY


def _name_bytes(command: str) -> bytes:
    b = command.encode("ascii")
    if not 0 < len(b) <= 32:
        raise ValueError(f"a Nanonis command name has 1 to 32 characters (got {command!r})")
    return b


def _pack(types, values, what: str) -> bytes:
    if len(types) != len(values):
        raise ValueError(f"{what} takes {len(types)} values ({', '.join(types) or 'none'}), got {len(values)}")
    out = bytearray()
    for code, v in zip(types, values):
        if code in _SCALARS:
            out += _SCALARS[code].pack(v)
        elif code == "+*i":
            out += struct.pack(f">i{len(v)}i", len(v), *v)
        elif code == "*f":
            out += struct.pack(f">{len(v)}f", *v)
        elif code == "*i":
            out += struct.pack(f">{len(v)}i", *v)
        elif code == "*-c":
            out += v.encode("utf-8")
        elif code == "2f":
            out += np.ascontiguousarray(v, dtype=">f4").tobytes()
        elif code == "*+c":
            for s in v:
                b = s.encode("utf-8")
                out += struct.pack(">i", len(b)) + b
        else:  # pragma: no cover - COMMANDS holds only the codes above
            raise ValueError(f"unknown type code {code!r}")
    return bytes(out)


def encode_request(command: str, args=(), response: bool = True) -> bytes:
    """The request message (header + body) of ``command`` with ``args`` (:data:`COMMANDS` types)."""
    types = COMMANDS[command][0]
    body = _pack(types, args, command)
    return _REQUEST_HEADER.pack(_name_bytes(command), len(body), 1 if response else 0, 0) + body


def encode_reply_body(command: str, values=(), error: str = "") -> bytes:
    """The reply body of ``command``: its return values, then the error section (``error``:
    status 1 and this description; empty: status 0). For an error reply ``values`` may be
    empty (the return values are then zeros, as a server that failed has none to give)."""
    types = COMMANDS[command][1]
    logical = _logical(types)
    if error and not values:
        values = tuple(0 if c in _SCALARS else _EMPTY[c] for c in logical)
    if len(values) != len(logical):
        raise ValueError(f"{command} returns {len(logical)} values ({', '.join(logical)}), got {len(values)}")
    physical: list = []
    for code, v in zip(logical, values):
        if code == "*+c":  # byte size and count of the string array precede it
            names = list(v)
            physical += [sum(4 + len(s.encode("utf-8")) for s in names), len(names), names]
        elif code in ("*f", "*i"):
            physical += [len(v), list(v)]
        elif code == "*-c":
            physical += [len(v.encode("utf-8")), v]
        elif code == "2f":
            a = np.asarray(v, dtype=np.float64).reshape(np.shape(v) if np.ndim(v) == 2 else (0, 0))
            physical += [a.shape[0], a.shape[1], a]
        else:
            physical.append(v)
    desc = error.encode("utf-8")
    return _pack(types, tuple(physical), command) + _ERROR.pack(1 if error else 0, len(desc)) + desc


_EMPTY = {"*f": [], "*i": [], "*+c": [], "*-c": "", "2f": np.zeros((0, 0))}


def _logical(types) -> tuple[str, ...]:
    """The codes of a reply's values as the caller sees them: the counts an array fills dropped."""
    out: list[str] = []
    for code in types:
        k = _DEPENDENT.get(code, 0)
        if k:
            del out[-k:]
        out.append(code)
    return tuple(out)


def encode_reply(command: str, values=(), error: str = "") -> bytes:
    """The whole reply message (header + :func:`encode_reply_body`)."""
    body = encode_reply_body(command, values, error)
    return _REPLY_HEADER.pack(_name_bytes(command), len(body)) + body


def encode_error_reply(command: str, error: str) -> bytes:
    """A reply to any command name with only an error section (status 1, ``error``)."""
    desc = error.encode("utf-8")
    body = _ERROR.pack(1, len(desc)) + desc
    return _REPLY_HEADER.pack(_name_bytes(command), len(body)) + body


def _command_name(raw: bytes, what: str) -> str:
    name = raw.split(b"\0", 1)[0]
    if any(c < 0x20 or c > 0x7E for c in name):
        raise InstrumentLinkLost(f"{what}: the command name field is not ASCII text ({raw[:32]!r})")
    return name.decode("ascii")


def parse_header(header: bytes, *, request: bool = False) -> tuple[str, int, int]:
    """(command, body size, send-response flag) of a 40-byte header (the flag is 1 for a reply).

    Raises :class:`InstrumentLinkLost` for a header that is not 40 bytes, a negative body size or
    one above :func:`body_limit` of the command (:data:`MAX_BODY`; a frame's reply may be larger)."""
    what = "Nanonis request" if request else "Nanonis reply"
    if len(header) != HEADER_SIZE:
        raise InstrumentLinkLost(f"{what}: the header has {len(header)} bytes, not {HEADER_SIZE}")
    if request:
        raw, size, flag, _ = _REQUEST_HEADER.unpack(header)
    else:
        (raw, size), flag = _REPLY_HEADER.unpack(header), 1
    name = _command_name(raw, what)
    limit = MAX_BODY if request else body_limit(name)
    if not 0 <= size <= limit:
        raise InstrumentLinkLost(f"{what} {name or '(no name)'}: body size {size} bytes is outside [0, {limit}]; "
                                 "the stream is not the Nanonis protocol")
    return name, size, flag


class _Reader:
    """Reads typed values from a body, every length checked against the bytes left."""

    def __init__(self, body: bytes, what: str) -> None:
        self.body, self.pos, self.what = memoryview(body), 0, what

    def need(self, n: int, item: str) -> None:
        if n < 0 or self.pos + n > len(self.body):
            raise InstrumentLinkLost(f"{self.what}: {item} needs {n} bytes at offset {self.pos} but the body has "
                                     f"{len(self.body)}; the reply is truncated or not the Nanonis protocol")

    def scalar(self, code: str):
        s = _SCALARS[code]
        self.need(s.size, f"a {code} value")
        (v,) = s.unpack_from(self.body, self.pos)
        self.pos += s.size
        return v

    def count(self, n, width: int, item: str) -> int:
        if not isinstance(n, int) or n < 0:
            raise InstrumentLinkLost(f"{self.what}: {item} count {n!r} is negative")
        self.need(n * width, f"{item} of {n} elements")
        return n

    def floats(self, n: int) -> tuple:
        n = self.count(n, 4, "a float32 array")
        out = struct.unpack_from(f">{n}f", self.body, self.pos)
        self.pos += 4 * n
        return out

    def ints(self, n: int) -> tuple:
        n = self.count(n, 4, "an int32 array")
        out = struct.unpack_from(f">{n}i", self.body, self.pos)
        self.pos += 4 * n
        return out

    def chars(self, n: int) -> str:
        """A string of ``n`` bytes whose size came before it."""
        if not isinstance(n, int) or not 0 <= n <= MAX_STRING:
            raise InstrumentLinkLost(f"{self.what}: a string of {n!r} bytes (allowed 0 to {MAX_STRING})")
        self.need(n, "a string")
        s = bytes(self.body[self.pos:self.pos + n]).split(b"\0", 1)[0].decode("utf-8", "replace")
        self.pos += n
        return s

    def matrix(self, rows: int, cols: int) -> np.ndarray:
        """A (rows, cols) float32 array (row-major), as float64."""
        if not (isinstance(rows, int) and isinstance(cols, int)) or rows < 0 or cols < 0:
            raise InstrumentLinkLost(f"{self.what}: a 2-D array of {rows!r} x {cols!r} elements")
        self.need(4 * rows * cols, f"a {rows} x {cols} float32 array")
        a = np.frombuffer(self.body, dtype=">f4", count=rows * cols, offset=self.pos).astype(np.float64)
        self.pos += 4 * rows * cols
        return a.reshape(rows, cols)

    def string(self) -> str:
        n = self.scalar("i")
        if not 0 <= n <= MAX_STRING:
            raise InstrumentLinkLost(f"{self.what}: a string of {n} bytes (allowed 0 to {MAX_STRING})")
        self.need(n, "a string")
        s = bytes(self.body[self.pos:self.pos + n]).split(b"\0", 1)[0].decode("utf-8", "replace")
        self.pos += n
        return s

    def strings(self, size: int, n: int) -> list:
        """A string array. Strict where the protocol is: the count and every string's length are
        bounded by the bytes left and the body must be consumed exactly (:meth:`done`). Tolerant
        of the array's declared byte size, which clients used on real controllers ignore (the
        document does not say whether it counts the strings' 4-byte length prefixes): it must
        only be a size this body could hold."""
        n = self.count(n, 4, "a string array")
        if not 0 <= size <= len(self.body):
            raise InstrumentLinkLost(f"{self.what}: a string array of {size} bytes in a body of {len(self.body)}")
        return [self.string() for _ in range(n)]

    def done(self) -> None:
        if self.pos != len(self.body):
            raise InstrumentLinkLost(f"{self.what}: {len(self.body) - self.pos} unexpected bytes after the last field")


def decode_reply(command: str, body: bytes):
    """The return values of ``command`` from its reply body, as a tuple; an array replaces the
    count (and byte size) that precede it (``Signals.ValsGet`` -> ``(values,)``).

    Raises
    ------
    ControllerError
        The error section reports an error (status 1 or a description): the message quotes the
        controller's description.
    InstrumentLinkLost
        The body does not have the layout of this command's reply.
    """
    types = COMMANDS[command][1]
    r = _Reader(body, f"Nanonis reply to {command}")
    values = []
    for code in types:
        if code in _SCALARS:
            values.append(r.scalar(code))
        elif code == "*f":
            values[-1:] = [r.floats(values[-1])]
        elif code == "*i":
            values[-1:] = [r.ints(values[-1])]
        elif code == "*-c":
            values[-1:] = [r.chars(values[-1])]
        elif code == "2f":
            values[-2:] = [r.matrix(values[-2], values[-1])]
        elif code == "*+c":
            size, n = values[-2], values[-1]
            values[-2:] = [r.strings(size, n)]
    status = r.scalar("I")
    desc = r.string()  # its size (int32) then its bytes
    r.done()
    if status > 1:
        raise InstrumentLinkLost(f"Nanonis reply to {command}: error status {status} is neither 0 nor 1")
    if status or desc.strip():
        first = (desc.strip().splitlines() or ["(no description)"])[0]
        raise ControllerError(f"the Nanonis controller refused {command}: {first}")
    return tuple(values)


def decode_request(command: str, body: bytes) -> tuple:
    """The arguments of a ``command`` request body (the simulated server's side).

    Raises :class:`KeyError` for a command not in :data:`COMMANDS` and
    :class:`InstrumentLinkLost` for a body without its layout."""
    types = COMMANDS[command][0]
    r = _Reader(body, f"Nanonis request {command}")
    args = []
    for code in types:
        if code in _SCALARS:
            args.append(r.scalar(code))
        elif code == "+*i":
            args.append(r.ints(r.scalar("i")))
    r.done()
    return tuple(args)
