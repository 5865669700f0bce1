#!/usr/bin/env python3
"""Reference client of the arsurf haptic UDP bridge: sends stylus poses, receives forces.

Standard library only, so this one file can be copied to the haptic PC as it is and run there
(``python client.py ...``); with arsurf installed it is ``python -m arsurf.haptics.client``. The packet layout is the one
documented in ``arsurf/haptics/udp_bridge.py`` and ``docs/bridge-protocol.rst`` (protocol version
3, little-endian, HMAC-SHA256 tag last, a per-session id from the server's CHALLENGE); ``tests/haptics/test_udp_bridge.py`` checks that this file and
the bridge agree byte for byte and that this client drops every bad FORCE packet.

Run it against a bridge with the session key the bridge wrote (``arsurf view --bridge-port``
prints the key file's path)::

    python -m arsurf.haptics.client --port 47474 --key-file /tmp/arsurf-bridge-xyz/bridge.key \
        --rate 1000 --duration 5 --radius 0.02

It first says HELLO and takes the session id from the bridge's CHALLENGE (a packet recorded in an
earlier session never belongs to this one), then moves a virtual stylus on a circle of ``--radius``
metres at ``--frequency`` Hz, sends one POSE per tick, reads the FORCE replies, and prints a JSON summary (packets, round-trip times, largest
force, dropped replies by reason). A real haptic PC replaces the circle with its device position
and applies :meth:`HapticClient.poll`'s force to the device: that force comes only from a FORCE
packet that passed every check (sender address, tag, sequence number, session, ``ack`` of one of
this client's poses, finite values, ``--max-force``) and is zero when no such packet arrived for
``--timeout`` seconds. On exit the client sends RELEASE so that another client may connect.
``examples/cpp/arsurf_client.cpp`` is the same client in C++ (on ``include/arsurf_bridge.h``).

The bridge's frame is arsurf's (x right, y away from the operator, z up; metres, newtons; the
FORCE is the one to apply to the stylus, docs/bridge.rst): the circle here is drawn in it. A
device in another frame converts at this edge: :func:`from_openhaptics` (HD frame: x right, y up,
z towards the operator, millimetres) before :meth:`HapticClient.send_pose`, and
:func:`to_openhaptics` on :meth:`HapticClient.poll`'s force before applying it.

Examples
--------
>>> c = HapticClient("127.0.0.1", 9, key=bytes(32))   # nothing needs to listen to build packets
>>> len(encode_pose(bytes(32), 1, 0.0, (0.0, 0.0, 0.0), session=bytes(16)))
156
>>> c.poll()
(0.0, 0.0, 0.0)
>>> c.close()
"""
from __future__ import annotations

import argparse
import hashlib
import hmac
import json
import math
import os
import socket
import stat
import struct
import sys
import time

MAGIC = b"ARSH"
VERSION = 3
TYPE_POSE = 1
TYPE_FORCE = 2
TYPE_RELEASE = 3
TYPE_HELLO = 4
TYPE_CHALLENGE = 5
MAC_SIZE = 32
SESSION_SIZE = 16
NO_SESSION = bytes(SESSION_SIZE)
HEADER = struct.Struct("<4sBBHQ")  # magic, version, type, flags, sequence number: 16 bytes
POSE = struct.Struct("<4sBBHQ16sd3d3d4dI")  # + 32-byte tag = 156 bytes
FORCE = struct.Struct("<4sBBHQ16sQdd3d")  # + 32-byte tag = 112 bytes
RELEASE = struct.Struct("<4sBBHQ16sd")  # + 32-byte tag = 72 bytes; HELLO: the same, session field zero
CHALLENGE = struct.Struct("<4sBBHQ16sQ")  # + 32-byte tag = 72 bytes
FORCE_SIZE = FORCE.size + MAC_SIZE
CHALLENGE_SIZE = CHALLENGE.size + MAC_SIZE
NAN3 = (math.nan, math.nan, math.nan)
WINDOW = 64
#: Reasons a datagram from the server is dropped (the keys of :attr:`HapticClient.stats`, with the totals).
DROP_REASONS = ("oversized", "truncated", "foreign", "bad_magic", "bad_version", "bad_type", "bad_mac",
                "replayed", "out_of_order", "bad_ack", "bad_session", "nonfinite", "over_limit")


