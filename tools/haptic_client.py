#!/usr/bin/env python3
"""Reference client of the arsurf haptic UDP bridge: sends stylus poses, receives forces.

Standard library only, so it can be copied to the haptic PC as it is. The packet layout is the one
documented in ``arsurf/haptics/udp_bridge.py`` (protocol version 1, little-endian, CRC-32 last);
``tests/test_udp_bridge.py`` checks that this file and the bridge agree byte for byte.

Run it against a bridge (``arsurf`` listens on 127.0.0.1:47474 by default)::

    python tools/haptic_client.py --port 47474 --rate 1000 --duration 5 --radius 0.02

It moves a virtual stylus on a circle of ``--radius`` metres at ``--frequency`` Hz, sends one POSE
per tick, reads the FORCE replies, and prints a JSON summary (packets, round-trip times, largest
force). A real haptic PC replaces the circle with its device position and applies ``force`` to
the device; if no FORCE arrives for ``--timeout`` seconds it must apply zero force.

Example
-------
>>> c = HapticClient("127.0.0.1", 9)          # nothing needs to listen to build packets
>>> len(encode_pose(1, 0.0, (0.0, 0.0, 0.0)))
108
>>> c.close()
"""
from __future__ import annotations

import argparse
import json
import math
import socket
import struct
import sys
import time
import zlib

MAGIC = b"ARSH"
VERSION = 1
TYPE_POSE = 1
TYPE_FORCE = 2
FLAG_RESET = 1
POSE = struct.Struct("<4sBBHId3d3d4dI")  # + u32 CRC-32 = 108 bytes
FORCE = struct.Struct("<4sBBHIIdd3d")  # + u32 CRC-32 = 60 bytes
CRC = struct.Struct("<I")
NAN3 = (math.nan, math.nan, math.nan)


def encode_pose(seq, t, position, velocity=NAN3, quaternion=(1.0, 0.0, 0.0, 0.0), buttons=0, reset=False):
    """POSE packet bytes (see the module docstring of arsurf.haptics.udp_bridge)."""
    body = POSE.pack(MAGIC, VERSION, TYPE_POSE, FLAG_RESET if reset else 0, seq & 0xFFFFFFFF, float(t),
                     *map(float, position), *map(float, velocity), *map(float, quaternion), buttons & 0xFFFFFFFF)
    return body + CRC.pack(zlib.crc32(body))


def decode_force(data):
    """FORCE packet fields as a dict, or None if the bytes are not a valid FORCE packet."""
    if len(data) != FORCE.size + 4:
        return None
    f = FORCE.unpack_from(data)
    if f[0] != MAGIC or f[1] != VERSION or f[2] != TYPE_FORCE:
        return None
    if CRC.unpack_from(data, FORCE.size)[0] != zlib.crc32(data[:FORCE.size]):
        return None
    return {"flags": f[3], "seq": f[4], "ack": f[5], "t": f[6], "echo": f[7], "force": f[8:11]}


class HapticClient:
    """Minimal client: :meth:`send_pose` once per tick, :meth:`poll` for the latest force."""

    def __init__(self, host="127.0.0.1", port=47474):
        self.server = (host, int(port))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.seq = 0
        self.t0 = time.perf_counter()
        self.force = (0.0, 0.0, 0.0)
        self.last_reply = None
        self.rtts = []
        self.invalid = 0

    def clock(self):
        return time.perf_counter() - self.t0

    def send_pose(self, position, velocity=NAN3, buttons=0, quaternion=(1.0, 0.0, 0.0, 0.0)):
        """Send one pose; the first packet carries the RESET flag. Returns its sequence number."""
        self.seq = (self.seq + 1) & 0xFFFFFFFF
        pkt = encode_pose(self.seq, self.clock(), position, velocity, quaternion, buttons, reset=self.seq == 1)
        self.sock.sendto(pkt, self.server)
        return self.seq

    def poll(self):
        """Read every pending FORCE packet; returns the latest force (N) received so far."""
        while True:
            try:
                data = self.sock.recv(2048)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # server not there yet (ICMP unreachable)
                break
            reply = decode_force(data)
            if reply is None:
                self.invalid += 1
                continue
            self.force = reply["force"]
            self.last_reply = (time.perf_counter(), reply)
            if math.isfinite(reply["echo"]):
                self.rtts.append(self.clock() - reply["echo"])
        return self.force

    def close(self):
        self.sock.close()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=47474)
    ap.add_argument("--rate", type=float, default=1000.0, help="poses per second")
    ap.add_argument("--duration", type=float, default=5.0, help="seconds")
    ap.add_argument("--radius", type=float, default=0.02, help="circle radius, m")
    ap.add_argument("--frequency", type=float, default=0.5, help="circle frequency, Hz")
    ap.add_argument("--timeout", type=float, default=0.1, help="apply zero force after this long without FORCE, s")
    args = ap.parse_args(argv)
    client = HapticClient(args.host, args.port)
    period = 1.0 / args.rate
    n = int(args.duration * args.rate)
    fmax = 0.0
    zeroed = 0
    start = time.perf_counter()
    try:
        for k in range(n):
            t = k * period
            w = 2.0 * math.pi * args.frequency
            pos = (args.radius * math.cos(w * t), args.radius * math.sin(w * t), 0.0)
            vel = (-args.radius * w * math.sin(w * t), args.radius * w * math.cos(w * t), 0.0)
            client.send_pose(pos, vel)
            f = client.poll()
            if client.last_reply is None or time.perf_counter() - client.last_reply[0] > args.timeout:
                f = (0.0, 0.0, 0.0)  # no news from the server: apply no force
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
        "replies_with_rtt": len(rtts),
        "invalid_replies": client.invalid,
        "ticks_with_zero_force_for_timeout": zeroed,
        "rtt_median_s": rtts[len(rtts) // 2] if rtts else None,
        "rtt_p99_s": rtts[min(len(rtts) - 1, int(0.99 * len(rtts)))] if rtts else None,
        "max_force_N": fmax,
    }
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