def from_openhaptics(hd_mm):
    """A position (mm) or velocity (mm/s) in OpenHaptics' HD frame (x right, y up, z towards the
    operator) in the bridge's frame, in m (m/s): :math:`(x, -z, y) \\times 10^{-3}`.

    >>> from_openhaptics((0.0, -2.0, 5.0))   # 2 mm down, 5 mm towards the operator
    (0.0, -0.005, -0.002)
    """
    x, y, z = hd_mm
    return (1e-3 * x, -1e-3 * z, 1e-3 * y)


def to_openhaptics(force):
    """The bridge's force (N, to apply to the stylus) in OpenHaptics' HD frame: :math:`(F_x, F_z, -F_y)`
    (a rotation, the inverse of :func:`from_openhaptics`'s: the power F.v is the same in both).

    >>> to_openhaptics((0.0, 0.0, 1.5))   # the surface pushes the hand up: HD +y
    (0.0, 1.5, -0.0)
    """
    fx, fy, fz = force
    return (fx, fz, -fy)


def mac(key, body):
    """HMAC-SHA256 tag of ``body`` under ``key`` (32 bytes)."""
    return hmac.new(key, body, hashlib.sha256).digest()


def encode_pose(key, seq, t, position, velocity=NAN3, quaternion=(1.0, 0.0, 0.0, 0.0), buttons=0, *, session):
    """POSE packet bytes of the session ``session`` (see the module docstring of arsurf.haptics.udp_bridge)."""
    body = POSE.pack(MAGIC, VERSION, TYPE_POSE, 0, seq, session, float(t), *map(float, position),
                     *map(float, velocity), *map(float, quaternion), buttons & 0xFFFFFFFF)
    return body + mac(key, body)


def encode_release(key, seq, t, *, session):
    """RELEASE packet bytes: this client is done, the server may accept another."""
    body = RELEASE.pack(MAGIC, VERSION, TYPE_RELEASE, 0, seq, session, float(t))
    return body + mac(key, body)


def encode_hello(key, seq, t):
    """HELLO packet bytes: ask the server for its session id (it answers with a CHALLENGE)."""
    body = RELEASE.pack(MAGIC, VERSION, TYPE_HELLO, 0, seq, NO_SESSION, float(t))
    return body + mac(key, body)


def decode_force(key, data):
    """FORCE packet fields as a dict, or None if the bytes are not a FORCE packet tagged under ``key``.

    Format and tag only; :meth:`HapticClient.poll` checks the rest before a force is applied.
    """
    if len(data) != FORCE_SIZE:
        return None
    f = FORCE.unpack_from(data)
    if f[0] != MAGIC or f[1] != VERSION or f[2] != TYPE_FORCE:
        return None
    if not hmac.compare_digest(mac(key, data[:FORCE.size]), data[FORCE.size:FORCE_SIZE]):
        return None
    return {"flags": f[3], "seq": f[4], "session": f[5], "ack": f[6], "t": f[7], "echo": f[8], "force": f[9:12]}


def _key_file_problem(path, fd):
    """Why the open key file ``fd`` may not be trusted (as ssh judges a private key), or None."""
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        return "is not a regular file"
    if os.name != "posix":
        return None
    if st.st_uid != os.geteuid():
        return f"is owned by uid {st.st_uid}, not by you (uid {os.geteuid()}): someone else may have planted it"
    if st.st_mode & 0o077:
        return f"is accessible to other users (mode {oct(st.st_mode & 0o777)}); chmod 600 it"
    folder = os.path.dirname(os.path.abspath(path))
    fst = os.stat(folder)
    if fst.st_uid not in (os.geteuid(), 0) or fst.st_mode & 0o022:
        return (f"is in a folder other users can write to or own ({folder}, uid {fst.st_uid}, mode "
                f"{oct(fst.st_mode & 0o777)}): someone else could have planted it; use a folder of your own")
    if st.st_size > 4096:
        return f"is {st.st_size} bytes; a key file is one line of hex"
    return None


def read_key(key=None, key_file=None):
    """The session key from hex text or from a key file.

    The file is opened without following a link or blocking, and refused (one line, exit status
    2) unless it is a regular file owned by this user, readable by its owner only, in a folder
    no one else can write to: the rules of the bridge's ``load_key`` (and of ssh).
    """
    if (key is None) == (key_file is None):
        raise SystemExit("haptic_client: give the session key with exactly one of --key HEX or --key-file PATH")
    if key_file is not None:
        flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
        try:
            fd = os.open(key_file, flags)
            try:
                why = _key_file_problem(key_file, fd)
                if why is None:
                    key = os.read(fd, 4097).decode("ascii", errors="replace")
            finally:
                os.close(fd)
        except OSError as exc:
            raise SystemExit(f"haptic_client: cannot read key file {key_file} ({exc.strerror})") from None
        if why is not None:
            raise SystemExit(f"haptic_client: key file {key_file} {why}")
    try:
        k = bytes.fromhex(key.strip())
    except ValueError:
        raise SystemExit("haptic_client: the key must be hexadecimal digits") from None
    if not 16 <= len(k) <= 64:
        raise SystemExit(f"haptic_client: the key must be 16 to 64 bytes (got {len(k)})")
    return k


class HapticClient:
    """Minimal client: :meth:`send_pose` once per tick, :meth:`poll` for the force to apply.

    Parameters
    ----------
    host, port : str, int
        The bridge.
    key : bytes
        The session key (16 to 64 bytes) the bridge uses.
    max_force : float, N
        The device's force limit: a FORCE above it is dropped, not clamped (default 7.9 N, Touch X).
    timeout : float, s
        Without a valid FORCE for this long, :meth:`poll` returns zero force (default 0.1 s).
    local_port : int
        Local UDP port (0: any). A fixed port lets a restarted client come back as the same peer.
    clock : callable
        Monotonic clock in seconds (default ``time.perf_counter``).
    """

    def __init__(self, host="127.0.0.1", port=47474, key=None, *, max_force=7.9, timeout=0.1, local_port=0,
                 clock=time.perf_counter):
        if not isinstance(key, (bytes, bytearray)) or not 16 <= len(key) <= 64:
            raise ValueError("key must be the bridge's session key, 16 to 64 bytes")
        if not (isinstance(max_force, (int, float)) and 0 < max_force < math.inf):
            raise ValueError(f"max_force must be a positive finite force in newtons (got {max_force!r})")
        self.key = bytes(key)
        self.max_force = float(max_force)
        self.timeout = float(timeout)
        self.server = socket.getaddrinfo(host, int(port), socket.AF_INET, socket.SOCK_DGRAM)[0][4][:2]
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1" if self.server[0].startswith("127.") else "", int(local_port)))
        self.sock.setblocking(False)
        self._clock = clock
        self.t0 = clock()
        # sequence numbers only grow under one key, across restarts too: start from the wall clock (us)
        self.seq = time.time_ns() // 1000
        self.first_seq = self.seq + 1
        self.force = (0.0, 0.0, 0.0)  # last accepted force
        self.last_reply = None  # (local time, fields) of the last accepted FORCE
        self._last_rx = -math.inf
        self._rseq = None
        self._seen = 0
        self.rtts = []
        self.stats = dict.fromkeys(("received", "accepted", "challenges", "hellos") + DROP_REASONS, 0)
        self.released = False
        self.session = None  # the server's session id, from its CHALLENGE (None: say HELLO first)
        self._last_hello = -math.inf

    @property
    def invalid(self):
        """FORCE packets dropped, all reasons."""
        return sum(self.stats[r] for r in DROP_REASONS)

    def clock(self):
        return self._clock() - self.t0

    def _next_seq(self):
        self.seq += 1
        return self.seq

    def hello(self):
        """Ask the bridge for its session id (HELLO; :meth:`poll` takes the CHALLENGE that answers)."""
        self._last_hello = self._clock()
        self.stats["hellos"] += 1
        try:
            self.sock.sendto(encode_hello(self.key, self._next_seq(), self.clock()), self.server)
        except OSError:  # the bridge not there yet (ICMP unreachable)
            pass

    def send_pose(self, position, velocity=NAN3, buttons=0, quaternion=(1.0, 0.0, 0.0, 0.0)):
        """Send one pose of this session; returns its sequence number.

        Without a session id yet it sends a HELLO instead and returns None; with one but no valid
        FORCE for ``timeout`` (the bridge may have restarted: a new session) it also says HELLO again,
        once per ``timeout``.
        """
        now = self._clock()
        if self.session is None or (now - self._last_rx > self.timeout and now - self._last_hello > self.timeout):
            self.hello()
            if self.session is None:
                return None
        seq = self._next_seq()
        self.sock.sendto(encode_pose(self.key, seq, self.clock(), position, velocity, quaternion, buttons,
                                     session=self.session), self.server)
        return seq

    def release(self):
        """Tell the bridge this client is done (it unpins the client; another may connect)."""
        if self.session is None:
            return
        try:
            self.sock.sendto(encode_release(self.key, self._next_seq(), self.clock(), session=self.session),
                             self.server)
            self.released = True
        except OSError:
            pass

    def _check(self, data, addr):
        """The FORCE fields if the datagram passes every check, else None (reason counted; an
        accepted CHALLENGE sets :attr:`session` and is counted in ``challenges``)."""
        st = self.stats
        n = len(data)
        if n > FORCE_SIZE:
            st["oversized"] += 1
            return None
        if addr[:2] != self.server:
            st["foreign"] += 1
            return None
        if n < HEADER.size:
            st["truncated"] += 1
            return None
        magic, version, kind, _, seq = HEADER.unpack_from(data)
        if magic != MAGIC:
            st["bad_magic"] += 1
            return None
        if version != VERSION:
            st["bad_version"] += 1
            return None
        if kind not in (TYPE_FORCE, TYPE_CHALLENGE):
            st["bad_type"] += 1
            return None
        body = FORCE.size if kind == TYPE_FORCE else CHALLENGE.size
        if n != body + MAC_SIZE:
            st["truncated" if n < body + MAC_SIZE else "oversized"] += 1
            return None
        if not hmac.compare_digest(mac(self.key, data[:body]), data[body:]):
            st["bad_mac"] += 1
            return None
        last = self._rseq
        if last is not None and seq <= last:
            k = last - seq
            st["replayed" if k < WINDOW and (self._seen >> k) & 1 else "out_of_order"] += 1
            return None
        f = (FORCE if kind == TYPE_FORCE else CHALLENGE).unpack_from(data)
        ack = f[6]
        if not self.first_seq <= ack <= self.seq:  # must acknowledge one of this client's packets
            st["bad_ack"] += 1
            return None
        if kind == TYPE_FORCE:
            if f[5] != self.session:  # another session's FORCE (this client's HELLO was not answered by it)
                st["bad_session"] += 1
                return None
            force = f[9:12]
            if not all(math.isfinite(v) for v in force) or not math.isfinite(f[7]):
                st["nonfinite"] += 1
                return None
            if math.sqrt(sum(v * v for v in force)) > self.max_force * (1.0 + 1e-9):
                st["over_limit"] += 1
                return None
        d = WINDOW if last is None else seq - last
        self._seen = ((self._seen << d) | 1) & ((1 << WINDOW) - 1) if d < WINDOW else 1
        self._rseq = seq
        if kind == TYPE_CHALLENGE:
            self.session = f[5]
            st["challenges"] += 1
            return None
        return {"flags": f[3], "seq": seq, "ack": ack, "t": f[7], "echo": f[8], "force": force}

    def poll(self):
        """Read every pending datagram; returns the force (N) to apply now.

        That is the last FORCE that passed every check, or zero if none did within ``timeout``.
        """
        while True:
            try:
                data, addr = self.sock.recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # server not there yet (ICMP unreachable)
                break
            self.stats["received"] += 1
            reply = self._check(data, addr)
            if reply is None:
                continue
            self.stats["accepted"] += 1
            self.force = reply["force"]
            self._last_rx = self._clock()
            self.last_reply = (self._last_rx, reply)
            if math.isfinite(reply["echo"]):
                self.rtts.append(self.clock() - reply["echo"])
        if self._clock() - self._last_rx > self.timeout:
            return (0.0, 0.0, 0.0)  # no news from the server: apply no force
        return self.force

    def close(self):
        """Send RELEASE (if a session was started) and close the socket."""
        if self.session is not None and not self.released:
            self.release()
        self.sock.close()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=47474)
    ap.add_argument("--key", help="session key as hex (visible to other users in the process list: "
                    "prefer --key-file)")
    ap.add_argument("--key-file", help="file holding the session key as hex (owner-only permissions)")
    ap.add_argument("--max-force", type=float, default=7.9, help="device force limit, N; larger FORCEs are dropped")
    ap.add_argument("--rate", type=float, default=1000.0, help="poses per second")
    ap.add_argument("--duration", type=float, default=5.0, help="seconds")
    ap.add_argument("--radius", type=float, default=0.02, help="circle radius, m")
    ap.add_argument("--frequency", type=float, default=0.5, help="circle frequency, Hz")
    ap.add_argument("--timeout", type=float, default=0.1, help="apply zero force after this long without FORCE, s")
    ap.add_argument("--local-port", type=int, default=0, help="local UDP port (0: any)")
    args = ap.parse_args(argv)
    key = read_key(args.key, args.key_file)
    client = HapticClient(args.host, args.port, key, max_force=args.max_force, timeout=args.timeout,
                          local_port=args.local_port)
    period = 1.0 / args.rate
    n = int(args.duration * args.rate)
    fmax = 0.0
    zeroed = poses = 0
    start = time.perf_counter()
    try:
        for k in range(n):
            t = k * period
            w = 2.0 * math.pi * args.frequency
            pos = (args.radius * math.cos(w * t), args.radius * math.sin(w * t), 0.0)
            vel = (-args.radius * w * math.sin(w * t), args.radius * w * math.cos(w * t), 0.0)
            poses += client.send_pose(pos, vel) is not None
            f = client.poll()
            if client.last_reply is None or time.perf_counter() - client.last_reply[0] > args.timeout:
                zeroed += 1
            fmax = max(fmax, math.sqrt(sum(v * v for v in f)))
            deadline = start + (k + 1) * period
            while time.perf_counter() < deadline:
                time.sleep(max(0.0, min(deadline - time.perf_counter() - 2e-4, 1e-3)))
        time.sleep(0.05)
        client.poll()
    finally:
        client.close()
    rtts = sorted(client.rtts)
    summary = {
        "sent": n,
        "poses_sent": poses,
        "hellos_sent": client.stats["hellos"],
        "replies_with_rtt": len(rtts),
        "invalid_replies": client.invalid,
        "dropped_replies": {r: client.stats[r] for r in DROP_REASONS if client.stats[r]},
        "ticks_with_zero_force_for_timeout": zeroed,
        "rtt_median_s": rtts[len(rtts) // 2] if rtts else None,
        "rtt_p99_s": rtts[min(len(rtts) - 1, int(0.99 * len(rtts)))] if rtts else None,
        "max_force_N": fmax,
    }
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
